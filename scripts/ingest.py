"""Rule ingest: one manifest entry -> results/<log_id>/canonical.parquet."""
from enclab import io
from enclab.runner import run


def main(smk):
    df, meta = io.ingest_log(smk.params.entry, smk.params.data_root, smk.params.devices)
    io.write_canonical(df, meta, smk.output.canonical)


run(snakemake, main)  # noqa: F821 (injected by Snakemake)
