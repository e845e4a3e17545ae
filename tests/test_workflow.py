"""End to end: the Snakemake workflow on the standard tiny workspace (tests/workspace.py).

Two short simulated Phantom runs (paper 000 stages), one paper-002 log (lrde stages, fast
sampler settings), a log with a NaN in the middle and one too short for the filters: the bad
logs fail alone with a message naming the file, the column and the row, leave no outputs,
every other log completes, and the second pass of ``make run`` (``batch_scope=completed``)
builds the batch tables, the run summary and the report without them. The runs are the
test session's (conftest.py), in the default mode and with one job per stage.
"""
import json
import re

import pandas as pd
import pytest

from workspace import run_workflow

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("mode", ["default_run", "per_rule_run"])
def test_bad_log_fails_alone_with_file_column_and_row(mode, request):
    run = request.getfixturevalue(mode)
    work = run.work
    assert run.first.returncode != 0, "the bad logs must make the first pass fail"
    assert run.second.returncode == 0, run.second.stderr[-3000:]
    assert "leaving out 2 log(s) without a summary" in run.second.stderr
    # chunked: every stage of a log in one job, its log is quantization.log
    log = "quantization.log" if mode == "default_run" else "ingest.log"
    message = (work / "results/bad/logs" / log).read_text()
    assert "bad.csv" in message and "theta2_counts" in message
    # Row 1234 of the table is line 1236 of the file (1-based, after the header line).
    assert "line 1236" in message
    assert not (work / "results/bad/canonical.parquet").exists()
    assert not (work / "results/bad/summary.json").exists()
    assert {p.name: p.read_bytes() for p in (work / "logs").iterdir()} == run.raw_before


def test_good_logs_complete_with_summary_contract(default_run):
    work = default_run.work
    summary = json.loads((work / "results/good1/summary.json").read_text())
    assert summary["log_id"] == "good1" and summary["fs_hz"] == pytest.approx(1000.0)
    assert summary["warnings"] == []
    rows = summary["quantization"]["rows"]
    position = [r for r in rows if r["order"] == 0 and r["signal"] == "x"]
    assert position, "position rows of x are missing"
    for r in position:
        # 3000 samples of a 1 mrad quantizer: the exact model is within a few per cent.
        assert r["empirical"]["std"] / r["theory"]["exact_std"] == pytest.approx(1.0, abs=0.05)
        assert r["empirical"]["max_abs"] <= r["theory"]["worst_case_trajectory"] * (1 + 1e-9)
    # 'bad' is its group's first log and failed: the figures are good1's (second pass)
    for name in ("figures/errors.png", "figures/comparison.png"):
        assert (work / "results/good1" / name).stat().st_size > 0
    batch = pd.read_csv(work / "results/batch/quantization.csv")
    assert set(batch["log_id"]) == {"good1", "good2"}
    assert (work / "results/figures/fig7_derivatives.png").exists()


def test_lrde_log_reports_offset_and_bias(default_run):
    work, params = default_run.work, default_run.lrde_params
    summary = json.loads((work / "results/lrde/summary.json").read_text())
    block = summary["lrde"]
    for key in ("A12", "E_b", "a_eq", "offset_a", "bias_b"):
        assert block[key]["q05"] <= block[key]["median"] <= block[key]["q95"]
    # An 8-cycle fit with a short chain: the stroke within 3 % of the truth (sub-per-cent
    # posterior width at 8 cycles, see bench_lrde), the offset within a tenth of a step.
    assert block["A12"]["median"] == pytest.approx(params["A12"], rel=0.03)
    assert block["offset_a"]["median"] == pytest.approx(params["offset_a"],
                                                        abs=0.1 * params["step"])
    # The residual stage of the same log (coarse against fine) reached the fit: a clean
    # encoder, so nothing was added and no term of the fit lacks its confirmation.
    reference = block["model"]["reference"]
    assert reference["truth"] == "fine" and reference["added"] == []
    assert all(r["status"] != "added from the truth channel" for r in reference["terms"])
    table = pd.read_csv(work / "results/batch/lrde.csv")
    assert set(table["log_id"]) == {"lrde"} and "A12" in set(table["quantity"])
    assert (work / "results/lrde/lrde/report.md").read_text().startswith("# Low-resolution")


def test_run_summary_names_what_ran_the_headlines_and_each_failure(default_run):
    results = default_run.work / "results"
    run = json.loads((results / "summary.json").read_text())
    assert run["logs"] == {"total": 5, "completed": 3, "failed": 2}
    failed = {f["log_id"]: f for f in run["failed"]}
    assert set(failed) == {"bad", "short"} and failed["bad"]["stage"] == "quantization"
    assert "line 1236" in failed["bad"]["error"] and "\n" not in failed["bad"]["error"]
    assert run["analyses"]["quantization"]["logs"] == 2
    assert run["analyses"]["lrde"]["rows"][0]["log_id"] == "lrde"
    assert run["analyses"]["residuals"]["rows"][0]["measured"] == "coarse"
    text = (results / "summary.txt").read_text()
    assert text.startswith("enclab: 5 logs, 3 completed, 2 failed")
    assert "bad [quantization]: logs/bad.csv: column 'theta2_counts', line 1236" in text


def test_report_opens_on_the_run_summary_with_thumbnails(default_run, tmp_path):
    # The report step of `make run`, on the shared run (it writes only the report file).
    work = default_run.work
    report = tmp_path / "report.html"
    done = run_workflow(work, "--cores", "1", "--report", str(report), "--report-metadata",
                        str(work / "results/report/metadata.yaml"), "--config",
                        "batch_scope=completed")
    assert done.returncode == 0, done.stderr[-3000:]
    html = report.read_text()
    desc = re.search(r"var workflow_desc = (.*?);\n", html).group(1)
    assert "enclab run summary" in desc and "2 failed" in desc and "line 1236" in desc
    assert re.search(r'var metadata = \{"logs completed": 3, "logs failed": 2\}', html)
    results = json.loads(re.search(r"var results = (\{.*?\});\n", html, re.S).group(1))
    figures = [path for path in results if path.endswith(".png")]
    assert figures and all(path.startswith("results/report/thumbs/") for path in figures)
    thumb = results["results/report/thumbs/log_errors/good1.png"]
    assert 'href="good1/figures/errors.png"' in thumb["caption"]  # the full-size figure
    assert "results/report/thumbs/residual_diagnostics/lrde/coarse.png" in results
    full = sum((work / "results" / p).stat().st_size for p in
               ("good1/figures/errors.png", "good1/figures/comparison.png"))
    thumbs = sum((work / p).stat().st_size for p in
                 ("results/report/thumbs/log_errors/good1.png",
                  "results/report/thumbs/log_comparison/good1.png"))
    assert thumbs < full / 4
