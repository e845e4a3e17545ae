"""End to end: the Snakemake workflow on a tiny manifest in a temporary directory.

One short simulated Phantom run (paper 000 stages), one paper-002 log (lrde stages, fast
sampler settings) and one log with a NaN in the middle: the bad log fails alone with a message
naming the file, the column and the row, leaves no outputs, every other log completes, and the
second pass of ``make run`` (``batch_scope=completed``) builds the batch tables without it.
"""
import json
import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from enclab import io
from enclab.lrde import simulate as lrde_sim
from enclab.simulate import phantom_protocol_run
from workspace import SNAKEMAKE, lrde_entry, phantom_entry, snakemake_command, write_workspace

pytestmark = pytest.mark.slow

@pytest.fixture(scope="module")
def workflow_run(tmp_path_factory):
    if not SNAKEMAKE.exists():
        pytest.fail(f"snakemake is not installed next to {sys.executable}")
    work = tmp_path_factory.mktemp("workflow")
    data = work / "logs"
    data.mkdir()
    log, _ = phantom_protocol_run(np.zeros(3), np.random.default_rng(3), duration_s=3.0)
    io.write_table(log, data / "good.parquet")
    bad = log.astype({"theta2_counts": float})
    bad.loc[1234, "theta2_counts"] = np.nan
    bad.to_csv(data / "bad.csv", index=False)
    step = lrde_sim.ROS_DRILL_STEP
    lrde_log, lrde_params = lrde_sim.open_loop_log(np.random.default_rng(5), bias=0.1 * step,
                                                   n_cycles=8, noise_std=0.01 * step,
                                                   truth_step=step / 100)
    io.write_table(lrde_log, data / "lrde.parquet")
    bad_entry = phantom_entry("bad", "bad.csv", "tiny") | {"format": "csv"}
    write_workspace(work, [phantom_entry("good", "good.parquet", "tiny"), bad_entry,
                           lrde_entry("lrde", "lrde.parquet")], fig7_group="tiny")
    raw_before = {p.name: p.read_bytes() for p in data.iterdir()}
    env = dict(os.environ, MPLBACKEND="Agg")
    command = snakemake_command(work, "--keep-going")
    # The two passes of `make run`: everything, then the batch over the logs that completed.
    first = subprocess.run(command, cwd=work, capture_output=True, text=True, env=env,
                           timeout=900)
    second = subprocess.run(command + ["--config", "batch_scope=completed"], cwd=work,
                            capture_output=True, text=True, env=env, timeout=900)
    return work, (first, second), raw_before, lrde_params


def test_bad_log_fails_alone_with_file_column_and_row(workflow_run):
    work, (first, second), raw_before, _ = workflow_run
    assert first.returncode != 0, "the bad log must make the first pass fail"
    assert second.returncode == 0, second.stderr[-3000:]
    assert "leaving out 1 log(s) without a summary" in second.stderr and "bad" in second.stderr
    message = (work / "results/bad/logs/ingest.log").read_text()
    assert "bad.csv" in message and "theta2_counts" in message
    # Row 1234 of the table is line 1236 of the file (1-based, after the header line).
    assert "1236" in message or "1234" in message
    assert not (work / "results/bad/canonical.parquet").exists()
    assert not (work / "results/bad/summary.json").exists()
    assert {p.name: p.read_bytes() for p in (work / "logs").iterdir()} == raw_before


def test_good_logs_complete_with_summary_contract(workflow_run):
    work, _, _, _ = workflow_run
    summary = json.loads((work / "results/good/summary.json").read_text())
    assert summary["log_id"] == "good" and summary["fs_hz"] == pytest.approx(1000.0)
    rows = summary["quantization"]["rows"]
    position = [r for r in rows if r["order"] == 0 and r["signal"] == "x"]
    assert position, "position rows of x are missing"
    for r in position:
        # 3000 samples of a 1 mrad quantizer: the exact model is within a few per cent.
        assert r["empirical"]["std"] / r["theory"]["exact_std"] == pytest.approx(1.0, abs=0.05)
        assert r["empirical"]["max_abs"] <= r["theory"]["worst_case_trajectory"] * (1 + 1e-9)
    for name in ("figures/errors.png", "figures/comparison.png"):
        assert (work / "results/good" / name).stat().st_size > 0
    batch = pd.read_csv(work / "results/batch/quantization.csv")
    assert set(batch["log_id"]) == {"good"}
    assert (work / "results/figures/fig7_derivatives.png").exists()


def test_lrde_log_reports_offset_and_bias(workflow_run):
    work, _, _, params = workflow_run
    summary = json.loads((work / "results/lrde/summary.json").read_text())
    block = summary["lrde"]
    for key in ("A12", "E_b", "a_eq", "offset_a", "bias_b"):
        assert block[key]["q05"] <= block[key]["median"] <= block[key]["q95"]
    # An 8-cycle fit with a short chain: the stroke within 3 % of the truth (sub-per-cent
    # posterior width at 8 cycles, see bench_lrde), the offset within a tenth of a step.
    assert block["A12"]["median"] == pytest.approx(params["A12"], rel=0.03)
    assert block["offset_a"]["median"] == pytest.approx(params["offset_a"],
                                                        abs=0.1 * params["step"])
    table = pd.read_csv(work / "results/batch/lrde.csv")
    assert set(table["log_id"]) == {"lrde"} and "A12" in set(table["quantity"])
    assert (work / "results/lrde/lrde/report.md").read_text().startswith("# Low-resolution")
