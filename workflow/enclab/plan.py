"""What a run does, from the configuration and the manifest: the workflow's plan.

Pure functions of ``(config, manifest entries)``: which analyses each log runs
(:func:`stages_of`), the chunks of the chunked mode (:func:`chunk_plan`), the logs, pairs and
rigs of each analysis (:func:`make_plan`), the files a run asks for
(:meth:`Plan.all_targets`), the inputs of a log's and of the run's summary, and the figures
the HTML report shows as thumbnails (:data:`REPORT_FIGURES`, :meth:`Plan.report_figures`).
``workflow/rules/common.smk`` wraps them for Snakemake; they touch no file (whether a log
completed is asked of the caller).
"""
from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

from enclab.residuals.pipeline import residual_pairs
from enclab.rig.manifest import rig_groups

__all__ = ["stages_of", "first_of_groups", "chunked_ids", "chunk_plan", "select_entries",
           "make_plan", "Plan", "ReportFigure", "REPORT_CATEGORIES", "REPORT_FIGURES", "THUMBNAIL_WIDTH",
           "thumbnail_pattern", "merged_settings"]


def stages_of(entry: Mapping) -> list[str]:
    """The analyses a manifest entry runs: its ``analysis.stages``, or by default the residual
    stage for a log with a truth/measured pair and the quantization-error stages otherwise.

    A truth/measured pair and nothing else declared (a plain CSV) runs the residual stage
    alone: re-quantizing needs the truth's grid or explicit steps, so the quantization-error
    stages are asked for by name on such a log.
    """
    stages = (entry.get("analysis") or {}).get("stages")
    if stages is None:
        stages = ["residuals"] if residual_pairs(entry) else ["quantization"]
    return stages


def first_of_groups(entries: Mapping[str, Mapping], ids: Sequence[str]) -> list[str]:
    """Every ungrouped log of ``ids`` and the first log of each repeat group (the per-log
    figures of the other repeats look alike; ask for them by name:
    results/<log_id>/figures/errors.png)."""
    seen, out = set(), []
    for i in ids:
        group = entries[i].get("group")
        if group is None or group not in seen:
            out.append(i)
            seen.add(group)
    return out


def chunked_ids(entries: Mapping[str, Mapping], chunk_size: int) -> list[str]:
    """The logs the chunked mode runs (sorted): those that run the quantization-error stages
    alone. A log with a truth/measured pair also runs the residual stage, whose block its
    summary.json must carry: it stays in per-rule mode. None when ``chunk_size`` is 0."""
    if not chunk_size:
        return []
    return sorted(i for i, entry in entries.items()
                  if stages_of(entry) == ["quantization"] and not residual_pairs(entry))


def chunk_plan(entries: Mapping[str, Mapping], chunk_size: int) -> dict[str, list[str]]:
    """``{"chunk0000": [log ids], ...}``: the chunked logs (:func:`chunked_ids`) in sorted
    order, ``chunk_size`` per chunk.

    The chunks are cut from every log of the manifest, before ``batch_scope: completed`` leaves
    failed logs out, so that the second pass of ``make run`` finds the same chunks (complete,
    nothing to rerun).
    """
    ids = chunked_ids(entries, chunk_size)
    return {f"chunk{k // chunk_size:04d}": ids[k:k + chunk_size]
            for k in range(0, len(ids), max(chunk_size, 1))}


def select_entries(manifest: Sequence[Mapping], only_logs: Sequence[str] | None) -> dict[str, Mapping]:
    """``{log id: entry}`` of the manifest, or of the ``only_logs`` it names (in that order).

    Raises
    ------
    ValueError
        When ``only_logs`` names a log the manifest does not hold.
    """
    entries = {entry["id"]: entry for entry in manifest}
    if only_logs:
        unknown = sorted(set(only_logs) - set(entries))
        if unknown:
            raise ValueError(f"config key 'only_logs': unknown log id(s) {unknown}; known: {sorted(entries)}")
        entries = {k: entries[k] for k in only_logs}
    return entries


def merged_settings(config: Mapping, entry: Mapping, analysis: str) -> dict:
    """``config[analysis]`` updated with the log's own ``analysis.<analysis>`` block."""
    settings = dict(config.get(analysis) or {})
    settings.update((entry.get("analysis") or {}).get(analysis) or {})
    return settings


class ReportFigure(NamedTuple):
    """A figure the HTML report shows as a thumbnail."""

    #: the full-size figure under results/ (wildcards ``{log_id}``, ``{channel}``, ``{rig}``)
    pattern: str
    #: caption file under workflow/report/
    caption: str
    #: report category: the analysis that draws the figure (:data:`REPORT_CATEGORIES`)
    category: str
    #: report subcategory (``"{log_id}"``: one per log or rig) or None
    subcategory: str | None
    #: whose figure it is: a key of :meth:`Plan.figure_instances`
    drawn_for: str


