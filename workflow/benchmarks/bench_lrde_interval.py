"""What do the LRDE likelihood's interval probabilities cost, gathered by kind or in place?

Cost of the LRDE likelihood's interval probabilities: gathered by kind or in place.

``log(Phi(upper) - Phi(lower))`` of every reading (:mod:`enclab.lrde.effects`) has two
evaluations: the entries near an interval edge gathered and taken by kind
(``_log_interval_sparse``), or every entry in place (``_log_interval_dense``).
``_log_interval_near`` picks the second when the share of near entries reaches
``_DENSE_SHARE``. This script times both on readings spread uniformly over a count
(``lower = -u / s``, ``upper = (1 - u) / s``) for a range of position noise ``s``, and the
pick, alternating them so that the machine's drift hits all alike; times are medians over
``--rounds`` rounds of ``--calls`` calls.

Usage::

    PYTHONPATH=workflow python -m benchmarks.bench_lrde_interval
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_interval --rounds 21 --out results/benchmarks

Writes ``<out>/lrde_interval.csv``.
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd

from .helpers import ROOT, stamp

NOISE_STEPS = (0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.3)
SHAPES = ((1, 2500), (16, 2000))


def _per_call(fn, calls):
    started = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - started) / calls


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument("--calls", type=int, default=20, help="calls per timing (x10 for one row)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    args = ap.parse_args(argv)
    from enclab.lrde import effects

    rng = np.random.default_rng(args.seed)
    rows = []
    for s in NOISE_STEPS:
        for shape in SHAPES:
            u = rng.uniform(0.0, 1.0, shape)
            lower, upper = -u / s, (1.0 - u) / s
            near = (lower >= -effects.INTERVAL_DEPTH) | (upper <= effects.INTERVAL_DEPTH)
            keep = np.flatnonzero(near)

            def gathered():
                idx = np.flatnonzero((lower >= -effects.INTERVAL_DEPTH) | (upper <= effects.INTERVAL_DEPTH))
                return effects.log_interval_probability(lower.ravel()[idx], upper.ravel()[idx],
                                                        "gathered")

            def in_place():
                return effects.log_interval_probability(lower.ravel(), upper.ravel(), "in_place")

            def picked():
                return effects.log_interval_probability(lower, upper, "rows")

            dense_rows = np.where(near, in_place().reshape(shape), 0.0).sum(axis=1)
            sparse_rows = np.bincount(keep // shape[1], weights=gathered(),
                                      minlength=shape[0])
            calls = args.calls * (10 if shape[0] == 1 else 1)
            times = {"gathered": [], "in_place": [], "picked": []}
            for _ in range(args.rounds):
                for name, fn in (("gathered", gathered), ("in_place", in_place),
                                 ("picked", picked)):
                    times[name].append(_per_call(fn, calls))
            med = {k: float(np.median(v)) for k, v in times.items()}
            rows.append({"noise_steps": s, "rows": shape[0], "samples": shape[1],
                         "near_share": float(near.mean()),
                         "gathered_ms": 1e3 * med["gathered"],
                         "in_place_ms": 1e3 * med["in_place"],
                         "picked_ms": 1e3 * med["picked"],
                         "in_place_over_gathered": med["in_place"] / med["gathered"],
                         "picked_path": "in place" if near.mean() >= effects.INTERVAL_DENSE_SHARE
                         else "gathered",
                         "max_row_difference": float(np.max(np.abs(dense_rows - sparse_rows)))})
            print(rows[-1], flush=True)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stamp(pd.DataFrame(rows)).to_csv(out / "lrde_interval.csv", index=False)
    print(f"wrote {out / 'lrde_interval.csv'}")


if __name__ == "__main__":
    main()
