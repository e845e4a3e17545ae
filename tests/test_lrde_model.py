"""Tests of the offset-encoder model (Zhang & Gao eqs. 1-21) against analytic answers."""
import numpy as np
import pytest

from enclab.lrde import model

STEP = np.deg2rad(0.09)  # Ros-Drill encoder resolution (paper 002, Section I)


def test_encoder_trigger_levels_follow_fig2():
    # Fig. 2: from theta = 0 the reading steps up at step - a and down at -a.
    a = 0.3 * STEP
    tiny = 1e-9 * STEP
    theta = np.array([0.0, STEP - a - tiny, STEP - a + tiny, -a + tiny, -a - tiny,
                      2 * STEP - a + tiny, -STEP - a - tiny])
    counts = model.encoder_counts(theta, STEP, a)
    assert counts.dtype == np.int64
    np.testing.assert_array_equal(counts, [0, 0, 1, 0, -1, 2, -2])


def test_half_step_offset_is_the_rounding_quantizer():
    theta = np.linspace(-5 * STEP, 5 * STEP, 10_001)
    reading = STEP * model.encoder_counts(theta, STEP, 0.5 * STEP)
    # Rounding: the error never exceeds half a step (plus float rounding).
    assert np.max(np.abs(reading - theta)) <= 0.5 * STEP * (1 + 1e-12)


def test_offset_error_is_uniform_below_the_offset():
    # e = step*floor((theta+a)/step) - theta = a - step*frac((theta+a)/step), so for theta
    # spread over many steps (e - a)/step ~ U(-1, 0]: the offset a shifts the error mean to
    # a - step/2 (zero only for the rounding quantizer a = step/2).
    rng = np.random.default_rng(1)
    n = 200_000
    a = rng.uniform(0, STEP, n)
    theta = rng.normal(0, 3 * STEP, n)
    e = STEP * model.encoder_counts(theta, STEP, a) - theta
    u = (e - a) / STEP
    assert u.min() > -1 - 1e-12 and u.max() <= 1e-12
    # Standard error of the mean of U(-1,0): sqrt(1/12/n) = 6.5e-4; 5 sigma.
    assert abs(u.mean() + 0.5) < 5 * np.sqrt(1 / 12 / n)
    # Var of the sample variance of U: (1/80 - 1/144)/n -> sd 1.7e-4; 5 sigma.
    assert abs(u.var() - 1 / 12) < 5 * np.sqrt((1 / 80 - 1 / 144) / n)


def test_sinusoid_stroke_and_bias_descriptors():
    t = np.linspace(0, 1, 100_001)
    theta = model.sinusoid(t, 0.31, 0.02, 5.0, 0.3)
    A1, A2 = theta.max(), -theta.min()
    # Eq. (2) and A12 = A1 + A2 on a dense grid (5 Hz, 1e5 points: max error ~ A (2 pi f dt)^2/2).
    assert A1 + A2 == pytest.approx(0.31, abs=1e-7)
    assert (A1 - A2) / 2 == pytest.approx(0.02, abs=1e-7)


def test_ideal_bias_reads_2n_steps_for_any_offset_and_stroke_in_band():
    # Proposition 1, "especially": with b = ideal bias every A12 in ((2n-1), (2n+1)) step
    # reads -n..n.
    phi = 2 * np.pi * (np.arange(20_000) + 0.5) / 20_000
    for n in (1, 2, 3):
        for a in np.linspace(0.01, 0.99, 7) * STEP:
            for A12 in np.linspace(2 * n - 0.99, 2 * n + 0.99, 9) * STEP:
                b = model.ideal_bias(STEP, a)
                counts = model.encoder_counts(b + 0.5 * A12 * np.sin(phi), STEP, a)
                assert (counts.min(), counts.max()) == (-n, n)


def test_epsilon_band_and_step_count_band():
    assert model.epsilon(3.44 * STEP, STEP) == pytest.approx(0.44 * STEP)
    assert model.epsilon(4.7 * STEP, STEP) == pytest.approx(0.3 * STEP)
    assert model.band_n(3.44 * STEP, STEP) == 2
    assert model.step_count_band(2, STEP) == pytest.approx((3 * STEP, 5 * STEP))
    with pytest.raises(ValueError, match="n must be"):
        model.step_count_band(0, STEP)
    with pytest.raises(ValueError, match="step"):
        model.epsilon(1.0, -1.0)


