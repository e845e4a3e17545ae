"""Empirical moments of quantization errors with honest confidence intervals.

The error of a quantized, filtered trajectory is autocorrelated (the motion moves only a few
steps per sample and the derivative filters have memory), so the textbook chi-square interval
for a standard deviation, which assumes independent samples, is far too narrow. Two remedies
are provided:

- :func:`error_moments` uses **non-overlapping batches** of one log: each batch gives an
  estimate of the variance; when the batches are much longer than the correlation time these
  estimates are nearly independent, and a Student-t interval on them is valid.
- :func:`pooled_std_ratio` pools **independent repeated runs** (e.g. seeded simulations)
  against a model standard deviation; runs are independent by construction, so the t-interval
  across runs is honest whatever the autocorrelation within a run.

References
----------
.. [1] G. S. Fishman, *Discrete-Event Simulation*, Springer, 2001 (the method of batch means).
.. [2] N. Colonnese and A. M. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives", Section IV (empirical error
   statistics).
"""
from __future__ import annotations

import numbers

import numpy as np

__all__ = ["error_moments", "pooled_std_ratio"]


def _check_level(ci_level) -> float:
    if isinstance(ci_level, bool) or not isinstance(ci_level, numbers.Real) or not 0.0 < ci_level < 1.0:
        raise ValueError(f"ci_level must be a number in (0, 1), got ci_level={ci_level!r}")
    return float(ci_level)


def _t_interval(estimates: np.ndarray, weights: np.ndarray, ci_level: float):
    """Weighted mean of ``estimates`` (axis 0) and its Student-t half-width.

    ``weights`` (shape (R,), summing to 1) are reliability weights; the spread uses the
    unbiased weighted variance ``sum w (v - vbar)^2 / (1 - sum w^2)`` and the standard error
    ``sqrt(sum w^2) * spread``, which reduce to ``s / sqrt(R)`` for equal weights.
    """
    w = weights.reshape((-1,) + (1,) * (estimates.ndim - 1))
    center = np.sum(w * estimates, axis=0)
    sum_w2 = float(np.sum(weights**2))
    spread_sq = np.sum(w * (estimates - center) ** 2, axis=0) / (1.0 - sum_w2)
    import scipy.stats  # deferred: heavy import, needed only for the interval

    quantile = scipy.stats.t.ppf(0.5 + ci_level / 2.0, df=estimates.shape[0] - 1)
    return center, quantile * np.sqrt(sum_w2 * spread_sq)


def _scalar_or_array(value):
    value = np.asarray(value, dtype=np.float64)
    return float(value) if value.ndim == 0 else value


def error_moments(err, ci_level: float = 0.95, n_batches: int = 20) -> dict:
    """Mean, standard deviation (with a batch-means interval) and peak of an error signal.

    Parameters
    ----------
    err : array_like, shape (N,) or (N, k)
        Error samples (measured - true) in time order; columns are coordinates. Must be
        finite: discard filter start-up transients and gaps before calling.
    ci_level : float
        Confidence level of ``std_ci`` in (0, 1).
    n_batches : int
        Number ``B >= 2`` of non-overlapping, contiguous batches for ``std_ci``; each must
        hold at least 2 samples and should be much longer than the error's correlation time.

    Returns
    -------
    dict
        ``mean``, ``std`` (``ddof=1``), ``std_ci`` = ``(lo, hi)``, ``max_abs`` (``max |err|``),
        ``n`` (N) and, for 2-D input only, ``cov`` (``(k, k)``, ``ddof=1``). Floats for 1-D
        input, arrays of shape ``(k,)`` for 2-D input.

    Notes
    -----
    Batch ``b`` (``np.array_split`` of the N samples into B nearly equal parts) gives
    ``v_b = mean over the batch of (err - mean(err))^2``; deviations are taken from the global
    mean so that a slowly drifting mean counts as spread, as it does in ``std``. If the batches
    are long compared with the correlation time, the ``v_b`` are nearly independent with a
    common mean, and the interval for the variance is
    ``std^2 +- t_{(1+ci_level)/2, B-1} s_v / sqrt(B)`` (``s_v`` the standard deviation of the
    ``v_b``); ``std_ci`` is its square root, the lower end clipped at 0. The interval is
    centred on ``std^2`` (which differs from ``mean(v_b)`` by ``O(1/N)``) so that it always
    contains the point estimate. With B = 20 the interval's own width is uncertain by about
    ``1/sqrt(2 (B - 1)) ~ 16 %``, the price of not assuming a correlation model.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> out = error_moments(rng.uniform(-0.5e-3, 0.5e-3, 100_000))
    >>> round(out["std"] / (1e-3 / 12**0.5), 2)
    1.0
    """
    ci_level = _check_level(ci_level)
    if not isinstance(n_batches, numbers.Integral) or isinstance(n_batches, bool) or n_batches < 2:
        raise ValueError(f"n_batches must be an integer >= 2, got n_batches={n_batches!r}")
    err = np.asarray(err)
    if not (np.issubdtype(err.dtype, np.floating) or np.issubdtype(err.dtype, np.integer)):
        raise ValueError(f"err must be a real numeric array, got dtype {err.dtype}")
    err = err.astype(np.float64, copy=False)
    if err.ndim not in (1, 2):
        raise ValueError(f"err must have shape (N,) or (N, k), got {err.shape}")
    n_samples = err.shape[0]
    if n_samples < 2 * n_batches:
        raise ValueError(
            f"err has {n_samples} samples, fewer than 2 per batch for n_batches={n_batches}"
        )
    bad = np.flatnonzero(~np.all(np.isfinite(err.reshape(n_samples, -1)), axis=1))
    if bad.size:
        raise ValueError(f"err must be finite; first non-finite sample at row {int(bad[0])}")

    mean = err.mean(axis=0)
    deviation_sq = (err - mean) ** 2
    variance = deviation_sq.sum(axis=0) / (n_samples - 1)
    batch_var = np.stack([chunk.mean(axis=0) for chunk in np.array_split(deviation_sq, n_batches)])
    _, half_width = _t_interval(batch_var, np.full(n_batches, 1.0 / n_batches), ci_level)
    lo = np.sqrt(np.maximum(variance - half_width, 0.0))
    hi = np.sqrt(variance + half_width)
    out = {
        "mean": _scalar_or_array(mean),
        "std": _scalar_or_array(np.sqrt(variance)),
        "std_ci": (_scalar_or_array(lo), _scalar_or_array(hi)),
        "max_abs": _scalar_or_array(np.max(np.abs(err), axis=0)),
        "n": int(n_samples),
    }
    if err.ndim == 2:
        centred = err - mean
        out["cov"] = centred.T @ centred / (n_samples - 1)
    return out


