"""The rig report: held-out tables per split and condition, the map and compliance curves with
their bands, and what remains at reversals.

From the result of :func:`enclab.rig.pipeline.analyse_rig` (one rig, one measured channel):
:func:`map_figure`, :func:`compliance_figure`, :func:`heldout_figure` and :func:`remains_figure`
return Figures (the caller saves them); :func:`markdown` the report text; :func:`fit_block` the
JSON block of a fit.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from enclab.rig import fit as rg
from enclab.residuals.calibration import compliance_curve, compliance_names

__all__ = ["remains", "map_figure", "compliance_figure", "heldout_figure", "remains_figure",
           "markdown", "condition_table", "split_table", "extrapolation_lines", "coverage_text",
           "fit_block"]

MRAD = 1e3
#: Largest relative change of a shared parameter between folds for it to count as pinned down.
SPREAD = 0.15


def remains(runs: Sequence[rg.Run], residuals: Mapping, spec: rg.RigSpec, bin_width: float = 0.002) -> dict:
    """Where the held-out residual is left, and how much of it repeats from reversal to reversal.

    ``residuals``: ``{run id: reading - prediction}`` of held-out runs. Samples after ``t_skip``
    with less than ``spec.travel`` of truth travel since the last reversal form the *reversal
    windows*. Returns their share of the residual's sum of squares, the residual std inside and
    outside them, and the *repeatable share*: the fraction of the windows' sum of squares that the
    mean over all reversals of the held-out runs (in bins of ``bin_width`` of travel, per direction)
    explains. A motion inside the play that repeats after every reversal (a mean transient) has a
    repeatable share near 1; stick-slip, steps at times that differ from one reversal to the next,
    near 0.
    """
    by_id = {r.run_id: r for r in runs}
    e_win, key_win, e_out = [], [], []
    for run_id, e in residuals.items():
        run = by_id[run_id]
        keep = run.t >= run.t[0] + spec.t_skip
        travel, direction = rg.reversal_travel(run.truth)
        win = keep & (travel < spec.travel)
        e = np.asarray(e) - np.mean(np.asarray(e)[keep])
        e_win.append(e[win])
        key_win.append(np.floor(travel[win] / bin_width).astype(int) * 2 + (direction[win] > 0))
        e_out.append(e[keep & ~win])
    if not e_win:
        return {}
    ew, kw, eo = np.concatenate(e_win), np.concatenate(key_win), np.concatenate(e_out)
    ss_w, ss_o = float(ew @ ew), float(eo @ eo)
    _, inv, counts = np.unique(kw, return_inverse=True, return_counts=True)
    means = np.bincount(inv, weights=ew) / counts
    within = ew - means[inv]
    return {"window_share": ss_w / (ss_w + ss_o), "window_std": float(np.sqrt(ss_w / ew.size)),
            "outside_std": float(np.sqrt(ss_o / eo.size)), "window_fraction": ew.size / (ew.size + eo.size),
            "repeatable_share": 1.0 - float(within @ within) / ss_w if ss_w else float("nan"),
            "n_window": int(ew.size), "n_outside": int(eo.size)}


def split_table(rows: Sequence[Mapping]) -> pd.DataFrame:
    """Held-out residual std per split (test runs pooled): before (offset only) and after, steady
    strokes and all samples (rad), with the quantization floor."""
    out = []
    df = pd.DataFrame(rows)
    for split, sel in df[df["role"] == "test"].groupby("split", sort=False):
        after = rg.pooled(sel.to_dict("records"))
        b_st = np.sqrt(np.sum(sel["before_steady_std"] ** 2 * sel["n_steady"]) / sel["n_steady"].sum())
        b_all = np.sqrt(np.sum(sel["before_all_std"] ** 2 * sel["n_all"]) / sel["n_all"].sum())
        out.append({"split": split, "test_runs": len(sel), "before_steady": b_st, "before_all": b_all,
                    "after_steady": after["steady_std"], "after_all": after["all_std"],
                    "floor": float(sel["floor_std"].iloc[0])})
    return pd.DataFrame(out)


def condition_table(rows: Sequence[Mapping], conditions: Sequence[str]) -> pd.DataFrame:
    """Held-out residual std per split and value of each condition (test runs pooled)."""
    df = pd.DataFrame(rows)
    df = df[df["role"] == "test"]
    out = []
    for split, sel in df.groupby("split", sort=False):
        for cond in conditions:
            if cond not in sel:
                continue
            for value, grp in sel.groupby(cond):
                p = rg.pooled(grp.to_dict("records"))
                out.append({"split": split, "condition": cond, "value": value, "runs": len(grp),
                            "before_steady": float(np.sqrt(np.mean(grp["before_steady_std"] ** 2))),
                            "before_all": float(np.sqrt(np.mean(grp["before_all_std"] ** 2))),
                            "after_steady": p["steady_std"], "after_all": p["all_std"]})
    return pd.DataFrame(out)


def _grid(fit: rg.RigFit, n: int = 400) -> np.ndarray:
    return np.linspace(fit.basis.lo, fit.basis.hi, n)


def map_figure(result: Mapping, title: str = "") -> Figure:
    """The calibration map of the fit on all runs with its 90 % band, the scale's line over
    the reference range, and each fold's map (thin); with an input-side map, a second panel of
    it over one input revolution."""
    fit = result["final"]
    fig = Figure(figsize=(7.5, 4.2), layout="constrained")
    if fit.spec.input_harmonics:
        ax, ax_in = fig.subplots(1, 2, width_ratios=[2, 1])
        phi = np.linspace(0, 2 * np.pi, 200)
        c, lo_in, hi_in = fit.input_curve(phi)
        ax_in.fill_between(phi, lo_in * MRAD, hi_in * MRAD, color="C2", alpha=0.3, lw=0, label="90 % band")
        ax_in.plot(phi, c * MRAD, color="C2", lw=1.5, label=f"{fit.spec.input_harmonics} harmonics")
        ax_in.set_xlabel("input-side angle (rad, one revolution)")
        ax_in.set_ylabel("input-side map (mrad, measured side)")
        ax_in.set_title(f"input side, gear ratio {fit.spec.gear_ratio:g}", fontsize=9)
        ax_in.legend(fontsize=7)
    else:
        ax = fig.add_subplot()
    if fit.basis is None:
        ax.text(0.5, 0.5, "no calibration map in this model", ha="center", transform=ax.transAxes)
        return fig
    a = _grid(fit)
    curve, lo, hi = fit.map_curve(a)
    ax.fill_between(a, lo * MRAD, hi * MRAD, color="C0", alpha=0.3, lw=0, label="90 % band (jackknife over runs)")
    ax.plot(a, curve * MRAD, color="C0", lw=1.5, label=f"map, knots every {fit.basis.spacing:g} rad")
    for f in result["folds"]:
        if f["fit"].basis is not None:
            ax.plot(a, f["fit"].map_curve(a)[0] * MRAD, lw=0.6, alpha=0.7, label=f"fold {f['split']}: {f['fold']}")
    ax.axvspan(*fit.basis.ref, color="0.92", zorder=0, label="reference range of the scale")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("measured-side angle (rad)")
    ax.set_ylabel("map (mrad)")
    scale = fit.shared().get("scale")
    ax.set_title((title + "\n" if title else "") + "calibration map: reading - angle, after offset and scale"
                 + (f" (scale {scale:+.4g})" if scale is not None else ""), fontsize=9)
    ax.legend(fontsize=7, loc="best")
    return fig


def _tmap_form(v) -> str:
    """A torque map's form in words: beyond its range, along its end slopes or a bounded take-up."""
    if len(v) > 3 and v[3] == "flat":
        return "bounded take-up beside the stiffness"
    return "continued along its end slopes"


