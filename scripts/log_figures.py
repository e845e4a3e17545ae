"""Rule log_figures: error traces and the theory-vs-measured comparison of one log."""
from enclab import analysis, io, plots
from enclab.runner import run


def main(smk):
    req, meta = io.read_canonical(smk.input.requantized)
    kin, _ = io.read_canonical(smk.input.kinematics)
    deriv, _ = io.read_canonical(smk.input.derivatives)
    summary = io.read_json(smk.input.summary)
    level = meta["levels"][0]["label"]
    tr = analysis.error_traces(req, kin, deriv, meta, level, smk.params.export,
                               smk.params.settle_tol)
    title = f"{meta['log_id']}: {tr['signal']} error at {level}"
    io.save_figure(plots.error_trace_figure(tr["t"], tr["errors"], title, tr["unit"],
                                            step=tr["step"]), smk.output.errors)
    table = analysis.summary_table(summary)
    truth = analysis.truth_channels(meta)[0]
    native = truth.get("step") or truth.get("native_step")
    fig = plots.real_log_figure(table, f"{meta['log_id']}: measured vs theory",
                                native_step=native, step_unit=truth["unit"])
    io.save_figure(fig, smk.output.comparison)


run(snakemake, main)  # noqa: F821
