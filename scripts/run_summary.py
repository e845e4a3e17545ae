"""Rule run_summary: what ran, the headline number of each analysis, what failed and why
(results/summary.json, the text `make run` prints, the page the HTML report opens on)."""
from pathlib import Path

import yaml
from enclab import report
from enclab.core import atomic
from enclab.runner import run


def main(smk):
    summaries = [atomic.read_json(p) for p in smk.input.summaries]
    failures = {i: report.failure_of(atomic.read_texts(Path("results") / i / "logs", "*.log"))
                for i in smk.params.failed}
    ratios = atomic.read_table(smk.input.ratios) if "ratios" in smk.input.keys() else None
    violations = atomic.read_table(smk.input.violations) if "violations" in smk.input.keys() else None
    design = atomic.read_json(smk.input.design)["design"] if "design" in smk.input.keys() else None
    rigs = [atomic.read_json(p) for p in smk.input.rigs] if "rigs" in smk.input.keys() else None
    written = {"summary.json": len(summaries), "figures": len(smk.input.figures),
               "batch tables": len(smk.input.tables)}
    summary = report.run_summary(summaries, smk.params.log_ids, failures, ratios=ratios,
                                 violations=violations, design=design,
                                 rigs=rigs, written=written)
    atomic.write_json(summary, smk.output.summary)
    atomic.write_text(report.summary_text(summary), smk.output.text)
    atomic.write_text(report.summary_rst(summary), smk.output.page)
    atomic.write_text(yaml.safe_dump(report.report_metadata(summary), sort_keys=False),
                      smk.output.metadata)


run(snakemake, main)  # noqa: F821
