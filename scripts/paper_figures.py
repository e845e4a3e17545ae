"""Rule paper_figures: the equivalents of Colonnese & Okamura's Fig. 6 (position, per
configuration) and Fig. 7 (derivatives against the cutoff at the zero configuration)."""
from enclab.core import atomic
from enclab.propagation import plots
from enclab.runner import run


def main(smk):
    pooled = atomic.read_table(smk.input.pooled)
    fig = smk.params.figures
    atomic.save_figure(plots.fig6_position_error(pooled, level=fig["fig6_level"]), smk.output.fig6)
    atomic.save_figure(plots.fig7_derivative_error(pooled, fig["fig7_group"], level=fig["fig6_level"]),
                       smk.output.fig7)


run(snakemake, main)  # noqa: F821
