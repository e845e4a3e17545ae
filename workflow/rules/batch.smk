# Quantization error across logs: batch table, pooled repeat groups, the equivalents of
# Colonnese & Okamura's Figs. 6 and 7.


rule batch_quantization:
    input:
        summaries=expand("results/{log_id}/summary.json", log_id=QUANT_IDS),
    output:
        table="results/batch/quantization.csv",
        pooled="results/batch/pooled.csv",
        ratios=report("results/batch/ratios.csv", category=REPORT_CATEGORIES["propagation"],
                      caption="../report/ratios.rst"),
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
# (enclab.plan.Plan.paper_figures).
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
# The figures' thumbnails and the run summary (enclab.plan: REPORT_FIGURES, Plan.report_figures).


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
