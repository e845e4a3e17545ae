"""The MRDLab rig on three of its runs (skipped when ../shared/data/real is absent).

Fit on 0.1 and 0.5 Hz, held out at 0.3 Hz (all at 10 % reaction torque): the rig model takes the
CUI channel from ~14 mrad to under 1 mrad on steady strokes of a run it never saw, and the scale
says the motor channel reads ~144 000 counts per output revolution, not 4196 x 35.
"""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"
if not REAL.is_dir():
    pytest.skip(f"real logs not available ({REAL} is absent)", allow_module_level=True)

from enclab.core import ingest, readers  # noqa: E402
from enclab.rig import fit as rig  # noqa: E402
from enclab.rig.manifest import rig_groups  # noqa: E402
from enclab.rig.pipeline import run_from_canonical  # noqa: E402

pytestmark = pytest.mark.shared


def test_mrdlab_rig_held_out_run():
    devices = yaml.safe_load((REPO / "config.yaml").read_text())["devices"]
    data_root, entries = readers.read_manifest(REPO / "data" / "manifest.real.yaml", devices)
    group = rig_groups(entries)["mrdlab_tool4"]
    assert len(group["runs"]) == 20
    by_id = {e["id"]: e for e in entries}
    wanted = {"mrdlab_00": "train", "mrdlab_0p5hz": "train", "mrdlab_20": "test"}
    runs = {}
    for member in group["runs"]:
        if member["log_id"] in wanted:
            df, meta = ingest.ingest_log(by_id[member["log_id"]], REPO / data_root, devices)
            runs[member["log_id"]] = run_from_canonical(df, meta, "theta_cui", "theta_motor", ["torque_back"],
                                                        member["conditions"], member["log_id"])
    spec = rig.RigSpec(spacing=0.05, compliance={"torque_back": ["linear"]}, latency="shared")
    fit = rig.fit_rig([runs[k] for k, v in wanted.items() if v == "train"], spec)
    test = runs["mrdlab_20"]
    pred, per = rig.predict_run(fit, test)
    score = rig.score_run(test, pred, spec)
    before = rig.score_run(test, test.truth + (test.measured - test.truth).mean(), spec)
    assert before["steady_std"] > 0.01
    assert score["steady_std"] < 1.0e-3
    assert 0.02 < per["play_width"] < 0.04
    assert 144_000 < 146_860 * (1 - fit.shared()["scale"]) < 144_600


def test_second_run_set_is_a_rig_that_extrapolates_in_load():
    # Tool_4_Maryland_L_4: 5 frequencies x 10 loads, gzipped; its load split trains on loads up
    # to 50 % and tests 60-100 %, its frequency split as mrdlab_tool4's.
    devices = yaml.safe_load((REPO / "config.yaml").read_text())["devices"]
    data_root, entries = readers.read_manifest(REPO / "data" / "manifest.real.yaml", devices)
    group = rig_groups(entries)["mrdlab_tool4_l4"]
    conds = [(m["conditions"]["frequency_hz"], m["conditions"]["load_pct"]) for m in group["runs"]]
    assert sorted(conds) == [(f, L) for f in (0.1, 0.2, 0.3, 0.4, 0.5) for L in range(10, 101, 10)]
    runs = [rig.Run(run_id=m["log_id"], t=[0.0, 1.0, 2.0], truth=[0.0] * 3, measured=[0.0] * 3, step=1.0,
                    conditions=m["conditions"]) for m in group["runs"]]
    folds = {f["split"]: f for f in rig.make_folds(runs, group["splits"])}
    by_id = {r.run_id: r.conditions for r in runs}
    assert max(by_id[i]["load_pct"] for i in folds["load"]["train"]) == 50
    assert min(by_id[i]["load_pct"] for i in folds["load"]["test"]) == 60
    assert {by_id[i]["frequency_hz"] for i in folds["frequency"]["test"]} == {0.2, 0.4}
    # every run's header states the declared frequency and load
    by_entry = {e["id"]: e for e in entries}
    for m in group["runs"]:
        with gzip.open(REPO / data_root / by_entry[m["log_id"]]["file"], "rt") as fh:
            fh.readline()
            header = fh.readline()
        f, L = m["conditions"]["frequency_hz"], m["conditions"]["load_pct"]
        assert f"{f:.2f} Hz" in header and f"torque of {L:.2f} percent" in header, (m["log_id"], header)
    # the gzipped runs read as the plain ones do
    entry = by_entry["mrdlab_l4_49"]
    df, meta = ingest.ingest_log(entry, REPO / data_root, devices)
    assert 19_900 < len(df) < 20_100
    run = run_from_canonical(df, meta, "theta_cui", "theta_motor", ["torque_back"])
    assert 0.45 < np.ptp(run.truth) / 2 < 0.55  # a 30 deg (0.52 rad) sine
