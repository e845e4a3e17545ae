"""Rule kinematics: operational positions of truth and levels, Jacobian at the truth."""
from enclab import stages
from enclab.runner import run


def main(smk):
    stages.kinematics(smk.input.requantized, smk.output.kinematics)


run(snakemake, main)  # noqa: F821