def test_paper_fig6_numbers():
    # Fig. 6: A12 = 0.31 deg with step 0.09 deg gives epsilon/2 = 0.02 deg.
    assert np.rad2deg(model.epsilon(np.deg2rad(0.31), STEP)) / 2 == pytest.approx(0.02)


@pytest.mark.parametrize("A12_steps", [3.2, 3.44, 3.9, 4.3, 4.8])
def test_prop1_band_is_necessary_and_sufficient(A12_steps):
    A12 = A12_steps * STEP
    a = 0.37 * STEP
    lo, hi = model.prop1_bias_band(A12, a, STEP)
    assert hi - lo == pytest.approx(model.epsilon(A12, STEP))
    phi = 2 * np.pi * (np.arange(200_000) + 0.5) / 200_000
    # Sampling the phase finely misses the extremes by at most A (pi/2e5)^2/2 ~ 1e-10 A:
    # biases a relative 1e-6 of a step from the band edges are decided unambiguously.
    margin = 1e-6 * STEP
    for b, inside in ((lo + margin, True), (hi - margin, True), (0.5 * (lo + hi), True),
                      (lo - margin, False), (hi + margin, False), (hi + 0.23 * STEP, False)):
        counts = model.encoder_counts(b + 0.5 * A12 * np.sin(phi), STEP, a)
        symmetric_2n = (counts.min(), counts.max()) == (-2, 2)
        assert symmetric_2n == inside, (b, lo, hi)
        # The analytic extreme counts agree with the sampled ones.
        assert model.expected_step_count(A12, a + b, STEP) == counts.max() - counts.min()


def test_dwell_half_widths_and_eq4_exact():
    f = 25.0
    rng = np.random.default_rng(7)
    for _ in range(50):
        A12 = rng.uniform(3.01, 4.99) * STEP
        half_eps = 0.5 * model.epsilon(A12, STEP)
        E_b = rng.uniform(-0.99, 0.99) * half_eps
        w1, w2 = model.dwell_half_widths(A12, 0.5 * STEP + E_b, STEP, f)
        assert model.dwell_stroke_eq4(w1, w2, f, STEP) == pytest.approx(A12, rel=1e-12)
        a_eq = model.dwell_a_eq(w1, w2, f, STEP, np.int64(2), np.int64(-2))
        assert a_eq == pytest.approx(0.5 * STEP + E_b, abs=1e-12 * STEP)
        # Longer top dwell <=> E_b > 0.
        assert np.sign(w1 - w2) == np.sign(E_b)


def test_dwell_half_widths_against_sampled_crest():
    # Independent check: time above the top trigger level on a dense grid.
    f, fs = 20.0, 2e6
    A12, a_eq = 3.44 * STEP, 0.55 * STEP
    t = np.arange(int(fs / f)) / fs
    counts = model.encoder_counts(0.5 * A12 * np.sin(2 * np.pi * f * t), STEP, a_eq)
    w1, w2 = model.dwell_half_widths(A12, a_eq, STEP, f)
    # Counting samples resolves each dwell 2w to +-1/fs.
    assert np.sum(counts == 2) / fs == pytest.approx(2 * w1, abs=1 / fs)
    assert np.sum(counts == -2) / fs == pytest.approx(2 * w2, abs=1 / fs)


def test_dwell_stroke_validates():
    with pytest.raises(ValueError, match="w1"):
        model.dwell_stroke_eq4(1.0, 0.001, 20.0, STEP)
    with pytest.raises(ValueError, match="steps_pp"):
        model.dwell_stroke(0.001, 0.001, 20.0, STEP, 1)


