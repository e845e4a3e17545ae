"""How do the low-resolution encoder's stroke and bias precision scale with cycles and rate?

How the low-resolution encoder's stroke and bias precision scale with cycles and sample rate.

Paper 002's setting as in bench_lrde.py: step 0.09 deg, offset a ~ U(0, step), stroke
A12 ~ U(3, 5) steps, bias deviation E_b inside Proposition 1's band, f ~ 20 Hz x U(0.9, 1.1), white
position jitter 0.005 step. For every setting (cycles x samples per period) and draw:

- ``posterior``: the posterior median of :func:`enclab.lrde.fit.fit_sinusoid` (default sampler);
- ``oracle``: the posterior median on a grid of (A12, E_b) for an oracle that knows the frequency,
  the phase and the jitter (flat priors, the public :func:`enclab.lrde.fit.log_likelihood`): the
  information floor that no estimator beats on average.

The RMSE per setting (in steps) is fitted by ``rmse = k cycles^-alpha (spp/100)^-beta``
(:func:`enclab.design.lrde.fit_law`), the law that design mode inverts. Appends per-setting rows
to ``results/benchmarks/design_lrde_scaling.csv`` and the laws to
``results/benchmarks/design_lrde_laws.csv`` (``date``, ``machine``, ``command`` on every row).

Usage::

    PYTHONPATH=workflow python -m benchmarks.design_lrde_scaling --draws 24 --jobs 2
    PYTHONPATH=workflow python -m benchmarks.design_lrde_scaling --quick
    # check a designed setting (one row, no law): 78 cycles at 100 samples per period
    PYTHONPATH=workflow python -m benchmarks.design_lrde_scaling --cycles 78 --spp 100 --draws 24
"""
from __future__ import annotations

import argparse
import concurrent.futures
from pathlib import Path

import numpy as np
import pandas as pd

from enclab.design.lrde import fit_law
from enclab.lrde import fit, simulate

from .helpers import open_loop_draw, provenance

STEP = simulate.ROS_DRILL_STEP
F_NOMINAL = 20.0
NOISE = 0.005


def _weighted_median(values, weights):
    order = np.argsort(values)
    cdf = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cdf, 0.5 * cdf[-1])])


def oracle_median(t, counts, p, rng):
    """Posterior medians (steps) of A12 and E_b on an adaptive grid, f/phase/jitter known."""
    A_true, e_true = p["A12"] / STEP, p["E_b"] / STEP
    log_s = np.log10(max(p["noise_std"], 1e-4 * STEP) / STEP)
    half = (0.1, 0.1)
    for size in (61, 81):
        # Offset the grid from the truth by a random fraction of a cell (no snapping).
        jitter = rng.uniform(-0.5, 0.5, 2) / (size - 1)
        A_grid = A_true + half[0] * (np.linspace(-1, 1, size) + 2 * jitter[0])
        e_grid = e_true + half[1] * (np.linspace(-1, 1, size) + 2 * jitter[1])
        A, E = np.meshgrid(A_grid, e_grid, indexing="ij")
        rows = np.column_stack([A.ravel(), E.ravel(), np.full(A.size, p["f_hz"]),
                                np.full(A.size, p["phase"]), np.full(A.size, log_s)])
        logp = np.concatenate([fit.log_likelihood(rows[i:i + 128], t, counts, STEP, 0.0, 0.0)
                               for i in range(0, len(rows), 128)]).reshape(A.shape)
        post = np.exp(logp - logp.max())
        mA, mE = post.sum(axis=1), post.sum(axis=0)
        sA = A_grid[mA > 1e-8 * mA.max()]
        sE = e_grid[mE > 1e-8 * mE.max()]
        half = (max(np.abs(sA - A_true).max() * 1.2, 0.002), max(np.abs(sE - e_true).max() * 1.2, 0.002))
    return _weighted_median(A_grid, mA), _weighted_median(e_grid, mE)


def one_draw(cycles: int, spp: float, draw: int, seed_seq) -> dict:
    sim_seed, fit_seed, grid_seed = seed_seq.spawn(3)
    df, p = open_loop_draw(np.random.default_rng(sim_seed), cycles, spp * F_NOMINAL, F_NOMINAL, NOISE)
    t, counts = df["t"].to_numpy(), df["counts"].to_numpy()
    row = {"cycles": cycles, "samples_per_period": spp, "draw": draw, "A12_true": p["A12"] / STEP,
           "E_b_true": p["E_b"] / STEP, "n_samples": int(t.size)}
    oA, oE = oracle_median(t, counts, p, np.random.default_rng(grid_seed))
    row.update(oracle_A12=oA, oracle_E_b=oE)
    try:
        s = fit.fit_sinusoid(t, counts, STEP, seed=fit_seed).summary
        row.update(posterior_A12=s["A12"]["median"] / STEP,
                   posterior_E_b=s["a_eq"]["median"] / STEP - 0.5)
    except ValueError as err:  # no complete cycle: recorded, not dropped
        row.update(posterior_A12=np.nan, posterior_E_b=np.nan, failed=str(err))
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, nargs="+", default=[5, 20, 80])
    parser.add_argument("--spp", type=float, nargs="+", default=[50.0, 100.0, 200.0],
                        help="samples per motion period (fs = spp x 20 Hz)")
    parser.add_argument("--draws", type=int, default=24)
    parser.add_argument("--seed", type=int, default=20261202)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="4 draws, cycles 5 20, spp 50 100")
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    if args.quick:
        args.draws, args.cycles, args.spp = 4, [5, 20], [50.0, 100.0]
    settings = [(c, s) for c in args.cycles for s in args.spp]
    seeds = np.random.SeedSequence(args.seed).spawn(len(settings))
    tasks = [(c, s, d, child) for (c, s), ss in zip(settings, seeds)
             for d, child in enumerate(ss.spawn(args.draws))]
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(one_draw, *zip(*tasks)))
    draws = pd.DataFrame(rows)
    summary = []
    for (c, s), g in draws.groupby(["cycles", "samples_per_period"]):
        for est in ("posterior", "oracle"):
            for q in ("A12", "E_b"):
                err = (g[f"{est}_{q}"] - g[f"{q}_true"]).dropna()
                summary.append({"cycles": c, "samples_per_period": s, "estimator": est,
                                "quantity": q, "n": int(err.size),
                                "rmse_steps": float(np.sqrt(np.mean(err**2))),
                                "bias_steps": float(err.mean())})
    summary = pd.DataFrame(summary)
    laws = []
    for (est, q), g in summary.groupby(["estimator", "quantity"]):
        try:
            law, stats = fit_law(g)
        except ValueError as err:  # one setting (a check of a designed setting): no law
            print(f"no law for {est} {q}: {err}")
            continue
        laws.append({"estimator": est, "quantity": q, **law.to_dict(), **stats})
    laws = pd.DataFrame(laws)
    stamp = provenance(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for frame, name in ((summary, "design_lrde_scaling.csv"), (laws, "design_lrde_laws.csv")):
        if frame.empty:
            continue
        frame = pd.concat([pd.DataFrame([stamp] * len(frame)), frame.reset_index(drop=True)], axis=1)
        path = out / name
        frame.to_csv(path, mode="a", header=not path.exists(), index=False)
    with pd.option_context("display.width", 200, "display.max_rows", 200):
        print(summary.round(5).to_string(index=False))
        if not laws.empty:
            print(laws.round(4).to_string(index=False))


if __name__ == "__main__":
    main()
