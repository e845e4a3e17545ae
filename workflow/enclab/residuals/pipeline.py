"""Residual stage of one log: canonical log in, residual block, figures and table out.

For each measured channel that has a truth channel on the same joint, the measured readings are
compared with the exact quantizer model of that channel applied to the truth
(:mod:`enclab.residuals.diagnostics`), then the effect library
(:func:`enclab.residuals.select.select_effects`) looks for the effects that explain what is left,
and the residual is reported before and after them.

Settings (``config["residuals"]`` updated with the log's ``analysis.residuals``):

``offset``
    ``"fit"`` (default): the measured channel's constant offset (unknown counter zero and
    rounding convention) is fitted, see :func:`enclab.residuals.diagnostics.fit_offset`; or a
    number (rad) when the channel's zero is known.
``line_pitch_counts``
    Counts per line of the code disc (4 for quadrature decoding).
``n_bins``
    Bins over a revolution and over a line pitch.
``alpha``, ``candidates``, ``distinguish_bic``
    Passed to ``select_effects`` (significance level; effect names to consider, null = all;
    the swap-in delta BIC below which an alternative is reported as not distinguishable).
``min_effect_floor_fraction``, ``min_effect_rad``, ``heldout_blocks``, ``transient_max_fraction``
    Passed to ``select_effects``: the practical size an effect must have (a fraction of the
    exact-model floor, a size in rad), the time blocks of the held-out figures, the longest
    edge transient cropped (docs/residuals.md, "Calibrated at any length").
``aux``
    ``{library name: channel name}`` of extra channels handed to the effects (e.g.
    ``{torque: torque_back}`` for compliance against a logged torque).
``seed``
    Root seed; each channel gets ``[seed, crc32(log_id/channel)]``.
``step``
    The measured channel's grid (rad) for a float channel whose grid is not detected.
``floor_fraction``
    A floor component (quantization, noise) is present when its std is at least this fraction
    of the other's (:func:`enclab.residuals.diagnostics.estimate_floor`).
``lut_entries``, ``map_max_order``
    Entries of the lookup table over one revolution and the highest harmonic of the angle map
    (:mod:`enclab.residuals.lookup_table`).
"""
from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping

import numpy as np
import pandas as pd

__all__ = ["residual_pairs", "channel_values", "sensor_floor", "channel_angle_map", "analyse_channel",
           "before_after_table", "format_effects", "indistinguishable_label", "heldout_sentence", "verdict",
           "summary_block", "batch_rows"]

METRIC = "std of (measured - exact-model prediction) [rad]"


def residual_pairs(meta_or_entry: Mapping) -> list[dict]:
    """``[{"measured", "truth", "joint"}]``: every measured channel with a truth channel on the
    same joint (manifest order), the pairs the residual stage analyses.

    Works on canonical metadata and on manifest entries (both list ``channels`` with ``name``,
    ``role`` and ``joint``). A log whose ``analysis.residuals`` is ``false`` has none.
    """
    if (meta_or_entry.get("analysis") or {}).get("residuals", True) is False:
        return []
    chans = meta_or_entry["channels"]
    truths = {c["joint"]: c["name"] for c in chans if c.get("role") == "truth"}
    return [{"measured": c["name"], "truth": truths[c["joint"]], "joint": c["joint"]}
            for c in chans if c.get("role") == "measured" and c.get("joint") in truths]


def channel_values(df: pd.DataFrame, meta: Mapping, name: str) -> tuple[np.ndarray, float | None]:
    """SI values of a canonical channel and its step (``None`` for a float channel):
    :class:`enclab.core.canonical.Channel` ``values`` and ``step``."""
    from enclab.core.canonical import Channel

    channel = Channel.named(meta, name, df)
    return channel.values, channel.step


def _selector() -> Callable:
    from enclab.residuals.select import select_effects

    return select_effects


