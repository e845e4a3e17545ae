"""How long does the design search take on 3 joints, the whole bank and 8 resolutions each?

Cost of the design search: 3 joints, a 7^3 grid of motion centres, the whole default filter
bank (both derivative orders budgeted, so every filter of ``derivatives.bank`` in every
architecture is a candidate), 8 candidate resolutions per joint (8^3 combinations).

Times :func:`enclab.design.search.search` (the model terms, every combination and estimator, the
feasible designs, the Pareto front and both choices; no simulation) ``--repeats`` times and
appends the median wall time, the CPU time and the load average to
``results/benchmarks/design_search.csv`` (``date``, ``machine``, ``command`` on every row).
The target is 60 s on 2 cores.

Usage::

    PYTHONPATH=workflow python -m benchmarks.design_search [--repeats 3] [--quick]
"""
from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from enclab.design.problem import problem_from_config
from enclab.design.search import search

from .helpers import provenance

def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="one repeat, 4 resolutions")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    config = yaml.safe_load(Path(args.config).read_text())
    spec = copy.deepcopy(config["design"])
    spec["budget"] = [{"order": 1, "std": 0.004, "worst": 0.05}, {"order": 2, "std": 2.0}]
    spec["filters"] = "bank"
    spec["architectures"] = ["operational", "joint"]
    spec["workspace"] = {**spec["workspace"], "points": 7}
    if args.quick:
        args.repeats = 1
        spec["resolutions"] = {k: v[:4] for k, v in spec["resolutions"].items()}
    walls, cpus = [], []
    for _ in range(args.repeats):
        problem = problem_from_config(spec, config["devices"], config["derivatives"])
        cpu0, wall0 = time.process_time(), time.perf_counter()
        result = search(problem)
        walls.append(time.perf_counter() - wall0)
        cpus.append(time.process_time() - cpu0)
    row = {**provenance(argv), "joints": problem.n_joints, "grid_points": int(problem.centres().shape[0]),
           "bound_cells": int(problem.bound_grid()[0].shape[0]),
           "resolutions": int(problem.steps.size), "combinations": int(result.combos.shape[0]),
           "estimators": len(result.candidates), "designs_evaluated": int(result.n_designs),
           "feasible": int(len(result.designs)), "repeats": args.repeats,
           "wall_s_median": float(np.median(walls)), "wall_s_max": float(np.max(walls)),
           "cpu_s_median": float(np.median(cpus)), "load_1min": os.getloadavg()[0],
           "cores": os.cpu_count()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "design_search.csv"
    table = pd.DataFrame([row])
    if path.exists():
        table = pd.concat([pd.read_csv(path), table], ignore_index=True)
    table.to_csv(path, index=False)
    print(pd.DataFrame([row]).T.to_string(header=False))


if __name__ == "__main__":
    main()
