"""How does the LRDE stage do on closed-loop logs (paper 002's own setting)?

Benchmark of the LRDE stage on closed-loop logs (paper 002's own setting).

Each draw is a PID servo tracking a 20 Hz sinusoid with the Ros-Drill encoder (0.09 deg) in
the loop (:func:`enclab.lrde.simulate.closed_loop_pid_log`, paper 002 Fig. 5), over a grid of

==========  ====================================================================
axis        values
==========  ====================================================================
gains       ``nominal`` (kp 800, ki 3000) and ``soft`` (kp 400, ki 1500), kd 0
effect      ``none``, ``dead_band`` (width U(0.05, 0.2) step, in the loop), ``missed_count``
            (one count lost at U(0.25, 0.75) of the log, in the loop)
channel     the reference declared as a ``command`` channel (the loop structures of
            :mod:`enclab.lrde.loop` offered), or not (``--no-command``: the periodic models
            alone; rows recorded before this column existed ran so, with ``fourier4`` and
            ``fourier6`` among the candidates)
==========  ====================================================================

and, drawn per log, the encoder offset ``a ~ U(0, step)``, the reference amplitude
``U(1, 3)`` steps (2 to 6 steps peak to peak) and the position noise (0 or 0.02 step, seen by
the encoder only). The loop's pull-in (the first 30 cycles) is left out of the log, and a fine
rounding channel of step/100 reads the motion (the stage's truth channel).

The true values are those of the docs' definitions for a motion that is not a sinusoid,
taken on the simulated angle at the sample instants (not on the fine channel: its rounding,
up to a hundredth of a step per turning point, does not average out over the cycles of a
motion that repeats exactly), over the cycles the stage averages over (from one upward
crossing of the reference's mean to the next, :func:`true_values`): ``A12`` the mean of
``max - min`` of the true angle (and, recorded beside it, ``max - min`` of the
cycle-averaged true angle, the stroke of the periodic part a periodic model describes), the
bias ``b`` the mean of ``(max + min) / 2``, and ``E_b = a + b - (m + 1/2) step`` in the frame
of the fit's centre count ``m`` (with a missed count the counter's offset after it, so that
both segments share the readings' frame). Per draw the stage runs as ``make run`` runs it
(:func:`enclab.lrde.pipeline.analyse_lrde_log`, the ``lrde`` settings of ``config.yaml``, 2
processes, freed memory kept and BLAS limited as in the rule's job) and records the chosen
model and the models whose posteriors the intervals pool (``averaged_over``), whether its
90 % intervals of ``A12`` and ``E_b`` hold the true values, whether the stage flags them
untrusted, and its wall time beside a 5M-iteration Python loop timed just before it (the
machine's speed at that moment), and the commit the stage ran (``code``; a ``+`` when the
checkout differed from it). A log "the model
describes" is one without an encoder effect whose motion repeats from cycle to cycle (standard
deviations of the per-cycle stroke and bias below 0.05 step): there an untrusted flag is false.

Usage (shards run side by side or one after another)::

    PYTHONPATH=workflow python -m benchmarks.lrde_closed_loop --draws 4 --cycles 20 --shard 0/2

Writes ``<out>/lrde_closed_loop_draws.csv`` and ``<out>/lrde_closed_loop.csv`` (per cell).
"""
from __future__ import annotations

import argparse
import pathlib
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import yaml


from enclab.core.allocator import keep_freed_memory
from enclab.core.parallel import limit_blas_threads
from enclab.lrde import loop, pipeline, simulate

from .helpers import ROOT, reference_loop_seconds, stamp

STEP = simulate.ROS_DRILL_STEP
FINE = STEP / 100
F_HZ, FS_HZ = 20.0, 2000.0
PULL_IN = 30
GAINS = {"nominal": (800.0, 3000.0), "soft": (400.0, 1500.0)}
EFFECTS = ("none", "dead_band", "missed_count")
PERIODIC_SD = 0.05  # step: per-cycle stroke and bias standard deviations of a repeating motion


