"""Dwell patterns of extreme low-resolution encoder readings (Zhang & Gao, eq. 4, Props. 1-2).

From a sampled count sequence: run lengths of constant readings, cycles of the oscillation,
per-cycle extreme readings and dwell half-widths, and the closed-form baselines (eq. 4 and
its offset companion :func:`enclab.lrde.model.dwell_a_eq`) that the Bayesian fit is
compared with.

Time resolution
---------------
Sample ``j`` stands for the cell ``[(t[j-1] + t[j]) / 2, (t[j] + t[j+1]) / 2)`` (sample-time
midpoints). Run durations, cycle boundaries and time-weighted means all use these cells, so
a run of ``L`` samples at a uniform rate ``fs`` lasts ``L / fs``. A reading change happens
somewhere between two samples and the midpoint is at most half a sample interval from it:
each end of a dwell is resolved to ``+-1/(2 fs)``, a dwell ``2w`` to ``+-1/fs`` and a
half-width ``w`` to ``+-1/(2 fs)``. Eq. (4) increases with both half-widths (for
``omega w < pi``), so evaluating it at ``w -+ 1/(2 fs)`` brackets the per-cycle stroke.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal", eq. (4), Propositions 1 and 2.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from enclab.lrde import model

__all__ = ["run_lengths", "segment_cycles", "cycle_table", "dwell_summary", "cycle_bias"]

CYCLE_COLUMNS = [
    "cycle", "i_start", "i_end", "t_start", "t_end", "period",
    "count_min", "count_max", "steps_pp", "centre_count", "symmetric", "n",
    "w1", "w2", "n_top_runs", "n_bottom_runs",
    "A12_dwell", "a_eq_dwell", "E_b_dwell",
    "mean_reading", "dc_offset", "dc_predicted", "dc_resolution", "f_hz", "step",
]


def _check_counts(counts) -> np.ndarray:
    arr = np.asarray(counts)
    if arr.ndim != 1:
        raise ValueError(f"counts must be one-dimensional, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"counts must have an integer dtype (store counts, not readings), "
                         f"got {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def _check_time(t, n: int) -> np.ndarray:
    arr = np.asarray(t, dtype=float)
    if arr.ndim != 1 or arr.size != n:
        raise ValueError(f"t must be one-dimensional with the length of counts ({n}), "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("t must be finite")
    if n > 1 and np.any(np.diff(arr) <= 0):
        bad = int(np.flatnonzero(np.diff(arr) <= 0)[0]) + 1
        raise ValueError(f"t must be strictly increasing; t[{bad}] = {arr[bad]!r} <= "
                         f"t[{bad - 1}] = {arr[bad - 1]!r}")
    return arr


def _cell_edges(t: np.ndarray) -> np.ndarray:
    """Edges of the sample cells: midpoints inside, half an interval beyond the ends."""
    if t.size == 1:
        return np.array([t[0], t[0]])
    mid = 0.5 * (t[:-1] + t[1:])
    return np.concatenate(([t[0] - (mid[0] - t[0])], mid, [t[-1] + (t[-1] - mid[-1])]))


def run_lengths(counts):
    """Runs of constant counts.

    Parameters
    ----------
    counts : array_like of int
        One-dimensional count sequence.

    Returns
    -------
    values, starts, lengths : numpy.ndarray of int64
        ``counts`` equals ``numpy.repeat(values, lengths)`` and run ``i`` occupies
        ``counts[starts[i] : starts[i] + lengths[i]]``; consecutive values differ.
    """
    c = _check_counts(counts)
    if c.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty.copy(), empty.copy()
    starts = np.concatenate(([0], np.flatnonzero(c[1:] != c[:-1]) + 1)).astype(np.int64)
    lengths = np.diff(np.concatenate((starts, [c.size]))).astype(np.int64)
    return c[starts], starts, lengths


def _hysteresis_levels(c: np.ndarray):
    """Mid level between robust extremes and the integer levels that arm and fire a crossing."""
    lo = np.quantile(c, 0.01, method="lower")
    hi = np.quantile(c, 0.99, method="higher")
    mid = 0.5 * (lo + hi)
    return int(np.floor(mid)) + 1, int(np.ceil(mid)) - 1, lo, hi


def segment_cycles(counts, t, f_hz=None):
    """Split a count sequence into cycles at upward crossings of its mid level.

    A Schmitt trigger on integer levels avoids chatter: with ``mid`` halfway between the
    1 % and 99 % quantiles of the counts, a crossing fires at the first sample reaching
    the smallest integer above ``mid`` after the counts were at or below the largest integer
    below ``mid``. The crossing time is the cell edge before that sample, so cycle ``k`` is
    the sample range ``[i_start, i_end)`` whose cells tile ``[t_start, t_end)`` exactly.
    Crossings closer than half a period to the previous kept one are dropped. Every crossing
    sample is a reading change, so no run of constant counts straddles two cycles.

    Parameters
    ----------
    counts : array_like of int
        Count sequence.
    t : array_like of float
        Sample times in s, strictly increasing.
    f_hz : float, optional
        Known motion frequency in Hz. When None it is estimated as the number of complete
        cycles over the time between the first and last kept crossing (mean period).

    Returns
    -------
    cycles : pandas.DataFrame
        One row per complete cycle: ``cycle``, ``i_start``, ``i_end`` (exclusive),
        ``t_start``, ``t_end``, ``period`` (s).
    f_hz : float
        The given frequency, or the estimate (NaN when fewer than two crossings).
    """
    c = _check_counts(counts)
    t = _check_time(t, c.size)
    if f_hz is not None and not (np.isscalar(f_hz) and np.isfinite(f_hz) and f_hz > 0):
        raise ValueError(f"f_hz must be None or a finite positive scalar (Hz), got {f_hz!r}")
    empty = pd.DataFrame({"cycle": np.zeros(0, np.int64), "i_start": np.zeros(0, np.int64),
                          "i_end": np.zeros(0, np.int64), "t_start": np.zeros(0),
                          "t_end": np.zeros(0), "period": np.zeros(0)})
    if c.size < 3:
        return empty, (float(f_hz) if f_hz is not None else float("nan"))
    high, low, lo, hi = _hysteresis_levels(c)
    if hi - lo < 1:
        return empty, (float(f_hz) if f_hz is not None else float("nan"))
    state = np.where(c >= high, 1, np.where(c <= low, -1, 0))
    last_decided = np.maximum.accumulate(np.where(state != 0, np.arange(c.size), 0))
    held = np.where(state[last_decided] != 0, state[last_decided], 0)
    crossings = np.flatnonzero((held[1:] == 1) & (held[:-1] == -1)) + 1
    edges = _cell_edges(t)
    t_cross = edges[crossings]
    if crossings.size >= 2:
        f_guess = float(f_hz) if f_hz is not None else 1.0 / float(np.median(np.diff(t_cross)))
        keep = [0]
        for i in range(1, crossings.size):
            if t_cross[i] - t_cross[keep[-1]] >= 0.5 / f_guess:
                keep.append(i)
        crossings, t_cross = crossings[keep], t_cross[keep]
    if f_hz is None:
        f_hz = ((crossings.size - 1) / (t_cross[-1] - t_cross[0])
                if crossings.size >= 2 else float("nan"))
    if crossings.size < 2:
        return empty, float(f_hz)
    cycles = pd.DataFrame({
        "cycle": np.arange(crossings.size - 1, dtype=np.int64),
        "i_start": crossings[:-1].astype(np.int64),
        "i_end": crossings[1:].astype(np.int64),
        "t_start": t_cross[:-1],
        "t_end": t_cross[1:],
    })
    cycles["period"] = cycles["t_end"] - cycles["t_start"]
    return cycles, float(f_hz)


def cycle_table(counts, t, step, f_hz=None) -> pd.DataFrame:
    """One row per complete cycle: extremes, dwell half-widths, eq. (4) and DC component.

    Parameters
    ----------
    counts : array_like of int
        Encoder counts (reading = ``step * counts``).
    t : array_like of float
        Sample times in s.
    step : float
        Encoder resolution in rad.
    f_hz : float, optional
        Motion frequency (e.g. the reference's); estimated by :func:`segment_cycles` if None.

    Returns
    -------
    pandas.DataFrame
        Columns (angles in rad, times in s):

        - ``cycle, i_start, i_end, t_start, t_end, period``: see :func:`segment_cycles`;
        - ``count_min, count_max, steps_pp`` (= max - min), ``centre_count``
          ((max + min) / 2);
        - ``symmetric``: ``steps_pp`` is even and >= 2 (``2n`` steps, as many up as down
          from ``centre_count``); ``n`` = ``steps_pp / 2`` for those, else -1;
        - ``w1, w2``: half the total time at the top / bottom reading within the cycle
          (``2w`` = run duration, to ``+-1/fs``); ``n_top_runs, n_bottom_runs`` count the
          runs at those readings (1 for a clean sinusoid; more flags chatter);
        - ``A12_dwell``: eq. (4) generalised (:func:`enclab.lrde.model.dwell_stroke`)
          with the frequency ``f_hz``; NaN unless ``symmetric``;
        - ``a_eq_dwell`` (absolute, :func:`enclab.lrde.model.dwell_a_eq`) and ``E_b_dwell``
          = ``a_eq_dwell - (centre_count + 1/2) step``, which is eq. (14)'s ``E_b`` for
          cycles centred on count 0 and its analogue relative to ``centre_count`` otherwise;
        - ``mean_reading``: time-weighted mean reading over the cycle; ``dc_offset`` =
          ``mean_reading - centre_count * step`` (the measured ``c0`` of eq. 18);
          ``dc_predicted``: the exact mean reading of a sinusoid with ``A12_dwell`` and
          ``E_b_dwell`` (eq. 20 inside Proposition 1's band); ``dc_resolution``: the bound
          ``(steps_pp + n + 1) step f / fs`` on the sampling error of ``dc_offset``
          (``2 steps_pp`` jumps each misplaced by at most ``1/(2 fs)``, plus the cycle
          window's ``+-1/fs`` slack at a reading at most ``n + 1`` steps from the centre);
        - ``f_hz`` and ``step``: the values used, repeated so that :func:`dwell_summary`
          needs only the table.
    """
    step = model._check_step(step)
    c = _check_counts(counts)
    t = _check_time(t, c.size)
    cycles, f_used = segment_cycles(c, t, f_hz)
    n_cyc = len(cycles)
    if n_cyc == 0:
        return pd.DataFrame({col: pd.Series(dtype=float) for col in CYCLE_COLUMNS})
    edges = _cell_edges(t)
    cell = np.diff(edges)
    starts_cyc = cycles["i_start"].to_numpy()
    stop = int(cycles["i_end"].iloc[-1])
    offsets = starts_cyc - starts_cyc[0]
    segment = c[starts_cyc[0]:stop]
    cmin = np.minimum.reduceat(segment, offsets)
    cmax = np.maximum.reduceat(segment, offsets)
    period = cycles["period"].to_numpy()
    mean_count = np.add.reduceat(segment * cell[starts_cyc[0]:stop], offsets) / period

    values, starts, lengths = run_lengths(c)
    inside = (starts >= starts_cyc[0]) & (starts < stop)
    values, starts, lengths = values[inside], starts[inside], lengths[inside]
    run_cycle = np.searchsorted(starts_cyc, starts, side="right") - 1
    duration = edges[starts + lengths] - edges[starts]
    top = values == cmax[run_cycle]
    bottom = values == cmin[run_cycle]
    w1 = 0.5 * np.bincount(run_cycle[top], weights=duration[top], minlength=n_cyc)
    w2 = 0.5 * np.bincount(run_cycle[bottom], weights=duration[bottom], minlength=n_cyc)
    n_top = np.bincount(run_cycle[top], minlength=n_cyc)
    n_bottom = np.bincount(run_cycle[bottom], minlength=n_cyc)

    steps_pp = cmax - cmin
    centre = 0.5 * (cmax + cmin)
    symmetric = (steps_pp >= 2) & (steps_pp % 2 == 0)
    n = np.where(symmetric, steps_pp // 2, -1)
    usable = symmetric & (w1 <= 0.5 / f_used) & (w2 <= 0.5 / f_used)
    A12 = np.full(n_cyc, np.nan)
    a_eq = np.full(n_cyc, np.nan)
    dc_pred = np.full(n_cyc, np.nan)
    if np.any(usable):
        A12[usable] = model.dwell_stroke(w1[usable], w2[usable], f_used, step,
                                         steps_pp[usable])
        # Dwells at the extremes that together last more than half a period
        # (cos(omega w1) + cos(omega w2) <= 0) fit no sinusoid: eq. (4) has no stroke there
        # (a motion that lingers at its turning points, as a servo's may).
        usable &= np.isfinite(A12) & (A12 > 0)
        A12[~usable] = np.nan
    if np.any(usable):
        a_eq[usable] = model.dwell_a_eq(w1[usable], w2[usable], f_used, step,
                                        cmax[usable], cmin[usable])
        dc_pred[usable] = model.mean_reading(A12[usable],
                                             a_eq[usable] - centre[usable] * step, step)
    fs_hz = 1.0 / float(np.median(np.diff(t)))
    table = pd.DataFrame({
        "cycle": cycles["cycle"].to_numpy(),
        "i_start": starts_cyc,
        "i_end": cycles["i_end"].to_numpy(),
        "t_start": cycles["t_start"].to_numpy(),
        "t_end": cycles["t_end"].to_numpy(),
        "period": period,
        "count_min": cmin.astype(np.int64),
        "count_max": cmax.astype(np.int64),
        "steps_pp": steps_pp.astype(np.int64),
        "centre_count": centre,
        "symmetric": symmetric,
        "n": n.astype(np.int64),
        "w1": w1,
        "w2": w2,
        "n_top_runs": n_top.astype(np.int64),
        "n_bottom_runs": n_bottom.astype(np.int64),
        "A12_dwell": A12,
        "a_eq_dwell": a_eq,
        "E_b_dwell": a_eq - (centre + 0.5) * step,
        "mean_reading": step * mean_count,
        "dc_offset": step * (mean_count - centre),
        "dc_predicted": dc_pred,
        "dc_resolution": (steps_pp + np.maximum(n, 0) + 1) * step * f_used / fs_hz,
        "f_hz": np.full(n_cyc, f_used),
        "step": np.full(n_cyc, step),
    })
    return table[CYCLE_COLUMNS]


def dwell_summary(table: pd.DataFrame) -> dict:
    """Dwell baselines over the cycles of a :func:`cycle_table`.

    The cycles used are the symmetric ones with the most common ``(n, centre_count)``.

    Returns
    -------
    dict
        - ``n_cycles``, ``n_symmetric``, ``fraction_symmetric``, ``n`` (modal),
          ``centre_count`` (modal), ``n_used``;
        - ``w1_mean, w2_mean, w1_std, w2_std`` (s);
        - ``dwell_formula_A12``: **eq. (4) evaluated at the mean half-widths** (the reported
          baseline: averaging the widths first lets the ``+-1/(2 fs)`` sampling errors of
          incommensurate cycles average out before the convex formula is applied);
          ``A12_mean_of_cycles``, ``A12_std_of_cycles``: the mean and spread of the per-cycle
          values (biased upwards by the convexity when the widths are noisy);
        - ``a_eq_dwell`` and ``E_b_dwell`` from the mean half-widths (``E_b`` relative to the
          modal centre count, i.e. eq. (14)'s ``E_b`` when that centre is 0);
        - ``prop1_epsilon_half``: ``epsilon(dwell_formula_A12) / 2``;
          ``prop1_in_band``: ``|E_b_dwell| < epsilon/2`` (must hold for readings that really
          come from a sinusoid, Proposition 1); ``prop1_fraction_cycles``: the same test
          per cycle with each cycle's own estimates;
        - ``prop2_n_tested``: cycles whose measured ``dc_offset`` and predicted DC both
          exceed ``dc_resolution``; ``prop2_sign_agreement``: the fraction of them where the
          signs agree (Proposition 2: ``c0`` has the sign of ``E_b``);
          ``prop2_sign_Eb_agreement``: fraction where ``sign(dc_offset) = sign(E_b_dwell)``.
        Values are NaN (or 0 counts) when no cycle qualifies.
    """
    required = {"symmetric", "n", "centre_count", "w1", "w2", "A12_dwell", "E_b_dwell",
                "dc_offset", "dc_predicted", "dc_resolution", "f_hz", "step"}
    missing = required - set(table.columns)
    if missing:
        raise ValueError(f"table lacks the cycle_table columns {sorted(missing)}")
    nan = float("nan")
    out = {"n_cycles": int(len(table)), "n_symmetric": int(table["symmetric"].sum()),
           "fraction_symmetric": (float(table["symmetric"].mean()) if len(table) else nan),
           "n": None, "centre_count": None, "n_used": 0,
           "w1_mean": nan, "w2_mean": nan, "w1_std": nan, "w2_std": nan,
           "dwell_formula_A12": nan, "A12_mean_of_cycles": nan, "A12_std_of_cycles": nan,
           "a_eq_dwell": nan, "E_b_dwell": nan, "prop1_epsilon_half": nan,
           "prop1_in_band": None, "prop1_fraction_cycles": nan,
           "prop2_n_tested": 0, "prop2_sign_agreement": nan, "prop2_sign_Eb_agreement": nan}
    sym = table[table["symmetric"] & np.isfinite(table["A12_dwell"])]
    if sym.empty:
        return out
    mode = sym.groupby(["n", "centre_count"]).size().idxmax()
    used = sym[(sym["n"] == mode[0]) & (sym["centre_count"] == mode[1])]
    n_mode, centre = int(mode[0]), float(mode[1])
    step = float(used["step"].iloc[0])
    f_hz = float(used["f_hz"].iloc[0])
    w1m, w2m = float(used["w1"].mean()), float(used["w2"].mean())
    cmax = np.int64(round(centre + n_mode))
    cmin = np.int64(round(centre - n_mode))
    A12 = float(model.dwell_stroke(w1m, w2m, f_hz, step, 2 * n_mode))
    a_eq = float(model.dwell_a_eq(w1m, w2m, f_hz, step, cmax, cmin))
    E_b = a_eq - (centre + 0.5) * step
    half_eps = 0.5 * float(model.epsilon(A12, step))
    cyc_half_eps = 0.5 * np.asarray(model.epsilon(used["A12_dwell"].to_numpy(), step))
    in_band_cycles = np.abs(used["E_b_dwell"].to_numpy()) < cyc_half_eps
    dc = used["dc_offset"].to_numpy()
    pred = used["dc_predicted"].to_numpy()
    res = used["dc_resolution"].to_numpy()
    tested = (np.abs(dc) > res) & (np.abs(pred) > res)
    out.update({
        "n": n_mode, "centre_count": centre, "n_used": int(len(used)),
        "w1_mean": w1m, "w2_mean": w2m,
        "w1_std": float(used["w1"].std(ddof=1)) if len(used) > 1 else nan,
        "w2_std": float(used["w2"].std(ddof=1)) if len(used) > 1 else nan,
        "dwell_formula_A12": A12,
        "A12_mean_of_cycles": float(used["A12_dwell"].mean()),
        "A12_std_of_cycles": float(used["A12_dwell"].std(ddof=1)) if len(used) > 1 else nan,
        "a_eq_dwell": a_eq, "E_b_dwell": E_b,
        "prop1_epsilon_half": half_eps,
        "prop1_in_band": bool(abs(E_b) < half_eps),
        "prop1_fraction_cycles": float(in_band_cycles.mean()),
        "prop2_n_tested": int(tested.sum()),
    })
    if tested.any():
        out["prop2_sign_agreement"] = float(np.mean(np.sign(dc[tested]) == np.sign(pred[tested])))
        eb = used["E_b_dwell"].to_numpy()[tested]
        out["prop2_sign_Eb_agreement"] = float(np.mean(np.sign(dc[tested]) == np.sign(eb)))
    return out


def cycle_bias(t, theta, f_hz) -> pd.DataFrame:
    """Per-period stroke and bias of a (near) sinusoidal true angle.

    Cuts ``theta`` into consecutive windows of one period ``1/f_hz`` from ``t[0]`` and returns
    per window ``t_mid``, ``A12 = max - min`` and ``bias = (max + min)/2`` (eq. 2 with
    ``A1 = max``, ``A2 = -min``).
    """
    f_hz = float(f_hz)
    if not np.isfinite(f_hz) or f_hz <= 0:
        raise ValueError(f"f_hz must be a finite number > 0, got {f_hz!r}")
    t = np.asarray(t, dtype=float)
    theta = np.asarray(theta, dtype=float)
    if t.shape != theta.shape or t.ndim != 1:
        raise ValueError(f"t and theta must be 1-D of equal length, got {t.shape}, {theta.shape}")
    index = np.floor((t - t[0]) * f_hz).astype(np.int64)
    n_full = int(index[-1])  # the last window may be incomplete: drop it
    keep = index < n_full
    frame = pd.DataFrame({"k": index[keep], "t": t[keep], "theta": theta[keep]})
    g = frame.groupby("k")
    hi, lo = g["theta"].max(), g["theta"].min()
    return pd.DataFrame({"t_mid": g["t"].mean().to_numpy(), "A12": (hi - lo).to_numpy(),
                         "bias": (0.5 * (hi + lo)).to_numpy()})
