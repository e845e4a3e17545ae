"""Does the residual stage hold at any length: clean logs named clean, power at 3x threshold?

Residual stage at any length: false effects on clean logs, power at 3x the threshold.

Question: does the selection stay quiet on clean logs and find an effect at 3x its detection
threshold, at 4e3, 4e4, 4e5 and 4e6 samples, and does no chosen effect leave the residual worse
than before?

Logs (``enclab.residuals.simulate``): a 4096-cpr measured channel against a 32768-cpr truth at
1 kHz, a sine, multi-sine or random smooth path of 0.3-1 rad peak (cycled over the draws).
Cases: ``clean`` (no effect) and ``hysteresis`` (a dead band of width ``h``, one parameter,
both signs). The threshold at each length is derived from the selection's own rules, not swept:
the larger of

* the practical size: a dead band shifts the angle by ``+-h/2``, rms ``h/2``, so
  ``h = 2 * min_effect_floor_fraction * floor``;
* the evidence threshold: on ``--pilots`` pilot logs with a dead band of ``h_p`` (a quarter
  step) the calibrated likelihood ratio ``LR_c`` of the dead band is measured; it grows as
  ``h^2`` for small ``h``, so the calibrated delta BIC crosses the criterion at
  ``h_p sqrt((bic_threshold + ln(n / c)) / LR_c)``; the median over pilots.

The effect logs carry ``3 x`` that threshold. A draw counts as *named* when any effect is
chosen, *correct* when the dead band is (or an alternative reported as not distinguishable
from it), *worse* when the residual std after the effects is above the one before.

Run in parts (``--lengths``, ``--draws``, ``--shard i/n``); rows are merged into
``results/benchmarks/residual_length/draws.csv`` by (length, case, draw) (thresholds in
``thresholds.csv`` beside it), the summary ``results/benchmarks/residual_length.csv`` is
rebuilt from every row present.

Commands of the table in the docs (each row names its own): ``--lengths 4000 --draws 100``,
``--lengths 40000 --draws 100``, ``--lengths 400000 --draws 10``, ``--lengths 4000000 --draws 5``
(the larger cells kept small: a 4,000,000-sample log takes 25-35 s of CPU; rerun with more
draws where the machine is free).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd


from enclab.residuals import effects as fx
from enclab.residuals import select as sel
from enclab.residuals import simulate as sim

from .helpers import ROOT, parse_shard, stamp, wilson

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8
FS = 1000.0
KINDS = ("sine", "multisine", "smooth")
FLOOR_FRACTION = 0.1  # the config default of residuals.min_effect_floor_fraction
BIC_THRESHOLD = 10.0
OUT = ROOT / "results" / "benchmarks"


def make_log(n: int, seed: int, h: float | None) -> dict:
    """One simulated log of ``n`` samples; a dead band of width ``h`` when given."""
    rng = np.random.default_rng([seed, n])
    kind = KINDS[seed % len(KINDS)]
    amplitude = rng.uniform(0.3, 1.0)
    motion = sim.random_motion(rng, kind, n / FS, amplitude)
    effects = {"hysteresis": {"h": h}} if h else {}
    log = sim.simulate_log(rng, motion, duration=n / FS, step=STEP, truth_step=TRUTH_STEP, effects=effects)
    log["kind"] = kind
    return log


def calibrated_lr(log: dict, effect) -> tuple[float, float, int, float]:
    """``(LR_c, c, n_fit, floor_std)`` of ``effect`` added to the base model of ``log``."""
    grid, counts = sel.grid_and_counts(log["measured"], STEP)
    fitted = sel.added_effect_fit(log["t"], log["truth"], counts, STEP, TRUTH_STEP, effect, grid=grid,
                                  subsample=True, with_inflation=True, with_floor=True)
    c = fitted["inflation"]
    return 2.0 * (fitted["ll_effect"] - fitted["ll_base"]) / c, c, fitted["n_fit"], fitted["floor_std"]


def threshold(n: int, pilots: int, seed0: int = 9000) -> dict:
    """The dead band's detection threshold at ``n`` samples (module notes)."""
    h_p = 0.25 * STEP
    evid, floors = [], []
    for j in range(pilots):
        log = make_log(n, seed0 + j, h_p)
        lr, c, n_fit, floor = calibrated_lr(log, fx.Hysteresis())
        floors.append(floor)
        need = BIC_THRESHOLD + math.log(n_fit / c)
        evid.append(h_p * math.sqrt(need / max(lr, 1e-12)))
    practical = 2.0 * FLOOR_FRACTION * float(np.median(floors))
    evidence = float(np.median(evid))
    return {"threshold_h": max(practical, evidence), "practical_h": practical, "evidence_h": evidence}


def run_draw(n: int, case: str, draw: int, h_test: float) -> dict:
    seed = 1000 * (case == "hysteresis") + draw
    sign = 1.0 if draw % 2 == 0 else -1.0
    h = sign * h_test if case == "hysteresis" else None
    log = make_log(n, seed, h)
    t0 = time.process_time()
    res = sel.select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    cpu = time.process_time() - t0
    names = [e.name for e in res.effects]
    alts = {a["name"] for e in res.effects for a in e.to_dict()["indistinguishable_from"]}
    hb, ha = res.heldout["before"], res.heldout["after"]
    return {"length": n, "case": case, "draw": draw, "seed": seed, "motion": log["kind"],
            "h": h if h else 0.0, "effects": "+".join(names), "named": bool(names),
            "correct": case == "hysteresis" and ("hysteresis" in names or "hysteresis" in alts),
            "before_std": res.before["std"], "after_std": res.after["std"],
            "floor_std": res.after["floor_std"], "worse": bool(res.after["std"] > res.before["std"]),
            "heldout_before_std": hb["std"], "heldout_after_std": ha["std"],
            "heldout_improves": bool(res.heldout["improves"]), "explained": bool(res.explained),
            "transients": len(res.transients), "cpu_s": cpu}


