# Rig fit: the runs a manifest groups with a `rig` key, fitted together per measured channel
# (docs/residuals.md "Rigs"). No rig in the manifest, no job.


rule rig:
    input:
        canonical=lambda wc: [f"results/{r['log_id']}/canonical.parquet" for r in RIGS[wc.rig]["runs"]],
    output:
        block="results/rigs/{rig}/{channel}/rig.json",
        report=report("results/rigs/{rig}/{channel}/report.md", category=REPORT_CATEGORIES["rig"],
                      subcategory="{rig}",
                      caption="../report/rig_report.rst"),
        heldout="results/rigs/{rig}/{channel}/heldout.csv",
        splits="results/rigs/{rig}/{channel}/splits.csv",
        conditions="results/rigs/{rig}/{channel}/conditions.csv",
        # figures: in the report as thumbnails (enclab.plan.REPORT_FIGURES)
        map="results/rigs/{rig}/{channel}/map.png",
        compliance="results/rigs/{rig}/{channel}/compliance.png",
        heldout_png="results/rigs/{rig}/{channel}/heldout.png",
        remains="results/rigs/{rig}/{channel}/remains.png",
    params:
        runs=lambda wc: RIGS[wc.rig]["runs"],
        pair=lambda wc: rig_pair(wc),
        compliance=lambda wc: RIGS[wc.rig]["compliance"],
        splits=lambda wc: RIGS[wc.rig]["splits"],
        settings=config.get("rig") or {},
        truth_counts_per_rev=lambda wc: rig_truth_cpr(wc),
        code=CODE_DIGEST,
    threads: 1
    log:
        "results/rigs/{rig}/logs/rig_{channel}.log",
    benchmark:
        "results/rigs/{rig}/benchmarks/rig_{channel}.tsv"
    script:
        "../../scripts/rig.py"


wildcard_constraints:
    rig=ids_regex(RIGS),
