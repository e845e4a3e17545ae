"""The run summary: what ran, the headline number of each analysis, what failed and why.

:func:`run_summary` condenses the per-log ``summary.json`` files, the batch tables and the
error lines of the logs that failed into one dictionary (``results/summary.json``);
:func:`summary_text` prints it at the end of ``make run`` and :func:`summary_rst` is the page
the HTML report opens on: the verdict of each analysis in one table and its headline figure
(:func:`headline_figures`) at the top, the details below. Pure functions: the rule script
``scripts/run_summary.py`` reads the files and writes the results.
"""
from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from enclab.residuals.pipeline import batch_rows as residual_rows

__all__ = ["failure_of", "headline_figures", "report_metadata", "run_summary", "summary_rst",
           "summary_text"]

_ORDER_NAMES = {0: "position", 1: "velocity", 2: "acceleration"}
_LRDE_QUANTITIES = ("A12", "E_b", "offset_a", "bias_b")
# The thumbnails rule report_thumbnails writes (results/report/thumbs/<kind>/<name>.png); the
# landing page shows them, each linking its full-size figure.
_THUMBS = "results/report/thumbs"
# Lines of each analysis in the landing page's verdict table; the rest follow below it.
_VERDICT_LINES = 3


def failure_of(log_texts: Mapping[str, str]) -> dict:
    """The stage and the one-line error of a failed log, from its rule logs.

    Parameters
    ----------
    log_texts : mapping
        ``{file name: text}`` of the log's files under ``results/<log_id>/logs/``.

    Returns
    -------
    dict
        ``stage`` (the log file's name without ``.log``, e.g. ``quantization`` or ``ingest``)
        and ``error`` (the first ``ERROR`` line, without its time stamp and log id); ``stage``
        None, and a pointer to the folder, when no log holds an error line (the log did not
        run: the run stopped before it).
    """
    for name in sorted(log_texts):
        for line in log_texts[name].splitlines():
            if " ERROR " in line:
                message = line.split(" ERROR ", 1)[1].strip()
                if message.startswith("[") and "] " in message:
                    message = message.split("] ", 1)[1]
                return {"stage": name.removesuffix(".log"), "error": message}
    return {"stage": None, "error": "no error line in its logs (results/<log_id>/logs/)"}


def _num(value) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _quantization(summaries: Sequence[Mapping], ratios: pd.DataFrame | None,
                  violations: pd.DataFrame | None) -> dict | None:
    logs = [s["log_id"] for s in summaries if s.get("quantization")]
    if not logs:
        return None
    orders = []
    if ratios is not None and not ratios.empty:
        for order, rows in ratios.groupby("order", sort=True):
            orders.append({
                "order": int(order), "name": _ORDER_NAMES.get(int(order), f"order {order}"),
                "n_rows": int(rows["n_rows"].sum()),
                "exact": [_num(rows["ratio_exact_min"].min()), _num(rows["ratio_exact_max"].max())],
                "pqn": [_num(rows["ratio_pqn_min"].min()), _num(rows["ratio_pqn_max"].max())],
            })
    return {"logs": len(logs), "ratios": orders,
            "bound_violations": None if violations is None else int(len(violations))}


def _lrde(summaries: Sequence[Mapping]) -> dict | None:
    rows = []
    for s in summaries:
        block = s.get("lrde")
        if not block:
            continue
        diag = block.get("diagnostics") or {}
        row = {"log_id": s["log_id"], "converged": diag.get("converged"),
               "rhat_max": _num(diag.get("rhat_max")), "ess_min": _num(diag.get("ess_min")),
               "reason": block.get("reason"),
               # the model the reported quantities come from (pooled: every model)
               "model": (block.get("averaged") or block.get("after") or {}).get("model")
               or (block.get("model") or {}).get("chosen"),
               "added_from_truth": ((block.get("model") or {}).get("reference") or {}).get(
                   "added") or [],
               "untrusted": {k: v.get("reason") for k, v in (block.get("trust") or {}).items()
                             if not v.get("trusted") and block.get(k) is not None}}
        for key in _LRDE_QUANTITIES:
            q = block.get(key)
            row[key] = None if q is None else {k: _num(q.get(k)) for k in ("median", "q05", "q95")}
        rows.append(row)
    return {"logs": len(rows), "rows": rows} if rows else None


