"""Design mode end to end: configuration in, the ``design`` block, a table and a figure out.

:func:`run_design` is what the ``design`` rule (``scripts/design.py``) and the command
(``python -m enclab.design``) call; it does no I/O.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from enclab.core.canonical import Channel
from enclab.design import check as chk
from enclab.design.lrde import lrde_design
from enclab.design.plots import pareto_figure
from enclab.design.problem import problem_from_config
from enclab.design.search import SearchResult, design_rows, search
from enclab.propagation.analysis import truth_channels

__all__ = ["run_design", "design_table", "truth_trajectory"]

_DEFAULT_CHECK = {"trajectories": 200, "duration_s": 5.0, "seed": 20261202}


def truth_trajectory(df: pd.DataFrame, meta: Mapping) -> np.ndarray:
    """(N, n) truth angles (SI) of a canonical log, joints in order, for a logged workspace."""
    return np.column_stack([Channel.of(chan, df).values for chan in truth_channels(meta)])


def design_table(result: SearchResult) -> pd.DataFrame:
    """The Pareto front (exact model) and the Table II design, one row each: resolution per
    joint, estimators, cost, lag, margin and, per budget item, the largest predicted std and
    worst case over the workspace (exact and Table II)."""
    rows = []
    for rank, (_, row) in enumerate(result.pareto.iterrows()):
        rows.append(("pareto", rank, design_rows(result, row)))
    if result.table2_chosen is not None:
        rows.append(("table2", 0, result.table2_chosen))
    records = []
    for kind, rank, d in rows:
        rec = {"kind": kind, "rank": rank, "cost": d["cost"], "lag_ms": 1e3 * d["lag_s"],
               "margin": d["margin"]}
        rec.update({f"resolution_{k}": v for k, v in d["resolution"].items()})
        rec["estimators"] = " ".join(f["label"] for f in d["filters"]) or "-"
        items = d.get("exact_view", d["items"]) if kind == "table2" else d["items"]
        for i, item in enumerate(items):
            for key in ("exact_std", "worst_case_trajectory", "pqn_std", "worst_case_table2"):
                rec[f"item{i}_{key}"] = item[key]
        records.append(rec)
    return pd.DataFrame(records)


def run_design(design: Mapping, devices: Mapping | None = None, derivatives: Mapping | None = None,
               trajectory: np.ndarray | None = None, simulate: bool = True) -> tuple[dict, pd.DataFrame, Figure]:
    """Search, choose, prove by simulation; the ``design`` block of summary.json (docs/architecture.md).

    Parameters
    ----------
    design : mapping
        The ``design:`` configuration block (see :func:`enclab.design.problem.problem_from_config`);
        ``check`` {``trajectories``, ``duration_s``, ``seed``} sets the simulation, ``lrde`` a
        low-resolution encoder request (:func:`enclab.design.lrde.lrde_design`).
    devices, derivatives : mapping, optional
        ``config["devices"]`` and ``config["derivatives"]``.
    trajectory : ndarray, optional
        The logged truth for ``workspace.log``.
    simulate : bool
        Run the simulation check (``check.trajectories`` random trajectories, the chosen design
        and the Table II design on the same ones).

    Returns
    -------
    block : dict
        ``{"design": {...}}``: ``problem`` (device, workspace, motion, budget, candidates),
        ``budget``, ``chosen`` (resolution and steps per joint, filters, cost, lag, margin, the
        exact and Table II predictions per budget item), ``table2_design`` (the same for the
        design PQN and Table II alone would choose, with ``exact_view``: the exact model's
        verdict on it), ``check`` (pass rates and measured/budget ratios of both), ``pareto``,
        ``search`` (designs evaluated, feasible) and, when requested, ``lrde``. Deterministic
        for a given configuration (the search time is logged instead).
    table : DataFrame
        :func:`design_table`.
    figure : Figure
        :func:`enclab.design.plots.pareto_figure`.
    """
    problem = problem_from_config(design, devices, derivatives, trajectory)
    result = search(problem)
    block = {
        "problem": problem.describe(),
        "budget": [b.to_dict() for b in problem.budget],
        "chosen": result.chosen,
        "table2_design": result.table2_chosen,
        "pareto": [design_rows(result, row) for _, row in result.pareto.iterrows()],
        "search": {"designs_evaluated": int(result.n_designs), "feasible": int(len(result.designs)),
                   "combinations": int(result.combos.shape[0]),
                   "estimators": len(result.candidates)},
    }
    # Times go to the log, not into the block: outputs are deterministic for a given config.
    logging.getLogger("enclab.design").info(
        "searched %d designs (%d feasible) in %.2f s", result.n_designs, len(result.designs),
        result.seconds)
    if result.chosen is None:
        block["message"] = ("no design meets the budget: relax it or add finer resolutions or "
                            "slower filters to the candidates")
    settings = {**_DEFAULT_CHECK, **dict(design.get("check") or {})}
    if simulate and int(settings["trajectories"]) > 0 and result.chosen is not None:
        rng = np.random.default_rng(int(settings["seed"]))
        theta = chk.random_trajectories(problem, int(settings["trajectories"]),
                                        float(settings["duration_s"]), rng)
        check = {"trajectories": int(settings["trajectories"]), "duration_s": float(settings["duration_s"]),
                 "seed": int(settings["seed"]),
                 "exact_design": chk.summarize(chk.simulate(problem, result.chosen, theta))}
        if result.table2_chosen is not None:
            check["table2_design"] = chk.summarize(chk.simulate(problem, result.table2_chosen, theta))
        block["check"] = check
    if design.get("lrde"):
        lrde = dict(design["lrde"])
        block["lrde"] = lrde_design(lrde.get("request", {}), lrde.get("laws", {}))
    figure = pareto_figure(result.designs, result.pareto, result.chosen, result.table2_chosen,
                           title=f"{problem.name}: {', '.join(b.label() for b in problem.budget)}")
    return {"design": block}, design_table(result), figure
