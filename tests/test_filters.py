"""Tests for enclab.propagation.filters: the derivative estimators of Colonnese & Okamura Fig. 5."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
from enclab.propagation.filters import (
    DISCRETIZATIONS,
    DerivativeFilter,
    apply,
    frequency_response,
    h2_norm_sq,
    h2_norm_sq_closed_form,
    impulse_response,
    l1_norm,
    lag_seconds,
    settle_samples,
    state_space,
    transfer_function,
)

FS = 1000.0


def cascade_impulse(filt: DerivativeFilter, fs_hz: float, n_samples: int) -> np.ndarray:
    """Independent reference: run the d differences and n stages one section at a time,
    with the coefficients written out from the module docstring (not taken from the code)."""
    w0T = 2 * math.pi * filt.fc_hz / fs_hz
    if filt.discretization == "exponential":
        alpha = 1 - math.exp(-w0T)
        b, a = [alpha], [1, -(1 - alpha)]
    else:
        gain = w0T / (2 + w0T)
        b, a = [gain, gain], [1, (w0T - 2) / (w0T + 2)]
    y = np.zeros(n_samples)
    y[0] = 1.0
    for _ in range(filt.d):
        y = np.diff(y, prepend=0.0) * fs_hz
    for _ in range(filt.n):
        y = scipy.signal.lfilter(b, a, y)
    return y


# ----------------------------------------------------------------------------- validation
def test_rejects_zero_stages_with_message():
    with pytest.raises(ValueError, match="n must be >= 1 low-pass stages"):
        DerivativeFilter(d=1, n=0, fc_hz=50.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"d": 4, "n": 1, "fc_hz": 50.0}, "d must be"),
        ({"d": 1.0, "n": 1, "fc_hz": 50.0}, "d must be"),
        ({"d": True, "n": 1, "fc_hz": 50.0}, "d must be"),
        ({"d": 1, "n": 1.5, "fc_hz": 50.0}, "n must be"),
        ({"d": 1, "n": 1, "fc_hz": 0.0}, "fc_hz must be"),
        ({"d": 1, "n": 1, "fc_hz": float("inf")}, "fc_hz must be"),
        ({"d": 1, "n": 1, "fc_hz": 50.0, "discretization": "tustin"}, "discretization must be"),
    ],
)
def test_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DerivativeFilter(**kwargs)


@pytest.mark.parametrize("fc", [500.0, 600.0])
def test_cutoff_at_or_above_nyquist_raises(fc):
    filt = DerivativeFilter(1, 1, fc)
    with pytest.raises(ValueError, match=r"cutoff fc_hz=.* must be below the Nyquist frequency fs/2=500"):
        transfer_function(filt, FS)
    with pytest.raises(ValueError, match="Nyquist"):
        apply(filt, np.zeros(10), FS)


def test_numpy_scalars_are_normalised():
    filt = DerivativeFilter(np.int64(2), np.int32(3), np.float32(12.5))
    assert type(filt.d) is int and type(filt.n) is int and type(filt.fc_hz) is float
    assert filt == DerivativeFilter(2, 3, 12.5)


@pytest.mark.parametrize(
    "filt, label",
    [
        (DerivativeFilter(1, 2, 50.0), "d1_n2_fc50_exp"),
        (DerivativeFilter(2, 1, 12.5, "bilinear"), "d2_n1_fc12p5_bil"),
        (DerivativeFilter(0, 3, 0.001, "bilinear"), "d0_n3_fc0p001_bil"),
        (DerivativeFilter(3, 1, 1 / 3), None),
        (DerivativeFilter(1, 1, 1e-5), None),
    ],
)
def test_label_and_dict_round_trip(filt, label):
    if label is not None:
        assert filt.label() == label
    assert DerivativeFilter.from_label(filt.label()) == filt
    spec = filt.to_dict()
    assert spec == {"d": filt.d, "n": filt.n, "fc_hz": filt.fc_hz, "discretization": filt.discretization}
    assert DerivativeFilter.from_dict(spec) == filt


def test_from_dict_rejects_unknown_and_missing_keys():
    with pytest.raises(ValueError, match="unknown keys"):
        DerivativeFilter.from_dict({"d": 1, "n": 1, "fc_hz": 5.0, "order": 2})
    with pytest.raises(ValueError, match="missing keys"):
        DerivativeFilter.from_dict({"d": 1, "n": 1})
    with pytest.raises(ValueError, match="label must look like"):
        DerivativeFilter.from_label("d1_n1_50_exp")


# ------------------------------------------------------------------------ transfer function
@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("fc", [0.01, 0.5, 50.0, 110.0, 111.0, 400.0, 499.0])
def test_low_pass_stage_has_exactly_unit_dc_gain(disc, fc):
    b, a = transfer_function(DerivativeFilter(0, 1, fc, disc), FS)
    assert a[0] == 1.0
    assert b.sum() == a.sum()


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("fc", [0.5, 50.0, 400.0])
def test_low_pass_cascade_has_unit_dc_gain(disc, n, fc):
    filt = DerivativeFilter(0, n, fc, disc)
    b, a = transfer_function(filt, FS)
    # Expanding (1 - p z^-1)^n rounds each coefficient by ~n ulps of its size, and sum(a)
    # = (1 - p)^n cancels, so the stored DC gain is 1 up to ~(n+1) eps sum|a| / |sum a|
    # (the bound grows like fc^-n: 1e-12 at 50 Hz, 3e-8 for n=3 at 0.5 Hz).
    bound = 4 * (n + 1) * np.finfo(float).eps * np.abs(a).sum() / abs(a.sum())
    assert abs(b.sum() / a.sum() - 1) <= bound
    assert abs(frequency_response(filt, FS, [0.0])[0] - 1) <= bound
    # The applied filter's step response settles at that gain.
    step = apply(filt, np.ones(settle_samples(filt, FS, tol=1e-15) + 10), FS)
    assert abs(step[-1] - 1) <= bound + 1e-13


def test_stage_coefficients_match_the_documented_formulas():
    w0T = 2 * math.pi * 50.0 / FS
    b, a = transfer_function(DerivativeFilter(0, 1, 50.0, "exponential"), FS)
    alpha = 1 - math.exp(-w0T)
    np.testing.assert_allclose(b, [alpha], rtol=1e-15)
    np.testing.assert_allclose(a, [1, -(1 - alpha)], rtol=1e-15)
    b, a = transfer_function(DerivativeFilter(0, 1, 50.0, "bilinear"), FS)
    gain = w0T / (2 + w0T)
    np.testing.assert_allclose(b, [gain, gain], rtol=1e-15)
    np.testing.assert_allclose(a, [1, (w0T - 2) / (w0T + 2)], rtol=1e-15)
    # One back difference in physical units: (1 - z^-1) * fs.
    b, a = transfer_function(DerivativeFilter(1, 1, 50.0, "exponential"), FS)
    np.testing.assert_allclose(b, [alpha * FS, -alpha * FS], rtol=1e-15)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d, n", [(1, 1), (1, 3), (2, 2), (3, 1)])
def test_back_differences_reproduce_polynomial_derivatives(disc, d, n):
    # t^d sampled at a power-of-two rate (exact samples). The d-th difference of t^d is d!.
    fs = 1024.0
    filt = DerivativeFilter(d, n, 20.0, disc)
    settle = settle_samples(filt, fs, tol=1e-15)
    t = np.arange(2 * settle + 50) / fs
    x = t**d
    y = apply(filt, x, fs)
    # Past twice the settling length the start-up transient (a free response that decays
    # like the impulse response) is negligible. What remains is float rounding in lfilter's
    # direct form II transposed, to first order in eps:
    # - every update of the M states and of the output rounds a sum of <= 3 terms, each
    #   bounded by |b_i| max|x|, |a_i| max|y| or a later state (itself a partial sum of
    #   such terms), so the M + 1 injected errors total <= 3 M eps (sum|b| max|x| +
    #   sum|a| max|y|);
    # - the stored b and a are products of d + n rounded first-order factors, a relative
    #   coefficient error <= (d + n + 1) eps, i.e. an input perturbation of the same size;
    # - both enter the output through the recursion 1/a(z), whose gain is its l1 norm
    #   (1/sum(a) = 1/(1 - p)^n for the positive pole here: 650 for n=3 at 20 Hz/1024 Hz).
    # Omitting that feedback gain underestimates the error ~100x for n=3 (observed 1.4e-13
    # against a bound of 1.8e-11; the bound is first-order worst case, not a typical error).
    b, a = transfer_function(filt, fs)
    n_state = max(len(a), len(b)) - 1
    impulse = np.zeros(20 * settle)
    impulse[0] = 1.0
    recursion_l1 = np.abs(scipy.signal.lfilter([1.0], a, impulse)).sum()
    eps = np.finfo(float).eps
    scale = np.abs(b).sum() * np.abs(x).max() + np.abs(a).sum() * np.abs(y).max()
    atol = recursion_l1 * (3 * n_state + d + n + 1) * eps * scale
    np.testing.assert_allclose(y[2 * settle :], math.factorial(d), rtol=0, atol=atol)
    # Still sharp enough to catch a coefficient wrong in its sixth significant digit.
    assert atol < 1e-6 * math.factorial(d)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
def test_frequency_response_matches_freqz_and_differentiator(disc):
    filt = DerivativeFilter(2, 2, 100.0, disc)
    freqs = np.array([0.0, 0.3, 1.0, 37.0, 250.0, 499.0])
    b, a = transfer_function(filt, FS)
    _, expected = scipy.signal.freqz(b, a, worN=freqs, fs=FS)
    np.testing.assert_allclose(frequency_response(filt, FS, freqs), expected, rtol=1e-12, atol=1e-12)
    # Far below the cutoff it is (j w)^2: relative deviation O((f/fc) + f/fs) ~ 1e-2 at 0.3 Hz.
    low = frequency_response(filt, FS, [0.3])[0]
    assert abs(low / (2j * math.pi * 0.3) ** 2 - 1) < 2e-2


# ---------------------------------------------------------------------------------- apply
def test_chunked_filtering_equals_whole_signal():
    rng = np.random.default_rng(20240611)
    x = rng.normal(size=(3000, 3)).cumsum(axis=0)
    for disc in DISCRETIZATIONS:
        filt = DerivativeFilter(2, 3, 35.0, disc)
        whole = apply(filt, x, FS)
        pieces, state = [], None
        for chunk in np.array_split(x, [1, 700, 701, 2100]):
            y, state = apply(filt, chunk, FS, zi=state, return_state=True)
            pieces.append(y)
        chunked = np.concatenate(pieces)
        np.testing.assert_allclose(chunked, whole, rtol=0, atol=1e-12 * np.max(np.abs(whole)))
        # The same along axis=1.
        whole_t = apply(filt, x.T, FS, axis=1)
        np.testing.assert_allclose(whole_t, whole.T, rtol=0, atol=1e-12 * np.max(np.abs(whole)))


def test_one_dimensional_state_is_broadcast():
    filt = DerivativeFilter(1, 2, 50.0)
    x = np.ones((40, 2))
    _, state = apply(filt, x[:, 0], FS, return_state=True)
    y_2d = apply(filt, x, FS, zi=state)
    y_1d = apply(filt, x[:, 0], FS, zi=state)
    np.testing.assert_array_equal(y_2d[:, 0], y_1d)
    np.testing.assert_array_equal(y_2d[:, 1], y_1d)
    with pytest.raises(ValueError, match="zi must have shape"):
        apply(filt, x, FS, zi=np.zeros(7))


def test_apply_rejects_non_finite_input_naming_index():
    x = np.zeros(10)
    x[6] = np.nan
    with pytest.raises(ValueError, match=r"index \(6,\)"):
        apply(DerivativeFilter(1, 1, 50.0), x, FS)


def test_apply_accepts_integer_counts():
    counts = np.arange(100, dtype=np.int64)
    y = apply(DerivativeFilter(1, 1, 50.0), counts, FS)
    assert y.dtype == np.float64
    np.testing.assert_allclose(y[-1], FS, rtol=1e-12)


# ------------------------------------------------------------------ impulse response, norms
@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d, n", [(0, 1), (1, 1), (1, 3), (2, 2), (3, 3)])
def test_impulse_response_matches_independent_cascade(disc, d, n):
    filt = DerivativeFilter(d, n, 20.0, disc)
    h = impulse_response(filt, FS)
    reference = cascade_impulse(filt, FS, len(h))
    np.testing.assert_allclose(h, reference, rtol=0, atol=1e-12 * np.max(np.abs(reference)))
    # The neglected tail is below 1e-14 of the energy: compare with a 4x longer response.
    longer = cascade_impulse(filt, FS, 4 * len(h))
    assert np.sum(longer[len(h) :] ** 2) < 1e-14 * np.sum(longer**2)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("fc", [1.0, 5.0, 50.0, 200.0, 450.0])
def test_h2_velocity_three_ways_agree(disc, fc):
    filt = DerivativeFilter(1, 1, fc, disc)
    closed = h2_norm_sq_closed_form(filt, FS)
    np.testing.assert_allclose(h2_norm_sq(filt, FS, method="impulse"), closed, rtol=1e-10)
    np.testing.assert_allclose(h2_norm_sq(filt, FS, method="lyapunov"), closed, rtol=1e-10)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d", [0, 1, 2, 3])
@pytest.mark.parametrize("n", [1, 2, 3])
@pytest.mark.parametrize("fc", [5.0, 50.0, 200.0])
def test_h2_impulse_equals_lyapunov(disc, d, n, fc):
    filt = DerivativeFilter(d, n, fc, disc)
    np.testing.assert_allclose(
        h2_norm_sq(filt, FS, method="impulse"), h2_norm_sq(filt, FS, method="lyapunov"), rtol=1e-10
    )


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d", [1, 2, 3])
def test_lyapunov_is_accurate_for_slow_triple_stage(disc, d):
    # Poles at 1 - 3e-3: a companion-form realization loses digits here (see state_space).
    filt = DerivativeFilter(d, 3, 0.5, disc)
    reference = cascade_impulse(filt, FS, 60_000)
    np.testing.assert_allclose(h2_norm_sq(filt, FS), np.sum(reference**2), rtol=1e-9)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
def test_state_space_reproduces_transfer_function(disc):
    filt = DerivativeFilter(2, 3, 40.0, disc)
    A, B, C, D = state_space(filt, FS)
    # Minimal order = degree of H(z): max(d, n) = 3 for the exponential stage (no zero),
    # d + n = 5 for the bilinear stage (zero at Nyquist per stage).
    b, a = transfer_function(filt, FS)
    order = max(len(a), len(b)) - 1
    assert order == {"exponential": 3, "bilinear": 5}[disc]
    assert A.shape == (order, order) and B.shape == (order, 1)
    assert C.shape == (1, order) and D.shape == (1, 1)
    _, (h_ss,) = scipy.signal.dimpulse((A, B, C, D, 1 / FS), n=300)
    h = impulse_response(filt, FS, n_samples=300)
    np.testing.assert_allclose(h_ss.ravel(), h, rtol=0, atol=1e-12 * np.max(np.abs(h)))


def test_closed_form_rejects_other_orders():
    with pytest.raises(ValueError, match="d=1, n=1"):
        h2_norm_sq_closed_form(DerivativeFilter(2, 1, 50.0), FS)
    with pytest.raises(ValueError, match="method must be"):
        h2_norm_sq(DerivativeFilter(1, 1, 50.0), FS, method="parseval")


def test_bilinear_and_exponential_velocity_noise_differ():
    exp_h2 = h2_norm_sq(DerivativeFilter(1, 1, 50.0, "exponential"), FS)
    bil_h2 = h2_norm_sq(DerivativeFilter(1, 1, 50.0, "bilinear"), FS)
    w0T = 2 * math.pi * 50.0 / FS
    alpha = 1 - math.exp(-w0T)
    gain = w0T / (2 + w0T)
    expected_ratio = 2 * gain**2 / (alpha**2 * 2 / (2 - alpha))
    np.testing.assert_allclose(bil_h2 / exp_h2, expected_ratio, rtol=1e-12)
    # About a third less noise std with the bilinear stage: sqrt(ratio) = 0.6624.
    assert 0.65 < math.sqrt(bil_h2 / exp_h2) < 0.67


@pytest.mark.parametrize("fc", [2.0, 50.0, 300.0])
def test_l1_norm_closed_forms(fc):
    # Exponential smoothing has a positive impulse response: l1 = DC gain = 1. Its first
    # difference is alpha/T at k=0 followed by negative terms summing to -alpha/T.
    alpha = 1 - math.exp(-2 * math.pi * fc / FS)
    np.testing.assert_allclose(l1_norm(DerivativeFilter(0, 2, fc), FS), 1.0, rtol=1e-12)
    np.testing.assert_allclose(l1_norm(DerivativeFilter(1, 1, fc), FS), 2 * alpha * FS, rtol=1e-12)


def test_l1_norm_of_alternating_bilinear_stage():
    # fc > fs/pi makes the bilinear pole negative: h_0 = K, h_k = K(1 + beta) beta^(k-1),
    # so l1 = K + K(1 + beta)/(1 - |beta|).
    fc = 400.0
    w0T = 2 * math.pi * fc / FS
    gain, beta = w0T / (2 + w0T), (2 - w0T) / (2 + w0T)
    assert beta < 0
    expected = gain + gain * (1 + beta) / (1 - abs(beta))
    np.testing.assert_allclose(l1_norm(DerivativeFilter(0, 1, fc, "bilinear"), FS), expected, rtol=1e-12)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d, n, fc", [(0, 1, 50.0), (1, 2, 10.0), (2, 3, 80.0), (1, 1, 1000.0 / math.pi)])
@pytest.mark.parametrize("tol", [1e-6, 1e-9])
def test_settle_samples_consistent_with_impulse_response(disc, d, n, fc, tol):
    filt = DerivativeFilter(d, n, fc, disc)
    settle = settle_samples(filt, FS, tol=tol)
    h = np.abs(cascade_impulse(filt, FS, 3 * settle + 100))
    threshold = tol * h.max()
    assert np.all(h[settle:] < threshold)
    assert h[settle - 1] >= threshold


def test_norm_tolerances_validated():
    with pytest.raises(ValueError, match="tol must be"):
        settle_samples(DerivativeFilter(1, 1, 50.0), FS, tol=0.0)
    with pytest.raises(ValueError, match="n_samples must be"):
        impulse_response(DerivativeFilter(1, 1, 50.0), FS, n_samples=0)


@pytest.mark.parametrize("disc", DISCRETIZATIONS)
@pytest.mark.parametrize("d, n, fc", [(1, 1, 50.0), (2, 3, 25.0), (1, 2, 200.0), (0, 1, 100.0)])
def test_lag_is_the_low_frequency_group_delay(disc, d, n, fc):
    filt = DerivativeFilter(d, n, fc, disc)
    # Closed forms: a back difference delays by half a sample; the exponential stage (pole
    # p = exp(-w0 T)) by p/(1-p) = 1/(exp(w0 T) - 1) samples; the bilinear stage by
    # 1/2 + p/(1-p) with p = (2 - w0 T)/(2 + w0 T), i.e. exactly 1/(w0 T) samples (= 1/w0).
    w0T = 2 * np.pi * fc / FS
    stage = 1 / np.expm1(w0T) if disc == "exponential" else 1 / w0T
    assert lag_seconds(filt, FS) == pytest.approx((0.5 * d + n * stage) / FS, rel=1e-12)
    # Independent: scipy's numerical group delay of the expanded transfer function at
    # w = 2 pi 1e-4 rad/sample, where the delay differs from its DC value by a relative
    # O((w / w0 T)^2) < 2e-5 and the d-fold zero at DC still leaves ~1e-8 of the numerator.
    b, a = transfer_function(filt, FS)
    _, delay = scipy.signal.group_delay((b, a), w=[2 * np.pi * 1e-4])
    assert lag_seconds(filt, FS) == pytest.approx(delay[0] / FS, rel=1e-4)
