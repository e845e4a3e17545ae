# Design mode: the per-joint encoder resolution and the derivative filter that meet the error
# budget of config `design:` (docs/design.md), with its Pareto figure, table and design block.


rule design:
    input:
        unpack(design_inputs),
    output:
        block=report("results/design/design.json", category=REPORT_CATEGORIES["design"],
                     caption="../report/design_block.rst"),
        table=report("results/design/designs.csv", category=REPORT_CATEGORIES["design"],
                     caption="../report/design_table.rst"),
        figure="results/design/pareto.png",
    params:
        design=config.get("design"),
        devices=config["devices"],
        derivatives=config["derivatives"],
        code=CODE_DIGEST,
    log:
        "results/design/logs/design.log",
    benchmark:
        "results/design/benchmarks/design.tsv"
    script:
        "../../scripts/design.py"
