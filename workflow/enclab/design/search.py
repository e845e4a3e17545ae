"""The search: every combination of per-joint steps and filters, checked against the budget.

For each combination of candidate steps (one per joint, ``R^n`` combinations) and each
candidate derivative estimator (filter and architecture), the largest predicted error over the
workspace is computed for every operational output, twice:

* **exact**: the exact model of the quantization error of the motion (worst grid phase by
  default, see :mod:`enclab.design.model`) and the worst case over the trajectory region
  (Taylor bound with the Hessian and the third-derivative bound);
* **Table II**: PQN (white error, ``||h||_2``) at the grid centres and the centre-configuration
  worst case ``1/2 |J| step ||h||_1`` -- what a design from Colonnese & Okamura's Table II alone would use.

A design is one step per joint plus one estimator per budgeted derivative order; it meets the
budget when every item holds on every named axis. Designs are ranked by cost (the sum of the
joints' encoder costs), then by lag (the largest low-frequency group delay of its filters),
then by margin (the smallest ``budget / predicted - 1`` over the items); the Pareto front is
the set of feasible designs that no other feasible design beats in both cost and lag.

Vectorization: operational variances are linear in the per-joint terms, so for each estimator
the variance of every combination at every workspace point is a sum of ``n`` broadcast arrays
(no loop over combinations); the maximum over the workspace is taken chunk by chunk.
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from enclab.design.model import (Candidate, JointTerms, WorkspaceTerms, candidates, joint_terms,
                                 workspace_terms)
from enclab.design.problem import DesignProblem

__all__ = ["Predictions", "SearchResult", "predict", "search", "design_rows"]

# Elements per chunk of (workspace points x outputs x combinations).
_CHUNK = 4_000_000
_MAX_COMBINATIONS = 2_000_000


@dataclass
class Predictions:
    """Largest predicted error over the workspace, arrays (K candidates, m outputs, C combos).

    ``std`` exact model (the problem's std criterion), ``std_average`` exact model averaged
    over the grid phase, ``worst`` trajectory-region bound, ``std_pqn`` PQN, ``worst_table2``
    Table II's centre-configuration bound.
    """

    std: np.ndarray
    std_average: np.ndarray
    worst: np.ndarray
    std_pqn: np.ndarray
    worst_table2: np.ndarray


def _combinations(n: int, n_steps: int) -> np.ndarray:
    total = n_steps**n
    if total > _MAX_COMBINATIONS:
        raise ValueError(f"{n_steps} candidate steps for {n} joints make {total} combinations "
                         f"(more than {_MAX_COMBINATIONS}); give fewer candidates")
    return np.array(list(itertools.product(range(n_steps), repeat=n)), dtype=np.int64)


def _separable_max(terms: np.ndarray, n_steps: int) -> np.ndarray:
    """``max_g sum_i terms[g, j, i, r_i]`` for every combination ``(r_1..r_n)``.

    ``terms`` (G, m, n, R) -> (m, R^n), combinations in ``itertools.product`` order.
    """
    g_total, m, n, _ = terms.shape
    n_comb = n_steps**n
    chunk = max(1, _CHUNK // max(m * n_comb, 1))
    out = np.full((m, n_comb), -np.inf)
    for start in range(0, g_total, chunk):
        part = terms[start:start + chunk]
        acc = part[:, :, 0, :]
        for i in range(1, n):
            acc = (acc[..., None] + part[:, :, i, :].reshape(part.shape[0], m, *([1] * i), n_steps))
        out = np.maximum(out, acc.reshape(part.shape[0], m, n_comb).max(axis=0))
    return out


def _chunked_max(fn, g_total: int, m: int, n_comb: int) -> np.ndarray:
    """``max_g fn(slice)`` with ``fn`` returning (g, m, C) for a slice of workspace points."""
    chunk = max(1, _CHUNK // max(m * n_comb, 1))
    out = np.full((m, n_comb), -np.inf)
    for start in range(0, g_total, chunk):
        out = np.maximum(out, fn(slice(start, start + chunk)).max(axis=0))
    return out


def predict(problem: DesignProblem, cands: list[Candidate], jt: JointTerms, ws: WorkspaceTerms,
            combos: np.ndarray) -> Predictions:
    """Predicted errors of every candidate and step combination (see :class:`Predictions`)."""
    n_steps = problem.steps.size
    n_comb = combos.shape[0]
    m = problem.device.n_outputs
    K = len(cands)
    eps = problem.steps[combos] * max(problem.offset_frac, 1 - problem.offset_frac)   # (C, n)
    s = eps.sum(axis=1)
    logged = ws.traj_var is not None
    std = np.empty((K, m, n_comb))
    std_avg = np.empty_like(std)
    std_pqn = np.empty_like(std)
    worst = np.empty_like(std)
    table2 = np.empty_like(std)

    # Worst case, shared pieces: lin = sum_i J^ eps_i, quad = sum_il H^ eps_i eps_l per point.
    g_total = ws.j_hat.shape[0]
    rem = 0.5 * ws.t3 * s**2

    def pieces(sl):
        lin = np.einsum("gji,ci->gjc", ws.j_hat[sl], eps)
        quad = np.einsum("gjil,ci,cl->gjc", ws.h_hat[sl], eps, eps)
        return np.stack([lin + 0.5 * quad + ws.t3 * s**3 / 6.0, lin + quad + rem * s], axis=0)

    chunk = max(1, _CHUNK // max(2 * m * n_comb, 1))
    bound0 = np.full((m, n_comb), -np.inf)   # position bound (Taylor, third order)
    bound_j = np.full((m, n_comb), -np.inf)  # joint architecture: the part multiplied by ||h||_1
    for start in range(0, g_total, chunk):
        part = pieces(slice(start, start + chunk)).max(axis=1)
        bound0, bound_j = np.maximum(bound0, part[0]), np.maximum(bound_j, part[1])
    centre0 = _chunked_max(lambda sl: np.einsum("gji,ci->gjc", ws.j0[sl], eps), ws.j0.shape[0],
                           m, n_comb)
    h_max = ws.h_hat.max(axis=0)              # (m, n, n), for the c e term (bounded term by term)

    def joint_bound(k):
        phi = jt.phi_max[k] if ws.phi_abs is None else ws.phi_abs[k]
        c_term = np.einsum("jil,i,cl->jc", h_max, phi, eps)
        return jt.l1[k] * bound_j + c_term + rem * float(np.sum(phi))

    for k, cand in enumerate(cands):
        if logged:
            for out, var, var0 in ((std, ws.traj_var, ws.traj_var0),
                                   (std_avg, ws.traj_var_average, ws.traj_var0_average)):
                if cand.filt is None:
                    v = var0.transpose(2, 0, 1)[None]                              # (1, m, n, R)
                else:
                    v = var[:, :, k, :].transpose(2, 0, 1)[None]
                    if cand.architecture == "joint":
                        v = v + ws.traj_cross[:, :, k, :].transpose(2, 0, 1)[None]
                out[k] = np.sqrt(np.maximum(_separable_max(v, n_steps), 0.0))
        else:
            var_k = jt.var0 if cand.filt is None else jt.var[:, :, k]              # (n, R)
            avg_k = jt.var0_average if cand.filt is None else jt.var_average[:, :, k]
            terms = ws.w2[..., None] * var_k[None, None]                            # (G, m, n, R)
            terms_avg = ws.w2[..., None] * avg_k[None, None]
            if cand.architecture == "joint":
                a = jt.phi_max[k]
                c2 = np.einsum("gjilm,l,m->gji", ws.q, a, a)                        # mean c_ji^2
                terms = terms + c2[..., None] * jt.var0[None, None]
                terms_avg = terms_avg + c2[..., None] * jt.var0_average[None, None]
            std[k] = np.sqrt(_separable_max(terms, n_steps))
            std_avg[k] = np.sqrt(_separable_max(terms_avg, n_steps))
        pqn_terms = ws.j0[..., None] ** 2 * jt.var_pqn[:, :, k][None, None]
        std_pqn[k] = np.sqrt(_separable_max(pqn_terms, n_steps))
        if cand.filt is None:
            worst[k] = bound0
            table2[k] = centre0
        elif cand.architecture == "operational":
            worst[k] = jt.l1[k] * bound0
            table2[k] = jt.l1[k] * centre0
        else:
            worst[k] = joint_bound(k)
            table2[k] = jt.l1[k] * centre0
    return Predictions(std, std_avg, worst, std_pqn, table2)


def _item_margins(problem: DesignProblem, cands: list[Candidate], std: np.ndarray,
                  worst: np.ndarray) -> dict[int, np.ndarray]:
    """Per budgeted order: (K_o, C) margin ``min over items and axes of budget/pred - 1`` for
    the candidates of that order (rows in the order of ``[k for k in cands if order]``)."""
    names = list(problem.device.output_names)
    out = {}
    for order in problem.orders:
        ks = [k for k, c in enumerate(cands) if c.order == order]
        margin = np.full((len(ks), std.shape[2]), np.inf)
        for item in problem.budget:
            if item.order != order:
                continue
            axes = [names.index(a) for a in item.axes]
            if item.std is not None:
                pred = std[ks][:, axes].max(axis=1)
                margin = np.minimum(margin, item.std / pred - 1.0)
            if item.worst is not None:
                pred = worst[ks][:, axes].max(axis=1)
                margin = np.minimum(margin, item.worst / pred - 1.0)
        out[order] = margin
    return out


def _enumerate(problem, cands, jt, margins, cost):
    """Feasible designs: arrays (combo, candidate index per derivative order, margin, lag)."""
    orders = problem.orders
    deriv = [o for o in orders if o > 0]
    base = margins[0][0] if 0 in orders else np.full(cost.size, np.inf)
    per_order = []
    for o in deriv:
        ks = np.array([k for k, c in enumerate(cands) if c.order == o])
        per_order.append((ks, margins[o]))
    combo_idx = np.arange(cost.size)
    max_lag = np.inf if problem.max_lag_s is None else problem.max_lag_s
    if not deriv:
        keep = base >= 0
        return combo_idx[keep], np.zeros((keep.sum(), 0), dtype=int), base[keep], np.zeros(keep.sum())
    # Meshgrid over (combo, k_o1, k_o2, ...), feasible only.
    rows_c, rows_k, rows_m, rows_l = [], [], [], []
    for c in combo_idx[base >= 0]:
        options = []
        for ks, marg in per_order:
            ok = (marg[:, c] >= 0) & (jt.lag[ks] <= max_lag)
            options.append((ks[ok], marg[ok, c]))
        if any(opt[0].size == 0 for opt in options):
            continue
        grids = np.meshgrid(*[np.arange(opt[0].size) for opt in options], indexing="ij")
        idx = [g.ravel() for g in grids]
        ks = np.stack([opt[0][ix] for opt, ix in zip(options, idx)], axis=1)
        marg = np.minimum.reduce([opt[1][ix] for opt, ix in zip(options, idx)] + [np.full(idx[0].size, base[c])])
        lag = jt.lag[ks].max(axis=1)
        rows_c.append(np.full(ks.shape[0], c))
        rows_k.append(ks)
        rows_m.append(marg)
        rows_l.append(lag)
    if not rows_c:
        return (np.zeros(0, dtype=int), np.zeros((0, len(deriv)), dtype=int), np.zeros(0), np.zeros(0))
    return (np.concatenate(rows_c), np.concatenate(rows_k), np.concatenate(rows_m),
            np.concatenate(rows_l))


@dataclass
class SearchResult:
    """The outcome of :func:`search`: predictions, feasible designs and the choices."""

    problem: DesignProblem
    candidates: list[Candidate]
    combos: np.ndarray
    cost: np.ndarray
    joint: JointTerms
    predictions: Predictions
    designs: pd.DataFrame         # feasible designs (exact model), ranked
    pareto: pd.DataFrame          # their (cost, lag) Pareto front
    chosen: dict | None
    table2_chosen: dict | None    # what PQN + Table II alone would choose
    seconds: float
    n_designs: int


def _ranked(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.sort_values(["cost", "lag_s", "margin"], ascending=[True, True, False],
                             kind="mergesort").reset_index(drop=True)


def _pareto(frame: pd.DataFrame) -> pd.DataFrame:
    """Designs that no other feasible design beats in both cost and lag (best margin on ties)."""
    if frame.empty:
        return frame
    best = _ranked(frame).drop_duplicates(["cost", "lag_s"], keep="first")
    keep, best_lag = [], np.inf
    for idx, row in best.iterrows():
        if row["lag_s"] < best_lag:
            keep.append(idx)
            best_lag = row["lag_s"]
    return best.loc[keep].reset_index(drop=True)


def _frame(problem, cands, combos, cost, c_idx, k_idx, margin, lag) -> pd.DataFrame:
    deriv = [o for o in problem.orders if o > 0]
    data = {"combo": c_idx, "cost": cost[c_idx], "lag_s": lag, "margin": margin}
    for j in range(problem.n_joints):
        data[f"step_{j + 1}"] = problem.steps[combos[c_idx, j]]
        data[f"resolution_{j + 1}"] = [problem.labels[r] for r in combos[c_idx, j]]
    for col, o in enumerate(deriv):
        data[f"estimator_order{o}"] = [cands[k].label() for k in k_idx[:, col]]
        data[f"k_order{o}"] = k_idx[:, col]
    return pd.DataFrame(data)


def design_rows(result: "SearchResult", row: pd.Series, table2: bool = False) -> dict:
    """JSON description of one design (a row of ``result.designs``): steps and resolutions per
    joint, estimators, cost, lag, margin and, per budget item, the exact and Table II
    predictions (largest over the workspace and the item's axes)."""
    problem, cands, pred = result.problem, result.candidates, result.predictions
    names = list(problem.device.output_names)
    c = int(row["combo"])
    deriv = [o for o in problem.orders if o > 0]
    ks = {o: int(row[f"k_order{o}"]) for o in deriv}
    if 0 in problem.orders:
        ks[0] = next(k for k, cand in enumerate(cands) if cand.order == 0)
    items = []
    for item in problem.budget:
        k = ks[item.order]
        axes = [names.index(a) for a in item.axes]
        entry = {**item.to_dict(), "estimator": cands[k].label(),
                 "exact_std": float(pred.std[k, axes, c].max()),
                 "exact_std_phase_average": float(pred.std_average[k, axes, c].max()),
                 "worst_case_trajectory": float(pred.worst[k, axes, c].max()),
                 "pqn_std": float(pred.std_pqn[k, axes, c].max()),
                 "worst_case_table2": float(pred.worst_table2[k, axes, c].max())}
        std_pred = entry["pqn_std"] if table2 else entry["exact_std"]
        worst_pred = entry["worst_case_table2"] if table2 else entry["worst_case_trajectory"]
        margins = ([item.std / std_pred - 1] if item.std is not None else []) + \
            ([item.worst / worst_pred - 1] if item.worst is not None else [])
        entry["margin"] = float(min(margins))
        items.append(entry)
    filters = []
    for o in deriv:
        cand = cands[ks[o]]
        filters.append({"order": o, "filter": cand.filt.to_dict(), "architecture": cand.architecture,
                        "label": cand.label(), "lag_s": float(result.joint.lag[ks[o]])})
    return {
        "resolution": {name: problem.labels[r] for name, r in zip(problem.device.joint_names,
                                                                  result.combos[c])},
        "steps": {name: float(problem.steps[r]) for name, r in zip(problem.device.joint_names,
                                                                 result.combos[c])},
        "filters": filters,
        "cost": float(row["cost"]),
        "lag_s": float(row["lag_s"]),
        "margin": float(row["margin"]),
        "items": items,
        "model": "pqn_table2" if table2 else "exact",
    }


def search(problem: DesignProblem) -> SearchResult:
    """Evaluate every design of ``problem`` and choose (see the module docstring).

    Returns
    -------
    SearchResult
        ``chosen`` is None when no design meets the budget (the tightest margin is in
        ``designs`` then empty; widen the candidates or relax the budget).
    """
    started = time.perf_counter()
    cands = candidates(problem)
    combos = _combinations(problem.n_joints, problem.steps.size)
    cost = problem.costs[combos].sum(axis=1)
    jt = joint_terms(problem, cands)
    ws = workspace_terms(problem, cands)
    pred = predict(problem, cands, jt, ws, combos)
    frames = {}
    for kind, std, worst in (("exact", pred.std, pred.worst),
                             ("table2", pred.std_pqn, pred.worst_table2)):
        margins = _item_margins(problem, cands, std, worst)
        frames[kind] = _ranked(_frame(problem, cands, combos, cost,
                                      *_enumerate(problem, cands, jt, margins, cost)))
    n_deriv = 1
    for o in problem.orders:
        if o > 0:
            n_deriv *= sum(1 for c in cands if c.order == o)
    result = SearchResult(problem, cands, combos, cost, jt, pred, frames["exact"],
                          _pareto(frames["exact"]), None, None, 0.0, combos.shape[0] * n_deriv)
    if not frames["exact"].empty:
        result.chosen = design_rows(result, frames["exact"].iloc[0])
    if not frames["table2"].empty:
        result.table2_chosen = design_rows(result, frames["table2"].iloc[0], table2=True)
        # The same design judged by the exact model: where Table II under-designs.
        result.table2_chosen["exact_view"] = design_rows(result, frames["table2"].iloc[0])["items"]
    result.seconds = time.perf_counter() - started
    return result
