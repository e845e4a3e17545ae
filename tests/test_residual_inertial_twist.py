"""The inertial twist (enclab.residuals.effects.InertialTwist) against a brute-force simulation:
a shaft that twists by ``c`` times the angular acceleration, with the acceleration written out
analytically rather than taken from the selection's smooth reconstruction."""
from __future__ import annotations

import numpy as np
from scipy import stats

from enclab.residuals import effects as fx
from enclab.residuals.select import select_effects

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8
Z90 = stats.norm.ppf(0.95)
# two tones: the acceleration is no multiple of the angle, so the twist is no scale error
TONES = ((0.4, 0.7, 0.0), (0.2, 1.9, 0.5))  # amplitude (rad), frequency (Hz), phase


def _twisted_log(seed, c, duration=6.0, fs_hz=1000.0):
    t = np.arange(int(duration * fs_hz)) / fs_hz
    w = [2 * np.pi * f for _, f, _ in TONES]
    theta = sum(a * np.sin(wk * t + p) for (a, _, p), wk in zip(TONES, w))
    acc = sum(-a * wk * wk * np.sin(wk * t + p) for (a, _, p), wk in zip(TONES, w))
    offset = np.random.default_rng(seed).uniform()
    counts = np.floor((theta - c * (acc - acc.mean())) / STEP + offset)
    truth = TRUTH_STEP * np.round(theta / TRUTH_STEP)
    return t, truth, STEP * counts


def test_inertial_twist_is_found_on_a_brute_force_simulated_log():
    c = 1.2e-4  # s^2: up to 2.5 steps of twist where the motion turns fastest
    t, truth, measured = _twisted_log(41, c)
    res = select_effects(t, truth, measured, STEP, truth_step=TRUTH_STEP,
                         candidates=["inertial_twist", "latency", "scale_mismatch"])
    assert [e.name for e in res.effects] == ["inertial_twist"]
    (e,) = res.effects
    lo, hi = e.ci["c"]
    se = (hi - lo) / (2 * Z90)
    assert abs(e.params["c"] - c) <= 4 * se and se < 0.05 * c
    # the acceleration is the derivative of a smoothed velocity, a few hundredths of a step of
    # twist off here: the residual falls by a factor of 6.7, to 1.3 times the exact-model floor
    assert res.after["std"] < 0.2 * res.before["std"]


def test_inertial_twist_is_tried_only_when_named():
    assert not fx.InertialTwist.default and fx.REGISTRY["inertial_twist"] is fx.InertialTwist
    t, truth, measured = _twisted_log(42, 1.2e-4, duration=3.0)
    res = select_effects(t, truth, measured, STEP, truth_step=TRUTH_STEP)
    assert "inertial_twist" not in {r.get("effect") for r in res.steps}
    res = select_effects(t, truth, measured, STEP, truth_step=TRUTH_STEP,
                         candidates=["inertial_twist", "angle_harmonics"])
    assert [e.name for e in res.effects] == ["inertial_twist"]
