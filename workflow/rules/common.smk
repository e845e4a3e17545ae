# Shared helpers: configuration and manifest validation (before any job runs), the list of logs,
# wildcard constraints and the code digest that makes library edits rerun affected jobs.
import os
import re

import yaml

from snakemake.logging import logger
from snakemake.utils import validate

import enclab
from enclab.core import readers as enclab_readers
from enclab.core import manifest as enclab_manifest
from enclab.core.errors import EnclabInputError
from enclab.residuals.pipeline import residual_pairs as enclab_residual_pairs
from enclab.rig.manifest import rig_groups as enclab_rig_groups


with open(os.path.join(workflow.basedir, "workflow/schemas/config.schema.yaml")) as handle:
    CONFIG_SCHEMA = yaml.safe_load(handle)
try:
    # First for a message naming the key (Snakemake's validate does not), then to fill defaults.
    enclab_manifest.check_document(config, CONFIG_SCHEMA, "configuration (config.yaml and --config)",
                                   "workflow/schemas/config.schema.yaml")
except EnclabInputError as err:
    raise WorkflowError(str(err)) from None
validate(config, schema="../schemas/config.schema.yaml")

try:
    DATA_ROOT, MANIFEST = enclab_readers.read_manifest(config["manifest"], devices=config["devices"])
except EnclabInputError as err:
    raise WorkflowError(str(err)) from None

ENTRIES = {entry["id"]: entry for entry in MANIFEST}
if config.get("only_logs"):
    unknown = sorted(set(config["only_logs"]) - set(ENTRIES))
    if unknown:
        raise WorkflowError(f"config key 'only_logs': unknown log id(s) {unknown}; known: {sorted(ENTRIES)}")
    ENTRIES = {k: ENTRIES[k] for k in config["only_logs"]}


def _stages(entry):
    stages = (entry.get("analysis") or {}).get("stages")
    if stages is None:
        # A truth/measured pair and nothing else declared (a plain CSV) runs the residual stage
        # alone: re-quantizing needs the truth's grid or explicit steps, so quantization is
        # asked for by name on such a log. Without a pair the default stays quantization.
        stages = ["residuals"] if enclab_residual_pairs(entry) else ["quantization"]
    return stages


LOG_IDS = sorted(ENTRIES)


# Chunked mode (config chunk_size > 0; rules in chunks.smk): logs that run only the paper-000
# stages, in sorted order, K per chunk. Chunks are cut from every log of the manifest, before
# batch_scope leaves failed logs out, so that the second pass of `make run` finds the same
# chunks (complete, nothing to rerun).
CHUNK_SIZE = int(config.get("chunk_size") or 0)
# A log with a truth/measured pair also runs the residual stage, whose block its summary.json
# must carry: it stays in per-rule mode.
CHUNKED_IDS = sorted(i for i in ENTRIES if _stages(ENTRIES[i]) == ["quantization"]
                     and not enclab_residual_pairs(ENTRIES[i])) if CHUNK_SIZE else []
CHUNKS = {f"chunk{k // CHUNK_SIZE:04d}": CHUNKED_IDS[k:k + CHUNK_SIZE]
          for k in range(0, len(CHUNKED_IDS), max(CHUNK_SIZE, 1))}
CHUNK_OF = {i: name for name, ids in CHUNKS.items() for i in ids}
if config.get("batch_scope", "all") == "completed":
    # Second pass after failures: keep the logs that produced a summary, name the others.
    _failed = [i for i in LOG_IDS if not os.path.exists(f"results/{i}/summary.json")]
    if _failed:
        logger.warning(f"batch_scope=completed: leaving out {len(_failed)} log(s) without a "
                       f"summary (see results/<log_id>/logs/): {', '.join(_failed)}")
    LOG_IDS = [i for i in LOG_IDS if i not in _failed]
QUANT_IDS = [i for i in LOG_IDS if "quantization" in _stages(ENTRIES[i])]
LRDE_IDS = [i for i in LOG_IDS if "lrde" in _stages(ENTRIES[i])]
# Residual stage: every measured channel with a truth channel on the same joint (nothing to
# declare; analysis.residuals: false opts a log out).
RESIDUAL_PAIRS = {i: enclab_residual_pairs(ENTRIES[i]) for i in LOG_IDS}
RESIDUAL_PAIRS = {i: p for i, p in RESIDUAL_PAIRS.items() if p}
RESIDUAL_IDS = sorted(RESIDUAL_PAIRS)
# Rigs (rig.smk): runs a manifest groups with a `rig` key; a rig with a failed run is left out.
try:
    RIGS = {name: rig for name, rig in enclab_rig_groups(list(ENTRIES.values())).items()
            if all(r["log_id"] in LOG_IDS for r in rig["runs"])}
