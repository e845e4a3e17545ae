"""Do the residual stage's findings on a truth channel carry into the LRDE fit?

Benchmark of the loop between the residual stage and the LRDE fit on truth-channel logs.

Each draw is a low-resolution log as in ``bench_lrde_effects.py`` (step 0.09 deg, ``A12 ~
U(3, 5)`` steps, ``E_b`` in Proposition 1's band, f ~ 20 Hz x U(0.9, 1.1) at 2 kHz, position
noise 0.005 step of the reading), with a fine rounding channel of step/100 reading the motion
itself, and the offset ``a ~ U(0, step)`` split from the bias ``b = a_eq - a``. Cases:

==========  =============================================
case        encoder effect (log-uniform size)
==========  =============================================
clean       none
hysteresis  dead band 1/50 .. 1/5 step of the reading
==========  =============================================

Per draw the two stages run as in ``make run``: the residual stage on the coarse channel
against the fine one (:func:`enclab.residuals.pipeline.analyse_channel`), its findings
translated (:func:`enclab.reference_effects.lrde_reference`), and the LRDE stage
(:func:`enclab.lrde.pipeline.analyse_lrde_log`, sampler settings of ``config.yaml``) with and
without them. Recorded: what the residual stage found, what the LRDE comparison chose alone,
the final model, and whether the 90 % intervals of ``A12``, ``E_b``, ``offset_a`` and
``bias_b`` hold the truth before (sinusoid) and after (final model), with the reference and
without it.

Usage::

    PYTHONPATH=workflow python -m benchmarks.lrde_truth_loop --draws 40 --clean-draws 20

Writes ``<out>/lrde_truth_loop_draws.csv`` and ``<out>/lrde_truth_loop.csv`` (summary).
"""
from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
import pandas as pd
import yaml


from enclab.lrde import effects, model, pipeline, simulate
from enclab.reference_effects import lrde_reference
from enclab.residuals.pipeline import analyse_channel

from .helpers import ROOT, stamp

STEP = simulate.ROS_DRILL_STEP
FINE = STEP / 100
KEYS = ("A12", "E_b", "offset_a", "bias_b")


def simulate_log(rng, case, n_cycles, fs_hz=2000.0):
    """``(df, meta, truth)`` of one draw."""
    f_hz = 20.0 * rng.uniform(0.9, 1.1)
    A12 = rng.uniform(3.0, 5.0) * STEP
    half_eps = 0.5 * float(model.epsilon(A12, STEP))
    E_b = rng.uniform(-half_eps, half_eps)
    a_eq = 0.5 * STEP + E_b
    a = rng.uniform(0.0, STEP)
    phase = rng.uniform(-np.pi, np.pi)
    size = 0.0 if case == "clean" else float(np.exp(rng.uniform(np.log(1 / 50),
                                                                np.log(1 / 5))))
    t = np.arange(int(np.floor((n_cycles + 1) * fs_hz / f_hz))) / fs_hz
    counts = effects.simulate_counts(rng, t, STEP, A12, a_eq, f_hz, phase,
                                     noise_std=0.005 * STEP, hysteresis=size * STEP)
    theta = (a_eq - a) + 0.5 * A12 * np.sin(2 * np.pi * f_hz * t + phase)
    df = pd.DataFrame({"t": t, "coarse": counts,
                       "fine": np.floor(theta / FINE + 0.5).astype(np.int64)})
    meta = {"log_id": f"{case}", "channels": [
        {"name": "fine", "role": "truth", "joint": 1, "unit": "rad", "storage": "counts",
         "step": FINE},
        {"name": "coarse", "role": "measured", "joint": 1, "unit": "rad", "storage": "counts",
         "step": STEP}]}
    return df, meta, {"A12": A12, "E_b": E_b, "offset_a": a, "bias_b": a_eq - a,
                      "size": size}


