"""Does the residual stage name undeclared effects in simulated logs, and only those?

Challenge benchmark of the residual stage: undeclared effects in simulated two-channel logs.

Each log: a 32768-cpr truth channel (rounding) and a 4096-cpr measured channel with a random
quantizer offset, 1 kHz, 10-15 s, motion a sine, a multi-sine or a random smooth path of peak
amplitude 0.5-3 rad. The measured channel carries zero, one or two effects at datasheet-scale
magnitudes; :func:`enclab.residuals.select.select_effects` sees only ``t, truth, measured,
step, truth_step`` (and the line pitch of the encoder, 16 counts, a datasheet value, not an
effect) and nothing about the effects.

Stages
------
1. *Population thresholds* (``--sweep-logs`` logs per magnitude): for each continuous effect,
   the ``delta_bic`` of the true effect added to the base model at 1/243, 1/81, 1/27 and 1/9 of
   the nominal magnitude; the threshold is the magnitude where the median ``delta_bic`` crosses
   the selection threshold (power law through the two sweep points around it, :func:`_crossing`).
   Integer effects (missed counts, wrap-around) have no continuous magnitude: one count or one
   wrap is the smallest possible.
2. *Challenge*: single effects at the nominal magnitude (``single``, at least 3x the population
   threshold; raised to 3x when the sweep finds the nominal below that); single effects at 3x
   the detection threshold *of that log* (``hard``: :func:`log_threshold` finds the magnitude
   where the true effect's ``delta_bic`` crosses the criterion on the log itself); single
   effects at 3x the population median threshold (``hard_median``: the earlier definition; at
   one magnitude the ``delta_bic`` of different logs spans 10-100x, so many of these logs are
   below their own threshold and no criterion could find the effect there); pairs of effects;
   clean controls.

Reported per kind and effect: ``strict_rate`` (the chosen set is exactly the true set) and,
separately, ``rate_incl_indist`` (exact, or a chosen effect that the selection itself reported
as not distinguishable from the true one on that log, ``FittedEffect.indistinguishable``);
``first``: the true effect was chosen; false-positive rate on clean logs; coverage of the
90 % intervals of the continuous parameters of true effects that were chosen; residual std
before/after and the exact-model floor. Per log also the first-round ``delta_bic`` of every
candidate (``round1_dbic``) and the swap-in ``delta_bic`` of the alternatives. Rates carry
Wilson 90 % intervals.

Usage::

    PYTHONPATH=workflow python -m benchmarks.challenge_residuals --per-effect 40 --clean 100 --pairs 10 --hard 40 --hard-median 40
    PYTHONPATH=workflow python -m benchmarks.challenge_residuals --per-effect 3 --clean 5 --pairs 1 --sweep-logs 2 --hard 3 --hard-median 3  # quick
    PYTHONPATH=workflow python -m benchmarks.challenge_residuals --scaling   # wall time at 1e4, 1e5, 1e6 samples

Writes ``<out>/challenge_residuals.csv`` (one row per log), ``<out>/challenge_residuals_summary.csv``
and ``<out>/challenge_residuals.png``; prints the summary table.
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    # Tiny BLAS calls inside the optimiser spin threads; on a shared machine this tripled the
    # wall time of a selection (measured 22 s -> 9 s on one log). One thread per worker
    # process, set before numpy loads BLAS, and only when run (an import changes nothing).
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import concurrent.futures  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from enclab.residuals import diagnostics as dg  # noqa: E402
from enclab.residuals.select import select_effects  # noqa: E402
from enclab.residuals import select as sel  # noqa: E402
from enclab.residuals import effects as fx  # noqa: E402
from enclab.residuals.simulate import random_map, random_motion, random_torque, simulate_log  # noqa: E402

from .helpers import stamp, wilson  # noqa: E402

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8
LINE_PITCH = 16 * STEP
WILSON_Z = 1.645  # the rates' Wilson intervals are 90 %
BIC_THRESHOLD = 10.0
SWEEP_SCALES = (1 / 243, 1 / 81, 1 / 27, 1 / 9)


def nominal_effect(name: str, rng: np.random.Generator, scale: float = 1.0) -> dict:
    """Datasheet-scale parameters of one effect, times ``scale`` for the continuous ones.

    hysteresis 0.5 count (dead band of a magnetic/optical read head); backlash 2 counts
    (3.1 mrad, ~10 arcmin, a precision planetary gearhead); eccentricity 0.5 count 1x and
    0.2 count 2x (~20 um run-out on a 25 mm code disk); interpolation error 0.1 count on a
    16-count line; quadrature edge error 0.1 count rms per edge; latency 0.25 ms; timestamp
    jitter 0.1 ms; scale mismatch 1e-3 (a gear ratio off by 0.1 %); missed counts 1-3 counts
    once; wrap-around at 2 pi; slow drift 0.2 mrad/s.
    """
    sign = rng.choice([-1.0, 1.0])
    if name == "hysteresis":
        return {"h": sign * 0.5 * STEP * scale}
    if name == "backlash":
        return {"w": sign * 2.0 * STEP * scale}
    if name == "angle_harmonics":
        p1, p2 = rng.uniform(0, 2 * np.pi, 2)
        a1, a2 = 0.5 * STEP * scale, 0.2 * STEP * scale
        return {"a1": a1 * math.sin(p1), "b1": a1 * math.cos(p1), "a2": a2 * math.sin(p2), "b2": a2 * math.cos(p2)}
    if name == "line_pitch_harmonics":
        p = rng.uniform(0, 2 * np.pi)
        a = 0.1 * STEP * scale
        return {"a": a * math.sin(p), "b": a * math.cos(p), "pitch": LINE_PITCH}
    if name == "quadrature_edges":
        e = rng.normal(0.0, 0.1 * STEP * scale, 3)
        return {"e0": e[0], "e1": e[1], "e2": e[2]}
    if name == "latency":
        return {"tau": sign * 0.25e-3 * scale}
    if name == "timestamp_jitter":
        return {"sigma_t": 0.1e-3 * scale}
    if name == "scale_mismatch":
        return {"g": sign * 1e-3 * scale}
    if name == "missed_counts":
        return {"times": [float(rng.uniform(0.2, 0.8))], "jumps": [int(sign * rng.integers(1, 4))]}
    if name == "wrap_around":
        return {"period": 2 * np.pi}
    if name == "slow_drift":
        # a thermal drift of the reading: 0.2 mrad/s (0.13 count/s at 4096 cpr)
        return {"rate": sign * 0.2e-3 * scale}
    raise ValueError(name)


CONTINUOUS = ["hysteresis", "backlash", "angle_harmonics", "line_pitch_harmonics", "quadrature_edges",
              "latency", "timestamp_jitter", "scale_mismatch"]
DISCRETE = ["missed_counts", "wrap_around"]
PAIRS = [("backlash", "latency"), ("angle_harmonics", "scale_mismatch"), ("hysteresis", "timestamp_jitter"),
         ("quadrature_edges", "latency"), ("missed_counts", "backlash"), ("line_pitch_harmonics", "scale_mismatch")]


ROTATING = ["scale_mismatch", "angle_harmonics", "latency", "missed_counts", "slow_drift"]
#: Effects of their own cases (``--compliance``, ``--map``): drawn with the log's motion.
MOTION_DRAWN = ["compliance_softening", "calibration_map"]
#: Effects whose continuous parameters are checked against their 90 % intervals.
COVERED = CONTINUOUS + ["compliance_softening"]


def smooth_map(rng: np.random.Generator, lo: float, hi: float, peak_to_peak: float) -> dict:
    """A smooth map outside the fitted spline family: three sines of the angle with wavelengths
    of 1/5 to 2/3 of the stroke and random phases, constant and slope removed, as a dense
    spline (a knot every 5 mrad) for :func:`simulate_log`."""
    stroke = hi - lo
    lam = rng.uniform(stroke / 5.0, stroke / 1.5, 3)
    amp = rng.uniform(0.3, 1.0, 3)
    ph = rng.uniform(0.0, 2.0 * np.pi, 3)
    knots = np.linspace(lo, hi, max(int(stroke / 0.005), 8) + 1)
    values = sum(a * np.sin(2.0 * np.pi * knots / w + p) for a, w, p in zip(amp, lam, ph))
    values = values - np.polyval(np.polyfit(knots, values, 1), knots)
    values = values * peak_to_peak / float(np.ptp(values))
    return {"knots": [float(k) for k in knots], "values": [float(v) for v in values]}


def motion_effect(name: str, rng: np.random.Generator, motion, t, map_shape: str = "spline") -> tuple[dict, dict]:
    """Parameters of an effect drawn from the log's own motion, and the aux channels it needs.

    ``compliance_softening``: the joint torque of the motion (:func:`random_torque`: inertia,
    friction and gravity, peak 1-5 N m, logged with 0.5 % noise); a twist ``k1 T + k2 T|T|``
    of 2-5 mrad at the peak torque before softening, softened by 25-50 % there (``k2`` of sign
    opposite to ``k1``: a gear's play taken up gradually). ``calibration_map``: a smooth map
    over the stroke (:func:`random_map`) of 1.5-4 mrad peak to peak with a bend every 1/4-1/8
    of the stroke, its constant and slope removed (an offset and a scale, not a map); with
    ``map_shape="smooth"`` a sum of sines of the angle instead (:func:`smooth_map`), which no
    spline of the fitted family holds exactly.
    """
    if name == "compliance_softening":
        peak = float(rng.uniform(1.0, 5.0))
        torque = random_torque(rng, motion, t, peak)
        k1 = float(rng.choice([-1.0, 1.0]) * rng.uniform(2e-3, 5e-3) / peak)
        k2 = float(-k1 * rng.uniform(0.25, 0.5) / peak)
        logged = torque + rng.normal(0.0, 0.005 * peak, t.size)
        return {"k1": k1, "k2": k2}, {"torque": torque, "logged": {"torque": logged}}
    if name == "calibration_map":
        th = np.asarray(motion(t), dtype=float)
        stroke = float(np.ptp(th))
        if map_shape == "smooth":
            return smooth_map(rng, float(th.min()), float(th.max()), float(rng.uniform(1.5e-3, 4e-3))), {}
        m = random_map(rng, float(th.min()), float(th.max()), float(rng.uniform(1.5e-3, 4e-3)),
                       stroke / float(rng.uniform(4.0, 8.0)))
        return m, {}
    raise ValueError(name)


def _rotation(rng, duration):
    """A rotating axis: 0.3-1.5 rev/s either way with a 10 % speed ripple, 3-22 turns."""
    f = float(rng.uniform(0.3, 1.5)) * rng.choice([-1.0, 1.0])
    fr, ph, c0 = float(rng.uniform(0.2, 1.0)), float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(-np.pi, np.pi))
    ripple = 0.1 * abs(f) / fr

    def motion(t):
        t = np.asarray(t, dtype=float)
        return c0 + 2 * np.pi * (f * t + np.sign(f) * ripple * np.sin(2 * np.pi * fr * t + ph) / (2 * np.pi))
    return motion


def _make_log(rng, names, scales, rotating=False, close=False, map_shape="spline"):
    duration = float(rng.uniform(10.0, 15.0))
    kind = str(rng.choice(["sine", "multisine", "smooth"]))
    amplitude = float(rng.uniform(0.5, 3.0))
    centre = float(rng.uniform(-np.pi, np.pi))
    if rotating:
        motion = _rotation(rng, duration)
        eff = {n: nominal_effect(n, rng, scales.get(n, 1.0)) for n in names}
        if "missed_counts" in eff:
            eff["missed_counts"]["times"] = [duration * x for x in eff["missed_counts"]["times"]]
        log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP, effects=eff)
        # a rotating axis logged in rad, 9 significant digits: its grid must be found from the data
        log["truth"] = np.array([float(f"{v:.9g}") for v in log["truth"]])
        return log, eff, {"duration": duration, "motion": "rotating", "amplitude": float("nan")}
    if "wrap_around" in names:
        # the motion must cross the wrap at +-pi
        amplitude = max(amplitude, 1.0)
        centre = float(np.pi - rng.uniform(0.2, 0.8) * amplitude) * rng.choice([-1.0, 1.0])
    motion = random_motion(rng, kind, duration, amplitude, centre)
    drawn = [n for n in names if n in MOTION_DRAWN]
    eff = {n: nominal_effect(n, rng, scales.get(n, 1.0)) for n in names if n not in MOTION_DRAWN}
    extra = {}
    if drawn:
        t = np.arange(int(round(duration * 1000.0))) / 1000.0
        for n in drawn:
            eff[n], more = motion_effect(n, rng, motion, t, map_shape)
            extra.update(more)
    if "missed_counts" in eff:
        eff["missed_counts"]["times"] = [duration * x for x in eff["missed_counts"]["times"]]
        if close:
            # 2-4 changes within about a second of each other, at least 0.1 s apart
            k = int(rng.integers(2, 5))
            t0 = float(rng.uniform(0.2, 0.7)) * duration
            gaps = rng.uniform(0.1, 1.0 / (k - 1), k - 1)
            eff["missed_counts"] = {"times": list(t0 + np.concatenate(([0.0], np.cumsum(gaps)))),
                                    "jumps": [int(rng.choice([-1, 1]) * rng.integers(1, 3)) for _ in range(k)]}
    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP, effects=eff,
                       torque=extra.get("torque"))
    log["aux"] = extra.get("logged", {})
    return log, eff, {"duration": duration, "motion": kind, "amplitude": amplitude}


def true_delta_bic(name, scale, seed) -> dict:
    """``delta_bic`` of the true effect added to the base model on the log ``seed`` with the effect
    at ``scale`` x nominal, its parameter count ``k`` and the fitted sample count ``n``.

    A log's draws (motion, effect signs and phases, quantizer offset, jitter) do not depend on
    ``scale``: one seed at several scales is one log with the effect turned up or down.
    """
    rng = np.random.default_rng(seed)
    log, eff, meta = _make_log(rng, [name], {name: scale})
    e = next(c() for c in fx.EFFECTS if c.name == name)
    fitted = sel.added_effect_fit(log["t"], log["truth"], *_counts(log), STEP, TRUTH_STEP, e,
                                  line_pitch=LINE_PITCH)
    k, n = fitted["k"], fitted["n_fit"]
    return {"delta_bic": 2 * (fitted["ll_effect"] - fitted["ll_base"]) - k * math.log(n), "k": k, "n": n}


def _sweep_job(args):
    name, scale, seed = args
    d = true_delta_bic(name, scale, seed)
    return {"effect": name, "scale": scale, "seed": seed, **d}


def _crossing(s_lo, d_lo, s_hi, d_hi, penalty):
    """Scale where ``delta_bic`` crosses the criterion between two points, interpolating
    ``log(2 dLL) = log(delta_bic + k ln N)`` against ``log(scale)``: a power law (2 dLL grows like
    magnitude^2 for a small shift, faster for a variance) through the two points."""
    y_lo = math.log(max(d_lo + penalty, 1e-3))
    y_hi = math.log(max(d_hi + penalty, 1e-3))
    y_t = math.log(BIC_THRESHOLD + penalty)
    if y_hi <= y_lo:
        return math.sqrt(s_lo * s_hi)
    x_lo, x_hi = math.log(s_lo), math.log(s_hi)
    return math.exp(x_lo + (y_t - y_lo) * (x_hi - x_lo) / (y_hi - y_lo))


def log_threshold(name, seed, start, factor=3.0, max_scale=3.0, max_evals=8):
    """Detection threshold of effect ``name`` on the log ``seed`` itself (fraction of nominal).

    The scale where the true effect's ``delta_bic`` against the base model crosses the selection
    threshold on this log: bracketed from ``start`` in steps of ``factor``, then the power-law
    crossing between the bracket. Logs differ in what they reveal (stroke, reversals, speed)
    by more than 10x in ``delta_bic`` at one magnitude, so a population median threshold puts
    many logs below their own. Returns ``(scale, evaluations)``; NaN when ``delta_bic`` stays
    below the criterion up to ``max_scale``.
    """
    s = float(start)
    d = true_delta_bic(name, s, seed)
    penalty = d["k"] * math.log(d["n"])
    evals = [(s, d["delta_bic"])]
    lo = hi = None
    while len(evals) < max_evals:
        s_last, d_last = evals[-1]
        if d_last > BIC_THRESHOLD:
            hi = (s_last, d_last)
            if lo is not None:
                break
            s = s_last / factor
        else:
            lo = (s_last, d_last)
            if hi is not None:
                break
            if s_last * factor > max_scale:
                return float("nan"), evals
            s = s_last * factor
        evals.append((s, true_delta_bic(name, s, seed)["delta_bic"]))
    if lo is None or hi is None:
        return float("nan"), evals
    return _crossing(lo[0], lo[1], hi[0], hi[1], penalty), evals


def _counts(log):
    return (np.round(log["measured"] / STEP).astype(np.int64),)


def _matches(chosen_alts, names) -> bool:
    """True set recovered when each chosen effect may stand for one of the alternatives the
    selection named as not distinguishable from it."""
    options = [[c] + alts for c, alts in chosen_alts]
    return any(set(combo) == set(names) and len(combo) == len(set(combo))
               for combo in itertools.product(*options)) if options else not names


def _challenge_job(args):
    kind, names, scales, seed = args
    extra = {}
    if kind == "hard":
        # 3x this log's own threshold (see log_threshold); scales holds the population ones to start from
        (name,) = names
        thr, evals = log_threshold(name, seed, scales[name])
        extra = {"log_threshold_scale": thr, "threshold_evals": json.dumps(evals)}
        if not np.isfinite(thr):
            return {"kind": kind, "true": name, "seed": seed, "skipped": True, **extra}
        scales = {name: 3.0 * thr}
    rng = np.random.default_rng(seed)
    rotating = kind == "rotating"
    log, eff, meta = _make_log(rng, list(names), scales, rotating=rotating, close=kind == "missed_close",
                               map_shape="smooth" if kind == "map_smooth" else "spline")
    t0 = time.perf_counter()
    # a rotating axis's truth is a float channel: its grid (the floor) is the selection's to find
    aux = log.get("aux") or None
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=None if rotating else TRUTH_STEP,
                         line_pitch=LINE_PITCH, aux=aux)
    wall = time.perf_counter() - t0
    chosen = [e.name for e in res.effects]
    alts = [(e.name, [a["name"] for a in e.indistinguishable]) for e in res.effects]
    cover = {}
    for e in res.effects:
        if e.name in eff and e.name in COVERED:
            for p, (lo, hi) in e.ci.items():
                true = eff[e.name][p]
                cover[f"{e.name}.{p}"] = bool(lo <= true <= hi)
    ratio = res.after["std"] / res.after["floor_std"] if res.after["floor_std"] > 0 else float("inf")
    found = _found_true(res, eff, names, float(log["t"][-1] - log["t"][0]))
    r_after = log["measured"] - res.model_prediction()
    ranking = dg.rank_covariates(r_after, dg.covariates_of(log["t"], log["truth"], aux))
    top = ranking[0] if ranking else {"name": "", "share": float("nan")}
    # every candidate's delta BIC against the base model (the first round of the selection):
    # tells a miss where the true effect was below the criterion from one where another won
    round1 = {r["effect"]: r["delta_bic"] for r in res.steps if r["step"] == 1}
    true_dbic = max((round1.get(n, float("nan")) for n in names), default=float("nan"))
    return {
        "kind": kind,
        "true": "+".join(names) if names else "clean",
        "chosen": "+".join(chosen),
        "exact": set(chosen) == set(names),
        "exact_or_indist": _matches(alts, names),
        "indistinguishable": json.dumps({e.name: {a["name"]: round(a["delta_bic"], 2) for a in e.indistinguishable}
                                         for e in res.effects}),
        "alternatives": json.dumps({e.name: {a["name"]: round(a["delta_bic"], 2) for a in e.alternatives}
                                    for e in res.effects}),
        "first": bool(names) and bool(chosen) and chosen[0] in names,
        "contains": set(names) <= set(chosen),
        "n_chosen": len(chosen),
        "round1_dbic": json.dumps(round1),
        "true_dbic_round1": true_dbic,
        "explained": res.explained,
        "found_true": found,
        "top_covariate": top["name"],
        "top_share": top["share"],
        # named: the true set (or a named indistinguishable alternative), or, unexplained, the
        # covariate ranking points at the covariate of the true effect's signature
        "named": bool(_matches(alts, names) or (not res.explained and names
                                                and top["name"] == SIGNATURE_COVARIATE.get(names[0]))),
        # named by the effect itself (or an alternative the report names as not distinguishable)
        "named_effect": bool(names) and bool(_matches(alts, names)),
        "merged": json.dumps({e.name: e.merged_with for e in res.effects if e.merged_with}),
        "coverage": json.dumps(cover),
        "true_params": json.dumps({k: {kk: (vv if not isinstance(vv, list) else vv) for kk, vv in v.items()} for k, v in eff.items()}),
        "fitted_params": json.dumps({e.name: e.params for e in res.effects}),
        "before_std": res.before["std"],
        "after_std": res.after["std"],
        "floor_std": res.after["floor_std"],
        "floor_hi": res.after["floor_ci"][1],
        "after_over_floor": ratio,
        "n_samples": int(log["t"].size),
        "wall_s": wall,
        "seed": seed,
        "test_scale": json.dumps(scales),
        "skipped": False,
        **meta,
        **extra,
    }


#: The covariate a residual of each effect follows when the effect is not modelled.
SIGNATURE_COVARIATE = {"slow_drift": "time", "missed_counts": "time", "angle_harmonics": "angle",
                       "scale_mismatch": "angle", "latency": "velocity", "hysteresis": "direction",
                       "backlash": "direction", "compliance_softening": "torque",
                       "calibration_map": "angle"}


def _found_true(res, eff, names, t_span: float) -> bool:
    """The one true effect chosen alone with its true value: every continuous parameter inside
    its 90 % interval; missed counts with the true jumps, each within 5 ms of its time; the
    wrap-around period exact. False for clean logs and pairs."""
    if len(names) != 1 or [e.name for e in res.effects] != list(names):
        return False
    (e,) = res.effects
    true = eff[e.name]
    if e.name == "missed_counts":
        k = len(true["times"])
        if len(e.params) != 2 * k:
            return False
        return all(e.params[f"n_{j + 1}"] == true["jumps"][j] and abs(e.params[f"t_{j + 1}"] - true["times"][j]) <= 5e-3
                   for j in range(k))
    if e.name == "wrap_around":
        return e.params["period"] == true["period"]
    if e.name == "calibration_map":
        # the simulated map is no member of the fitted spline basis: no true coefficients
        return False
    if e.name == "slow_drift":
        # the simulated drift is rate * (t - t_mid): c1 = rate T / 2, c2 = c3 = 0
        half = 0.5 * t_span
        want = {"c1": true["rate"] * half, "c2": 0.0, "c3": 0.0}
        return all(e.ci[p][0] <= want[p] <= e.ci[p][1] for p in want)
    return all(e.ci[p][0] <= true.get(p, 0.0) <= e.ci[p][1] for p in e.ci)


def _map(fn, jobs, n_jobs):
    if n_jobs <= 1:
        return [fn(j) for j in jobs]
    with concurrent.futures.ProcessPoolExecutor(n_jobs) as ex:
        return list(ex.map(fn, jobs, chunksize=1))


def thresholds(sweep: pd.DataFrame) -> dict:
    """Scale (fraction of nominal) where the median ``delta_bic`` over the sweep logs crosses the
    selection threshold (the population threshold; :func:`_crossing` between the sweep points)."""
    out = {}
    for name, g in sweep.groupby("effect"):
        med = g.groupby("scale")["delta_bic"].median().sort_index()
        s, d = med.index.to_numpy(float), med.to_numpy(float)
        penalty = float(g["k"].iloc[0]) * math.log(float(g["n"].median()))
        thr = float("nan")
        above = np.flatnonzero(d > BIC_THRESHOLD)
        if above.size and above[0] > 0:
            i = above[0]
            thr = _crossing(s[i - 1], d[i - 1], s[i], d[i], penalty)
        elif above.size and above[0] == 0:
            thr = float(s[0])  # an upper bound: detected already at the smallest scale
        out[name] = thr
    return out


def _rate(k, n):
    lo, hi = wilson(k, n, WILSON_Z)
    return k / n if n else float("nan"), f"[{lo:.2f}, {hi:.2f}]"


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """One row per kind and true set. ``strict_rate``: the chosen set is exactly the true set;
    ``rate_incl_indist``: the same, or a chosen effect is one the selection itself named as not
    distinguishable from the true one on that log (reported separately, never merged)."""
    rows = []
    for (kind, true), g in df.groupby(["kind", "true"], sort=False):
        skipped = int(g["skipped"].sum())
        g = g[~g["skipped"]]
        n = len(g)
        if n == 0:
            rows.append({"kind": kind, "true": true, "n_logs": 0, "n_skipped": skipped})
            continue
        strict, strict_ci = _rate(int(g["exact"].sum()), n)
        incl, incl_ci = _rate(int(g["exact_or_indist"].sum()), n)
        hits = [v for c in g["coverage"] for v in json.loads(c).values()]
        row = {
            "kind": kind,
            "true": true,
            "n_logs": n,
            "n_skipped": skipped,
            "strict_rate": strict,
            "strict_ci90": strict_ci,
            "rate_incl_indist": incl,
            "incl_indist_ci90": incl_ci,
            "first_rate": float(g["first"].mean()),
            "any_effect_rate": float((g["n_chosen"] > 0).mean()),
            "coverage90": (sum(hits) / len(hits)) if hits else float("nan"),
            "n_params": len(hits),
            "before_std_mrad": 1e3 * g["before_std"].median(),
            "after_std_mrad": 1e3 * g["after_std"].median(),
            "floor_std_mrad": 1e3 * g["floor_std"].median(),
            "after_over_floor_median": g["after_over_floor"].median(),
            "after_within_10pct": float((np.abs(g["after_over_floor"] - 1) <= 0.1).mean()),
            "explained_rate": float(g["explained"].astype(bool).mean()),
            "found_true_rate": float(g["found_true"].astype(bool).mean()),
            "explained_given_found": (float(g.loc[g["found_true"].astype(bool), "explained"].astype(bool).mean())
                                      if g["found_true"].astype(bool).any() else float("nan")),
            "named_rate": float(g["named"].astype(bool).mean()),
            "named_effect_rate": float(g["named_effect"].astype(bool).mean()),
            "named_effect_ci90": _rate(int(g["named_effect"].astype(bool).sum()), n)[1],
            "wall_s_median": g["wall_s"].median(),
        }
        rows.append(row)
    return pd.DataFrame(rows)


def figure(summary: pd.DataFrame) -> Figure:
    summary = summary[summary["n_logs"] > 0]
    fig = Figure(figsize=(11, 5))
    axs = fig.subplots(1, 3, sharey=True)
    lab = [f"{k}: {t}" for k, t in zip(summary["kind"], summary["true"])]
    y = np.arange(len(lab))
    axs[0].barh(y, summary["strict_rate"], color="C0", label="strict: exact set")
    axs[0].plot(summary["rate_incl_indist"], y, "k|", ms=10,
                label="exact set or a named\nindistinguishable alternative")
    axs[0].axvline(0.95, color="r", lw=0.8)
    axs[0].set_yticks(y, lab, fontsize=7)
    axs[0].set_xlabel("identification rate (clean: no effect)")
    axs[0].legend(fontsize=7)
    cov = summary["coverage90"].to_numpy(float)
    ok = np.isfinite(cov)
    axs[1].barh(y[ok], cov[ok], color="C1")
    axs[1].axvline(0.9, color="r", lw=0.8)
    axs[1].tick_params(labelleft=False)
    axs[1].set_xlabel("coverage of 90 % intervals")
    axs[2].barh(y, summary["after_over_floor_median"], color="C2")
    axs[2].axvline(1.0, color="k", lw=0.8)
    axs[2].axvline(1.1, color="r", lw=0.8)
    axs[2].axvline(0.9, color="r", lw=0.8)
    axs[2].tick_params(labelleft=False)
    axs[2].set_xlabel("after-residual std / exact floor (median)")
    fig.tight_layout()
    return fig


def scaling(sizes=(10_000, 100_000, 1_000_000), seed=7) -> pd.DataFrame:
    """Wall time of one selection against log length (1 kHz; a clean log and a latency log)."""
    rows = []
    for n in sizes:
        for name in ("clean", "latency"):
            rng = np.random.default_rng(seed)
            duration = n / 1000.0
            motion = random_motion(rng, "multisine", duration, 1.0)
            eff = {} if name == "clean" else {"latency": {"tau": 0.25e-3}}
            log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP, effects=eff)
            t0 = time.perf_counter()
            res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP, line_pitch=LINE_PITCH)
            rows.append({"n_samples": n, "log": name, "wall_s": time.perf_counter() - t0,
                         "chosen": "+".join(e.name for e in res.effects)})
            print(rows[-1], flush=True)
    return pd.DataFrame(rows)


def floor_calibration(n_logs: int, seed: int) -> pd.DataFrame:
    """Calibration of the exact-model floor on clean logs like the embedded ``res_clean_r01``.

    A 4000-cpr motor encoder through a 23:1 gear (truth) and an 8192-cpr output encoder, a
    20 deg sine for 6 s at 1 kHz, the base model only (no effect). Two motions: 1 Hz, which
    passes the same 1000 angles six times, and 1.137 Hz, which does not. Per log: the residual
    std over the floor, whether it lies outside the floor's 90 % interval and above the verdict's
    limit, with the interval's standard error from time blocks alone and from the larger of
    time blocks and angle bins (the library's).
    """
    from enclab.core.quantize import quantize

    ts, st = 2 * np.pi / (4000 * 23), 2 * np.pi / 8192
    t = np.arange(6000) / 1000.0
    rows = []
    for freq in (1.0, 1.137):
        for i, s in enumerate(np.random.SeedSequence(seed).spawn(n_logs)):
            rng = np.random.default_rng(s)
            theta = (np.deg2rad(20.0) * np.sin(2 * np.pi * freq * t + rng.uniform(0, 2 * np.pi))
                     + rng.uniform(0, st) + rng.normal(0, 1e-6, t.size))
            truth = quantize(theta, ts) * ts
            # the time-block standard error alone (3 truth cells each side: the reach of
            # residual_stats at this truth step) beside the library's
            terms = sel.floor_interval_terms(t, truth, quantize(theta, st, 0.0), st, ts, reach=3)
            floor_var, var = terms["floor_var"], terms["residual_var"]
            for label, se in (("time blocks", terms["se_time_blocks"]),
                              ("time blocks and angle bins", terms["se_library"])):
                lo, hi = max(floor_var - terms["z90"] * se, 0.0), floor_var + terms["z90"] * se
                rows.append({"freq_hz": freq, "log": i, "interval_from": label,
                             "after_over_floor": math.sqrt(var / floor_var),
                             "outside_ci90": bool(var < lo or var > hi),
                             "above_limit": bool(var > floor_var + terms["t99"] * se)})
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-effect", type=int, default=40)
    ap.add_argument("--clean", type=int, default=100)
    ap.add_argument("--pairs", type=int, default=10, help="logs per pair of effects")
    ap.add_argument("--sweep-logs", type=int, default=6)
    ap.add_argument("--hard", type=int, default=10,
                    help="logs per continuous effect at 3x the log's own detection threshold")
    ap.add_argument("--hard-median", type=int, default=10,
                    help="logs per continuous effect at 3x the population median threshold")
    ap.add_argument("--drift", type=int, default=40, help="logs with an undeclared slow drift (0.2 mrad/s)")
    ap.add_argument("--missed-close", type=int, default=10,
                    help="logs with 2-4 missed counts within about a second of each other")
    ap.add_argument("--rotating", type=int, default=10, help="logs per effect on a rotating axis (float truth)")
    ap.add_argument("--compliance", type=int, default=40,
                    help="logs with an undeclared softening compliance against a logged torque")
    ap.add_argument("--map", type=int, default=40, help="logs with an undeclared smooth calibration map")
    ap.add_argument("--map-smooth", type=int, default=0,
                    help="logs with an undeclared map that is a sum of sines of the angle (outside the spline family)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=20261128)
    ap.add_argument("--out", default="results/benchmarks")
    ap.add_argument("--scaling", action="store_true", help="only time one selection at 1e4, 1e5, 1e6 samples")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from the summary CSV in --out")
    ap.add_argument("--floor", type=int, default=0,
                    help="only the floor calibration on this many clean res_clean-like logs per motion")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        summary = pd.read_csv(out / "challenge_residuals_summary.csv")
        figure(summary).savefig(out / "challenge_residuals.png", dpi=110, metadata={"Software": None})
        return
    if args.scaling:
        scaling().to_csv(out / "challenge_residuals_scaling.csv", index=False)
        return
    if args.floor:
        fl = floor_calibration(args.floor, args.seed)
        stamp(fl).to_csv(out / "challenge_residuals_floor.csv", index=False)
        summ = fl.groupby(["freq_hz", "interval_from"]).agg(
            n=("log", "size"), ratio_mean=("after_over_floor", "mean"), ratio_sd=("after_over_floor", "std"),
            outside_ci90=("outside_ci90", "mean"), above_limit=("above_limit", "mean")).reset_index()
        stamp(summ).to_csv(out / "challenge_residuals_floor_summary.csv", index=False)
        print(summ.round(3).to_string(index=False))
        return
    ss = np.random.SeedSequence(args.seed)
    seeds = iter(int(s.generate_state(1)[0]) for s in ss.spawn(100000))
    t_start = time.perf_counter()

    sweep_jobs = [(n, sc, next(seeds)) for n in CONTINUOUS for sc in SWEEP_SCALES for _ in range(args.sweep_logs)]
    sweep = pd.DataFrame(_map(_sweep_job, sweep_jobs, args.jobs))
    thr = thresholds(sweep)
    scales = {n: max(1.0, 3.0 * thr[n]) if np.isfinite(thr[n]) else 1.0 for n in CONTINUOUS}
    # where a log's own threshold search starts: the population one, or a tenth of nominal
    start = {n: thr[n] if np.isfinite(thr[n]) else 0.1 for n in CONTINUOUS}

    jobs = [("clean", (), {}, next(seeds)) for _ in range(args.clean)]
    for n in CONTINUOUS + DISCRETE:
        jobs += [("single", (n,), scales, next(seeds)) for _ in range(args.per_effect)]
    for n in CONTINUOUS:
        jobs += [("hard", (n,), start, next(seeds)) for _ in range(args.hard)]
    hard_median = {n: 3.0 * thr[n] for n in CONTINUOUS if np.isfinite(thr[n])}
    for n in hard_median:
        jobs += [("hard_median", (n,), hard_median, next(seeds)) for _ in range(args.hard_median)]
    for pair in PAIRS:
        jobs += [("pair", pair, scales, next(seeds)) for _ in range(args.pairs)]
    jobs += [("drift", ("slow_drift",), {}, next(seeds)) for _ in range(args.drift)]
    jobs += [("missed_close", ("missed_counts",), {}, next(seeds)) for _ in range(args.missed_close)]
    for n in ROTATING:
        jobs += [("rotating", (n,), scales, next(seeds)) for _ in range(args.rotating)]
    jobs += [("compliance", ("compliance_softening",), {}, next(seeds)) for _ in range(args.compliance)]
    jobs += [("map", ("calibration_map",), {}, next(seeds)) for _ in range(args.map)]
    jobs += [("map_smooth", ("calibration_map",), {}, next(seeds)) for _ in range(args.map_smooth)]
    df = pd.DataFrame(_map(_challenge_job, jobs, args.jobs))
    df["skipped"] = df["skipped"].astype(bool)
    summary = summarize(df)
    summary["threshold_scale"] = [thr.get(t, float("nan")) for t in summary["true"]]
    test_scale = {"single": scales, "hard_median": hard_median}
    summary["test_over_threshold"] = [
        3.0 if k == "hard" else
        test_scale[k].get(t, float("nan")) / thr[t] if k in test_scale and t in thr and np.isfinite(thr[t])
        else float("nan")
        for k, t in zip(summary["kind"], summary["true"])]
    tmp = out / "challenge_residuals.csv.tmp"
    stamp(df).to_csv(tmp, index=False)
    tmp.replace(out / "challenge_residuals.csv")
    stamp(summary).to_csv(out / "challenge_residuals_summary.csv", index=False)
    stamp(sweep).to_csv(out / "challenge_residuals_sweep.csv", index=False)
    figure(summary).savefig(out / "challenge_residuals.png", dpi=110, metadata={"Software": None})

    ran = df[~df["skipped"]]
    clean = ran[ran["kind"] == "clean"]
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 40)
    print(summary.drop(columns=["strict_ci90", "incl_indist_ci90"]).round(3).to_string(index=False))
    print()
    print("population thresholds (fraction of nominal magnitude):", {k: round(v, 4) for k, v in thr.items()})

    def rate_line(label, k, n):
        lo, hi = wilson(k, n, WILSON_Z)
        return f"{label}: {k}/{n} = {k / max(n, 1):.3f} (90% Wilson {lo:.3f}-{hi:.3f})"

    groups = {"single effects at datasheet size (>= 3x the population threshold)": ["single"],
              "single effects at 3x the log's own threshold": ["hard"],
              "single effects at 3x the population median threshold": ["hard_median"]}
    for label, kinds in groups.items():
        g = ran[ran["kind"].isin(kinds)]
        if len(g):
            print(label)
            print("  " + rate_line("strict (exact set)", int(g["exact"].sum()), len(g)))
            print("  " + rate_line("exact set or a named indistinguishable alternative",
                                   int(g["exact_or_indist"].sum()), len(g)))
    n_skip = int(df["skipped"].sum())
    if n_skip:
        print(f"hard logs without a threshold below {3.0}x nominal (left out): {n_skip}")
    kf = int((clean["n_chosen"] > 0).sum())
    print(rate_line("clean false positives", kf, len(clean)))
    print(rate_line("clean logs with no effect", len(clean) - kf, len(clean)))
    for kind, label in (("drift", "slow drift (undeclared) named by the effect or the covariate ranking"),
                        ("missed_close", "missed counts close together: the exact set"),
                        ("rotating", "rotating axes (float truth): the exact set or a named alternative"),
                        ("compliance", "softening compliance (undeclared) named by the effect"),
                        ("map", "smooth calibration map (undeclared) named by the effect"),
                        ("map_smooth", "map as a sum of sines of the angle (undeclared) named by the effect")):
        g = ran[ran["kind"] == kind]
        if len(g):
            col = {"drift": "named", "missed_close": "exact", "compliance": "named_effect",
                   "map": "named_effect", "map_smooth": "named_effect"}.get(kind, "exact_or_indist")
            print(rate_line(label, int(g[col].astype(bool).sum()), len(g)))
    found = ran[ran["found_true"].astype(bool)]
    print(rate_line("one true effect found with its true value -> explained", int(found["explained"].astype(bool).sum()),
                    len(found)))
    rot = found[found["kind"] == "rotating"]
    if len(rot):
        print("  " + rate_line("of which rotating axes", int(rot["explained"].astype(bool).sum()), len(rot)))
    single = ran[ran["kind"].isin(["single", "hard", "hard_median"])]
    hits = [v for c in single["coverage"] for v in json.loads(c).values()]
    if hits:
        print(f"90% interval coverage (single effects, {len(hits)} parameters): {sum(hits) / len(hits):.3f}")
    r = ran["after_over_floor"]
    print(f"after/floor std ratio: median {r.median():.3f}, within 10%: {(np.abs(r - 1) <= 0.1).mean():.3f} of logs")
    print(f"selection wall time per log: median {ran['wall_s'].median():.2f} s, max {ran['wall_s'].max():.2f} s; "
          f"total {time.perf_counter() - t_start:.0f} s with {args.jobs} jobs")


if __name__ == "__main__":
    main()