def _residuals(summaries: Sequence[Mapping]) -> dict | None:
    rows = []
    for s in summaries:
        # a coarse log's block from its held-out motion-model comparison has no channels
        if "channels" not in (s.get("residuals") or {}):
            continue
        for row in residual_rows(s):
            rows.append({k: row.get(k) for k in ("log_id", "measured", "truth", "verdict", "effects",
                                                 "after_over_floor", "explained")})
    if not rows:
        return None
    return {"channels": len(rows), "explained": sum(1 for r in rows if r["explained"]),
            "rows": rows}


def _rigs(blocks: Sequence[Mapping] | None, max_spread: float = 0.15) -> dict | None:
    rows = []
    for b in blocks or []:
        splits = [{k: _num(s.get(k)) if k != "split" else s["split"]
                   for k in ("split", "before_steady", "after_steady", "after_all", "floor")}
                  for s in b.get("splits") or []]
        loose = sorted(name for name, v in (b.get("spread") or {}).items()
                       if (_num(v.get("rel_dev")) is not None and v["rel_dev"] > max_spread)
                       or (v.get("kept_in") or 0) < (v.get("folds") or 0))
        rows.append({"rig": b["rig"], "measured": b["measured"], "runs": len(b.get("runs") or []),
                     "splits": splits, "not_pinned_down": loose})
    return {"rigs": len(rows), "rows": rows} if rows else None


def _design(block: Mapping | None) -> dict | None:
    if not block:
        return None
    chosen = block.get("chosen")
    out = {"budget": [dict(b) for b in block.get("budget") or []], "chosen": None,
           "message": block.get("message")}
    if chosen:
        out["chosen"] = {"resolution": dict(chosen["resolution"]),
                         "filters": [f["label"] for f in chosen.get("filters") or []],
                         "cost": _num(chosen.get("cost")), "lag_s": _num(chosen.get("lag_s")),
                         "margin": _num(chosen.get("margin"))}
    check = block.get("check") or {}
    out["pass_rate"] = {kind: _num(check[kind]["pass_rate"])
                        for kind in ("exact_design", "table2_design") if kind in check}
    out["trajectories"] = check.get("trajectories")
    return out


def run_summary(summaries: Sequence[Mapping], log_ids: Sequence[str],
                failures: Mapping[str, Mapping], *, ratios: pd.DataFrame | None = None,
                violations: pd.DataFrame | None = None, design: Mapping | None = None,
                rigs: Sequence[Mapping] | None = None, written: Mapping[str, int] | None = None) -> dict:
    """Condense a run into what ran, the headline numbers, failures and warnings.

    Parameters
    ----------
    summaries : sequence of dict
        The ``summary.json`` of every log that completed.
    log_ids : sequence of str
        Every log of the run (completed or not).
    failures : mapping
        ``{log_id: failure_of(...)}`` of the logs that did not complete.
    ratios, violations : DataFrame, optional
        ``results/batch/ratios.csv`` and ``results/batch/bound_violations.csv``.
    design : mapping, optional
        The ``design`` block of ``results/design/design.json``.
    rigs : sequence of dict, optional
        The ``rig.json`` of every rig and measured channel (``results/rigs/<rig>/<channel>/``).
    written : mapping, optional
        Counts of the files written, by kind (``{"summaries": 70, ...}``).

    Returns
    -------
    dict
        ``logs`` {total, completed, failed}, ``analyses`` {quantization, lrde,
        residuals, rigs, design} (None for an analysis that did not run), ``completed``
        [log_id], ``failed`` [{log_id, stage, error}] (the logs with an error line),
        ``not_run`` [log_id] (neither completed nor failed: the run stopped before them),
        ``warnings`` [{log_id, warning}], ``written``.
    """
    completed = sorted(s["log_id"] for s in summaries)
    missing = sorted(set(log_ids) - set(completed))
    unknown = sorted(set(failures) - set(missing))
    if unknown:
        raise ValueError(f"failures given for logs that completed or are not in the run: {unknown}")
    reasons = {i: dict(failures.get(i) or failure_of({})) for i in missing}
    # A log with an error line failed; one without never ran (the run stopped before it).
    failed = [{"log_id": i, **r} for i, r in reasons.items() if r.get("stage")]
    not_run = [i for i, r in reasons.items() if not r.get("stage")]
    warnings = [{"log_id": s["log_id"], "warning": w}
                for s in sorted(summaries, key=lambda s: s["log_id"]) for w in s.get("warnings") or []]
    return {
        "logs": {"total": len(set(log_ids) | set(completed)), "completed": len(completed),
                 "failed": len(failed)},
        "analyses": {"quantization": _quantization(summaries, ratios, violations),
                     "lrde": _lrde(summaries), "residuals": _residuals(summaries),
                     "rigs": _rigs(rigs), "design": _design(design)},
        "completed": completed,
        "failed": failed,
        "not_run": not_run,
        "warnings": warnings,
        "written": dict(written or {}),
    }


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _angle(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value * 1e3:.4g} mrad" if abs(value) < 0.1 else f"{value:.4g} rad"