def term_label(name: str, spec: rg.RigSpec) -> str:
    """``T``, ``T|T|`` or ``tanh(T/T0)`` of a compliance coefficient's name."""
    channel, _, term = name.partition(":")
    if term == "saturating":
        return f"tanh(T/{spec.torque_scales[channel]:.3g} N m)"
    return "T|T|" if term == "signed_square" else "T"


def _channel_curve(fit: rg.RigFit, channel: str, T: np.ndarray) -> np.ndarray:
    names = compliance_names(fit.spec.compliance)
    coef = [fit.coef[fit.names.index(n)] for n in names]
    return (compliance_curve(coef, fit.spec.compliance, channel, T, fit.spec.torque_scales)
            + fit.torque_map_curve(channel, T))


def compliance_figure(result: Mapping, torques: Mapping, title: str = "") -> Figure:
    """Twist of the measured side against each torque channel (the channel's terms alone), fit
    on all runs with a 90 % jackknife band, over the logged torque range; each fold thin."""
    fit = result["final"]
    spec = fit.spec.compliance
    channels = list(spec)
    fig = Figure(figsize=(4.0 * max(len(channels), 1), 3.6), layout="constrained")
    if not channels:
        fig.add_subplot().text(0.5, 0.5, "no compliance in this model", ha="center")
        return fig
    names = compliance_names(spec)
    idx = {n: fit.names.index(n) for n in names}
    for k, ch in enumerate(channels):
        ax = fig.add_subplot(1, len(channels), k + 1)
        lo, hi = torques[ch]
        T = np.linspace(lo, hi, 200)
        curve = _channel_curve(fit, ch, T)
        if fit.cov is not None:
            cols = [n for n in names if n.startswith(ch + ":")]
            J = np.column_stack([compliance_curve([1.0 if m == n else 0.0 for m in names], spec, ch, T,
                                                  fit.spec.torque_scales) for n in cols])
            ii = [idx[n] for n in cols]
            if ch in fit.spec.torque_map:
                J = np.column_stack([J, rg.torque_map_basis(*fit.spec.torque_map[ch]).design(T)])
                ii += [i for i, n in enumerate(fit.names) if n.startswith(f"tmap_{ch}")]
            sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, fit.cov[np.ix_(ii, ii)], J), 0))
            ax.fill_between(T, (curve - 1.6449 * sd) * MRAD, (curve + 1.6449 * sd) * MRAD, color="C1",
                            alpha=0.3, lw=0, label="90 % band")
        ax.plot(T, curve * MRAD, color="C1", lw=1.5, label="all runs")
        for f in result["folds"]:
            if ch in f["fit"].spec.compliance:
                ax.plot(T, _channel_curve(f["fit"], ch, T) * MRAD, lw=0.6, alpha=0.7, label=f"fold {f['fold']}")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(f"{ch} (N m)")
        ax.set_ylabel("twist (mrad)")
        terms = " + ".join(f"{fit.coef[idx[n]]:+.3g} {term_label(n, fit.spec)}"
                           for n in names if n.startswith(ch + ":"))
        if ch in fit.spec.torque_map:
            terms += f" + map ({fit.spec.torque_map[ch][2]} intervals, {_tmap_form(fit.spec.torque_map[ch])})"
        ax.set_title(f"{ch}: {terms} (rad, N m)", fontsize=8)
        ax.legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


