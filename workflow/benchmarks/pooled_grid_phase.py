"""Does a repeat group of logs sample the grid phase the exact model averages over?

An independent check of a pooled group's measured/exact ratios on the logs themselves. Each log
of the group (``--logs``, a glob of Parquet files with integer truth counts at the fine step
0.125 mrad, as the embedded Phantom runs) is re-quantized to 1 mrad as the workflow does, and
every joint's error is filtered by every filter of ``derivatives.bank`` (and unfiltered):

- ``logged``: at the log's own grid phase (the workflow's measurement);
- ``all_phases``: at each of the ``r = 8`` grid phases of the fine truth (the fine counts
  shifted by ``k = 0..r-1`` before re-quantization), whose average is exactly the grid-phase
  average the exact model predicts (a fine-quantized truth has no other phases).

Per joint and filter it prints and appends to ``results/benchmarks/pooled_grid_phase.csv``
(``date``, ``machine``, ``command`` on every row) the pooled measured/exact std ratio of each
kind, ``sqrt(mean over runs of measured/exact variance)``, with a Student-t 95 % interval over
the runs, and whether the interval excludes 1. The exact variance is the same for every phase
(it depends on the truth's increments only), so a ``logged`` ratio away from 1 with an
``all_phases`` ratio at 1 means the runs' grid phases, not the model, make the difference.

Usage::

    PYTHONPATH=workflow python -m benchmarks.pooled_grid_phase --logs 'data/sim/phantom_c00_r*.parquet'
    PYTHONPATH=workflow python -m benchmarks.pooled_grid_phase --quick   # 6 logs, 4 filters
"""
from __future__ import annotations

import argparse
import glob
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


def run_variances(fine: np.ndarray, bank, model) -> tuple[np.ndarray, np.ndarray]:
    """Measured variances ``(filters + 1, RATIO)`` at every grid phase (phase 0: as logged) and
    exact variances ``(filters + 1,)`` of one joint; row 0 is the unfiltered error."""
    shifted = fine[:, None] + np.arange(RATIO)[None, :]
    err = (quantize.requantize_counts(shifted, RATIO) * RATIO - shifted) * TRUTH_STEP
    impulses = [filters.impulse_response(f, FS, tol=1e-12) for f in bank]
    r_hs = [theory.impulse_autocorrelation(h) for h in impulses]
    c = theory.exact_joint_autocovariance(fine * TRUTH_STEP, model, max(r.size for r in r_hs) - 1)
    measured = [np.var(err, axis=0)]
    exact = [model.variance]
    for filt, r_h in zip(bank, r_hs):
        skip = filters.settle_samples(filt, FS)
        measured.append(np.var(filters.apply(filt, err, FS)[skip:], axis=0))
        exact.append(r_h[0] * c[0] + 2 * np.dot(r_h[1:], c[1:r_h.size]))
    return np.array(measured), np.array(exact)


def pooled(ratios: np.ndarray) -> tuple[float, float, float]:
    """sqrt of the mean variance ratio over runs and its Student-t 95 % interval."""
    mean = ratios.mean()
    half = scipy.stats.t.ppf(0.975, ratios.size - 1) * ratios.std(ddof=1) / np.sqrt(ratios.size)
    return float(np.sqrt(mean)), float(np.sqrt(max(mean - half, 0.0))), float(np.sqrt(mean + half))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", default="data/sim/phantom_c00_r*.parquet", help="glob of one group's logs")
    parser.add_argument("--label", default=None, help="label of the data in the CSV (default: the glob)")
    parser.add_argument("--config", default="config.yaml")
    parser.add_argument("--quick", action="store_true", help="6 logs, 4 filters")
    parser.add_argument("--show", default="d1_n1_fc200_exp", help="filter whose per-run ratios are printed")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    paths = sorted(glob.glob(args.logs))
    bank = analysis.filter_bank(yaml.safe_load(Path(args.config).read_text())["derivatives"])
    if args.quick:
        paths, bank = paths[:6], bank[::12]
    if len(paths) < 2:
        raise SystemExit(f"--logs {args.logs!r}: need at least 2 logs, found {len(paths)}")
    model = theory.QuantizerErrorModel(STEP, 0.5, truth_step=TRUTH_STEP)
    labels = ["position"] + [f.label() for f in bank]
    stamp = provenance(argv)
    first = pd.read_parquet(paths[0])
    joints = [c for c in first.columns if c.endswith("_counts")]
    rows, per_run = [], {}
    for joint in joints:
        logged, phases = [], []
        for path in paths:
            fine = pd.read_parquet(path, columns=[joint])[joint].to_numpy().astype(np.int64)
            measured, exact = run_variances(fine, bank, model)
            logged.append(measured[:, 0] / exact)
            phases.append(measured.mean(axis=1) / exact)
        logged, phases = np.array(logged), np.array(phases)
        if args.show in labels:
            per_run[joint.removesuffix("_counts")] = np.sqrt(logged[:, labels.index(args.show)] / phases[:, labels.index(args.show)])
        for q, label in enumerate(labels):
            row = {**stamp, "data": args.label or args.logs, "runs": len(paths),
                   "joint": joint.removesuffix("_counts"), "filter": label}
            for kind, values in (("logged", logged[:, q]), ("all_phases", phases[:, q])):
                ratio, lo, hi = pooled(values)
                row.update({f"{kind}_ratio": ratio, f"{kind}_lo": lo, f"{kind}_hi": hi,
                            f"{kind}_excludes_1": bool(lo > 1 or hi < 1)})
            rows.append(row)
    table = pd.DataFrame(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "pooled_grid_phase.csv"
    table.to_csv(path, mode="a", header=not path.exists(), index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 500):
        summary = table.groupby("joint").agg(
            rows=("filter", "size"),
            logged_excluded=("logged_excludes_1", "sum"),
            logged_dev_max=("logged_ratio", lambda r: float(np.abs(r - 1).max())),
            logged_dev_median=("logged_ratio", lambda r: float(np.median(r - 1))),
            phases_excluded=("all_phases_excludes_1", "sum"),
            phases_dev_max=("all_phases_ratio", lambda r: float(np.abs(r - 1).max())))
        print(f"{args.label or args.logs}: {len(paths)} runs, {len(labels)} rows per joint")
        print(summary.round(5).to_string())
        print(table[["joint", "filter", "logged_ratio", "logged_lo", "logged_hi", "all_phases_ratio",
                     "all_phases_lo", "all_phases_hi"]].round(5).to_string(index=False))
        for joint, values in per_run.items():
            print(f"{joint} {args.show}: per-run std at the logged phase / over all phases:",
                  " ".join(f"{v:.4f}" for v in values))


if __name__ == "__main__":
    main()
