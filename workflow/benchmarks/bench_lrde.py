"""How accurate and how calibrated are the LRDE stroke/bias estimators on simulated draws?

Benchmark of the LRDE stroke/bias estimators on simulated draws (paper 002 setting).

Each draw: step 0.09 deg, offset a ~ U(0, step), stroke A12 ~ U(3 step, 5 step) (the n = 2
band of eq. 6), bias deviation E_b ~ U(-epsilon/2, epsilon/2) (Proposition 1's band, so the
readings are 4 steps peak to peak about count 0 and eq. 4 applies), bias b = E_b + step/2 - a,
random phase, frequency ~ U(0.9, 1.1) x 20 Hz (so the 2 kHz sampling grid is not commensurate
with the motion and successive cycles are sampled at different phases), white position noise
(default 0.005 step, the likelihood's noise model; ``--noise``). A log holds n + 1 periods so
that n complete crossing-to-crossing cycles exist.

Estimators of A12 and E_b: posterior median of :func:`enclab.lrde.fit.fit_sinusoid`
(default sampler settings), eq. (4) per cycle (every complete cycle is one estimate), eq. (4)
at the mean half-widths, and the least-squares sine fit of the readings (E_b from its
intercept, since the mean of floor(x) is x - 1/2). E_b is always taken relative to count 0
(``a_eq - step/2``), the frame of the simulated truth. Reported per (cycles, estimator): RMSE and
bias; for the posterior also the 90 % interval coverage, median wall time per fit, min ESS per
second and the fraction of fits flagged converged.

Usage::

    PYTHONPATH=workflow python -m benchmarks.bench_lrde --draws 200 --cycles 1 5 20 100 --jobs 2
    PYTHONPATH=workflow python -m benchmarks.bench_lrde --draws 10 --cycles 20      # quick

Writes ``<out>/lrde_draws.csv``, ``<out>/lrde_summary.csv`` and ``<out>/lrde_rmse.png``.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import pathlib
import time

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from enclab.lrde import dwell, fit, simulate

from .helpers import open_loop_draw

STEP = simulate.ROS_DRILL_STEP
# Draws whose pooled sampling phases leave a gap above this (in samples) count as
# commensurate in the summary (see sampling_phase_gap).
COMMENSURATE_GAP = 0.5


def one_draw(rng, n_cycles, fs_hz, f_nominal, noise_frac, fit_seed, sampler, truth_frac=None):
    df, p = open_loop_draw(rng, n_cycles, fs_hz, f_nominal, noise_frac, truth_frac)
    f_hz, A12, E_b = p["f_hz"], p["A12"], p["E_b"]
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    truth = None if truth_frac is None else df["truth_counts"].to_numpy() * truth_frac * STEP
    rows = []
    base = {"cycles": n_cycles, "A12_true": A12, "E_b_true": E_b, "f_hz_true": f_hz,
            "phase_gap": sampling_phase_gap(fs_hz / f_hz, n_cycles)}
    table = dwell.cycle_table(c, t, STEP)
    summ = dwell.dwell_summary(table)
    used = table[table["symmetric"] & (table["n"] == 2) & (table["centre_count"] == 0)]
    used = used.iloc[:n_cycles]
    for _, row in used.iterrows():
        rows.append(base | {"estimator": "eq4_per_cycle", "A12": row["A12_dwell"],
                            "E_b": row["E_b_dwell"]})
    centre = summ["centre_count"] if summ["centre_count"] is not None else 0.0
    rows.append(base | {"estimator": "eq4_averaged", "A12": summ["dwell_formula_A12"],
                        "E_b": summ["E_b_dwell"] + STEP * centre})
    try:
        init = fit.initial_guess(t, c, STEP)
    except ValueError as err:
        # A log without a complete crossing-to-crossing cycle (possible at 1 cycle): the
        # sine fits cannot start; counted as failures in the summary, not dropped silently.
        failed = {"A12": np.nan, "E_b": np.nan, "failed": str(err)}
        return rows + [base | {"estimator": est} | failed
                       for est in ("least_squares", "posterior_median")]
    w = 2 * np.pi * init["f_hz"] * (t - init["t_ref"])
    design = np.column_stack((np.ones_like(t), np.sin(w), np.cos(w)))
    # Nonlinear refinement of the frequency is unnecessary here: f is estimated from the
    # crossings to << 1/(duration), so the linear fit at that f is the LS sine fit.
    coef = np.linalg.lstsq(design, c.astype(float), rcond=None)[0]
    rows.append(base | {"estimator": "least_squares",
                        "A12": 2 * STEP * np.hypot(coef[1], coef[2]),
                        "E_b": STEP * coef[0]})
    started = time.perf_counter()
    r = fit.fit_sinusoid(t, c, STEP, seed=fit_seed, truth=truth, **sampler)
    wall = time.perf_counter() - started
    s = r.summary
    # E_b relative to count 0 (the truth's frame) = a_eq - step/2, whatever centre count the
    # fit used for its own E_b.
    eb = {k: v - 0.5 * STEP for k, v in s["a_eq"].items()}
    rows.append(base | {
        "estimator": "posterior_median", "A12": s["A12"]["median"], "E_b": eb["median"],
        "A12_q05": s["A12"]["q05"], "A12_q95": s["A12"]["q95"],
        "E_b_q05": eb["q05"], "E_b_q95": eb["q95"],
        "wall_s": wall, "ess_min": min(r.ess.values()), "rhat_max": max(r.rhat.values()),
        "converged": r.converged}
        | ({} if r.offset_a is None else {
            "a_true": p["offset_a"], "a_q05": r.offset_a["q05"], "a_q95": r.offset_a["q95"],
            "b_true": p["bias"], "b_q05": r.bias_b["q05"], "b_q95": r.bias_b["q95"]}))
    return rows


def sampling_phase_gap(samples_per_period, n_cycles):
    """Largest gap, in samples, between the sampling phases of ``n_cycles`` periods.

    Cycle ``k`` is sampled at offsets ``k * samples_per_period mod 1`` (in samples) from the
    first cycle's grid; sorted on the circle, their largest gap is the time resolution with
    which the pooled cycles locate a reading change. Near 1 the sampling is commensurate with
    the motion (every cycle sampled at the same phases) and pooling cycles cannot resolve a
    dwell edge better than one sample; near ``1 / n_cycles`` the phases are evenly spread.
    """
    offsets = np.sort(np.mod(np.arange(max(int(n_cycles), 1)) * samples_per_period, 1.0))
    gaps = np.diff(np.concatenate([offsets, [offsets[0] + 1.0]]))
    return float(gaps.max())


def summarise(draws: pd.DataFrame) -> pd.DataFrame:
    out = []
    draws = draws.assign(sampling=np.where(draws["phase_gap"] > COMMENSURATE_GAP,
                                           "commensurate", "spread"))
    groups = [((c, e, "all"), g) for (c, e), g in draws.groupby(["cycles", "estimator"])]
    groups += [((c, e, s), g) for (c, e, s), g
               in draws.groupby(["cycles", "estimator", "sampling"])]
    for (cycles, est, sampling), g in groups:
        n_failed = int((~np.isfinite(g["A12"])).sum())
        g = g[np.isfinite(g["A12"])]
        eA, eE = g["A12"] - g["A12_true"], g["E_b"] - g["E_b_true"]
        row = {"cycles": cycles, "estimator": est, "draws": sampling, "n": len(g),
               "n_failed": n_failed,
               "A12_rmse_step": np.sqrt(np.mean(eA**2)) / STEP,
               "A12_bias_step": eA.mean() / STEP,
               "E_b_rmse_step": np.sqrt(np.mean(eE**2)) / STEP,
               "E_b_bias_step": eE.mean() / STEP}
        if est == "posterior_median":
            row |= {
                "A12_cover90": np.mean((g["A12_q05"] < g["A12_true"])
                                       & (g["A12_true"] < g["A12_q95"])),
                "E_b_cover90": np.mean((g["E_b_q05"] < g["E_b_true"])
                                       & (g["E_b_true"] < g["E_b_q95"])),
                "wall_median_s": g["wall_s"].median(),
                "ess_per_s_median": (g["ess_min"] / g["wall_s"]).median(),
                "converged_fraction": g["converged"].astype(float).mean(),
                "rhat_max": g["rhat_max"].max()}
            if "a_true" in g:
                row |= {name + "_cover90": np.mean((g[name + "_q05"] < g[name + "_true"])
                                                   & (g[name + "_true"] < g[name + "_q95"]))
                        for name in ("a", "b")}
        out.append(row)
    return pd.DataFrame(out).sort_values(["draws", "cycles", "estimator"], kind="stable")


def rmse_figure(summary: pd.DataFrame) -> Figure:
    fig = Figure(figsize=(9, 4), layout="constrained")
    axes = fig.subplots(1, 2)
    summary = summary[summary["draws"] == "all"]
    for ax, col, label in zip(axes, ("A12_rmse_step", "E_b_rmse_step"),
                              ("A12 RMSE [steps]", "E_b RMSE [steps]")):
        for est, g in summary.groupby("estimator"):
            ax.plot(g["cycles"], g[col], "o-", label=est)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("complete cycles in the log")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=8)
    return fig


def _task(cycles, d, child, args, sampler):
    sim_seed, fit_seed = child.spawn(2)
    return [row | {"draw": d} for row in one_draw(np.random.default_rng(sim_seed), cycles,
                                                   args.fs, args.f, args.noise, fit_seed,
                                                   sampler, args.truth_step)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--cycles", type=int, nargs="+", default=[1, 5, 20, 100])
    ap.add_argument("--seed", type=int, default=20260)
    ap.add_argument("--fs", type=float, default=2000.0)
    ap.add_argument("--f", type=float, default=20.0)
    ap.add_argument("--noise", type=float, default=0.005, help="position noise, steps")
    ap.add_argument("--out", default="results/benchmarks")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--n-steps", type=int, default=400, help="as config.yaml lrde.n_steps")
    ap.add_argument("--n-burn", type=int, default=400, help="as config.yaml lrde.n_burn")
    ap.add_argument("--resume", action="store_true",
                    help="skip the (cycles, draw) pairs already in <out>/lrde_draws.partial.csv")
    ap.add_argument("--truth-step", type=float, default=None, metavar="FRACTION",
                    help="add a fine truth channel of this step (fraction of the coarse step, "
                         "e.g. 0.01) and score the offset a and bias b intervals")
    ap.add_argument("--sigma-range", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                    help="jitter prior range in steps (default: the fit's open range)")
    args = ap.parse_args(argv)
    sampler = {"n_steps": args.n_steps, "n_burn": args.n_burn}
    if args.sigma_range is not None:
        sampler["sigma_range"] = tuple(args.sigma_range)
    root = np.random.SeedSequence(args.seed)
    tasks = []
    for cycles, ss in zip(args.cycles, root.spawn(len(args.cycles))):
        for d, child in enumerate(ss.spawn(args.draws)):
            tasks.append((cycles, d, child))
    # Interleaved by draw, so that a run stopped early has as many draws of every cycle count;
    # the draws done so far are rewritten to lrde_draws.partial.csv every 20 fits, and
    # --resume skips them (seeds are fixed per (cycles, draw), so the rows are the same).
    tasks.sort(key=lambda task: (task[1], task[0]))
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    partial = out / "lrde_draws.partial.csv"
    if args.resume and partial.exists():
        done = pd.read_csv(partial)
        rows = [{k: v for k, v in r.items() if not (isinstance(v, float) and np.isnan(v))}
                for r in done.to_dict("records")]
        finished = set(zip(done["cycles"], done["draw"]))
        tasks = [task for task in tasks if (task[0], task[1]) not in finished]
        print(f"resuming: {len(finished)} draws read from {partial}", flush=True)
    # Seeds are fixed per (cycles, draw) before any work starts, so the rows do not depend on
    # --jobs; wall times do (two fits on two cores contend for memory bandwidth).
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(_task, cycles, d, child, args, sampler): (cycles, d)
                   for cycles, d, child in tasks}
        for k, future in enumerate(concurrent.futures.as_completed(futures), start=1):
            rows += future.result()
            cycles, d = futures[future]
            print(f"[{k}/{len(tasks)}] cycles={cycles} draw={d + 1}/{args.draws}", flush=True)
            if k % 20 == 0:
                pd.DataFrame(rows).to_csv(partial, index=False)
    rows.sort(key=lambda r: (r["cycles"], r["draw"]))
    draws = pd.DataFrame(rows)
    summary = summarise(draws)
    draws.to_csv(out / "lrde_draws.csv", index=False)
    partial.unlink(missing_ok=True)
    summary.to_csv(out / "lrde_summary.csv", index=False)
    rmse_figure(summary).savefig(out / "lrde_rmse.png", dpi=120, metadata={"Software": None})
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(summary.to_string(index=False))


if __name__ == "__main__":
    main()