def heldout_figure(result: Mapping, conditions: Sequence[str], title: str = "") -> Figure:
    """Held-out residual std per split and condition value, before and after (steady and all)."""
    table = condition_table(result["rows"], conditions)
    splits = list(dict.fromkeys(table["split"])) if len(table) else []
    fig = Figure(figsize=(4.2 * max(len(splits), 1), 3.8), layout="constrained")
    floor = float(pd.DataFrame(result["rows"])["floor_std"].iloc[0]) if result["rows"] else None
    for k, split in enumerate(splits):
        ax = fig.add_subplot(1, len(splits), k + 1)
        sel = table[table["split"] == split]
        labels = [f"{c}={v:g}" if isinstance(v, (int, float)) else f"{c}={v}" for c, v in zip(sel["condition"], sel["value"])]
        x = np.arange(len(sel))
        for j, (col, lab) in enumerate((("before_all", "before, all"), ("after_all", "after, all"),
                                         ("after_steady", "after, steady"))):
            ax.bar(x + (j - 1) * 0.27, sel[col] * MRAD, width=0.27, label=lab)
        if floor:
            ax.axhline(floor * MRAD, color="k", lw=0.8, ls="--", label="quantization floor")
        ax.set_yscale("log")
        ax.set_xticks(x, labels, rotation=45, ha="right", fontsize=7)
        ax.set_ylabel("held-out residual std (mrad)")
        ax.set_title(f"split: {split}", fontsize=9)
        ax.legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