# The report's categories: one per analysis, named by the question it answers.
REPORT_CATEGORIES = {"propagation": "Quantization error", "lrde": "Low-resolution encoder",
                     "residuals": "Residual effects", "rig": "Rig fit", "design": "Design"}
_QUANTIZATION_ERROR, _LOW_RESOLUTION_ENCODER, _RESIDUAL_EFFECTS, _RIG_FIT, _DESIGN = (
    REPORT_CATEGORIES[a] for a in ("propagation", "lrde", "residuals", "rig", "design"))


def _figure(pattern, caption, category, drawn_for, subcategory="{log_id}"):
    return ReportFigure(pattern, caption, category, subcategory, drawn_for)


# Every figure the workflow draws enters the HTML report as a thumbnail (under 5 MB for the
# embedded default); the full-size figures stay in results/ and each caption links its own.
# A new figure adds a line.
REPORT_FIGURES = {
    "log_errors": _figure("results/{log_id}/figures/errors.png", "log_errors.rst",
                          _QUANTIZATION_ERROR, "quantization_figure_logs"),
    "log_comparison": _figure("results/{log_id}/figures/comparison.png", "log_comparison.rst",
                              _QUANTIZATION_ERROR, "quantization_figure_logs"),
    "lrde_corner": _figure("results/{log_id}/lrde/corner.png", "lrde_corner.rst",
                           _LOW_RESOLUTION_ENCODER, "lrde_logs"),
    "lrde_dwell": _figure("results/{log_id}/lrde/dwell_ppc.png", "lrde_dwell.rst",
                          _LOW_RESOLUTION_ENCODER, "lrde_logs"),
    "lrde_bias_cycles": _figure("results/{log_id}/lrde/bias_cycles.png", "lrde_bias_cycles.rst",
                                _LOW_RESOLUTION_ENCODER, "lrde_logs"),
    "lrde_misfit": _figure("results/{log_id}/lrde/misfit.png", "lrde_misfit.rst",
                           _LOW_RESOLUTION_ENCODER, "lrde_logs"),
    "residual_diagnostics": _figure("results/{log_id}/residuals/{channel}/diagnostics.png",
                                    "residual_diagnostics.rst", _RESIDUAL_EFFECTS,
                                    "residual_channels"),
    "residual_before_after": _figure("results/{log_id}/residuals/{channel}/before_after.png",
                                     "residual_before_after.rst", _RESIDUAL_EFFECTS,
                                     "residual_channels"),
    "residual_covariates": _figure("results/{log_id}/residuals/{channel}/covariates.png",
                                   "residual_covariates.rst", _RESIDUAL_EFFECTS,
                                   "residual_channels"),
    "ratio_figure": _figure("results/figures/ratios.png", "ratio_figure.rst", _QUANTIZATION_ERROR,
                            "quantization_batch", subcategory=None),
    "fig6": _figure("results/figures/fig6_position.png", "fig6.rst", _QUANTIZATION_ERROR,
                    "paper_figures", subcategory=None),
    "fig7": _figure("results/figures/fig7_derivatives.png", "fig7.rst", _QUANTIZATION_ERROR,
                    "paper_figures", subcategory=None),
    "design_pareto": _figure("results/design/pareto.png", "design_pareto.rst", _DESIGN, "design",
                             subcategory=None),
    "rig_map": _figure("results/rigs/{rig}/{channel}/map.png", "rig_map.rst", _RIG_FIT,
                       "rig_channels"),
    "rig_compliance": _figure("results/rigs/{rig}/{channel}/compliance.png", "rig_compliance.rst",
                              _RIG_FIT, "rig_channels"),
    "rig_heldout": _figure("results/rigs/{rig}/{channel}/heldout.png", "rig_heldout.rst", _RIG_FIT,
                           "rig_channels"),
    "rig_remains": _figure("results/rigs/{rig}/{channel}/remains.png", "rig_remains.rst", _RIG_FIT,
                           "rig_channels"),
}
THUMBNAIL_WIDTH = 480


def thumbnail_pattern(kind: str) -> str:
    """The file name pattern of a kind's thumbnails inside results/report/thumbs/<kind>/."""
    pattern = REPORT_FIGURES[kind].pattern
    if "{channel}" in pattern:
        return "{log_id}/{channel}.png"
    return "{log_id}.png" if "{log_id}" in pattern else "{name}.png"


