"""Is the LRDE posterior itself calibrated when the true model is fitted?

Calibration of the LRDE posterior itself: the true model, no comparison, no pooling.

The effects benchmark (``bench_lrde_effects.py``) measures the stage: coverage there mixes
the posterior with the model the comparison chose and with pooling. This script separates
them. For fresh draws of ``bench_lrde_effects.simulate_case`` it fits the *true* model
(the sinusoid, or the sinusoid plus the draw's dead band) with emcee at the stage's sampler
settings, started at its point fit, and records whether the 90 % intervals of ``A12`` and
``E_b`` hold the truth (``joint``). It also scores ``E_b`` on a grid with every other
parameter at its true value and records the truth's quantile in that conditional posterior
(``conditional``): the likelihood against its simulator, free of the other parameters.

A joint coverage below the conditional one points at the marginalisation over the other
parameters (frequency, phase, band width, jitter); both below nominal at the likelihood; a
stage coverage below the joint one at the model choice or pooling.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_calibration --case hysteresis --cycles 100 --draws 40
    PYTHONPATH=workflow python -m benchmarks.lrde_calibration --case clean --cycles 100 --draws 40 \\
        --conditional-only

Writes ``<out>/lrde_calibration_draws.csv`` and ``<out>/lrde_calibration.csv`` (appends).
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd


from enclab.core.allocator import keep_freed_memory
from enclab.lrde import effects, fit

from .bench_lrde_effects import STEP, simulate_case
from .helpers import ROOT, stamp, wilson

CASES = ("clean", "noise", "hysteresis")


def conditional_quantile(t, counts, truth, effect_terms, half_width=0.02, n_grid=801):
    """Quantile of the true ``E_b`` in its posterior with every other parameter at the truth
    (flat prior on a grid of +-``half_width`` step around it)."""
    sim = truth["simulator"]
    row = [truth["A12"] / STEP, truth["E_b"] / STEP, truth["f_hz"], truth["phase"],
           np.log10(sim["noise_std"] / STEP)]
    if "hysteresis" in effect_terms:
        row.append(sim["hysteresis"] / STEP)
    row = np.asarray(row)
    grid = row[1] + np.linspace(-half_width, half_width, n_grid)
    rows = np.repeat(row[None, :], grid.size, axis=0)
    rows[:, 1] = grid
    # a_eq = (0 + 1/2 + E_b) step in the simulator's frame: centre count 0, phase at t = 0.
    ll = effects.log_likelihood(rows, t, counts, STEP, 0.0, 0.0, (), effect_terms)
    w = np.exp(ll - ll.max())
    cdf = np.cumsum(w) / w.sum()
    if cdf[0] > 1e-3 or cdf[-2] < 1 - 1e-3:
        raise RuntimeError(f"the E_b grid of +-{half_width} step is too narrow for this log")
    return float(np.interp(row[1], grid, cdf))


def one_draw(case, cycles, seed, sampler, conditional_only):
    rng = np.random.default_rng(seed)
    t, counts, truth = simulate_case(rng, case, cycles)
    effect_terms = ("hysteresis",) if "hysteresis" in truth["simulator"] else ()
    row = {"case": case, "cycles": cycles, "seed": seed, "size": truth["size"]}
    q = conditional_quantile(t, counts, truth, effect_terms)
    row["E_b_conditional_quantile"] = q
    row["E_b_conditional_cover"] = bool(0.05 <= q <= 0.95)
    if conditional_only:
        return row
    started = time.perf_counter()
    point = fit.map_fit(t, counts, STEP, effects=effect_terms)
    result = fit.fit_sinusoid(t, counts, STEP, seed, effects=effect_terms, start=point["x"],
                              **sampler)
    row["wall_s"] = time.perf_counter() - started
    row["converged"] = result.converged
    for name in ("A12", "E_b"):
        s = result.summary[name]
        row[f"{name}_q05"], row[f"{name}_q95"] = s["q05"], s["q95"]
        row[f"{name}_joint_cover"] = bool(s["q05"] <= truth[name] <= s["q95"])
    return row


def summarise(draws: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (cycles, case), g in draws.groupby(["cycles", "case"]):
        row = {"cycles": cycles, "case": case, "n": len(g)}
        for col in ("E_b_conditional_cover", "A12_joint_cover", "E_b_joint_cover"):
            if col in g and g[col].notna().all():
                k = int(g[col].astype(bool).sum())
                lo, hi = wilson(k, len(g))
                row[col] = k / len(g)
                row[f"{col}_ci"] = f"{lo:.2f}-{hi:.2f}"
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=CASES, default="hysteresis")
    ap.add_argument("--cycles", type=int, default=100)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--seed", type=int, default=20261203,
                    help="seeds seed + i: fresh draws, not the effects benchmark's")
    ap.add_argument("--conditional-only", action="store_true",
                    help="skip the emcee fits (seconds per draw instead of tens)")
    ap.add_argument("--n-ensembles", type=int, default=4)
    ap.add_argument("--n-walkers", type=int, default=16)
    ap.add_argument("--n-steps", type=int, default=250)
    ap.add_argument("--n-burn", type=int, default=100)
    ap.add_argument("--max-steps", type=int, default=1000)
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    args = ap.parse_args(argv)
    keep_freed_memory()
    sampler = {"n_ensembles": args.n_ensembles, "n_walkers": args.n_walkers,
               "n_steps": args.n_steps, "n_burn": args.n_burn, "max_steps": args.max_steps}
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(args.draws):
        rows.append(one_draw(args.case, args.cycles, args.seed + i, sampler,
                             args.conditional_only))
        print(rows[-1], flush=True)
    draws = stamp(pd.DataFrame(rows))
    summary = stamp(summarise(draws))
    for name, frame in (("lrde_calibration_draws.csv", draws), ("lrde_calibration.csv", summary)):
        path = out / name
        if path.exists():
            frame = pd.concat([pd.read_csv(path), frame], ignore_index=True)
        frame.to_csv(path, index=False)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(summary)


if __name__ == "__main__":
    main()
