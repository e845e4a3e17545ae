"""Rule batch_residuals: results/batch/residuals.csv, one row per log and measured channel."""
import pandas as pd
from enclab.core import atomic
from enclab.residuals.pipeline import batch_rows
from enclab.runner import run


def main(smk):
    rows = [row for path in smk.input.summaries for row in batch_rows(atomic.read_json(path))]
    atomic.write_table(pd.DataFrame(rows), smk.output.table)


run(snakemake, main)  # noqa: F821
