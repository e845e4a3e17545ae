"""Does the LRDE effect comparison name the right effect, and do the intervals hold?

Each draw is a benchmark log of ``bench_lrde.py`` (step 0.09 deg, ``a ~ U(0, step)``,
``A12 ~ U(3, 5) step``, ``E_b`` in Proposition 1's band, f ~ 20 Hz x U(0.9, 1.1) at 2 kHz,
position noise 0.005 step, random phase) read through
:func:`enclab.lrde.effects.simulate_counts` with one effect of a random size:

=============  ================================================  ======================
case           size (log-uniform unless said)                    right name
=============  ================================================  ======================
clean          -                                                 sinusoid
hysteresis     dead band 1/50 .. 1/5 step                        hysteresis
drift          frequency change 0.5 .. 3 % over the log (+-)     drift
count_jump     one missed count at U(0.25, 0.75) of the log      count_jump
harmonic       3rd harmonic, amplitude 0.01 .. 0.1 step          harmonic3
noise          position noise U(0.005, 0.1) step                 sinusoid
=============  ================================================  ======================

Per draw the stage's own steps run: the effect comparison
(:func:`enclab.lrde.compare.compare_effect_models`), the sinusoid's emcee fit (``before``),
when the comparison chooses a model that model's emcee fit, and one of each model it cannot
tell from its pick (or, when it keeps the sinusoid, does not rule out), pooled with the pick's
with equal weights as the stage reports them (``after``), with the sampler
settings of ``config.yaml`` (``--n-walkers`` etc.). Recorded: the chosen model, whether it names
the right term, the predictive check, 90 % intervals of ``A12`` and ``E_b`` before and after
(``E_b`` relative to count 0 in the frame of the longer segment for a jump) and of the pick's
own fit (``pick``, the same as ``after`` unless pooled), convergence and wall time. ``A12``
is the peak-to-peak stroke (eq. 2) of the true and of the fitted motion; a 3rd harmonic
leaves the bias (the extremes' midpoint) where the mean is.

A draw's effect is *named* when the chosen model contains its term, and *identified* when it
is named or the comparison lists its term among the models not distinguishable from the pick
(the report then says "not distinguishable from ..."); a clean or noise log is identified only
when the sinusoid stays. A model not ruled out beside a kept sinusoid names nothing.

Summary per (cycles, case): ``n``; named and identified rates with Wilson 95 % intervals; the
detection threshold (the size at which a logistic fit of identified vs log size crosses 50 %)
and the named and identified rates among draws of at least 3x that size; coverage of the 90 %
intervals before and after; the rate of converged, trusted intervals that miss the truth by
more than their own width; the share of draws whose ``after`` is pooled; the median wall
time. A row ``case = all`` per cycle count pools
every case for the confident-miss rate.

Usage::

    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --draws 100 --clean-draws 200 \\
        --cycles 20 100
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --draws 10 --clean-draws 20 --cycles 20
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --cycles 20 --shard 1/2   # half of a run
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --redo some_draws.csv --out redone
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --from-draws all.csv redone/lrde_effects_draws.csv
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_effects --from-draws more/lrde_effects_draws.csv \\
        --pool-with docs/benchmarks/lrde_effects_summary.csv    # continue a run kept as a summary

Writes ``<out>/lrde_effects_draws.csv`` and ``<out>/lrde_effects_summary.csv``.
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd
from scipy.optimize import minimize


from enclab.core.allocator import keep_freed_memory
from enclab.lrde import compare, effects, fit, model, simulate

from .helpers import ROOT, log_uniform, stamp, wilson

STEP = simulate.ROS_DRILL_STEP
CASES = ("clean", "hysteresis", "drift", "count_jump", "harmonic", "noise")
RIGHT = {"clean": None, "hysteresis": "hysteresis", "drift": "drift",
         "count_jump": "count_jump", "harmonic": "harmonic3", "noise": None}


def simulate_case(rng, case, n_cycles, fs_hz=2000.0, f_nominal=20.0, noise_frac=0.005):
    """``(t, counts, truth)``: one benchmark log with the effect of ``case`` at a random size.

    ``truth`` holds ``A12`` (the simulator's: twice the fundamental's amplitude), ``stroke``
    (the motion's peak-to-peak stroke, eq. 2: ``A12`` unless harmonics distort the motion, and
    the estimand scored), ``E_b`` (count-0 frame of the reference segment), ``size`` (the
    effect's size in the unit of the table above: step fraction, relative drift, step) and
    the simulator arguments.
    """
    f_hz = f_nominal * rng.uniform(0.9, 1.1)
    rng.uniform(0, 1)  # an unused offset draw, kept so that a seed still gives the same log
    A12 = rng.uniform(3.0, 5.0) * STEP
    half_eps = 0.5 * float(model.epsilon(A12, STEP))
    E_b = rng.uniform(-half_eps, half_eps)
    a_eq = 0.5 * STEP + E_b
    phase = rng.uniform(-np.pi, np.pi)
    t = np.arange(int(np.floor((n_cycles + 1) * fs_hz / f_hz))) / fs_hz
    kw = {"noise_std": noise_frac * STEP}
    size = 0.0
    e_b_ref = E_b
    if case == "hysteresis":
        size = log_uniform(rng, 1 / 50, 1 / 5)
        kw["hysteresis"] = size * STEP
    elif case == "drift":
        size = log_uniform(rng, 0.005, 0.03)
        kw["drift"] = rng.choice([-1.0, 1.0]) * size / t[-1]
    elif case == "count_jump":
        index = int(rng.uniform(0.25, 0.75) * t.size)
        kw["jump"] = (index, -1)
        size = 1.0
        if index < t.size - index:  # the later segment is the longer one: its frame
            e_b_ref = E_b - STEP
    elif case == "harmonic":
        size = log_uniform(rng, 0.01, 0.1)
        ph3 = rng.uniform(-np.pi, np.pi)
        kw["harmonics"] = {3: (size * STEP * np.cos(ph3), size * STEP * np.sin(ph3))}
    elif case == "noise":
        size = rng.uniform(0.005, 0.1)
        kw["noise_std"] = size * STEP
    counts = effects.simulate_counts(rng, t, STEP, A12, a_eq, f_hz, phase, **kw)
    stroke = A12
    if "harmonics" in kw:
        orders = tuple(kw["harmonics"])
        stroke = float(model.stroke_and_midpoint(
            A12, orders, [[kw["harmonics"][k][0] for k in orders]],
            [[kw["harmonics"][k][1] for k in orders]])[0][0])
    return t, counts, {"A12": A12, "stroke": stroke, "E_b": e_b_ref, "size": size, "f_hz": f_hz,
                       "phase": phase, "a_eq": a_eq, "simulator": kw}


def interval(result, name):
    """The 90 % interval of ``name`` in a fit ``result``; ``E_b`` from ``a_eq``'s."""
    if name == "E_b":
        q = result.summary["a_eq"]
        return q["q05"] - 0.5 * STEP, q["q95"] - 0.5 * STEP
    q = result.summary[name]
    return q["q05"], q["q95"]


def one_draw(case, n_cycles, seed, sampler):
    rng = np.random.default_rng(seed)
    t, counts, truth = simulate_case(rng, case, n_cycles)
    root = np.random.SeedSequence(seed)
    fit_seed, compare_seed, after_seed, alternatives_seed = root.spawn(4)
    started = time.perf_counter()
    row = {"case": case, "cycles": n_cycles, "seed": seed, "size": truth["size"],
           "A12_true": truth["stroke"], "E_b_true": truth["E_b"]}
    try:
        comp = compare.compare_effect_models(t, counts, STEP, compare_seed)
    except ValueError as err:
        row["failed"] = str(err)
        return row
    # As the stage: the sinusoid's ensembles start at its point fit.
    before = fit.fit_sinusoid(t, counts, STEP, fit_seed, start=comp["full_fits"]["sinusoid"]["x"],
                              **sampler)
    after = pick = before
    if comp["chosen"] != "sinusoid":
        point = comp["full_fits"][comp["chosen"]]
        after = pick = fit.fit_sinusoid(t, counts, STEP, after_seed,
                                        harmonics=tuple(comp["chosen_harmonics"]),
                                        effects=tuple(comp["chosen_effects"]), start=point["x"],
                                        **sampler)
    # As the stage: the models not distinguishable from the pick (or not ruled out beside a
    # kept sinusoid) are fitted and pooled with it.
    alt_terms = compare.alternative_terms(comp)
    alt_fits = [fit.fit_sinusoid(t, counts, STEP, seed_alt, harmonics=harmonics,
                                 effects=effects, start=point["x"], **sampler)
                for (_, harmonics, effects, point), seed_alt
                in zip(alt_terms, alternatives_seed.spawn(len(alt_terms)))]
    if alt_fits:
        after = fit.pool_fits([pick] + alt_fits)
    row["wall_s"] = time.perf_counter() - started
    right = RIGHT[case]
    terms = comp["chosen"].split("+")
    alternatives = [term for label in comp["indistinguishable"] for term in label.split("+")]
    named = (comp["chosen"] == "sinusoid") if right is None else (right in terms)
    row |= {"chosen": comp["chosen"], "indistinguishable": "|".join(comp["indistinguishable"]),
            "not_ruled_out": "|".join(comp["not_ruled_out"]),
            "named": named,
            # The requirement's "identified": named, or named by the report as not
            # distinguishable from the pick (a clean log has no such allowance).
            "identified": named or (right is not None and right in alternatives),
            "check_z": comp["check"]["z"], "trusted": comp["check"]["trusted"],
            "before_converged": before.converged, "after_converged": after.converged}
    row["pooled"] = after is not pick
    for label, r in (("before", before), ("after", after), ("pick", pick)):
        for name in ("A12", "E_b"):
            lo, hi = interval(r, name)
            true = row[f"{name}_true"]
            row[f"{name}_{label}_q05"], row[f"{name}_{label}_q95"] = lo, hi
            row[f"{name}_{label}_cover"] = bool(lo <= true <= hi)
            miss = max(lo - true, true - hi, 0.0)
            row[f"{name}_{label}_confident_miss"] = bool(
                r.converged and row["trusted"] and miss > (hi - lo))
    return row


def draw_seed(base, case, cycles, i) -> int:
    """Seed of draw ``i`` of ``case`` at ``cycles`` cycles. A case's seeds do not depend on
    which other cases run beside it, so scripts that rerun these logs get the same ones."""
    return base + 100_000 * CASES.index(case) + 1000 * cycles + i


def read_draws(paths) -> pd.DataFrame:
    """Draws CSVs concatenated; a draw listed again (same cycles, case and seed) takes the
    later file's row."""
    draws = pd.concat([pd.read_csv(p) for p in paths], ignore_index=True)
    return draws.drop_duplicates(["cycles", "case", "seed"], keep="last")


def parse_shard(ap, text) -> tuple[int, int]:
    """``K/N`` of ``--shard`` (an argparse error unless 0 <= K < N)."""
    k, n = (int(x) for x in text.split("/"))
    if not 0 <= k < n:
        ap.error(f"--shard {text}: K must be in 0..N-1")
    return k, n


def add_rerun_arguments(ap, cases) -> None:
    """The options of a script that reruns this benchmark's logs of one cycle count (same
    logs and seeds for the same case, cycle count and draw index)."""
    ap.add_argument("--cases", nargs="+", default=list(cases), choices=CASES)
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--draws", type=int, default=100, help="index of the draw to stop at")
    ap.add_argument("--first-draw", type=int, default=0)
    ap.add_argument("--seed", type=int, default=20261202,
                    help="base seed of bench_lrde_effects.py (same logs for the same draw)")
    ap.add_argument("--shard", default="0/1", metavar="K/N")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--from-draws", nargs="+", default=None, metavar="CSV",
                    help="summarise these draws instead of running any")