def remains_figure(result: Mapping, runs: Sequence[rg.Run], title: str = "") -> Figure:
    """Held-out residual against the truth's travel since the last reversal (first split's test
    runs): where what remains sits."""
    fig = Figure(figsize=(7.5, 3.8), layout="constrained")
    ax = fig.add_subplot()
    spec = result["spec"]
    by_id = {r.run_id: r for r in runs}
    folds = result["folds"]
    if not folds:
        return fig
    first = folds[0]["split"]
    for run_id, e in ((k, v) for f in folds if f["split"] == first for k, v in f["residuals"].items()):
        run = by_id[run_id]
        travel, direction = rg.reversal_travel(run.truth)
        keep = (run.t >= run.t[0] + spec.t_skip) & (travel < 3 * spec.travel)
        ax.plot(travel[keep] * direction[keep], (e[keep] - np.mean(e)) * MRAD, ",", alpha=0.3)
    ax.axvline(spec.travel, color="k", lw=0.6, ls="--")
    ax.axvline(-spec.travel, color="k", lw=0.6, ls="--", label=f"steady beyond {spec.travel:g} rad")
    ax.set_xlabel("truth travel since the last reversal x direction (rad)")
    ax.set_ylabel("held-out residual (mrad)")
    ax.set_title((title + "\n" if title else "") + f"what remains (split {first}, held-out runs)", fontsize=9)
    ax.legend(fontsize=7)
    return fig


