# Across logs: batch table, pooled repeat groups, Fig. 6 / Fig. 7 equivalents.


rule batch_quantization:
    input:
        summaries=expand("results/{log_id}/summary.json", log_id=QUANT_IDS),
    output:
        table="results/batch/quantization.csv",
        pooled="results/batch/pooled.csv",
        ratios=report("results/batch/ratios.csv", category="Batch", caption="../report/ratios.rst"),
        violations="results/batch/bound_violations.csv",
    params:
        ci_level=config["moments"]["ci_level"],
        code=CODE_DIGEST,
    log:
        "results/batch/logs/batch_quantization.log",
    benchmark:
        "results/batch/benchmarks/batch_quantization.tsv"
    script:
        "../../scripts/batch_quantization.py"


rule ratio_figure:
    input:
        pooled="results/batch/pooled.csv",
    output:
        ratios="results/figures/ratios.png",
    params:
        code=CODE_DIGEST,
    log:
        "results/batch/logs/ratio_figure.log",
    benchmark:
        "results/batch/benchmarks/ratio_figure.tsv"
    script:
        "../../scripts/ratio_figure.py"


# Requested only when the manifest holds the configured Fig. 6 level and Fig. 7 group
# (see paper_figures_apply in common.smk).
rule paper_figures:
    input:
        pooled="results/batch/pooled.csv",
    output:
        fig6="results/figures/fig6_position.png",
        fig7="results/figures/fig7_derivatives.png",
    params:
        figures=config["figures"],
        code=CODE_DIGEST,
    log:
        "results/batch/logs/paper_figures.log",
    benchmark:
        "results/batch/benchmarks/paper_figures.tsv"
    script:
        "../../scripts/paper_figures.py"


# ----------------------------------------------------------------------------- run summary, report
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
    "residual_diagnostics": ("results/{log_id}/residuals/{channel}/diagnostics.png",
                             "residual_diagnostics.rst", "Residuals", "{log_id}"),
    "residual_before_after": ("results/{log_id}/residuals/{channel}/before_after.png",
                              "residual_before_after.rst", "Residuals", "{log_id}"),
    "ratio_figure": ("results/figures/ratios.png", "ratio_figure.rst", "Paper 000", None),
    "fig6": ("results/figures/fig6_position.png", "fig6.rst", "Paper 000", None),
    "fig7": ("results/figures/fig7_derivatives.png", "fig7.rst", "Paper 000", None),
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
    }
    for kind, same in (("log_comparison", "log_errors"), ("lrde_dwell", "lrde_corner"),
                       ("lrde_bias_cycles", "lrde_corner"),
                       ("residual_before_after", "residual_diagnostics"), ("fig7", "fig6")):
        instances[kind] = instances[same]
    out = {}
    for kind, (pattern, *_) in REPORT_FIGURES.items():
        pairs = []
        for wc in instances[kind]:
            name = "/".join(wc[k] for k in ("log_id", "channel") if k in wc) or \
                os.path.basename(pattern)[: -len(".png")]
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


rule report_thumbnails:
    input:
        [src for pairs in report_figures().values() for src, _ in pairs],
    output:
        **thumbnail_outputs(),
    params:
        pairs=[pair for pairs in report_figures().values() for pair in pairs],
        width=THUMBNAIL_WIDTH,
        code=CODE_DIGEST,
    log:
        "results/logs/report_thumbnails.log",
    benchmark:
        "results/logs/report_thumbnails.benchmark.tsv"
    script:
        "../../scripts/report_thumbnails.py"


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
    return inputs


# What ran, the headline number of each analysis, what failed and why: results/summary.json,
# the text `make run` prints at its end, and the page the HTML report opens on (common.smk).
rule run_summary:
    input:
        unpack(run_summary_inputs),
    output:
        summary="results/summary.json",
        text="results/summary.txt",
        page="results/report/summary.rst",
        metadata="results/report/metadata.yaml",
    params:
        log_ids=sorted(ENTRIES),
        failed=sorted(set(ENTRIES) - set(LOG_IDS)),
        code=CODE_DIGEST,
    log:
        "results/logs/run_summary.log",
    benchmark:
        "results/logs/run_summary.benchmark.tsv"
    script:
        "../../scripts/run_summary.py"