def _range(pair) -> str:
    lo, hi = pair
    return "n/a" if lo is None or hi is None else f"{lo:.3f}-{hi:.3f}"


def _headlines(run: Mapping) -> list[tuple[str, list[str]]]:
    """``(analysis, lines)`` pairs in the order the analyses are reported."""
    out = []
    q = run["analyses"].get("quantization")
    if q:
        lines = []
        for o in q["ratios"]:
            lines.append(f"{o['name']}: measured/exact std {_range(o['exact'])}, measured/PQN "
                         f"{_range(o['pqn'])} ({o['n_rows']} rows)")
        if q.get("bound_violations") is not None:
            lines.append("max|error| within the trajectory worst case in every row"
                         if q["bound_violations"] == 0 else
                         f"max|error| above the trajectory worst case in {q['bound_violations']} rows "
                         "(results/batch/bound_violations.csv)")
        out.append((f"quantization ({_count(q['logs'], 'log')})", lines))
    lrde = run["analyses"].get("lrde")
    if lrde:
        lines = []
        for r in lrde["rows"]:
            parts = []
            for key in _LRDE_QUANTITIES:
                q3 = r.get(key)
                if q3 and q3.get("median") is not None:
                    parts.append(f"{key} {_angle(q3['median'])} [{_angle(q3['q05'])}, {_angle(q3['q95'])}]")
            state = "converged" if r.get("converged") else "NOT converged"
            model = f"; model {r['model']}" if r.get("model") else ""
            if r.get("added_from_truth"):
                model += f", {' and '.join(r['added_from_truth'])} found against the truth channel"
            lines.append(f"{r['log_id']}: " + ", ".join(parts) + f" (90 %; {state}{model})")
            untrusted = r.get("untrusted") or {}
            if untrusted:
                lines.append(f"{r['log_id']}: UNTRUSTED {', '.join(sorted(untrusted))}: "
                             f"{next(iter(untrusted.values()))}")
        out.append((f"low-resolution encoder ({_count(lrde['logs'], 'log')})", lines))
    res = run["analyses"].get("residuals")
    if res:
        lines = []
        for r in res["rows"]:
            effects = r.get("effects") or "no effect needed"
            ratio = r.get("after_over_floor")
            ratio = "" if ratio is None else f", after/floor {ratio:.2f}"
            lines.append(f"{r['log_id']}/{r['measured']}: {r['verdict']}{ratio}; {effects}")
        out.append((f"residuals ({_count(res['channels'], 'channel')}, {res['explained']} explained)",
                    lines))
    rigs = run["analyses"].get("rigs")
    if rigs:
        lines = []
        for r in rigs["rows"]:
            held = "; ".join(
                f"by {x['split']}: {_angle(x['before_steady'])} -> {_angle(x['after_steady'])} "
                f"steady, {_angle(x['after_all'])} all (floor {_angle(x['floor'])})"
                for x in r["splits"])
            lines.append(f"{r['rig']}/{r['measured']} ({r['runs']} runs), held out {held}")
            if r["not_pinned_down"]:
                lines.append(f"{r['rig']}/{r['measured']}: not pinned down across folds: "
                             + ", ".join(r["not_pinned_down"]))
        out.append((f"rigs ({_count(rigs['rigs'], 'channel')})", lines))
    design = run["analyses"].get("design")
    if design:
        budget = "; ".join(_budget_text(b) for b in design["budget"])
        chosen = design["chosen"]
        if chosen is None:
            lines = [f"budget {budget}: {design.get('message') or 'no design meets it'}"]
        else:
            resolution = ", ".join(f"{k} {v}" for k, v in chosen["resolution"].items())
            lines = [f"budget {budget}",
                     f"chosen: {resolution}; {', '.join(chosen['filters']) or 'no filter'}; "
                     f"cost {chosen['cost']:g}, lag {1e3 * chosen['lag_s']:.3g} ms, "
                     f"margin {100 * chosen['margin']:.3g} %"]
        rates = design.get("pass_rate") or {}
        if rates:
            names = {"exact_design": "chosen design", "table2_design": "PQN/Table II design"}
            lines.append(f"simulated on {design.get('trajectories')} trajectories: " + ", ".join(
                f"{names[k]} within budget in {100 * v:.1f} %" for k, v in rates.items()))
        out.append(("design", lines))
    return out


