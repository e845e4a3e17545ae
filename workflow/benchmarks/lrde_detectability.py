"""Which benchmark logs carry evidence of their effect at all?

The oracle's model comparison.

For every draw of ``bench_lrde_effects.py`` with a sized effect (``hysteresis``, ``drift``,
``harmonic``), the log is simulated again from its seed and the score the comparison uses (the
full-log likelihood with the held-out score's time blur, :func:`enclab.lrde.compare.blurred_log_likelihood`)
is taken at the **true parameters** of the right model and at the sinusoid's point fit. The
oracle's BIC gain ``2 (log L_truth - log L_sine) - n_extra ln N`` is what a comparison that
knew the answer would see: where it is negative, the readings favour the sinusoid even over the
truth, and no method that scores these readings can name the effect (a dead band on a nearly
symmetric pattern acts as a phase lag the sinusoid absorbs). The truth is not a fit, so the gain
errs low by what fitting would add; beside it, the right model's point fit started at the
truth's sinusoid terms (``refit_gain``).

Per case, among draws of at least 3x the detection threshold of the benchmark's summary: the
named rate overall and among the draws whose oracle gain is positive (the logs that hold the
evidence); over all draws, the coverage of the 90 % intervals of ``A12`` and ``E_b`` (after)
among the draws with and without that evidence.

Usage (from the repository root)::

    PYTHONPATH=workflow python -m benchmarks.lrde_detectability \\
        --draws results/benchmarks/lrde_effects_draws.csv --cycles 20
    # after a change that leaves the likelihood alone: keep the gains already computed
    PYTHONPATH=workflow python -m benchmarks.lrde_detectability --cycles 20 \\
        --reuse results/benchmarks/lrde_detectability_draws.csv --out results/benchmarks

Writes ``<out>/lrde_detectability_draws.csv`` and ``<out>/lrde_detectability.csv``.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
import pandas as pd


from enclab.core import atomic
from enclab.lrde import compare, fit
from enclab.lrde import effects as lrde_effects

from .bench_lrde_effects import STEP, simulate_case, threshold
from .helpers import ROOT, stamp

TERMS = {"hysteresis": ((), ("hysteresis",)), "drift": ((), ("drift",)), "harmonic": ((3,), ())}


def true_point(truth: dict, case: str, sine: dict) -> dict:
    """The right model at the simulator's parameters, in the frame of ``sine`` (a point fit)."""
    kw = truth["simulator"]
    t_ref = sine["t_ref"]
    f, phase = truth["f_hz"], truth["phase"]
    kappa = kw.get("drift", 0.0)
    # The simulator's phase runs from t = 0, the model's from t_ref: re-expand about t_ref.
    f_model = f * (1.0 + kappa * t_ref)
    phase_model = phase + 2.0 * np.pi * f * (t_ref + 0.5 * kappa * t_ref ** 2)
    # Within the fit's phase bounds (its starting phase +- pi); the likelihood is periodic.
    centre = sine["init"]["phase"]
    phase_model = (phase_model - centre + np.pi) % (2.0 * np.pi) + centre - np.pi
    x = [truth["A12"] / STEP, truth["a_eq"] / STEP - sine["centre"] - 0.5, f_model, phase_model,
         np.log10(kw["noise_std"] / STEP)]
    harmonics, effects = TERMS[case]
    for k in harmonics:
        c, s = kw["harmonics"][k]
        x += [c / STEP, s / STEP]
    if "hysteresis" in effects:
        x.append(kw["hysteresis"] / STEP)
    if "drift" in effects:
        x.append(kappa / (1.0 + kappa * t_ref))
    extra_scale = [STEP] * (2 * len(harmonics)) + lrde_effects.effect_scales(effects, STEP, sine["dt"])
    return {**sine, "x": np.array(x), "harmonics": harmonics, "effects": effects, "extra_scale": extra_scale}


