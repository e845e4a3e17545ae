"""What makes the MRDLab da Vinci tool's output encoders differ from its motor encoder?

MRDLab da Vinci tool rig: output encoders against the motor encoder.

The 8192-cpr CUI output encoder (and the 4000-cpr front-end encoder) against the back-end motor
encoder divided by the 35:1 gear ratio (the truth; data/manifest.real.yaml, entry
mrdlab_0p5hz) differ by far more than quantization. Candidates, each fitted to the residual of
the exact quantizer model, r = angle_out - angle_motor - c:

- ``scale``       r = s * theta                        (gear-ratio / counts-per-rev mismatch)
- ``hysteresis``  r = -h * sign(v)                     (dead band: instant shift at reversal)
- ``backlash``    r = play_w(theta) - theta            (play operator: a ramp of width w)
- ``compliance``  r = kappa * torque                   (twist against the logged back-end torque)

and their combinations. Each model's continuous parameters are fitted by least squares (the
play width by a 1-D bounded search), scored by BIC and, because the residual of a slow motion is
strongly autocorrelated, on held-out data: fitted on one half of the log, scored on the other
(both ways). The predicted reading is then ``q(theta_motor + c + effect)`` on the output grid,
so "after" is the same exact-model residual as "before". Across the 20 runs of the factorial set
(0.1-0.5 Hz x 10-40 % reaction torque) a backlash keeps its width and a compliance its
coefficient while the torque changes: the check that separates them.

When the effect library is installed (``enclab.residuals.select``), its forward selection is
run on the same logs too (with the back-end torque as ``aux["torque"]``).

Usage (from the repository root; needs ../shared/data/real)::

    PYTHONPATH=workflow python -m benchmarks.mrdlab_residuals                 # 40.TXT only
    PYTHONPATH=workflow python -m benchmarks.mrdlab_residuals --all           # the 20 runs
    PYTHONPATH=workflow python -m benchmarks.mrdlab_residuals --all --out results/analyses
    PYTHONPATH=workflow python -m benchmarks.mrdlab_residuals --library-candidates scale_mismatch hysteresis backlash compliance

Writes ``mrdlab_models.csv`` (one row per run, channel and model) and ``mrdlab_residuals.md``.
"""
from __future__ import annotations

import argparse
import copy
import math
import re
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from enclab.core import atomic, ingest, readers
from enclab.residuals import diagnostics as dg
from enclab.residuals.effects import play_operator
from enclab.residuals.pipeline import channel_values
from scipy import optimize

from .helpers import ROOT

TORQUE_STEP = 3.9811e-5  # N m per Futek count (PROVENANCE.md)
MODELS = {
    "exact": (),
    "scale": ("scale",),
    "hysteresis": ("hysteresis",),
    "backlash": ("backlash",),
    "compliance": ("compliance",),
    "scale+backlash": ("scale", "backlash"),
    "scale+compliance": ("scale", "compliance"),
    "backlash+compliance": ("backlash", "compliance"),
    "scale+backlash+compliance": ("scale", "backlash", "compliance"),
    "scale+hysteresis+compliance": ("scale", "hysteresis", "compliance"),
}


def _design(effects, theta, v, torque, width):
    cols = [np.ones_like(theta)]
    if "scale" in effects:
        cols.append(theta - theta.mean())
    if "hysteresis" in effects:
        cols.append(-np.sign(v))
    if "compliance" in effects:
        cols.append(torque - torque.mean())
    if "backlash" in effects:
        cols.append(play_operator(theta, width) - theta)
    return np.column_stack(cols)


def fit_model(effects, theta, v, torque, r, train):
    """Least squares of the linear terms; the play width by a bounded 1-D search.

    The play term enters with a free coefficient (1 for a pure play); it is kept so that a
    compliance-like smooth ramp cannot masquerade as play through the width alone.
    """
    def solve(width):
        X = _design(effects, theta, v, torque, width)
        beta, *_ = np.linalg.lstsq(X[train], r[train], rcond=None)
        return X, beta, float(np.sum((r[train] - X[train] @ beta) ** 2))

    width = None
    if "backlash" in effects:
        res = optimize.minimize_scalar(lambda w: solve(w)[2], bounds=(1e-5, 0.08), method="bounded",
                                       options={"xatol": 1e-6})
        width = float(res.x)
    X, beta, _ = solve(width or 0.0)
    return X @ beta, beta, width