def rerun_draws(ap, args, one, path, show) -> pd.DataFrame:
    """Run ``one(case, seed)`` on the draws that :func:`add_rerun_arguments` select, or read
    ``--from-draws``; the rows so far are written to ``path`` after every draw and the keys
    ``show`` of each printed."""
    if args.from_draws:
        draws = read_draws(args.from_draws)
    else:
        k, n = parse_shard(ap, args.shard)
        rows = []
        for case in args.cases:
            for i in range(args.first_draw, args.draws):
                if i % n == k:
                    rows.append(one(case, draw_seed(args.seed, case, args.cycles, i)))
                    print({key: rows[-1][key] for key in show}, flush=True)
                    stamp(pd.DataFrame(rows)).to_csv(path, index=False)
        draws = stamp(pd.DataFrame(rows))
    draws.to_csv(path, index=False)
    return draws


def threshold(size, named):
    """Size at which a logistic fit of named vs log10(size) crosses 50 % (NaN if none)."""
    x, y = np.log10(np.asarray(size, dtype=float)), np.asarray(named, dtype=float)
    if y.all() or not y.any() or np.ptp(x) == 0:
        return np.nan

    def nll(p):
        eta = p[0] + p[1] * (x - x.mean())
        return np.sum(np.logaddexp(0, eta) - y * eta)

    p = minimize(nll, [0.0, 1.0], method="Nelder-Mead").x
    if p[1] <= 0:
        return np.nan
    return float(10 ** (x.mean() - p[0] / p[1]))