def one(case: str, cycles: int, seed: int) -> dict:
    t, counts, truth = simulate_case(np.random.default_rng(seed), case, cycles)
    sine = fit.map_fit(t, counts, STEP)
    oracle = true_point(truth, case, sine)
    harmonics, effects = TERMS[case]
    refit = fit.map_fit(t, counts, STEP, harmonics=harmonics, effects=effects, start=oracle["x"],
                        init=sine["init"])
    n_extra = 2 * len(harmonics) + len(effects)
    penalty = n_extra * np.log(t.size)
    ll_sine = compare.blurred_log_likelihood(sine, t, counts)
    ll_true = compare.blurred_log_likelihood(oracle, t, counts)
    ll_refit = compare.blurred_log_likelihood(refit, t, counts)
    return {"oracle_gain": 2.0 * (ll_true - ll_sine) - penalty,
            "refit_gain": 2.0 * (ll_refit - ll_sine) - penalty}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", nargs="+", default=[str(ROOT / "results" / "benchmarks" / "lrde_effects_draws.csv")])
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--cases", nargs="+", default=list(TERMS), choices=list(TERMS))
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--reuse", default=None, metavar="CSV",
                    help="an earlier lrde_detectability_draws.csv: its draws keep their gains "
                         "(they depend only on the log and the likelihood), the others are "
                         "computed")
    args = ap.parse_args(argv)
    draws = pd.concat([pd.read_csv(p) for p in args.draws], ignore_index=True)
    draws = draws.drop_duplicates(["cycles", "case", "seed"], keep="last")
    draws = draws[(draws["cycles"] == args.cycles) & draws["case"].isin(args.cases)]
    known = {}
    if args.reuse:
        old = pd.read_csv(args.reuse)
        known = {(int(r.cycles), r.case, int(r.seed)): {"oracle_gain": r.oracle_gain,
                                                         "refit_gain": r.refit_gain}
                 for r in old.itertuples(index=False)}
    rows = []
    started = time.perf_counter()
    for k, r in enumerate(draws.itertuples(index=False)):
        rows.append({"case": r.case, "cycles": r.cycles, "seed": r.seed, "size": r.size,
                     "named": bool(r.named), "identified": bool(r.identified),
                     "A12_after_cover": bool(r.A12_after_cover), "E_b_after_cover": bool(r.E_b_after_cover),
                     **(known.get((int(r.cycles), r.case, int(r.seed)))
                        or one(r.case, int(r.cycles), int(r.seed)))})
        if (k + 1) % 20 == 0:
            print(f"{k + 1}/{len(draws)} draws, {time.perf_counter() - started:.0f} s", file=sys.stderr)
    per = pd.DataFrame(rows)
    summary = []
    for case, g in per.groupby("case", sort=False):
        th = threshold(g["size"], g["identified"])
        big = g[g["size"] >= 3 * th] if np.isfinite(th) else g.iloc[:0]
        evident = big[big["oracle_gain"] > 0]
        summary.append({"cycles": args.cycles, "case": case, "n": len(g), "threshold": th,
                        "n_at_3x": len(big), "named_at_3x": big["named"].mean() if len(big) else None,
                        "n_at_3x_evident": len(evident),
                        "named_at_3x_evident": evident["named"].mean() if len(evident) else None,
                        "missed_at_3x_oracle_negative": int((~big["named"] & (big["oracle_gain"] <= 0)).sum()),
                        "missed_all_oracle_negative": int((~g["named"] & (g["oracle_gain"] <= 0)).sum()),
                        "missed_all": int((~g["named"]).sum()),
                        "n_evident": int((g["oracle_gain"] > 0).sum()),
                        "A12_cover_evident": g.loc[g["oracle_gain"] > 0, "A12_after_cover"].mean(),
                        "E_b_cover_evident": g.loc[g["oracle_gain"] > 0, "E_b_after_cover"].mean(),
                        "A12_cover_not_evident": g.loc[g["oracle_gain"] <= 0, "A12_after_cover"].mean(),
                        "E_b_cover_not_evident": g.loc[g["oracle_gain"] <= 0, "E_b_after_cover"].mean()})
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_table(stamp(per), out / "lrde_detectability_draws.csv")
    table = stamp(pd.DataFrame(summary))
    atomic.write_table(table, out / "lrde_detectability.csv")
    print(pd.DataFrame(summary).to_string())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
