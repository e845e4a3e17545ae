"""Rule ratio_figure: measured / theory std ratios of every pooled row."""
from enclab import io, plots
from enclab.runner import run


def main(smk):
    io.save_figure(plots.ratio_figure(io.read_table(smk.input.pooled)), smk.output.ratios)


run(snakemake, main)  # noqa: F821
