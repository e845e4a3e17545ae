# Quantization error per log: requantize -> kinematics -> derivatives / moments / theory -> summary.


rule requantize:
    input:
        canonical="results/{log_id}/canonical.parquet",
    output:
        requantized="results/{log_id}/requantized.parquet",
    params:
        requantize=config["requantize"],
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/requantize.log",
    benchmark:
        "results/{log_id}/benchmarks/requantize.tsv"
    script:
        "../../scripts/requantize.py"


rule kinematics:
    input:
        requantized="results/{log_id}/requantized.parquet",
    output:
        kinematics="results/{log_id}/kinematics.parquet",
    params:
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/kinematics.log",
    benchmark:
        "results/{log_id}/benchmarks/kinematics.tsv"
    script:
        "../../scripts/kinematics.py"


rule derivatives:
    input:
        requantized="results/{log_id}/requantized.parquet",
    output:
        derivatives="results/{log_id}/derivatives.parquet",
    params:
        export=config["derivatives"]["export"],
        derivatives=config["derivatives"],
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/derivatives.log",
    benchmark:
        "results/{log_id}/benchmarks/derivatives.tsv"
    script:
        "../../scripts/derivatives.py"


rule moments:
    input:
        requantized="results/{log_id}/requantized.parquet",
        kinematics="results/{log_id}/kinematics.parquet",
    output:
        moments="results/{log_id}/moments.json",
    params:
        derivatives=config["derivatives"],
        moments=config["moments"],
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/moments.log",
    benchmark:
        "results/{log_id}/benchmarks/moments.tsv"
    script:
        "../../scripts/moments.py"


rule theory:
    input:
        requantized="results/{log_id}/requantized.parquet",
        kinematics="results/{log_id}/kinematics.parquet",
    output:
        theory="results/{log_id}/theory.json",
    params:
        derivatives=config["derivatives"],
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/theory.log",
    benchmark:
        "results/{log_id}/benchmarks/theory.tsv"
    script:
        "../../scripts/theory.py"


rule summary:
    input:
        unpack(summary_inputs),
    output:
        summary="results/{log_id}/summary.json",
    params:
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/summary.log",
    benchmark:
        "results/{log_id}/benchmarks/summary.tsv"
    script:
        "../../scripts/summary.py"


rule log_figures:
    input:
        requantized="results/{log_id}/requantized.parquet",
        kinematics="results/{log_id}/kinematics.parquet",
        derivatives="results/{log_id}/derivatives.parquet",
        summary="results/{log_id}/summary.json",
    output:
        # in the report as thumbnails (enclab.plan.REPORT_FIGURES)
        errors="results/{log_id}/figures/errors.png",
        comparison="results/{log_id}/figures/comparison.png",
    params:
        export=config["derivatives"]["export"],
        settle_tol=config["derivatives"]["settle_tol"],
        code=CODE_DIGEST,
        source=source_of,
    log:
        "results/{log_id}/logs/log_figures.log",
    benchmark:
        "results/{log_id}/benchmarks/log_figures.tsv"
    script:
        "../../scripts/log_figures.py"