def wilson90(k: int, n: int) -> tuple[float, float]:
    """Wilson 90 % interval of a rate ``k / n``, clipped to [0, 1]."""
    lo, hi = wilson(k, n, 1.645)
    return max(0.0, lo), min(1.0, hi)


def summarize(draws: pd.DataFrame, thresholds: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (n, case), g in draws.groupby(["length", "case"], sort=True):
        k = int(g["correct"].sum()) if case == "hysteresis" else int(g["named"].sum())
        lo, hi = wilson90(k, len(g))
        thr = thresholds[thresholds["length"] == n]
        rows.append({
            "length": int(n), "case": case, "draws": len(g),
            "h_over_step": float(g["h"].abs().median() / STEP) if case == "hysteresis" else 0.0,
            "threshold_over_step": float(thr["threshold_h"].iloc[0] / STEP) if len(thr) else float("nan"),
            "rate": ("correct " if case == "hysteresis" else "named ") + f"{k}/{len(g)}",
            "rate_90ci": f"{lo:.3f}-{hi:.3f}",
            "named_other": int((g["named"] & ~g["correct"]).sum()) if case == "hysteresis" else 0,
            "worse": int(g["worse"].sum()),
            "heldout_not_improved": int((~g["heldout_improves"]).sum()),
            "explained": int(g["explained"].sum()),
            "transients": int(g["transients"].sum()),
            "after_over_floor": float((g["after_std"] / g["floor_std"]).mean()),
            "cpu_s_per_log": float(g["cpu_s"].mean()),
        })
    return pd.DataFrame(rows)


def save(out: Path, old: pd.DataFrame, rows: list, thr_old: pd.DataFrame, thr_rows: list) -> pd.DataFrame:
    """Merge the new draws and thresholds into the CSVs; rebuild and write the summary."""
    new = stamp(pd.DataFrame(rows)) if rows else pd.DataFrame()
    draws = pd.concat([old, new], ignore_index=True).drop_duplicates(["length", "case", "draw"], keep="last")
    draws.to_csv(out / "residual_length" / "draws.csv", index=False)
    thr_all = pd.concat([thr_old, stamp(pd.DataFrame(thr_rows))] if thr_rows else [thr_old], ignore_index=True)
    thr_all.to_csv(out / "residual_length" / "thresholds.csv", index=False)
    summary = summarize(draws, thr_all)
    # one provenance per summary row: the latest draw of its cell
    last = draws.sort_values("date").groupby(["length", "case"]).tail(1).set_index(["length", "case"])
    prov = pd.DataFrame([last.loc[(r.length, r.case), ["date", "machine", "command"]].to_dict()
                         for r in summary.itertuples()])
    stamp(pd.concat([prov, summary], axis=1)).to_csv(out / "residual_length.csv", index=False)
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", type=int, nargs="+", default=[4000, 40000, 400000, 4000000])
    ap.add_argument("--draws", type=int, default=100, help="draws per case and length")
    ap.add_argument("--pilots", type=int, default=5, help="pilot logs of the evidence threshold")
    ap.add_argument("--cases", nargs="+", default=["clean", "hysteresis"], choices=["clean", "hysteresis"])
    ap.add_argument("--shard", type=parse_shard, default=(0, 1), help="i/n: every n-th draw from the i-th")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--redo", action="store_true", help="rerun draws already in the draws CSV")
    args = ap.parse_args(argv)
    (args.out / "residual_length").mkdir(parents=True, exist_ok=True)
    draws_path, thr_path = args.out / "residual_length" / "draws.csv", args.out / "residual_length" / "thresholds.csv"
    old = pd.read_csv(draws_path) if draws_path.exists() else pd.DataFrame()
    thr_old = pd.read_csv(thr_path) if thr_path.exists() else pd.DataFrame(columns=["length"])
    rows, thr_rows = [], []
    for n in args.lengths:
        known = thr_old[thr_old["length"] == n]
        if len(known):
            thr = known.iloc[0].to_dict()
        else:
            thr = {"length": n, **threshold(n, args.pilots), "pilots": args.pilots}
            thr_rows.append(thr)
            print(f"{n}: threshold {thr['threshold_h'] / STEP:.3f} step (practical {thr['practical_h'] / STEP:.3f},"
                  f" evidence {thr['evidence_h'] / STEP:.3f})", flush=True)
        for case in args.cases:
            done = set(old.loc[(old["length"] == n) & (old["case"] == case), "draw"]) if len(old) else set()
            for draw in range(args.shard[0], args.draws, args.shard[1]):
                if draw in done and not args.redo:
                    continue
                row = run_draw(n, case, draw, 3.0 * float(thr["threshold_h"]))
                rows.append(row)
                print(f"{n} {case} {draw}: {row['effects'] or '-'} worse={row['worse']} "
                      f"heldout {row['heldout_before_std']:.3g}->{row['heldout_after_std']:.3g} "
                      f"{row['cpu_s']:.1f}s", flush=True)
                if len(rows) % 10 == 0:  # a long run interrupted keeps what it measured
                    save(args.out, old, rows, thr_old, thr_rows)
    summary = save(args.out, old, rows, thr_old, thr_rows)
    print(summary.to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
