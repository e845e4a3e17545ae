"""The angle-error map of a measured channel in the forms a motor controller loads.

Two forms, both functions of the *measured* angle (what the controller reads):

- **harmonics** of the measured angle, ``e(a) = sum_k a_k cos(k a) + b_k sin(k a)`` for
  ``k = 1 .. K`` (the form of interpolating magnetic encoders' and resolvers' calibration), with
  ``K`` chosen by held-out error;
- a **lookup table** of ``N`` entries over one revolution of the measured side, at
  ``a_j = 2 pi j / N`` (``j = 0 .. N-1``), read by linear interpolation between entries and
  periodically across ``2 pi``.

Sign convention: ``error = measured - truth - offset`` (rad), the project's; the table's
``correction`` is ``-error``, so that ``true angle = measured + correction(measured)``.

Held out: time is cut into ``n_blocks`` contiguous blocks, the map is fitted on the even blocks
and scored on the odd ones and the other way round; the held-out error is the rms of the error
left on the scored blocks (both halves pooled). Each order ``0 .. max_order`` is scored so, and
the smallest held-out error wins (order 0 is no map: the error's mean alone). The table is
scored the same way, built from the harmonics fitted on the other half. ``nuisance`` columns (a
level shift found beside the map) are fitted with the map and removed with it, so the map is
not bent by them.

Every function is pure: arrays in, dicts and DataFrames out (files are written by the rule's
script).
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

__all__ = ["harmonic_columns", "harmonic_curve", "angle_map", "lookup_entries", "table_document",
           "table_frame", "ARCSEC_PER_RAD", "CONVENTION"]

#: Seconds of arc per radian.
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi

#: The angle and sign convention written into every table.
CONVENTION = ("angle: the measured channel's reading (rad), the table spans one revolution of the "
              "measured side from 0 at entry 0 in steps of 2 pi / N; error = measured - truth - "
              "offset; correction = -error; true angle = measured + correction(measured), linear "
              "interpolation between entries, periodic over 2 pi; over part of a revolution the covered "
              "entries have zero mean (covered_level_rad, the channels' zero offset there, removed)")


def harmonic_columns(angle, order: int) -> np.ndarray:
    """``[cos a, sin a, cos 2a, sin 2a, ...]`` up to ``order`` (shape (N, 2 order))."""
    a = np.asarray(angle, dtype=float)
    if order < 0:
        raise ValueError(f"order must be >= 0, got order={order!r}")
    cols = []
    for k in range(1, order + 1):
        cols += [np.cos(k * a), np.sin(k * a)]
    return np.column_stack(cols) if cols else np.zeros((a.size, 0))


def harmonic_curve(coefficients, angle) -> np.ndarray:
    """The harmonic map at ``angle`` for ``coefficients = [a1, b1, a2, b2, ...]`` (rad)."""
    c = np.asarray(coefficients, dtype=float)
    return harmonic_columns(angle, c.size // 2) @ c if c.size else np.zeros(np.size(angle))


def _interp_periodic(grid_values, angle) -> np.ndarray:
    n = grid_values.size
    x = np.mod(np.asarray(angle, dtype=float), 2.0 * np.pi) * n / (2.0 * np.pi)
    j = np.floor(x).astype(np.int64) % n
    f = x - np.floor(x)
    return (1.0 - f) * grid_values[j] + f * grid_values[(j + 1) % n]


def _fit(design, y):
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return coef


def _covered(angle, n_entries: int) -> np.ndarray:
    """Entries whose interpolation interval (either side) holds measured angles."""
    x = np.mod(np.asarray(angle, dtype=float), 2.0 * np.pi) * n_entries / (2.0 * np.pi)
    hit = np.bincount(np.floor(x).astype(np.int64) % n_entries, minlength=n_entries) > 0
    return hit | np.roll(hit, 1)


def angle_map(angle, error, *, n_entries: int = 256, max_order: int = 8, n_blocks: int = 20,
              nuisance=None, step: float | None = None) -> dict:
    """Harmonic map of the measured angle (order by held-out error) and its lookup table.

    Parameters
    ----------
    angle : array_like
        Measured angle (rad).
    error : array_like
        ``measured - truth - offset`` (rad), same length.
    n_entries : int
        Entries of the lookup table over one revolution.
    max_order : int
        Highest harmonic tried.
    n_blocks : int
        Contiguous time blocks dealt alternately to the two halves (module notes).
    nuisance : array_like, optional
        (N, m) columns fitted beside the map (a level shift's step).
    step : float, optional
        The measured channel's count (rad): errors are also given in counts.

    Returns
    -------
    dict
        ``order``, ``coefficients`` (``[a1, b1, ...]``, rad, on all samples), ``amplitudes``
        (rad per order), ``heldout_by_order`` (rms, rad), ``heldout_rms`` (the harmonics, chosen
        order), ``heldout_rms_none`` (order 0), ``heldout_rms_table`` (the table), ``insample_rms``,
        ``nuisance_coefficients``, ``n_entries``, ``entries`` (:func:`lookup_entries`),
        ``covered_fraction`` (share of the revolution the log's angles cover), ``step``.
    """
    a = np.asarray(angle, dtype=float)
    e = np.asarray(error, dtype=float)
    if a.ndim != 1 or e.shape != a.shape:
        raise ValueError(f"angle and error must be 1-D of one length, got {a.shape} and {e.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(e))):
        raise ValueError("angle and error must be finite")
    if int(n_entries) < 4:
        raise ValueError(f"n_entries must be >= 4, got n_entries={n_entries!r}")
    if int(max_order) < 0 or 2 * int(max_order) >= int(n_entries):
        raise ValueError(f"max_order must be in [0, n_entries/2), got max_order={max_order!r}")
    if int(n_blocks) < 2 or a.size < 4 * int(n_blocks):
        raise ValueError(f"need n_blocks >= 2 and at least 4 samples per block, got n_blocks={n_blocks!r} "
                         f"for {a.size} samples")
    nu = np.zeros((a.size, 0)) if nuisance is None else np.asarray(nuisance, dtype=float).reshape(a.size, -1)
    blocks = np.array_split(np.arange(a.size), int(n_blocks))
    halves = (np.concatenate(blocks[0::2]), np.concatenate(blocks[1::2]))
    base = np.column_stack([np.ones(a.size), nu])
    grid = 2.0 * np.pi * np.arange(int(n_entries)) / int(n_entries)

    def heldout(order, table=False):
        cols = harmonic_columns(a, order)
        design = np.column_stack([base, cols])
        sse = 0.0
        for fit, test in (halves, halves[::-1]):
            coef = _fit(design[fit], e[fit])
            if table:
                curve = _interp_periodic(harmonic_curve(coef[base.shape[1]:], grid), a[test])
                pred = base[test] @ coef[:base.shape[1]] + curve
            else:
                pred = design[test] @ coef
            sse += float(np.sum((e[test] - pred) ** 2))
        return math.sqrt(sse / a.size)

    by_order = [heldout(k) for k in range(int(max_order) + 1)]
    order = int(np.argmin(by_order))
    design = np.column_stack([base, harmonic_columns(a, order)])
    coef = _fit(design, e)
    harm = coef[base.shape[1]:]
    insample = math.sqrt(float(np.mean((e - design @ coef) ** 2)))
    out = {
        "order": order,
        "coefficients": [float(c) for c in harm],
        "amplitudes": [float(math.hypot(harm[2 * k], harm[2 * k + 1])) for k in range(order)],
        "heldout_by_order": by_order,
        "heldout_rms": by_order[order],
        "heldout_rms_none": by_order[0],
        "heldout_rms_table": heldout(order, table=True),
        "insample_rms": insample,
        "nuisance_coefficients": [float(c) for c in coef[1:base.shape[1]]],
        "n_entries": int(n_entries),
        "step": None if step is None else float(step),
    }
    covered = _covered(a, int(n_entries))
    out["covered_fraction"] = float(np.mean(covered))
    # Over part of a revolution the harmonics and the constant are confounded: the curve's mean
    # over the covered angles is then an offset between the two channels' zeros (the constant
    # column takes it back), not an angle error. The table holds the map less that mean, so
    # that its covered entries meet the uncovered ones (0) without a step of that size.
    level = 0.0 if covered.all() else float(np.mean(harmonic_curve(harm, grid)[covered]))
    out["covered_level"] = level
    out["entries"] = lookup_entries(harm, int(n_entries), covered=covered, level=level)
    return out


def lookup_entries(coefficients, n_entries: int, covered=None, level: float = 0.0) -> list[dict]:
    """``[{"index", "angle", "error", "correction", "covered"}]`` (rad) of the harmonic map at
    ``2 pi j / n_entries``, less ``level`` (rad); an entry outside the angles the log covered
    has correction 0 and ``covered`` False (the map says nothing there)."""
    grid = 2.0 * np.pi * np.arange(int(n_entries)) / int(n_entries)
    err = harmonic_curve(coefficients, grid) - float(level)
    cov = np.ones(grid.size, bool) if covered is None else np.asarray(covered, bool)
    err = np.where(cov, err, 0.0)
    return [{"index": j, "angle": float(grid[j]), "error": float(err[j]), "correction": float(-err[j]),
             "covered": bool(cov[j])} for j in range(grid.size)]


def _figures(rms: float, step: float | None) -> dict:
    return {"rad": float(rms), "counts": None if not step else float(rms / step),
            "arcsec": float(rms * ARCSEC_PER_RAD)}


def table_document(fit: dict, *, channel: str, log_id: str, floor: dict | None = None) -> dict:
    """The JSON a controller loads: units, convention, the entries and the held-out errors
    (rad, counts of the measured channel where it has a grid, arcseconds)."""
    step = fit.get("step")
    doc = {
        "log_id": log_id, "channel": channel, "units": {"angle": "rad", "error": "rad", "correction": "rad"},
        "convention": CONVENTION, "n_entries": fit["n_entries"], "interpolation": "linear, periodic",
        "harmonic_order": fit["order"], "harmonic_coefficients": fit["coefficients"],
        "counts_per_rev": None if not step else float(2.0 * np.pi / step),
        "heldout_error": {"table": _figures(fit["heldout_rms_table"], step),
                          "harmonics": _figures(fit["heldout_rms"], step),
                          "without_map": _figures(fit["heldout_rms_none"], step)},
        "covered_fraction": fit["covered_fraction"],
        # removed from the covered entries: the channels' zero offset over a partial turn
        "covered_level_rad": fit.get("covered_level", 0.0),
        "entries": fit["entries"],
    }
    if floor is not None:
        doc["floor"] = {"kind": floor.get("kind"), **_figures(floor.get("std", float("nan")), step)}
    return doc


def table_frame(document: dict) -> pd.DataFrame:
    """The lookup table as CSV rows: ``index, angle_rad, error_rad, correction_rad,
    correction_counts, correction_arcsec, covered``."""
    rows = document["entries"]
    cpr = document.get("counts_per_rev")
    per_count = None if not cpr else 2.0 * np.pi / cpr
    return pd.DataFrame({
        "index": [r["index"] for r in rows],
        "angle_rad": [r["angle"] for r in rows],
        "error_rad": [r["error"] for r in rows],
        "correction_rad": [r["correction"] for r in rows],
        "correction_counts": [r["correction"] / per_count if per_count else float("nan") for r in rows],
        "correction_arcsec": [r["correction"] * ARCSEC_PER_RAD for r in rows],
        "covered": [r["covered"] for r in rows],
    })
