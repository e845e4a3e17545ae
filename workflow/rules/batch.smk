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
        ratios=report("results/figures/ratios.png", category="Paper 000",
                      caption="../report/ratio_figure.rst"),
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
        fig6=report("results/figures/fig6_position.png", category="Paper 000",
                    caption="../report/fig6.rst"),
        fig7=report("results/figures/fig7_derivatives.png", category="Paper 000",
                    caption="../report/fig7.rst"),
    params:
        figures=config["figures"],
        code=CODE_DIGEST,
    log:
        "results/batch/logs/paper_figures.log",
    benchmark:
        "results/batch/benchmarks/paper_figures.tsv"
    script:
        "../../scripts/paper_figures.py"
