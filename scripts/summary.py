"""Rule summary: results/<log_id>/summary.json from the blocks of the stages the log ran."""
from enclab import log_summary
from enclab.runner import run


def main(smk):
    log_summary.summary(dict(smk.input.items()), smk.output.summary)


run(snakemake, main)  # noqa: F821
