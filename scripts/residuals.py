"""Rule residuals: one measured channel against the exact quantizer model of its truth channel,
the effect selection, and the residual before and after."""
from enclab import io
from enclab.residuals.pipeline import analyse_channel
from enclab.runner import run


def main(smk):
    df, meta = io.read_canonical(smk.input.canonical)
    block, figures, table = analyse_channel(df, meta, dict(smk.params.pair), dict(smk.params.settings))
    io.write_table(table, smk.output.table)
    io.save_figure(figures["diagnostics"], smk.output.diagnostics)
    io.save_figure(figures["before_after"], smk.output.before_after)
    io.save_figure(figures["covariates"], smk.output.covariates)
    io.write_json(block, smk.output.block)


run(snakemake, main)  # noqa: F821