def _settings(settings: Mapping | None) -> dict:
    out = {"offset": "fit", "line_pitch_counts": 4, "n_bins": 24, "alpha": 0.01, "candidates": None,
           "distinguish_bic": 10.0, "aux": {}, "seed": 0, "step": None, "floor_fraction": 0.5,
           "lut_entries": 256, "map_max_order": 8,
           "min_effect_floor_fraction": 0.1, "min_effect_rad": 0.0, "heldout_blocks": 10,
           "transient_max_fraction": 0.02}
    unknown = set(settings or {}) - set(out)
    if unknown:
        raise ValueError(f"residuals settings: unknown key(s) {sorted(unknown)}; expected {sorted(out)}")
    out.update(settings or {})
    return out


def _effects_label(effects) -> str:
    return ", ".join(e.name for e in effects) if effects else ""


def _dbic(x: float) -> str:
    """A swap-in delta BIC with one decimal; a tie the optimiser left a hair below zero is 0.0."""
    return "0.0" if abs(x) < 0.05 else f"{x:.1f}"


def format_effects(effects) -> str:
    """``"backlash(w=0.01199 [0.01198, 0.012], dBIC=4.1e+04, runner-up hysteresis +312)"`` for the
    summary's effect dicts: parameters with their 90 % intervals, and the best swap-in
    alternative; an alternative the log cannot tell apart is spelled out
    (``"NOT DISTINGUISHABLE from hysteresis (swap-in dBIC 1.7 < 10)"``)."""
    out = []
    for e in effects or []:
        if e.get("merged_with"):
            # separate values of effects the motion cannot separate are not physical values
            ptp = (e.get("derived") or {}).get("joint_peak_to_peak", float("nan"))
            out.append(f"{e['name']}(merged with {'+'.join(e['merged_with'])}: joint shift {ptp:.4g} rad "
                       f"peak to peak, dBIC={e.get('delta_bic', float('nan')):.3g})")
            continue
        ci = e.get("ci") or {}
        params = ", ".join(
            f"{k}={v:.4g}" + (f" [{ci[k][0]:.4g}, {ci[k][1]:.4g}]" if k in ci and ci[k] is not None else "")
            for k, v in (e.get("params") or {}).items())
        text = f"{e['name']}({params}, dBIC={e.get('delta_bic', float('nan')):.3g}"
        alts = e.get("alternatives") or []
        close = e.get("indistinguishable_from") or []
        margin = e.get("distinguish_bic", float("nan"))
        if close:
            text += ", NOT DISTINGUISHABLE from " + " or ".join(
                f"{a['name']} (swap-in dBIC {_dbic(a['delta_bic'])} < {margin:g})" for a in close)
        elif alts:
            text += f", runner-up {alts[0]['name']} {alts[0]['delta_bic']:+.3g}"
        out.append(text + ")")
    return "; ".join(out)


def indistinguishable_label(effects) -> str:
    """``"hysteresis~backlash (dBIC 1.7)"`` for every chosen effect with alternatives the log
    cannot tell apart, ``""`` when every choice is distinguished."""
    return "; ".join(f"{e['name']}~{a['name']} (dBIC {_dbic(a['delta_bic'])})"
                     for e in effects or [] for a in e.get("indistinguishable_from") or [])


def heldout_sentence(selection: Mapping) -> str:
    """``"held out (fitted on the even and scored on the odd of 10 equal time blocks): std
    3.1e-4 rad before the effects, 2.2e-4 after"``, or ``""`` without held-out figures."""
    hb, ha = selection.get("heldout_before"), selection.get("heldout_after")
    if not hb or not ha:
        return ""
    how = (selection.get("heldout") or {}).get("how") or "held-out part of the log"
    return f"held out ({how}): std {hb['std']:.3g} rad before the effects, {ha['std']:.3g} after"


def verdict(explained, after_over_floor) -> str:
    """``"explained"`` or ``"unexplained (after/floor 18)"``."""
    if explained:
        return "explained"
    ratio = "n/a" if after_over_floor is None else f"{after_over_floor:.3g}"
    return f"unexplained (after/floor {ratio})"


# Peak memory of the residual stage per sample of a truth/measured pair: 1.41 GB for 3e6
# samples (workflow/benchmarks/bench_memory.py; the selection's context, the exact model's
# floor probabilities and the figures), rounded up.
RESIDUAL_BYTES_PER_SAMPLE = 500.0


