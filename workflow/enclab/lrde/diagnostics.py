"""MCMC convergence diagnostics, written independently of emcee so they can cross-check it.

References
----------
.. [1] A. D. Sokal, "Monte Carlo Methods in Statistical Mechanics: Foundations and New
   Algorithms", 1996 (integrated autocorrelation time, automatic window ``M >= c tau``).
.. [2] A. Gelman et al., Bayesian Data Analysis, 3rd ed., Sec. 11.4-11.5 (split R-hat,
   effective sample size).
"""
from __future__ import annotations

import numpy as np

__all__ = ["autocorrelation", "integrated_time", "split_rhat", "split_rhat_ensembles",
           "effective_sample_size"]


def _chains(x) -> np.ndarray:
    """Validate and return ``x`` as float array of shape ``(n_chains, n_steps)``."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise ValueError(f"chains must have shape (n_chains, n_steps), got {arr.shape}")
    if arr.shape[1] < 4:
        raise ValueError(f"chains need at least 4 steps, got {arr.shape[1]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("chains must be finite")
    return arr


def autocorrelation(x) -> np.ndarray:
    """Normalised autocorrelation function, averaged over chains (FFT, zero padded).

    Each chain's autocovariance is normalised by its own variance before averaging (the
    definition emcee uses, so the two agree to rounding); constant chains are skipped.

    Parameters
    ----------
    x : array_like, shape (n_chains, n_steps) or (n_steps,)

    Returns
    -------
    numpy.ndarray, shape (n_steps,)
        ``rho[0] = 1``; a constant chain returns ``rho = 1`` at lag 0 and 0 elsewhere.
    """
    arr = _chains(x)
    n = arr.shape[1]
    centred = arr - arr.mean(axis=1, keepdims=True)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(centred, n=size, axis=1)
    acov = np.fft.irfft(spectrum * np.conj(spectrum), n=size, axis=1)[:, :n]
    varying = acov[:, 0] > 0
    if not np.any(varying):
        rho = np.zeros(n)
        rho[0] = 1.0
        return rho
    return (acov[varying] / acov[varying, :1]).mean(axis=0)


def integrated_time(x, c: float = 5.0) -> float:
    """Integrated autocorrelation time ``tau = 1 + 2 sum_{k>=1} rho_k`` with Sokal's window.

    The sum is truncated at the smallest ``M`` with ``M >= c tau(M)``; for an AR(1) chain
    with coefficient ``phi`` the exact value is ``(1 + phi) / (1 - phi)``.

    Parameters
    ----------
    x : array_like, shape (n_chains, n_steps) or (n_steps,)
    c : float
        Window constant (5 as in emcee).
    """
    if not (np.isscalar(c) and np.isfinite(c) and c > 0):
        raise ValueError(f"c must be a finite positive scalar, got {c!r}")
    rho = autocorrelation(x)
    taus = 2.0 * np.cumsum(rho) - 1.0
    window = np.arange(taus.size) >= c * taus
    m = int(np.argmax(window)) if np.any(window) else taus.size - 1
    return float(taus[m])


def _rhat(chains: np.ndarray) -> float:
    """Classic potential scale reduction of BDA3 eq. (11.4) for chains of shape (m, n)."""
    n = chains.shape[1]
    within = chains.var(axis=1, ddof=1).mean()
    between_over_n = chains.mean(axis=1).var(ddof=1)
    if within == 0:
        return 1.0 if between_over_n == 0 else float("inf")
    var_plus = (n - 1) / n * within + between_over_n
    return float(np.sqrt(var_plus / within))


def split_rhat(x) -> float:
    """Split R-hat (BDA3 eq. 11.4 on half chains).

    Each chain is cut into two halves (an odd last sample is dropped) so that a trend within a
    chain also inflates R-hat. ``R = sqrt(((n - 1)/n W + B/n) / W)`` with ``W`` the mean
    within-half variance and ``B/n`` the variance of the half means. For autocorrelated
    chains ``R^2 - 1 ~ (tau - 1)/n`` even at convergence, so ``R <= 1.01`` needs halves of
    about ``50 tau`` samples.

    Parameters
    ----------
    x : array_like, shape (n_chains, n_steps)
    """
    arr = _chains(x)
    half = arr.shape[1] // 2
    return _rhat(np.concatenate((arr[:, :half], arr[:, half:2 * half]), axis=0))


def split_rhat_ensembles(x) -> float:
    """Split R-hat across independent ensembles, each ensemble's walkers pooled.

    Each ensemble is cut in time into two halves; a half's sample is every walker position
    at every step of that half, so the ``2 n_ensembles`` "chains" have
    ``n_walkers * n_steps / 2`` samples each and R-hat compares ensembles (and their early
    and late halves) rather than single walkers, whose short chains would inflate R-hat by
    ``(tau - 1) / n`` (see :func:`split_rhat`).

    Parameters
    ----------
    x : array_like, shape (n_ensembles, n_steps, n_walkers)
    """
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 3 or arr.shape[0] < 2 or arr.shape[1] < 4:
        raise ValueError(f"x must have shape (n_ensembles >= 2, n_steps >= 4, n_walkers), "
                         f"got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("x must be finite")
    half = arr.shape[1] // 2
    first = arr[:, :half, :].reshape(arr.shape[0], -1)
    second = arr[:, half:2 * half, :].reshape(arr.shape[0], -1)
    return _rhat(np.concatenate((first, second), axis=0))


def effective_sample_size(x, c: float = 5.0) -> float:
    """Effective sample size ``n_chains * n_steps / tau`` (``tau`` from :func:`integrated_time`)."""
    arr = _chains(x)
    return float(arr.size / max(integrated_time(arr, c), 1.0))