except ValueError as err:
    raise WorkflowError(f"{config['manifest']}: {err}") from None
# (rig, measured channel) of every rig fit: results/rigs/<rig>/<channel>/
RIG_CHANNELS = [(name, p["measured"]) for name, rig in RIGS.items() for p in rig["pairs"]]


def _first_of_groups(ids):
    """Every ungrouped log and the first log of each repeat group (the per-log figures of the
    other repeats look alike; ask for them by name: results/<log_id>/figures/errors.png)."""
    seen, out = set(), []
    for i in ids:
        group = ENTRIES[i].get("group")
        if group is None or group not in seen:
            out.append(i)
            seen.add(group)
    return out


FIGURE_IDS = _first_of_groups(QUANT_IDS)
# The HTML report (snakemake --report) opens on the run summary once rule run_summary wrote it.
REPORT_PAGE = "results/report/summary.rst"
report: os.path.abspath(REPORT_PAGE) if os.path.exists(REPORT_PAGE) else "../report/workflow.rst"
# The chunked logs whose figures their chunk draws: as FIGURE_IDS, but over every log of the
# manifest (like the chunks themselves), so that the second pass finds the chunks complete.
CHUNK_FIGURE_IDS = [i for i in _first_of_groups([i for i in sorted(ENTRIES)
                                                  if "quantization" in _stages(ENTRIES[i])])
                    if i in CHUNK_OF]
CODE_DIGEST = enclab.code_digest()


def ids_regex(ids):
    return "|".join(re.escape(i) for i in ids) or "NO_LOGS"


wildcard_constraints:
    log_id=ids_regex(LOG_IDS),
    channel="[A-Za-z_][A-Za-z0-9_]*",
    chunk=r"chunk\d+",


def _readable(path):
    return os.path.exists(path) and os.access(path, os.R_OK)


def raw_inputs(wildcards):
    # A missing or unreadable file is left out so that ingest runs and fails for this log
    # alone with a clear message: a missing input would stop Snakemake from building the whole
    # DAG, and an unreadable one stops the whole run when Snakemake records a finished job's
    # metadata (it reads every input under --max-checksum-file-size to store its checksum).
    files = enclab_readers.entry_files(ENTRIES[wildcards.log_id], DATA_ROOT)
    return [f for f in files if _readable(f)]


def chunk_raw_inputs(wildcards):
    """The readable data files of every log in a chunk (see raw_inputs)."""
    return [f for i in CHUNKS[wildcards.chunk]
            for f in enclab_readers.entry_files(ENTRIES[i], DATA_ROOT) if _readable(f)]


def source_of(wildcards):
    """The log's data file, which a failure of any of its jobs names (enclab.runner)."""
    return enclab_readers.entry_files(ENTRIES[wildcards.log_id], DATA_ROOT)[0]


def entry_of(wildcards):
    return ENTRIES[wildcards.log_id]


def device_of(wildcards):
    device = ENTRIES[wildcards.log_id].get("device")
    return config["devices"][device] if isinstance(device, str) else device


def summary_inputs(wildcards):
    """summary.json merges the blocks of the stages a log runs (quantization, lrde, residuals)."""
    log_id = wildcards.log_id
    inputs = {"canonical": f"results/{log_id}/canonical.parquet"}
    if log_id in QUANT_IDS:
        inputs.update(requantized=f"results/{log_id}/requantized.parquet",
                      moments=f"results/{log_id}/moments.json",
                      theory=f"results/{log_id}/theory.json")
    if log_id in LRDE_IDS:
        inputs["lrde"] = f"results/{log_id}/lrde/lrde.json"
    if log_id in RESIDUAL_PAIRS:
        inputs["residuals"] = [f"results/{log_id}/residuals/{p['measured']}/residuals.json"
                               for p in RESIDUAL_PAIRS[log_id]]
    return inputs


def residual_settings(wildcards):
    """config["residuals"] updated with the log's own analysis.residuals block."""
    settings = dict(config.get("residuals") or {})
    settings.update((ENTRIES[wildcards.log_id].get("analysis") or {}).get("residuals") or {})
    return settings


def residual_pair(wildcards):
    for pair in RESIDUAL_PAIRS.get(wildcards.log_id, []):
        if pair["measured"] == wildcards.channel:
            return pair
    raise WorkflowError(f"log {wildcards.log_id!r} has no measured channel {wildcards.channel!r} "
                        "with a truth channel on the same joint")


def rig_pair(wildcards):
    for pair in RIGS[wildcards.rig]["pairs"]:
        if pair["measured"] == wildcards.channel:
            return pair
    raise WorkflowError(f"rig {wildcards.rig!r} has no measured channel {wildcards.channel!r}")


