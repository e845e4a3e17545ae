"""Residual diagnostics of a measured encoder channel against the exact quantizer model.

Two quantities per log (``measured`` and ``truth`` in rad, the measured channel's step
``step``, the truth channel's own step ``truth_step`` or ``None`` for a continuous truth):

- the **error** ``e = measured - (truth + c)``: what quantization alone makes uniform on
  ``[-step/2, step/2)``, widened by the truth's own quantization (the convolution of
  ``U(+-step/2)`` with ``U(+-truth_step/2)`` when the two grids are independent);
- the **residual** ``r = measured - q(truth + c)`` with ``q`` the measured channel's rounding
  quantizer: zero wherever the exact model holds, except when the truth's own quantization
  moves a sample across a transition of the measured grid (the exact-model floor,
  :func:`residual_floor`). Effects the model lacks show as structure in ``r``.

``c`` is one constant (:func:`fit_offset`): a counts channel's zero and its rounding convention
(floor vs round) are unknown, so the offset that centres the error is fitted; it is reported,
and an offset is never counted as an effect.

Every function is pure: arrays in, arrays or dicts of floats out. Sign convention everywhere:
error = measured - true.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import signal as sps

from enclab.core.quantize import quantize

__all__ = [
    "fit_offset",
    "exact_prediction",
    "error_floor_std",
    "residual_floor",
    "predicted_error_pdf",
    "predicted_mass_outside",
    "moments",
    "histogram",
    "velocity",
    "binned",
    "conditioned",
    "velocity_sign",
    "spectrum",
    "diagnose",
    "scalar_summary",
    "heldout_share",
    "rank_covariates",
    "covariates_of",
    "covariate_sentence",
    "noise_std_variogram",
    "estimate_floor",
]


def _arrays(*arrays, names):
    out = [np.asarray(a, dtype=np.float64) for a in arrays]
    n = out[0].shape
    for a, name in zip(out, names):
        if a.ndim != 1:
            raise ValueError(f"{name} must be 1-D, got shape {a.shape}")
        if a.shape != n:
            raise ValueError(f"{name} has {a.size} samples, {names[0]} has {n[0]}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite; first non-finite value at index "
                             f"{int(np.flatnonzero(~np.isfinite(a))[0])}")
    return out


def _step(name, value, allow_none=False):
    if value is None and allow_none:
        return None
    if value is None or not math.isfinite(float(value)) or float(value) <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {name}={value!r}")
    return float(value)


def fit_offset(truth, measured, step: float | None = None, resolution: int = 400) -> float:
    """Constant offset ``c`` of the measured channel, so that ``measured ~ q(truth + c)``.

    First ``mean(measured - truth)``: for a rounding quantizer the error has mean zero over a
    motion that covers the grid's phase, so the mean difference estimates the channel's zero
    plus its rounding convention (a floor quantizer reads ``step/2`` low); effects symmetric in
    the direction of motion (backlash, hysteresis) leave it unchanged. The mean of a slow
    motion's error is noisy at the 1 % of a step level, and every 1 % of a step in ``c`` adds
    1 % of samples where the exact model misses a transition; so, given ``step``, ``c`` is
    refined within half a step of the mean to the value where ``q(truth + c)`` agrees with the
    most samples (the centre of the best plateau on a grid of ``step / resolution``; the one
    nearest the mean among ties).

    Parameters
    ----------
    truth, measured : array_like
        Angles (rad), 1-D of one length.
    step : float or None
        Measured channel's step; ``None`` returns the mean difference.
    resolution : int
        Grid points per step for the refinement.
    """
    truth, measured = _arrays(truth, measured, names=("truth", "measured"))
    c0 = float(np.mean(measured - truth))
    if step is None:
        return c0
    step = _step("step", step)
    # Sample i agrees with q(truth + c) for c in [lo_i, lo_i + step).
    lo = np.sort(measured - truth - step / 2)
    hi = lo + step
    grid = c0 + step * np.linspace(-0.5, 0.5, resolution + 1)
    agree = np.searchsorted(lo, grid, side="right") - np.searchsorted(hi, grid, side="right")
    best = agree == agree.max()
    if agree.max() == 0:
        return c0
    # Plateaus of the maximum: take the centre of the one nearest c0.
    idx = np.flatnonzero(best)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    centres = np.array([grid[r].mean() for r in runs])
    return float(centres[np.argmin(np.abs(centres - c0))])


def exact_prediction(truth, step: float, offset: float = 0.0) -> np.ndarray:
    """Reading of the measured channel predicted by the exact model: ``q(truth + offset)``.

    ``q`` rounds to the measured grid (multiples of ``step``), the quantizer of paper 000.
    """
    step = _step("step", step)
    (truth,) = _arrays(truth, names=("truth",))
    return step * quantize(truth + offset, step, 0.5).astype(np.float64)


def error_floor_std(step: float, truth_step: float | None = None, nested: bool = False) -> float:
    """Std of the error ``measured - truth`` when quantization is the only effect.

    Independent grids: ``sqrt((step**2 + truth_step**2) / 12)``. Nested grids (the measured
    channel re-quantized from the truth's counts, e.g. the re-quantized levels):
    ``sqrt((step**2 - truth_step**2) / 12)``.
    """
    step = _step("step", step)
    ts = _step("truth_step", truth_step, allow_none=True) or 0.0
    return math.sqrt((step**2 + (-1 if nested else 1) * ts**2) / 12.0)


def residual_floor(step: float, truth_step: float | None = None) -> dict:
    """Exact-model floor of the residual ``r = measured - q(truth)``.

    With the true angle's phase uniform on the measured grid and the truth's own rounding error
    ``u ~ U(+-truth_step/2)`` independent of it, ``r = +-step`` exactly when a transition lies
    between the true angle and the truth reading (probability ``|u| / step``) and 0 otherwise:
    ``P(r != 0) = truth_step / (4 step)``, mean 0, ``std = sqrt(step * truth_step / 4)``
    (valid for ``truth_step <= step``). A continuous truth gives a floor of 0.

    Nested grids (``step`` an integer multiple of ``truth_step``, e.g. a channel re-quantized
    from the truth) fix where the measured transitions sit in the truth's cells, so ``P(r != 0)``
    is ``|d| / step`` for their distance ``d`` from a truth cell boundary, between 0 and
    ``truth_step / (2 step)``; the value returned is its average over ``d``.

    Returns
    -------
    dict
        ``std``, ``p_nonzero``.
    """
    step = _step("step", step)
    ts = _step("truth_step", truth_step, allow_none=True) or 0.0
    if ts > step:
        raise ValueError(f"truth_step={ts!r} is coarser than step={step!r}; the truth must be the finer channel")
    return {"std": math.sqrt(step * ts / 4.0), "p_nonzero": ts / (4.0 * step)}


def predicted_error_pdf(x, step: float, truth_step: float | None = None) -> np.ndarray:
    """Density of the error under quantization alone: ``U(+-step/2)`` convolved with
    ``U(+-truth_step/2)`` (a trapezoid; the uniform itself for a continuous truth)."""
    step = _step("step", step)
    ts = _step("truth_step", truth_step, allow_none=True) or 0.0
    x = np.abs(np.asarray(x, dtype=np.float64))
    if ts == 0.0:
        return np.where(x < step / 2, 1.0 / step, np.where(x == step / 2, 0.5 / step, 0.0))
    lo, hi = abs(step - ts) / 2, (step + ts) / 2
    ramp = (hi - x) / (hi - lo) / max(step, ts)
    return np.where(x <= lo, 1.0 / max(step, ts), np.where(x < hi, ramp, 0.0))


def predicted_mass_outside(step: float, truth_step: float | None = None) -> float:
    """Probability that the error leaves ``[-step/2, step/2]`` under quantization alone:
    ``truth_step / (4 step)`` (the two triangles of the trapezoid beyond ``+-step/2``)."""
    step = _step("step", step)
    ts = _step("truth_step", truth_step, allow_none=True) or 0.0
    if ts > step:
        raise ValueError(f"truth_step={ts!r} is coarser than step={step!r}")
    return ts / (4.0 * step)


def moments(x) -> dict:
    """``mean``, ``std`` (ddof 0), ``rms``, ``max_abs`` and ``n`` of a 1-D array."""
    (x,) = _arrays(x, names=("x",))
    if x.size == 0:
        raise ValueError("x is empty")
    return {"mean": float(np.mean(x)), "std": float(np.std(x)), "rms": float(np.sqrt(np.mean(x * x))),
            "max_abs": float(np.max(np.abs(x))), "n": int(x.size)}


def histogram(error, step: float, truth_step: float | None = None, n_bins: int = 41,
              span_steps: float | None = None) -> dict:
    """Histogram of the error (density) next to the predicted density.

    ``span_steps`` is the half-width of the histogram in steps; ``None`` covers 99.9 % of the
    samples and at least 1.5 steps (at most 200).

    Returns
    -------
    dict
        ``edges``, ``density`` (empirical), ``predicted`` (mean of the predicted density over
        each bin, from its trapezoid integral), ``mass_outside`` (empirical fraction beyond
        ``+-step/2``), ``mass_outside_predicted``, ``mass_beyond_span`` (fraction outside the
        plotted range).
    """
    step = _step("step", step)
    (error,) = _arrays(error, names=("error",))
    if span_steps is None:
        span_steps = float(np.clip(np.quantile(np.abs(error), 0.999) / step + 0.5, 1.5, 200.0))
    edges = np.linspace(-span_steps * step, span_steps * step, n_bins + 1)
    counts, _ = np.histogram(error, bins=edges)
    width = np.diff(edges)
    # Bin means of the piecewise-linear density by a fine midpoint rule (exact to ~1e-6).
    fine = np.linspace(0, 1, 201)[:-1] + 0.0025
    xs = edges[:-1, None] + width[:, None] * fine[None, :]
    predicted = predicted_error_pdf(xs, step, truth_step).mean(axis=1)
    half = step / 2
    return {
        "edges": edges, "density": counts / (error.size * width), "predicted": predicted,
        "mass_outside": float(np.mean(np.abs(error) > half * (1 + 1e-9))),
        "mass_outside_predicted": predicted_mass_outside(step, truth_step),
        "mass_beyond_span": float(np.mean((error < edges[0]) | (error >= edges[-1]))),
    }


def velocity(t, theta) -> np.ndarray:
    """Velocity of ``theta`` by second-order central differences on the time stamps (rad/s)."""
    t, theta = _arrays(t, theta, names=("t", "theta"))
    if t.size < 3 or np.any(np.diff(t) <= 0):
        raise ValueError("t must hold at least 3 strictly increasing time stamps")
    return np.gradient(theta, t)


def binned(x, r, edges) -> dict:
    """Mean, std, standard error and count of ``r`` in bins of ``x`` (empty bins give NaN).

    ``sem = std / sqrt(n)`` treats the samples as independent; residuals of a slow motion are
    correlated, so read it as a lower bound.
    """
    x, r = _arrays(x, r, names=("x", "r"))
    edges = np.asarray(edges, dtype=np.float64)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    inside = (x >= edges[0]) & (x <= edges[-1])
    nb = edges.size - 1
    n = np.bincount(idx[inside], minlength=nb).astype(np.float64)
    s1 = np.bincount(idx[inside], weights=r[inside], minlength=nb)
    s2 = np.bincount(idx[inside], weights=r[inside] ** 2, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        std = np.sqrt(np.maximum(s2 / n - mean**2, 0.0))
        sem = std / np.sqrt(n)
    return {"edges": edges, "centres": 0.5 * (edges[1:] + edges[:-1]), "mean": mean, "std": std,
            "sem": sem, "n": n.astype(np.int64)}


def _quantile_edges(x, n_bins):
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([x.min() - 0.5, x.max() + 0.5])
    return edges


def velocity_sign(v, r) -> dict:
    """Mean of ``r`` while moving forward (v > 0) and backward (v < 0), and their difference
    (the signature of hysteresis, dead band and backlash)."""
    v, r = _arrays(v, r, names=("v", "r"))
    fwd, bwd = v > 0, v < 0
    out = {}
    for key, mask in (("forward", fwd), ("backward", bwd)):
        n = int(mask.sum())
        out[key] = {"mean": float(np.mean(r[mask])) if n else float("nan"),
                    "std": float(np.std(r[mask])) if n else float("nan"), "n": n}
    out["difference"] = out["forward"]["mean"] - out["backward"]["mean"]
    return out


def conditioned(t, truth, measured_counts, r, *, n_bins: int = 24, line_pitch: float,
                velocity_bins: int = 20, time_bins: int = 20) -> dict:
    """The residual conditioned on the signatures of the candidate effects.

    Parameters
    ----------
    t, truth, r : array_like
        Time (s), truth angle (rad), residual (rad).
    measured_counts : array_like of int
        The measured channel in counts (for the count-mod-4 pattern of quadrature decoding).
    n_bins : int
        Bins over a revolution and over a line pitch.
    line_pitch : float
        Angle of one line of the code disc (rad), e.g. 4 counts of a quadrature encoder.

    Returns
    -------
    dict
        ``angle_mod_2pi`` (the angle wrapped to ``[-pi, pi)``), ``angle_mod_pitch`` (in
        pitches), ``count_mod_4``, ``velocity``, ``time`` (each a :func:`binned` result) and ``velocity_sign`` (:func:`velocity_sign`).
    """
    t, truth, r = _arrays(t, truth, r, names=("t", "truth", "r"))
    line_pitch = _step("line_pitch", line_pitch)
    counts = np.asarray(measured_counts)
    if counts.shape != r.shape:
        raise ValueError(f"measured_counts has shape {counts.shape}, r has {r.shape}")
    v = velocity(t, truth)
    return {
        "angle_mod_2pi": binned(np.mod(truth + np.pi, 2 * np.pi) - np.pi, r,
                                np.linspace(-np.pi, np.pi, n_bins + 1)),
        "angle_mod_pitch": binned(np.mod(truth, line_pitch) / line_pitch, r, np.linspace(0, 1, n_bins + 1)),
        "count_mod_4": binned(np.mod(counts, 4).astype(np.float64), r, np.arange(5) - 0.5),
        "velocity": binned(v, r, _quantile_edges(v, velocity_bins)),
        "time": binned(t, r, np.linspace(t[0], t[-1], time_bins + 1)),
        "velocity_sign": velocity_sign(v, r),
    }


def spectrum(t, r, nperseg: int = 2048) -> dict:
    """One-sided Welch power spectral density of ``r`` (rad^2/Hz) at the median sample rate."""
    t, r = _arrays(t, r, names=("t", "r"))
    fs = 1.0 / float(np.median(np.diff(t)))
    f, p = sps.welch(r - r.mean(), fs=fs, nperseg=min(nperseg, r.size), detrend=False)
    return {"f_hz": f, "psd": p, "fs_hz": fs}


def diagnose(t, truth, measured, step: float, truth_step: float | None = None, *,
             offset: float | None = None, line_pitch_counts: int = 4, n_bins: int = 24,
             noise_std: float = 0.0) -> dict:
    """Every diagnostic of one measured channel against the exact quantizer model.

    Parameters
    ----------
    t, truth, measured : array_like
        Time (s), truth and measured angles (rad), 1-D of one length.
    step, truth_step : float
        Measured channel's step; the truth channel's step or ``None`` (continuous truth).
    offset : float or None
        Measured channel offset ``c``; ``None`` fits it (:func:`fit_offset`).
    line_pitch_counts : int
        Counts per line of the code disc (4 for quadrature decoding).
    noise_std : float
        The sensor's own noise (rad, :func:`estimate_floor`): it adds its variance to both
        floors (for the residual approximately: the effect library's floor is exact).

    Returns
    -------
    dict
        ``offset``, ``error`` and ``residual`` arrays, ``error_moments``, ``residual_moments``,
        ``floor`` (``error_std``, ``residual_std``, ``residual_p_nonzero``), ``histogram``,
        ``conditioned``, ``spectrum``.
    """
    t, truth, measured = _arrays(t, truth, measured, names=("t", "truth", "measured"))
    step = _step("step", step)
    if offset is None:
        offset = fit_offset(truth, measured, step)
    prediction = exact_prediction(truth, step, offset)
    error = measured - truth - offset
    residual = measured - prediction
    counts = np.rint(measured / step).astype(np.int64)
    floor = residual_floor(step, truth_step)
    return {
        "offset": float(offset),
        "prediction": prediction,
        "error": error,
        "residual": residual,
        "error_moments": moments(error),
        "residual_moments": moments(residual),
        "floor": {"error_std": math.sqrt(error_floor_std(step, truth_step) ** 2 + noise_std**2),
                  "residual_std": math.sqrt(floor["std"] ** 2 + noise_std**2),
                  "residual_p_nonzero": floor["p_nonzero"]},
        "histogram": histogram(error, step, truth_step),
        "conditioned": conditioned(t, truth, counts, residual, n_bins=n_bins,
                                   line_pitch=line_pitch_counts * step),
        "spectrum": spectrum(t, residual),
    }


def scalar_summary(diag: Mapping) -> dict:
    """The JSON-friendly numbers of a :func:`diagnose` result (no per-sample arrays)."""
    cond = diag["conditioned"]

    def spread(b):
        m = b["mean"][b["n"] > 0]
        return float(np.max(m) - np.min(m)) if m.size else float("nan")

    return {
        "offset": diag["offset"],
        "error": diag["error_moments"],
        "residual": diag["residual_moments"],
        "floor": dict(diag["floor"]),
        "mass_outside": diag["histogram"]["mass_outside"],
        "mass_outside_predicted": diag["histogram"]["mass_outside_predicted"],
        "velocity_sign": cond["velocity_sign"],
        "spread_of_bin_means": {k: spread(cond[k]) for k in
                                ("angle_mod_2pi", "angle_mod_pitch", "count_mod_4", "velocity", "time")},
    }


#: What a residual that follows each covariate points to (the words of the ranking).
COVARIATE_HINTS = {
    "time": "a slow drift or creep",
    "angle": "a repeatable error of the measured angle (a calibration map)",
    "input angle": "an error periodic or repeatable in the input-side angle (gear mesh, motor encoder)",
    "velocity": "a speed-dependent lag or friction",
    "acceleration": "inertia or a compliance driven by the acceleration torque",
    "direction": "a direction-dependent error (play, friction, hysteresis)",
}


def _smooth_fit(x, r, train, n_bins):
    """Binned means of ``r[train]`` over quantile bins of ``x[train]``, joined linearly
    (constant beyond the outer bin centres): a smooth function of ``x`` fitted on ``train``."""
    edges = _quantile_edges(x[train], n_bins)
    b = binned(x[train], r[train], edges)
    ok = b["n"] > 0
    # the mean x of each bin (not the bin centre): exact for a covariate with few values
    xs = binned(x[train], x[train], edges)["mean"][ok]
    ys = b["mean"][ok]
    order = np.argsort(xs)
    return lambda z: np.interp(z, xs[order], ys[order])


def heldout_share(x, r, *, n_blocks: int = 10, n_bins: int = 16) -> float:
    """Held-out share of the variance of ``r`` that a smooth function of ``x`` explains.

    Time is cut into ``n_blocks`` contiguous blocks; the smooth function (binned means over
    ``n_bins`` quantile bins of ``x``, joined linearly) is fitted on the even blocks and scored
    on the odd ones, and the other way round. The share is ``1 - SSE_held_out / SS``, with
    ``SS`` the held-out sum of squares about the training mean: 0 when ``x`` tells nothing
    (it can come out slightly negative; clipped at 0), 1 when ``r`` is a function of ``x``.
    Contiguous blocks keep a slowly varying residual from scoring its own neighbours.
    """
    x, r = _arrays(x, r, names=("x", "r"))
    blocks = np.array_split(np.arange(r.size), n_blocks)
    even = np.concatenate(blocks[0::2])
    odd = np.concatenate(blocks[1::2])
    sse = ss = 0.0
    for train, test in ((even, odd), (odd, even)):
        f = _smooth_fit(x, r, train, n_bins)
        sse += float(np.sum((r[test] - f(x[test])) ** 2))
        ss += float(np.sum((r[test] - np.mean(r[train])) ** 2))
    if ss <= 0:
        return 0.0
    return float(max(0.0, 1.0 - sse / ss))


def covariates_of(t, truth, aux: Mapping | None = None) -> dict:
    """The candidate covariates of a residual: time, the angle, its velocity, acceleration and
    direction of motion (from the truth), and every aux channel under its own name (an
    ``input angle`` entry is the input side of a gear)."""
    t, truth = _arrays(t, truth, names=("t", "truth"))
    v = velocity(t, truth)
    # the acceleration of a quantized angle: smooth the velocity over ~21 samples first
    k = min(21, v.size)
    vs = np.convolve(v, np.ones(k) / k, mode="same")
    out = {"time": t, "angle": truth, "velocity": vs, "acceleration": np.gradient(vs, t),
           "direction": np.sign(vs)}
    for name, arr in (aux or {}).items():
        out[str(name)] = np.asarray(arr, dtype=float)
    return out


def rank_covariates(r, covariates: Mapping, *, n_blocks: int = 10, n_bins: int = 16) -> list[dict]:
    """Covariates ranked by the held-out share of the variance of ``r`` each explains
    (:func:`heldout_share`), largest first: ``[{"name", "share", "hint"}]``. A covariate that
    is constant over the log is left out."""
    (r,) = _arrays(r, names=("r",))
    out = []
    for name, x in covariates.items():
        x = np.asarray(x, dtype=float)
        if x.shape != r.shape:
            raise ValueError(f"covariate {name!r} has shape {x.shape}, the residual {r.shape}")
        if not np.all(np.isfinite(x)) or float(np.ptp(x)) == 0.0:
            continue
        out.append({"name": str(name), "share": heldout_share(x, r, n_blocks=n_blocks, n_bins=n_bins),
                    "hint": COVARIATE_HINTS.get(str(name), f"an effect of the logged channel {name!r}")})
    out.sort(key=lambda d: -d["share"])
    return out


def covariate_sentence(ranking, min_share: float = 0.1) -> str:
    """The ranking in words: ``"the rest follows time: 81 % of its variance, a slow drift or
    creep"``, with the runners-up above ``min_share``; or that no candidate explains
    ``min_share`` of it."""
    if not ranking:
        return "no covariate to rank the rest against"
    top = ranking[0]
    if top["share"] < min_share:
        return (f"the rest follows none of {', '.join(d['name'] for d in ranking)}: the best, "
                f"{top['name']}, explains {100 * top['share']:.0f} % of its variance held out "
                "(noise-like, or driven by something not logged)")
    text = f"the rest follows {top['name']}: {100 * top['share']:.0f} % of its variance, {top['hint']}"
    more = [d for d in ranking[1:3] if d["share"] >= min_share]
    if more:
        text += "; then " + ", ".join(f"{d['name']} ({100 * d['share']:.0f} %)" for d in more)
    return text


def noise_std_variogram(x, max_lag: int = 64, plateau: float = 1.15) -> dict:
    """Std of the part of ``x`` that decorrelates within ``max_lag`` samples (a sensor's noise).

    The second-difference variogram ``g(k) = mean((x[i+k] - 2 x[i] + x[i-k])^2) / 6`` is the
    variance of a white noise at every lag, and that of a noise of correlation time ``T`` (a
    filtered sensor) once ``k >> T``; a smooth part of ``x`` (an angle error, a drift) adds
    terms growing like ``k^4`` that the second difference keeps small at short lags. ``g`` is
    evaluated at ``k = 1, 2, 4, ... <= max_lag``; the noise variance is ``g(k)`` at the first lag
    where doubling the lag changes ``g`` by less than the factor ``plateau`` (the plateau of
    a decorrelated noise), or at the lag where it changes least when none does (a lower bound
    for a noise filtered longer than ``max_lag``). Samples whose second difference exceeds
    8 times the rms are left out once (a level shift or a missed count is no noise).

    Returns
    -------
    dict
        ``std`` (rad), ``lag`` (samples), ``plateau`` (bool: the doubling criterion held).
    """
    (x,) = _arrays(x, names=("x",))
    lags = [k for k in (2 ** np.arange(12)) if 2 * int(k) < x.size // 4 and k <= max_lag]
    if not lags:
        return {"std": 0.0, "lag": 0, "plateau": False}

    def g(k):
        d = x[2 * k:] - 2.0 * x[k:-k] + x[:-2 * k]
        d2 = d * d
        rms2 = float(np.mean(d2))
        if rms2 > 0:
            d2 = d2[d2 <= 64.0 * rms2]
        return float(np.mean(d2)) / 6.0 if d2.size else 0.0

    gam = [g(int(k)) for k in lags]
    best, found = 0, False
    ratios = []
    for i in range(len(lags) - 1):
        ratio = gam[i + 1] / gam[i] if gam[i] > 0 else float("inf")
        ratios.append(abs(math.log(ratio)) if np.isfinite(ratio) and ratio > 0 else float("inf"))
        if ratio < plateau and not found:
            best, found = i, True
    if not found and ratios:
        best = int(np.argmin(ratios))
    return {"std": math.sqrt(max(gam[best], 0.0)), "lag": int(lags[best]), "plateau": bool(found)}


def estimate_floor(truth, measured, step: float | None, truth_step: float | None = None, *,
                   offset: float | None = None, noise_fraction: float = 0.5) -> dict:
    """What limits the measured channel: its quantization, its noise, or both.

    A grid is the measured channel's step ``step`` (a counts channel, a declared or detected
    grid; ``None`` when it has none). The noise is :func:`noise_std_variogram` of the error
    ``measured - truth - offset`` with the quantization's share removed: the variogram of a
    quantized channel whose noise dithers it holds ``(step^2 + truth_step^2) / 12`` besides the
    noise; a hard quantizer on a slow motion holds less (its error is a sawtooth in the angle,
    not white), so what is left is no larger than the noise. The noise is present when its std is
    above ``noise_fraction`` of the quantization's own std ``step / sqrt(12)`` (below it the
    readings are a hard quantizer's, flickering at the transitions); any noise counts on a
    channel without a grid, and a grid whose quantization std is below ``noise_fraction`` of the
    noise's leaves the kind ``noise`` (the grid is then finer than the noise resolves).

    Returns
    -------
    dict
        ``kind`` (``quantization``, ``noise`` or ``both``), ``step`` (the grid, or None),
        ``noise_std`` (rad, 0 when not present), ``noise_lag`` (samples at which the variogram
        was read), ``quantization_std`` (``step / sqrt(12)``, 0 without a grid) and ``std``
        (the floor of the error ``measured - truth``: both combined with the truth's own
        quantization).
    """
    truth, measured = _arrays(truth, measured, names=("truth", "measured"))
    step = _step("step", step, allow_none=True)
    ts = _step("truth_step", truth_step, allow_none=True) or 0.0
    if offset is None:
        offset = fit_offset(truth, measured, step)
    vg = noise_std_variogram(measured - truth - offset)
    q_var = (step**2 if step else 0.0) / 12.0
    noise_var = max(vg["std"] ** 2 - q_var - ts * ts / 12.0, 0.0)
    noise = math.sqrt(noise_var)
    if step is None:
        kind = "noise"
    elif noise <= noise_fraction * math.sqrt(q_var):
        kind, noise = "quantization", 0.0
    elif math.sqrt(q_var) < noise_fraction * noise:
        kind = "noise"
    else:
        kind = "both"
    return {"kind": kind, "step": step, "noise_std": noise, "noise_lag": vg["lag"],
            "quantization_std": math.sqrt(q_var), "std": math.sqrt(q_var + noise * noise + ts * ts / 12.0)}
