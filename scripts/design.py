"""Rule design: config design: block -> design.json (the design block), designs.csv, pareto.png."""
from enclab.core import atomic, canonical
from enclab.design.pipeline import run_design, truth_trajectory
from enclab.runner import run


def main(smk):
    trajectory = None
    if "canonical" in smk.input.keys():
        trajectory = truth_trajectory(*canonical.read_canonical(smk.input.canonical))
    block, table, figure = run_design(smk.params.design, smk.params.devices, smk.params.derivatives,
                                      trajectory)
    atomic.write_json(block, smk.output.block)
    atomic.write_table(table, smk.output.table)
    atomic.save_figure(figure, smk.output.figure)


run(snakemake, main)  # noqa: F821
