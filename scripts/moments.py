"""Rule moments: empirical error moments over the whole derivative-filter bank."""
from enclab import analysis, io
from enclab.runner import run


def main(smk):
    req, meta = io.read_canonical(smk.input.requantized)
    kin, _ = io.read_canonical(smk.input.kinematics)
    p = smk.params
    analysis.check_cutoffs(p.derivatives, meta)
    rows = analysis.empirical_rows(
        req, kin, meta, meta["levels"], analysis.filter_bank(p.derivatives),
        p.derivatives["architectures"], settle_tol=p.derivatives["settle_tol"],
        ci_level=p.moments["ci_level"], n_batches=p.moments["n_batches"])
    io.write_json({"log_id": meta["log_id"], "rows": rows}, smk.output.moments)


run(snakemake, main)  # noqa: F821