@dataclass(frozen=True)
class Plan:
    """The logs, pairs and rigs each analysis runs on, and the files the run asks for.

    Built by :func:`make_plan`; every list of log ids is sorted unless said otherwise.
    """

    config: Mapping
    #: ``{log id: manifest entry}`` of every log the run was asked for (failed ones included)
    entries: Mapping[str, Mapping]
    #: the logs the run goes on with (``batch_scope: completed`` leaves out failed ones)
    log_ids: list[str]
    #: the logs left out because they produced no summary (``batch_scope: completed``)
    failed: list[str]
    quantization_ids: list[str]
    lrde_ids: list[str]
    #: ``{log id: [{"measured", "truth", "joint"}]}`` of the residual stage, in log order
    residual_pairs: dict[str, list[dict]]
    #: :func:`enclab.rig.manifest.rig_groups` of the rigs whose runs all completed
    rigs: dict[str, dict]
    #: the chunked mode's chunks (:func:`chunk_plan`) and their logs
    chunks: dict[str, list[str]]
    chunked_ids: list[str]

    @property
    def residual_ids(self) -> list[str]:
        return sorted(self.residual_pairs)

    @property
    def rig_channels(self) -> list[tuple[str, str]]:
        """``(rig, measured channel)`` of every rig fit: results/rigs/<rig>/<channel>/."""
        return [(name, p["measured"]) for name, rig in self.rigs.items() for p in rig["pairs"]]

    @property
    def chunk_of(self) -> dict[str, str]:
        return {i: name for name, ids in self.chunks.items() for i in ids}

    @property
    def figure_ids(self) -> list[str]:
        """The logs whose per-log figures the run draws (:func:`first_of_groups`)."""
        return first_of_groups(self.entries, self.quantization_ids)

    @property
    def chunk_figure_ids(self) -> list[str]:
        """The chunked logs whose figures their chunk draws: as :attr:`figure_ids`, but over
        every log asked for (like the chunks themselves), so that the second pass finds the
        chunks complete."""
        chunk_of = self.chunk_of
        asked = [i for i in sorted(self.entries) if "quantization" in stages_of(self.entries[i])]
        return [i for i in first_of_groups(self.entries, asked) if i in chunk_of]

    @property
    def paper_figures(self) -> bool:
        """Fig. 6/7 equivalents (Colonnese & Okamura) need the configured Fig. 7 repeat group
        on a device with x, y, z."""
        group = self.config["figures"]["fig7_group"]
        return any(self.entries[i].get("group") == group for i in self.quantization_ids)

    @property
    def design(self) -> bool:
        return bool(self.config.get("design"))

    def figure_instances(self) -> dict[str, list[dict]]:
        """``{drawn_for: [wildcards]}``: the instances of each :attr:`ReportFigure.drawn_for`."""
        return {
            "quantization_figure_logs": [{"log_id": i} for i in self.figure_ids],
            "lrde_logs": [{"log_id": i} for i in self.lrde_ids],
            "residual_channels": [{"log_id": i, "channel": p["measured"]}
                                  for i, pairs in self.residual_pairs.items() for p in pairs],
            "quantization_batch": [{}] if self.quantization_ids else [],
            "paper_figures": [{}] if self.paper_figures else [],
            "design": [{}] if self.design else [],
            # a rig's thumbnails are named <rig>/<channel>.png (log_id = the rig's name)
            "rig_channels": [{"log_id": name, "rig": name, "channel": channel}
                             for name, channel in self.rig_channels],
        }

    def report_figures(self) -> dict[str, list[tuple[str, str]]]:
        """``{kind: [(full-size figure, thumbnail)]}`` of the figures this run draws, in
        :data:`REPORT_FIGURES` order."""
        instances = self.figure_instances()
        out = {}
        for kind, figure in REPORT_FIGURES.items():
            pairs = []
            for wc in instances[figure.drawn_for]:
                if "log_id" in wc:
                    name = os.path.join(wc["log_id"], wc["channel"]) if "channel" in wc else wc["log_id"]
                else:
                    name = os.path.basename(figure.pattern)[: -len(".png")]
                pairs.append((figure.pattern.format(**wc), f"results/report/thumbs/{kind}/{name}.png"))
            if pairs:
                out[kind] = pairs
        return out

    def all_targets(self) -> list[str]:
        """The files rule ``all`` asks for."""
        targets = [f"results/{i}/summary.json" for i in self.log_ids]
        targets += [f"results/{i}/figures/errors.png" for i in self.figure_ids]
        targets += [f"results/{i}/lrde/report.md" for i in self.lrde_ids]
        if self.quantization_ids:
            targets += ["results/batch/quantization.csv", "results/batch/pooled.csv",
                        "results/figures/ratios.png"]
        if self.paper_figures:
            targets += ["results/figures/fig6_position.png", "results/figures/fig7_derivatives.png"]
        if self.lrde_ids:
            targets += ["results/batch/lrde.csv"]
        for log_id, pairs in self.residual_pairs.items():
            targets += [f"results/{log_id}/residuals/{p['measured']}/{name}"
                        for p in pairs for name in ("diagnostics.png", "before_after.png", "covariates.png")]
        if self.residual_pairs:
            targets += ["results/batch/residuals.csv"]
        targets += [f"results/rigs/{name}/{channel}/report.md" for name, channel in self.rig_channels]
        if self.design:
            targets += ["results/design/design.json", "results/design/designs.csv",
                        "results/design/pareto.png"]
        # batch.smk: the run summary and the report's thumbnails
        targets += ["results/summary.json"]
        targets += [f"results/report/thumbs/{kind}" for kind in self.report_figures()]
        return targets

    def summary_inputs(self, log_id: str) -> dict:
        """Inputs of a log's summary.json: the blocks of the analyses the log runs."""
        inputs = {"canonical": f"results/{log_id}/canonical.parquet"}
        if log_id in self.quantization_ids:
            inputs.update(requantized=f"results/{log_id}/requantized.parquet",
                          moments=f"results/{log_id}/moments.json",
                          theory=f"results/{log_id}/theory.json")
        if log_id in self.lrde_ids:
            inputs["lrde"] = f"results/{log_id}/lrde/lrde.json"
        if log_id in self.residual_pairs:
            inputs["residuals"] = self.residual_blocks(log_id)
        return inputs

    def residual_blocks(self, log_id: str) -> list[str]:
        """The log's residuals.json files, one per measured channel (none without a pair)."""
        return [f"results/{log_id}/residuals/{p['measured']}/residuals.json"
                for p in self.residual_pairs.get(log_id, [])]

    def design_inputs(self) -> dict:
        """Rule design: a logged workspace needs the log's canonical table, a box nothing."""
        log_id = ((self.config.get("design") or {}).get("workspace") or {}).get("log")
        return {"canonical": f"results/{log_id}/canonical.parquet"} if log_id else {}

    def run_summary_inputs(self) -> dict:
        """Inputs of the run summary: every summary.json, figure and batch table."""
        inputs = {"summaries": [f"results/{i}/summary.json" for i in self.log_ids],
                  "figures": [src for pairs in self.report_figures().values() for src, _ in pairs]}
        tables = []
        if self.quantization_ids:
            inputs.update(ratios="results/batch/ratios.csv",
                          violations="results/batch/bound_violations.csv")
            tables += ["results/batch/quantization.csv", "results/batch/pooled.csv",
                       "results/batch/ratios.csv", "results/batch/bound_violations.csv"]
        tables += ["results/batch/lrde.csv"] if self.lrde_ids else []
        tables += ["results/batch/residuals.csv"] if self.residual_pairs else []
        inputs["tables"] = tables
        if self.design:
            inputs["design"] = "results/design/design.json"
        if self.rig_channels:
            inputs["rigs"] = [f"results/rigs/{name}/{channel}/rig.json"
                              for name, channel in self.rig_channels]
        return inputs