def simulate_log(rng, gains, effect, n_cycles, command=True):
    """``(df, meta, truth)`` of one draw (truth: fine-channel values and what was drawn)."""
    kp, ki = GAINS[gains]
    amplitude = rng.uniform(1.0, 3.0) * STEP
    noise = float(rng.choice([0.0, 0.02])) * STEP
    offset_frac = rng.uniform(0.0, 1.0)
    n_total = PULL_IN + n_cycles
    n_samples = int(round(n_total * FS_HZ / F_HZ))
    kw = {}
    if effect == "dead_band":
        kw["dead_band"] = rng.uniform(0.05, 0.2) * STEP
    elif effect == "missed_count":
        first = int(round(PULL_IN * FS_HZ / F_HZ))
        kw["missed_count"] = (first + int(rng.uniform(0.25, 0.75) * (n_samples - first)), -1)
    df, p = simulate.closed_loop_pid_log(rng, amplitude=amplitude, f_hz=F_HZ, fs_hz=FS_HZ,
                                         n_cycles=n_total, offset_frac=offset_frac, kp=kp,
                                         ki=ki, noise_std=noise, truth_step=FINE, **kw)
    keep = df["t"].to_numpy() >= PULL_IN / F_HZ
    t = df["t"].to_numpy()[keep]
    a_eff = np.full(t.size, p["offset_a"])
    if p["missed_count"] is not None:
        index, delta = p["missed_count"]
        a_eff[np.flatnonzero(keep) >= index] += delta * STEP
    out = pd.DataFrame({"t": t - t[0], "coarse": df["counts"].to_numpy()[keep],
                        "fine": df["truth_counts"].to_numpy()[keep],
                        "reference": df["reference"].to_numpy()[keep]})
    meta = {"log_id": "closed_loop_draw", "channels": [
        {"name": "coarse", "role": "measured", "joint": 1, "unit": "counts",
         "storage": "counts", "step": STEP},
        {"name": "fine", "role": "truth", "joint": 1, "unit": "counts", "storage": "counts",
         "step": FINE}] + ([{"name": "reference", "role": "command", "joint": 1, "unit": "rad",
                             "storage": "float", "step": None}] if command else [])}
    truth = {**true_values(df["theta"].to_numpy()[keep], out["reference"].to_numpy(), a_eff),
             "amplitude_steps": amplitude / STEP, "noise_steps": noise / STEP,
             "offset_frac": offset_frac, "dead_band_steps": kw.get("dead_band", 0.0) / STEP}
    return out, meta, truth


def true_values(theta, reference, a_eff) -> dict:
    """The docs' definitions on the true angle, over the cycles the stage averages over (those
    between the reference's upward crossings of its mean,
    :func:`enclab.lrde.loop.reference_cycles`): a mean over other cycles differs by the cycle-to-cycle scatter of the stroke and bias, a
    few thousandths of a step on a noisy 20-cycle log, as much as the intervals' own width."""
    starts = loop.reference_cycles(reference)
    seg = slice(starts[0], starts[-1])
    idx = starts[:-1] - starts[0]
    top = np.maximum.reduceat(theta[seg], idx)
    bottom = np.minimum.reduceat(theta[seg], idx)
    a_cyc = np.add.reduceat(a_eff[seg], idx) / np.diff(starts)
    stroke, mid = top - bottom, 0.5 * (top + bottom)
    # The cycle-averaged motion (what a periodic model describes): the mean over cycles at
    # each phase (cycles of a whole number of samples).
    per = int(np.min(np.diff(starts)))
    shape = np.mean([theta[i:i + per] for i in starts[:-1]], axis=0)
    return {"A12_true": float(stroke.mean()), "A12_avg_true": float(np.ptp(shape)),
            "a_plus_b": float(np.mean(a_cyc + mid)),
            "stroke_sd_steps": float(stroke.std() / STEP),
            "bias_sd_steps": float(mid.std() / STEP)}


