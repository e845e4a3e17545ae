"""Rule run_summary: what ran, the headline number of each analysis, what failed and why
(results/summary.json, the text `make run` prints, the page the HTML report opens on)."""
from pathlib import Path

import yaml

from enclab import io, report
from enclab.runner import run


def main(smk):
    summaries = [io.read_json(p) for p in smk.input.summaries]
    failures = {i: report.failure_of(io.read_texts(Path("results") / i / "logs", "*.log"))
                for i in smk.params.failed}
    ratios = io.read_table(smk.input.ratios) if "ratios" in smk.input.keys() else None
    violations = io.read_table(smk.input.violations) if "violations" in smk.input.keys() else None
    design = io.read_json(smk.input.design)["design"] if "design" in smk.input.keys() else None
    written = {"summary.json": len(summaries), "figures": len(smk.input.figures),
               "batch tables": len(smk.input.tables)}
    summary = report.run_summary(summaries, smk.params.log_ids, failures, ratios=ratios,
                                 violations=violations, design=design,
                                 written=written)
    io.write_json(summary, smk.output.summary)
    io.write_text(report.summary_text(summary), smk.output.text)
    io.write_text(report.summary_rst(summary), smk.output.page)
    io.write_text(yaml.safe_dump(report.report_metadata(summary), sort_keys=False),
                  smk.output.metadata)


run(snakemake, main)  # noqa: F821
