"""Ingest every real log of data/manifest.real.yaml and check it against its PROVENANCE.md.

Skipped when ../shared/data/real is absent (a fresh clone has only the small copies in data/).
Numbers quoted in the comments come from the PROVENANCE.md files or were measured on these files
with enclab (see the report of the ingest layer).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"
if not REAL.is_dir():
    pytest.skip(f"real logs not available ({REAL} is absent)", allow_module_level=True)

from enclab.core import ingest, readers  # noqa: E402

pytestmark = pytest.mark.shared
MANIFEST = REPO / "data" / "manifest.real.yaml"


@pytest.fixture(scope="module")
def logs():
    devices = yaml.safe_load((REPO / "config.yaml").read_text())["devices"]
    # data_root is relative to the repository root (the working directory of the workflow)
    data_root, entries = readers.read_manifest(MANIFEST, devices)
    data_root = REPO / data_root
    return {e["id"]: (e, *ingest.ingest_log(e, data_root, devices)) for e in entries}


def channel(meta, name):
    return next(c for c in meta["channels"] if c["name"] == name)


def angle(df, meta, name):
    return df[name].to_numpy() * channel(meta, name)["step"]


def test_every_entry_ingests_with_the_expected_size(logs):
    sizes = {log_id: (len(df), meta["n_samples"]) for log_id, (_, df, meta) in logs.items()}
    # the 50 runs of the second MRDLab run set (measured with enclab: 19 977-20 001 samples)
    second = [sizes.pop(k) for k in [k for k in sizes if k.startswith("mrdlab_l4_")]]
    assert len(second) == 50 and all(19_977 <= n == m <= 20_001 for n, m in second)
    # the other 19 runs of the MRDLab rig (measured with enclab: 19 982-20 000 samples per file)
    rig_runs = {k: sizes.pop(k)[0] for k in [k for k in sizes if k.startswith("mrdlab_") and k != "mrdlab_0p5hz"]}
    assert rig_runs == {
        "mrdlab_00": 19994, "mrdlab_01": 19996, "mrdlab_02": 20000, "mrdlab_03": 20000,
        "mrdlab_10": 19997, "mrdlab_11": 20000, "mrdlab_12": 20000, "mrdlab_13": 20000,
        "mrdlab_20": 19998, "mrdlab_21": 20000, "mrdlab_22": 19982, "mrdlab_23": 20000,
        "mrdlab_30": 19995, "mrdlab_31": 20000, "mrdlab_32": 20000, "mrdlab_33": 20000,
        "mrdlab_41": 20000, "mrdlab_42": 20000, "mrdlab_43": 19991}
    assert sizes == {
        "mrdlab_0p5hz": (19996, 19996),  # 19 994-19 998 per MRDLab file
        "encos_5hz": (6700, 6700),  # samples 600..7299 kept by the crop
        "encos_5hz_lrde": (6700, 6700),  # the same file and crop
        "franka_excitation": (20544, 20544),  # 143 808 values / 7 joints
        "emps": (24841, 24841),
        "dcmotor_pr": (20000, 20000),
    }
    for _, df, meta in logs.values():
        assert meta["time_report"]["n_backwards"] == 0
        assert df["t"].is_monotonic_increasing


def test_devices_and_stages(logs):
    assert logs["franka_excitation"][2]["device"] == {"kind": "franka_panda"}
    assert logs["emps"][2]["device"] == {"kind": "single_joint", "unit": "m"}
    assert logs["dcmotor_pr"][2]["analysis"] == {"stages": ["lrde"]}


def test_mrdlab_steps_and_rate(logs):
    _, df, meta = logs["mrdlab_0p5hz"]
    assert channel(meta, "theta_motor")["step"] == pytest.approx(2 * math.pi / (4196 * 35), rel=1e-15)
    assert channel(meta, "theta_cui")["step"] == pytest.approx(2 * math.pi / 8192, rel=1e-15)
    assert channel(meta, "theta_front")["step"] == pytest.approx(2 * math.pi / 4000, rel=1e-15)
    assert all(channel(meta, n)["storage"] == "counts" for n in ("theta_motor", "theta_cui", "theta_front"))
    # median of differences of stamps printed to 1 us (up to 20 s): float64 rounding of one
    # difference is <= 2 ulp(20 s) = 7e-15 s, 7e-12 of 1 ms; one print unit would be 1e-3
    assert meta["fs_hz"] == pytest.approx(1000.0, rel=1e-6)
    assert meta["time_report"]["jitter_rms_s"] < 1e-9  # time stamps printed to 1 us, all 1 ms apart


def test_mrdlab_channels_increase_together(logs):
    _, df, meta = logs["mrdlab_0p5hz"]
    names = ("theta_motor", "theta_cui", "theta_front")
    # 50 ms increments: many counts of motion for every channel, so the sign shows clearly
    moves = {n: np.diff(angle(df, meta, n)[::50]) for n in names}
    for a, b in [(0, 1), (0, 2), (1, 2)]:
        assert np.corrcoef(moves[names[a]], moves[names[b]])[0, 1] > 0.95


def test_mrdlab_motor_and_output_encoder_differ_by_backlash_only(logs):
    _, df, meta = logs["mrdlab_0p5hz"]
    motor, cui = angle(df, meta, "theta_motor"), angle(df, meta, "theta_cui")
    diff = motor - cui
    diff -= np.median(diff)
    velocity = np.convolve(np.diff(motor), np.ones(51) / 51, mode="same")
    rising, falling = velocity > 2e-5, velocity < -2e-5  # 2e-5 rad/ms: clearly moving
    offset_up, offset_down = np.median(diff[1:][rising]), np.median(diff[1:][falling])
    # Direction-dependent offset (backlash/compliance through the 35:1 gearbox): measured
    # +0.0149 / -0.0124 rad, i.e. a play of ~0.027 rad, larger than the ~0.008 rad read off the
    # provenance zoom plots.
    assert 0.005 < offset_up < 0.02 and -0.02 < offset_down < -0.005
    # Otherwise the two agree: the whole difference stays within that play plus 3 CUI counts
    # (measured max 0.0267 rad).
    assert np.max(np.abs(diff)) < (offset_up - offset_down) + 3 * channel(meta, "theta_cui")["step"]
    # Scale check of counts_per_rev * gear_ratio = 4196 * 35: the strokes agree to 1 %.
    assert np.ptp(motor) / np.ptp(cui) == pytest.approx(1.0, abs=0.01)


def test_encos_trailing_rows_crop_and_grid(logs):
    _, df, meta = logs["encos_5hz"]
    report = meta["time_report"]
    # 740 rows have no MotorFbPos; in 2 of them MotorCmdPos is still logged (cropped away),
    # the other 738 are empty in both channels and dropped as logger padding.
    assert report["trailing_empty_dropped"] == 738
    assert df["t"].iloc[0] == pytest.approx(0.6) and df["t"].iloc[-1] == pytest.approx(7.299)
    assert report["fs_hz"] == 1000.0 and report["n_gaps"] == 0 and report["n_repeated"] == 0
    fb = channel(meta, "theta")
    assert (fb["storage"], fb["step"]) == ("counts", 12.5 / 65536)
    assert channel(meta, "theta_cmd")["storage"] == "float"
    changes = np.diff(df["theta"].to_numpy())
    # odd multiples of 12.5/65536 are rare (0.005-0.015 %): the effective step is 25/65536 rad
    assert np.count_nonzero(changes % 2) / changes.size < 5e-4
    # A 5 Hz sine fit of the feedback checks time base and unit at once. PROVENANCE (whole sine,
    # from 0.5 s): amplitude 0.04163 rad, residual RMS 4.7e-4 rad.
    t = df["t"].to_numpy()
    basis = np.column_stack([np.sin(2 * np.pi * 5 * t), np.cos(2 * np.pi * 5 * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(basis, angle(df, meta, "theta"), rcond=None)
    residual = angle(df, meta, "theta") - basis @ coef
    assert math.hypot(coef[0], coef[1]) == pytest.approx(0.04163, abs=5e-4)
    assert np.sqrt(np.mean(residual**2)) < 6e-4


def test_franka_time_stamps_are_reported_not_rejected(logs):
    _, df, meta = logs["franka_excitation"]
    report = meta["time_report"]
    assert report["fs_hz"] == pytest.approx(1000.0, rel=1e-3)  # median step 1.000 ms
    assert report["max_gap_s"] == pytest.approx(8.81e-3, rel=1e-3)  # max step 8.8 ms
    assert report["n_gaps"] > 0 and report["jitter_rms_s"] > 1e-5
    assert all(channel(meta, f"theta{j}")["storage"] == "float" for j in range(1, 8))
    # joint ranges [rad] from PROVENANCE: q1 -2.149...0.774, q6 0.540...3.066
    for name, low, high in [("theta1", -2.149, 0.774), ("theta6", 0.540, 3.066)]:
        assert df[name].min() == pytest.approx(low, abs=1e-3)
        assert df[name].max() == pytest.approx(high, abs=1e-3)
    # ~6 % of consecutive samples repeat in every joint (logging, not quantization)
    joints = df[[f"theta{j}" for j in range(1, 8)]].to_numpy()
    repeats = np.all(np.diff(joints, axis=0) == 0, axis=1).mean()
    assert 0.05 < repeats < 0.08


def test_emps_grid_is_detected(logs):
    _, df, meta = logs["emps"]
    x = channel(meta, "x")
    assert (x["unit"], x["storage"]) == ("m", "counts")
    assert x["step"] == pytest.approx(5e-8, rel=1e-9)
    position = angle(df, meta, "x")
    # PROVENANCE's range "0...0.2464 m" is rounded: the file's extremes are -2.2e-5 and 0.246378 m
    assert position.min() == pytest.approx(-2.2e-5, abs=1e-9)
    assert position.max() == pytest.approx(0.24637775, abs=1e-9)
    assert meta["time_report"]["nominal_rate_hz"] == 1000.0


def test_dcmotor_levels_and_reference(logs):
    _, df, meta = logs["dcmotor_pr"]
    y = channel(meta, "theta")
    assert (y["role"], y["storage"]) == ("measured", "counts")
    assert y["step"] == pytest.approx(math.radians(450 / 128), rel=1e-15)
    assert df["theta"].nunique() == 54  # 54 distinct values per PROVENANCE
    assert meta["fs_hz"] == 500.0
    # 90 deg reference sine: peak 90.005 deg per PROVENANCE
    assert df["theta_ref"].abs().max() == pytest.approx(math.radians(90.0), abs=math.radians(0.05))
