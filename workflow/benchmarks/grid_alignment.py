"""How does a run's sub-step centre move its measured/exact ratio, and where should repeats go?

A repeat group may place its runs grid-aligned, independent uniform, or stratified over one step.

A single joint follows paper 000's protocol (1 kHz, 15 s, 3 deg sinusoid at a frequency drawn in
5 +- 0.1 Hz, truth at 0.125 mrad) and is re-quantized 8x to a 1 mrad step. With a constant
amplitude every cycle turns around at the same place on the coarse grid, so one run's derivative-
noise std depends on where its centre sits within the step; the exact model predicts the average
over that position. The script measures

1. the per-run ratio (measured std / exact-model std) as a function of the centre, on a grid of
   ``--centres`` centres over one step for ``--trajectories`` random trajectories (its range and
   its mean over the step);
2. the scatter of a *pooled* group of ``--runs`` runs (the embedded Fig. 7 group pools 20) under
   four designs, each repeated ``--pools`` times: every centre on a grid point (``aligned``),
   independent uniform centres (``uniform``), one centre uniform within each stratum of width
   step/runs (``stratified``) and evenly spaced centres step/runs apart with one random offset
   (``systematic``, what ``data/tools/make_embedded_data.py`` does per joint); the order of the
   centres over the runs is random.

Rows are appended to ``results/benchmarks/grid_alignment.csv`` (``date``, ``machine``,
``command`` on every row).

Usage::

    PYTHONPATH=workflow python -m benchmarks.grid_alignment            # ~4 CPU-min
    PYTHONPATH=workflow python -m benchmarks.grid_alignment --quick
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from enclab.core import quantize
from enclab.propagation import filters, theory

from .helpers import provenance

FS = 1000.0
TRUTH_STEP = 1.25e-4
RATIO = 8
STEP = RATIO * TRUTH_STEP
FILTERS = [filters.DerivativeFilter(1, 1, 200.0), filters.DerivativeFilter(1, 1, 50.0),
           filters.DerivativeFilter(1, 3, 25.0), filters.DerivativeFilter(2, 2, 50.0)]


class RunRatios:
    """Measured/exact variance ratios of one single-joint run, for a fixed set of filters."""

    def __init__(self, bank, duration_s: float = 15.0):
        self.bank = list(bank)
        self.h = [filters.impulse_response(f, FS, tol=1e-12) for f in self.bank]
        self.r_h = [theory.impulse_autocorrelation(h) for h in self.h]
        self.settle = [filters.settle_samples(f, FS) for f in self.bank]
        self.max_lag = max(r.size for r in self.r_h) - 1
        self.t = np.arange(int(round(duration_s * FS))) / FS
        self.model = theory.QuantizerErrorModel(STEP, 0.5, truth_step=TRUTH_STEP)

    def motion(self, rng: np.random.Generator) -> np.ndarray:
        """A centre-free protocol trajectory (rad)."""
        return np.deg2rad(3.0) * np.sin(2 * np.pi * rng.uniform(4.9, 5.1) * self.t
                                         + rng.uniform(0, 2 * np.pi))

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """Per filter: var(measured filtered error) / exact-model variance, for the run ``theta``."""
        fine = quantize.quantize(theta, TRUTH_STEP)
        err = (quantize.requantize_counts(fine, RATIO) * RATIO - fine) * TRUTH_STEP
        c = theory.exact_joint_autocovariance(fine * TRUTH_STEP, self.model, self.max_lag)
        out = []
        for filt, r_h, skip in zip(self.bank, self.r_h, self.settle):
            measured = np.var(filters.apply(filt, err, FS)[skip:], ddof=1)
            out.append(measured / theory.filtered_variance(r_h, c[: r_h.size]))
        return np.array(out)


def centre_design(kind: str, rng: np.random.Generator, runs: int) -> np.ndarray:
    """Sub-step centres (rad) of one repeat group of ``runs`` runs."""
    if kind == "aligned":
        return np.zeros(runs)
    if kind == "uniform":
        return rng.uniform(-STEP / 2, STEP / 2, size=runs)
    if kind == "stratified":
        return ((rng.permutation(runs) + rng.uniform(size=runs)) / runs - 0.5) * STEP
    if kind == "systematic":
        return ((rng.permutation(runs) + rng.uniform()) / runs - 0.5) * STEP
    raise ValueError(f"kind must be aligned, uniform, stratified or systematic, got {kind!r}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trajectories", type=int, default=4)
    parser.add_argument("--centres", type=int, default=64)
    parser.add_argument("--runs", type=int, default=20, help="runs per pooled group (default 20)")
    parser.add_argument("--pools", type=int, default=12, help="pooled groups per design")
    parser.add_argument("--seed", type=int, default=20261122)
    parser.add_argument("--quick", action="store_true", help="2 trajectories, 16 centres, 4 pools")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    if args.quick:
        args.trajectories, args.centres, args.pools = 2, 16, 4
    ratios = RunRatios(FILTERS)
    rng = np.random.default_rng(args.seed)
    labels = [f.label() for f in FILTERS]
    rows = []

    # 1. the per-run std ratio as a function of the sub-step centre
    grid = ((np.arange(args.centres) + 0.5) / args.centres - 0.5) * STEP
    curves = []
    for _ in range(args.trajectories):
        base = ratios.motion(rng)
        curves.append(np.array([ratios(base + c) for c in grid]))
    curves = np.sqrt(np.array(curves))  # std ratios, (trajectories, centres, filters)
    for k, label in enumerate(labels):
        rows.append({"part": "per_run", "design": "centre_grid", "filter": label,
                     "n": args.trajectories * args.centres,
                     "mean": float(curves[..., k].mean()), "sd": float(curves[..., k].std(ddof=1)),
                     "min": float(curves[..., k].min()), "max": float(curves[..., k].max())})

    # 2. pooled groups: sqrt(mean variance ratio) over the runs of a group, as enclab.propagation.batch pools
    for kind in ("aligned", "uniform", "stratified", "systematic"):
        pooled = []
        for _ in range(args.pools):
            centres = centre_design(kind, rng, args.runs)
            v = np.array([ratios(ratios.motion(rng) + c) for c in centres])
            pooled.append(np.sqrt(v.mean(axis=0)))
        pooled = np.array(pooled)
        for k, label in enumerate(labels):
            rows.append({"part": "pooled", "design": kind, "filter": label, "n": args.pools,
                         "mean": float(pooled[:, k].mean()), "sd": float(pooled[:, k].std(ddof=1)),
                         "min": float(pooled[:, k].min()), "max": float(pooled[:, k].max())})

    table = pd.DataFrame(rows)
    table.insert(0, "runs_per_pool", args.runs)
    for name, value in reversed(provenance(argv).items()):
        table.insert(0, name, value)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "grid_alignment.csv"
    table.to_csv(path, mode="a", header=not path.exists(), index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 100):
        print(table.drop(columns=["date", "machine", "command"]).round(5).to_string(index=False))


if __name__ == "__main__":
    main()
