"""Rule ingest: one manifest entry -> results/<log_id>/canonical.parquet."""
from enclab import stages
from enclab.runner import run


def main(smk):
    stages.ingest(smk.params.entry, smk.params.data_root, smk.params.devices,
                  smk.output.canonical)


run(snakemake, main)  # noqa: F821 (injected by Snakemake)
