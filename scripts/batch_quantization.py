"""Rule batch_quantization: every summary.json -> the batch table, the pooled table (repeat
groups) and the measured/theory ratio table."""
import pandas as pd
from enclab.core import atomic
from enclab.propagation import analysis, batch
from enclab.runner import run


def main(smk):
    table = pd.concat([analysis.summary_table(atomic.read_json(p)) for p in smk.input.summaries],
                      ignore_index=True)
    pooled = batch.pool_runs(table, ci_level=smk.params.ci_level)
    atomic.write_table(table, smk.output.table)
    atomic.write_table(pooled, smk.output.pooled)
    atomic.write_table(batch.ratio_table(pooled), smk.output.ratios)
    atomic.write_table(batch.bound_violations(table), smk.output.violations)


run(snakemake, main)  # noqa: F821