def check_memory(n_samples: int, meta: Mapping) -> None:
    """Refuse, with one line, a log whose residual stage would need more memory than is free
    (about :data:`RESIDUAL_BYTES_PER_SAMPLE` per sample), instead of being killed by the system."""
    from enclab.core.errors import EnclabInputError
    from enclab.core.ingest import available_memory_bytes

    need, free = RESIDUAL_BYTES_PER_SAMPLE * n_samples, available_memory_bytes()
    if free is not None and need > free:
        raise EnclabInputError(
            (meta.get("source") or {}).get("file") or meta.get("log_id"),
            f"{n_samples:,} samples need about {need / 1e9:.1f} GB of memory in the residual "
            f"stage, {free / 1e9:.1f} GB are available", key="crop",
            expected="a log that fits in memory",
            hint="Crop the log (crop: t_start/t_end) or split it into several logs, each a "
            "run of its own.")


def sensor_floor(truth, measured, step, truth_step, *, declared_step=None, offset=None,
                 floor_fraction: float = 0.5, where: str = "") -> tuple[dict, float, float | None, np.ndarray]:
    """What limits the measured channel, and the grid the effect library analyses it on.

    The channel's grid is its counts step, else ``declared_step``, else the grid its values sit
    on (:func:`enclab.core.ingest.grid_step`), else none. A float truth's grid is
    found the same way (a grid coarser than the measured one is a coincidence of the motion,
    not a truth grid, and is ignored); two grids within 0.1 % of each other are one grid
    (one 1/32-unit grid written with a few digits). The floor is
    :func:`enclab.residuals.diagnostics.estimate_floor`. The analysis grid is the channel's own
    where quantization is present; where noise dominates it is the coarsest multiple of the
    channel's grid (or, without one, the step) at most a quarter of the noise std and not finer
    than the truth's grid, and the readings are rounded to it: the library's count likelihood
    then sees the noise as a jitter of four counts or more, and rounding adds at most
    ``1/192`` of the noise variance.

    Returns
    -------
    floor : dict
        :func:`~enclab.residuals.diagnostics.estimate_floor` plus ``analysis_step``.
    step : float
        The analysis grid (rad).
    truth_step : float or None
    measured : ndarray
        The readings on the analysis grid.

    Raises
    ------
    ValueError
        When the truth's grid is coarser than the measured channel's (``where`` names them).
    """
    from enclab.core.ingest import grid_step
    from enclab.residuals import diagnostics as dg

    grid = step if step is not None else (float(declared_step) if declared_step is not None else None)
    if grid is None:
        est = grid_step(measured)
        grid = est if est > 0 else None
    if truth_step is None:
        est = grid_step(truth)
        truth_step = est if est > 0 and (grid is None or est <= grid * (1.0 + 1e-3)) else None
    if grid is not None and truth_step is not None and truth_step > grid:
        if truth_step > grid * (1.0 + 1e-3):
            raise ValueError(f"{where}: the truth's grid ({truth_step:.6g} rad) is coarser than the measured "
                             f"channel's ({grid:.6g} rad); the finer channel must be the truth")
        truth_step = grid
    floor = dg.estimate_floor(truth, measured, grid, truth_step, offset=offset, noise_fraction=floor_fraction)
    noise = floor["noise_std"]
    fine = max(0.25 * noise, truth_step or 0.0)
    if grid is not None and floor["kind"] != "noise":
        step_a = grid
    elif grid is not None:
        step_a = grid * max(1.0, math.floor(fine / grid))
    else:
        spread = float(np.std(np.asarray(measured, float) - np.asarray(truth, float)))
        step_a = fine if fine > 0 else max(0.25 * spread, 1e-12)
    if step_a != grid:
        measured = step_a * np.round(np.asarray(measured, float) / step_a)
    floor["analysis_step"] = float(step_a)
    return floor, float(step_a), truth_step, np.asarray(measured, float)


