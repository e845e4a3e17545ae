"""Motion models of the low-resolution fit (enclab.lrde.motion): paper 002's quantities for a
periodic motion that is not a sinusoid, against brute-force readings."""
import math

import numpy as np
import pytest

from enclab.lrde import effects, fit, model, motion, simulate

STEP = np.deg2rad(0.09)
PHI = 2.0 * np.pi * (np.arange(20_000) + 0.5) / 20_000  # one cycle, dense


def _shape(rng, orders, size):
    """Coefficients ``{k: (c_k, s_k)}`` in steps and the motion about its mean on PHI."""
    coef = {k: tuple(rng.uniform(-size, size, 2)) for k in orders}
    theta = rng.uniform(1.5, 2.0) * np.sin(PHI)
    for k, (c, s) in coef.items():
        theta = theta + c * np.cos(k * PHI) + s * np.sin(k * PHI)
    return coef, theta


def test_labels_and_configuration():
    assert motion.motion_model([]).label == "sinusoid"
    assert motion.motion_model([3]).label == "harmonic3"
    assert motion.motion_model([2, 3]).label == "harmonic2+harmonic3"
    four = motion.motion_model("fourier4")
    assert four.harmonics == (2, 3, 4) and four.gradient_point_fit
    assert motion.from_harmonics((2, 3, 4)) == four
    assert effects.model_label((2, 3, 4, 5, 6), ("hysteresis",)) == "fourier6+hysteresis"
    for bad in ("fourier", "harmonic3", [3, 2], [1]):
        with pytest.raises(ValueError):
            motion.motion_model(bad)


@pytest.mark.parametrize("orders", [(2, 3), (2, 3, 4, 5, 6)])
def test_proposition_1_holds_for_any_periodic_shape_with_turning_point_definitions(orders):
    # The counts of one cycle run from floor((min + a)/step) to floor((max + a)/step): with
    # A12 = max - min and a_eq = a + (max + min)/2 the step count and its symmetry are
    # Proposition 1's for any shape (brute force on a dense phase grid, in steps).
    rng = np.random.default_rng(7)
    for _ in range(40):
        coef, theta = _shape(rng, orders, 0.15)
        orders_ = tuple(coef)
        # The shape's stroke and midpoint from the package (fundamental by projection on
        # the grid, harmonics as drawn).
        half = 2.0 * np.mean(theta * np.sin(PHI))
        stroke, mid = model.stroke_and_midpoint(
            np.array([2.0 * half]), orders_, [[coef[k][0] for k in orders_]],
            [[coef[k][1] for k in orders_]])
        assert stroke[0] == pytest.approx(np.ptp(theta), abs=1e-6)
        a = rng.uniform(0.0, 1.0)
        counts = np.floor(theta + a)  # step 1: theta in steps
        a_eq = a + mid[0]
        e_b = a_eq - 0.5
        n = int(model.band_n(stroke[0], 1.0))
        half_eps = 0.5 * float(model.epsilon(stroke[0], 1.0))
        symmetric = counts.min() == -n and counts.max() == n
        if abs(abs(e_b) - half_eps) > 1e-4:  # away from the band's edge (grid resolution)
            assert symmetric == (abs(e_b) < half_eps)
        assert counts.max() - counts.min() == model.expected_step_count(stroke[0], a_eq, 1.0)


def test_proposition_2_needs_a_half_wave_symmetric_shape():
    # Odd orders only (theta(phi + pi) = -theta(phi)): the mean reading over a cycle is odd in
    # E_b, as for the sine (Proposition 2). An even order breaks it: the restoring signal
    # vanishes away from E_b = 0.
    base = 1.7 * np.sin(PHI)

    def mean_reading(theta, e_b):
        return float(np.floor(theta + 0.5 + e_b).mean())

    odd = base + 0.12 * np.cos(3 * PHI) - 0.05 * np.sin(5 * PHI)
    even = base + 0.12 * np.cos(2 * PHI)
    # Quadrature error of the dense grid: at most (steps pp) / len(PHI) = 2e-4.
    for e_b in (0.05, 0.1, 0.2):
        assert mean_reading(odd, e_b) == pytest.approx(-mean_reading(odd, -e_b), abs=5e-4)
    assert abs(mean_reading(odd, 0.0)) < 5e-4
    assert abs(mean_reading(even, 0.0)) > 0.01


def test_turning_point_midpoint_of_a_second_harmonic_is_analytic():
    # theta = A/2 sin(phi) + c cos(2 phi), |c| < A/8: theta' = cos(phi) (A/2 - 4 c sin(phi))
    # vanishes only at phi = +-pi/2, so max = A/2 - c and min = -A/2 - c: stroke A and
    # midpoint -c exactly.
    A, c = 3.4 * STEP, 0.2 * STEP
    samples = np.array([[A, 0.0, 20.0, 0.0, 0.01 * STEP, c, 0.0]])
    names = fit.param_names((2,))
    stroke, midpoint = fit._stroke_samples(samples, names, (2,))
    assert stroke[0] == pytest.approx(A, rel=1e-9)
    assert midpoint[0] == pytest.approx(-c, rel=1e-9)


