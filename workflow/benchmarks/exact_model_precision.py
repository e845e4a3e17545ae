"""How close is the exact non-white model, filter by filter, once run-to-run scatter is averaged?

Many trajectories of one joint of paper 000's protocol, every filter of the configured bank.

Protocol: 1 kHz, 15 s, 3 deg at 5 +- 0.1 Hz, truth at 0.125 mrad re-quantized 8x to 1 mrad
(``--continuous``: a continuous truth quantized at 1 mrad). One run's derivative-noise std
depends on where its centre sits within the coarse step (a constant amplitude turns around at
the same place on the grid every cycle; grid_alignment.py), and the model predicts the average
over that position. Each trajectory (random frequency and phase) is therefore run at
``--centres`` centres spread evenly over one step (one random offset), and its pooled ratio
``sqrt(sum measured variance / sum predicted variance)`` is one unbiased, low-scatter sample;
trajectories are independent, so the Student-t interval over them is honest.

Prints per filter the mean measured/exact and measured/PQN ratios with the 95 % interval of the
former, and appends them to ``results/benchmarks/exact_model_precision.csv`` (``date``,
``machine``, ``command`` on every row).

Usage::

    PYTHONPATH=workflow python -m benchmarks.exact_model_precision --runs 40 [--jobs 2]
    PYTHONPATH=workflow python -m benchmarks.exact_model_precision --quick
"""
from __future__ import annotations

import argparse
import concurrent.futures
from pathlib import Path

import numpy as np
import pandas as pd
import scipy.stats
import yaml
from enclab.core import quantize
from enclab.propagation import analysis, filters, theory

from .helpers import provenance

FS = 1000.0
TRUTH_STEP = 1.25e-4
RATIO = 8
STEP = RATIO * TRUTH_STEP


def trajectory_ratios(seed_seq, bank, centres: int, continuous: bool) -> dict:
    """Pooled measured/exact and measured/PQN std ratios of one trajectory over its centres."""
    rng = np.random.default_rng(seed_seq)
    t = np.arange(int(15 * FS)) / FS
    base = np.deg2rad(3.0) * np.sin(2 * np.pi * rng.uniform(4.9, 5.1) * t + rng.uniform(0, 2 * np.pi))
    offsets = ((np.arange(centres) + rng.uniform()) / centres - 0.5) * STEP
    model = theory.QuantizerErrorModel(STEP, 0.5, truth_step=None if continuous else TRUTH_STEP)
    impulses = [filters.impulse_response(f, FS, tol=1e-12) for f in bank]
    r_hs = [theory.impulse_autocorrelation(h) for h in impulses]
    settles = [filters.settle_samples(f, FS) for f in bank]
    max_lag = max(r.size for r in r_hs) - 1
    measured, exact = np.zeros(len(bank)), np.zeros(len(bank))
    for offset in offsets:
        theta = base + offset
        if continuous:
            truth, err = theta, quantize.quantize(theta, STEP) * STEP - theta
        else:
            fine = quantize.quantize(theta, TRUTH_STEP)
            truth = fine * TRUTH_STEP
            err = (quantize.requantize_counts(fine, RATIO) * RATIO - fine) * TRUTH_STEP
        c = theory.exact_joint_autocovariance(truth, model, max_lag)
        for q, (filt, r_h, skip) in enumerate(zip(bank, r_hs, settles)):
            measured[q] += np.var(filters.apply(filt, err, FS)[skip:])
            exact[q] += r_h[0] * c[0] + 2 * np.dot(r_h[1:], c[1:r_h.size])
    pqn = np.array([float(np.sum(h**2)) for h in impulses]) * STEP**2 / 12 * centres
    return {"exact": np.sqrt(measured / exact), "pqn": np.sqrt(measured / pqn)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=40, help="independent trajectories")
    parser.add_argument("--centres", type=int, default=16, help="centres per trajectory")
    parser.add_argument("--seed", type=int, default=20261128)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--continuous", action="store_true", help="continuous truth")
    parser.add_argument("--quick", action="store_true", help="8 trajectories x 8 centres")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    if args.quick:
        args.runs, args.centres = 8, 8
    bank = analysis.filter_bank(yaml.safe_load(Path(args.config).read_text())["derivatives"])
    seeds = np.random.SeedSequence(args.seed).spawn(args.runs)
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        runs = list(pool.map(trajectory_ratios, seeds, [bank] * args.runs,
                             [args.centres] * args.runs, [args.continuous] * args.runs))
    exact = np.array([r["exact"] for r in runs])
    pqn = np.array([r["pqn"] for r in runs])
    q = scipy.stats.t.ppf(0.975, args.runs - 1)
    summary = pd.DataFrame({
        "d": [f.d for f in bank], "n": [f.n for f in bank], "fc_hz": [f.fc_hz for f in bank],
        "discretization": [f.discretization for f in bank],
        "exact_mean": exact.mean(axis=0),
        "exact_ci95": q * exact.std(axis=0, ddof=1) / np.sqrt(args.runs),
        "pqn_mean": pqn.mean(axis=0)})
    stamp = {**provenance(argv), "truth": "continuous" if args.continuous else "0.125 mrad re-quantized 8x",
             "runs": args.runs, "centres": args.centres}
    table = pd.concat([pd.DataFrame([stamp] * len(summary)), summary], axis=1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "exact_model_precision.csv"
    table.to_csv(path, mode="a", header=not path.exists(), index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 200):
        print(f"{args.runs} trajectories x {args.centres} centres per filter; mean measured/exact "
              "+- 95 % interval")
        print(summary.round(5).to_string(index=False))
    worst = (summary["exact_mean"] - 1).abs().max()
    print(f"\nlargest |mean measured/exact - 1| = {worst:.5f}; widest 95 % interval +-"
          f"{summary['exact_ci95'].max():.5f}")


if __name__ == "__main__":
    main()
