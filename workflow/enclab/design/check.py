"""Proof by simulation: a design on random trajectories of its workspace, against the budget.

The Section IV protocol of Colonnese & Okamura, generalised: each trajectory moves every joint as
``c_i + A_i sin(2 pi f_i t + phi_i)`` with the centre ``c`` uniform over the workspace's centre
box, ``f_i`` uniform in the motion's band and ``phi_i`` uniform; a logged workspace is replayed
with a uniform sub-step shift per joint instead. The truth is continuous; the encoder reads
``step * floor(theta / step + offset_frac)``; the operational error is exact (forward
kinematics of the readings minus that of the truth, no linearisation) and filtered as the
design says (in operational space, or in joint space as ``J(theta^) G theta^ - J(theta) G theta``).
The start-up transient of each filter is discarded. A trajectory passes when every budget item
holds on every axis: measured std (over the trajectory) and max |error| within the budget.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from enclab.design.problem import DesignProblem
from enclab.propagation import filters as flt

__all__ = ["random_trajectories", "simulate", "summarize"]

_BATCH = 50


def random_trajectories(problem: DesignProblem, count: int, duration_s: float,
                        rng: np.random.Generator) -> np.ndarray:
    """``(N, count, n)`` joint trajectories of the problem's workspace (see module docstring)."""
    if count < 1:
        raise ValueError(f"count must be a positive number of trajectories, got {count!r}")
    if problem.trajectory is not None:
        theta = problem.trajectory
        shift = rng.uniform(0.0, float(problem.steps.max()), size=(count, problem.n_joints))
        return theta[:, None, :] + shift[None]
    n_samples = int(round(duration_s * problem.fs_hz))
    if n_samples < 2:
        raise ValueError(f"duration_s={duration_s!r} gives fewer than 2 samples")
    lo, hi = problem.centre_box().T
    centre = rng.uniform(lo, hi, size=(count, problem.n_joints))
    f_lo, f_hi = problem.motion.freq_band
    freqs = rng.uniform(f_lo, f_hi, size=(count, problem.n_joints))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(count, problem.n_joints))
    t = np.arange(n_samples)[:, None, None] / problem.fs_hz
    return centre + problem.motion.amplitude * np.sin(2.0 * np.pi * freqs * t + phase)


def _estimators(design: Mapping):
    out = {}
    for f in design["filters"]:
        out[int(f["order"])] = (flt.DerivativeFilter.from_dict(dict(f["filter"])), f["architecture"])
    return out


def simulate(problem: DesignProblem, design: Mapping, theta: np.ndarray) -> pd.DataFrame:
    """Measured errors of ``design`` on the trajectories ``theta`` (N, T, n).

    Parameters
    ----------
    problem : DesignProblem
    design : mapping
        A design as :func:`enclab.design.search.design_rows` describes it (``steps`` per joint
        name, ``filters`` with ``order``, ``filter``, ``architecture``).
    theta : ndarray (N, T, n)

    Returns
    -------
    pandas.DataFrame
        One row per trajectory, budget item and axis: ``trajectory``, ``item`` (index into
        ``problem.budget``), ``order``, ``axis``, ``std``, ``max_abs``, ``std_budget``,
        ``worst_budget``.
    """
    device, fs = problem.device, problem.fs_hz
    steps = np.array([design["steps"][name] for name in device.joint_names])
    estimators = _estimators(design)
    names = list(device.output_names)
    n_samples, count, n = theta.shape
    rows = []
    for start in range(0, count, _BATCH):
        block = theta[:, start:start + _BATCH]
        b = block.shape[1]
        flat = block.reshape(-1, n)
        reading = steps * np.floor(flat / steps + problem.offset_frac)
        x_err = (device.forward(reading) - device.forward(flat)).reshape(n_samples, b, -1)
        errors = {0: (x_err, 0)}
        for order, (filt, arch) in estimators.items():
            skip = min(flt.settle_samples(filt, fs), n_samples - 2)
            if arch == "operational":
                errors[order] = (flt.apply(filt, x_err, fs, axis=0), skip)
            else:
                phi = flt.apply(filt, block, fs, axis=0).reshape(-1, n)
                phi_err = flt.apply(filt, (reading - flat).reshape(n_samples, b, n), fs, axis=0).reshape(-1, n)
                jq = device.jacobian(reading)
                y = (np.einsum("kji,ki->kj", jq - device.jacobian(flat), phi)
                     + np.einsum("kji,ki->kj", jq, phi_err))
                errors[order] = (y.reshape(n_samples, b, -1), skip)
        for idx, item in enumerate(problem.budget):
            err, skip = errors[item.order]
            err = err[skip:]
            std = err.std(axis=0, ddof=1)
            peak = np.abs(err).max(axis=0)
            for axis in item.axes:
                j = names.index(axis)
                for t_local in range(b):
                    rows.append((start + t_local, idx, item.order, axis, std[t_local, j],
                                 peak[t_local, j], item.std, item.worst))
    return pd.DataFrame(rows, columns=["trajectory", "item", "order", "axis", "std", "max_abs",
                                       "std_budget", "worst_budget"])


def summarize(measured: pd.DataFrame) -> dict:
    """Pass rate and per-item ratios measured/budget from :func:`simulate`'s table.

    Returns
    -------
    dict
        ``trajectories``, ``passed``, ``pass_rate``, ``items``: per budget item the largest and
        the 95th percentile over trajectories of (max over axes) ``std/std_budget`` and
        ``max_abs/worst_budget``, and the item's own pass rate.
    """
    frame = measured.copy()
    frame["std_ratio"] = frame["std"] / frame["std_budget"]
    frame["worst_ratio"] = frame["max_abs"] / frame["worst_budget"]
    per = frame.groupby(["trajectory", "item"])[["std_ratio", "worst_ratio"]].max()
    ok = (per["std_ratio"].fillna(0) <= 1.0) & (per["worst_ratio"].fillna(0) <= 1.0)
    passed = ok.groupby(level="trajectory").all()
    items = []
    for item, group in per.groupby(level="item"):
        entry = {"item": int(item), "pass_rate": float(ok.xs(item, level="item").mean())}
        for col in ("std_ratio", "worst_ratio"):
            values = group[col].dropna()
            if not values.empty:
                entry[f"{col}_max"] = float(values.max())
                entry[f"{col}_q95"] = float(values.quantile(0.95))
                entry[f"{col}_median"] = float(values.median())
        items.append(entry)
    return {"trajectories": int(passed.size), "passed": int(passed.sum()),
            "pass_rate": float(passed.mean()), "items": items}
