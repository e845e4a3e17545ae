"""Rule moments: empirical error moments over the whole derivative-filter bank."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.moments(smk.input.requantized, smk.input.kinematics, smk.params.derivatives,
                     smk.params.moments, smk.output.moments)


run(snakemake, main)  # noqa: F821
