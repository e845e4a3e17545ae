"""How far below the bar must a model's held-out gain fall before the stage ignores it?

When the effect comparison keeps the sinusoid, each candidate that still predicts each fold
better by ``min_gain`` nats or more in all is *not ruled out*: it is fitted too and pooled with
the sinusoid's posterior (:func:`enclab.lrde.compare.compare_effect_models`). A small gain
left out lets an effect too small to name shift the intervals (a 3rd harmonic moves the turning
points ``A12`` is read from); every model let in costs the stage an emcee fit and widens the
intervals of logs that hold no effect.

Per draw of ``bench_lrde_effects.py`` (same logs and seeds for the same case, cycle count and
draw index) the comparison runs once with the lowest gain of ``--gains``; the sinusoid's fit
and each model not ruled out at that gain are sampled once, and for every gain of
``--gains`` the stage's ``after`` is formed from the models whose gain reaches it (pooled with
equal weights, :func:`enclab.lrde.fit.pool_fits`). A chosen effect is pooled with the models
not distinguishable from it, whatever the gain. Recorded per draw and gain: whether ``after``
is pooled, and whether its 90 % intervals of ``A12`` (the stroke) and ``E_b`` hold the truth.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_min_gain --cases harmonic clean --draws 100
    PYTHONPATH=workflow python -m benchmarks.lrde_min_gain --cases harmonic --draws 100 --shard 1/2
    PYTHONPATH=workflow python -m benchmarks.lrde_min_gain --from-draws a/lrde_min_gain_draws.csv \\
        b/lrde_min_gain_draws.csv

Writes ``<out>/lrde_min_gain_draws.csv`` and ``<out>/lrde_min_gain.csv`` (per case, cycle
count and gain: coverage with Wilson 95 % intervals, pooled share, median width of ``A12``'s
interval against the sinusoid's own).
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd


from enclab.core.allocator import keep_freed_memory
from enclab.lrde import compare, fit

from . import bench_lrde_effects as bench
from .helpers import stamp, wilson

STEP = bench.STEP
GAINS = (1.0, 0.5, 0.25)


def one_draw(case, n_cycles, seed, sampler, gains):
    """One log through the comparison at the lowest gain; ``after`` for every gain."""
    rng = np.random.default_rng(seed)
    t, counts, truth = bench.simulate_case(rng, case, n_cycles)
    fit_seed, compare_seed, after_seed, alternatives_seed = np.random.SeedSequence(seed).spawn(4)
    started = time.perf_counter()
    comp = compare.compare_effect_models(t, counts, STEP, compare_seed, min_gain=min(gains))
    before = fit.fit_sinusoid(t, counts, STEP, fit_seed,
                              start=comp["full_fits"]["sinusoid"]["x"], **sampler)
    pick = before
    if comp["chosen"] != "sinusoid":
        point = comp["full_fits"][comp["chosen"]]
        pick = fit.fit_sinusoid(t, counts, STEP, after_seed,
                                harmonics=tuple(comp["chosen_harmonics"]),
                                effects=tuple(comp["chosen_effects"]), start=point["x"],
                                **sampler)
    terms = compare.alternative_terms(comp)
    fits = {label: fit.fit_sinusoid(t, counts, STEP, s, harmonics=h, effects=e,
                                    start=point["x"], **sampler)
            for (label, h, e, point), s in zip(terms, alternatives_seed.spawn(len(terms)))}
    gain = {m["label"]: m["delta_elpd"] for m in comp["models"]}
    right = bench.RIGHT[case]
    row = {"case": case, "cycles": n_cycles, "seed": seed, "size": truth["size"],
           "A12_true": truth["stroke"], "E_b_true": truth["E_b"], "chosen": comp["chosen"],
           "named": (comp["chosen"] == "sinusoid") if right is None
           else right in comp["chosen"].split("+"),
           "not_ruled_out": "|".join(f"{label}:{gain[label]:.2f}"
                                     for label in comp["not_ruled_out"]),
           "trusted": comp["check"]["trusted"]}
    lo, hi = bench.interval(pick, "A12")
    own_width = hi - lo
    for g in gains:
        labels = comp["indistinguishable"] + [label for label in comp["not_ruled_out"]
                                              if gain[label] >= g]
        after = fit.pool_fits([pick] + [fits[label] for label in labels]) if labels else pick
        row[f"pooled_{g:g}"] = bool(labels)
        for name in ("A12", "E_b"):
            lo, hi = bench.interval(after, name)
            row[f"{name}_cover_{g:g}"] = bool(lo <= row[f"{name}_true"] <= hi)
            if name == "A12":
                row[f"A12_width_ratio_{g:g}"] = (hi - lo) / own_width
    row["wall_s"] = time.perf_counter() - started
    return row


def summarise(draws: pd.DataFrame, gains) -> pd.DataFrame:
    rows = []
    for (cycles, case), d in draws.groupby(["cycles", "case"], sort=True):
        for g in gains:
            row = {"cycles": cycles, "case": case, "min_gain": g, "n": len(d),
                   "pooled_rate": d[f"pooled_{g:g}"].mean()}
            for name in ("A12", "E_b"):
                k = int(d[f"{name}_cover_{g:g}"].sum())
                lo, hi = wilson(k, len(d))
                row |= {f"{name}_cover": k / len(d), f"{name}_cover_ci_lo": lo,
                        f"{name}_cover_ci_hi": hi}
            row["A12_width_ratio_median"] = float(d[f"A12_width_ratio_{g:g}"].median())
            row["median_wall_s"] = float(d["wall_s"].median())
            rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    bench.add_rerun_arguments(ap, ["harmonic", "clean"])
    ap.add_argument("--gains", type=float, nargs="+", default=list(GAINS))
    args = ap.parse_args(argv)
    keep_freed_memory()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    gains = sorted(set(args.gains), reverse=True)
    sampler = {"n_ensembles": 4, "n_walkers": 16, "n_steps": 250, "n_burn": 100,
               "max_steps": 1000}
    draws = bench.rerun_draws(
        ap, args, lambda case, seed: one_draw(case, args.cycles, seed, sampler, gains),
        out / "lrde_min_gain_draws.csv",
        ("case", "seed", "size", "chosen", "not_ruled_out", "wall_s"))
    summary = stamp(summarise(draws, gains))
    summary.to_csv(out / "lrde_min_gain.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(summary)


if __name__ == "__main__":
    main()
