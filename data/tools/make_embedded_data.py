"""Regenerate the embedded default data set and its manifest (data/sim/, data/manifest.yaml).

Simulated Phantom Premium 1.5 runs of paper 000's Section IV protocol (1 kHz, 15 s, 3 deg
sinusoids at distinct frequencies within 0.1 Hz of 5 Hz, truth at the robot's 0.125 mrad
resolution), written as ordinary logs: a Parquet table with a time column in seconds and one
int64 counts column per joint. Every run of one centre configuration shares a repeat group, so
the batch stage pools them as a lab pools repeated runs. Two paper-002 logs of an extreme
low-resolution encoder, and two two-channel logs for the residual stage (a motor encoder through
a gearbox against an output encoder: one with backlash, one clean).

Deterministic: the same seed gives byte-identical logs. Usage (from the repository root)::

    .venv/bin/python data/tools/make_embedded_data.py            # the committed default
    .venv/bin/python data/tools/make_embedded_data.py --help
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from enclab.core import atomic
from enclab.core.quantize import quantize
from enclab.lrde import simulate as lrde_sim
from enclab.propagation.simulate import fig6_configurations_deg, phantom_protocol_run
from enclab.residuals.effects import play_operator

ROOT = Path(__file__).resolve().parents[2]
TRUTH_STEP = 1.25e-4
# A lab centres the arm to within about a millimetre-radian and the encoder's zero is arbitrary,
# so the sub-step position of the motion on the coarse grid differs from run to run. It matters:
# with a constant amplitude every cycle turns around at the same place on the grid, and one run's
# derivative-noise std depends on that place by -2.5 % to +1.4 % (d1 n1 fc200) and by -9 % to
# +11 % (d1 n3 fc25); the exact model predicts the average over the sub-step position. A repeat
# group therefore spreads each joint's runs evenly over one coarse step (one random offset per
# joint, runs in a random order), so that its pooled runs estimate that average rather than a
# random draw of it: over 20 runs the pooled ratio scatters by 0.05 % (d1 n1) and 0.5 % (n3
# fc25, 1 sd) instead of 0.25 % and 1.1 % with independent uniform centres
# (workflow/benchmarks/grid_alignment.py, docs/quantization-error.md).
CENTRE_JITTER = 1e-3


def systematic_centres(rng: np.random.Generator, runs: int, joints: int, width: float) -> np.ndarray:
    """``(runs, joints)`` offsets in ``[-width/2, width/2)``, evenly spaced ``width/runs`` apart
    for each joint with one uniform random offset per joint, in a random order over the runs
    (independently per joint), so every offset is marginally uniform."""
    order = np.stack([rng.permutation(runs) for _ in range(joints)], axis=1)
    return ((order + rng.uniform(size=joints)) / runs - 0.5) * width


def phantom_entries(out_dir: Path, seed: int, fig6_repeats: int, fig7_repeats: int,
                    steps: list[float]) -> list[dict]:
    entries = []
    configs = fig6_configurations_deg()
    streams = np.random.SeedSequence(seed).spawn(len(configs))
    for c, (centre_deg, stream) in enumerate(zip(configs, streams)):
        repeats = fig7_repeats if c == 0 else fig6_repeats
        group = f"phantom_c{c:02d}"
        run_seeds = stream.spawn(repeats)
        centres = systematic_centres(np.random.default_rng(stream.spawn(1)[0]), repeats, 3,
                                     CENTRE_JITTER)
        for r, (run_seed, jitter) in enumerate(zip(run_seeds, centres), start=1):
            rng = np.random.default_rng(run_seed)
            log, truth = phantom_protocol_run(np.deg2rad(centre_deg) + jitter, rng)
            name = f"{group}_r{r:02d}"
            atomic.write_table(log, out_dir / f"{name}.parquet")
            freqs = ", ".join(f"{f:.4f}" for f in truth["freqs_hz"])
            entries.append({
                "id": name,
                "file": f"sim/{name}.parquet",
                "format": "parquet",
                "description": (f"Simulated Phantom Premium 1.5, centre ({', '.join(f'{v:g}' for v in centre_deg)}) deg, "
                                f"(+ {', '.join(f'{1e3 * v:+.3f}' for v in jitter)} mrad), 3 deg sinusoids at ({freqs}) Hz, "
                                "truth at 0.125 mrad"),
                "group": group,
                "tags": ["simulated", "phantom", "fig7" if c == 0 else "fig6"],
                "provenance": "enclab data/tools/make_embedded_data.py (seed %d); protocol of "
                              "Colonnese & Okamura, Section IV" % seed,
                "device": "phantom_premium_1_5",
                "time": {"column": "t", "unit": "s", "nominal_rate_hz": 1000.0},
                "channels": [
                    {"name": f"theta{j}", "column": f"theta{j}_counts", "role": "truth",
                     "joint": j, "unit": "counts", "step": TRUTH_STEP}
                    for j in (1, 2, 3)
                ],
                "analysis": {"requantize": {"steps": steps}},
            })
    return entries


def lrde_entries(out_dir: Path, seed: int) -> list[dict]:
    """Paper 002 logs: the Ros-Drill encoder (0.09 deg) on a 0.31 deg stroke, open loop and in a
    PID loop, each with a fine truth encoder (step/100) that identifies the offset and the bias.
    """
    step = lrde_sim.ROS_DRILL_STEP
    truth_step = step / 100
    open_rng, closed_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    open_log, open_p = lrde_sim.open_loop_log(open_rng, bias=0.12 * step, n_cycles=20,
                                              noise_std=0.01 * step, truth_step=truth_step)
    closed_log, closed_p = lrde_sim.closed_loop_pid_log(closed_rng, n_cycles=60,
                                                        truth_step=truth_step)
    runs = [
        ("lrde_open_r01", open_log, open_p, None,
         "open-loop 20 Hz sinusoid, A12 %.4f deg, bias %.4f deg, offset %.4f deg, E_b %.4f deg"
         % tuple(np.rad2deg([open_p["A12"], open_p["bias"], open_p["offset_a"], open_p["E_b"]]))),
        # The PID loop starts at rest; its first 0.5 s (10 cycles) are the pull-in transient.
        ("lrde_closed_r01", closed_log, closed_p, {"t_start": 0.5, "t_end": None},
         "PID loop tracking a 0.145 deg, 20 Hz sinusoid with the coarse encoder as feedback, "
         "offset %.4f deg" % np.rad2deg(closed_p["offset_a"])),
    ]
    entries = []
    for name, log, params, crop, description in runs:
        atomic.write_table(log, out_dir / f"{name}.parquet")
        entries.append({
            "id": name,
            "file": f"sim/{name}.parquet",
            "format": "parquet",
            "description": f"Simulated extreme low-resolution encoder (0.09 deg): {description}",
            "group": name.rsplit("_", 1)[0],
            "tags": ["simulated", "lrde"],
            "provenance": "enclab data/tools/make_embedded_data.py (seed %d); Ros-Drill example "
                          "of Zhang & Gao" % seed,
            "device": "lrde_axis",
            "crop": crop,
            "time": {"column": "t", "unit": "s", "nominal_rate_hz": float(params["fs_hz"])},
            "channels": [
                {"name": "coarse", "column": "counts", "role": "measured", "joint": 1,
                 "unit": "counts", "step": step},
                {"name": "fine", "column": "truth_counts", "role": "truth", "joint": 1,
                 "unit": "counts", "step": truth_step},
            ],
            "analysis": {"stages": ["lrde"]},
        })
    return entries


def residual_entries(out_dir: Path, seed: int) -> list[dict]:
    """Two-channel logs for the residual stage: a motor encoder through a gearbox (the fine
    truth) and an 8192-cpr output encoder (the measured channel, its counter zero arbitrary),
    1 Hz, 20 deg sine for 6 s at 1 kHz. One with gear backlash (0.012 rad of play between motor
    and output), one clean control. Nothing about the effect is declared in the manifest.
    """
    cpr_motor, gear, cpr_out = 4000, 23, 8192
    motor_step = 2 * np.pi / (cpr_motor * gear)
    out_step = 2 * np.pi / cpr_out
    t = np.arange(6000) / 1000.0
    entries = []
    runs = [("res_backlash_r01", 0.012, "gear backlash: 0.012 rad of play between motor and output"),
            ("res_clean_r01", 0.0, "clean control: the output encoder reads the motor angle exactly")]
    for (name, width, description), ss in zip(runs, np.random.SeedSequence(seed).spawn(len(runs))):
        rng = np.random.default_rng(ss)
        theta = np.deg2rad(20.0) * np.sin(2 * np.pi * 1.0 * t + rng.uniform(0, 2 * np.pi)) \
            + rng.uniform(0, out_step) + rng.normal(0, 1e-6, t.size)
        load = play_operator(theta, width) if width else theta
        zero = int(rng.integers(-5000, 5000))
        log = pd.DataFrame({"t": t,
                            "motor_counts": quantize(theta, motor_step),
                            "output_counts": quantize(load, out_step, 0.0) + zero})
        atomic.write_table(log, out_dir / f"{name}.parquet")
        entries.append({
            "id": name,
            "file": f"sim/{name}.parquet",
            "format": "parquet",
            "description": f"Simulated motor and output encoders on one geared axis; {description}",
            "group": None,
            "tags": ["simulated", "residuals"],
            "provenance": "enclab data/tools/make_embedded_data.py (seed %d)" % seed,
            "device": {"kind": "single_joint"},
            "time": {"column": "t", "unit": "s", "nominal_rate_hz": 1000.0},
            "channels": [
                {"name": "motor", "column": "motor_counts", "role": "truth", "joint": 1,
                 "unit": "counts", "counts_per_rev": cpr_motor, "gear_ratio": gear},
                {"name": "output", "column": "output_counts", "role": "measured", "joint": 1,
                 "unit": "counts", "counts_per_rev": cpr_out},
            ],
        })
    return entries


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=20261122)
    parser.add_argument("--fig6-repeats", type=int, default=8,
                        help="runs per Fig. 6 configuration other than zero (default 8)")
    parser.add_argument("--fig7-repeats", type=int, default=20,
                        help="runs at the zero configuration, pooled for Fig. 7 (default 20)")
    parser.add_argument("--steps", type=float, nargs="+", default=[1e-3],
                        help="re-quantization steps [rad] of the simulated logs (default 1e-3)")
    args = parser.parse_args(argv)
    sim_dir = ROOT / "data" / "sim"
    sim_dir.mkdir(parents=True, exist_ok=True)
    for old in [*sim_dir.glob("phantom_*.parquet"), *sim_dir.glob("lrde_*.parquet"),
                *sim_dir.glob("res_*.parquet")]:
        old.unlink()
    entries = phantom_entries(sim_dir, args.seed, args.fig6_repeats, args.fig7_repeats, args.steps)
    entries += lrde_entries(sim_dir, args.seed + 1)
    entries += residual_entries(sim_dir, args.seed + 2)
    static = ROOT / "data" / "tools" / "manifest_static.yaml"
    if static.exists():
        entries += yaml.safe_load(static.read_text())["logs"]
    header = ("# Embedded default manifest, generated by data/tools/make_embedded_data.py; edit that\n"
              "# tool (or data/tools/manifest_static.yaml), not this file.\n")
    text = header + yaml.safe_dump({"data_root": "data", "logs": entries}, sort_keys=False, width=100)
    atomic.write_text(text, ROOT / "data" / "manifest.yaml")
    print(f"wrote {len(entries)} manifest entries, {len(list(sim_dir.glob('*.parquet')))} simulated logs")


if __name__ == "__main__":
    main()
