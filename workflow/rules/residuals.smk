# Residual effects per measured channel (every measured channel with a truth channel on the same
# joint): residual against the exact quantizer model, diagnostics, effect selection, before/after,
# and the angle-error map as a lookup table.


rule residuals:
    input:
        canonical="results/{log_id}/canonical.parquet",
    output:
        block="results/{log_id}/residuals/{channel}/residuals.json",
        table=report("results/{log_id}/residuals/{channel}/before_after.csv",
                     category=REPORT_CATEGORIES["residuals"],
                     subcategory="{log_id}", caption="../report/residual_table.rst"),
        # figures: in the report as thumbnails (enclab.plan.REPORT_FIGURES)
        diagnostics="results/{log_id}/residuals/{channel}/diagnostics.png",
        before_after="results/{log_id}/residuals/{channel}/before_after.png",
        covariates="results/{log_id}/residuals/{channel}/covariates.png",
        # the angle-error map as a controller loads it (docs/residuals.md "Lookup table")
        lut_csv="results/{log_id}/residuals/{channel}/lookup_table.csv",
        lut_json="results/{log_id}/residuals/{channel}/lookup_table.json",
    params:
        pair=lambda wc: residual_pair(wc),
        settings=lambda wc: residual_settings(wc),
        code=CODE_DIGEST,
        source=source_of,
    threads: 1
    # an LRDE fit (the longest job) waits for its log's residual stage
    priority: 1
    log:
        "results/{log_id}/logs/residuals_{channel}.log",
    benchmark:
        "results/{log_id}/benchmarks/residuals_{channel}.tsv"
    script:
        "../../scripts/residuals.py"


rule batch_residuals:
    input:
        summaries=expand("results/{log_id}/summary.json", log_id=RESIDUAL_IDS),
    output:
        table=report("results/batch/residuals.csv", category=REPORT_CATEGORIES["residuals"],
                     caption="../report/residual_batch.rst"),
    params:
        code=CODE_DIGEST,
    log:
        "results/batch/logs/batch_residuals.log",
    benchmark:
        "results/batch/benchmarks/batch_residuals.tsv"
    script:
        "../../scripts/batch_residuals.py"