def summarise(draws: pd.DataFrame, thresholds: dict | None = None) -> pd.DataFrame:
    """Summary rows per (cycles, case); ``thresholds`` maps (cycles, case) to a detection
    threshold to count against instead of the one these draws' logistic fit gives."""
    thresholds = thresholds or {}
    rows = []
    for (cycles, case), g in draws.groupby(["cycles", "case"]):
        g = g[g["chosen"].notna()]
        if "identified" not in g:
            g = g.assign(identified=g["named"])
        n = len(g)
        k = int(g["named"].sum())
        lo, hi = wilson(k, n)
        k_id = int(g["identified"].sum())
        id_lo, id_hi = wilson(k_id, n)
        row = {"cycles": cycles, "case": case, "n": n, "named_rate": k / n if n else np.nan,
               "named_ci_lo": lo, "named_ci_hi": hi,
               "identified_rate": k_id / n if n else np.nan,
               "identified_ci_lo": id_lo, "identified_ci_hi": id_hi}
        if case in ("hysteresis", "drift", "harmonic"):
            th = thresholds.get((cycles, case), threshold(g["size"], g["identified"]))
            row["threshold"] = th
            big = g[g["size"] >= 3 * th] if np.isfinite(th) else g.iloc[0:0]
            row["n_at_3x"] = len(big)
            row["named_at_3x"] = big["named"].mean() if len(big) else np.nan
            row["identified_at_3x"] = big["identified"].mean() if len(big) else np.nan
        for label in ("before", "after"):
            for name in ("A12", "E_b"):
                row[f"{name}_cover_{label}"] = g[f"{name}_{label}_cover"].mean()
        row["confident_miss_rate"] = (g["A12_after_confident_miss"]
                                      | g["E_b_after_confident_miss"]).mean()
        row["untrusted_rate"] = (~g["trusted"].astype(bool)).mean()
        # Runs before the pooled report have no such column: their "after" is the pick's.
        row["pooled_rate"] = (g["pooled"].astype(bool).mean() if "pooled" in g
                              and g["pooled"].notna().all() else np.nan)
        row["converged_after"] = g["after_converged"].mean()
        row["median_wall_s"] = g["wall_s"].median()
        row["confused_with"] = "|".join(sorted(set(g.loc[~g["named"].astype(bool),
                                                         "chosen"])))
        rows.append(row)
    for cycles, g in draws[draws["chosen"].notna()].groupby("cycles"):
        # The confident-miss requirement is a rate over all logs, every case pooled.
        rows.append({"cycles": cycles, "case": "all", "n": len(g),
                     "confident_miss_rate": (g["A12_after_confident_miss"]
                                             | g["E_b_after_confident_miss"]).mean(),
                     "untrusted_rate": (~g["trusted"].astype(bool)).mean(),
                     "median_wall_s": g["wall_s"].median()})
    return pd.DataFrame(rows)


