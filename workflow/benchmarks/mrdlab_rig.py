"""How well do rig models of the MRDLab tool's CUI output encoder predict held-out runs?

MRDLab da Vinci tool as a rig: the CUI output encoder of all 20 runs fitted together.

The 20 runs of ``Tool_4_Maryland_L_2`` (5 frequencies x 4 reaction-torque levels, the rig
``mrdlab_tool4`` of ``data/manifest.real.yaml``) against the back-end motor encoder through the
35:1 gear. A ladder of rig models (:mod:`enclab.rig.fit`), each fitted on training runs and
scored on held-out runs:

- ``play+scale``: per-run offset and play width, shared scale;
- ``+map``: and the calibration map of the measured-side angle (knots every 0.05 rad);
- ``+map+torque+lag``: and the compliance (``T`` and ``T|T|`` of the back torque, ``T`` of the
  front torque) and a per-run latency;
- ``rig``: the compliance, one latency for the rig, the reversal transient
  (knots every 4 mrad of motor travel), and the map's knot spacing chosen per fold on the
  training runs; ``rig, per-run latency`` the same with a latency per run;
- ``rig+takeup`` (the rig rule's model for a declared ``signed_square``): the ``rig`` model
  with its form chosen per fold on the training runs: the back torque's ``T|T|`` kept or
  replaced by the play take-up ``tanh(T/T0)``
  (``T0`` = 0.1, 0.2, 0.4 or 0.8 times the torque's std), the reversal transient kept or left
  out; chosen on the steady strokes of one training condition value held out at a time, then the
  knot spacing the same way;
- ``rig+torquemap``: the ``rig`` model with the back torque's ``T|T|`` replaced by its torque map,
  the take-up curve of the transmission (a spline of the back torque, constant and linear parts
  removed, over the torque range every training condition covers, continued along its end
  slopes beyond): its number of intervals (4, 8 or 16) chosen per fold on the training runs, one
  condition value held out at a time, on every sample, then the knot spacing the same way. The
  gear's side of its play follows the torque it carries, not only the travel since a reversal:
  at a load that nearly balances the friction the torque stays near zero well into a stroke;
- ``rig+torquemap+form`` (the rig rule's model for ``compliance: {torque_back: [linear, map],
  torque_front: [linear]}``): the same with the reversal transient kept or left out and each
  torque channel kept or left out, chosen per fold on the training runs (one-standard-error
  rule, :func:`enclab.rig.fit.choose_variant`) before the number of intervals.

Splits: frequency (train 0.1/0.3/0.5 Hz, test 0.2/0.4 Hz) and load (train 10/20 %, test 30/40 %);
``--loro`` runs leave-one-run-out folds instead (knot spacing fixed at 0.05 rad, ``--loro-max``
of them, every k-th run held out) for the spread of the shared parameters.

Writes ``results/benchmarks/mrdlab_rig.csv`` (held-out residual std per model, split and
condition, with the targets) and ``results/benchmarks/mrdlab_rig_params.csv`` (the shared
parameters of each fold and their spread; for a torque map, ``<channel>:twist_curve``: the span
of the twist against that torque on the range the folds' maps share, and the largest deviation of
a fold's curve from their mean relative to it), and copies both to ``--copy-to`` when given.

``--rules`` instead runs the rig rule's own model (``config.yaml`` ``rig`` settings and the
manifest's declared compliance, :func:`enclab.rig.pipeline.report_rig`) on each rig of
``--rigs`` (default: ``mrdlab_tool4``, the 20 runs of ``Tool_4_Maryland_L_2``, and
``mrdlab_tool4_l4``, the 50 runs of ``Tool_4_Maryland_L_4`` to 100 % load, whose load split
trains on loads up to 50 % and tests 60-100 %) and writes ``results/benchmarks/mrdlab_rigs.csv``:
per rig and split the held-out steady / all std, the training runs' own held-out std, whether the
split extrapolates and the term that carries its held-out excess, per held-out condition value,
and the CPU seconds of the fit (``time.process_time``, one BLAS thread as in the rule) beside the
CPU seconds of a 5M-iteration Python loop measured in the same process.

Usage (from the repository root; needs ../shared/data/real)::

    PYTHONPATH=workflow python -m benchmarks.mrdlab_rig
    PYTHONPATH=workflow python -m benchmarks.mrdlab_rig --models rig --loro --suffix _loro
    PYTHONPATH=workflow python -m benchmarks.mrdlab_rig --rules
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    # One BLAS thread, as the rig rule runs (Snakemake sets it to the rule's threads): on a
    # shared machine, idle BLAS threads spinning on the small products of a rig fit cost more
    # CPU than the fit. Set before numpy loads BLAS, and only when run (an import changes nothing).
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import yaml  # noqa: E402

from enclab.core import atomic, ingest, readers  # noqa: E402
from enclab.rig import fit as rig  # noqa: E402
from enclab.rig.manifest import rig_groups  # noqa: E402
from enclab.rig.pipeline import report_rig, rule_spec, run_from_canonical  # noqa: E402
from enclab.rig.report import remains, split_table  # noqa: E402
from .helpers import ROOT, reference_loop_seconds, stamp  # noqa: E402

RIG = "mrdlab_tool4"
COMP = {"torque_back": ["linear", "signed_square"], "torque_front": ["linear"]}
SPACINGS = [0.2, 0.1, 0.07, 0.05, 0.035]
TORQUE_KNOTS = [4, 8, 16]
MODELS = {
    "play+scale": (rig.RigSpec(spacing=None, latency=False), None),
    "+map": (rig.RigSpec(spacing=0.05, latency=False), None),
    "+map+torque+lag": (rig.RigSpec(spacing=0.05, compliance=COMP), None),
    "rig": (rig.RigSpec(spacing=0.05, compliance=COMP, latency="shared", transient=0.004), SPACINGS),
    "rig, per-run latency": (rig.RigSpec(spacing=0.05, compliance=COMP, transient=0.004), SPACINGS),
    "rig+takeup": (rig.RigSpec(spacing=0.05, compliance=COMP, latency="shared", transient=0.004), SPACINGS,
                   "takeup"),
    "rig+torquemap": (rig.RigSpec(spacing=0.05, compliance={"torque_back": ["linear"], "torque_front": ["linear"]},
                                  torque_map={"torque_back": 8}, latency="shared", transient=0.004), SPACINGS,
                      None, TORQUE_KNOTS),
    "rig+torquemap+form": (rig.RigSpec(spacing=0.05, compliance={"torque_back": ["linear"], "torque_front": ["linear"]},
                                       torque_map={"torque_back": 4}, latency="shared", transient=0.004), SPACINGS,
                           "takeup", TORQUE_KNOTS),
}
# Done-when targets (steady, all) in rad and the independent study's reference for the full model
TARGETS = {"frequency": (0.55e-3, 1.20e-3), "load": (0.70e-3, 1.45e-3)}
STUDY = {("play+scale", "frequency"): (1.56e-3, 1.89e-3), ("+map", "frequency"): (0.78e-3, 1.28e-3),
         ("+map+torque+lag", "frequency"): (0.58e-3, 1.25e-3), ("+map+torque+lag", "load"): (0.73e-3, 1.52e-3)}


def load_runs(name: str = RIG, with_group: bool = False):
    """The runs of rig ``name`` of ``data/manifest.real.yaml`` and its splits (and its group:
    declared compliance, channel pairs, with ``with_group``)."""
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    data_root, entries = readers.read_manifest(ROOT / "data" / "manifest.real.yaml", devices=config["devices"])
    group = rig_groups(entries)[name]
    by_id = {e["id"]: e for e in entries}
    pair = group["pairs"][0]
    runs = []
    for member in group["runs"]:
        df, meta = ingest.ingest_log(by_id[member["log_id"]], ROOT / data_root, config["devices"])
        runs.append(run_from_canonical(df, meta, pair["measured"], pair["truth"],
                                           list(group["compliance"] or COMP), member["conditions"],
                                           member["log_id"]))
    if with_group:
        return runs, group["splits"], group
    return runs, group["splits"]


def rule_rows(names) -> list[dict]:
    """The rig rule's model on each rig of ``names``: held-out std per split (and per condition
    value), the extrapolation verdict and the CPU seconds of the fit beside a loop reference."""
    settings = yaml.safe_load((ROOT / "config.yaml").read_text())["rig"]
    rows = []
    for name in names:
        runs, splits, group = load_runs(name, with_group=True)
        spec, knots = rule_spec(settings, group["compliance"])
        ref_before = reference_loop_seconds()
        start = time.process_time()
        out = report_rig(name, group["pairs"][0]["measured"], runs, spec, splits, settings["spacings"],
                         variants="takeup", torque_knots=knots,
                         extrapolation_ratio=settings["extrapolation_ratio"])
        cpu = time.process_time() - start
        ref = 0.5 * (ref_before + reference_loop_seconds())
        ext = {e["split"]: e for e in out["block"]["extrapolation"]}
        for sp in out["block"]["splits"]:
            e = ext.get(sp["split"], {})
            shares = e.get("excess_share") or {}
            rows.append({"rig": name, "runs": len(runs), "split": sp["split"], "condition": "all test runs",
                         "value": "", "test_runs": sp["test_runs"],
                         "before_steady": sp["before_steady"], "before_all": sp["before_all"],
                         "steady": sp["after_steady"], "all": sp["after_all"], "floor": sp["floor"],
                         "train_heldout_steady": e.get("inner", {}).get("steady"),
                         "train_heldout_all": e.get("inner", {}).get("all"),
                         "x_others_steady": e.get("ratio_to_others", {}).get("steady"),
                         "x_train_steady": e.get("ratio_to_inner", {}).get("steady"),
                         "extrapolates": e.get("extrapolates"), "blame": e.get("blame"),
                         "blame_share": shares.get(e.get("blame")) if e.get("blame") else None,
                         "form": " | ".join(
                             "; ".join(f"{c}: {'+'.join(t)}" for c, t in f["compliance"].items())
                             + "".join(f"; {c} map {v['intervals']} {v['form']}" for c, v in f["torque_map"].items())
                             + f"; transient {f['transient'] or 'none'}; spacing {f['spacing']}"
                             for f in out["block"]["folds"] if f["split"] == sp["split"]),
                         "cpu_s": cpu, "loop_5M_cpu_s": ref})
        ct = out["tables"]["conditions"]
        for r in ct.itertuples(index=False):
            rows.append({"rig": name, "runs": len(runs), "split": r.split, "condition": r.condition,
                         "value": r.value, "test_runs": r.runs, "before_steady": r.before_steady,
                         "before_all": r.before_all, "steady": r.after_steady, "all": r.after_all})
        print(f"{name}: {len(runs)} runs, {cpu:.1f} s CPU (5M loop {ref:.3f} s)", file=sys.stderr)
        print(out["tables"]["splits"].to_string(), file=sys.stderr)
        for e in out["block"]["extrapolation"]:
            print(f"  {e['split']}: extrapolates={e['extrapolates']} {e['reason']} blame={e['blame']} "
                  f"{e['excess_share']}", file=sys.stderr)
    return rows


def _form(spec: rig.RigSpec) -> str:
    """The compliance terms, torque scales and transient a fold chose, in words."""
    terms = "; ".join(f"{c}: {'+'.join(t)}" for c, t in spec.compliance.items())
    scales = ", ".join(f"{c} T0={v:.3g} N m" for c, v in spec.torque_scales.items())
    tmap = ", ".join(f"{c} torque map {v[2]} intervals on [{v[0]:.3g}, {v[1]:.3g}] N m"
                     + (f" ({v[3]})" if len(v) > 3 else "")
                     for c, v in spec.torque_map.items())
    return (f"{terms}{'; ' + scales if scales else ''}{'; ' + tmap if tmap else ''}; "
            f"transient {spec.transient or 'none'}")


def torque_curve_spread(folds_out, n: int = 101) -> dict:
    """Per torque map: the twist against the torque alone (linear term plus map, its mean
    removed) of each fold on the torque range all folds' maps share; ``span`` (rad) of their
    mean curve and ``rel_dev``, the largest deviation of a fold's curve from it over that span.
    A map's linear coefficient is its mean slope over its own range, so it is no parameter to
    compare across folds; the curve is."""
    maps = [f["fit"] for f in folds_out if f["fit"].spec.torque_map]
    out = {}
    for channel in sorted({c for fit in maps for c in fit.spec.torque_map}):
        fits = [fit for fit in maps if channel in fit.spec.torque_map]
        lo = max(fit.spec.torque_map[channel][0] for fit in fits)
        hi = min(fit.spec.torque_map[channel][1] for fit in fits)
        if len(fits) < 2 or not hi > lo:
            continue
        T = np.linspace(lo, hi, n)
        curves = []
        for fit in fits:
            c = fit.shared().get(f"{channel}:linear", 0.0) * T + fit.torque_map_curve(channel, T)
            curves.append(c - c.mean())
        curves = np.array(curves)
        mean = curves.mean(axis=0)
        span = float(np.ptp(mean))
        out[channel] = {"span": span, "rel_dev": float(np.max(np.abs(curves - mean)) / span)}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--loro", action="store_true",
                        help="leave-one-run-out folds instead of the condition splits (spacing fixed)")
    parser.add_argument("--loro-max", type=int, default=10, help="at most this many leave-one-run-out folds")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks")
    parser.add_argument("--copy-to", type=Path, default=None)
    parser.add_argument("--suffix", default="", help="appended to the CSV names (e.g. _loro)")
    parser.add_argument("--rules", action="store_true",
                        help="the rig rule's own model on each of --rigs (writes mrdlab_rigs.csv)")
    parser.add_argument("--rigs", nargs="+", default=[RIG, "mrdlab_tool4_l4"])
    args = parser.parse_args(argv)
    if not (ROOT.parent / "shared" / "data" / "real").is_dir():
        print("../shared/data/real is absent: nothing to analyse", file=sys.stderr)
        return 1
    if args.rules:
        args.out.mkdir(parents=True, exist_ok=True)
        name = f"mrdlab_rigs{args.suffix}.csv"
        atomic.write_table(stamp(pd.DataFrame(rule_rows(args.rigs))), args.out / name)
        if args.copy_to:
            args.copy_to.mkdir(parents=True, exist_ok=True)
            shutil.copy(args.out / name, args.copy_to / name)
        return 0
    runs, splits = load_runs()
    rows, params = [], []
    for model in args.models:
        spec, spacings, *extra = MODELS[model]
        variants = extra[0] if extra else None
        knots = extra[1] if len(extra) > 1 else None
        start = time.perf_counter()
        if args.loro:
            # Leave-one-run-out folds only, the knot spacing fixed (0.05 rad), every k-th run held
            # out (--loro-max folds): the spread of the shared parameters over many training sets.
            folds = rig.make_folds(runs, [{"name": "runs", "leave_one_run_out": True}])
            folds = folds[::max(len(folds) // args.loro_max, 1)][:args.loro_max]
            res, out = rig.evaluate(runs, spec, folds, None, keep_residuals=True, variants=variants,
                                    torque_knots=knots)
        else:
            res, out = rig.evaluate(runs, spec, rig.make_folds(runs, splits), spacings, keep_residuals=True,
                                    variants=variants, torque_knots=knots)
        seconds = time.perf_counter() - start
        table = split_table(res)
        for _, r in table.iterrows():
            split = r["split"]
            target = TARGETS.get(split)
            study = STUDY.get((model, split))
            res_split = {k: v for f in out if f["split"] == split for k, v in f["residuals"].items()}
            rem = remains(runs, res_split, spec) if split in TARGETS else {}
            rows.append({"model": model, "split": split, "condition": "all test runs", "value": "",
                         "runs": int(r["test_runs"]), "before_steady": r["before_steady"],
                         "before_all": r["before_all"], "steady": r["after_steady"], "all": r["after_all"],
                         "floor": r["floor"],
                         "target_steady": target[0] if target else None, "target_all": target[1] if target else None,
                         "met": bool(target and r["after_steady"] <= target[0] and r["after_all"] <= target[1]),
                         "study_steady": study[0] if study else None, "study_all": study[1] if study else None,
                         "window_share": rem.get("window_share"), "repeatable_share": rem.get("repeatable_share"),
                         "window_std": rem.get("window_std"), "outside_std": rem.get("outside_std"),
                         "seconds": seconds})
        df = pd.DataFrame(res)
        for split, sel in df[df["role"] == "test"].groupby("split", sort=False):
            if split not in TARGETS:
                continue
            for cond in ("frequency_hz", "load_pct"):
                for value, grp in sel.groupby(cond):
                    p = rig.pooled(grp.to_dict("records"))
                    rows.append({"model": model, "split": split, "condition": cond, "value": value,
                                 "runs": len(grp),
                                 "before_steady": float(np.sqrt(np.mean(grp["before_steady_std"] ** 2))),
                                 "before_all": float(np.sqrt(np.mean(grp["before_all_std"] ** 2))),
                                 "steady": p["steady_std"], "all": p["all_std"],
                                 "floor": float(grp["floor_std"].iloc[0])})
        cond_folds = [f for f in out if f["split"] in TARGETS]
        spread = rig.fold_spread(cond_folds)
        loro_spread = rig.fold_spread([f for f in out if f["split"] == "runs"]) if args.loro else {}
        for f in out:
            fit = f["fit"]
            ci = fit.ci()
            widths = [v["play_width"] for v in fit.per_run.values()]
            lat = [v["latency"] for v in fit.per_run.values()]
            for name, value in {**fit.shared(), "play_width_mean": float(np.mean(widths)),
                                **({"latency_mean": float(np.mean(lat))} if spec.latency is True else {})}.items():
                if name.startswith("transient"):
                    continue
                params.append({"model": model, "split": f["split"], "fold": str(f["fold"]),
                               "spacing": f["spacing"], "form": _form(fit.spec), "parameter": name, "value": value,
                               "ci_lo": ci.get(name, (None, None))[0], "ci_hi": ci.get(name, (None, None))[1],
                               "spread_over_condition_folds": spread.get(name, {}).get("rel_dev"),
                               "kept_in_condition_folds": f"{spread[name]['kept_in']}/{spread[name]['folds']}"
                               if name in spread else None,
                               "spread_over_loro_folds": loro_spread.get(name, {}).get("rel_dev")})
        for group in ([cond_folds, "spread_over_condition_folds"],
                      [[f for f in out if f["split"] == "runs"], "spread_over_loro_folds"]):
            for channel, c in torque_curve_spread(group[0]).items():
                params.append({"model": model, "split": "all folds", "fold": "", "spacing": None, "form": "",
                               "parameter": f"{channel}:twist_curve", "value": c["span"],
                               "ci_lo": None, "ci_hi": None, group[1]: c["rel_dev"]})
        print(f"{model}: {seconds:.0f} s", file=sys.stderr)
        for f in out:
            print(f"  fold {f['fold']}: spacing {f['spacing']}, {_form(f['fit'].spec)}; variant scores "
                  f"{f.get('variant_scores')}", file=sys.stderr)
        print(table.to_string(), file=sys.stderr)
        print({k: round(v["rel_dev"], 3) for k, v in spread.items() if not k.startswith("transient")}, file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    outputs = {f"mrdlab_rig{args.suffix}.csv": pd.DataFrame(rows),
               f"mrdlab_rig_params{args.suffix}.csv": pd.DataFrame(params)}
    for name, frame in outputs.items():
        atomic.write_table(stamp(frame), args.out / name)
        if args.copy_to:
            args.copy_to.mkdir(parents=True, exist_ok=True)
            shutil.copy(args.out / name, args.copy_to / name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
