"""Rule theory: Table II, the exact model and the trajectory worst case for every row."""
from enclab import analysis, io
from enclab.runner import run


def main(smk):
    req, meta = io.read_canonical(smk.input.requantized)
    kin, _ = io.read_canonical(smk.input.kinematics)
    d = smk.params.derivatives
    analysis.check_cutoffs(d, meta)
    rows = analysis.theory_rows(req, kin, meta, meta["levels"], analysis.filter_bank(d),
                                d["architectures"], settle_tol=d["settle_tol"])
    io.write_json({"log_id": meta["log_id"], "rows": rows}, smk.output.theory)


run(snakemake, main)  # noqa: F821
