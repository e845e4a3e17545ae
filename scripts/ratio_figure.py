"""Rule ratio_figure: measured / theory std ratios of every pooled row."""
from enclab.core import atomic
from enclab.propagation import plots
from enclab.runner import run


def main(smk):
    atomic.save_figure(plots.ratio_figure(atomic.read_table(smk.input.pooled)), smk.output.ratios)


run(snakemake, main)  # noqa: F821