def analyse_run(path: Path, entry: dict, devices: dict, channels=("theta_cui", "theta_front"),
                use_library: bool = True, library_candidates=None) -> list[dict]:
    entry = copy.deepcopy(entry)
    entry["file"] = str(path.relative_to(ROOT.parent / "shared" / "data" / "real"))
    root = ROOT.parent / "shared" / "data" / "real"
    df, meta = ingest.ingest_log(entry, root, devices)
    header = path.read_text(errors="replace").splitlines()[1]
    freq = float(re.search(r"([\d.]+) Hz", header).group(1))
    load = float(re.search(r"reaction torque of ([\d.]+) percent", header).group(1))
    t = df["t"].to_numpy(float)
    theta, theta_step = channel_values(df, meta, "theta_motor")
    torque = channel_values(df, meta, "torque_back")[0]
    v = dg.velocity(t, theta)
    n = t.size
    halves = [np.arange(n) < n // 2, np.arange(n) >= n // 2]
    rows = []
    for name in channels:
        measured, step = channel_values(df, meta, name)
        c = dg.fit_offset(theta, measured, step)
        before = measured - dg.exact_prediction(theta, step, c)
        r = measured - theta - c
        for model, effects in MODELS.items():
            pred, beta, width = fit_model(effects, theta, v, torque, r, np.ones(n, bool))
            after = measured - dg.exact_prediction(theta + c + pred, step, 0.0)
            k = len(beta) + (width is not None)
            rss = float(np.sum((r - pred) ** 2))
            held = []
            for train, test in (halves, halves[::-1]):
                p_h, *_ = fit_model(effects, theta, v, torque, r, train)
                held.append(float(np.sqrt(np.mean((r[test] - p_h[test]) ** 2))))
            coef = dict(zip(["offset"] + [e for e in ("scale", "hysteresis", "compliance", "backlash")
                                          if e in effects], beta))
            rows.append({
                "file": path.name, "freq_hz": freq, "load_pct": load, "channel": name, "step": step,
                "model": model, "n_params": k,
                "before_std": float(np.std(before)), "after_std": float(np.std(after)),
                "floor_std": dg.residual_floor(step, theta_step)["std"],
                "bic": n * math.log(rss / n) + k * math.log(n),
                "heldout_rms": float(np.mean(held)),
                "scale": coef.get("scale"), "hysteresis_h": coef.get("hysteresis"),
                "kappa_rad_per_Nm": coef.get("compliance"), "play_width": width,
                "play_gain": coef.get("backlash"),
            })
        if use_library:
            rows.append(_library_row(path, freq, load, name, t, theta, theta_step, measured, step, c,
                                     torque, library_candidates))
    return rows


def _library_row(path, freq, load, name, t, theta, theta_step, measured, step, c, torque, candidates=None):
    try:
        from enclab.residuals.select import select_effects
    except ImportError:
        return {"file": path.name, "freq_hz": freq, "load_pct": load, "channel": name,
                "model": "library", "message": "enclab.residuals.select not installed"}
    start = time.perf_counter()
    res = select_effects(t, theta + c, measured, step, truth_step=theta_step,
                         aux={"torque": torque}, seed=0, candidates=candidates)
    effects = "; ".join(
        f"{e.name}(" + ", ".join(f"{k}={v:.4g} [{e.ci[k][0]:.4g}, {e.ci[k][1]:.4g}]"
                                 for k, v in e.params.items()) + f", dBIC={e.delta_bic:.0f})"
        for e in res.effects)
    return {"file": path.name, "freq_hz": freq, "load_pct": load, "channel": name, "step": step,
            "model": "library" if candidates is None else "library(" + ",".join(candidates) + ")",
            "before_std": res.before["std"], "after_std": res.after["std"],
            "floor_std": res.after.get("floor_std"), "effects": effects, "message": res.message,
            "explained": res.explained, "seconds": time.perf_counter() - start}


def markdown(table: pd.DataFrame) -> str:
    lines = ["# MRDLab: output encoders against the motor encoder", "",
             "Residual std (rad) of the exact quantizer model before and after each candidate "
             "model, and the held-out rms of the continuous fit (fit on one half, scored on the "
             "other), per channel, median over the runs analysed "
             f"({table['file'].nunique()} file(s)).", ""]
    fits = table[~table["model"].str.startswith("library")]
    med = fits.groupby(["channel", "model"], sort=False)[
        ["before_std", "after_std", "heldout_rms", "floor_std", "bic"]].median()
    lines.append(med.to_markdown(floatfmt=".4g"))
    lines += ["", "Fitted parameters of the full model (scale+backlash+compliance) per run:", ""]
    full = fits[fits["model"] == "scale+backlash+compliance"][
        ["file", "freq_hz", "load_pct", "channel", "scale", "play_width", "play_gain",
         "kappa_rad_per_Nm", "after_std"]]
    lines.append(full.to_markdown(index=False, floatfmt=".4g"))
    lib = table[table["model"].str.startswith("library")]
    if len(lib):
        lines += ["", "Effect library (forward selection with the back-end torque as aux):", ""]
        lines.append(lib[[c for c in ("file", "channel", "model", "before_std", "after_std", "floor_std",
                                      "explained", "effects", "message", "seconds")
                          if c in lib]].to_markdown(index=False, floatfmt=".4g"))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="the 20 runs of the factorial set")
    parser.add_argument("--no-library", action="store_true", help="skip the effect library")
    parser.add_argument("--channels", nargs="+", default=["theta_cui", "theta_front"])
    parser.add_argument("--library-candidates", nargs="+", default=None,
                        help="effect names the library may choose from (default: all), e.g. the "
                             "script's own set: scale_mismatch hysteresis backlash compliance")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "analyses")
    args = parser.parse_args(argv)
    data = ROOT.parent / "shared" / "data" / "real" / "mrdlab_davinci_tool" / "data" / "Tool_4_Maryland_L_2"
    if not data.exists():
        print(f"{data} is absent: nothing to analyse", file=sys.stderr)
        return 1
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    manifest = yaml.safe_load((ROOT / "data" / "manifest.real.yaml").read_text())
    _, entries = readers.read_manifest(ROOT / "data" / "manifest.real.yaml", devices=config["devices"])
    entry = next(e for e in entries if e["id"] == "mrdlab_0p5hz")
    del manifest
    files = sorted(data.glob("*.TXT")) if args.all else [data / "40.TXT"]
    rows = []
    for path in files:
        start = time.perf_counter()
        rows += analyse_run(path, entry, config["devices"], tuple(args.channels),
                            use_library=not args.no_library, library_candidates=args.library_candidates)
        print(f"{path.name}: {time.perf_counter() - start:.1f} s", file=sys.stderr)
    table = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic.write_table(table, args.out / "mrdlab_models.csv")
    atomic.write_text(markdown(table), args.out / "mrdlab_residuals.md")
    print(markdown(table))
    return 0


if __name__ == "__main__":
    sys.exit(main())
