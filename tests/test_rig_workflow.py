"""The rig rule end to end on a tiny simulated rig (4 runs of 4 s), and the manifest's rig key.

Only the rig report is asked for: ingest of the 4 runs and the rig job run, nothing else.
"""
from __future__ import annotations

import json
import subprocess

import numpy as np
import pandas as pd
import pytest
import yaml

from enclab.rig import fit as rig
from enclab.rig.manifest import rig_groups
from workspace import ROOT, snakemake_command

STEP = 2 * np.pi / 8192
TRUTH_STEP = 2 * np.pi / 146860
TORQUE_STEP = 1e-5
CONDS = [{"frequency_hz": f, "load": L} for f, L in ((0.5, 0.0), (0.75, 0.3), (1.0, 0.6), (0.75, 0.0))]
RIG = {"name": "simrig", "compliance": {"torque_back": ["linear"]},
       "splits": [{"name": "frequency", "by": "frequency_hz", "train": [0.5, 1.0], "test": [0.75]}]}


def entry(i: int, cond: dict) -> dict:
    return {"id": f"run{i}", "file": f"run{i}.csv", "format": "csv",
            "time": {"column": "t", "unit": "s", "nominal_rate_hz": 1000.0},
            "channels": [
                {"name": "theta_in", "column": "truth", "role": "truth", "joint": 1, "unit": "counts",
                 "step": TRUTH_STEP},
                {"name": "theta_out", "column": "out", "role": "measured", "joint": 1, "unit": "counts",
                 "step": STEP},
                {"name": "torque_back", "column": "tb", "role": "aux", "unit": "counts", "step": TORQUE_STEP}],
            "rig": {**RIG, "conditions": {"frequency_hz": cond["frequency_hz"], "load_pct": cond["load"]}}}


def test_rig_groups_checks_the_manifest():
    entries = [entry(i, c) for i, c in enumerate(CONDS)]
    groups = rig_groups(entries)
    assert list(groups) == ["simrig"] and len(groups["simrig"]["runs"]) == 4
    assert groups["simrig"]["pairs"] == [{"measured": "theta_out", "truth": "theta_in"}]
    odd = [entry(i, c) for i, c in enumerate(CONDS)]
    odd[2]["rig"] = {**odd[2]["rig"], "compliance": {}}
    with pytest.raises(ValueError, match="log 'run2', key rig.compliance: differs from log 'run0'"):
        rig_groups(odd)
    with pytest.raises(ValueError, match="rig 'simrig' has one run"):
        rig_groups(entries[:1])
    bad = [entry(i, c) for i, c in enumerate(CONDS)]
    del bad[1]["rig"]["conditions"]["frequency_hz"]
    bad[1]["rig"] = {**bad[1]["rig"], "conditions": {"load_pct": 0.3}}
    with pytest.raises(ValueError, match="log 'run1', key rig.conditions: no 'frequency_hz'"):
        rig_groups(bad)
    missing = [entry(i, c) for i, c in enumerate(CONDS)]
    for e in missing:
        e["rig"] = {**e["rig"], "compliance": {"torque_front": ["linear"]}}
    with pytest.raises(ValueError, match="no channel 'torque_front'"):
        rig_groups(missing)


@pytest.mark.slow
def test_rig_rule_writes_the_report(tmp_path):
    runs = rig.simulate_rig(np.random.default_rng(3), CONDS, step=STEP, truth_step=TRUTH_STEP, scale=0.01,
                            map_fn=lambda y: 0.002 * np.sin(2 * np.pi * y / 0.3),
                            compliance={"torque_back:linear": 0.05}, play_width=0.02, latency=0.001)
    data = tmp_path / "logs"
    data.mkdir()
    for i, r in enumerate(runs):
        pd.DataFrame({"t": r.t, "truth": np.round(r.truth / TRUTH_STEP).astype(int),
                      "out": np.round(r.measured / STEP).astype(int),
                      "tb": np.round(r.torques["torque_back"] / TORQUE_STEP).astype(int)}).to_csv(
            data / f"run{i}.csv", index=False)
    (tmp_path / "manifest.yaml").write_text(yaml.safe_dump(
        {"data_root": "logs", "logs": [entry(i, c) for i, c in enumerate(CONDS)]}))
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["manifest"] = "manifest.yaml"
    config["rig"].update(spacings=[0.3, 0.1], t_skip=0.5)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    out = "results/rigs/simrig/theta_out"
    proc = subprocess.run(snakemake_command(tmp_path, f"{out}/report.md"), cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    block = json.loads((tmp_path / out / "rig.json").read_text())
    assert block["runs"] == ["run0", "run1", "run2", "run3"]
    split = block["splits"][0]
    assert split["split"] == "frequency" and split["test_runs"] == 2
    # shared terms from run0 and run2 bring the held-out runs near the quantization floor
    assert split["after_all"] < 1.5 * split["floor"] < split["before_all"]
    assert block["final"]["spacing"] == 0.1
    assert block["final"]["shared"]["torque_back:linear"] == pytest.approx(0.05, rel=0.2)
    conditions = pd.read_csv(tmp_path / out / "conditions.csv")
    assert set(conditions["condition"]) == {"frequency_hz", "load_pct"}
    # where the fit holds: the split's verdict against its training runs, what the runs covered
    ext = block["extrapolation"]
    assert [e["split"] for e in ext] == ["frequency"] and ext[0]["ratio"] == config["rig"]["extrapolation_ratio"]
    assert ext[0]["coverage"]["train"]["conditions"]["frequency_hz"] == [0.5, 1.0]
    assert block["coverage"]["conditions"]["frequency_hz"] == [0.5, 0.75, 1.0]
    report = (tmp_path / out / "report.md").read_text()
    assert "## Held out" in report and "## What remains" in report and "## Where the fit holds" in report
    for name in ("map", "compliance", "heldout", "remains"):
        assert (tmp_path / out / f"{name}.png").stat().st_size > 0
    # nothing but ingest and the rig ran
    assert not (tmp_path / "results/run0/residuals").exists()
