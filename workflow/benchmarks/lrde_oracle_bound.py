"""How well could *any* estimator do on the bench_lrde.py draws?

An oracle posterior for the bench_lrde.py draws.

The oracle knows everything but the stroke and the bias: the frequency, the phase and the
jitter are fixed at their true values, and the posterior of ``(A12, a_eq)`` under flat priors
is computed exactly on a grid (no MCMC) from the same interval likelihood as
:func:`enclab.lrde.fit.log_likelihood`. Its posterior median is at least as good as the
5-parameter fit's on average (it has strictly more information), so its RMSE is a floor for
the ``posterior_median`` row of bench_lrde.py. Comparing that floor with the RMSE of eq. (4)
averaged over cycles shows whether a target ratio (issue: posterior RMSE <= 1/3 of eq. 4
averaged, at 20 cycles) is reachable at all with this sampling.

The draws are exactly bench_lrde.py's (same seed tree, same simulator), so the tables can be
joined on (cycles, draw).

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_oracle_bound --draws 200 --cycles 20 --jobs 2

Writes ``<out>/lrde_oracle.csv`` (per draw: oracle, eq. 4 averaged and sampling phase gap) and
prints RMSEs for all draws and split into commensurate / spread sampling.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import pathlib

import numpy as np
import pandas as pd

from enclab.lrde import dwell, fit

from .bench_lrde import COMMENSURATE_GAP, STEP, sampling_phase_gap
from .helpers import open_loop_draw


def grid_posterior(t, counts, A_grid, aeq_grid, f_hz, phase, sigma):
    """Normalised posterior on the (A12, a_eq) grid (steps), flat prior, known f/phase/sigma."""
    sine = np.sin(2.0 * np.pi * f_hz * t + phase)
    A, E = np.meshgrid(A_grid, aeq_grid, indexing="ij")
    rows = np.column_stack([A.ravel(), E.ravel()])
    s = sigma / STEP
    logp = np.empty(len(rows))
    for i in range(0, len(rows), 256):
        a, e = rows[i:i + 256, 0:1], rows[i:i + 256, 1:2]
        z = e + 0.5 * a * sine
        logp[i:i + 256] = fit.log_interval_probability((counts - z) / s, (counts + 1 - z) / s).sum(1)
    logp = logp.reshape(A.shape)
    post = np.exp(logp - logp.max())
    return post / post.sum()


def weighted_median(values, weights):
    order = np.argsort(values)
    cdf = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cdf, 0.5 * cdf[-1])])


def one_draw(rng, n_cycles, fs_hz, f_nominal, noise_frac):
    df, p = open_loop_draw(rng, n_cycles, fs_hz, f_nominal, noise_frac)
    A12, f_hz = p["A12"], p["f_hz"]
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    A_true, aeq_true = A12 / STEP, p["a_eq"] / STEP
    # Coarse then fine grid around the truth (the oracle may look: it only sets the window).
    # The grid centre is shifted off the truth by a random fraction of a cell so that a flat
    # posterior's median cannot snap onto the true value.
    half = (0.25, 0.12)
    for _ in range(2):
        jitter = rng.uniform(-0.5, 0.5, 2) / 60.0
        A_grid = np.linspace(-half[0], half[0], 121) + A_true + jitter[0] * half[0]
        e_grid = np.linspace(-half[1], half[1], 121) + aeq_true + jitter[1] * half[1]
        post = grid_posterior(t, c, A_grid, e_grid, f_hz, p["phase"], max(p["noise_std"], 1e-4 * STEP))
        mA, mE = post.sum(1), post.sum(0)
        support_A = A_grid[mA > 1e-8 * mA.max()]
        support_E = e_grid[mE > 1e-8 * mE.max()]
        half = (max(np.abs(support_A - A_true).max() * 1.2, 0.003),
                max(np.abs(support_E - aeq_true).max() * 1.2, 0.002))
    summ = dwell.dwell_summary(dwell.cycle_table(c, t, STEP))
    return {"cycles": n_cycles, "A12_true": A12, "f_hz_true": f_hz,
            "phase_gap": sampling_phase_gap(fs_hz / f_hz, n_cycles),
            "oracle_A12": weighted_median(A_grid, mA) * STEP,
            "oracle_a_eq": weighted_median(e_grid, mE) * STEP, "a_eq_true": p["a_eq"],
            "eq4_averaged_A12": summ["dwell_formula_A12"]}


def _task(cycles, d, child, args):
    sim_seed, _ = child.spawn(2)
    return one_draw(np.random.default_rng(sim_seed), cycles, args.fs, args.f, args.noise) | {
        "draw": d}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--cycles", type=int, nargs="+", default=[20])
    ap.add_argument("--seed", type=int, default=20260, help="as bench_lrde.py")
    ap.add_argument("--fs", type=float, default=2000.0)
    ap.add_argument("--f", type=float, default=20.0)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="results/benchmarks")
    args = ap.parse_args(argv)
    # bench_lrde.py spawns one child per entry of ITS --cycles list (default 1 5 20 100) and one
    # grandchild per draw; reproduce that tree so the draws match.
    bench_cycles = [1, 5, 20, 100]
    root = np.random.SeedSequence(args.seed)
    tasks = []
    for cycles, ss in zip(bench_cycles, root.spawn(len(bench_cycles))):
        if cycles in args.cycles:
            tasks += [(cycles, d, child) for d, child in enumerate(ss.spawn(args.draws))]
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(_task, *zip(*tasks), [args] * len(tasks)))
    table = pd.DataFrame(rows).sort_values(["cycles", "draw"])
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "lrde_oracle.csv", index=False)
    table["sampling"] = np.where(table["phase_gap"] > COMMENSURATE_GAP, "commensurate", "spread")
    lines = []
    for (cycles, sampling), g in [((c, "all"), g) for c, g in table.groupby("cycles")] + list(
            table.groupby(["cycles", "sampling"])):
        rmse = {k: float(np.sqrt(np.mean((g[k] - g["A12_true"]) ** 2)) / STEP)
                for k in ("oracle_A12", "eq4_averaged_A12")}
        lines.append({"cycles": cycles, "draws": sampling, "n": len(g),
                      "oracle_A12_rmse_step": rmse["oracle_A12"],
                      "eq4_averaged_A12_rmse_step": rmse["eq4_averaged_A12"],
                      "ratio": rmse["oracle_A12"] / rmse["eq4_averaged_A12"]})
    summary = pd.DataFrame(lines)
    summary.to_csv(out / "lrde_oracle_summary.csv", index=False)
    print(summary.to_string(index=False))


if __name__ == "__main__":
    main()
