"""Residual diagnostics against analytic answers (seeded; tolerances from the sample size).

The reference experiment: a true angle uniform over many steps (independent samples), a truth
channel rounding it to a fine grid whose step is incommensurate with the measured step, and a
measured channel rounding it to the coarse grid. Then the error measured - truth is uniform
+-step/2 convolved with uniform +-truth_step/2, and the residual measured - q(truth) is +-step
with probability truth_step / (4 step) (enclab.residuals.diagnostics.residual_floor).
"""
import math

import numpy as np
import pytest
from enclab.core.quantize import quantize, requantize_counts
from enclab.residuals import diagnostics as dg
from scipy import integrate

STEP = 0.767e-3
TRUTH_STEP = STEP / 17.93  # MRDLab-like: motor encoder / gear ratio against the output encoder
N = 200_000


def _reference(rng, offset_frac=0.5, n=N, effect=None):
    theta = rng.uniform(-400 * STEP, 400 * STEP, n)
    truth = TRUTH_STEP * quantize(theta, TRUTH_STEP).astype(float)
    seen = theta if effect is None else theta + effect(theta)
    measured = STEP * quantize(seen, STEP, offset_frac).astype(float)
    return theta, truth, measured


def test_residual_floor_probability_matches_binomial():
    rng = np.random.default_rng(11)
    _, truth, measured = _reference(rng)
    r = measured - dg.exact_prediction(truth, STEP, 0.0)
    floor = dg.residual_floor(STEP, TRUTH_STEP)
    p = floor["p_nonzero"]
    assert set(np.unique(np.round(r / STEP)).tolist()) <= {-1.0, 0.0, 1.0}
    sigma = math.sqrt(p * (1 - p) / N)
    assert np.mean(r != 0) == pytest.approx(p, abs=4 * sigma)
    assert floor["std"] == pytest.approx(STEP * math.sqrt(p))
    assert np.std(r) == pytest.approx(floor["std"], rel=4 * sigma / (2 * p))


def test_error_moments_histogram_and_mass_outside():
    rng = np.random.default_rng(12)
    _, truth, measured = _reference(rng)
    e = measured - truth
    # var(e) = (step^2 + truth_step^2)/12; the sample variance of a bounded uniform-like
    # variable has relative sd sqrt(0.8/N) (kurtosis 1.8 of the uniform).
    assert np.std(e) == pytest.approx(dg.error_floor_std(STEP, TRUTH_STEP), rel=4 * math.sqrt(0.8 / N) / 2)
    h = dg.histogram(e, STEP, TRUTH_STEP, n_bins=40, span_steps=1.5)
    p_out = dg.predicted_mass_outside(STEP, TRUTH_STEP)
    assert h["mass_outside_predicted"] == pytest.approx(TRUTH_STEP / (4 * STEP))
    assert h["mass_outside"] == pytest.approx(p_out, abs=4 * math.sqrt(p_out / N))
    width = np.diff(h["edges"])
    expected = h["predicted"] * width * N
    observed = h["density"] * width * N
    used = expected > 50
    chi2 = np.sum((observed[used] - expected[used]) ** 2 / expected[used])
    # chi-square with `used.sum()` degrees of freedom: mean k, sd sqrt(2k).
    k = used.sum()
    assert chi2 < k + 5 * math.sqrt(2 * k)


@pytest.mark.parametrize("truth_step", [None, TRUTH_STEP, 0.6 * STEP])
def test_predicted_pdf_integrates_to_one_with_the_right_variance(truth_step):
    ts = truth_step or 0.0
    hi = (STEP + ts) / 2
    points = sorted({-hi, -abs(STEP - ts) / 2, abs(STEP - ts) / 2, hi})
    mass = integrate.quad(lambda x: dg.predicted_error_pdf(x, STEP, truth_step), -hi, hi,
                          points=points)[0]
    var = integrate.quad(lambda x: x * x * dg.predicted_error_pdf(x, STEP, truth_step), -hi, hi,
                         points=points)[0]
    assert mass == pytest.approx(1.0, abs=1e-9)
    # quad's default epsrel 1.49e-8 on the variance is 7.5e-9 on its square root
    assert math.sqrt(var) == pytest.approx(dg.error_floor_std(STEP, truth_step), rel=1e-7)