def _budget_text(item: Mapping) -> str:
    order = _ORDER_NAMES.get(int(item["order"]), f"order {item['order']}")
    limits = [f"{key} <= {item[key]:g}" for key in ("std", "worst") if item.get(key) is not None]
    return f"{order} {' and '.join(limits)}"


def _written_line(run: Mapping) -> str:
    written = run.get("written") or {}
    return ", ".join(f"{n} {kind}" for kind, n in written.items())


def _not_run_count(run: Mapping) -> str:
    return f", {len(run['not_run'])} not run" if run.get("not_run") else ""


def summary_text(run: Mapping) -> str:
    """The run summary as plain text (printed at the end of ``make run``)."""
    logs = run["logs"]
    lines = [f"enclab: {_count(logs['total'], 'log')}, {logs['completed']} completed, "
             f"{logs['failed']} failed" + _not_run_count(run)]
    for title, items in _headlines(run):
        lines.append(f"  {title}")
        lines += [f"    {item}" for item in items]
    if run["warnings"]:
        lines.append(f"  warnings ({len(run['warnings'])})")
        lines += [f"    {w['log_id']}: {w['warning']}" for w in run["warnings"]]
    if run["failed"]:
        lines.append(f"  FAILED ({len(run['failed'])}; each log's messages: results/<log_id>/logs/)")
        lines += [f"    {f['log_id']} [{f['stage']}]: {f['error']}" for f in run["failed"]]
    if run.get("not_run"):
        lines.append(f"  NOT RUN ({len(run['not_run'])}; the run stopped before them: rerun)")
        lines.append(f"    {', '.join(run['not_run'])}")
    if run.get("completed"):
        lines.append(f"  completed ({len(run['completed'])}): {', '.join(run['completed'])}")
    if run.get("written"):
        lines.append(f"  written under results/: {_written_line(run)}")
    return "\n".join(lines) + "\n"


def _rst_text(text: Any) -> str:
    """Text for an rst paragraph: one line, markup characters escaped."""
    text = " ".join(str(text).split())
    for char in "\\*`_|":
        text = text.replace(char, "\\" + char)
    return text


def headline_figures(run: Mapping) -> list[dict]:
    """The figure that heads each analysis that ran, for the report's landing page.

    Parameters
    ----------
    run : mapping
        A :func:`run_summary` dictionary.

    Returns
    -------
    list of dict
        In the order the analyses are reported: ``analysis``, ``thumbnail`` (the path of the
        report thumbnail, relative to the run's folder), ``figure`` (the full-size figure,
        relative to ``results/``, where the report lies) and ``caption``. Quantization: the
        measured/predicted ratios of the batch; low-resolution encoder: the bias per cycle of
        the first log; residuals: before and after the effects of the first channel left
        unexplained (else the first channel); rigs: the first rig's held-out error; design: the
        Pareto front.
    """
    analyses = run["analyses"]
    out = []

    def add(analysis, kind, name, figure, caption):
        out.append({"analysis": analysis, "thumbnail": f"{_THUMBS}/{kind}/{name}.png",
                    "figure": figure, "caption": caption})

    if analyses.get("quantization"):
        add("quantization", "ratio_figure", "ratios", "figures/ratios.png",
            "measured std over PQN's and over the exact model's, every row of the batch")
    if analyses.get("lrde"):
        log = analyses["lrde"]["rows"][0]["log_id"]
        add("low-resolution encoder", "lrde_bias_cycles", log, f"{log}/lrde/bias_cycles.png",
            f"{log}: the bias deviation E_b of every cycle, inside Proposition 1's band")
    if analyses.get("residuals"):
        rows = analyses["residuals"]["rows"]
        row = next((r for r in rows if not r.get("explained")), rows[0])
        log, channel = row["log_id"], row["measured"]
        add("residuals", "residual_before_after", f"{log}/{channel}",
            f"{log}/residuals/{channel}/before_after.png",
            f"{log}/{channel}: the residual before and after the effects ({row['verdict']})")
    if analyses.get("rigs"):
        row = analyses["rigs"]["rows"][0]
        rig, channel = row["rig"], row["measured"]
        add("rigs", "rig_heldout", f"{rig}/{channel}", f"rigs/{rig}/{channel}/heldout.png",
            f"{rig}/{channel}: held-out error before and after the rig model")
    if analyses.get("design"):
        add("design", "design_pareto", "pareto", "design/pareto.png",
            "every feasible design by cost and lag; the chosen one")
    return out


