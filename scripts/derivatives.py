"""Rule derivatives: the exported derivative estimators (truth and every level)."""
from enclab import analysis, io
from enclab.runner import run


def main(smk):
    req, meta = io.read_canonical(smk.input.requantized)
    analysis.check_cutoffs(smk.params.derivatives, meta)
    table = analysis.export_derivatives(req, meta, meta["levels"], smk.params.export)
    io.write_canonical(table, meta, smk.output.derivatives)


run(snakemake, main)  # noqa: F821
