"""Challenge benchmark of the residual stage: undeclared effects in simulated two-channel logs.

Each log: a 32768-cpr truth channel (rounding) and a 4096-cpr measured channel with a random
quantizer offset, 1 kHz, 10-15 s, motion a sine, a multi-sine or a random smooth path of peak
amplitude 0.5-3 rad. The measured channel carries zero, one or two effects at datasheet-scale
magnitudes; :func:`enclab.residuals.select.select_effects` sees only ``t, truth, measured,
step, truth_step`` (and the line pitch of the encoder, 16 counts, a datasheet value, not an
effect) and nothing about the effects.

Stages
------
1. *Thresholds* (``--sweep-logs`` logs per magnitude): for each continuous effect, the
   ``delta_bic`` of the effect added to the base model at 1/243, 1/81, 1/27 and 1/9 of the
   nominal magnitude; the detection threshold is the magnitude where the median ``delta_bic`` crosses
   the selection threshold (log-log interpolation). Integer effects (missed counts, wrap-around)
   have no continuous magnitude: one count or one wrap is the smallest possible.
2. *Challenge*: single effects at the nominal magnitude (at least 3x the threshold; raised
   to 3x when the sweep finds the nominal below that), single effects at exactly 3x the
   threshold (``hard``, ``--hard`` logs each), pairs of effects, clean controls.

Reported: identification rate per effect (``exact``: the chosen set is exactly the true set;
``first``: the true effect was chosen), false-positive rate on clean logs, coverage of the 90 %
intervals of continuous parameters, residual std before/after and the exact-model floor.
Rates carry Wilson 90 % intervals.

Usage::

    python workflow/benchmarks/challenge_residuals.py --per-effect 40 --clean 100 --pairs 10 --jobs 2
    python workflow/benchmarks/challenge_residuals.py --per-effect 3 --clean 5 --pairs 1 --sweep-logs 2 --hard 1  # quick
    python workflow/benchmarks/challenge_residuals.py --scaling   # wall time at 1e4, 1e5, 1e6 samples

Writes ``<out>/challenge_residuals.csv`` (one row per log), ``<out>/challenge_residuals_summary.csv``
and ``<out>/challenge_residuals.png``; prints the summary table.
"""
from __future__ import annotations

import os

# Tiny BLAS calls inside the optimiser spin threads; on a shared machine this tripled the
# wall time of a selection (measured 22 s -> 9 s on one log). One thread per worker process.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import concurrent.futures  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from enclab.residuals.select import select_effects  # noqa: E402
from enclab.residuals import select as sel  # noqa: E402
from enclab.residuals import effects as fx  # noqa: E402
from enclab.residuals.simulate import random_motion, simulate_log  # noqa: E402

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8
LINE_PITCH = 16 * STEP
BIC_THRESHOLD = 10.0
SWEEP_SCALES = (1 / 243, 1 / 81, 1 / 27, 1 / 9)