def test_prop2_dc_component_analytic_vs_numeric():
    A12 = np.deg2rad(0.31)
    half_eps = 0.5 * model.epsilon(A12, STEP)
    n_points = 400_000
    E_values = np.linspace(-0.95, 0.95, 11) * half_eps
    c0 = np.array([model.dc_component(E, A12, STEP, 2) for E in E_values])
    for E, c in zip(E_values, c0):
        # 8 jumps per cycle, each misplaced by at most half a cell: |error| <= 4 step / n_points.
        num = model.dc_component_numeric(E, A12, STEP, n_points=n_points)
        assert abs(c - num) <= 4 * STEP / n_points
        assert c == pytest.approx(model.mean_reading(A12, 0.5 * STEP + E, STEP), abs=1e-15)
    # Eq. (21): odd in E_b, zero at 0, same sign as E_b, |c0| increasing in |E_b|.
    np.testing.assert_allclose(c0, -c0[::-1], atol=1e-18)
    assert model.dc_component(0.0, A12, STEP, 2) == 0.0
    assert np.all(np.sign(c0[E_values != 0]) == np.sign(E_values[E_values != 0]))
    assert np.all(np.diff(c0) > 0)


def test_dc_component_rejects_out_of_band():
    A12 = np.deg2rad(0.31)
    with pytest.raises(ValueError, match="E_b"):
        model.dc_component(0.6 * model.epsilon(A12, STEP), A12, STEP, 2)
    with pytest.raises(ValueError, match="A12"):
        model.dc_component(0.0, 5.5 * STEP, STEP, 2)


def _extremes_by_bounded_search(A12, orders, c, s):
    """Independent reference: bounded scalar searches around a dense grid's extremes."""
    from scipy.optimize import minimize_scalar

    def theta(phi):
        return 0.5 * A12 * np.sin(phi) + sum(ck * np.cos(k * phi) + sk * np.sin(k * phi)
                                             for k, ck, sk in zip(orders, c, s))
    grid = np.linspace(0.0, 2.0 * np.pi, 20001)
    values = theta(grid)
    out = []
    for sign in (1.0, -1.0):
        i = int(np.argmax(sign * values))
        res = minimize_scalar(lambda p: -sign * theta(p), bounds=(grid[i] - 1e-3, grid[i] + 1e-3),
                              method="bounded", options={"xatol": 1e-12})
        out.append(max(sign * values[i], -res.fun) * sign)
    return out[0] - out[1], 0.5 * (out[0] + out[1])


def test_stroke_and_midpoint_match_a_bounded_search_and_the_sine_cases():
    rng = np.random.default_rng(11)
    n = 40
    A12 = rng.uniform(2.0, 5.0, n)
    orders = (2, 3, 5)
    # Up to 0.6 of the fundamental's amplitude: several local extrema per cycle.
    c = rng.uniform(-0.6, 0.6, (n, 3)) * A12[:, None] / 2
    s = rng.uniform(-0.6, 0.6, (n, 3)) * A12[:, None] / 2
    stroke, mid = model.stroke_and_midpoint(A12, orders, c, s)
    for i in range(n):
        ref_stroke, ref_mid = _extremes_by_bounded_search(A12[i], orders, c[i], s[i])
        assert stroke[i] == pytest.approx(ref_stroke, abs=1e-10 * A12[i])
        assert mid[i] == pytest.approx(ref_mid, abs=1e-10 * A12[i])
    # A pure sine: 2 A about its mean.
    stroke, mid = model.stroke_and_midpoint(A12, (), np.zeros((n, 0)), np.zeros((n, 0)))
    np.testing.assert_allclose(stroke, A12, rtol=1e-15)
    np.testing.assert_allclose(mid, 0.0, atol=1e-15 * A12.max())
    # sin(phi) + s3 sin(3 phi) with s3 < A/18 peaks at phi = pi/2: stroke A12 - 2 s3; odd
    # harmonics keep the extremes symmetric about the mean.
    s3 = rng.uniform(-1.0, 1.0, n) * A12 / 40
    stroke, mid = model.stroke_and_midpoint(A12, (3,), np.zeros((n, 1)), s3[:, None])
    np.testing.assert_allclose(stroke, A12 - 2 * s3, rtol=1e-13)
    np.testing.assert_allclose(mid, 0.0, atol=1e-13 * A12.max())
    with pytest.raises(ValueError, match=">= 2"):
        model.stroke_and_midpoint(A12, (1,), np.zeros((n, 1)), np.zeros((n, 1)))