def code_version() -> str:
    """The checkout's commit (with ``+`` when its files differ from it), or ``unknown``: the
    draws of one table may come from several versions of the stage."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+" if dirty.strip() else "")


def one_draw(gains, effect, n_cycles, seed, settings, threads, command=True):
    rng = np.random.default_rng(seed)
    df, meta, truth = simulate_log(rng, gains, effect, n_cycles, command)
    # The machine's speed beside the stage: a 5M-iteration Python loop, timed just before.
    ref_s = reference_loop_seconds(clock=time.perf_counter)
    started = time.perf_counter()
    block, _, _, _ = pipeline.analyse_lrde_log(df, meta, seed, dict(settings), threads=threads)
    wall = time.perf_counter() - started
    row = {"gains": gains, "effect": effect, "cycles": n_cycles, "seed": seed,
           "command_channel": bool(command), "centre_count": block["centre_count"],
           "chosen": block["model"]["chosen"],
           # The models whose posteriors the reported intervals pool ("" when the pick's own).
           "averaged_over": "|".join(block["model"].get("averaged_over") or []),
           "trusted": all(v["trusted"] for v in block["trust"].values()),
           "converged": block["diagnostics"]["converged"], "wall_s": wall,
           "reference_loop_s": ref_s}
    for name in ("A12", "E_b"):
        row[f"{name}_median"], row[f"{name}_q05"], row[f"{name}_q95"] = (
            block[name]["median"], block[name]["q05"], block[name]["q95"])
    return scored(row, truth)


def scored(row, truth) -> dict:
    """``row`` (the stage's intervals) with the true values and whether the intervals hold
    them."""
    row = {**row, **truth,
           "E_b_true": truth["a_plus_b"] - (row["centre_count"] + 0.5) * STEP,
           "described": (row["effect"] == "none" and truth["stroke_sd_steps"] < PERIODIC_SD
                         and truth["bias_sd_steps"] < PERIODIC_SD)}
    for name in ("A12", "E_b"):
        lo, hi = row[f"{name}_q05"], row[f"{name}_q95"]
        true = row[f"{name}_true"]
        row[f"{name}_cover"] = bool(lo <= true <= hi)
        row[f"{name}_confident_miss"] = bool(row["converged"] and row["trusted"]
                                             and max(lo - true, true - hi, 0.0) > hi - lo)
    row["A12_avg_cover"] = bool(row["A12_q05"] <= row["A12_avg_true"] <= row["A12_q95"])
    return row


def rescored(draws: pd.DataFrame) -> pd.DataFrame:
    """Recorded draws scored again against the true values as :func:`true_values` defines
    them, each log simulated again from its seed (the stage is not run again)."""
    rows = []
    for _, r in draws.iterrows():
        row = r.to_dict()
        if pd.isna(row.get("centre_count")):
            # Rows recorded without it: the fit's centre count from the old true values.
            row["centre_count"] = round((row["a_plus_b"] - row["E_b_true"]) / STEP - 0.5)
        _, _, truth = simulate_log(np.random.default_rng(int(row["seed"])), row["gains"],
                                   row["effect"], int(row["cycles"]))
        rows.append(scored(row, truth))
    return pd.DataFrame(rows)[list(draws.columns) + [c for c in rows[0] if c not in draws]]


def summarise(draws: pd.DataFrame) -> pd.DataFrame:
    rows = []
    draws = draws.copy()
    # Draws recorded before the command_channel column existed ran without one.
    draws["command_channel"] = (draws["command_channel"] if "command_channel" in draws
                                else pd.Series(False, index=draws.index)).fillna(False).astype(bool)
    for (cycles, command, gains, effect), g in draws.groupby(
            ["cycles", "command_channel", "gains", "effect"]):
        described = g[g["described"]]
        rows.append({"cycles": cycles, "command_channel": command, "gains": gains,
                     "effect": effect,
                     "n": len(g),
                     "A12_cover": g["A12_cover"].mean(), "E_b_cover": g["E_b_cover"].mean(),
                     "A12_avg_cover": g["A12_avg_cover"].mean(),
                     "A12_bias_steps": ((g["A12_median"] - g["A12_true"]) / STEP).mean(),
                     "untrusted": 1.0 - g["trusted"].mean(),
                     "n_described": len(described),
                     "untrusted_described": (1.0 - described["trusted"].mean()
                                             if len(described) else np.nan),
                     "confident_miss": (g["A12_confident_miss"] | g["E_b_confident_miss"]).mean(),
                     "chosen": "|".join(f"{k}:{v}" for k, v in
                                        g["chosen"].value_counts().items()),
                     # Rows recorded before the code column existed: "earlier".
                     "code": "|".join(f"{k}:{v}" for k, v in g.get(
                         "code", pd.Series("earlier", index=g.index)).fillna("earlier")
                         .value_counts().items()),
                     "wall_s_median": g["wall_s"].median(), "wall_s_max": g["wall_s"].max(),
                     "wall_over_reference_median": (
                         (g["wall_s"] / g["reference_loop_s"]).median()
                         if "reference_loop_s" in g else np.nan)})
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gains", nargs="+", default=list(GAINS), choices=list(GAINS))
    ap.add_argument("--effects", nargs="+", default=list(EFFECTS), choices=EFFECTS)
    ap.add_argument("--cycles", type=int, nargs="+", default=[20])
    ap.add_argument("--draws", type=int, default=100, help="draws per cell (index to stop at)")
    ap.add_argument("--first-draw", type=int, default=0)
    ap.add_argument("--seed", type=int, default=20261204)
    ap.add_argument("--shard", default="0/1", metavar="K/N",
                    help="run the draws whose running index is K modulo N")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--motion-models", nargs="+", default=None,
                    help="lrde.motion_models for these logs (YAML items; default config.yaml's "
                         "candidates)")
    ap.add_argument("--no-command", action="store_true",
                    help="do not declare the reference as a command channel (the loop "
                         "structures are then not offered)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--from-draws", nargs="+", default=None, metavar="CSV",
                    help="summarise these draws instead of running any")
    ap.add_argument("--rescore", action="store_true",
                    help="with --from-draws: score the recorded intervals again against the "
                         "true values as defined now (each log simulated again from its seed)")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.from_draws:
        draws = pd.concat([pd.read_csv(p) for p in args.from_draws], ignore_index=True)
        if "command_channel" not in draws:
            draws["command_channel"] = False
        draws["command_channel"] = draws["command_channel"].fillna(False).astype(bool)
        draws = draws.drop_duplicates(["cycles", "command_channel", "gains", "effect", "seed"],
                                      keep="last")
        if args.rescore:
            draws = rescored(draws)
    else:
        k, n = (int(x) for x in args.shard.split("/"))
        if not 0 <= k < n:
            ap.error(f"--shard {args.shard}: K must be in 0..N-1")
        settings = dict(yaml.safe_load((ROOT / "config.yaml").read_text())["lrde"])
        settings.pop("seed")
        # The process as the rule's job runs it (enclab.runner.run): freed memory kept,
        # BLAS on the stage's threads.
        keep_freed_memory()
        limit_blas_threads(args.threads)
        if args.motion_models is not None:
            settings["motion_models"] = [yaml.safe_load(m) for m in args.motion_models]
        jobs = [(g, e, c, args.seed + 100_000 * EFFECTS.index(e) + 10_000 * list(GAINS).index(g)
                 + 1000 * c + i)
                for i in range(args.first_draw, args.draws) for c in args.cycles for g in args.gains
                for e in args.effects]
        rows, code = [], code_version()
        path = out / (f"lrde_closed_loop_draws_{k}of{n}.csv" if n > 1
                      else "lrde_closed_loop_draws.csv")
        for j, job in enumerate(jobs):
            if j % n != k:
                continue
            rows.append(one_draw(*job, settings, args.threads, not args.no_command)
                        | {"code": code})
            r = rows[-1]
            print(f"{r['gains']} {r['effect']} {r['cycles']} cyc seed {r['seed']}: "
                  f"{r['chosen']} trusted={r['trusted']} A12 cover={r['A12_cover']} "
                  f"E_b cover={r['E_b_cover']} {r['wall_s']:.0f} s", flush=True)
            stamp(pd.DataFrame(rows)).to_csv(path, index=False)
        draws = stamp(pd.DataFrame(rows))
        draws.to_csv(path, index=False)
        if n > 1:
            return 0
    draws.to_csv(out / "lrde_closed_loop_draws.csv", index=False)
    stamp(summarise(draws)).to_csv(out / "lrde_closed_loop.csv", index=False)
    print(summarise(draws).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
