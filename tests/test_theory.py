"""Tests for enclab.propagation.theory: Table II (worst case, PQN), the exact model, trajectory bounds.

Every prediction is checked against an independent method: brute force over the residues of
the quantizer, numerical integration, white-noise Monte Carlo, seeded simulations of quantized
trajectories (pooled over independent runs, intervals from :func:`enclab.propagation.moments.pooled_std_ratio`)
and closed forms derived in the comments (constant-velocity ramp).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from enclab.core.quantize import quantize, requantize_counts
from enclab.propagation.filters import (
    DerivativeFilter,
    apply,
    h2_norm_sq,
    impulse_response,
    l1_norm,
    settle_samples,
)
from enclab.propagation.kinematics import PhantomPremium15
from enclab.propagation.moments import pooled_std_ratio
from enclab.propagation.theory import (
    QuantizerErrorModel,
    exact_joint_autocovariance,
    exact_mean_joint,
    exact_operational_autocovariance,
    exact_std_joint,
    exact_std_joint_architecture,
    exact_std_operational,
    impulse_autocorrelation,
    pqn_derivative_cov_operational,
    pqn_derivative_std_joint,
    pqn_position_cov,
    pqn_position_std,
    sinusoid_autocovariance,
    sinusoid_run_autocovariance,
    worst_case_derivative,
    worst_case_derivative_joint,
    worst_case_position,
    worst_case_trajectory_derivative,
    worst_case_trajectory_derivative_joint,
    worst_case_trajectory_position,
)

FS = 1000.0
STEP = 1e-3  # the paper's artificial quantization, 1 mrad
TRUTH_STEP = 1.25e-4  # the Phantom's own encoders, 0.125 mrad (ratio 8)
AMP = math.radians(3.0)
N_SAMPLES = 15_000  # 15 s at 1 kHz (Section IV)
VELOCITY_FILTER = DerivativeFilter(1, 1, 50.0, "exponential")  # d=1, n=1, 50 Hz (Section IV)


def phase_grid(n_points):
    """Midpoints of n_points equal cells of [0, 1): the phase theta/step within one step."""
    return (np.arange(n_points) + 0.5) / n_points


def error_of(theta, step, offset_frac=0.5):
    """Quantization error measured - true, from the counts quantizer."""
    return quantize(theta, step, offset_frac) * step - theta


# ------------------------------------------------------------------ QuantizerErrorModel
@pytest.mark.parametrize("offset_frac", [0.0, 0.25, 0.5, 0.9])
def test_continuous_truth_moments_match_phase_average(offset_frac):
    # Phase average by the midpoint rule over one step: the error is linear in the phase
    # except for one jump, so mean and variance are exact up to the jump's cell, an error
    # <= step^2 / n_points in the second moment.
    n_points = 200_000
    err = error_of(phase_grid(n_points) * STEP, STEP, offset_frac)
    model = QuantizerErrorModel(STEP, offset_frac)
    tol = 2 * STEP**2 / n_points
    assert abs(err.mean() - model.mean) < tol / STEP
    assert abs(err.var() - model.variance) < tol
    assert model.variance == pytest.approx(STEP**2 / 12, rel=1e-15)
    lo, hi = model.bounds
    assert lo < err.min() and err.max() <= hi
    assert hi - lo == pytest.approx(STEP, rel=1e-15)
    assert model.max_abs == pytest.approx(max(offset_frac, 1 - offset_frac) * STEP, rel=1e-15)


@pytest.mark.parametrize("ratio, offset_frac", [(8, 0.5), (8, 0.0), (5, 0.5), (16, 0.3), (1, 0.5)])
def test_quantized_truth_moments_match_residues(ratio, offset_frac):
    # Brute force: every residue of the fine count mod ratio, re-quantized with the integer
    # formula of enclab.core.quantize; the error is (coarse reading - fine reading).
    truth_step = STEP / ratio
    fine = np.arange(-5 * ratio, 5 * ratio)
    err = (ratio * requantize_counts(fine, ratio, offset_frac) - fine) * truth_step
    model = QuantizerErrorModel(STEP, offset_frac, truth_step=truth_step)
    assert model.ratio == ratio
    np.testing.assert_allclose(np.sort(model.levels()), np.unique(err), rtol=1e-12, atol=1e-20)
    assert model.mean == pytest.approx(err.mean(), abs=1e-15 * STEP)
    assert model.variance == pytest.approx(err.var(), rel=1e-12, abs=1e-30)
    assert model.variance == pytest.approx((STEP**2 - truth_step**2) / 12, rel=1e-12, abs=1e-30)
    assert model.bounds == pytest.approx((err.min(), err.max()), rel=1e-12)


def test_rounding_on_both_grids_has_half_fine_step_tie_bias():
    model = QuantizerErrorModel(STEP, 0.5, truth_step=TRUTH_STEP)
    np.testing.assert_allclose(np.sort(model.levels()) / TRUTH_STEP, np.arange(-3, 5), atol=1e-12)
    assert model.mean == pytest.approx(TRUTH_STEP / 2, rel=1e-12)
    assert model.max_abs == pytest.approx(STEP / 2, rel=1e-12)
    # The continuous-truth model is unbiased.
    assert QuantizerErrorModel(STEP).mean == 0.0


def test_model_rejects_bad_arguments():
    with pytest.raises(ValueError, match="step must be"):
        QuantizerErrorModel(0.0)
    with pytest.raises(ValueError, match="offset_frac must be"):
        QuantizerErrorModel(STEP, 1.0)
    with pytest.raises(ValueError, match="must be a positive integer"):
        QuantizerErrorModel(STEP, truth_step=3e-4)
    with pytest.raises(ValueError, match="needs a quantized truth"):
        QuantizerErrorModel(STEP).levels()
    with pytest.raises(ValueError, match="whole multiples of truth_step"):
        QuantizerErrorModel(STEP, truth_step=TRUTH_STEP).autocovariance(0.5 * TRUTH_STEP)


@pytest.mark.parametrize("offset_frac", [0.5, 0.2])
def test_continuous_autocovariance_matches_numerical_integration(offset_frac):
    # C(delta) = (1/step) int_0^step g(u) g(u + delta) du - mean^2 by the midpoint rule; the
    # integrand is piecewise smooth with two jumps per period, each of height <= step^2
    # (|g| <= step), so the rule errs by <= 2 step^2 / n_points (plus O(n^-2) smooth part).
    n_points = 100_000
    u = phase_grid(n_points) * STEP
    g = error_of(u, STEP, offset_frac)
    model = QuantizerErrorModel(STEP, offset_frac)
    deltas = np.array([0.0, 0.1, 0.37, 0.5, 0.9, 1.0, 1.618, -0.37, 7.25]) * STEP
    numeric = np.array([np.mean(g * error_of(u + d, STEP, offset_frac)) for d in deltas]) - g.mean() ** 2
    np.testing.assert_allclose(model.autocovariance(deltas), numeric, rtol=0, atol=3 * STEP**2 / n_points)
    # Closed-form landmarks: variance at 0, minimum -step^2/24 at half a step, even in delta.
    assert model.autocovariance(0.0) == pytest.approx(STEP**2 / 12, rel=1e-12)
    assert model.autocovariance(0.5 * STEP) == pytest.approx(-(STEP**2) / 24, rel=1e-12)
    assert model.autocovariance(-0.3 * STEP) == pytest.approx(float(model.autocovariance(0.3 * STEP)), rel=1e-12)


@pytest.mark.parametrize("offset_frac", [0.5, 0.0])
def test_quantized_truth_autocovariance_matches_residues(offset_frac):
    # Circular autocovariance over the 8 residues: exact.
    r = 8
    fine = np.arange(r)
    err = (r * requantize_counts(fine, r, offset_frac) - fine) * TRUTH_STEP
    model = QuantizerErrorModel(STEP, offset_frac, truth_step=TRUTH_STEP)
    for j in range(-3, 2 * r):
        brute = np.mean(err * np.roll(err, -j)) - err.mean() ** 2
        assert float(model.autocovariance(j * TRUTH_STEP)) == pytest.approx(brute, abs=1e-12 * STEP**2)


# --------------------------------------------------------------------------- Table II, PQN
def phantom_jacobian():
    # A configuration off the zero pose so that every entry of J matters.
    return PhantomPremium15().jacobian(np.array([0.3, 0.4, -0.2]))


def test_pqn_position_matches_white_noise_monte_carlo():
    rng = np.random.default_rng(40)
    n = 200_000
    steps = np.array([1e-3, 2e-3, 0.5e-3])
    J = phantom_jacobian()
    e = rng.uniform(-0.5, 0.5, (n, 3)) * steps
    x = e @ J.T
    # A sum of independent uniforms has kurtosis <= 3, so Var(s^2)/sigma^4 <= 2/n and
    # sd(s)/sigma <= sqrt(2/n)/2 = 1.6e-3; 5 sigma.
    np.testing.assert_allclose(x.std(axis=0, ddof=1), pqn_position_std(J, steps), rtol=5 * math.sqrt(2 / n) / 2)
    cov = pqn_position_cov(J, steps)
    np.testing.assert_allclose(cov, J @ np.diag(steps**2 / 12) @ J.T, rtol=1e-12)
    # Off-diagonal entries: sd <= sqrt(2/n) * max variance.
    np.testing.assert_allclose(np.cov(x.T), cov, rtol=0, atol=5 * math.sqrt(2 / n) * cov.diagonal().max())


def filtered_white_std_tolerance(h, n, z=5.0):
    """z-sigma relative tolerance on the sample std of n samples of white noise through h.

    For a (near-)Gaussian stationary output with autocorrelation rho,
    Var(s^2)/sigma^4 = (2/n) sum_m rho(m)^2 (two-sided), and sd(s)/sigma is half of its root.
    The uniform input has negative excess kurtosis, which only lowers the variance.
    """
    r_h = impulse_autocorrelation(h)
    rho = r_h / r_h[0]
    sum_rho_sq = 1 + 2 * np.sum(rho[1:] ** 2)
    return z * math.sqrt(2 * sum_rho_sq / n) / 2


@pytest.mark.parametrize("disc", ["exponential", "bilinear"])
def test_pqn_derivative_matches_white_noise_through_filter(disc):
    rng = np.random.default_rng(41)
    filt = DerivativeFilter(1, 1, 50.0, disc)
    h = impulse_response(filt, FS)
    n = 200_000
    e = rng.uniform(-STEP / 2, STEP / 2, n + h.size)
    y = apply(filt, e, FS)[h.size :]
    predicted = pqn_derivative_std_joint(h, STEP)[0]
    assert predicted == pytest.approx(math.sqrt(h2_norm_sq(filt, FS)) * STEP / math.sqrt(12), rel=1e-12)
    assert abs(y.std(ddof=1) / predicted - 1) < filtered_white_std_tolerance(h, n)


def test_pqn_operational_architectures_agree_with_shared_filter_and_monte_carlo():
    rng = np.random.default_rng(42)
    h = impulse_response(VELOCITY_FILTER, FS)
    J = phantom_jacobian()
    steps = np.array([1e-3, 1e-3, 2e-3])
    op = pqn_derivative_cov_operational(h, J, steps, "operational")
    joint = pqn_derivative_cov_operational(h, J, steps, "joint")
    np.testing.assert_allclose(op, joint, rtol=1e-12)
    np.testing.assert_allclose(op, np.sum(h**2) * pqn_position_cov(J, steps), rtol=1e-12)
    n = 100_000
    e = rng.uniform(-0.5, 0.5, (n + h.size, 3)) * steps
    y = apply(VELOCITY_FILTER, e @ J.T, FS)[h.size :]
    np.testing.assert_allclose(y.std(axis=0, ddof=1), np.sqrt(op.diagonal()), rtol=filtered_white_std_tolerance(h, n))
    with pytest.raises(ValueError, match="architecture must be"):
        pqn_derivative_cov_operational(h, J, steps, "cartesian")


def test_worst_case_position_is_attained_and_never_exceeded():
    rng = np.random.default_rng(43)
    J = phantom_jacobian()
    bound = worst_case_position(J, STEP / 2)
    np.testing.assert_allclose(bound, np.abs(J).sum(axis=1) * STEP / 2, rtol=1e-15)
    # Attained at the corner e = sign(J_j) step/2 of the error box.
    for j in range(3):
        assert abs(J[j] @ (np.sign(J[j]) * STEP / 2)) == pytest.approx(bound[j], rel=1e-12)
    e = rng.uniform(-STEP / 2, STEP / 2, (100_000, 3))
    assert np.all(np.abs(e @ J.T) <= bound)


@pytest.mark.parametrize("filt", [VELOCITY_FILTER, DerivativeFilter(2, 2, 20.0, "bilinear")])
def test_worst_case_derivative_is_the_l1_gain(filt):
    rng = np.random.default_rng(44)
    # The default response is truncated where the tail *energy* is < 1e-14, which leaves
    # a tail l1 of ~1e-9 relative; 4x longer makes it < 1e-30 for these poles (|p| <= 0.88).
    h = impulse_response(filt, FS, n_samples=4 * impulse_response(filt, FS).size)
    bound = worst_case_derivative(h, STEP / 2)
    assert bound == pytest.approx(l1_norm(filt, FS) * STEP / 2, rel=1e-12)
    # Attained by the input that matches the sign of the time-reversed response.
    assert np.convolve(np.sign(h[::-1]) * STEP / 2, h, mode="valid")[0] == pytest.approx(bound, rel=1e-12)
    y = apply(filt, rng.uniform(-STEP / 2, STEP / 2, 50_000), FS)
    assert np.all(np.abs(y) <= bound)
    # Filter in joint space (eq. 27): |J| times the per-joint peak of phi~.
    J = phantom_jacobian()
    np.testing.assert_allclose(worst_case_derivative_joint(h, J, STEP / 2), np.abs(J).sum(axis=1) * bound, rtol=1e-12)


# ------------------------------------------------------------------- exact model, ramps
def ramp_discrepancy_bound(n, max_partial_quotient):
    """Bound on the discrepancy D_N of {x0 + k alpha} when alpha's continued fraction has
    partial quotients <= K (Kuipers & Niederreiter, Uniform Distribution of Sequences,
    Ch. 2, Thm 3.4): N D_N <= 3 + (1/log(golden) + K/log(K + 1)) log N."""
    golden = (1 + math.sqrt(5)) / 2
    k = max_partial_quotient
    return (3 + (1 / math.log(golden) + k / math.log(k + 1)) * math.log(n)) / n


@pytest.mark.parametrize(
    "steps_per_sample, max_partial_quotient",
    [
        ((math.sqrt(5) - 1) / 2, 1),  # f = 0.618 = [0; 1, 1, 1, ...]
        ((3 - math.sqrt(5)) / 2, 2),  # f = 0.382 = [0; 2, 1, 1, ...]
        (2 + (math.sqrt(5) - 1) / 2, 1),  # more than one step per sample, same f = 0.618
        (math.sqrt(2) - 1, 2),  # f = 0.414 = [0; 2, 2, 2, ...]
    ],
)
def test_ramp_back_difference_variance(steps_per_sample, max_partial_quotient):
    # Ramp theta(k) = theta0 + k delta, delta = v T. For the continuous sawtooth
    # e(theta) = a - step frac((theta + a)/step) the slopes cancel in a difference:
    # e(k) - e(k-1) = -step (f - [a jump between k-1 and k]), f = frac(delta/step), i.e.
    # -step f on a fraction 1 - f of phases and +step (1 - f) on a fraction f. Mean 0,
    # variance step^2 [f^2 (1 - f) + (1 - f)^2 f] = step^2 f (1 - f). Equivalently
    # 2 (C(0) - C(delta)) = 2 step^2 (1/12 - (1/12 - f(1 - f)/2)). So
    # Var[(e(k) - e(k-1))/T] = (step/T)^2 f (1 - f), whereas PQN says (step/T)^2 / 6.
    T = 1 / FS
    delta = steps_per_sample * STEP
    f = steps_per_sample % 1.0
    n = 100_000
    theta = 0.123 * STEP + delta * np.arange(n + 1)
    model = QuantizerErrorModel(STEP)
    back_difference = np.array([1.0, -1.0]) / T
    closed_form = (STEP / T) * math.sqrt(f * (1 - f))
    assert exact_std_joint(theta, model, back_difference) == pytest.approx(closed_form, rel=1e-12)
    assert pqn_derivative_std_joint(back_difference, STEP)[0] == pytest.approx(STEP / T / math.sqrt(6), rel=1e-12)
    # Simulation: the phases theta(k)/step mod 1 form a Kronecker sequence; the squared
    # difference is step^2 (f^2 + (1 - 2f) [jump]), so its sample mean is
    # step^2 (f^2 + (1 - 2f) nu) with nu the visit fraction of an arc of length f, and
    # |nu - f| <= D_N. (The float alpha is rational, but its continued fraction only departs
    # from the irrational one at denominators ~1e16 >> N, which the bound does not reach.)
    # Observed: 1 % of the bound.
    err = error_of(theta, STEP)
    diff = np.diff(err) / T
    simulated_var = np.mean(diff**2)
    tol = (STEP / T) ** 2 * abs(1 - 2 * f) * ramp_discrepancy_bound(n, max_partial_quotient)
    assert abs(simulated_var - closed_form**2) < tol
    assert tol < 1e-2 * closed_form**2


@pytest.mark.parametrize("fine_steps_per_sample", [1, 3, 5, 7, 13])
def test_ramp_on_quantized_truth_is_exact(fine_steps_per_sample):
    # Fine counts advance j per sample, j coprime to r: the residue mod r visits all r
    # values once per period of r samples, so the sample statistics over whole periods
    # equal the phase average exactly:
    # Var[(e(k) - e(k-1))/T] = 2 (C(0) - C(j truth_step)) / T^2 = (truth_step/T)^2 j' (r - j'),
    # j' = j mod r.
    T, r, j = 1 / FS, 8, fine_steps_per_sample
    fine = 37 + j * np.arange(8 * r + 1)
    err = (r * requantize_counts(fine, r) - fine) * TRUTH_STEP
    model = QuantizerErrorModel(STEP, truth_step=TRUTH_STEP)
    back_difference = np.array([1.0, -1.0]) / T
    jr = j % r
    closed_form = (TRUTH_STEP / T) * math.sqrt(jr * (r - jr))
    predicted = exact_std_joint(fine * TRUTH_STEP, model, back_difference)
    assert predicted == pytest.approx(closed_form, rel=1e-12, abs=1e-12)
    assert np.std(np.diff(err) / T) == pytest.approx(closed_form, rel=1e-12, abs=1e-12)
    assert np.mean(err[1:]) == pytest.approx(exact_mean_joint(model), rel=1e-12)
    assert exact_mean_joint(model, back_difference) == 0.0


def test_joint_autocovariance_is_trajectory_average():
    theta = np.array([0.0, 0.3, 0.9, 1.0, 2.5]) * STEP
    model = QuantizerErrorModel(STEP)
    c = exact_joint_autocovariance(theta, model, 2)
    expected_lag1 = np.mean(model.autocovariance(np.diff(theta)))
    expected_lag2 = np.mean(model.autocovariance(theta[2:] - theta[:-2]))
    np.testing.assert_allclose(c, [STEP**2 / 12, expected_lag1, expected_lag2], rtol=1e-12)
    with pytest.raises(ValueError, match="longer than the filter memory"):
        exact_joint_autocovariance(theta, model, 5)
    with pytest.raises(ValueError, match="max_lag must be"):
        exact_joint_autocovariance(theta, model, -1)


# --------------------------------------------------------------- exact model, sinusoids
def sinusoid_runs(rng, runs, freqs_hz=(5.0,), centre=0.0, n_samples=N_SAMPLES):
    """Independent runs of Section IV's motion: centre + 3 deg sin(2 pi f t + phase) + b,
    with a random phase and a random sub-step shift b per run and joint. Shape
    (n_samples, runs, joints)."""
    freqs = np.asarray(freqs_hz)
    t = np.arange(n_samples)[:, None, None] / FS
    phase = rng.uniform(0, 2 * np.pi, (runs, freqs.size))
    shift = rng.uniform(0, STEP, (runs, freqs.size))
    return centre + shift + AMP * np.sin(2 * np.pi * freqs * t + phase)


@pytest.mark.parametrize("disc", ["exponential", "bilinear"])
def test_exact_model_predicts_quantized_sinusoid_where_pqn_does_not(disc):
    # One joint, 1 kHz, 3 deg at 5 Hz, step 1 mrad, d=1 n=1 fc=50 Hz: at most 1.6 steps per
    # sample, so the error is not white. 200 independent runs (random phase and sub-step
    # offset); the 99.9 % interval of the pooled std ratio is honest because runs are
    # independent. 15 s hold 75 whole periods, so every run has the same distribution of
    # increments and one exact prediction serves all runs.
    rng = np.random.default_rng(50)
    runs = 200
    theta = sinusoid_runs(rng, runs)[:, :, 0]
    err = error_of(theta, STEP)
    model = QuantizerErrorModel(STEP)
    filt = DerivativeFilter(1, 1, 50.0, disc)
    h = impulse_response(filt, FS)
    settle = settle_samples(filt, FS, tol=1e-12)
    y = apply(filt, err, FS)[settle:]
    exact = exact_std_joint(theta[:, 0], model, h)
    pqn = pqn_derivative_std_joint(h, STEP)[0]
    # Position: the phase-averaged model is exact, std = step/sqrt(12).
    ratio, lo, hi = pooled_std_ratio(err.std(axis=0, ddof=1), np.full(runs, N_SAMPLES), model.std, 0.999)
    assert lo <= 1 <= hi and hi - lo < 0.01
    # Derivative: the exact model is inside the interval, PQN is outside
    # (measured: PQN low by 1.5 % for exponential smoothing, high by 5.7 % for bilinear).
    ratio, lo, hi = pooled_std_ratio(y.std(axis=0, ddof=1), np.full(runs, y.shape[0]), exact, 0.999)
    assert lo <= 1 <= hi and hi - lo < 0.02
    assert not (lo <= pqn / exact <= hi)
    assert abs(exact / pqn - 1) > 0.01


def test_exact_model_with_quantized_truth_tie_bias():
    # Truth quantized at 0.125 mrad, measured channel re-quantized to 1 mrad (ratio 8): the
    # error against the fine reading has mean +truth_step/2 and variance
    # (step^2 - truth_step^2)/12, and its derivative std follows the discrete model.
    rng = np.random.default_rng(51)
    runs = 100
    theta = sinusoid_runs(rng, runs)[:, :, 0]
    fine = quantize(theta, TRUTH_STEP)
    err = (8 * requantize_counts(fine, 8) - fine) * TRUTH_STEP
    model = QuantizerErrorModel(STEP, truth_step=TRUTH_STEP)
    ratio, lo, hi = pooled_std_ratio(err.std(axis=0, ddof=1), np.full(runs, N_SAMPLES), model.std, 0.999)
    assert lo <= 1 <= hi
    # The run means: a t-test at 99.9 % on 100 independent runs.
    run_means = err.mean(axis=0)
    half = 3.39 * run_means.std(ddof=1) / math.sqrt(runs)  # t_{0.9995, 99} = 3.39
    assert abs(run_means.mean() - model.mean) < half
    assert abs(run_means.mean()) > half  # the tie bias is resolved, not zero
    h = impulse_response(VELOCITY_FILTER, FS)
    settle = settle_samples(VELOCITY_FILTER, FS, tol=1e-12)
    y = apply(VELOCITY_FILTER, err, FS)[settle:]
    exact = exact_std_joint(fine[:, 0] * TRUTH_STEP, model, h)
    ratio, lo, hi = pooled_std_ratio(y.std(axis=0, ddof=1), np.full(runs, y.shape[0]), exact, 0.999)
    assert lo <= 1 <= hi


# ------------------------------------------------------- Phantom: exact model and bounds
PHANTOM_FREQS = (4.93, 5.0, 5.07)  # within 0.1 Hz of 5 Hz, distinct (Section IV)
PHANTOM_CENTRE = np.array([0.0, 0.3, 0.3])


def test_exact_operational_std_on_phantom():
    # Filter in operational space (Fig. 2A) and in joint space (Fig. 2B), 16 runs of 5 s
    # (runtime); the prediction is computed per run (the joints' relative phases change the
    # Jacobian weighting) and its mean variance is the reference.
    rng = np.random.default_rng(60)
    device = PhantomPremium15()
    runs, n_samples = 16, 5000
    thetas = sinusoid_runs(rng, runs, PHANTOM_FREQS, PHANTOM_CENTRE, n_samples)
    model = QuantizerErrorModel(STEP)
    h = impulse_response(VELOCITY_FILTER, FS)
    settle = settle_samples(VELOCITY_FILTER, FS, tol=1e-12)
    op_std, joint_std, op_pred, joint_pred = [], [], [], []
    for r in range(runs):
        theta = thetas[:, r]
        measured = quantize(theta, STEP) * STEP
        J, H = device.jacobian(theta), device.hessian(theta)
        x_err = device.forward(measured) - device.forward(theta)
        op_std.append(apply(VELOCITY_FILTER, x_err, FS)[settle:].std(axis=0, ddof=1))
        op_pred.append(exact_std_operational(theta, J, model, h) ** 2)
        phi = apply(VELOCITY_FILTER, theta, FS)
        phi_hat = apply(VELOCITY_FILTER, measured, FS)
        y_joint = np.einsum("kji,ki->kj", device.jacobian(measured), phi_hat) - np.einsum("kji,ki->kj", J, phi)
        joint_std.append(y_joint[settle:].std(axis=0, ddof=1))
        joint_pred.append(exact_std_joint_architecture(theta, J, H, phi, model, h) ** 2)
    n = np.full(runs, n_samples - settle)
    for stds, pred in ((op_std, op_pred), (joint_std, joint_pred)):
        ratio, lo, hi = pooled_std_ratio(np.array(stds), n, np.sqrt(np.mean(pred, axis=0)), 0.999)
        assert np.all(lo <= 1) and np.all(1 <= hi) and np.all(hi - lo < 0.03)


@pytest.fixture(scope="module")
def phantom_run():
    rng = np.random.default_rng(61)
    device = PhantomPremium15()
    theta = sinusoid_runs(rng, 1, PHANTOM_FREQS, PHANTOM_CENTRE)[:, 0]
    measured = quantize(theta, STEP) * STEP
    return device, theta, measured


def test_trajectory_position_bound_holds_where_centre_bound_fails(phantom_run):
    device, theta, measured = phantom_run
    x_err = device.forward(measured) - device.forward(theta)
    J, H = device.jacobian(theta), device.hessian(theta)
    # Third derivatives of a revolute chain's position are bounded by l1 + l2 (theory docs).
    bound = worst_case_trajectory_position(J, H, STEP / 2, device.l1 + device.l2)
    assert np.all(np.abs(x_err) <= bound)
    # Tight: the simulation comes within 3 % of the bound on every coordinate (measured 1.2 %).
    assert np.all(np.max(np.abs(x_err) / bound, axis=0) > 0.97)
    # Table II's bound at the centre configuration is exceeded along the motion
    # (measured: by 5.7 %, 1.8 % and 5.6 % in x, y, z here).
    centre = worst_case_position(device.jacobian(PHANTOM_CENTRE), STEP / 2)
    assert np.any(np.abs(x_err).max(axis=0) > centre)
    # It equals the first-order term of the trajectory bound at the centre.
    J_centre = device.jacobian(PHANTOM_CENTRE)[None]
    first_order = worst_case_trajectory_position(J_centre, np.zeros((1, 3, 3, 3)), STEP / 2)[0]
    np.testing.assert_allclose(first_order, centre, rtol=1e-15)


def test_trajectory_derivative_bounds_hold(phantom_run):
    device, theta, measured = phantom_run
    # Long enough that the l1 norm of the neglected tail is < 1e-30 (see the l1 test): the
    # applied IIR filter's full response must be covered for the bound to be rigorous.
    h = impulse_response(VELOCITY_FILTER, FS, n_samples=4 * impulse_response(VELOCITY_FILTER, FS).size)
    J, H = device.jacobian(theta), device.hessian(theta)
    # Filter in operational space, from rest.
    x_err = device.forward(measured) - device.forward(theta)
    y_op = apply(VELOCITY_FILTER, x_err, FS)
    bound_x = worst_case_trajectory_position(J, H, STEP / 2, device.l1 + device.l2)
    bound_op = worst_case_trajectory_derivative(bound_x, h)
    assert np.all(np.abs(y_op) <= bound_op)
    assert np.all(bound_op.max(axis=0) <= worst_case_derivative(h, bound_x.max(axis=0)) * (1 + 1e-12))
    # Filter in joint space, from rest.
    phi = apply(VELOCITY_FILTER, theta, FS)
    phi_hat = apply(VELOCITY_FILTER, measured, FS)
    y_joint = np.einsum("kji,ki->kj", device.jacobian(measured), phi_hat) - np.einsum("kji,ki->kj", J, phi)
    bound_joint = worst_case_trajectory_derivative_joint(J, H, phi, h, STEP / 2, device.l1 + device.l2)
    assert np.all(np.abs(y_joint) <= bound_joint)


# ------------------------------------------- exact model, pooled to 0.3 % for every family
# Every (d, n, discretization) family at the paper's 50 Hz cutoff.
FAMILIES = [DerivativeFilter(d, n, 50.0, disc) for d in (1, 2) for n in (1, 2, 3)
            for disc in ("exponential", "bilinear")]
# A model error of this size in a std must make the pooled tests fail.
DETECT = 0.003


def systematic_offsets(rng, runs, step):
    """``runs`` sub-step centres evenly spaced over one step with one random offset: each is
    uniform on the step, so their mean of any statistic is unbiased for the grid-phase
    average the exact model predicts, with far less scatter than independent centres (one
    run's derivative-noise std moves with its centre by up to +-10 %, because a constant
    amplitude turns around at the same place on the grid in every cycle)."""
    return ((np.arange(runs) + rng.uniform()) / runs - 0.5) * step


def assert_pooled_within(per_trajectory, labels):
    """``per_trajectory``: (K, filters) ratios measured/model std, one per independent
    trajectory (each pooled over its centres). Trajectories are independent, so the spread
    over them gives the standard error of the mean ratio. Accepted: |mean - 1| <= DETECT/2,
    with 3 se <= DETECT/2. A model off by DETECT (0.3 %) passes only if the pooled estimate
    errs by more than DETECT/2 >= 3 se towards it (probability < 0.14 %); a correct model
    fails only by an error beyond 3 se either way (< 0.3 %)."""
    mean = per_trajectory.mean(axis=0)
    se = per_trajectory.std(axis=0, ddof=1) / math.sqrt(per_trajectory.shape[0])
    assert np.all(3 * se <= DETECT / 2), dict(zip(labels, se.round(6)))
    assert np.all(np.abs(mean - 1) <= DETECT / 2), dict(zip(labels, (mean - 1).round(5)))


def _family_responses():
    """Impulse responses, their autocorrelations and settle lengths of FAMILIES, and the
    longest autocorrelation lag."""
    impulses = [impulse_response(f, FS, tol=1e-12) for f in FAMILIES]
    r_hs = [impulse_autocorrelation(h) for h in impulses]
    settles = [settle_samples(f, FS, tol=1e-12) for f in FAMILIES]
    return impulses, r_hs, settles, max(r.size for r in r_hs) - 1


@pytest.mark.slow
@pytest.mark.parametrize("truth_step", [None, TRUTH_STEP])
def test_exact_model_pooled_to_0p3_percent_every_family_joint(truth_step):
    # One joint, Section IV motion (3 deg, 5 +- 0.1 Hz, 1 kHz), 6 trajectories x 64 centres of
    # 10 s, continuous truth (the design setting) or a 0.125 mrad truth re-quantized 8x (the
    # embedded Phantom logs). A continuous truth's per-run ratio jumps where a turning point
    # crosses a threshold, so evenly spaced centres need to be dense (64) to average it.
    rng = np.random.default_rng(70)
    n_traj, n_centres, n_samples = 6, 64, 10_000
    model = QuantizerErrorModel(STEP, truth_step=truth_step)
    impulses, r_hs, settles, max_lag = _family_responses()
    t = np.arange(n_samples) / FS
    ratios = []
    for _ in range(n_traj):
        base = AMP * np.sin(2 * np.pi * rng.uniform(4.9, 5.1) * t + rng.uniform(0, 2 * np.pi))
        measured, predicted = np.zeros(len(FAMILIES)), np.zeros(len(FAMILIES))
        for offset in systematic_offsets(rng, n_centres, STEP):
            theta = base + offset
            if truth_step is None:
                truth, err = theta, error_of(theta, STEP)
            else:
                fine = quantize(theta, truth_step)
                truth, err = fine * truth_step, (8 * requantize_counts(fine, 8) - fine) * truth_step
            c = exact_joint_autocovariance(truth, model, max_lag)
            for q, (filt, r_h, skip) in enumerate(zip(FAMILIES, r_hs, settles)):
                measured[q] += np.var(apply(filt, err, FS)[skip:])
                predicted[q] += r_h[0] * c[0] + 2 * np.dot(r_h[1:], c[1:r_h.size])
        ratios.append(np.sqrt(measured / predicted))
    assert_pooled_within(np.array(ratios), [f.label() for f in FAMILIES])


CENTRE0 = np.zeros(3)


@pytest.mark.slow
def test_exact_model_pooled_to_0p3_percent_every_family_phantom():
    # Phantom Premium 1.5 about (0, 0.3, 0.3) rad, truth at 0.125 mrad re-quantized 8x (as the
    # embedded logs), every family filtered in operational space (Fig. 2A) and the velocity
    # families in joint space (Fig. 2B); 8 trajectories x 16 runs of 4 s, each joint's centres
    # spread evenly over one step in an independent random order. The prediction is computed
    # per run (the Jacobian weighting) and pooled as a variance.
    rng = np.random.default_rng(71)
    device = PhantomPremium15()
    n_traj, n_centres, n_samples = 8, 16, 4000
    model = QuantizerErrorModel(STEP, truth_step=TRUTH_STEP)
    impulses, r_hs, settles, max_lag = _family_responses()
    velocity = [q for q, f in enumerate(FAMILIES) if f.d == 1]
    t = np.arange(n_samples)[:, None] / FS
    ratios = []
    for _ in range(n_traj):
        base = CENTRE0 + AMP * np.sin(
            2 * np.pi * (np.array(PHANTOM_FREQS) + rng.uniform(-0.02, 0.02, 3)) * t
            + rng.uniform(0, 2 * np.pi, 3))
        offsets = np.stack([rng.permutation(systematic_offsets(rng, n_centres, STEP))
                            for _ in range(3)], axis=1)
        meas = np.zeros((len(FAMILIES) + len(velocity), 3))
        pred = np.zeros_like(meas)
        for offset in offsets:
            fine = quantize(base + offset, TRUTH_STEP)
            truth = fine * TRUTH_STEP
            measured = 8 * requantize_counts(fine, 8) * TRUTH_STEP
            J, H = device.jacobian(truth), device.hessian(truth)
            x_err = device.forward(measured) - device.forward(truth)
            c_x = exact_operational_autocovariance(truth, J, model, max_lag)
            mean_x = J @ np.full(3, model.mean)  # the tie-rule mean, J-weighted
            for q, (filt, r_h, skip) in enumerate(zip(FAMILIES, r_hs, settles)):
                meas[q] += np.var(apply(filt, x_err, FS)[skip:], axis=0)
                pred[q] += (r_h[0] * c_x[:, 0] + 2 * c_x[:, 1:r_h.size] @ r_h[1:]
                            + np.var(apply(filt, mean_x, FS)[skip:], axis=0))
            J_hat = device.jacobian(measured)
            phis = [apply(FAMILIES[q], truth, FS) for q in velocity]
            pred[len(FAMILIES):] += exact_std_joint_architecture(
                truth, J, H, np.array(phis), model, [impulses[q] for q in velocity]) ** 2
            for row, q in enumerate(velocity, start=len(FAMILIES)):
                phi_err = apply(FAMILIES[q], measured - truth, FS)
                y = (np.einsum("kji,ki->kj", J_hat - J, phis[row - len(FAMILIES)])
                     + np.einsum("kji,ki->kj", J_hat, phi_err))
                meas[row] += np.var(y[settles[q]:], axis=0)
        ratios.append(np.sqrt(meas / pred).ravel())
    labels = [f"{f.label()}_{arch}_{axis}" for f, arch in
              [(f, "operational") for f in FAMILIES] + [(FAMILIES[q], "joint") for q in velocity]
              for axis in "xyz"]
    assert_pooled_within(np.array(ratios), labels)


# ------------------------------------------------------------ exact model of a sinusoid
def test_sinusoid_autocovariance_matches_bessel_series_and_a_long_run():
    # Independent method 1: the Fourier series of b and E cos(z cos psi) = J0(z) give
    # C(m) = step^2/(2 pi^2) sum_k J0(2 pi k x)/k^2, x = a_m/step; truncated at K = 20000 its
    # tail is below sum_{k>K} 1/k^2 < 1/K, i.e. < 6e-4 of C(0) = step^2/12.
    from scipy.special import j0

    model = QuantizerErrorModel(STEP, 0.3)  # the offset does not enter a covariance
    f = 5.03
    c = sinusoid_autocovariance(AMP, f, FS, model, 60)
    k = np.arange(1, 20_001)
    x = 2 * AMP * np.abs(np.sin(np.pi * f * np.arange(61) / FS)) / STEP
    series = STEP**2 / (2 * np.pi**2) * (j0(2 * np.pi * np.outer(x, k)) / k**2).sum(axis=1)
    np.testing.assert_allclose(c, series, rtol=0, atol=6e-4 * STEP**2 / 12)
    assert c[0] == pytest.approx(STEP**2 / 12, rel=1e-12)
    # Independent method 2: the trajectory average over a 400 s run (2000 periods, a random
    # sub-step centre); a finite run departs from the equidistributed phase by O(1/periods).
    t = np.arange(400_000) / FS
    theta = 0.37 * STEP + AMP * np.sin(2 * np.pi * f * t + 0.4)
    np.testing.assert_allclose(exact_joint_autocovariance(theta, model, 60), c, rtol=0,
                               atol=1e-3 * STEP**2 / 12)


def test_sinusoid_run_autocovariance_is_one_run_and_averages_to_the_model():
    model = QuantizerErrorModel(STEP)
    f, centre = 5.03, 0.3 * STEP
    # One long run at a fixed sub-step centre (3000 periods): its own error autocovariance.
    t = np.arange(600_000) / FS
    theta = centre + AMP * np.sin(2 * np.pi * f * t + 0.4)
    err = error_of(theta, STEP)
    dev = err - err.mean()
    brute = [np.mean(dev[m:] * dev[: dev.size - m]) for m in range(6)]
    frac = (centre / STEP + model.offset_frac) % 1.0
    cov, mean = sinusoid_run_autocovariance(AMP, f, FS, model, 5, frac, points_per_step=256)
    # Quadrature and the finite run each err by ~1e-4 of C(0) (measured 4e-5).
    np.testing.assert_allclose(cov, brute, rtol=0, atol=1e-3 * STEP**2 / 12)
    assert mean == pytest.approx(err.mean(), abs=1e-3 * STEP)
    # This run is one draw: its derivative noise differs from the grid-phase average.
    assert abs(cov[1] - sinusoid_autocovariance(AMP, f, FS, model, 5)[1]) > 0.005 * STEP**2 / 12
    # Averaged over the grid phase it is the closed form (lags up to 40 samples, where the
    # frequency's rounding to a whole grid shift, < 1e-5 relative, does not matter).
    fracs = (np.arange(256) + 0.5) / 256
    cov, _ = sinusoid_run_autocovariance(AMP, f, FS, model, 40, fracs)
    np.testing.assert_allclose(cov.mean(axis=0), sinusoid_autocovariance(AMP, f, FS, model, 40),
                               rtol=0, atol=2e-3 * STEP**2 / 12)


def test_sinusoid_models_reject_bad_arguments():
    model = QuantizerErrorModel(STEP)
    with pytest.raises(ValueError, match="continuous truth"):
        sinusoid_autocovariance(AMP, 5.0, FS, QuantizerErrorModel(STEP, truth_step=TRUTH_STEP), 3)
    with pytest.raises(ValueError, match="Nyquist"):
        sinusoid_autocovariance(AMP, 600.0, FS, model, 3)
    with pytest.raises(ValueError, match="amplitude"):
        sinusoid_autocovariance(0.0, 5.0, FS, model, 3)
    with pytest.raises(ValueError, match="centre_frac"):
        sinusoid_run_autocovariance(AMP, 5.0, FS, model, 3, 1.0)