def channel_angle_map(t, measured, truth, offset, res, *, step=None, n_entries=256, max_order=8) -> dict:
    """:func:`enclab.residuals.lookup_table.angle_map` of one channel: the error
    ``measured - truth - offset`` against the measured angle, beside the shift of the angle that
    the chosen effects other than angle maps make (a level shift, a compliance, a play, a
    drift: their joint shift as one column with a free coefficient), so that the map is not bent
    by them. The effects marked ``angle_map`` (harmonics, a calibration map, a scale) are what
    the table holds and are left to it."""
    from enclab.residuals import lookup_table

    nuisance = None
    fitted, ctx = getattr(res, "_fitted", None), getattr(res, "_ctx", None)
    if fitted is not None and ctx is not None:
        x = np.array(fitted.x, dtype=float)
        others = False
        for e, sl in zip(fitted.model.effects, fitted.model.slices):
            if getattr(e, "angle_map", False):
                x[sl] = e.null()
            else:
                others = True
        if others:
            mu, _ = fitted.model.forward(ctx, x)
            shift = (mu - x[0]) * ctx.step - ctx.truth
            if float(np.ptp(shift)) > 0:
                nuisance = shift[:, None]
    measured = np.asarray(measured, float)
    return lookup_table.angle_map(measured, measured - np.asarray(truth, float) - offset, n_entries=n_entries,
                                  max_order=max_order, nuisance=nuisance, step=step)