def test_nested_grid_floor_matches_requantized_counts():
    rng = np.random.default_rng(13)
    theta = rng.uniform(-300 * STEP, 300 * STEP, N)
    fine = STEP / 8
    counts = quantize(theta, fine)
    e = STEP * requantize_counts(counts, 8).astype(float) - fine * counts
    assert np.std(e) == pytest.approx(dg.error_floor_std(STEP, fine, nested=True), rel=2 * math.sqrt(0.8 / N) * 2)


@pytest.mark.parametrize("offset_frac, zero", [(0.5, 0), (0.0, 7), (0.3137, -3)])
def test_fit_offset_recovers_zero_and_rounding_convention(offset_frac, zero):
    rng = np.random.default_rng(14)
    _, truth, measured = _reference(rng, offset_frac=offset_frac, n=50_000)
    measured = measured + zero * STEP
    # q(theta) with offset_frac f reads like rounding of theta + (f - 0.5) step.
    true_c = (offset_frac - 0.5) * STEP + zero * STEP
    c = dg.fit_offset(truth, measured, STEP)
    # Agreement is lost at rate |c - true_c| / step: the plateau of full agreement is
    # truth_step wide at most, so c is within truth_step of the true offset.
    assert c == pytest.approx(true_c, abs=TRUTH_STEP)
    assert dg.fit_offset(truth, measured) == pytest.approx(true_c, abs=5 * STEP / math.sqrt(12 * 50_000))


