"""Rule summary: results/<log_id>/summary.json from the blocks of the stages the log ran."""
from enclab import analysis, io
from enclab.residuals.pipeline import summary_block
from enclab.runner import run


def main(smk):
    inputs = dict(smk.input.items())
    if "moments" in inputs:
        req, meta = io.read_canonical(inputs["requantized"])
        summary = analysis.build_summary(
            meta, meta["levels"], io.read_json(inputs["moments"])["rows"],
            io.read_json(inputs["theory"])["rows"], analysis.centre_of(req, meta))
    else:
        _, meta = io.read_canonical(inputs["canonical"])
        summary = analysis.log_header(meta)
    if "lrde" in inputs:
        summary["lrde"] = io.read_json(inputs["lrde"])
    if "residuals" in inputs:
        paths = smk.input.residuals
        paths = [paths] if isinstance(paths, str) else list(paths)
        summary["residuals"] = summary_block([io.read_json(p) for p in paths])
    if "residuals" not in summary and (summary.get("lrde") or {}).get("residuals"):
        # A coarse log without a truth/measured pair: its residual analysis is the held-out
        # motion-model comparison of the lrde stage (enclab.lrde.compare).
        summary["residuals"] = summary["lrde"]["residuals"]
    io.write_json(summary, smk.output.summary)


run(snakemake, main)  # noqa: F821