def rig_truth_cpr(wildcards):
    """Counts per measured-side revolution the truth channel declares (counts_per_rev x
    gear_ratio), for the rig report's scale; None for a channel in rad."""
    first = ENTRIES[RIGS[wildcards.rig]["runs"][0]["log_id"]]
    chan = next(c for c in first["channels"] if c["name"] == rig_pair(wildcards)["truth"])
    cpr = chan.get("counts_per_rev")
    return float(cpr) * float(chan.get("gear_ratio") or 1) if cpr else None


def lrde_residual_inputs(wildcards):
    """The log's residuals.json files: what the residual stage found enters the LRDE fit."""
    return [f"results/{wildcards.log_id}/residuals/{p['measured']}/residuals.json"
            for p in RESIDUAL_PAIRS.get(wildcards.log_id, [])]


def lrde_settings(wildcards):
    """config["lrde"] updated with the log's own analysis.lrde block."""
    settings = dict(config.get("lrde") or {})
    settings.update((ENTRIES[wildcards.log_id].get("analysis") or {}).get("lrde") or {})
    return settings


def paper_figures_apply():
    """Fig. 6/7 equivalents need the configured Fig. 7 repeat group on a device with x, y, z."""
    group = config["figures"]["fig7_group"]
    return any(ENTRIES[i].get("group") == group for i in QUANT_IDS)


def design_inputs(wildcards):
    """Rule design: a logged workspace needs the log's canonical table, a box nothing."""
    log_id = ((config.get("design") or {}).get("workspace") or {}).get("log")
    return {"canonical": f"results/{log_id}/canonical.parquet"} if log_id else {}


def all_targets():
    targets = expand("results/{log_id}/summary.json", log_id=LOG_IDS)
    targets += expand("results/{log_id}/figures/errors.png", log_id=FIGURE_IDS)
    targets += expand("results/{log_id}/lrde/report.md", log_id=LRDE_IDS)
    if QUANT_IDS:
        targets += ["results/batch/quantization.csv", "results/batch/pooled.csv",
                    "results/figures/ratios.png"]
    if paper_figures_apply():
        targets += ["results/figures/fig6_position.png", "results/figures/fig7_derivatives.png"]
    if LRDE_IDS:
        targets += ["results/batch/lrde.csv"]
    for log_id, pairs in RESIDUAL_PAIRS.items():
        targets += [f"results/{log_id}/residuals/{p['measured']}/{name}"
                    for p in pairs for name in ("diagnostics.png", "before_after.png", "covariates.png")]
    if RESIDUAL_IDS:
        targets += ["results/batch/residuals.csv"]
    targets += [f"results/rigs/{name}/{channel}/report.md" for name, channel in RIG_CHANNELS]
    if config.get("design"):
        targets += ["results/design/design.json", "results/design/designs.csv",
                    "results/design/pareto.png"]
    # batch.smk: the run summary and the report's thumbnails
    targets += ["results/summary.json"]
    targets += [f"results/report/thumbs/{kind}" for kind in report_figures()]
    return targets


# ----------------------------------------------------------------------------- report (batch.smk)
# Every figure the workflow draws enters the HTML report as a thumbnail (under 5 MB for the
# embedded default); the full-size figures stay in results/ and each caption links its own.
# kind: (full-size figure, caption, report category, subcategory); a new figure adds a line.
REPORT_FIGURES = {
    "log_errors": ("results/{log_id}/figures/errors.png", "log_errors.rst", "Per log", "{log_id}"),
    "log_comparison": ("results/{log_id}/figures/comparison.png", "log_comparison.rst", "Per log",
                       "{log_id}"),
    "lrde_corner": ("results/{log_id}/lrde/corner.png", "lrde_corner.rst", "Paper 002", "{log_id}"),
    "lrde_dwell": ("results/{log_id}/lrde/dwell_ppc.png", "lrde_dwell.rst", "Paper 002", "{log_id}"),
    "lrde_bias_cycles": ("results/{log_id}/lrde/bias_cycles.png", "lrde_bias_cycles.rst", "Paper 002",
                         "{log_id}"),
    "lrde_misfit": ("results/{log_id}/lrde/misfit.png", "lrde_misfit.rst", "Paper 002", "{log_id}"),
    "residual_diagnostics": ("results/{log_id}/residuals/{channel}/diagnostics.png",
                             "residual_diagnostics.rst", "Residuals", "{log_id}"),
    "residual_before_after": ("results/{log_id}/residuals/{channel}/before_after.png",
                              "residual_before_after.rst", "Residuals", "{log_id}"),
    "residual_covariates": ("results/{log_id}/residuals/{channel}/covariates.png",
                            "residual_covariates.rst", "Residuals", "{log_id}"),
    "ratio_figure": ("results/figures/ratios.png", "ratio_figure.rst", "Paper 000", None),
    "fig6": ("results/figures/fig6_position.png", "fig6.rst", "Paper 000", None),
    "fig7": ("results/figures/fig7_derivatives.png", "fig7.rst", "Paper 000", None),
    "design_pareto": ("results/design/pareto.png", "design_pareto.rst", "Design", None),
    "rig_map": ("results/rigs/{rig}/{channel}/map.png", "rig_map.rst", "Rigs", "{log_id}"),
    "rig_compliance": ("results/rigs/{rig}/{channel}/compliance.png", "rig_compliance.rst", "Rigs", "{log_id}"),
    "rig_heldout": ("results/rigs/{rig}/{channel}/heldout.png", "rig_heldout.rst", "Rigs", "{log_id}"),
    "rig_remains": ("results/rigs/{rig}/{channel}/remains.png", "rig_remains.rst", "Rigs", "{log_id}"),
}
THUMBNAIL_WIDTH = 480


