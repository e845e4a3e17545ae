"""Rule theory: Table II, the exact model and the trajectory worst case for every row."""
from enclab.propagation import pipeline
from enclab.runner import run


def main(smk):
    pipeline.theory(smk.input.requantized, smk.input.kinematics, smk.params.derivatives,
                    smk.output.theory)


run(snakemake, main)  # noqa: F821