def analyse_channel(df: pd.DataFrame, meta: Mapping, pair: Mapping, settings: Mapping | None = None,
                    selector: Callable | None = None) -> tuple[dict, dict, pd.DataFrame]:
    """Residual of one measured channel against the exact model, before and after the effects.

    Parameters
    ----------
    df, meta : DataFrame, dict
        Canonical log (:func:`enclab.core.canonical.read_canonical`).
    pair : dict
        ``{"measured", "truth"}`` channel names (:func:`residual_pairs`).
    settings : dict
        See the module docstring.
    selector : callable, optional
        ``select_effects`` of the effect library (default); tests may pass another with the
        same signature.

    Returns
    -------
    block : dict
        ``residuals.json``: channel names, steps, offset, the diagnostics before and after,
        the selection (``to_summary()`` plus ``explained`` and ``message``).
    figures : dict
        ``diagnostics``, ``before_after`` and ``covariates`` (the residual after the effects
        against its top covariates) matplotlib Figures.
    table : DataFrame
        The before/after table: one row per stage with std, mean, rms, max |r| and the floor.

    Raises
    ------
    ValueError
        When the truth channel's grid is coarser than the measured channel's, or the settings
        are unknown.
    """
    # Imported here: common.smk imports this module for residual_pairs on every DAG build.
    from enclab.residuals import diagnostics as dg
    from enclab.residuals import lookup_table, plots

    cfg = _settings(settings)
    log_id = meta.get("log_id", "?")
    check_memory(len(df), meta)
    t = df["t"].to_numpy(dtype=np.float64)
    truth, truth_step = channel_values(df, meta, pair["truth"])
    measured, step = channel_values(df, meta, pair["measured"])
    floor, step_a, truth_step, measured_a = sensor_floor(
        truth, measured, step, truth_step, declared_step=cfg["step"],
        offset=None if cfg["offset"] == "fit" else float(cfg["offset"]),
        floor_fraction=float(cfg["floor_fraction"]), where=f"log {log_id!r}: measured channel "
        f"{pair['measured']!r} against truth channel {pair['truth']!r}")
    offset = None if cfg["offset"] == "fit" else float(cfg["offset"])
    diag = dg.diagnose(t, truth, measured_a, step_a, truth_step, offset=offset,
                       line_pitch_counts=int(cfg["line_pitch_counts"]), n_bins=int(cfg["n_bins"]),
                       noise_std=floor["noise_std"])
    offset = diag["offset"]
    aux = {key: channel_values(df, meta, name)[0] for key, name in (cfg["aux"] or {}).items()}
    seed = [int(cfg["seed"]), zlib.crc32(f"{log_id}/{pair['measured']}".encode())]
    select = selector or _selector()
    # a sensor's own noise is part of the exact model, like the truth's quantization
    extra = {"noise_std": floor["noise_std"]} if floor["noise_std"] > 0 else {}
    # The offset is part of the exact model, not an effect: the library sees truth + c, so a
    # counter's unknown zero never competes with the physical candidates.
    res = select(t, truth + offset, measured_a, step_a, truth_step=truth_step, aux=aux or None,
                 seed=int(np.random.SeedSequence(seed).generate_state(1)[0]),
                 candidates=cfg["candidates"], alpha=float(cfg["alpha"]),
                 distinguish_bic=float(cfg["distinguish_bic"]),
                 line_pitch=int(cfg["line_pitch_counts"]) * step_a,
                 min_effect_floor_fraction=float(cfg["min_effect_floor_fraction"]),
                 min_effect_rad=float(cfg["min_effect_rad"]), heldout_blocks=int(cfg["heldout_blocks"]),
                 transient_max_fraction=float(cfg["transient_max_fraction"]), **extra)
    # On the log the selection ran on (its truth, aux channels and counts, so that effects
    # needing the torque or the measured counts are included), without the edge transients it
    # cropped (``res.kept``; a selector without that attribute ran on every sample).
    kept = getattr(res, "kept", slice(None))
    after_pred = np.asarray(res.model_prediction(), dtype=np.float64)
    r_after = measured_a[kept] - after_pred
    v = dg.velocity(t, truth)[kept]
    after_diag = {"residual": dg.moments(r_after), "velocity_sign": dg.velocity_sign(v, r_after)}
    selection = dict(res.to_summary())
    # Outside the catalogue: what the rest follows, ranked by held-out share of its variance
    others = {c["name"]: channel_values(df, meta, c["name"])[0][kept] for c in meta["channels"]
              if c["name"] not in (pair["measured"], pair["truth"])}
    covariates = dg.covariates_of(t[kept], truth[kept], others)
    ranking = dg.rank_covariates(r_after, covariates)
    message = str(res.message)
    outside = None
    if not res.explained:
        outside = dg.covariate_sentence(ranking)
        message = f"{message}; {outside}"
    held = heldout_sentence(selection)
    if held:
        message = f"{message}; {held}"
    selection.update(explained=bool(res.explained), message=message, covariates=ranking,
                     outside_catalogue=outside)
    amap = channel_angle_map(t[kept], measured[kept], truth[kept], offset, res, step=floor["step"],
                             n_entries=int(cfg["lut_entries"]), max_order=int(cfg["map_max_order"]))
    block = {
        "log_id": log_id, "measured": pair["measured"], "truth": pair["truth"],
        "step": step_a, "truth_step": truth_step, "offset": offset,
        "offset_steps": offset / step_a,
        "floor_kind": floor["kind"], "floor": floor,
        "angle_map": {k: v for k, v in amap.items() if k != "entries"},
        "lookup_table": lookup_table.table_document(amap, channel=pair["measured"], log_id=log_id, floor=floor),
        "convention": "residual = measured - q(truth + offset), q rounds to the measured grid; "
                      "error = measured - truth - offset; rad",
        "before": dg.scalar_summary(diag),
        "after": after_diag,
        "selection": selection,
    }
    title = f"{log_id}: {pair['measured']} vs {pair['truth']}"
    figures = {
        "diagnostics": plots.diagnostics_figure(t, truth, diag, step_a, title=title),
        "before_after": plots.before_after_figure(t[kept], truth[kept], measured_a[kept],
                                                  np.asarray(diag["prediction"])[kept], after_pred,
                                                  step_a, title=title,
                                                  effects_label=_effects_label(res.effects)),
        "covariates": plots.covariates_figure(r_after, covariates, ranking, step_a, title=title),
    }
    table = before_after_table(log_id, pair, step_a, diag, r_after, res.before, res.after,
                               selection["effects"], explained=bool(res.explained))
    return block, figures, table


