"""Rule residuals: one measured channel against the exact quantizer model of its truth channel,
the effect selection, and the residual before and after."""
from enclab.core import atomic, canonical
from enclab.residuals.pipeline import analyse_channel
from enclab.runner import run


def main(smk):
    df, meta = canonical.read_canonical(smk.input.canonical)
    block, figures, table = analyse_channel(df, meta, dict(smk.params.pair), dict(smk.params.settings))
    atomic.write_table(table, smk.output.table)
    atomic.save_figure(figures["diagnostics"], smk.output.diagnostics)
    atomic.save_figure(figures["before_after"], smk.output.before_after)
    atomic.save_figure(figures["covariates"], smk.output.covariates)
    atomic.write_json(block, smk.output.block)


run(snakemake, main)  # noqa: F821
