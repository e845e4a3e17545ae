"""Which models does the effect comparison's fold test keep out, and should it?

A candidate replaces the sinusoid only if its held-out gain exceeds ``min_z`` standard errors
*and* it predicts no fold worse by more than ``fold_se`` of that fold's own standard errors
(:func:`enclab.lrde.compare.compare_effect_models`). With ``fold_se = 0`` every fold must be
predicted better; the default 2 lets a fold lose within its noise.

Per draw of ``bench_lrde_effects.py`` (same logs and seeds for the same case, cycle count and
draw index) the comparison runs with each value of ``--fold-se`` (the first one always; the
others only where some model clears ``min_z`` and predicts a fold worse, the only draws whose
choice they can change; elsewhere their choice is the first run's). Recorded per draw: the
model chosen under each value, whether it names the right effect (the sinusoid on a clean or
noisy log) and whether its estimates are trusted; the models that clear ``min_z`` but lose a
fold, with each fold's gain and standard error.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_fold_rule --cases harmonic hysteresis clean --draws 200
    PYTHONPATH=workflow python -m benchmarks.lrde_fold_rule --cases clean --draws 200 --shard 1/2
    PYTHONPATH=workflow python -m benchmarks.lrde_fold_rule --from-draws a/lrde_fold_rule_draws.csv \\
        b/lrde_fold_rule_draws.csv

Writes ``<out>/lrde_fold_rule_draws.csv`` and ``<out>/lrde_fold_rule.csv`` (per case, cycle
count and ``fold_se``: named rate with its Wilson 95 % interval, draws whose choice differs
from the first value's).
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd


from enclab.core.allocator import keep_freed_memory
from enclab.lrde import compare

from . import bench_lrde_effects as bench
from .helpers import stamp, wilson

STEP = bench.STEP
FOLD_SE = (2.0, 0.0)
MIN_Z = 2.0


def _named(case, chosen) -> bool:
    right = bench.RIGHT[case]
    return chosen == "sinusoid" if right is None else right in chosen.split("+")


def one_draw(case, n_cycles, seed, fold_ses):
    """The comparison of one benchmark log under each fold test."""
    rng = np.random.default_rng(seed)
    t, counts, truth = bench.simulate_case(rng, case, n_cycles)
    _, compare_seed, _, _ = np.random.SeedSequence(seed).spawn(4)
    started = time.perf_counter()
    first = compare.compare_effect_models(t, counts, STEP, compare_seed, fold_se=fold_ses[0])
    split = [m for m in first["models"][1:]
             if m["z"] is not None and m["z"] > MIN_Z and min(m["delta_elpd_halves"]) <= 0]
    row = {"case": case, "cycles": n_cycles, "seed": seed, "size": truth["size"],
           "split": "|".join(
               f"{m['label']}:" + ",".join(f"{g:.1f}/{s:.1f}" for g, s in zip(
                   m["delta_elpd_halves"], m["delta_se_halves"])) for m in split)}
    for value in fold_ses:
        comp = first
        if value != fold_ses[0] and split:
            comp = compare.compare_effect_models(t, counts, STEP, compare_seed, fold_se=value)
        row |= {f"chosen_{value:g}": comp["chosen"],
                f"named_{value:g}": _named(case, comp["chosen"]),
                f"trusted_{value:g}": comp["check"]["trusted"]}
    row["wall_s"] = time.perf_counter() - started
    return row


def summarise(draws: pd.DataFrame, fold_ses) -> pd.DataFrame:
    rows = []
    for (cycles, case), d in draws.groupby(["cycles", "case"], sort=True):
        for value in fold_ses:
            k = int(d[f"named_{value:g}"].sum())
            lo, hi = wilson(k, len(d))
            differs = d[d[f"chosen_{value:g}"] != d[f"chosen_{fold_ses[0]:g}"]]
            rows.append({"cycles": cycles, "case": case, "fold_se": value, "n": len(d),
                         "named_rate": k / len(d), "named_ci_lo": lo, "named_ci_hi": hi,
                         "untrusted_rate": float((~d[f"trusted_{value:g}"].astype(bool)).mean()),
                         "n_split": int((d["split"].fillna("") != "").sum()),
                         "n_differs": len(differs),
                         "differs": "; ".join(
                             f"{r.seed} ({r.size:.3g}): {getattr(r, f'chosen_{fold_ses[0]:g}')}"
                             f" -> {getattr(r, f'chosen_{value:g}')}"
                             for r in differs.itertuples()),
                         "median_wall_s": float(d["wall_s"].median())})
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bench.add_rerun_arguments(ap, ["harmonic", "hysteresis", "clean", "noise"])
    ap.add_argument("--fold-se", type=float, nargs="+", default=list(FOLD_SE),
                    help="values of the fold test; the first is run on every draw")
    args = ap.parse_args(argv)
    keep_freed_memory()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fold_ses = list(dict.fromkeys(args.fold_se))
    draws = bench.rerun_draws(
        ap, args, lambda case, seed: one_draw(case, args.cycles, seed, fold_ses),
        out / "lrde_fold_rule_draws.csv",
        ("case", "seed", "size", "split", "wall_s", *(f"chosen_{v:g}" for v in fold_ses)))
    summary = stamp(summarise(draws, fold_ses))
    summary.to_csv(out / "lrde_fold_rule.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(summary.drop(columns=["date", "machine", "command"]))


if __name__ == "__main__":
    main()