def pooled_std_ratio(stds, ns, reference, ci_level: float = 0.95):
    """Pool the standard deviations of independent runs and compare them with a model.

    Parameters
    ----------
    stds : array_like, shape (R,) or (R, k)
        Standard deviation of each of ``R >= 2`` independent runs (per coordinate).
    ns : array_like of int, shape (R,)
        Number of samples behind each run's standard deviation (each ``>= 2``).
    reference : float or array_like, shape (k,)
        Model standard deviation(s), ``> 0``.
    ci_level : float
        Confidence level in (0, 1).

    Returns
    -------
    ratio, lo, hi : float or ndarray of shape (k,)
        ``sqrt(pooled variance) / reference`` and its confidence interval.

    Notes
    -----
    The pooled variance is the mean of the run variances weighted by ``n_r - 1`` (the plain
    mean for equal run lengths). Its interval is a Student-t interval with ``R - 1`` degrees
    of freedom from the spread of the run variances across runs (weighted standard error,
    see ``_t_interval``); the ratio interval takes the square root of its ends (lower end
    clipped at 0). Because the runs are independent this is valid however strongly the
    samples within a run are correlated; it does not use ``n_r`` beyond the weights.
    """
    ci_level = _check_level(ci_level)
    stds = np.asarray(stds, dtype=np.float64)
    if stds.ndim not in (1, 2) or stds.shape[0] < 2:
        raise ValueError(f"stds must have shape (R,) or (R, k) with R >= 2 runs, got {stds.shape}")
    if not np.all(np.isfinite(stds)) or np.any(stds < 0):
        raise ValueError("stds must be finite and non-negative")
    ns = np.asarray(ns)
    if ns.shape != (stds.shape[0],) or not np.issubdtype(ns.dtype, np.integer) or np.any(ns < 2):
        raise ValueError(
            f"ns must be integers >= 2 of shape ({stds.shape[0]},), got {ns.tolist()!r}"
        )
    reference = np.asarray(reference, dtype=np.float64)
    if reference.shape not in ((), stds.shape[1:]) or not np.all(np.isfinite(reference)) or np.any(reference <= 0):
        raise ValueError(
            f"reference must be positive and finite with shape () or {stds.shape[1:]}, got {reference!r}"
        )
    dof = ns.astype(np.float64) - 1.0
    variance, half_width = _t_interval(stds**2, dof / dof.sum(), ci_level)
    ratio = np.sqrt(variance) / reference
    lo = np.sqrt(np.maximum(variance - half_width, 0.0)) / reference
    hi = np.sqrt(variance + half_width) / reference
    return _scalar_or_array(ratio), _scalar_or_array(lo), _scalar_or_array(hi)
