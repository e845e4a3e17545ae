"""Simulated two-channel logs (fine truth channel, coarse measured channel) with known effects.

The continuous motion ``theta(t)`` is a callable so that latency and timestamp jitter are
simulated exactly (``theta(t - tau)``, ``theta(t + N(0, sigma_t^2))``), not through the
first-order terms the model uses. The truth channel is ``truth_step * round(theta / truth_step)``;
the measured channel ``step * floor(theta_eff / step + c)`` with the effects applied to the
continuous angle.
"""
from __future__ import annotations


import numpy as np

from enclab.residuals import effects as fx

__all__ = ["random_motion", "simulate_log"]


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
    ``scale_mismatch {g}``, ``compliance {kappa}`` (needs ``torque``), ``slow_drift {rate, quad}``
    (``rate (t - t_mid) + quad (t - t_mid)^2``, rad/s and rad/s^2), ``missed_counts {times,
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
    if "scale_mismatch" in effects:
        te = te + effects["scale_mismatch"]["g"] * (te - truth.mean())
    if "angle_harmonics" in effects:
        p = effects["angle_harmonics"]
        te = te + p.get("a1", 0) * np.cos(te) + p.get("b1", 0) * np.sin(te) + p.get("a2", 0) * np.cos(2 * te) + p.get("b2", 0) * np.sin(2 * te)
    if "line_pitch_harmonics" in effects:
        p = effects["line_pitch_harmonics"]
        w = 2 * np.pi * te / p.get("pitch", 4 * step)
        te = te + p.get("a", 0) * np.cos(w) + p.get("b", 0) * np.sin(w)
    if "slow_drift" in effects:
        p = effects["slow_drift"]
        tm = t - 0.5 * (t[0] + t[-1])
        te = te + p.get("rate", 0.0) * tm + p.get("quad", 0.0) * tm**2
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