def _ramp(n=100_000, fs=1000.0, period_s=20.0, amp=600 * STEP, seed=21):
    """Triangle wave (constant speed both ways) with a small jitter so phases spread."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    phase = np.mod(t / period_s, 1.0)
    theta = amp * (4 * np.abs(phase - 0.5) - 1) + rng.normal(0, 0.05 * STEP, n)
    return t, theta


def test_velocity_sign_and_velocity_bins_see_hysteresis():
    t, theta = _ramp()
    h = 0.3 * STEP
    v_true = np.gradient(theta, t)
    truth = TRUTH_STEP * quantize(theta, TRUTH_STEP).astype(float)
    measured = STEP * quantize(theta + h * np.sign(v_true), STEP).astype(float)
    d = dg.diagnose(t, truth, measured, STEP, TRUTH_STEP, offset=0.0)
    vs = d["conditioned"]["velocity_sign"]
    # The jitter flips the sample-to-sample sign locally; the central difference of the
    # triangle wave follows the ramp's sign except within a few samples of the jitter.
    assert vs["difference"] == pytest.approx(2 * h, rel=0.1)
    assert np.sign(v_true).mean() == pytest.approx(0.0, abs=0.05)
    vb = d["conditioned"]["velocity"]
    ok = vb["n"] > 0
    assert np.all(np.abs(vb["mean"][ok]) == pytest.approx(h, rel=0.25))


def test_angle_mod_2pi_recovers_eccentricity():
    rng = np.random.default_rng(22)
    n = 400_000
    t = np.arange(n) / 1000.0
    theta = rng.uniform(0, 4 * np.pi, n)  # two revolutions' worth of phases
    eps = 2.0 * STEP
    truth = TRUTH_STEP * quantize(theta, TRUTH_STEP).astype(float)
    measured = STEP * quantize(theta + eps * np.sin(theta), STEP).astype(float)
    cond = dg.conditioned(np.sort(t), truth, np.rint(measured / STEP).astype(int),
                          measured - dg.exact_prediction(truth, STEP), n_bins=24, line_pitch=4 * STEP)
    b = cond["angle_mod_2pi"]
    w = 2 * np.pi / 24
    # The bin mean of eps*sin over a bin of width w is eps*sin(centre)*sinc(w/2).
    expected = eps * np.sin(b["centres"]) * np.sin(w / 2) / (w / 2)
    assert np.max(np.abs(b["mean"] - expected)) < 5 * np.max(b["sem"])


def test_count_mod_4_pattern():
    rng = np.random.default_rng(23)
    theta = rng.uniform(-400 * STEP, 400 * STEP, N)
    truth = theta  # a continuous truth: the exact model is then exact, floor 0
    counts = quantize(theta, STEP)
    shift = np.array([0, 1, 0, -1])[np.mod(counts, 4)]
    measured = STEP * (counts + shift).astype(float)
    r = measured - dg.exact_prediction(truth, STEP)
    b = dg.binned(np.mod(np.rint(measured / STEP), 4).astype(float), r, np.arange(5) - 0.5)
    assert dg.residual_floor(STEP, None)["std"] == 0.0
    # Reported count c+shift: counts 1 -> 2 (r=+1), 3 -> 2 (r=-1), 0 -> 0, 2 -> 2.
    assert b["n"][1] == 0 and b["n"][3] == 0
    assert b["mean"][0] == pytest.approx(0.0, abs=1e-15)
    assert b["mean"][2] == pytest.approx(0.0, abs=0.01 * STEP)


def test_binned_matches_a_loop_and_spectrum_parseval():
    rng = np.random.default_rng(24)
    x = rng.uniform(0, 1, 5000)
    r = rng.normal(0, 1, 5000)
    edges = np.linspace(0, 1, 8)
    b = dg.binned(x, r, edges)
    for i in range(7):
        sel = (x >= edges[i]) & ((x < edges[i + 1]) | ((i == 6) & (x == 1.0)))
        assert b["n"][i] == sel.sum()
        assert b["mean"][i] == pytest.approx(r[sel].mean())
        assert b["std"][i] == pytest.approx(r[sel].std())
    fs = 1000.0
    t = np.arange(2**16) / fs
    white = rng.normal(0, 1e-4, t.size)
    sp = dg.spectrum(t, white)
    # One-sided PSD of white noise: 2 sigma^2 / fs; Welch's average over 63 segments of 2048
    # has relative sd ~ 1/sqrt(63 * 2048 / 2) per bin averaged over ~1000 bins.
    assert np.mean(sp["psd"][1:-1]) == pytest.approx(2 * 1e-8 / fs, rel=0.02)
    tone = 1e-4 * np.sin(2 * np.pi * 37.0 * t)
    assert dg.spectrum(t, tone)["f_hz"][np.argmax(dg.spectrum(t, tone)["psd"])] == pytest.approx(37.0, abs=0.5)


def test_diagnose_on_a_clean_log_sits_on_the_floor():
    t, theta = _ramp(seed=25)
    truth = TRUTH_STEP * quantize(theta, TRUTH_STEP).astype(float)
    measured = STEP * quantize(theta, STEP, 0.0).astype(float) + 11 * STEP
    d = dg.diagnose(t, truth, measured, STEP, TRUTH_STEP)
    assert d["offset"] == pytest.approx(-0.5 * STEP + 11 * STEP, abs=TRUTH_STEP)
    # 100 000 samples crossing ~1200 transitions 10 times each: P(r != 0) within 20 %.
    assert d["residual_moments"]["std"] == pytest.approx(d["floor"]["residual_std"], rel=0.2)
    s = dg.scalar_summary(d)
    assert abs(s["velocity_sign"]["difference"]) < 0.02 * STEP
    assert s["mass_outside"] == pytest.approx(s["mass_outside_predicted"], rel=0.3)


def test_bad_inputs_raise_naming_the_argument():
    with pytest.raises(ValueError, match="measured has 3 samples"):
        dg.diagnose([0, 1, 2, 3], [0, 1, 2, 3], [0, 1, 2], STEP)
    with pytest.raises(ValueError, match="step must be a finite positive"):
        dg.exact_prediction([0.0], 0.0)
    with pytest.raises(ValueError, match="truth must be finite; first non-finite value at index 1"):
        dg.fit_offset([0.0, np.nan], [0.0, 0.0])
    with pytest.raises(ValueError, match="coarser than step"):
        dg.residual_floor(STEP, 2 * STEP)
