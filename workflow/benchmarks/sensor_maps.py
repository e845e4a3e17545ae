"""Does the residual stage read sensors that are not hard quantizers right?

Sensors that are not hard quantizers through the residual stage: floor kind, map, lookup table.

Question: on a magnetic encoder (1st-4th harmonic error, noise), a resolver (2nd harmonic), a
potentiometer (nonlinear track, noise) and a servo (filtered output sensor and motor encoder on
one grid, a preload taken up at a torque reversal halfway), each against a fine reference
(``enclab.residuals.simulate.SENSORS``), does the residual stage name the map (and the servo's
level shift), and is the lookup table's held-out error within 1.2x the floor?

Each draw runs ``enclab.residuals.pipeline.analyse_channel`` with every candidate effect and
writes its lookup table under ``results/benchmarks/sensor_maps/``. One row per draw in
``results/benchmarks/sensor_maps.csv``; ``ref_loop_s`` is a 5M-iteration Python loop timed
beside each draw (the stage's seconds are comparable only as a ratio to it on a shared machine).

    PYTHONPATH=workflow python -m benchmarks.sensor_maps [--draws 2] [--duration 8] [--seed 20261204]
"""
from __future__ import annotations

import argparse
import json
import pathlib
import time

import numpy as np
import pandas as pd

from enclab.residuals import lookup_table as lut
from enclab.residuals import pipeline
from enclab.residuals.simulate import SENSORS, sensor_canonical, simulate_sensor

from .helpers import reference_loop_seconds, stamp

MAPS = {"angle_harmonics", "harmonic_map", "calibration_map", "scale_mismatch"}


def one(kind: str, seed: int, duration: float, out: pathlib.Path) -> dict:
    sim = simulate_sensor(np.random.default_rng(seed), kind, duration=duration)
    df, meta, pair, settings = sensor_canonical(sim, f"{kind}_{seed}")
    ref = reference_loop_seconds(clock=time.perf_counter)
    t0 = time.process_time()
    block, _, _ = pipeline.analyse_channel(df, meta, pair, settings)
    cpu = time.process_time() - t0
    doc = block["lookup_table"]
    lut.table_frame(doc).to_csv(out / f"{kind}_{seed}_lookup_table.csv", index=False)
    (out / f"{kind}_{seed}_lookup_table.json").write_text(json.dumps(doc, indent=1))
    effects = block["selection"]["effects"]
    names = [e["name"] for e in effects]
    shift = next((e for e in effects if e["name"] == "level_shift"), None)
    am = block["angle_map"]
    true_shift = SENSORS[kind].get("level_shift")
    return {
        "sensor": kind, "seed": seed, "n": int(sim["t"].size),
        "floor_kind": block["floor_kind"], "noise_true": sim["noise"], "noise_est": block["floor"]["noise_std"],
        "floor_true": sim["floor_std"], "effects": " + ".join(names),
        "map_named": bool(MAPS & set(names)), "explained": bool(block["selection"]["explained"]),
        "level_shift_true": true_shift or 0.0,
        "level_shift_d": None if shift is None else -shift["params"]["d"] if shift["derived"]["at_sign_changes"]
        else shift["params"]["d"],
        "level_shift_t": None if shift is None else shift["derived"]["t_shift"],
        "map_order": am["order"], "heldout_table": am["heldout_rms_table"],
        "heldout_harmonics": am["heldout_rms"], "heldout_no_map": am["heldout_rms_none"],
        "heldout_over_floor": am["heldout_rms_table"] / sim["floor_std"],
        "heldout_arcsec": doc["heldout_error"]["table"]["arcsec"],
        "cpu_s": cpu, "ref_loop_s": ref,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=2, help="draws per sensor")
    parser.add_argument("--duration", type=float, default=8.0, help="log length (s) at 1 kHz")
    parser.add_argument("--seed", type=int, default=20261204)
    parser.add_argument("--sensors", nargs="*", default=sorted(SENSORS))
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    tables = out / "sensor_maps"
    tables.mkdir(parents=True, exist_ok=True)
    rows = []
    for kind in args.sensors:
        for k in range(args.draws):
            rows.append(one(kind, args.seed + k, args.duration, tables))
            print(pd.DataFrame(rows[-1:]).round(6).to_string(index=False), flush=True)
    table = stamp(pd.DataFrame(rows), argv)
    table.to_csv(out / "sensor_maps.csv", index=False)
    summary = table.groupby("sensor").agg(
        draws=("seed", "size"), floor_kind=("floor_kind", lambda s: "/".join(sorted(set(s)))),
        map_named=("map_named", "mean"), explained=("explained", "mean"),
        heldout_over_floor_max=("heldout_over_floor", "max"), map_order=("map_order", "median"),
        cpu_s=("cpu_s", "median"), ref_loop_s=("ref_loop_s", "median")).reset_index()
    stamp(summary, argv).to_csv(out / "sensor_maps_summary.csv", index=False)
    print(summary.round(4).to_string(index=False))


if __name__ == "__main__":
    main()
