"""Rule residuals: one measured channel against the exact quantizer model of its truth channel,
the effect selection, the residual before and after, and the angle-error map as a lookup table."""
from enclab.core import atomic, canonical
from enclab.residuals.lookup_table import table_frame
from enclab.residuals.pipeline import analyse_channel
from enclab.runner import run


def main(smk):
    df, meta = canonical.read_canonical(smk.input.canonical)
    block, figures, table = analyse_channel(df, meta, dict(smk.params.pair), dict(smk.params.settings))
    lut = block.pop("lookup_table")
    block["lookup_table"] = {"files": {"csv": str(smk.output.lut_csv), "json": str(smk.output.lut_json)},
                             "heldout_error": lut["heldout_error"], "n_entries": lut["n_entries"]}
    atomic.write_table(table_frame(lut), smk.output.lut_csv)
    atomic.write_json(lut, smk.output.lut_json)
    atomic.write_table(table, smk.output.table)
    atomic.save_figure(figures["diagnostics"], smk.output.diagnostics)
    atomic.save_figure(figures["before_after"], smk.output.before_after)
    atomic.save_figure(figures["covariates"], smk.output.covariates)
    atomic.write_json(block, smk.output.block)


run(snakemake, main)  # noqa: F821
