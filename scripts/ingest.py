"""Rule ingest: one manifest entry -> results/<log_id>/canonical.parquet."""
from enclab.core.ingest import ingest_to_canonical
from enclab.runner import run


def main(smk):
    ingest_to_canonical(smk.params.entry, smk.params.data_root, smk.params.devices,
                        smk.output.canonical)


run(snakemake, main)  # noqa: F821 (injected by Snakemake)