def markdown(name: str, channel: str, result: Mapping, conditions: Sequence[str],
             truth_counts_per_rev: float | None = None) -> str:
    """The rig report in words and tables."""
    fit = result["final"]
    lines = [f"# Rig {name}: {channel}", ""]
    n = len(fit.train_ids)
    per_run = "offset, play width" + (", latency" if fit.spec.latency is True else "")
    lines += [f"{n} runs fitted together. Per run: {per_run}. Shared by the rig: "
              + ", ".join(x for x in (["scale"] if fit.spec.scale else [])
                          + (["latency"] if fit.spec.latency == "shared" else [])
                          + ([f"calibration map (knots every {fit.spec.spacing:g} rad, chosen on "
                              "held-out runs)"] if fit.spec.spacing else [])
                          + (["compliance " + ", ".join(f"{n.split(':')[0]} {term_label(n, fit.spec)}"
                                                         for n in compliance_names(fit.spec.compliance))]
                             if fit.spec.compliance else [])
                          + [f"torque map of {c} ({v[2]} intervals over {v[0]:.3g} .. {v[1]:.3g} N m, "
                             f"{_tmap_form(v)}, chosen "
                             "on held-out runs)" for c, v in fit.spec.torque_map.items()]
                          + ([f"reversal transient (knots every {fit.spec.transient:g} rad)"] if fit.spec.transient else [])
                          + ([(f"input-side map ({fit.spec.input_harmonics} harmonics per input revolution, "
                               f"gear ratio {fit.spec.gear_ratio:g})")] if fit.spec.input_harmonics else []))
              + ".", ""]
    forms = [f for f in result["folds"] if f.get("variant_scores")]
    if forms:
        lines += ["Model form per fold, chosen on the steady strokes of its training runs (groups of them "
                  "held out in turn): " + "; ".join(
                      f"{f['fold']}: " + ", ".join([f"{n.split(':')[0]} {term_label(n, f['fit'].spec)}"
                                                   for n in compliance_names(f["fit"].spec.compliance)]
                                                  + [f"{c} left out" for c in result["spec"].compliance
                                                     if c not in f["fit"].spec.compliance])
                      + (f", reversal transient (knots every {f['fit'].spec.transient:g} rad)"
                         if f["fit"].spec.transient else ", no reversal transient") for f in forms) + ".", ""]
    lines += ["## Held out", "", "Residual std (mrad) of reading - prediction on runs the shared terms never "
              f"saw (their own {per_run} refitted): *steady* = strokes with more than "
              f"{fit.spec.travel:g} rad of truth travel since the last reversal, *all* = every sample after "
              f"{fit.spec.t_skip:g} s. *before* = the offset alone.", ""]
    st = split_table(result["rows"])
    if len(st):
        lines.append((st.set_index("split")[["test_runs", "before_steady", "before_all", "after_steady",
                                             "after_all", "floor"]]
                      .assign(**{c: lambda d, c=c: d[c] * MRAD for c in ("before_steady", "before_all",
                                                                          "after_steady", "after_all", "floor")})
                      .to_markdown(floatfmt=".3f")))
        lines += ["", "Per condition (test runs):", ""]
        ct = condition_table(result["rows"], conditions)
        for c in ("before_steady", "before_all", "after_steady", "after_all"):
            ct[c] = ct[c] * MRAD
        lines.append(ct.to_markdown(index=False, floatfmt=".3f"))
    lines += extrapolation_lines(result)
    lines += ["", "## Shared parameters", "", "Fit on all runs with 90 % intervals (delete-one-run jackknife), "
              "and their spread across the folds (largest deviation from the fold mean / |mean|):", ""]
    ci = fit.ci()
    spread = result["spread"]
    prm = []
    for k, v in fit.shared().items():
        lo_hi = ci.get(k, (float("nan"), float("nan")))
        prm.append({"parameter": k, "value": v, "ci_lo": lo_hi[0], "ci_hi": lo_hi[1],
                    "fold_mean": spread.get(k, {}).get("mean"),
                    "fold_spread": spread.get(k, {}).get("rel_dev")})
    if prm:
        lines.append(pd.DataFrame(prm).to_markdown(index=False, floatfmt=".4g"))
        loose = [n for n in rg.loose_parameters(spread, SPREAD) if n in fit.shared()]
        if loose:
            left_out = [n for n in loose if spread[n]["kept_in"] < spread[n]["folds"]]
            lines += ["", f"Not pinned down: {', '.join(loose)} move by more than {SPREAD:.0%} between folds"
                      + (f" or are left out by the form some folds' training runs chose ({', '.join(left_out)})"
                         if left_out else "")
                      + "; read them as a fit of these runs, not as physical values (the folds' training runs do "
                      "not cover the same range of the covariate, and the terms trade off against each other "
                      "and the per-run play there)."]
    dropped = [c for c in result["spec"].compliance if c not in fit.spec.compliance]
    if dropped:
        kept = {c: sum(c in f["fit"].spec.compliance for f in result["folds"]) for c in dropped}
        lines += ["", "Left out: " + ", ".join(f"{c} (kept by {kept[c]} of {len(result['folds'])} folds)"
                                               for c in dropped)
                  + ": the form without it predicts held-out training runs as well (within one standard "
                  "error: one-standard-error rule) or better, so no value is reported for it."]
    if truth_counts_per_rev and "scale" in fit.shared():
        s = fit.shared()["scale"]
        lines += ["", f"Scale {s:+.4g}: the truth channel reads {truth_counts_per_rev * (1 - s):,.0f} counts per "
                  f"measured-side revolution, not the declared {truth_counts_per_rev:,.0f}."]
    per = pd.DataFrame([{"run": k, **v} for k, v in fit.per_run.items()])
    if len(per):
        lines += ["", "Per run (fit on all runs): "
                  f"play width {per['play_width'].min():.4g}-{per['play_width'].max():.4g} rad"
                  + (f", latency {per['latency'].min() * 1e3:.3g}-{per['latency'].max() * 1e3:.3g} ms"
                     if fit.spec.latency is True else "") + "."]
    lines += ["", "## What remains", ""]
    for split, rem in result["remains"].items():
        if not rem:
            continue
        lines.append(
            f"- split {split}: the reversal windows (less than {fit.spec.travel:g} rad of truth travel since "
            f"the last reversal, {rem['window_fraction']:.0%} of the samples) hold {rem['window_share']:.0%} "
            f"of the held-out residual's sum of squares (std {rem['window_std'] * MRAD:.2f} mrad inside, "
            f"{rem['outside_std'] * MRAD:.2f} mrad outside). Of it, {rem['repeatable_share']:.0%} repeats from "
            "reversal to reversal (the mean over all held-out reversals at the same travel and direction); "
            f"the other {1 - rem['repeatable_share']:.0%} does not."
            + (" The repeatable part is a motion inside the play whose shape changes with the condition "
               "held out: the training runs' reversal transient does not carry over to it."
               if rem["repeatable_share"] >= 0.5 and fit.spec.transient else ""))
    excess = [r for r in result["remains"].values() if r and r["window_std"] > 1.5 * r["outside_std"]]
    if excess:
        lines += ["", "The reversal windows hold more than the steady strokes. Inside the play the measured "
                  "side is not driven by the truth side: it moves when friction and the load let it, in steps "
                  "at times that differ from one reversal to the next (stick-slip: the part that does not "
                  "repeat). A model of the reading as a "
                  "function of the truth's motion (a play operator, a reversal transient) can at best follow "
                  "the repeatable part; the rest needs a measurement of the measured side's own driving torque "
                  "at the instant it slips, or a stochastic model.", ""]
    else:
        lines += ["", "The reversal windows hold no more than the steady strokes: nothing is left at the "
                  "reversals.", ""]
    return "\n".join(lines) + "\n"