def _covers(est, true):
    if est is None:
        return None
    lo, hi = est["q05"], est["q95"]
    return bool(lo <= true <= hi), bool(max(lo - true, true - hi, 0.0) > hi - lo)


def one_draw(case, n_cycles, seed, settings):
    rng = np.random.default_rng(seed)
    df, meta, truth = simulate_log(rng, case, n_cycles)
    row = {"case": case, "cycles": n_cycles, "seed": seed, "size": truth["size"]}
    row |= {f"{key}_true": truth[key] for key in KEYS}
    started = time.perf_counter()
    try:
        res_block, _, _ = analyse_channel(df, meta, {"measured": "coarse", "truth": "fine"},
                                          {"seed": seed})
    except Exception as err:  # a failed stage is a result of the benchmark, not its end
        row["failed"] = f"residual stage: {type(err).__name__}: {err}"
        return row
    ref = lrde_reference(res_block)
    row["residual_wall_s"] = time.perf_counter() - started
    row["residual_found"] = "|".join(f["residual_effect"] for f in ref["found"])
    block = None
    for label, refs in (("alone", None), ("loop", {"coarse": ref})):
        started = time.perf_counter()
        if block is not None and set(ref["effects"]) <= set(block["model"].get("effects") or []):
            # nothing to add: the stage's fit is the one without the reference (same seed)
            block = dict(block, model=dict(block["model"], reference={
                "added": [], "terms": [{"term": e, "status": "found by both",
                                        "consistent": None} for e in ref["effects"]]}))
            row[f"{label}_wall_s"] = row["alone_wall_s"]
        else:
            block, _, _, _ = pipeline.analyse_lrde_log(df, meta, seed, dict(settings),
                                                       references=refs)
            row[f"{label}_wall_s"] = time.perf_counter() - started
        m = block["model"]
        row[f"{label}_chosen"] = m.get("chosen")
        row[f"{label}_model"] = block["after"]["model"]
        row[f"{label}_trusted"] = all(v["trusted"] for k, v in block["trust"].items()
                                      if block.get(k) is not None)
        row[f"{label}_converged"] = bool(block["after"]["converged"])
        if label == "loop":
            r = m.get("reference") or {}
            row["added"] = "|".join(r.get("added", []))
            row["status"] = "|".join(f"{x['term']}:{x['status']}:{x['consistent']}"
                                     for x in r.get("terms", []))
        # E_b is reported relative to the centre count c of the readings (eq. 14 in c's frame)
        row[f"{label}_centre_count"] = block["centre_count"]
        frame = {"E_b": -block["centre_count"] * STEP}
        for when in ("before", "after"):
            for key in KEYS:
                est = block[when].get(key)
                row[f"{label}_{key}_{when}_q05"] = est and est["q05"]
                row[f"{label}_{key}_{when}_q95"] = est and est["q95"]
                cov = _covers(est, truth[key] + frame.get(key, 0.0))
                row[f"{label}_{key}_{when}_cover"] = None if cov is None else cov[0]
                row[f"{label}_{key}_{when}_confident_miss"] = (
                    None if cov is None else cov[1] and row[f"{label}_converged"]
                    and row[f"{label}_trusted"])
    right = "hysteresis" if case == "hysteresis" else None
    for label in ("alone", "loop"):
        terms = row[f"{label}_model"].split("+")
        row[f"{label}_named"] = (right in terms) if right else (terms == ["sinusoid"])
    return row


def _count_zero_frame(draws: pd.DataFrame) -> pd.DataFrame:
    """Rows written without the centre count: ``E_b``'s frame is the whole number of steps
    nearest to the interval's offset from the truth (the stroke keeps ``E_b`` inside half a
    step), and its coverage is recomputed in that frame."""
    out = draws.copy()
    for label in ("alone", "loop"):
        if f"{label}_centre_count" in out and out[f"{label}_centre_count"].notna().all():
            continue
        for when in ("before", "after"):
            lo, hi = out[f"{label}_E_b_{when}_q05"], out[f"{label}_E_b_{when}_q95"]
            true = out["E_b_true"] + STEP * np.round((0.5 * (lo + hi) - out["E_b_true"]) / STEP)
            cover = (lo <= true) & (true <= hi)
            out[f"{label}_E_b_{when}_cover"] = cover.where(lo.notna())
            miss = np.maximum(np.maximum(lo - true, true - hi), 0.0) > (hi - lo)
            out[f"{label}_E_b_{when}_confident_miss"] = (
                miss & out[f"{label}_converged"].astype(bool)
                & out[f"{label}_trusted"].astype(bool)).where(lo.notna())
    return out