def report_figures():
    """{kind: [(full-size figure, thumbnail)]} of the figures this run draws."""
    instances = {
        "log_errors": [{"log_id": i} for i in FIGURE_IDS],
        "lrde_corner": [{"log_id": i} for i in LRDE_IDS],
        "residual_diagnostics": [{"log_id": i, "channel": p["measured"]}
                                 for i, pairs in RESIDUAL_PAIRS.items() for p in pairs],
        "ratio_figure": [{}] if QUANT_IDS else [],
        "fig6": [{}] if paper_figures_apply() else [],
        "design_pareto": [{}] if config.get("design") else [],
        # a rig's thumbnails are named <rig>/<channel>.png (log_id = the rig's name)
        "rig_map": [{"log_id": name, "rig": name, "channel": channel}
                    for name, channel in RIG_CHANNELS],
    }
    for kind, same in (("log_comparison", "log_errors"), ("lrde_dwell", "lrde_corner"),
                       ("lrde_bias_cycles", "lrde_corner"), ("lrde_misfit", "lrde_corner"),
                       ("residual_before_after", "residual_diagnostics"),
                       ("residual_covariates", "residual_diagnostics"), ("fig7", "fig6"),
                       ("rig_compliance", "rig_map"), ("rig_heldout", "rig_map"), ("rig_remains", "rig_map")):
        instances[kind] = instances[same]
    out = {}
    for kind, (pattern, *_) in REPORT_FIGURES.items():
        pairs = []
        for wc in instances[kind]:
            if "log_id" in wc:
                name = os.path.join(wc["log_id"], wc["channel"]) if "channel" in wc else wc["log_id"]
            else:
                name = os.path.basename(pattern)[: -len(".png")]
            pairs.append((pattern.format(**wc), f"results/report/thumbs/{kind}/{name}.png"))
        if pairs:
            out[kind] = pairs
    return out


def _thumbnail_pattern(kind):
    pattern = REPORT_FIGURES[kind][0]
    if "{channel}" in pattern:
        return "{log_id}/{channel}.png"
    return "{log_id}.png" if "{log_id}" in pattern else "{name}.png"


def thumbnail_outputs():
    return {kind: report(directory(f"results/report/thumbs/{kind}"),
                         patterns=[_thumbnail_pattern(kind)],
                         caption=f"../report/{REPORT_FIGURES[kind][1]}",
                         category=REPORT_FIGURES[kind][2], subcategory=REPORT_FIGURES[kind][3])
            for kind in report_figures()}


def run_summary_inputs(wildcards):
    inputs = {"summaries": expand("results/{log_id}/summary.json", log_id=LOG_IDS),
              "figures": [src for pairs in report_figures().values() for src, _ in pairs]}
    tables = []
    if QUANT_IDS:
        inputs.update(ratios="results/batch/ratios.csv",
                      violations="results/batch/bound_violations.csv")
        tables += ["results/batch/quantization.csv", "results/batch/pooled.csv",
                   "results/batch/ratios.csv", "results/batch/bound_violations.csv"]
    tables += ["results/batch/lrde.csv"] if LRDE_IDS else []
    tables += ["results/batch/residuals.csv"] if RESIDUAL_IDS else []
    inputs["tables"] = tables
    if config.get("design"):
        inputs["design"] = "results/design/design.json"
    if RIG_CHANNELS:
        inputs["rigs"] = [f"results/rigs/{name}/{channel}/rig.json" for name, channel in RIG_CHANNELS]
    return inputs
