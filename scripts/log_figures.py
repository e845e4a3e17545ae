"""Rule log_figures: error traces and the theory-vs-measured comparison of one log."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.log_figures(dict(smk.input.items()), smk.params.export, smk.params.settle_tol,
                         smk.output.errors, smk.output.comparison)


run(snakemake, main)  # noqa: F821
