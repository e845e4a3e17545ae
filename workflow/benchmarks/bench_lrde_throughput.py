"""What does the LRDE fit's MCMC cost per likelihood call, per fit and per effective sample?

MCMC throughput of the LRDE fit: likelihood cost per call, wall time, ESS and ESS per second.

Runs the same simulated 20-cycle logs (the setting of ``bench_lrde.py``: step 0.09 deg,
A12 ~ U(3, 5) step, E_b inside Proposition 1's band, f ~ U(0.9, 1.1) x 20 Hz at 2 kHz,
0.005-step jitter) through one or more implementations of :mod:`enclab.lrde.fit`, each in
its own subprocess so that two versions of the package can be compared in one run:

- ``--impl NAME=PATH[:SETTINGS]``: ``PATH`` is a ``workflow`` directory holding an ``enclab``
  package (e.g. a ``git worktree`` of an older commit), ``SETTINGS`` a JSON object of
  :func:`fit_sinusoid` keyword arguments (default: the package's own defaults with the
  sampler lengths of ``config.yaml``).

Per implementation it reports the median over draws of the wall time of one fit, the minimum
ESS over parameters, ESS per second, the largest split R-hat, and the median time of one
vectorised log-likelihood call (16 walkers near the posterior, median of 300 calls).

Usage::

    git worktree add --detach ../enclab-before <commit>
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_throughput --draws 10 \\
        --impl 'before=../enclab-before/workflow:{"n_steps": 400, "n_burn": 400}' \\
        --impl 'after=workflow:{"n_steps": 250, "n_burn": 250}'

Writes ``<out>/lrde_throughput.csv`` (one row per implementation and draw) and
``<out>/lrde_throughput_summary.csv``, and prints the summary.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import textwrap

import pandas as pd

from .helpers import write_performance_section

_WORKER = textwrap.dedent('''
    import json, sys, time
    import numpy as np
    from enclab.lrde import fit, model, simulate  # the implementation on PYTHONPATH
    settings = json.loads(sys.argv[1]); seed = int(sys.argv[2]); draws = int(sys.argv[3])
    cycles = int(sys.argv[4])
    STEP = simulate.ROS_DRILL_STEP
    rows = []
    for d, child in enumerate(np.random.SeedSequence(seed).spawn(draws)):
        sim, fit_seed = child.spawn(2)
        rng = np.random.default_rng(sim)
        f_hz = 20.0 * rng.uniform(0.9, 1.1)
        a_frac = rng.uniform()
        A12 = rng.uniform(3.0, 5.0) * STEP
        E_b = rng.uniform(-0.5, 0.5) * float(model.epsilon(A12, STEP))
        df, p = simulate.open_loop_log(rng, A12=A12, bias=E_b + 0.5 * STEP - a_frac * STEP,
                                       f_hz=f_hz, fs_hz=2000.0, n_cycles=cycles + 1,
                                       offset_frac=a_frac, noise_std=0.005 * STEP)
        t, c = df["t"].to_numpy(), df["counts"].to_numpy()
        started = time.perf_counter()
        r = fit.fit_sinusoid(t, c, STEP, seed=fit_seed, **settings)
        wall = time.perf_counter() - started
        # One likelihood call: 16 walkers at the posterior's last positions, converted by hand
        # (older versions of enclab.lrde.fit have no _to_internal).
        last = r.chains[0, -1, :16].copy()
        internal = np.column_stack([last[:, 0] / STEP, last[:, 1] / STEP, last[:, 2],
                                    last[:, 3], np.log10(last[:, 4] / STEP)])
        kw = dict(t=t, counts=c, step=STEP, centre_count=r.centre_count, t_ref=r.t_ref)
        if hasattr(fit, "uniform_grid"):
            kw["grid"] = fit.uniform_grid(t)
        calls = []
        for _ in range(300):
            t0 = time.perf_counter()
            fit.log_likelihood(internal, **kw)
            calls.append(time.perf_counter() - t0)
        ess_min = min(r.ess.values())
        rows.append({"draw": d, "n_samples": t.size, "wall_s": wall, "ess_min": ess_min,
                     "ess_per_s": ess_min / wall, "rhat_max": max(r.rhat.values()),
                     "tau_max": max(r.tau.values()), "converged": bool(r.converged),
                     "likelihood_call_ms": 1e3 * float(np.median(calls))})
    print(json.dumps(rows))
''')


def run_impl(name, path, settings, seed, draws, cycles):
    # PYTHONPATH comes before the installed package: the child imports the enclab of ``path``.
    out = subprocess.run([sys.executable, "-c", _WORKER, json.dumps(settings),
                          str(seed), str(draws), str(cycles)],
                         check=True, capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(path)))
    rows = json.loads(out.stdout.strip().splitlines()[-1])
    return [r | {"impl": name, "settings": json.dumps(settings, sort_keys=True)} for r in rows]


def parse_impl(text):
    name, _, rest = text.partition("=")
    path, _, settings = rest.partition(":")
    if not name or not path:
        raise SystemExit(f"--impl must be NAME=PATH[:SETTINGS], got {text!r}")
    return name, pathlib.Path(path).resolve(), json.loads(settings) if settings else {}


def write_performance_rows(summary, table, args, path):
    """The ``mcmc`` section of the project's performance table (bench_performance.py)."""
    load = os.getloadavg()[0]
    rows = []
    for _, s in summary.iterrows():
        mine = table[table["impl"] == s["impl"]]
        n = int(mine["n_samples"].median())
        met = s["wall_median_s"] <= 3.0 and s["ess_min_min"] >= 1000
        rows.append({
            "section": "mcmc", "case": f"{args.cycles}-cycle LRDE fit, impl {s['impl']}",
            "stage": "fit_sinusoid", "n_samples": n, "n_joints": 1, "reps": int(s["fits"]),
            "median_s": round(float(s["wall_median_s"]), 3),
            "samples_per_s": round(n / float(s["wall_median_s"])), "ratio_to_read": None,
            "peak_rss_mb": None, "target": "median <= 3 s, min ESS >= 1000",
            "met": "yes" if met else "no",
            "notes": (f"min ESS median {s['ess_min_median']:.0f} (lowest {s['ess_min_min']:.0f}), "
                      f"ESS/s {s['ess_per_s_median']:.0f}, R-hat max {s['rhat_max']:.4f}, "
                      f"likelihood call {s['likelihood_call_ms_median']:.3f} ms; "
                      f"settings {mine['settings'].iloc[0]}; load avg {load:.1f}")})
    write_performance_section(rows, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--impl", action="append", type=parse_impl,
                    help="NAME=PATH[:SETTINGS] (repeatable; default: this checkout)")
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=1,
                    help="alternate the implementations this many times (noisy machines)")
    ap.add_argument("--out", default="results/benchmarks")
    args = ap.parse_args(argv)
    impls = args.impl or [("current", pathlib.Path("workflow").resolve(),
                           {"n_steps": 250, "n_burn": 250})]
    rows = []
    for round_ in range(args.rounds):
        for name, path, settings in impls:
            print(f"round {round_ + 1}/{args.rounds}: {name} ({path}) {settings}", flush=True)
            rows += [r | {"round": round_} for r in
                     run_impl(name, path, settings, args.seed, args.draws, args.cycles)]
    table = pd.DataFrame(rows)
    summary = table.groupby("impl", sort=False).agg(
        fits=("wall_s", "size"), wall_median_s=("wall_s", "median"),
        ess_min_median=("ess_min", "median"), ess_min_min=("ess_min", "min"),
        ess_per_s_median=("ess_per_s", "median"), rhat_max=("rhat_max", "max"),
        converged_fraction=("converged", "mean"),
        likelihood_call_ms_median=("likelihood_call_ms", "median")).reset_index()
    if len(summary) > 1:
        first = summary.iloc[0]
        summary["wall_ratio_to_first"] = summary["wall_median_s"] / first["wall_median_s"]
        summary["ess_per_s_ratio_to_first"] = (summary["ess_per_s_median"]
                                               / first["ess_per_s_median"])
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "lrde_throughput.csv", index=False)
    summary.to_csv(out / "lrde_throughput_summary.csv", index=False)
    write_performance_rows(summary, table, args, out / "performance.csv")
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(summary.to_string(index=False))


if __name__ == "__main__":
    main()
