# Shared helpers: configuration and manifest validation (before any job runs), the run's plan
# (enclab.plan: which logs each analysis runs on, the chunks, the targets and the report's
# figures), wildcard constraints, the input functions the rules call and the code digest that
# makes library edits rerun affected jobs.
import os
import re

import yaml

from snakemake.logging import logger
from snakemake.utils import validate

import enclab
from enclab.core import readers as enclab_readers
from enclab.core import manifest as enclab_manifest
from enclab.core.errors import EnclabInputError
from enclab import plan as enclab_plan


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

# The plan of the run (enclab.plan): the logs, pairs and rigs each analysis runs on, the chunks
# of the chunked mode and the files rule all asks for; the names below are its parts.
try:
    ENTRIES = enclab_plan.select_entries(MANIFEST, config.get("only_logs"))
    PLAN = enclab_plan.make_plan(config, ENTRIES,
                                 has_summary=lambda i: os.path.exists(f"results/{i}/summary.json"))
except ValueError as err:
    raise WorkflowError(str(err)) from None
if PLAN.failed:
    # Second pass after failures (batch_scope=completed): name the logs left out.
    logger.warning(f"batch_scope=completed: leaving out {len(PLAN.failed)} log(s) without a "
                   f"summary (see results/<log_id>/logs/): {', '.join(PLAN.failed)}")
LOG_IDS = PLAN.log_ids
QUANT_IDS = PLAN.quantization_ids
LRDE_IDS = PLAN.lrde_ids
# Residual stage: every measured channel with a truth channel on the same joint (nothing to
# declare; analysis.residuals: false opts a log out).
RESIDUAL_PAIRS = PLAN.residual_pairs
RESIDUAL_IDS = PLAN.residual_ids
# Rigs (rig.smk): runs a manifest groups with a `rig` key; a rig with a failed run is left out.
RIGS = PLAN.rigs
# Chunked mode (config chunk_size > 0; rules in chunks.smk).
CHUNKS = PLAN.chunks
CHUNKED_IDS = PLAN.chunked_ids
CHUNK_OF = PLAN.chunk_of
CHUNK_FIGURE_IDS = PLAN.chunk_figure_ids
# The HTML report (snakemake --report) opens on the run summary once rule run_summary wrote it.
REPORT_PAGE = "results/report/summary.rst"
report: os.path.abspath(REPORT_PAGE) if os.path.exists(REPORT_PAGE) else "../report/workflow.rst"
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


def summary_inputs(wildcards):
    """summary.json merges the blocks of the analyses a log runs."""
    return PLAN.summary_inputs(wildcards.log_id)


def residual_settings(wildcards):
    """config["residuals"] updated with the log's own analysis.residuals block."""
    return enclab_plan.merged_settings(config, ENTRIES[wildcards.log_id], "residuals")


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
    return PLAN.residual_blocks(wildcards.log_id)


def lrde_settings(wildcards):
    """config["lrde"] updated with the log's own analysis.lrde block."""
    return enclab_plan.merged_settings(config, ENTRIES[wildcards.log_id], "lrde")


def design_inputs(wildcards):
    return PLAN.design_inputs()


def all_targets():
    return PLAN.all_targets()


# ----------------------------------------------------------------------------- report (batch.smk)
# The figure registry is enclab.plan.REPORT_FIGURES; Snakemake's report() flags stay here.
THUMBNAIL_WIDTH = enclab_plan.THUMBNAIL_WIDTH
# report(category=...) of every rule: one category per analysis
REPORT_CATEGORIES = enclab_plan.REPORT_CATEGORIES


def report_figures():
    """{kind: [(full-size figure, thumbnail)]} of the figures this run draws."""
    return PLAN.report_figures()


def thumbnail_outputs():
    figures = enclab_plan.REPORT_FIGURES
    return {kind: report(directory(f"results/report/thumbs/{kind}"),
                         patterns=[enclab_plan.thumbnail_pattern(kind)],
                         caption=f"../report/{figures[kind].caption}",
                         category=figures[kind].category, subcategory=figures[kind].subcategory)
            for kind in report_figures()}


def run_summary_inputs(wildcards):
    return PLAN.run_summary_inputs()
