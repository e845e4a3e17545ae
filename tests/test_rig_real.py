"""The MRDLab rig on three of its runs (skipped when ../shared/data/real is absent).

Fit on 0.1 and 0.5 Hz, held out at 0.3 Hz (all at 10 % reaction torque): the rig model takes the
CUI channel from ~14 mrad to under 1 mrad on steady strokes of a run it never saw, and the scale
says the motor channel reads ~144 000 counts per output revolution, not 4196 x 35.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"
if not REAL.is_dir():
    pytest.skip(f"real logs not available ({REAL} is absent)", allow_module_level=True)

from enclab.core import ingest, readers  # noqa: E402
from enclab.residuals import rig  # noqa: E402
from enclab.residuals.rig_manifest import rig_groups  # noqa: E402

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
            runs[member["log_id"]] = rig.run_from_canonical(df, meta, "theta_cui", "theta_motor", ["torque_back"],
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