def _fmt_values(values) -> str:
    return ", ".join(f"{v:g}" if isinstance(v, (int, float)) else str(v) for v in values)


def coverage_text(cov: Mapping) -> str:
    """The conditions, torque ranges and angle range of a :func:`enclab.rig.fit.coverage`."""
    parts = [f"{k} {_fmt_values(v)}" for k, v in cov["conditions"].items()]
    parts += [f"{c} {lo:.3g} .. {hi:.3g} N m" for c, (lo, hi) in cov["torques"].items()]
    parts.append(f"measured-side angle {cov['angle'][0]:.3g} .. {cov['angle'][1]:.3g} rad")
    return "; ".join(parts)


def extrapolation_lines(result: Mapping) -> list[str]:
    """The report's section on where the fit holds: per condition split whether it extrapolates
    (and the term to blame when not), and the conditions the runs covered."""
    ext = result.get("extrapolation") or []
    lines = ["", "## Where the fit holds", ""]
    if ext:
        ratio = ext[0]["ratio"]
        lines += [f"A split does not extrapolate when its held-out std (steady strokes or all samples) exceeds "
                  f"{ratio:g}x the smallest of the other splits' or {ratio:g}x its training runs' own held-out "
                  "std (one value of the split's condition held out at a time) (`rig.extrapolation_ratio`). "
                  "Blame: each shared term refitted on the test runs alone, the others at their training "
                  "values; its share of the held-out excess (held-out sum of squares on every sample minus "
                  "that with every shared term refitted on the test runs).", ""]
        table = []
        for e in ext:
            shares = sorted(((v, t) for t, v in e["excess_share"].items() if np.isfinite(v)), reverse=True)
            table.append({"split": e["split"], "steady": e["heldout"]["steady"] * MRAD,
                          "all": e["heldout"]["all"] * MRAD,
                          "training runs held out, steady": e["inner"]["steady"] * MRAD,
                          "training runs held out, all": e["inner"]["all"] * MRAD,
                          "x others (steady/all)": f"{e['ratio_to_others']['steady']:.2f} / "
                                                   f"{e['ratio_to_others']['all']:.2f}",
                          "x training (steady/all)": f"{e['ratio_to_inner']['steady']:.2f} / "
                                                     f"{e['ratio_to_inner']['all']:.2f}",
                          "extrapolates": "yes" if e["extrapolates"] else "**no**",
                          "excess share by term": ", ".join(f"{t} {v:.0%}" for v, t in shares[:3])})
        lines.append(pd.DataFrame(table).to_markdown(index=False, floatfmt=".3f"))
        lines.append("")
        for e in ext:
            cov = e["coverage"]
            if e["extrapolates"]:
                lines.append(f"- split {e['split']}: extrapolates from its training runs ({coverage_text(cov['train'])}) "
                             f"to its test runs ({coverage_text(cov['test'])}).")
            else:
                blame = e["blame"]
                share = e["excess_share"].get(blame) if blame else None
                lines.append(
                    f"- split {e['split']}: **the fit does not extrapolate** from its training runs "
                    f"({coverage_text(cov['train'])}) to its test runs ({coverage_text(cov['test'])}): "
                    f"{e['reason']}."
                    + (f" The term to blame is {blame}: refitted on the test runs alone it removes {share:.0%} "
                       f"of the held-out excess (every shared term refitted: std "
                       f"{e['refit_all'] * MRAD:.3g} mrad on all samples); its training value does not carry over to "
                       f"{e['by']} outside the training runs' values." if blame else ""))
        lines.append("")
    cov = result.get("coverage")
    if cov:
        lines += [f"The fit on all runs was trained on: {coverage_text(cov)}. Inside these it interpolates; "
                  "beyond them its map is held at its end values, a torque map continues along its end "
                  "slopes, and no held-out run has tested it there."]
    return lines