def before_after_table(log_id, pair, step, diag, r_after, lib_before, lib_after, effects,
                       explained: bool | None = None) -> pd.DataFrame:
    """One row per stage (exact model, with the selected effects) of one measured channel.

    ``std``, ``mean``, ``rms``, ``max_abs`` are those of this stage's residual
    (``measured - q(truth + c)`` before, ``measured - model_prediction`` after); ``floor_std``
    and its interval are the effect library's (``SelectionResult.before/after``); ``effects``
    lists the selected effects with their 90 % intervals and alternatives (:func:`format_effects`);
    ``verdict`` (after row) is :func:`verdict` of ``explained``.
    """
    from enclab.residuals import diagnostics as dg

    rows = []
    for stage, r, lib in (("before", diag["residual"], lib_before), ("after", r_after, lib_after)):
        m = dg.moments(r)
        floor = lib.get("floor_std", diag["floor"]["residual_std"])
        ci = lib.get("floor_ci") or (None, None)
        rows.append({"log_id": log_id, "measured": pair["measured"], "truth": pair["truth"],
                     "stage": stage, "std": m["std"], "mean": m["mean"], "rms": m["rms"],
                     "max_abs": m["max_abs"], "std_steps": m["std"] / step, "floor_std": floor,
                     "floor_ci_lo": ci[0], "floor_ci_hi": ci[1],
                     "std_over_floor": m["std"] / floor if floor else None,
                     "verdict": verdict(explained, m["std"] / floor if floor else None)
                     if stage == "after" and explained is not None else "",
                     "effects": format_effects(effects) if stage == "after" else ""})
    return pd.DataFrame(rows)


def summary_block(blocks: list[Mapping]) -> dict | None:
    """The ``residuals`` block of summary.json from the channel blocks of one log.

    The contract keys (``metric``, ``before``, ``after``, ``effects``: docs/output-contract.md)
    are those of the first measured channel (manifest order); every channel's block is under
    ``channels``.
    """
    if not blocks:
        return None
    per = {}
    for b in blocks:
        sel = dict(b["selection"])
        sel.update(measured=b["measured"], truth=b["truth"], step=b["step"],
                   truth_step=b["truth_step"], offset=b["offset"])
        if "floor_kind" in b:
            sel.update(floor_kind=b["floor_kind"], floor=b.get("floor"), angle_map=b.get("angle_map"),
                       lookup_table=(b.get("lookup_table") or {}).get("files"))
        sel.setdefault("metric", METRIC)
        per[b["measured"]] = sel
    first = per[blocks[0]["measured"]]
    return {**first, "channels": per}


def batch_rows(summary: Mapping) -> list[dict]:
    """Rows of ``results/batch/residuals.csv`` from one summary.json (one per measured channel)."""
    block = summary.get("residuals")
    if not block:
        return []
    rows = []
    for name, sel in block["channels"].items():
        before, after = sel.get("before") or {}, sel.get("after") or {}
        effects = sel.get("effects") or []
        floor = after.get("floor_std", before.get("floor_std"))
        ratio = (after.get("std") / floor) if floor and after.get("std") is not None else None
        rows.append({
            "log_id": summary["log_id"], "measured": name, "truth": sel.get("truth"),
            "step": sel.get("step"), "truth_step": sel.get("truth_step"), "offset": sel.get("offset"),
            "floor_kind": sel.get("floor_kind"),
            "map_order": (sel.get("angle_map") or {}).get("order"),
            "map_heldout_rms": (sel.get("angle_map") or {}).get("heldout_rms_table"),
            "before_std": before.get("std"), "after_std": after.get("std"), "floor_std": floor,
            # the same model refitted on the even time blocks and scored on the odd ones
            "heldout_before_std": (sel.get("heldout_before") or {}).get("std"),
            "heldout_after_std": (sel.get("heldout_after") or {}).get("std"),
            "transients": "; ".join(f"{tr['edge']} {tr['t_start']:.6g}-{tr['t_end']:.6g} s"
                                    for tr in sel.get("transients") or []),
            "after_over_floor": ratio,
            "explained": sel.get("explained"),
            "verdict": verdict(sel.get("explained"), ratio),
            "effects": format_effects(effects),
            "indistinguishable": indistinguishable_label(effects),
            # what the rest follows when unexplained (held-out covariate ranking, in words)
            "outside_catalogue": sel.get("outside_catalogue") or "",
            "message": sel.get("message"),
        })
    return rows
