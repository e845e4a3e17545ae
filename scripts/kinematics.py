"""Rule kinematics: operational positions of truth and levels, Jacobian at the truth."""
from enclab import analysis, io
from enclab.runner import run


def main(smk):
    req, meta = io.read_canonical(smk.input.requantized)
    io.write_canonical(analysis.kinematics_table(req, meta, meta["levels"]), meta,
                       smk.output.kinematics)


run(snakemake, main)  # noqa: F821
