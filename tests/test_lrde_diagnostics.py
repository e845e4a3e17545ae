"""Diagnostics against AR(1) chains with known autocorrelation time and against emcee."""
import emcee
import numpy as np
import pytest

from enclab.lrde import diagnostics


def _ar1(rng, phi, n_chains, n_steps):
    # Stationary start: x0 ~ N(0, 1/(1 - phi^2)), unit innovations.
    x = np.empty((n_chains, n_steps))
    x[:, 0] = rng.normal(0, 1 / np.sqrt(1 - phi**2), n_chains)
    eps = rng.normal(size=(n_chains, n_steps))
    for j in range(1, n_steps):
        x[:, j] = phi * x[:, j - 1] + eps[:, j]
    return x


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_integrated_time_of_ar1(phi):
    rng = np.random.default_rng(11)
    x = _ar1(rng, phi, 8, 20_000)
    tau_true = (1 + phi) / (1 - phi)
    tau = diagnostics.integrated_time(x)
    # Sokal: var(tau_hat)/tau^2 ~ 2 (2M + 1)/N with M ~ 5 tau and N = 160 000 samples:
    # relative sd 1.1 % (phi=0), 2.1 % (0.5), 4.9 % (0.9). 4 sd plus the window's truncation
    # bias (phi^M, negligible) gives the tolerance.
    rel_sd = np.sqrt(2 * (2 * 5 * tau_true + 1) / x.size)
    assert tau == pytest.approx(tau_true, rel=4 * rel_sd)
    # Independent cross-check: emcee's estimator on the same chains (emcee wants (steps, walkers)).
    tau_emcee = emcee.autocorr.integrated_time(x.T[:, :, None], quiet=True)[0]
    # The same estimator and window: only the order of float operations differs (FFT
    # autocovariance, a sum over M <= 100 lags: < 1e-12 relative). A window one lag off would
    # move tau by 2 rho_M / tau = 2 * 0.9**95 / 19 = 5e-6 (phi = 0.9): rel=1e-6 catches it.
    assert tau == pytest.approx(tau_emcee, rel=1e-6)
    ess = diagnostics.effective_sample_size(x)
    assert ess == pytest.approx(x.size / tau_true, rel=4 * rel_sd)


def test_split_rhat_flags_disagreeing_and_trending_chains():
    rng = np.random.default_rng(3)
    iid = rng.normal(size=(4, 5000))
    # For iid chains R-hat - 1 is O(1/n): with 8 halves of 2500, well below 0.01.
    assert diagnostics.split_rhat(iid) < 1.005
    shifted = iid + np.array([0.0, 0.0, 0.0, 1.0])[:, None]
    assert diagnostics.split_rhat(shifted) > 1.1
    trend = iid + np.linspace(0, 3, 5000)[None, :]
    assert diagnostics.split_rhat(trend) > 1.1


def test_diagnostics_validate():
    with pytest.raises(ValueError, match="at least 4 steps"):
        diagnostics.integrated_time(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="shape"):
        diagnostics.split_rhat(np.zeros((2, 3, 4)))


def test_split_rhat_ensembles_pools_walkers():
    rng = np.random.default_rng(5)
    # 4 ensembles x 200 steps x 32 walkers of AR(1) (tau = 19): per-walker split R-hat is
    # inflated by ~(tau - 1)/n = 18/100 (R ~ 1.09) although everything is stationary, while the
    # ensemble version has halves of 3200 samples: R^2 - 1 ~ 18/3200, R < 1.01.
    x = _ar1(rng, 0.9, 4 * 32, 200).reshape(4, 32, 200).transpose(0, 2, 1)
    assert diagnostics.split_rhat_ensembles(x) < 1.01
    assert diagnostics.split_rhat(x.transpose(0, 2, 1).reshape(-1, 200)) > 1.03
    # One ensemble displaced by ~2 stationary sd (sd = 1/sqrt(1 - 0.81) = 2.3): the 8 half
    # means (0 x6, 5 x2) have variance 5.36 against W ~ 5.3, so R ~ sqrt(2) >> 1.1.
    shifted = x + np.array([0.0, 0.0, 0.0, 5.0])[:, None, None]
    assert diagnostics.split_rhat_ensembles(shifted) > 1.1
    with pytest.raises(ValueError, match="n_ensembles"):
        diagnostics.split_rhat_ensembles(x[:1])
