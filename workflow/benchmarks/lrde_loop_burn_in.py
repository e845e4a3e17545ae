"""Is the loop posterior's burn-in long enough: does doubling it move the intervals?

Benchmark of the loop structures' sampler (:func:`enclab.lrde.loop.fit_loop`) on the
closed-loop benchmark's logs (:func:`benchmarks.lrde_closed_loop.simulate_log`, same seeds).

Per draw the structure the closed-loop benchmark's stage chose for that log (its draws table,
``--draws-table``) is fitted twice from the same seed and point fit: with the stage's burn-in
(400 steps, the chains checked after the first half of it, where a noisy log's may end) and
with twice that. Both runs make the same first 450 steps, so where both end at their first
check the comparison is of the block after 200 steps against the block after 400 of the same
chains. Recorded per draw: the log's position noise, the posterior's median jitter, the
burn-in each fit kept (``n_burn``), whether it converged, the shift of the medians of ``A12``
and ``E_b`` in half-widths of the longer burn-in's 90 % interval and the ratio of the
intervals' widths, and each fit's wall time beside a 5M-iteration Python loop. The summary
gives the same per group: chains that ended after half the burn-in, and those that did not.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_loop_burn_in --cycles 20 40 --draws 4

Writes ``<out>/lrde_loop_burn_in_draws.csv`` and ``<out>/lrde_loop_burn_in.csv``.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
import pandas as pd

from enclab.core.allocator import keep_freed_memory
from enclab.core.parallel import limit_blas_threads
from enclab.lrde import loop

from .helpers import ROOT, reference_loop_seconds, stamp
from .lrde_closed_loop import STEP, simulate_log

BURN_IN = 400  # the stage's (fit_loop's default)


def _fit(df, structure, seed, n_burn, threads):
    started = time.perf_counter()
    fit = loop.fit_loop(df["t"].to_numpy(), df["coarse"].to_numpy(),
                        df["reference"].to_numpy(), STEP, seed, structure, n_burn=n_burn,
                        threads=threads)
    return fit, time.perf_counter() - started


def one_draw(gains, effect, cycles, seed, structure, threads) -> dict:
    df, _, truth = simulate_log(np.random.default_rng(seed), gains, effect, cycles)
    ref_s = reference_loop_seconds(clock=time.perf_counter)
    stage, stage_s = _fit(df, structure, seed, BURN_IN, threads)
    longer, longer_s = _fit(df, structure, seed, 2 * BURN_IN, threads)
    row = {"gains": gains, "effect": effect, "cycles": cycles, "seed": seed,
           "structure": structure, "noise_steps": truth["noise_steps"],
           "jitter_steps": stage.summary["sigma"]["median"] / STEP,
           "n_burn": stage.settings["n_burn"], "converged": stage.converged,
           "n_burn_longer": longer.settings["n_burn"], "converged_longer": longer.converged,
           "wall_s": stage_s, "wall_longer_s": longer_s, "reference_loop_s": ref_s}
    for name in ("A12", "E_b"):
        a, b = stage.summary[name], longer.summary[name]
        half = 0.5 * (b["q95"] - b["q05"])
        row[f"{name}_shift_hw"] = (a["median"] - b["median"]) / half
        row[f"{name}_width_ratio"] = (a["q95"] - a["q05"]) / (2 * half)
    return row


def summarise(draws: pd.DataFrame) -> pd.DataFrame:
    rows = []
    early = draws["n_burn"] < BURN_IN
    for label, part in (("after half the burn-in", draws[early]),
                        ("after the whole burn-in", draws[~early])):
        if part.empty:
            continue
        row = {"chains_ended": label, "logs": len(part),
               "converged": int(part["converged"].sum()),
               "noise_steps": "|".join(f"{v:g}" for v in sorted(part["noise_steps"].unique())),
               "jitter_steps_min": part["jitter_steps"].min(),
               "jitter_steps_max": part["jitter_steps"].max()}
        for name in ("A12", "E_b"):
            row[f"{name}_shift_hw_max"] = part[f"{name}_shift_hw"].abs().max()
            row[f"{name}_width_ratio_min"] = part[f"{name}_width_ratio"].min()
            row[f"{name}_width_ratio_max"] = part[f"{name}_width_ratio"].max()
        row["wall_ratio_median"] = (part["wall_s"] / part["wall_longer_s"]).median()
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, nargs="+", default=[20])
    ap.add_argument("--draws", type=int, default=8, help="logs per cell of the draws table")
    ap.add_argument("--draws-table", default=str(ROOT / "docs" / "benchmarks"
                                                 / "lrde_closed_loop_draws.csv"),
                    help="the closed-loop benchmark's draws: cells, seeds, chosen structures")
    ap.add_argument("--code", default=None,
                    help="only the draws the table recorded at this commit (its code column)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    args = ap.parse_args(argv)
    table = pd.read_csv(args.draws_table)
    if "command_channel" in table:
        table = table[table["command_channel"].fillna(False).astype(bool)]
    if args.code is not None:
        table = table[table["code"].astype(str) == args.code]
    table = table[table["cycles"].isin(args.cycles)
                  & table["chosen"].astype(str).str.startswith("loop-")]
    table = table.drop_duplicates(["cycles", "gains", "effect", "seed"], keep="last")
    table = table.groupby(["cycles", "gains", "effect"], sort=False).head(args.draws)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    keep_freed_memory()
    limit_blas_threads(args.threads)
    rows = []
    for r in table.itertuples():
        rows.append(one_draw(r.gains, r.effect, int(r.cycles), int(r.seed), r.chosen,
                             args.threads))
        x = rows[-1]
        print(f"{r.gains} {r.effect} {r.cycles} cyc seed {r.seed} {r.chosen}: burn-in "
              f"{x['n_burn']} vs {x['n_burn_longer']}, A12 {x['A12_shift_hw']:+.2f} hw "
              f"x{x['A12_width_ratio']:.2f}, E_b {x['E_b_shift_hw']:+.2f} hw "
              f"x{x['E_b_width_ratio']:.2f}, {x['wall_s']:.0f} s vs {x['wall_longer_s']:.0f} s",
              flush=True)
        stamp(pd.DataFrame(rows)).to_csv(out / "lrde_loop_burn_in_draws.csv", index=False)
    draws = stamp(pd.DataFrame(rows))
    draws.to_csv(out / "lrde_loop_burn_in_draws.csv", index=False)
    summary = summarise(draws)
    stamp(summary).to_csv(out / "lrde_loop_burn_in.csv", index=False)
    print(summary.to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
