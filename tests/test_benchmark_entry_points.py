"""The public entry points the benchmarks call instead of the library's private functions,
checked against independent computations."""
import numpy as np
import pytest
from scipy.special import log_ndtr

from enclab.lrde import effects, fit
from enclab.propagation import theory
from enclab.residuals import effects as fx
from enclab.residuals import select as sel


def _log_interval(lower, upper):
    """log(Phi(upper) - Phi(lower)) by reflection to the lower tail (no cancellation)."""
    flip = lower > 0
    lo, up = np.where(flip, -upper, lower), np.where(flip, -lower, upper)
    return log_ndtr(up) + np.log1p(-np.exp(log_ndtr(lo) - log_ndtr(up)))


def test_filtered_variance_of_an_ar1_error_matches_a_long_simulation():
    # AR(1) error e_k = phi e_{k-1} + w_k: C(m) = phi^m / (1 - phi^2); through a 3-tap FIR the
    # variance is sum_m r_h(|m|) C(|m|). A 400k-sample simulation agrees within its error.
    phi, h = 0.6, np.array([0.5, 0.3, 0.2])
    lags = np.arange(h.size)
    exact = theory.filtered_variance(theory.impulse_autocorrelation(h), phi**lags / (1 - phi**2))
    rng = np.random.default_rng(3)
    w = rng.normal(size=400_000)
    e = np.empty_like(w)
    e[0] = w[0] / np.sqrt(1 - phi**2)
    for k in range(1, w.size):
        e[k] = phi * e[k - 1] + w[k]
    y = np.convolve(e, h, mode="valid")
    # Var of a sample variance of a correlated series: a few times 2 var^2 / n; 5 % is > 10 sigma.
    assert np.var(y) == pytest.approx(float(exact), rel=0.05)


@pytest.mark.parametrize("path", ["gathered", "in_place"])
def test_interval_log_probability_paths_match_scipy(path):
    rng = np.random.default_rng(1)
    lower = rng.uniform(-6.0, 6.0, 2000)
    upper = lower + rng.uniform(3.0, 12.0, lower.size)
    got = effects.log_interval_probability(lower, upper, path)
    # the paths drop tails below Phi(-8) = 6e-16 against probabilities above 1/2
    np.testing.assert_allclose(got, _log_interval(lower, upper), rtol=1e-10, atol=1e-14)


def test_interval_log_probability_rows_are_the_sums_of_the_entries():
    rng = np.random.default_rng(2)
    u = rng.uniform(0.0, 1.0, (16, 500))
    lower, upper = -u / 0.05, (1.0 - u) / 0.05
    rows = effects.log_interval_probability(lower, upper, "rows")
    each = effects.log_interval_probability(lower.ravel(), upper.ravel(), "in_place")
    np.testing.assert_allclose(rows, each.reshape(lower.shape).sum(axis=1), rtol=1e-12)
    with pytest.raises(ValueError, match="path"):
        effects.log_interval_probability(lower, upper, "sparse")


def test_fit_interval_log_probability_matches_scipy():
    rng = np.random.default_rng(4)
    lower = rng.uniform(-10.0, 10.0, 1000)
    upper = lower + rng.uniform(3.2, 6.0, lower.size)
    got = fit.log_interval_probability(lower, upper)
    # beyond 8 the far bound is dropped: exp(-b w - w^2 / 2) < 1e-11 for widths w >= 3.2
    np.testing.assert_allclose(got, _log_interval(lower, upper), rtol=1e-10, atol=1e-11)


def _clean_log(seed, n=3000):
    step = 2 * np.pi / 4096
    truth_step = step / 8
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    theta = 0.3 * np.sin(2 * np.pi * 1.37 * t + rng.uniform(0, 2 * np.pi)) + rng.uniform(0, step)
    truth = np.floor(theta / truth_step + 0.5) * truth_step
    measured = np.floor(theta / step) * step
    return t, truth, measured, step, truth_step


def test_grid_and_counts_reads_the_grid_back():
    t, truth, measured, step, truth_step = _clean_log(0)
    grid, counts = sel.grid_and_counts(measured + 0.25 * step, step)
    assert grid == pytest.approx(0.25 * step, abs=1e-9 * step)
    np.testing.assert_array_equal(counts, np.round(measured / step).astype(np.int64))


def test_an_effect_added_to_a_clean_log_gains_little():
    # On a log the base model describes, the added effect's likelihood gain is small (its
    # parameters fit noise), never negative beyond the optimiser's tolerance.
    t, truth, measured, step, truth_step = _clean_log(1)
    grid, counts = sel.grid_and_counts(measured, step)
    out = sel.added_effect_fit(t, truth, counts, step, truth_step, fx.Hysteresis(), grid=grid,
                               with_inflation=True, with_floor=True)
    assert out["n_fit"] == t.size and out["k"] >= 1
    gain = 2.0 * (out["ll_effect"] - out["ll_base"])
    assert -1e-3 <= gain < 10.0 + out["k"] * np.log(t.size)
    assert out["inflation"] >= 1.0 and out["floor_std"] > 0.0
    terms = sel.floor_interval_terms(t, truth, counts, step, truth_step)
    assert terms["floor_var"] == pytest.approx(out["floor_std"] ** 2)
    assert terms["se_time_blocks"] > 0.0 and terms["se_library"] > 0.0