def fit_block(fit: rg.RigFit) -> dict:
    """The JSON block of one rig fit: its settings, shared terms with 90 % intervals, per-run
    effects and, when fitted, the calibration map's curve and band on a grid."""
    block = {"spacing": fit.spec.spacing, "shared": fit.shared(),
             "compliance": dict(fit.spec.compliance), "torque_scales": dict(fit.spec.torque_scales),
             "torque_map": {c: {"lo": float(v[0]), "hi": float(v[1]), "intervals": int(v[2]),
                                "form": v[3] if len(v) > 3 else "linear"}
                            for c, v in fit.spec.torque_map.items()},
             "transient": fit.spec.transient,
             "ci90": {k: list(v) for k, v in fit.ci().items()}, "per_run": fit.per_run,
             "train": list(fit.train_ids)}
    if fit.basis is not None:
        a = _grid(fit, 101)
        curve, lo, hi = fit.map_curve(a)
        block["map"] = {"angle": a.tolist(), "curve": curve.tolist(), "band_lo": lo.tolist(),
                        "band_hi": hi.tolist(), "scale_reference_range": list(fit.basis.ref)}
    if fit.spec.input_harmonics:
        phi = np.linspace(0, 2 * np.pi, 101)
        curve, lo, hi = fit.input_curve(phi)
        block["input_map"] = {"input_angle": phi.tolist(), "curve": curve.tolist(), "band_lo": lo.tolist(),
                              "band_hi": hi.tolist(), "gear_ratio": fit.spec.gear_ratio,
                              "harmonics": fit.spec.input_harmonics}
    return block