def nominal_effect(name: str, rng: np.random.Generator, scale: float = 1.0) -> dict:
    """Datasheet-scale parameters of one effect, times ``scale`` for the continuous ones.

    hysteresis 0.5 count (dead band of a magnetic/optical read head); backlash 2 counts
    (3.1 mrad, ~10 arcmin, a precision planetary gearhead); eccentricity 0.5 count 1x and
    0.2 count 2x (~20 um run-out on a 25 mm code disk); interpolation error 0.1 count on a
    16-count line; quadrature edge error 0.1 count rms per edge; latency 0.25 ms; timestamp
    jitter 0.1 ms; scale mismatch 1e-3 (a gear ratio off by 0.1 %); missed counts 1-3 counts
    once; wrap-around at 2 pi.
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
    raise ValueError(name)


CONTINUOUS = ["hysteresis", "backlash", "angle_harmonics", "line_pitch_harmonics", "quadrature_edges",
              "latency", "timestamp_jitter", "scale_mismatch"]
DISCRETE = ["missed_counts", "wrap_around"]
PAIRS = [("backlash", "latency"), ("angle_harmonics", "scale_mismatch"), ("hysteresis", "timestamp_jitter"),
         ("quadrature_edges", "latency"), ("missed_counts", "backlash"), ("line_pitch_harmonics", "scale_mismatch")]


def _make_log(rng, names, scales):
    duration = float(rng.uniform(10.0, 15.0))
    kind = str(rng.choice(["sine", "multisine", "smooth"]))
    amplitude = float(rng.uniform(0.5, 3.0))
    centre = float(rng.uniform(-np.pi, np.pi))
    if "wrap_around" in names:
        # the motion must cross the wrap at +-pi
        amplitude = max(amplitude, 1.0)
        centre = float(np.pi - rng.uniform(0.2, 0.8) * amplitude) * rng.choice([-1.0, 1.0])
    motion = random_motion(rng, kind, duration, amplitude, centre)
    eff = {n: nominal_effect(n, rng, scales.get(n, 1.0)) for n in names}
    if "missed_counts" in eff:
        eff["missed_counts"]["times"] = [duration * x for x in eff["missed_counts"]["times"]]
    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP, effects=eff)
    return log, eff, {"duration": duration, "motion": kind, "amplitude": amplitude}


def _sweep_job(args):
    name, scale, seed = args
    rng = np.random.default_rng(seed)
    log, eff, meta = _make_log(rng, [name], {name: scale})
    ctx = sel._make_ctx(log["t"], log["truth"], *_counts(log), STEP, TRUTH_STEP, {}, 0.0, LINE_PITCH)
    base = sel._Model([])
    x, ll = sel._fit(base, ctx, sel._base_start(ctx))
    cur = sel._Fitted(base, x, ll)
    e = next(c() for c in fx.EFFECTS if c.name == name)
    new = sel._extend(cur, e, ctx)
    k = new.model.n_params() - base.n_params()
    dbic = 2 * (new.ll - cur.ll) - k * math.log(ctx.fit_idx.size)
    return {"effect": name, "scale": scale, "seed": seed, "delta_bic": dbic}


def _counts(log):
    return (np.round(log["measured"] / STEP).astype(np.int64),)


def _challenge_job(args):
    kind, names, scales, seed = args
    rng = np.random.default_rng(seed)
    log, eff, meta = _make_log(rng, list(names), scales)
    t0 = time.perf_counter()
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP, line_pitch=LINE_PITCH)
    wall = time.perf_counter() - t0
    chosen = [e.name for e in res.effects]
    cover = {}
    for e in res.effects:
        if e.name in eff and e.name in CONTINUOUS:
            for p, (lo, hi) in e.ci.items():
                true = eff[e.name][p]
                cover[f"{e.name}.{p}"] = bool(lo <= true <= hi)
    ratio = res.after["std"] / res.after["floor_std"] if res.after["floor_std"] > 0 else float("nan")
    return {
        "kind": kind,
        "true": "+".join(names) if names else "clean",
        "chosen": "+".join(chosen),
        "exact": set(chosen) == set(names),
        "first": bool(names) and bool(chosen) and chosen[0] in names,
        "contains": set(names) <= set(chosen),
        "n_chosen": len(chosen),
        "explained": res.explained,
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
        **meta,
    }


def wilson(k, n, z=1.645):
    """Wilson score interval of a proportion (90 % by default)."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (c - h, c + h)


def _map(fn, jobs, n_jobs):
    if n_jobs <= 1:
        return [fn(j) for j in jobs]
    with concurrent.futures.ProcessPoolExecutor(n_jobs) as ex:
        return list(ex.map(fn, jobs, chunksize=1))


def thresholds(sweep: pd.DataFrame) -> dict:
    """Scale (fraction of nominal) where the median delta BIC crosses the selection threshold."""
    out = {}
    for name, g in sweep.groupby("effect"):
        med = g.groupby("scale")["delta_bic"].median().sort_index()
        s, d = med.index.to_numpy(float), med.to_numpy(float)
        # delta BIC + k ln N = 2 delta loglik grows like magnitude^2 for a small effect:
        # interpolate log(2 dLL) against log(scale) between the sweep points
        thr = float("nan")
        above = np.flatnonzero(d > BIC_THRESHOLD)
        if above.size and above[0] > 0:
            i = above[0]
            x0, x1, y0, y1 = math.log(s[i - 1]), math.log(s[i]), d[i - 1], d[i]
            thr = math.exp(x0 + (BIC_THRESHOLD - y0) * (x1 - x0) / (y1 - y0))
        elif above.size and above[0] == 0:
            thr = float(s[0])  # an upper bound: detected already at the smallest scale
        out[name] = thr
    return out


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (kind, true), g in df.groupby(["kind", "true"], sort=False):
        n = len(g)
        k_exact, k_first = int(g["exact"].sum()), int(g["first"].sum())
        hits = [v for c in g["coverage"] for v in json.loads(c).values()]
        lo, hi = wilson(k_exact, n)
        row = {
            "kind": kind,
            "true": true,
            "n_logs": n,
            "exact_rate": k_exact / n,
            "exact_ci90": f"[{lo:.2f}, {hi:.2f}]",
            "first_rate": k_first / n,
            "any_effect_rate": float((g["n_chosen"] > 0).mean()),
            "coverage90": (sum(hits) / len(hits)) if hits else float("nan"),
            "n_params": len(hits),
            "before_std_mrad": 1e3 * g["before_std"].median(),
            "after_std_mrad": 1e3 * g["after_std"].median(),
            "floor_std_mrad": 1e3 * g["floor_std"].median(),
            "after_over_floor_median": g["after_over_floor"].median(),
            "after_within_10pct": float((np.abs(g["after_over_floor"] - 1) <= 0.1).mean()),
            "explained_rate": float(g["explained"].mean()),
            "wall_s_median": g["wall_s"].median(),
        }
        rows.append(row)
    return pd.DataFrame(rows)


