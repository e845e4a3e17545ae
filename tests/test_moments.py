"""Tests for enclab.propagation.moments: error moments with batch-means and pooled-run intervals."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
import scipy.stats
from enclab.propagation.moments import error_moments, pooled_std_ratio

STEP = 1e-3


def ar1(rng, phi, n_samples, n_series, burn_in=500):
    """Stationary AR(1) series (columns), unit innovations: variance 1 / (1 - phi^2)."""
    w = rng.standard_normal((n_samples + burn_in, n_series))
    return scipy.signal.lfilter([1.0], [1.0, -phi], w, axis=0)[burn_in:]


def binomial_tolerance(p, trials, z=3.5):
    """Half-width of a z-sigma band for an empirical coverage of `trials` Bernoulli(p)."""
    return z * math.sqrt(p * (1 - p) / trials)


# ------------------------------------------------------------------------------ error_moments
def test_uniform_white_error_has_step_over_sqrt12_std():
    rng = np.random.default_rng(2024)
    n = 200_000
    err = rng.uniform(-STEP / 2, STEP / 2, n)
    out = error_moments(err)
    sigma = STEP / math.sqrt(12)
    # Var(s^2) = (mu4 - sigma^4)/n with mu4 = step^4/80 and sigma^4 = step^4/144, so
    # sd(s)/sigma = sqrt(1/80 - 1/144) * 12 / 2 / sqrt(n) = 0.447/sqrt(n) = 1.0e-3; 5 sigma.
    rel_sd = math.sqrt(1 / 80 - 1 / 144) * 6 / math.sqrt(n)
    assert abs(out["std"] / sigma - 1) < 5 * rel_sd
    # The mean has sd sigma/sqrt(n); the peak is within step * (few / n) of step/2.
    assert abs(out["mean"]) < 5 * sigma / math.sqrt(n)
    assert STEP / 2 * (1 - 20 / n) < out["max_abs"] <= STEP / 2
    assert out["n"] == n and "cov" not in out
    lo, hi = out["std_ci"]
    assert lo < out["std"] < hi
    # For white noise the exact half-width of the variance interval is about
    # 1.96 sd(s^2); the batch estimate of sd(s^2) has B - 1 = 19 degrees of freedom, so
    # (half-width / exact) / (t_19 / 1.96) lies in the chi_19 / sqrt(19) band (1e-4 tails).
    half_width = (hi**2 - lo**2) / 2
    exact = 1.96 * sigma**2 * 12 * math.sqrt(1 / 80 - 1 / 144) / math.sqrt(n)
    ratio = half_width / exact / (scipy.stats.t.ppf(0.975, 19) / 1.96)
    band = np.sqrt(scipy.stats.chi2.ppf([1e-4, 1 - 1e-4], 19) / 19)
    assert band[0] < ratio < band[1]


def test_two_dimensional_input_gives_per_column_moments_and_cov():
    rng = np.random.default_rng(7)
    n = 100_000
    mix = np.array([[1.0, 0.0], [0.6, 0.8]])
    err = rng.standard_normal((n, 2)) @ mix.T + np.array([0.5, -1.0])
    out = error_moments(err)
    expected_cov = mix @ mix.T
    # Entries of a sample covariance have sd sqrt((S_ii S_jj + S_ij^2)/n) <= sqrt(2/n) = 4.5e-3
    # (unit variances); 5 sigma.
    np.testing.assert_allclose(out["cov"], expected_cov, atol=5 * math.sqrt(2 / n))
    np.testing.assert_allclose(out["std"], np.sqrt(np.diag(out["cov"])), rtol=1e-12)
    np.testing.assert_allclose(out["mean"], [0.5, -1.0], atol=5 / math.sqrt(n))
    lo, hi = out["std_ci"]
    assert lo.shape == hi.shape == (2,) and np.all(lo < out["std"]) and np.all(out["std"] < hi)
    one = error_moments(err[:, 1])
    assert one["std"] == pytest.approx(float(out["std"][1]), rel=1e-12)
    assert one["std_ci"][1] == pytest.approx(float(hi[1]), rel=1e-12)


def test_batch_interval_covers_autocorrelated_error_at_nominal_rate():
    # 1000 independent AR(1) series (phi = 0.9: correlation time of the squares
    # (1 + phi^2)/(1 - phi^2) = 9.5 samples, batches of 200). A 2-D call treats the series as
    # columns, which is just a vectorized loop for std_ci.
    rng = np.random.default_rng(31)
    phi, n_samples, trials = 0.9, 4000, 1000
    x = ar1(rng, phi, n_samples, trials)
    true_std = 1 / math.sqrt(1 - phi**2)
    out = error_moments(x, ci_level=0.95, n_batches=20)
    lo, hi = out["std_ci"]
    coverage = np.mean((lo <= true_std) & (true_std <= hi))
    assert abs(coverage - 0.95) < binomial_tolerance(0.95, trials)
    # Why batches: the chi-square interval that assumes independent samples covers about
    # half the time here (its width is ~sqrt(9.5) too small).
    s = out["std"]
    chi_lo = s * np.sqrt((n_samples - 1) / scipy.stats.chi2.ppf(0.975, n_samples - 1))
    chi_hi = s * np.sqrt((n_samples - 1) / scipy.stats.chi2.ppf(0.025, n_samples - 1))
    assert np.mean((chi_lo <= true_std) & (true_std <= chi_hi)) < 0.7


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"err": np.zeros(39)}, "fewer than 2 per batch"),
        ({"err": np.zeros((50, 2, 2))}, "shape"),
        ({"err": np.r_[np.zeros(50), np.nan]}, "row 50"),
        ({"err": np.zeros(100), "ci_level": 1.0}, "ci_level must be"),
        ({"err": np.zeros(100), "n_batches": 1}, "n_batches must be"),
        ({"err": np.array(["a"] * 100)}, "real numeric"),
    ],
)
def test_error_moments_rejects_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        error_moments(**kwargs)


# --------------------------------------------------------------------------- pooled_std_ratio
def test_pooled_ratio_analytic_values():
    # Weights n - 1 = (10, 30): pooled variance (10 * 1 + 30 * 4) / 40 = 3.25.
    ratio, lo, hi = pooled_std_ratio([1.0, 2.0], [11, 31], reference=0.5)
    assert ratio == pytest.approx(math.sqrt(3.25) / 0.5, rel=1e-12)
    assert lo <= ratio <= hi
    # Equal weights, variances (1, 2, 3): mean 2, s = 1, se = 1/sqrt(3), t_{0.975, 2} = 4.303.
    half = scipy.stats.t.ppf(0.975, 2) / math.sqrt(3)
    ratio, lo, hi = pooled_std_ratio(np.sqrt([1.0, 2.0, 3.0]), [100, 100, 100], reference=1.0)
    assert ratio == pytest.approx(math.sqrt(2.0), rel=1e-12)
    assert lo == 0.0 and hi == pytest.approx(math.sqrt(2.0 + half), rel=1e-12)


def test_pooled_ratio_covers_one_at_nominal_rate_for_autocorrelated_runs():
    # 600 repetitions (columns) of R = 8 independent AR(1) runs each, vectorized as (R, k).
    # A run's sample variance is biased low by ~(1 + phi)/(1 - phi)/n = 0.9 % here; the
    # reference is its exact expectation, so that the check is on the interval, not on that
    # bias: E[s^2] = sigma^2 (1 - 2/(n (n - 1)) sum_{m>=1} (n - m) phi^m).
    rng = np.random.default_rng(97)
    phi, n_samples, runs, trials = 0.8, 1000, 8, 600
    x = ar1(rng, phi, n_samples, runs * trials).reshape(n_samples, runs, trials)
    stds = x.std(axis=0, ddof=1)
    lags = np.arange(1, n_samples)
    expected_var = (1 - 2 / (n_samples * (n_samples - 1)) * np.sum((n_samples - lags) * phi**lags)) / (1 - phi**2)
    ratio, lo, hi = pooled_std_ratio(stds, np.full(runs, n_samples), math.sqrt(expected_var))
    assert ratio.shape == lo.shape == hi.shape == (trials,)
    coverage = np.mean((lo <= 1) & (1 <= hi))
    assert abs(coverage - 0.95) < binomial_tolerance(0.95, trials)
    # The pooled ratio itself: sd of the pooled variance over R * trials runs of AR(1) is
    # sqrt(2 (1 + phi^2)/(1 - phi^2) / n / (R trials)) = 1.4e-3 relative, half that on the
    # std; 5 sigma.
    rel_sd = math.sqrt(2 * (1 + phi**2) / (1 - phi**2) / n_samples / (runs * trials)) / 2
    assert abs(np.mean(ratio**2) ** 0.5 - 1) < 5 * rel_sd


def test_pooled_ratio_per_coordinate_reference():
    stds = np.array([[1.0, 4.0], [1.0, 4.0]])
    ratio, lo, hi = pooled_std_ratio(stds, [50, 50], reference=[2.0, 2.0])
    np.testing.assert_allclose(ratio, [0.5, 2.0], rtol=1e-12)
    # No spread across runs: a zero-width interval.
    np.testing.assert_allclose(lo, ratio, rtol=1e-12)
    np.testing.assert_allclose(hi, ratio, rtol=1e-12)


@pytest.mark.parametrize(
    "args, match",
    [
        (([1.0], [10], 1.0), "R >= 2"),
        (([1.0, -1.0], [10, 10], 1.0), "non-negative"),
        (([1.0, 1.0], [10, 1], 1.0), "ns must be"),
        (([1.0, 1.0], [10.0, 10.0], 1.0), "ns must be"),
        (([1.0, 1.0], [10, 10], 0.0), "reference must be"),
        (([[1.0, 1.0], [1.0, 1.0]], [10, 10], [1.0, 1.0, 1.0]), "reference must be"),
    ],
)
def test_pooled_ratio_rejects_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        pooled_std_ratio(*args)
