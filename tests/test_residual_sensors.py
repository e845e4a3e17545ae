"""Sensors that are not hard quantizers: the floor's kind, the angle-error map in the forms the
field uses (harmonics of the measured angle, a lookup table), and the residual stage on them,
each against a fine reference (enclab.residuals.simulate.SENSORS)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from enclab.residuals import diagnostics as dg
from enclab.residuals import lookup_table as lut
from enclab.residuals import pipeline
from enclab.residuals.simulate import SENSORS, sensor_canonical, simulate_sensor

KINDS = {"magnetic": "both", "resolver": "noise", "potentiometer": "both", "servo": "noise"}


@pytest.fixture(scope="module")
def sims():
    return {kind: simulate_sensor(np.random.default_rng(5), kind) for kind in SENSORS}


@pytest.mark.parametrize("kind", sorted(SENSORS))
def test_floor_kind_and_noise_of_each_sensor(sims, kind):
    sim = sims[kind]
    floor = dg.estimate_floor(sim["truth"], sim["measured"], sim["step"], sim["truth_step"])
    assert floor["kind"] == KINDS[kind]
    # the variance of 8000 white samples is known to sqrt(2/N) = 1.6 % (std: 0.8 %); the
    # second-difference variogram (6 sigma^2 from three correlated samples) and the servo's
    # filtered noise (read at its plateau, ~1/(1 - pole) = 3x fewer independent samples) widen
    # that several times: 8 % on the std
    assert floor["noise_std"] == pytest.approx(sim["noise"], rel=0.08)


def test_a_hard_quantizer_is_quantization_and_a_quantizer_under_its_noise_is_noise():
    t = np.arange(8000) / 1000.0
    theta = 1.2 * np.sin(2 * np.pi * 0.4 * t)
    step = 2 * np.pi / 4096
    hard = dg.estimate_floor(theta, step * np.floor(theta / step + 0.3), step)
    assert hard["kind"] == "quantization" and hard["noise_std"] == 0.0
    assert hard["std"] == pytest.approx(step / math.sqrt(12.0))
    noisy = theta + np.random.default_rng(1).normal(0.0, 10 * step, t.size)
    fine = dg.estimate_floor(theta, step * np.round(noisy / step), step)
    assert fine["kind"] == "noise"     # a grid ten times finer than the noise: 0.29 / 10 < 0.5


@pytest.mark.parametrize("kind", sorted(SENSORS))
def test_angle_map_heldout_within_the_floor_and_table_written(sims, kind):
    sim = sims[kind]
    nuisance = None if sim["torque"] is None else (sim["torque"] < 0).astype(float)[:, None]
    fit = lut.angle_map(sim["measured"], sim["measured"] - sim["truth"], n_entries=256, max_order=8,
                        nuisance=nuisance, step=sim["step"])
    spec = SENSORS[kind]
    true_order = max([k for k, _, _ in spec.get("harmonics", [])] or [1])
    assert fit["order"] >= true_order
    # a perfect map leaves the floor; the 1.2 margin covers the fit's own variance (a few
    # dozen coefficients fitted on 4000 samples: a fraction of a percent) and the interpolation
    # error of a 256-entry table (h^2/8 |e''| = 1.5e-4 * 16 * 2 mrad = 5e-6 rad at order 4)
    assert fit["heldout_rms_table"] <= 1.2 * sim["floor_std"]
    assert fit["heldout_rms"] <= 1.2 * sim["floor_std"]
    # the map matters: without it the held-out error is several times the floor
    assert fit["heldout_rms_none"] > 2.0 * sim["floor_std"]
    doc = lut.table_document(fit, channel="measured", log_id=kind,
                             floor=dg.estimate_floor(sim["truth"], sim["measured"], sim["step"], sim["truth_step"]))
    json.dumps(doc)
    frame = lut.table_frame(doc)
    assert len(frame) == 256 and frame["angle_rad"].iloc[1] == pytest.approx(2 * np.pi / 256)
    he = doc["heldout_error"]["table"]
    assert he["arcsec"] == pytest.approx(he["rad"] * 206264.806, rel=1e-8)
    if sim["step"]:
        assert he["counts"] == pytest.approx(he["rad"] / sim["step"])
        assert doc["counts_per_rev"] == pytest.approx(2 * np.pi / sim["step"])
    else:
        assert he["counts"] is None
    # the table corrects the reading: measured + correction(measured) is the true angle up to
    # the floor, on the angles the log covers
    cov = frame["covered"].to_numpy()
    if kind != "potentiometer":
        assert cov.all()
    corr = np.interp(np.mod(sim["measured"], 2 * np.pi), np.append(frame["angle_rad"], 2 * np.pi),
                     np.append(frame["correction_rad"], frame["correction_rad"].iloc[0]))
    left = sim["measured"] + corr - sim["theta"] - sim["level_shift"]
    assert np.std(left) <= 1.2 * sim["floor_std"]


def test_table_entries_are_the_harmonics_at_the_grid_angles():
    coef = [1e-3, -2e-3, 0.0, 5e-4]
    entries = lut.lookup_entries(coef, 8)
    a = 2 * np.pi * np.arange(8) / 8
    expect = 1e-3 * np.cos(a) - 2e-3 * np.sin(a) + 5e-4 * np.sin(2 * a)
    np.testing.assert_allclose([e["error"] for e in entries], expect, rtol=0, atol=1e-18)
    np.testing.assert_allclose([e["correction"] for e in entries], -expect, rtol=0, atol=1e-18)


def test_a_partial_turn_table_holds_the_map_not_the_channels_zero_offset():
    # A 1 rad stroke: a 2nd-harmonic error of 2e-4 rad beside a 0.5 rad offset between the two
    # channels' zeros. Over a sixth of a turn the harmonics and the constant are confounded
    # (the curve's mean there is free); the table's covered entries follow the error curve
    # less its mean there, so they meet the uncovered entries (0) without a step.
    rng = np.random.default_rng(7)
    a = 0.5 + 0.5 * np.sin(2 * np.pi * np.arange(20_000) / 2_000.0)
    true_error = 2e-4 * np.sin(2 * a)
    fit = lut.angle_map(a, 0.5 + true_error + rng.normal(0.0, 2e-5, a.size), n_entries=256, max_order=4)
    cov = np.array([e["covered"] for e in fit["entries"]])
    assert 0 < cov.mean() < 0.3
    err = np.array([e["error"] for e in fit["entries"]])[cov]
    grid = 2 * np.pi * np.arange(256)[cov] / 256
    expect = 2e-4 * np.sin(2 * grid)
    # the harmonics are free over a partial turn; what a 2e-5 noise on 20,000 samples leaves
    # of the curve's shape is a few 1e-6: 2e-5 rad bounds it with a wide margin, and the
    # offset (0.5 rad) is 25,000 times that
    np.testing.assert_allclose(err - err.mean(), expect - expect.mean(), rtol=0, atol=2e-5)
    assert abs(err.mean()) < 1e-12 and fit["covered_level"] != 0.0


def test_same_grid_reference_is_analysed_and_a_coarser_one_is_named():
    rng = np.random.default_rng(2)
    step = 7.84422e-05
    theta = 0.5 * np.sin(2 * np.pi * 0.3 * np.arange(4000) / 1000.0)
    truth = step * np.round(theta / step)
    measured = step * np.round((theta + rng.normal(0.0, 3e-4, theta.size)) / step)
    # the reference's grid written with a few digits reads a hair coarser than the sensor's
    floor, step_a, ts, meas = pipeline.sensor_floor(truth, measured, step, step * (1 + 1e-7))
    assert ts == step and floor["kind"] == "noise" and step_a >= step
    # the analysis grid is a multiple of the sensor's, a quarter of the noise at most
    assert step_a / step == pytest.approx(round(step_a / step)) and step_a <= 0.25 * floor["noise_std"] + step
    with pytest.raises(ValueError, match="log 'x'.*coarser"):
        pipeline.sensor_floor(truth, measured, step, 2 * step, where="log 'x'")


@pytest.mark.slow
def test_magnetic_encoder_map_named_and_explained(sims):
    df, meta, pair, settings = sensor_canonical(sims["magnetic"], "magnetic")
    block, _, table = pipeline.analyse_channel(df, meta, pair, settings | {"seed": 1})
    names = [e["name"] for e in block["selection"]["effects"]]
    assert "harmonic_map" in names
    assert block["selection"]["explained"]
    assert block["floor_kind"] == "both"
    assert block["angle_map"]["heldout_rms_table"] <= 1.2 * sims["magnetic"]["floor_std"]
    assert len(block["lookup_table"]["entries"]) == 256
    summary = pipeline.summary_block([block])
    assert summary["channels"]["measured"]["floor_kind"] == "both"


@pytest.mark.slow
def test_servo_log_on_one_grid_gets_map_level_shift_and_heldout_figure(sims):
    sim = sims["servo"]
    df, meta, pair, settings = sensor_canonical(sim, "servo")
    block, _, _ = pipeline.analyse_channel(
        df, meta, pair, settings | {"candidates": ["angle_harmonics", "harmonic_map", "calibration_map",
                                                   "level_shift", "slow_drift", "hysteresis"]})
    by_name = {e["name"]: e for e in block["selection"]["effects"]}
    assert "level_shift" in by_name
    assert {"angle_harmonics", "harmonic_map", "calibration_map"} & set(by_name)
    shift = by_name["level_shift"]
    # at the torque's reversal; the torque goes from + to -, so the reading's rise is -d
    assert shift["derived"]["at_sign_changes"] == 1.0
    assert shift["derived"]["t_shift"] == pytest.approx(0.5 * sim["t"][-1], abs=2e-3)
    lo, hi = shift["ci"]["d"]
    assert lo <= -SENSORS["servo"]["level_shift"] <= hi
    assert block["floor_kind"] == "noise"
    held = block["angle_map"]
    assert held["heldout_rms_table"] <= 1.2 * sim["floor_std"] < held["heldout_rms_none"]
