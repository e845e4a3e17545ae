"""Rule kinematics: operational positions of truth and levels, Jacobian at the truth."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.kinematics(smk.input.requantized, smk.output.kinematics)


run(snakemake, main)  # noqa: F821
