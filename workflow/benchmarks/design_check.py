"""Do the designs that design mode chooses meet their budgets on simulated trajectories?

Proof by simulation of design mode: several budgets, each design on the same random trajectories.

The worked example's device and workspace (config.yaml ``design:``: Phantom Premium 1.5, +-30 deg
per joint, Section IV motion of 3 deg at 5 +- 0.1 Hz about centres spread over the box, 1 kHz,
8 resolutions from 1024 to 131072 cpr, the whole derivative bank in both architectures) with
budgets spanning std-only, worst-case-only and both, for position, velocity and acceleration.
For every budget three designs are chosen and simulated on the same ``--trajectories`` random
trajectories (``--duration`` s each, the Section IV protocol generalised, enclab.design.check):

- ``exact``: the exact model at the worst grid phase of one run and the trajectory worst case
  (the default of design mode);
- ``exact_average``: the exact model averaged over the grid phase (and the trajectory worst case);
- ``table2``: PQN and Table II's centre-configuration worst case alone.

A row per budget and design is appended to ``results/benchmarks/design_check.csv`` (``date``,
``machine``, ``command`` on every row): the design, its predicted margin, the pass rate and,
per budget item, the largest and 95th-percentile measured/budget ratios.

Usage::

    PYTHONPATH=workflow python -m benchmarks.design_check            # 8 budgets x 200 trajectories of 15 s
    PYTHONPATH=workflow python -m benchmarks.design_check --quick    # 3 budgets x 40 trajectories of 5 s
"""
from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from enclab.design import check as chk
from enclab.design.problem import problem_from_config
from enclab.design.search import search

from .helpers import provenance

BUDGETS = [
    ("velocity std 4 mm/s", "std", [{"order": 1, "std": 0.004}]),
    ("velocity std 2 mm/s", "std", [{"order": 1, "std": 0.002}]),
    ("acceleration std 0.5 m/s2", "std", [{"order": 2, "std": 0.5}]),
    ("position worst 0.2 mm", "worst", [{"order": 0, "worst": 0.0002}]),
    ("velocity worst 20 mm/s", "worst", [{"order": 1, "worst": 0.020}]),
    ("velocity std 10 + worst 50 mm/s (worked example)", "both", [{"order": 1, "std": 0.010, "worst": 0.050}]),
    ("velocity std 3 + worst 20 mm/s", "both", [{"order": 1, "std": 0.003, "worst": 0.020}]),
    ("position std 0.1 mm + velocity std 2 mm/s", "std", [{"order": 0, "std": 0.0001}, {"order": 1, "std": 0.002}]),
]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--trajectories", type=int, default=200)
    parser.add_argument("--duration", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=20261202)
    parser.add_argument("--quick", action="store_true", help="3 budgets, 40 trajectories of 5 s")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    config = yaml.safe_load(Path(args.config).read_text())
    budgets = BUDGETS
    if args.quick:
        budgets, args.trajectories, args.duration = [BUDGETS[i] for i in (0, 3, 5)], 40, 5.0
    stamp = provenance(argv)
    rows = []
    for b, (label, kind, budget) in enumerate(budgets):
        designs = {}
        for arm, std in (("exact", "worst_phase"), ("exact_average", "average")):
            spec = copy.deepcopy(config["design"])
            spec.update(budget=budget, std=std)
            problem = problem_from_config(spec, config["devices"], config["derivatives"])
            started = time.perf_counter()
            result = search(problem)
            seconds = time.perf_counter() - started
            designs[arm] = (result.chosen, seconds)
            if arm == "exact":
                designs["table2"] = (result.table2_chosen, seconds)
                base = problem
        # The same trajectories for every design of this budget.
        theta = chk.random_trajectories(base, args.trajectories, args.duration,
                                        np.random.default_rng([args.seed, b]))
        for arm, (design, seconds) in designs.items():
            row = {**stamp, "budget": label, "kind": kind, "design": arm,
                   "trajectories": args.trajectories, "duration_s": args.duration,
                   "search_s": round(seconds, 2)}
            if design is None:
                rows.append({**row, "pass_rate": np.nan, "note": "no feasible design"})
                continue
            summary = chk.summarize(chk.simulate(base, design, theta))
            row.update(resolution=" ".join(design["resolution"].values()),
                       estimators=" ".join(f["label"] for f in design["filters"]) or "-",
                       cost=design["cost"], lag_ms=1e3 * design["lag_s"], predicted_margin=design["margin"],
                       passed=summary["passed"], pass_rate=summary["pass_rate"])
            for i, item in enumerate(summary["items"]):
                for key in ("std_ratio_max", "std_ratio_q95", "worst_ratio_max", "worst_ratio_q95"):
                    if key in item:
                        row[f"item{i}_{key}"] = item[key]
                pred = design["items"][i]
                row[f"item{i}_pred_std"] = pred["pqn_std"] if arm == "table2" else pred["exact_std"]
                row[f"item{i}_pred_worst"] = (pred["worst_case_table2"] if arm == "table2"
                                              else pred["worst_case_trajectory"])
            rows.append(row)
            print(json.dumps({k: row.get(k) for k in ("budget", "design", "resolution", "estimators",
                                                      "cost", "pass_rate")}), flush=True)
    table = pd.DataFrame(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "design_check.csv"
    if path.exists():
        table = pd.concat([pd.read_csv(path), table], ignore_index=True)
    table.to_csv(path, index=False)
    with pd.option_context("display.width", 250, "display.max_rows", 100, "display.max_colwidth", 40):
        new = table.tail(len(rows))
        print(new[["budget", "design", "resolution", "estimators", "cost", "pass_rate"]].to_string(index=False))


if __name__ == "__main__":
    main()
