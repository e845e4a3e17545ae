"""Rule batch_quantization: every summary.json -> the batch table, the pooled table (repeat
groups) and the measured/theory ratio table."""
import pandas as pd

from enclab import analysis, batch, io
from enclab.runner import run


def main(smk):
    table = pd.concat([analysis.summary_table(io.read_json(p)) for p in smk.input.summaries],
                      ignore_index=True)
    pooled = batch.pool_runs(table, ci_level=smk.params.ci_level)
    io.write_table(table, smk.output.table)
    io.write_table(pooled, smk.output.pooled)
    io.write_table(batch.ratio_table(pooled), smk.output.ratios)
    io.write_table(batch.bound_violations(table), smk.output.violations)


run(snakemake, main)  # noqa: F821