def figure(summary: pd.DataFrame) -> Figure:
    fig = Figure(figsize=(11, 4.5))
    axs = fig.subplots(1, 3, sharey=True)
    lab = [f"{k}: {t}" for k, t in zip(summary["kind"], summary["true"])]
    y = np.arange(len(lab))
    axs[0].barh(y, summary["exact_rate"], color="C0", label="exact set")
    axs[0].plot(summary["first_rate"], y, "k|", ms=10, label="true effect chosen")
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-effect", type=int, default=40)
    ap.add_argument("--clean", type=int, default=100)
    ap.add_argument("--pairs", type=int, default=10, help="logs per pair of effects")
    ap.add_argument("--sweep-logs", type=int, default=6)
    ap.add_argument("--hard", type=int, default=10, help="logs per continuous effect at 3x its threshold")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=20261128)
    ap.add_argument("--out", default="results/benchmarks")
    ap.add_argument("--scaling", action="store_true", help="only time one selection at 1e4, 1e5, 1e6 samples")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from the summary CSV in --out")
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
    ss = np.random.SeedSequence(args.seed)
    seeds = iter(int(s.generate_state(1)[0]) for s in ss.spawn(100000))
    t_start = time.perf_counter()

    sweep_jobs = [(n, sc, next(seeds)) for n in CONTINUOUS for sc in SWEEP_SCALES for _ in range(args.sweep_logs)]
    sweep = pd.DataFrame(_map(_sweep_job, sweep_jobs, args.jobs))
    thr = thresholds(sweep)
    scales = {n: max(1.0, 3.0 * thr[n]) if np.isfinite(thr[n]) else 1.0 for n in CONTINUOUS}

    jobs = [("clean", (), {}, next(seeds)) for _ in range(args.clean)]
    for n in CONTINUOUS + DISCRETE:
        jobs += [("single", (n,), scales, next(seeds)) for _ in range(args.per_effect)]
    hard = {n: 3.0 * thr[n] for n in CONTINUOUS if np.isfinite(thr[n])}
    for n in hard:
        jobs += [("hard", (n,), hard, next(seeds)) for _ in range(args.hard)]
    for pair in PAIRS:
        jobs += [("pair", pair, scales, next(seeds)) for _ in range(args.pairs)]
    df = pd.DataFrame(_map(_challenge_job, jobs, args.jobs))
    summary = summarize(df)
    summary["threshold_scale"] = [thr.get(t, float("nan")) for t in summary["true"]]
    summary["test_over_threshold"] = [
        (scales if k == "single" else hard).get(t, float("nan")) / thr[t] if t in thr and np.isfinite(thr[t]) else float("nan")
        for k, t in zip(summary["kind"], summary["true"])]
    tmp = out / "challenge_residuals.csv.tmp"
    df.to_csv(tmp, index=False)
    tmp.replace(out / "challenge_residuals.csv")
    summary.to_csv(out / "challenge_residuals_summary.csv", index=False)
    sweep.to_csv(out / "challenge_residuals_sweep.csv", index=False)
    figure(summary).savefig(out / "challenge_residuals.png", dpi=110, metadata={"Software": None})

    single = df[df["kind"].isin(["single", "hard"])]
    clean = df[df["kind"] == "clean"]
    hits = [v for c in single["coverage"] for v in json.loads(c).values()]
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    print(summary.drop(columns=["exact_ci90"]).round(3).to_string(index=False))
    print()
    print("thresholds (fraction of nominal magnitude):", {k: round(v, 4) for k, v in thr.items()})
    ks, kf = int(single["exact"].sum()), int((clean["n_chosen"] > 0).sum())
    print(f"single-effect exact identification: {ks}/{len(single)} = {ks / max(len(single), 1):.3f} "
          f"(90% Wilson {wilson(ks, len(single))[0]:.3f}-{wilson(ks, len(single))[1]:.3f}); "
          f"true effect chosen: {int(single['first'].sum())}/{len(single)}")
    print(f"clean false positives: {kf}/{len(clean)} = {kf / max(len(clean), 1):.3f} "
          f"(90% Wilson {wilson(kf, len(clean))[0]:.3f}-{wilson(kf, len(clean))[1]:.3f})")
    if hits:
        print(f"90% interval coverage (single effects, {len(hits)} parameters): {sum(hits) / len(hits):.3f}")
    r = df["after_over_floor"]
    print(f"after/floor std ratio: median {r.median():.3f}, within 10%: {(np.abs(r - 1) <= 0.1).mean():.3f} of logs")
    print(f"selection wall time per log: median {df['wall_s'].median():.2f} s, max {df['wall_s'].max():.2f} s; "
          f"total {time.perf_counter() - t_start:.0f} s with {args.jobs} jobs")


if __name__ == "__main__":
    main()
