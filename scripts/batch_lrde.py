"""Rule batch_lrde: the lrde block of every summary.json -> one row per log and quantity."""
import pandas as pd
from enclab.core import atomic
from enclab.lrde.report import batch_rows
from enclab.runner import run


def main(smk):
    rows = []
    for path in smk.input.summaries:
        summary = atomic.read_json(path)
        rows += batch_rows(summary["log_id"], summary["lrde"])
    atomic.write_table(pd.DataFrame(rows), smk.output.table)


run(snakemake, main)  # noqa: F821
