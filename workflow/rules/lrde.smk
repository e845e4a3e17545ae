# Low-resolution encoder per log: dwell patterns and the emcee fit of stroke, bias and offset
# (after Zhang & Gao) -> report.


rule lrde_fit:
    input:
        canonical="results/{log_id}/canonical.parquet",
        # with a truth channel, the residual stage's findings on the coarse channel
        residuals=lrde_residual_inputs,
    output:
        block="results/{log_id}/lrde/lrde.json",
        cycles="results/{log_id}/lrde/cycles.csv",
        report=report("results/{log_id}/lrde/report.md", category=REPORT_CATEGORIES["lrde"],
                      subcategory="{log_id}", caption="../report/lrde_report.rst"),
        # figures: in the report as thumbnails (enclab.plan.REPORT_FIGURES)
        corner="results/{log_id}/lrde/corner.png",
        dwell="results/{log_id}/lrde/dwell_ppc.png",
        bias_cycles="results/{log_id}/lrde/bias_cycles.png",
        misfit="results/{log_id}/lrde/misfit.png",
    params:
        settings=lambda wc: lrde_settings(wc),
        code=CODE_DIGEST,
        source=source_of,
    # the comparison's point fits and the emcee fits run side by side (same results with 1)
    threads: 2
    # the longest job of a run: started first (the greedy scheduler prefers larger inputs)
    priority: 1
    log:
        "results/{log_id}/logs/lrde_fit.log",
    benchmark:
        "results/{log_id}/benchmarks/lrde_fit.tsv"
    script:
        "../../scripts/lrde_fit.py"


rule batch_lrde:
    input:
        summaries=expand("results/{log_id}/summary.json", log_id=LRDE_IDS),
    output:
        table=report("results/batch/lrde.csv", category=REPORT_CATEGORIES["lrde"],
                     caption="../report/lrde_batch.rst"),
    params:
        code=CODE_DIGEST,
    log:
        "results/batch/logs/batch_lrde.log",
    benchmark:
        "results/batch/benchmarks/batch_lrde.tsv"
    script:
        "../../scripts/batch_lrde.py"
