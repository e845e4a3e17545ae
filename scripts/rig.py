"""Rule rig: the runs of one rig fitted together for one measured channel; shared effects on
training runs, scored on held-out runs (docs/residuals.md "Rigs")."""
from enclab.core import atomic, canonical
from enclab.rig.pipeline import report_rig, rule_spec, run_from_canonical
from enclab.runner import run


def main(smk):
    p = smk.params
    runs = []
    for path, member in zip(smk.input.canonical, p.runs):
        df, meta = canonical.read_canonical(path)
        runs.append(run_from_canonical(df, meta, p.pair["measured"], p.pair["truth"],
                                       list(p.compliance), member["conditions"], member["log_id"]))
    s = dict(p.settings)
    spec, knots = rule_spec(s, p.compliance)
    # The compliance's form (declared, or the play take-up), the reversal transient and a torque
    # map's number of intervals are chosen per fold on its training runs, like the knot spacing.
    out = report_rig(smk.wildcards.rig, p.pair["measured"], runs, spec, list(p.splits), s["spacings"],
                     p.truth_counts_per_rev, variants="takeup", torque_knots=knots,
                     extrapolation_ratio=s["extrapolation_ratio"])
    atomic.write_json(out["block"], smk.output.block)
    for key in ("heldout", "splits", "conditions"):
        atomic.write_table(out["tables"][key], smk.output[key])
    for key in ("map", "compliance", "heldout_png", "remains"):
        atomic.save_figure(out["figures"][key.replace("_png", "")], smk.output[key])
    atomic.write_text(out["markdown"], smk.output.report)


run(snakemake, main)  # noqa: F821