RATES = ("named_rate", "identified_rate", "A12_cover_before", "E_b_cover_before",
         "A12_cover_after", "E_b_cover_after", "confident_miss_rate", "untrusted_rate",
         "pooled_rate", "converged_after")


def _count(rate, n):
    """The count behind a rate of ``n`` draws (a table keeps 4 significant digits)."""
    return float(np.rint(rate * n)) if n else 0.0


def pool_summaries(earlier: pd.DataFrame, draws: pd.DataFrame) -> pd.DataFrame:
    """Summary rows of ``draws`` pooled with an ``earlier`` summary of *other* draws.

    For a run continued whose earlier per-draw rows are gone but whose summary is kept: per
    (cycles, case) in both, every rate becomes a count (rate x n), counts add and the Wilson
    intervals come from the sums. The detection threshold is the earlier row's, and ``draws``
    are counted at 3x of it. A median does not pool, so ``median_wall_s`` is left empty (the
    two runs' rows keep theirs). Draws must not repeat: their seeds are the caller's to keep
    apart (``--first-draw``)."""
    earlier = earlier.drop(columns=[c for c in ("date", "machine", "command") if c in earlier])
    keys = {(int(r.cycles), r.case): r for r in earlier.itertuples(index=False)}
    later = summarise(draws, {k: r.threshold for k, r in keys.items()
                              if np.isfinite(getattr(r, "threshold", np.nan))})
    rows = []
    for new in later.to_dict("records"):
        key = (int(new["cycles"]), new["case"])
        if key not in keys:
            continue
        old = keys[key]._asdict()
        n = int(old["n"] + new["n"])
        row = {"cycles": key[0], "case": key[1], "n": n}
        for name in RATES:
            a, b = old.get(name, np.nan), new.get(name, np.nan)
            row[name] = ((_count(a, old["n"]) + _count(b, new["n"])) / n
                         if np.isfinite(a) and np.isfinite(b) else np.nan)
        for name, lo, hi in (("named_rate", "named_ci_lo", "named_ci_hi"),
                             ("identified_rate", "identified_ci_lo", "identified_ci_hi")):
            if key[1] != "all":
                row[lo], row[hi] = wilson(int(round(row[name] * n)), n)
        if np.isfinite(old.get("threshold", np.nan)):
            row["threshold"] = old["threshold"]
            n3 = int(old["n_at_3x"] + new["n_at_3x"])
            row["n_at_3x"] = n3
            for name in ("named_at_3x", "identified_at_3x"):
                k3 = sum(_count(r[name], int(r["n_at_3x"])) for r in (old, new)
                         if r["n_at_3x"] > 0)
                row[name] = k3 / n3 if n3 else np.nan
        if key[1] != "all":
            confused = {c for r in (old, new) if isinstance(r.get("confused_with"), str)
                        for c in r["confused_with"].split("|") if c}
            row["confused_with"] = "|".join(sorted(confused))
        row["median_wall_s"] = np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=100,
                    help="draws per effect and cycle count (with --first-draw: the index to stop at)")
    ap.add_argument("--clean-draws", type=int, default=200)
    ap.add_argument("--cycles", type=int, nargs="+", default=[20, 100])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--seed", type=int, default=20261202)
    ap.add_argument("--n-ensembles", type=int, default=4)
    ap.add_argument("--n-walkers", type=int, default=16)
    ap.add_argument("--n-steps", type=int, default=250)
    ap.add_argument("--n-burn", type=int, default=100)
    ap.add_argument("--max-steps", type=int, default=1000,
                    help="as the stage: unconverged chains go on in blocks of --n-steps up "
                         "to this")
    ap.add_argument("--time-budget", type=float, default=None,
                    help="stop drawing after this many seconds (rows so far are kept)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--from-draws", default=None, metavar="CSV", nargs="+",
                    help="only summarise existing lrde_effects_draws.csv files (concatenated; "
                         "a draw listed again, same cycles, case and seed, takes the later "
                         "file's row)")
    ap.add_argument("--pool-with", default=None, metavar="SUMMARY_CSV",
                    help="with --from-draws: also pool those draws with this earlier summary "
                         "of other draws (pool_summaries); the output keeps the earlier rows, "
                         "the new draws' rows and the pooled rows")
    ap.add_argument("--redo", default=None, metavar="CSV",
                    help="run again the draws (cycles, case, seed) of this draws CSV, e.g. "
                         "the ones a change can affect; merge with --from-draws")
    ap.add_argument("--first-draw", type=int, default=0,
                    help="index of the first draw per case (continue an earlier run)")
    ap.add_argument("--shard", default="0/1", metavar="K/N",
                    help="run only the draws whose index is K modulo N: N processes with "
                         "K = 0..N-1 share one run; merge their CSVs with --from-draws")
    args = ap.parse_args(argv)
    keep_freed_memory()  # as the stage's job process does (enclab.runner.run)
    if args.from_draws:
        out = pathlib.Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        draws = read_draws(args.from_draws)
        draws.to_csv(out / "lrde_effects_draws.csv", index=False)
        summary = stamp(summarise(draws))
        if args.pool_with:
            earlier = pd.read_csv(args.pool_with)
            pooled = stamp(pool_summaries(earlier, draws))
            # Its own provenance, so that the page tells the pooled rows from this run's.
            pooled["command"] += f"  # pooled: {args.pool_with} + these draws"
            summary = pd.concat([earlier, summary, pooled], ignore_index=True)
        summary.to_csv(out / "lrde_effects_summary.csv", index=False)
        with pd.option_context("display.width", 250, "display.max_columns", 40):
            print(summary)
        return
    sampler = {"n_ensembles": args.n_ensembles, "n_walkers": args.n_walkers,
               "n_steps": args.n_steps, "n_burn": args.n_burn, "max_steps": args.max_steps}
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    k, n = parse_shard(ap, args.shard)
    # Interleave cases so that a time budget cuts every case to about the same size.
    tasks = []
    if args.redo:
        redo = pd.read_csv(args.redo)
        tasks = [(r.case, int(r.cycles), int(r.seed)) for r in redo.itertuples()
                 if int(r.Index) % n == k]
    for cycles in ([] if args.redo else args.cycles):
        n_max = max(args.draws, args.clean_draws)
        for i in range(args.first_draw, n_max):
            for case in args.cases:
                n_case = args.clean_draws if case == "clean" else args.draws
                if i < n_case and i % n == k:
                    tasks.append((case, cycles, draw_seed(args.seed, case, cycles, i)))
    if not tasks:
        ap.error(f"no draws to run: --first-draw {args.first_draw} is the index of the first draw, "
                 f"--draws {args.draws} and --clean-draws {args.clean_draws} the index to stop at")
    started = time.perf_counter()
    rows = []
    for case, cycles, seed in tasks:
        if args.time_budget is not None and time.perf_counter() - started > args.time_budget:
            break
        rows.append(one_draw(case, cycles, seed, sampler))
        print({k: rows[-1].get(k) for k in ("case", "cycles", "size", "chosen", "named",
                                            "trusted", "A12_after_cover", "E_b_after_cover",
                                            "wall_s")}, flush=True)
        draws = stamp(pd.DataFrame(rows))
        draws.to_csv(out / "lrde_effects_draws.csv", index=False)
    draws = stamp(pd.DataFrame(rows))
    draws.to_csv(out / "lrde_effects_draws.csv", index=False)
    summary = stamp(summarise(draws))
    summary.to_csv(out / "lrde_effects_summary.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(summary)


if __name__ == "__main__":
    main()
