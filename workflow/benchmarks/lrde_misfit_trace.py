"""Are effects outside the LRDE catalogue flagged and placed, rather than misnamed?

The effect comparison (:func:`enclab.lrde.compare.compare_effect_models`) can only name the
terms it knows. An effect it does not know is absorbed by the nearest candidates (a misplaced
edge by a dead band plus a 3rd harmonic, say) and, if nothing else looks, reported under a
wrong name. The localized check (:func:`enclab.lrde.compare.misfit_trace`) asks where the
chosen fit explains the readings worse than it expects itself to; this script measures it:

* on the catalogued cases of ``bench_lrde_effects.py`` (same simulator and sizes): how often a
  log is flagged although its own effect is in the catalogue (split by whether the comparison
  named it: a missed effect flagged is a correct flag);
* on effects outside the catalogue, each at a random size: how often the log is flagged, how
  often it is neither flagged nor kept as a plain sinusoid (a wrong name reported as if
  sound), and which covariate the trace names.

=================  ==============================================  ==========================
case               size (log-uniform unless said)                  where it acts
=================  ==============================================  ==========================
edge_error         one visited edge off its pitch, 0.05..0.4 step  one count (edges, dwells)
harmonic5          5th harmonic, 0.03..0.2 step                    position of the motion,
                                                                   every cycle alike
amplitude_drift    stroke changes 5..25 % over the log (+-)        time in the log
bias_drift         bias moves 0.1..0.5 step over the log (+-)      time in the log
two_jumps          missed counts at U(0.2, 0.45) and U(0.55, 0.8)  time in the log
=================  ==============================================  ==========================

"Where it acts" is scored by the covariate the trace names (``ACTS_ON``); successive dwells
ending early or late together count for the drifts and the harmonic.

Per draw only the comparison's point fits run (no emcee): the flag does not depend on the
sampler. Summary per (cycles, case): ``n``, the share of logs whose global predictive check
fails, the share the localized check flags at the stage's threshold (and at -4 and -6, to see
the margin), the share misnamed and unflagged, and the covariate the trace names most often.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_misfit_trace --draws 12 --cycles 20
    PYTHONPATH=workflow python -m benchmarks.lrde_misfit_trace --draws 4 --cycles 20 --cases edge_error clean

Writes ``<out>/lrde_misfit_trace_draws.csv`` and ``<out>/lrde_misfit_trace.csv``. With
``--from-draws CSV`` it summarises an earlier run's draws instead (stamped with that run's
provenance); ``--keep SUMMARY_CSV`` keeps an earlier summary's rows above the new ones.
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd


from enclab.lrde import compare

from . import bench_lrde_effects as effects_bench
from .helpers import ROOT, log_uniform, stamp

STEP = effects_bench.STEP
OUTSIDE = ("edge_error", "harmonic5", "amplitude_drift", "bias_drift", "two_jumps")
CASES = effects_bench.CASES + OUTSIDE
# The trace's covariates that place each effect where it acts. Successive dwells alike say
# "a change slower than a cycle, or a shape repeated every cycle": right for the drifts and
# the harmonic, not for one misplaced edge or two missed counts (which other rows place).
_COUNT = ("count before the sample", "dwell length per count")
_SLOW = ("time in the log", "dwell timing from cycle to cycle")
DWELL_ROWS = ("dwell length per count", "dwell timing from cycle to cycle")
ACTS_ON = {"edge_error": _COUNT,
           "harmonic5": ("position and direction of the motion",
                         "dwell timing from cycle to cycle") + _COUNT,
           "amplitude_drift": _SLOW, "bias_drift": _SLOW, "two_jumps": ("time in the log",)}


def simulate_outside(rng, case, n_cycles, fs_hz=2000.0, f_nominal=20.0, noise_frac=0.005):
    """``(t, counts, size)``: a benchmark log (as ``bench_lrde_effects.simulate_case``) with one
    effect the comparison has no term for."""
    f_hz = f_nominal * rng.uniform(0.9, 1.1)
    A12 = rng.uniform(3.0, 5.0) * STEP
    a_eq = rng.uniform(0.0, 1.0) * STEP
    phase = rng.uniform(-np.pi, np.pi)
    t = np.arange(int(np.floor((n_cycles + 1) * fs_hz / f_hz))) / fs_hz
    u = t / t[-1]
    phi = 2.0 * np.pi * f_hz * t + phase
    gain, bias, harmonic, size = 0.0, 0.0, 0.0, 0.0
    sign = rng.choice([-1.0, 1.0])
    if case == "harmonic5":
        size = log_uniform(rng, 0.03, 0.2)
        harmonic = size * STEP * np.sin(5 * phi + rng.uniform(-np.pi, np.pi))
    elif case == "amplitude_drift":
        size = log_uniform(rng, 0.05, 0.25)
        gain = sign * size
    elif case == "bias_drift":
        size = log_uniform(rng, 0.1, 0.5)
        bias = sign * size * STEP
    theta = 0.5 * A12 * (1.0 + gain * (u - 0.5)) * np.sin(phi) + harmonic + a_eq + bias * u
    x = theta / STEP + rng.normal(0.0, noise_frac, t.size)
    counts = np.floor(x).astype(np.int64)
    if case == "edge_error":
        size = log_uniform(rng, 0.05, 0.4)
        edges = np.arange(int(np.floor(x.min())) + 1, int(np.floor(x.max())) + 1)
        edge = int(rng.choice(edges))
        shift = sign * size
        # The edge below count `edge` sits at edge + shift instead of at edge.
        lo, hi = sorted((edge, edge + shift))
        moved = (x >= lo) & (x < hi)
        counts[moved] = edge - 1 if shift > 0 else edge
    elif case == "two_jumps":
        size = 2.0
        for where in (rng.uniform(0.2, 0.45), rng.uniform(0.55, 0.8)):
            counts[int(where * t.size):] -= 1
    return t, counts, size


def one_draw(case, n_cycles, seed, local_z):
    rng = np.random.default_rng(seed)
    if case in OUTSIDE:
        t, counts, size = simulate_outside(rng, case, n_cycles)
    else:
        t, counts, truth = effects_bench.simulate_case(rng, case, n_cycles)
        size = truth["size"]
    started = time.perf_counter()
    comp = compare.compare_effect_models(t, counts, STEP, seed, local_z=local_z)
    trace = comp["check"]["trace"]
    right = effects_bench.RIGHT.get(case)
    named = (None if case in OUTSIDE else
             comp["chosen"] == "sinusoid" if right is None else right in comp["chosen"].split("+"))
    return {"case": case, "cycles": n_cycles, "seed": seed, "size": size,
            "outside": case in OUTSIDE, "chosen": comp["chosen"], "named": named,
            "check_z": comp["check"]["z"], "trusted": comp["check"]["trusted"],
            "trace_z": trace.get("z"), "trace_z_all": trace.get("z_all"),
            "covariate": trace.get("covariate"), "where": trace.get("where"),
            "wall_s": time.perf_counter() - started}


def summarise(draws: pd.DataFrame, local_z: float) -> pd.DataFrame:
    rows = []
    for (cycles, case), g in draws.groupby(["cycles", "case"], sort=False):
        global_fail = g["check_z"] < compare.DEFAULT_TRUST_Z
        flagged = ~g["trusted"].astype(bool)
        row = {"cycles": cycles, "case": case, "n": len(g),
               "global_check_failed": global_fail.mean(),
               "flagged": flagged.mean(),
               "flagged_at_-4": ((g["trace_z"] < -4) | global_fail).mean(),
               "flagged_at_-6": ((g["trace_z"] < -6) | global_fail).mean(),
               "local_z_threshold": local_z,
               "median_trace_z": g["trace_z"].median(),
               "median_wall_s": g["wall_s"].median()}
        if g["outside"].iloc[0]:
            row["misnamed_unflagged"] = ((g["chosen"] != "sinusoid") & ~flagged).mean()
            row["chosen_when_unflagged"] = "|".join(sorted(set(g.loc[~flagged, "chosen"])))
            placed = g.loc[flagged, "covariate"]
            row["trace_names_where_it_acts"] = (placed.isin(ACTS_ON[case]).mean()
                                                if len(placed) else np.nan)
        else:
            named = g["named"].astype(bool)
            row["flagged_when_named"] = flagged[named].mean() if named.any() else np.nan
            row["flagged_when_missed"] = flagged[~named].mean() if (~named).any() else np.nan
        row["trace_covariate_mode"] = (g.loc[flagged, "covariate"].mode().iloc[0]
                                       if flagged.any() else "")
        row["flagged_headed_by_dwells"] = (flagged & g["covariate"].isin(DWELL_ROWS)).mean()
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--cycles", type=int, nargs="+", default=[20])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--seed", type=int, default=20261203)
    ap.add_argument("--local-z", type=float, default=compare.DEFAULT_LOCAL_Z)
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--from-draws", default=None, metavar="CSV",
                    help="summarise an earlier run's per-draw table instead of drawing")
    ap.add_argument("--keep", default=None, metavar="SUMMARY_CSV",
                    help="an earlier summary whose rows are kept above the new ones")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.from_draws:
        draws = pd.read_csv(args.from_draws)
        # The summary is of that run: its date, machine and command.
        first = draws.iloc[0]
        summary = summarise(draws, args.local_z).assign(
            **{k: first[k] for k in ("date", "machine", "command") if k in draws})
        _write_summary(stamp(summary), args.keep, out)
        return
    rows = []
    for cycles in args.cycles:
        for i in range(args.draws):
            for case in args.cases:
                seed = args.seed + 100_000 * CASES.index(case) + 1000 * cycles + i
                rows.append(one_draw(case, cycles, seed, args.local_z))
                r = rows[-1]
                print(f"{case:16s} {cycles:4d} size {r['size']:.3g}: {r['chosen']:24s} "
                      f"check {r['check_z']:6.1f} trace {r['trace_z']:6.1f} {r['where']}",
                      flush=True)
                stamp(pd.DataFrame(rows)).to_csv(out / "lrde_misfit_trace_draws.csv",
                                                 index=False)
    _write_summary(stamp(summarise(pd.DataFrame(rows), args.local_z)), args.keep, out)


def _write_summary(summary, keep, out):
    if keep:
        summary = pd.concat([pd.read_csv(keep), summary], ignore_index=True)
    summary.to_csv(out / "lrde_misfit_trace.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(summary)


if __name__ == "__main__":
    main()
