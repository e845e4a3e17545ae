"""Rule derivatives: the exported derivative estimators (truth and every level)."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.derivatives(smk.input.requantized, smk.params.derivatives, smk.params.export,
                         smk.output.derivatives)


run(snakemake, main)  # noqa: F821