def make_plan(config: Mapping, entries: Mapping[str, Mapping],
              has_summary: Callable[[str], bool] | None = None) -> Plan:
    """The plan of a run.

    Parameters
    ----------
    config : dict
        The validated workflow configuration (``chunk_size``, ``batch_scope``, ``figures``,
        ``design``, ``manifest``).
    entries : dict
        ``{log id: normalised manifest entry}`` of the logs asked for (:func:`select_entries`).
    has_summary : callable, optional
        ``log id -> bool``: whether the log's summary.json exists. Needed with
        ``batch_scope: completed`` (the second pass after failures keeps the logs that
        produced a summary).

    Raises
    ------
    ValueError
        A manifest's ``rig`` keys that do not form rigs (:func:`enclab.rig.manifest.rig_groups`),
        the message prefixed with the manifest's path.
    """
    chunk_size = int(config.get("chunk_size") or 0)
    log_ids = sorted(entries)
    failed = []
    if config.get("batch_scope", "all") == "completed":
        failed = [i for i in log_ids if not has_summary(i)]
        log_ids = [i for i in log_ids if i not in failed]
    pairs = {i: residual_pairs(entries[i]) for i in log_ids}
    try:
        rigs = {name: rig for name, rig in rig_groups(list(entries.values())).items()
                if all(r["log_id"] in log_ids for r in rig["runs"])}
    except ValueError as err:
        raise ValueError(f"{config['manifest']}: {err}") from None
    return Plan(
        config=config, entries=entries, log_ids=log_ids, failed=failed,
        quantization_ids=[i for i in log_ids if "quantization" in stages_of(entries[i])],
        lrde_ids=[i for i in log_ids if "lrde" in stages_of(entries[i])],
        residual_pairs={i: p for i, p in pairs.items() if p},
        rigs=rigs,
        chunks=chunk_plan(entries, chunk_size),
        chunked_ids=chunked_ids(entries, chunk_size))