def _verdict_table(run: Mapping) -> list[str]:
    """An rst list-table: each analysis and its first lines; failed logs last."""
    rows = []
    for title, items in _headlines(run):
        shown = [_rst_text(item) for item in items[:_VERDICT_LINES]]
        if len(items) > _VERDICT_LINES:
            shown.append(f"... {len(items) - _VERDICT_LINES} more below")
        rows.append((_rst_text(title), shown or ["(no rows)"]))
    if run["failed"]:
        rows.append(("failed", [f"{_count(len(run['failed']), 'log')}: "
                                + ", ".join(f"``{f['log_id']}``" for f in run["failed"])]))
    if not rows:
        return []
    out = [".. list-table::", "   :class: enclab-verdicts", "   :header-rows: 1",
           "   :widths: 22 78", "", "   * - analysis", "     - result"]
    for title, lines in rows:
        out.append(f"   * - **{title}**")
        out.append(f"     - - {lines[0]}")
        out += [f"       - {line}" for line in lines[1:]]
    return out + [""]


def _figure_block(run: Mapping) -> list[str]:
    """The headline figures as raw HTML, side by side (``.enclab-figures`` in report.css).

    Each image is the thumbnail next to the report (``results/report.html`` reads
    ``report/thumbs/...``); a report moved away from ``results/`` falls back to the copy
    Snakemake embeds in it (its ``results`` table, keyed by the path from the run's folder).
    Each links its full-size figure.
    """
    figures = headline_figures(run)
    if not figures:
        return []
    out = [".. raw:: html", "", '   <div class="enclab-figures">']
    for f in figures:
        local = f["thumbnail"].removeprefix("results/")
        fallback = ("this.onerror=null; var r = window.results && window.results["
                    f"'{f['thumbnail']}']; if (r) this.src = r.data_uri;")
        caption = f"<strong>{html.escape(f['analysis'])}</strong>: {html.escape(f['caption'])}"
        out += ['   <figure class="enclab-figure">',
                f'   <a href="{html.escape(f["figure"])}"><img src="{html.escape(local)}" '
                f'alt="{html.escape(f["analysis"])}" onerror="{html.escape(fallback)}"></a>',
                f"   <figcaption>{caption}</figcaption>", "   </figure>"]
    return out + ["   </div>", ""]


def summary_rst(run: Mapping) -> str:
    """The run summary as reStructuredText: the page the HTML report opens on.

    At the top what a lab would print: one line of counts, the verdict table (each analysis
    and its first lines, the failed logs) and the headline figure of each analysis
    (:func:`headline_figures`); below, every line of an analysis the table cut short, the
    failures, warnings and what was written. The report renders this page as a Jinja
    template, so it is wrapped in a raw block.
    """
    logs = run["logs"]
    out = ["{% raw %}", "enclab run summary", "==================", "",
           f"**{_count(logs['total'], 'log')}**: {logs['completed']} completed, "
           f"**{logs['failed']} failed**{_not_run_count(run)}.",
           ""]
    out += _verdict_table(run)
    out += _figure_block(run)
    # every line of the analyses the verdict table cut short
    longer = [(title, items) for title, items in _headlines(run) if len(items) > _VERDICT_LINES]
    for title, items in longer:
        out += [f"**{_rst_text(title)}**", ""]
        out += [f"- {_rst_text(item)}" for item in items] + [""]
    if run["failed"]:
        out += ["**Failed logs** (their messages: ``results/<log_id>/logs/``)", ""]
        out += [f"- ``{f['log_id']}`` [{_rst_text(f['stage'])}]: {_rst_text(f['error'])}"
                for f in run["failed"]] + [""]
    if run.get("not_run"):
        out += ["**Not run** (the run stopped before them: rerun)", ""]
        out += [f"- ``{i}``" for i in run["not_run"]] + [""]
    if run.get("completed"):
        out += ["**Completed**: " + ", ".join(f"``{i}``" for i in run["completed"]), ""]
    if run["warnings"]:
        out += ["**Warnings**", ""]
        out += [f"- ``{w['log_id']}``: {_rst_text(w['warning'])}" for w in run["warnings"]] + [""]
    if run.get("written"):
        out += [f"Written under ``results/``: {_rst_text(_written_line(run))}. Every figure is "
                "in the report as a thumbnail; each caption links the full-size figure.", ""]
    out += ["{% endraw %}", ""]
    return "\n".join(out)


def report_metadata(run: Mapping) -> dict:
    """Numbers for the report's landing page (``snakemake --report-metadata``)."""
    out = {"logs completed": run["logs"]["completed"], "logs failed": run["logs"]["failed"]}
    if run.get("not_run"):
        out["logs not run"] = len(run["not_run"])
    return out
