"""Simulated two-channel logs (fine truth channel, coarse measured channel) with known effects.

The continuous motion ``theta(t)`` is a callable so that latency and timestamp jitter are
simulated exactly (``theta(t - tau)``, ``theta(t + N(0, sigma_t^2))``), not through the
first-order terms the model uses. The truth channel is ``truth_step * round(theta / truth_step)``;
the measured channel ``step * floor(theta_eff / step + c)`` with the effects applied to the
continuous angle.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import CubicSpline

from enclab.residuals import effects as fx

__all__ = ["random_motion", "random_torque", "random_map", "simulate_log", "SENSORS", "simulate_sensor", "sensor_canonical"]


def random_motion(rng: np.random.Generator, kind: str, duration: float, amplitude: float, centre: float = 0.0):
    """A smooth motion callable ``theta(t)`` (rad) of one of three kinds.

    ``"sine"``: one sine of 0.3-1.5 Hz; ``"multisine"``: three sines of 0.2-2 Hz with amplitudes
    summing to ``amplitude``; ``"smooth"``: random-phase sum of 8 sines with 1/f amplitudes
    between 0.1 and 1.5 Hz (a random smooth path), scaled to peak ``amplitude``.
    """
    if kind == "sine":
        f = rng.uniform(0.3, 1.5)
        ph = rng.uniform(0, 2 * np.pi)
        return lambda t: centre + amplitude * np.sin(2 * np.pi * f * t + ph)
    if kind == "multisine":
        fs = rng.uniform(0.2, 2.0, 3)
        w = rng.dirichlet(np.ones(3)) * amplitude
        ph = rng.uniform(0, 2 * np.pi, 3)
        return lambda t: centre + sum(w[i] * np.sin(2 * np.pi * fs[i] * np.asarray(t) + ph[i]) for i in range(3))
    if kind == "smooth":
        fs = np.linspace(0.1, 1.5, 8) * rng.uniform(0.9, 1.1, 8)
        a = 1.0 / fs
        ph = rng.uniform(0, 2 * np.pi, 8)
        tt = np.linspace(0, duration, 2001)
        raw = sum(a[i] * np.sin(2 * np.pi * fs[i] * tt + ph[i]) for i in range(8))
        scale = amplitude / float(np.max(np.abs(raw)))
        return lambda t: centre + scale * sum(a[i] * np.sin(2 * np.pi * fs[i] * np.asarray(t) + ph[i]) for i in range(8))
    raise ValueError(f"unknown motion kind {kind!r}; use 'sine', 'multisine' or 'smooth'")


def random_torque(rng: np.random.Generator, motion, t, peak: float):
    """Joint torque (N m) of a motion: inertia, viscous and Coulomb friction and gravity.

    ``T = J a + b v + T_c tanh(v / 0.05) + T_g sin(theta)`` with the velocity and acceleration of
    ``motion`` (central differences of the callable, 0.1 ms), random positive ``J, b, T_c, T_g``
    of comparable shares, scaled to a largest ``|T|`` of ``peak``.
    """
    t = np.asarray(t, dtype=float)
    h = 1e-4
    th = np.asarray(motion(t), dtype=float)
    v = (np.asarray(motion(t + h)) - np.asarray(motion(t - h))) / (2 * h)
    a = (np.asarray(motion(t + h)) - 2 * th + np.asarray(motion(t - h))) / (h * h)
    parts = [a, v, np.tanh(v / 0.05), np.sin(th)]
    w = rng.uniform(0.2, 1.0, len(parts))
    tq = sum(wi * p / max(float(np.max(np.abs(p))), 1e-12) for wi, p in zip(w, parts))
    return peak * tq / float(np.max(np.abs(tq)))


def random_map(rng: np.random.Generator, lo: float, hi: float, peak_to_peak: float, spacing: float):
    """A smooth calibration map over ``[lo, hi]``: ``{knots, values}`` for :func:`simulate_log`.

    Random values at knots about ``spacing`` apart (a not-a-knot cubic spline through them),
    their least-squares constant and slope over a uniform grid of ``[lo, hi]`` removed (those
    are a quantizer offset and a scale mismatch, not a map), scaled to ``peak_to_peak`` (rad).
    """
    n = max(int(np.ceil((hi - lo) / spacing)), 3)
    knots = np.linspace(lo, hi, n + 1)
    values = rng.normal(0.0, 1.0, knots.size)
    grid = np.linspace(lo, hi, 2001)
    curve = CubicSpline(knots, values)(grid)
    A = np.column_stack([np.ones_like(grid), grid])
    coef, *_ = np.linalg.lstsq(A, curve, rcond=None)
    # a spline through (values - line at the knots) is the spline minus the line: exact removal
    values = values - (coef[0] + coef[1] * knots)
    scale = peak_to_peak / float(np.ptp(CubicSpline(knots, values)(grid)))
    return {"knots": [float(k) for k in knots], "values": [float(v) * scale for v in values]}


def simulate_log(
    rng: np.random.Generator,
    motion,
    *,
    duration: float = 10.0,
    fs_hz: float = 1000.0,
    step: float,
    truth_step: float,
    effects: dict | None = None,
    offset_frac: float | None = None,
    torque=None,
):
    """One simulated log with the effects ``{name: params}`` applied to the measured channel.

    Supported names and parameters (SI): ``hysteresis {h}``, ``backlash {w}``,
    ``angle_harmonics {a1, b1, a2, b2}``, ``line_pitch_harmonics {a, b, pitch}``,
    ``quadrature_edges {e0, e1, e2}``, ``latency {tau}``, ``timestamp_jitter {sigma_t}``,
    ``scale_mismatch {g}``, ``compliance {kappa}`` and ``compliance_softening {k1, k2}``
    (``k1 T + k2 T|T|``; both need ``torque``, the true torque, which the effect follows),
    ``calibration_map {knots, values}`` (a not-a-knot cubic spline through ``values`` at the
    angles ``knots``, held at its end values outside them), ``slow_drift {rate, quad}``
    (``rate (t - t_mid) + quad (t - t_mid)^2``, rad/s and rad/s^2), ``level_shift {time, size}``
    (the reading ``size`` rad higher from ``time`` on) or ``level_shift {torque, size}`` (half of
    ``size`` times the sign of the given torque array), ``missed_counts {times,
    jumps}``, ``wrap_around {period}``.

    Returns
    -------
    dict
        ``t``, ``theta`` (continuous), ``truth``, ``measured`` (rad), ``counts``, ``offset_frac``.
    """
    effects = dict(effects or {})
    n = int(round(duration * fs_hz))
    t = np.arange(n) / fs_hz
    c = rng.uniform(0.0, 1.0) if offset_frac is None else float(offset_frac)
    theta = np.asarray(motion(t), dtype=float)
    truth = truth_step * np.round(theta / truth_step)
    te = theta.copy()
    if "latency" in effects:
        te = np.asarray(motion(t - effects["latency"]["tau"]), dtype=float)
    if "timestamp_jitter" in effects:
        te = np.asarray(motion(t + rng.normal(0.0, effects["timestamp_jitter"]["sigma_t"], n)), dtype=float)
    if "hysteresis" in effects:
        v = np.gradient(theta, t)
        te = te - 0.5 * effects["hysteresis"]["h"] * fx.motion_sign(v)
    if "backlash" in effects:
        w = effects["backlash"]["w"]
        p = fx.play_operator(te, abs(w))
        te = p if w >= 0 else 2 * te - p
    if "compliance" in effects:
        tq = np.asarray(torque, dtype=float)
        te = te + effects["compliance"]["kappa"] * (tq - tq.mean())
    if "compliance_softening" in effects:
        tq = np.asarray(torque, dtype=float)
        p = effects["compliance_softening"]
        te = te + p["k1"] * tq + p["k2"] * tq * np.abs(tq)
    if "scale_mismatch" in effects:
        te = te + effects["scale_mismatch"]["g"] * (te - truth.mean())
    if "angle_harmonics" in effects:
        p = effects["angle_harmonics"]
        te = te + p.get("a1", 0) * np.cos(te) + p.get("b1", 0) * np.sin(te) + p.get("a2", 0) * np.cos(2 * te) + p.get("b2", 0) * np.sin(2 * te)
    if "calibration_map" in effects:
        p = effects["calibration_map"]
        knots = np.asarray(p["knots"], dtype=float)
        spline = CubicSpline(knots, np.asarray(p["values"], dtype=float))
        te = te + spline(np.clip(te, knots[0], knots[-1]))
    if "line_pitch_harmonics" in effects:
        p = effects["line_pitch_harmonics"]
        w = 2 * np.pi * te / p.get("pitch", 4 * step)
        te = te + p.get("a", 0) * np.cos(w) + p.get("b", 0) * np.sin(w)
    if "slow_drift" in effects:
        p = effects["slow_drift"]
        tm = t - 0.5 * (t[0] + t[-1])
        te = te + p.get("rate", 0.0) * tm + p.get("quad", 0.0) * tm**2
    if "level_shift" in effects:
        p = effects["level_shift"]
        if "torque" in p:  # a preload taken up at every reversal of the torque
            tq = np.asarray(p["torque"], dtype=float)
            te = te + 0.5 * p["size"] * np.sign(tq)
        else:
            te = te + p["size"] * (t >= p["time"])
    counts = np.floor(te / step + c).astype(np.int64)
    if "quadrature_edges" in effects:
        p = effects["quadrature_edges"]
        e = np.array([p["e0"], p["e1"], p["e2"], -(p["e0"] + p["e1"] + p["e2"])])
        # exact edge displacement: count m is entered at theta = (m - c) step + e_{m mod 4}
        base = np.floor(te / step + c).astype(np.int64)
        up = base + 1
        counts = np.where(te >= (up - c) * step + e[up % 4], up, base)
        counts = np.where(te < (base - c) * step + e[base % 4], base - 1, counts)
    if "missed_counts" in effects:
        p = effects["missed_counts"]
        for tj, nj in zip(p["times"], p["jumps"]):
            counts = counts - int(nj) * (t >= tj)
    measured = step * counts
    if "wrap_around" in effects:
        period = effects["wrap_around"]["period"]
        measured = np.mod(measured + 0.5 * period, period) - 0.5 * period
        # keep the wrapped reading on the grid of step
        measured = step * np.round(measured / step)
        counts = np.round(measured / step).astype(np.int64)
    return {"t": t, "theta": theta, "truth": truth, "measured": measured, "counts": counts, "offset_frac": c}


#: Sensors that are not hard quantizers, each against a fine reference (:func:`simulate_sensor`).
#: ``step`` is the sensor's output grid (None: a continuous output), ``noise`` its white noise
#: std (rad; ``filter`` > 0 makes it a first-order low-pass noise of that pole with the same
#: std), ``harmonics`` the angle error ``[(k, a_k, b_k)]`` (rad, of the true angle), ``poly``
#: a nonlinear map ``sum c_j (theta / half_stroke)^j`` (rad), ``motion`` ``turn`` (a shaft
#: rotating at a varying speed over several turns) or ``swing`` (a sine over ``stroke`` rad).
SENSORS = {
    # interpolating magnetic encoder, 14-bit output, 1st-4th harmonic error (eccentricity,
    # magnet tilt, the sensor's own twice-per-turn error) and noise of about half a count
    "magnetic": {"step": 2 * np.pi / 2**14, "noise": 2.0e-4, "filter": 0.0, "motion": "turn",
                 "harmonics": [(1, 2.0e-3, -1.0e-3), (2, 8.0e-4, 6.0e-4), (3, -4.0e-4, 3.0e-4),
                               (4, 3.0e-4, 2.0e-4)]},
    # resolver read by a resolver-to-digital converter as a float: twice-per-turn error, noise
    "resolver": {"step": None, "noise": 6.0e-5, "filter": 0.0, "motion": "turn",
                 "harmonics": [(2, 1.2e-3, -7.0e-4)]},
    # potentiometer on a 12-bit ADC over its 300 degree track: a nonlinear track and noise
    "potentiometer": {"step": np.deg2rad(300.0) / 2**12, "noise": 6.0e-4, "filter": 0.0, "motion": "swing",
                      "stroke": np.deg2rad(270.0), "poly": [0.0, 0.0, 4.0e-3, 2.5e-3]},
    # servo: output-side sensor read through an ADC and filtered, against the motor encoder
    # through the gear, both stored on one 1/32-unit grid; constant torque one way, then the
    # other (a preload taken up: a level shift halfway)
    "servo": {"step": 2 * np.pi / 80000, "noise": 2.0e-4, "filter": 0.7, "motion": "turn",
              "harmonics": [(1, 1.5e-3, 5.0e-4)], "level_shift": 9.0e-4},
}


def simulate_sensor(rng: np.random.Generator, kind: str, *, duration: float = 8.0, fs_hz: float = 1000.0,
                    truth_step: float | None = None, spec: dict | None = None) -> dict:
    """One log of a sensor of :data:`SENSORS` (or ``spec``) against a fine reference.

    The true angle follows the sensor's motion; the reference reads it on ``truth_step``
    (default ``2 pi / 2**20``, a fine encoder; the servo's reference is on the sensor's own
    grid, the motor encoder through the gear stored on it). The sensor reads the true angle
    plus its error map and its noise (white, or low-pass filtered to the same std), rounded to
    its grid when it has one. The servo's torque is +1 then -1 from halfway, and its reading
    shifts by ``level_shift`` there.

    Returns
    -------
    dict
        ``t``, ``theta``, ``truth``, ``measured`` (rad), ``step``, ``truth_step``, ``noise``,
        ``error`` (the sensor's error map along the log, rad), ``torque`` (or None),
        ``floor_std`` (the std the error would have with a perfect map:
        ``sqrt(noise^2 + step^2 / 12 + truth_step^2 / 12)``) and ``spec``.
    """
    if spec is None:
        if kind not in SENSORS:
            raise ValueError(f"unknown sensor {kind!r}; known: {sorted(SENSORS)}")
        spec = SENSORS[kind]
    n = int(round(duration * fs_hz))
    t = np.arange(n) / fs_hz
    if spec["motion"] == "turn":
        f, a, fv = rng.uniform(0.35, 0.6), rng.uniform(0.5, 1.0), rng.uniform(0.2, 0.5)
        theta = 2 * np.pi * f * t + a * np.sin(2 * np.pi * fv * t) + rng.uniform(0, 2 * np.pi)
    else:
        half = 0.5 * spec["stroke"]
        f = rng.uniform(0.3, 0.6)
        theta = half * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    step = spec.get("step")
    if truth_step is None:
        truth_step = step if kind == "servo" else 2 * np.pi / 2**20
    truth = truth_step * np.round(theta / truth_step)
    err = np.zeros(n)
    for k, ak, bk in spec.get("harmonics", []):
        err = err + ak * np.cos(k * theta) + bk * np.sin(k * theta)
    if spec.get("poly"):
        x = theta / (0.5 * spec["stroke"])
        err = err + sum(c * x**j for j, c in enumerate(spec["poly"]))
    torque = None
    shift = np.zeros(n)
    if spec.get("level_shift"):
        torque = np.where(t < 0.5 * t[-1], 1.0, -1.0)
        shift = spec["level_shift"] * (torque < 0)
    noise = rng.normal(0.0, spec["noise"], n)
    pole = float(spec.get("filter", 0.0))
    if pole > 0:
        from scipy.signal import lfilter

        noise = lfilter([math.sqrt(1.0 - pole * pole)], [1.0, -pole], noise)
    reading = theta + err + shift + noise
    measured = reading if step is None else step * np.round(reading / step)
    floor = math.sqrt(spec["noise"] ** 2 + ((step or 0.0) ** 2 + truth_step**2) / 12.0)
    return {"t": t, "theta": theta, "truth": truth, "measured": measured, "step": step, "truth_step": truth_step,
            "noise": spec["noise"], "error": err, "torque": torque, "level_shift": shift, "floor_std": floor,
            "spec": spec}


def sensor_canonical(sim: dict, log_id: str = "sensor"):
    """A :func:`simulate_sensor` log as the canonical log ingest makes of it (truth and, when it
    has a grid, the sensor as counts; a continuous sensor as float; the servo's torque as a
    float channel), with its pair and the residual settings that declare the torque.

    Returns
    -------
    df, meta, pair, settings
    """
    cols = {"t": sim["t"], "truth": np.rint(sim["truth"] / sim["truth_step"]).astype(np.int64)}
    chans = [{"name": "truth", "role": "truth", "joint": 1, "storage": "counts", "step": sim["truth_step"]}]
    if sim["step"]:
        cols["measured"] = np.rint(sim["measured"] / sim["step"]).astype(np.int64)
        chans.append({"name": "measured", "role": "measured", "joint": 1, "storage": "counts", "step": sim["step"]})
    else:
        cols["measured"] = sim["measured"]
        chans.append({"name": "measured", "role": "measured", "joint": 1, "storage": "float", "step": None})
    settings = {}
    if sim.get("torque") is not None:
        cols["torque"] = sim["torque"]
        chans.append({"name": "torque", "role": "command", "joint": 1, "storage": "float", "step": None})
        settings["aux"] = {"torque": "torque"}
    import pandas as pd

    meta = {"log_id": log_id, "channels": chans}
    return pd.DataFrame(cols), meta, {"measured": "measured", "truth": "truth"}, settings
