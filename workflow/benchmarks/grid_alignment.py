"""Why the embedded logs jitter the motion centre: grid-aligned vs random sub-step centre.

A single joint follows paper 000's protocol (1 kHz, 15 s, 3 deg sinusoid at a frequency drawn in
5 +- 0.1 Hz, truth at 0.125 mrad) and is re-quantized 8x to a 1 mrad step. In one arm every run
is centred exactly on a 1 mrad grid point; in the other the centre is shifted by U(-0.5, 0.5)
mrad, as a lab's arbitrary encoder zero does. For each run and derivative estimator the measured
std of the filtered error is divided by the exact non-white model's prediction (computed on the
same trajectory); the script prints the mean ratio and its standard error over the runs.

With a grid-aligned centre the turning points sit at the same place on the grid in every run,
so the dwell there is the same in every run and the ratio is biased low by ~1.5 %; a random
centre gives ratios consistent with 1 (the model is an average over the sub-step phase).

Usage::

    .venv/bin/python workflow/benchmarks/grid_alignment.py            # 40 runs per arm, ~1 min
    .venv/bin/python workflow/benchmarks/grid_alignment.py --runs 10
"""
from __future__ import annotations

import argparse

import numpy as np

from enclab import filters
from exact_model_precision import filter_ratios  # same folder: run as a script

FILTERS = [filters.DerivativeFilter(1, 1, 200.0), filters.DerivativeFilter(1, 1, 50.0),
           filters.DerivativeFilter(2, 2, 50.0)]


def one_run(rng: np.random.Generator, jitter: bool) -> list[float]:
    return [row["ratio_exact"] for row in filter_ratios(rng, FILTERS, jitter)]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=20261122)
    args = parser.parse_args(argv)
    print(f"{args.runs} runs per arm; measured std / exact-model std of the filtered error")
    print(f"{'centre':>8} " + " ".join(f"{f.label():>22}" for f in FILTERS))
    for jitter in (False, True):
        rng = np.random.default_rng(args.seed)
        r = np.array([one_run(rng, jitter) for _ in range(args.runs)])
        mean, sem = r.mean(axis=0), r.std(axis=0, ddof=1) / np.sqrt(args.runs)
        cells = " ".join(f"{m:>13.4f} +- {s:.4f}" for m, s in zip(mean, sem))
        print(f"{'random' if jitter else 'aligned':>8} {cells}")


if __name__ == "__main__":
    main()
