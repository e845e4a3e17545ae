# Ingest: manifest entry -> canonical Parquet (t in s, channels in SI or int64 counts).


rule ingest:
    input:
        raw_inputs,
    output:
        canonical="results/{log_id}/canonical.parquet",
    params:
        entry=entry_of,
        data_root=DATA_ROOT,
        devices=config["devices"],
        code=CODE_DIGEST,
    # before the chunks: the logs that still ingest alone lead to the longest jobs (lrde_fit)
    priority: 1
    log:
        "results/{log_id}/logs/ingest.log",
    benchmark:
        "results/{log_id}/benchmarks/ingest.tsv"
    script:
        "../../scripts/ingest.py"