def summarise(draws: pd.DataFrame) -> pd.DataFrame:
    rows = []
    failed = draws["failed"].notna() if "failed" in draws else pd.Series(False, draws.index)
    for (cycles, case), g_all in draws.groupby(["cycles", "case"]):
        g = g_all[~failed.loc[g_all.index]]
        r = {"cycles": cycles, "case": case, "n": len(g), "failed": int(len(g_all) - len(g)),
             "residual_named": float((g["residual_found"].fillna("") != "").mean()),
             "named_alone": float(g["alone_named"].mean()),
             "named_loop": float(g["loop_named"].mean()),
             "median_wall_s_loop": float((g["residual_wall_s"] + g["loop_wall_s"]).median())}
        for label in ("alone", "loop"):
            for key in KEYS:
                for when in ("before", "after"):
                    col = g[f"{label}_{key}_{when}_cover"].dropna().astype(bool)
                    r[f"{label}_{key}_{when}"] = float(col.mean()) if len(col) else None
            misses = g[[c for c in g.columns if c.startswith(f"{label}_")
                        and c.endswith("after_confident_miss")]].fillna(False).astype(bool)
            r[f"{label}_confident_miss_rate"] = float(misses.any(axis=1).mean())
        rows.append(r)
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40, help="hysteresis draws per cycle count")
    ap.add_argument("--clean-draws", type=int, default=20)
    ap.add_argument("--cycles", type=int, nargs="+", default=[20])
    ap.add_argument("--seed", type=int, default=20261203)
    ap.add_argument("--first-draw", type=int, default=0)
    ap.add_argument("--time-budget", type=float, default=None,
                    help="stop drawing after this many seconds (rows so far are kept)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--from-draws", nargs="+", default=None, metavar="CSV",
                    help="only summarise existing lrde_truth_loop_draws.csv files")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.from_draws:
        draws = _count_zero_frame(pd.concat([pd.read_csv(p) for p in args.from_draws],
                                            ignore_index=True))
    else:
        settings = dict(yaml.safe_load((ROOT / "config.yaml").read_text())["lrde"])
        settings.pop("seed")
        tasks = [(case, cycles, args.seed + 100_000 * c_i + 1000 * cycles + i)
                 for cycles in args.cycles
                 for i in range(args.first_draw, max(args.draws, args.clean_draws))
                 for c_i, case in enumerate(("clean", "hysteresis"))
                 if i < (args.clean_draws if case == "clean" else args.draws)]
        started, rows = time.perf_counter(), []
        for case, cycles, seed in tasks:
            if args.time_budget is not None and time.perf_counter() - started > args.time_budget:
                break
            rows.append(one_draw(case, cycles, seed, settings))
            print({k: rows[-1].get(k) for k in ("case", "size", "residual_found",
                                                "alone_model", "loop_model",
                                                "loop_offset_a_after_cover",
                                                "loop_bias_b_after_cover")}, flush=True)
            stamp(pd.DataFrame(rows)).to_csv(out / "lrde_truth_loop_draws.csv", index=False)
        draws = stamp(pd.DataFrame(rows))
    draws.to_csv(out / "lrde_truth_loop_draws.csv", index=False)
    summary = stamp(summarise(draws))
    summary.to_csv(out / "lrde_truth_loop.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 60):
        print(summary.T)


if __name__ == "__main__":
    main()