def test_fourier_point_fit_reaches_the_optimum_of_a_distorted_motion():
    # A 40-cycle log of a motion with 2nd to 4th harmonics read by the offset encoder. The
    # Fourier series' point fit (least-squares start, L-BFGS-B) must reach a log-likelihood at
    # least that of the true motion (the maximum is at least there; 0.5 nat allows for the
    # optimizer's stopping tolerance), and its stroke must read the log's step count (eq. 6
    # band). The stroke itself is not pinned by the point fit: between the crossings of the
    # outer levels a free shape has room (the posterior's interval carries that).
    rng = np.random.default_rng(3)
    t = np.arange(int(40 * 2000 / 20)) / 2000.0
    harmonics = {2: (0.15 * STEP, -0.1 * STEP), 3: (-0.2 * STEP, 0.05 * STEP),
                 4: (0.1 * STEP, 0.1 * STEP)}
    A12f, a_eq, phase = 3.5 * STEP, 0.55 * STEP, 0.3
    counts = effects.simulate_counts(rng, t, STEP, A12f, a_eq, 20.0, phase,
                                     noise_std=0.01 * STEP, harmonics=harmonics)
    m = fit.map_fit(t, counts, STEP, harmonics=motion.motion_model("fourier4").harmonics)
    x = m["x"]
    truth = np.array([A12f / STEP, a_eq / STEP - (m["centre"] + 0.5), 20.0,
                      np.angle(np.exp(1j * (phase + 2 * np.pi * 20.0 * m["t_ref"]))),
                      np.log10(0.01)] + [v / STEP for k in (2, 3, 4) for v in harmonics[k]])
    truth_ll = fit.log_likelihood(truth[None], t, counts, STEP, m["centre"], m["t_ref"], None,
                                  (2, 3, 4))[0]
    assert m["log_lik"] >= truth_ll - 0.5
    stroke, _ = model.stroke_and_midpoint(np.array([x[0]]), (2, 3, 4), [x[5::2][:3]],
                                          [x[6::2][:3]])
    k = int(np.ptp(counts))
    assert k - 1 < stroke[0] < k + 1


def test_closed_loop_missed_count_moves_the_motion_not_the_readings():
    # The controller acts on the reading: a lost count (delta = -1) makes it drive the shaft
    # one step further up, and the readings' pattern stays where it was.
    rng = np.random.default_rng(5)
    n_cycles, per = 80, 100
    index = 50 * per
    df, p = simulate.closed_loop_pid_log(rng, n_cycles=n_cycles, offset_frac=0.4,
                                         missed_count=(index, -1))
    theta, counts = df["theta"].to_numpy(), df["counts"].to_numpy()
    before, after = slice(30 * per, index), slice(index + 20 * per, None)
    # Means over whole cycles of a settled loop: the shift is one step to within the cycle
    # to cycle wander of the bias (a few hundredths of a step).
    assert theta[after].mean() - theta[before].mean() == pytest.approx(STEP, abs=0.1 * STEP)
    assert counts[after].mean() == pytest.approx(counts[before].mean(), abs=0.1)


def test_bias_figure_draws_the_fitted_motion_beside_the_truth():
    from enclab.lrde import dwell, plots

    df, p = simulate.closed_loop_pid_log(np.random.default_rng(2), n_cycles=12, offset_frac=0.3,
                                         truth_step=STEP / 100)
    t, counts = df["t"].to_numpy(), df["counts"].to_numpy()
    cycles = dwell.cycle_table(counts, t, STEP, f_hz=20.0)
    truth = plots.truth_bias_deviation(t, df["truth_counts"].to_numpy() * STEP / 100, 20.0,
                                       STEP, p["offset_a"], 0)
    e_b = {"median": 0.01 * STEP, "q05": -0.02 * STEP, "q95": 0.04 * STEP}
    fig = plots.bias_cycles_plot(cycles, STEP, truth, fitted={"E_b": e_b, "label": "fourier6"})
    labels = [line.get_label() for line in fig.axes[0].get_lines()]
    assert any("fitted motion (fourier6" in x for x in labels)
    assert any("true angle" in x for x in labels)
    fitted = next(line for line in fig.axes[0].get_lines() if "fitted" in line.get_label())
    np.testing.assert_allclose(fitted.get_ydata(), np.rad2deg(e_b["median"]))


# ------------------------------------------------- drifting and distorted sinusoid (closed forms)
def test_drift_phase_instantaneous_frequency():
    t = np.linspace(0, 5, 50001)
    phi = motion.drift_phase(t, 2.0, 0.3, drift_hz_per_s=0.1, t_ref=1.0)
    f_inst = np.gradient(phi, t) / (2 * np.pi)
    np.testing.assert_allclose(f_inst[1:-1], 2.0 + 0.1 * (t[1:-1] - 1.0), atol=1e-9)
    assert phi[np.searchsorted(t, 1.0)] == pytest.approx(0.3)


def test_distorted_sinusoid_terms_recovered_exactly_by_least_squares():
    t = np.linspace(0, 3, 3000)
    truth = dict(bias=0.01, amplitude=0.2, f0_hz=1.3, phase=0.4, drift_hz_per_s=0.02, a3=0.004, psi3=1.1, a2=0.002, psi2=-0.5)
    y = motion.distorted_sinusoid(t, **truth)
    phi = motion.drift_phase(t, 1.3, 0.4, 0.02)
    X = np.column_stack([np.ones_like(t), np.sin(phi), np.sin(2 * phi), np.cos(2 * phi), np.sin(3 * phi), np.cos(3 * phi)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    assert coef[0] == pytest.approx(0.01, abs=1e-12)
    assert coef[1] == pytest.approx(0.2, abs=1e-12)
    assert math.hypot(coef[2], coef[3]) == pytest.approx(0.002, abs=1e-12)
    assert math.hypot(coef[4], coef[5]) == pytest.approx(0.004, abs=1e-12)
    assert math.atan2(coef[5], coef[4]) == pytest.approx(1.1, abs=1e-9)
    # with no distortion and no drift it is the plain sinusoid
    np.testing.assert_allclose(motion.distorted_sinusoid(t, 0.0, 1.0, 1.3, 0.4), np.sin(2 * np.pi * 1.3 * t + 0.4), atol=1e-12)
