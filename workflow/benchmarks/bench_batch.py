"""How much do the Snakemake jobs cost per log on a batch of many small logs?

Per-log overhead of the Snakemake jobs on a batch of many small logs.

Generates N simulated Phantom runs (Colonnese & Okamura protocol: 3 joints, 1 kHz, 15 s by
default, ``enclab.propagation.simulate.phantom_protocol_run``), a manifest and a configuration in a
temporary workspace, then measures, in one run of this script:

- ``in-process``: the quantization-error stages of every log called one after the other in one Python
  (``enclab.propagation.pipeline.quantization_log`` through ``enclab.runner.run_chunk``, the same calls and
  files as the workflow): the compute the workflow cannot avoid;
- ``in-process xC``: the same, split into C Pythons running side by side (one share of the logs
  each): what the compute alone costs when C processes share the machine, as the workflow's
  jobs do (memory bandwidth, caches, a busy host's other work);
- each requested workflow mode, ``snakemake --cores C`` with the default workflow profile (as
  ``make run`` runs it) to every log's ``summary.json`` and ``derivatives.parquet`` (no figures,
  no MCMC): ``per-rule`` (``chunk_size=0``, one job per stage and log) and ``batched``
  (``chunk_size=K``, one job per K logs plus a publishing shell job per log).

Columns of ``results/benchmarks/batch_overhead.csv`` (times in s):

``wall_s``, ``wall_per_log_s``
    Elapsed time of the whole run, and divided by N.
``cpu_per_log_s``
    CPU time (user + system) of the process and all its children, divided by N.
``overhead_cpu_per_log_s``
    ``(cpu - cpu of in-process) / N``: the work each log costs on top of its compute (Python
    starts, imports, Snakemake's bookkeeping, extra file copies). The issue's target
    (<= 0.5 s) is checked on it and, where measured, on ``own_cpu_per_log_s`` (the figure the
    ``batch`` rows of ``performance.csv`` give): two runs of the same work differ in CPU time
    on a shared machine, so this difference can come out below zero.
``overhead_wall_per_log_s``
    ``(wall - wall of in-process / cores) / N``: the elapsed time per log beyond the ideal
    parallel compute. On a loaded machine the cores are not all ours, which inflates it.
``overhead_cpu_vs_parallel_per_log_s``
    ``(cpu - cpu of in-process xC) / N``: the overhead without the compute's own slow-down from
    sharing the machine, which no change to the workflow removes.
``snakemake_cpu_s``, ``jobs_cpu_s``, ``chunk_jobs_cpu_s``, ``stages_in_jobs_cpu_s``
    Where a workflow run's CPU goes: the Snakemake process itself (DAG, scheduling, per-job
    bookkeeping), every job it started (and the ILP scheduler's solver processes, if used),
    of these the ``process_chunk`` jobs (each logs its own CPU time), and inside those the
    stages of each log (``run_chunk`` logs each log's CPU time); batched mode only.
``own_cpu_per_log_s``
    ``(cpu - stages_in_jobs_cpu) / N``: the CPU of everything but the stages' own work, from
    one run alone (no reference run, so no run-to-run difference in how fast the same work
    goes on a shared machine); batched mode only.

Every mode's ``summary.json`` files are compared with the in-process ones (SHA-256): a mode
whose outputs differ is reported as such (``identical`` column).

Usage::

    PYTHONPATH=workflow nice python -m benchmarks.bench_batch               # N=500, both modes
    PYTHONPATH=workflow nice python -m benchmarks.bench_batch --n 100 --modes batched
"""
from __future__ import annotations

import argparse
import hashlib
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from .helpers import ROOT, child_env, module_argv, write_performance_section

SMALL_BANK = {"d": [1, 2], "n": [1, 2], "fc_hz": [50, 100],
              "discretization": ["exponential", "bilinear"]}
MODES = ("per-rule", "batched")
PROFILE = ROOT / "workflow/profiles/default"
# Snakemake's own CPU time apart from its jobs': its main() in a Python that writes its
# RUSAGE_SELF (every thread) to argv[1] on exit. Kept free of this module's imports.
SNAKEMAKE_WITH_CPU = """\
import resource, sys
from snakemake.cli import main
try:
    main(sys.argv[2:])
finally:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    with open(sys.argv[1], "w") as handle:
        handle.write(f"{usage.ru_utime + usage.ru_stime}\\n")
"""
# enclab.runner's last line of a job's log, and run_chunk's line for each log of a chunk.
CHUNK_CPU = re.compile(r" INFO done in [0-9.]+ s, ([0-9.]+) s CPU$", re.MULTILINE)
LOG_CPU = re.compile(r" INFO \[[^]]+\] done in [0-9.]+ s, ([0-9.]+) s CPU$", re.MULTILINE)


def _entry(log_id: str) -> dict:
    """A simulated Phantom run (truth counts of 0.125 mrad) re-quantized at 1 mrad."""
    return {"id": log_id, "file": f"{log_id}.parquet", "format": "parquet",
            "device": "phantom_premium_1_5", "group": "bench",
            "time": {"column": "t", "unit": "s", "nominal_rate_hz": 1000.0},
            "channels": [{"name": f"theta{j}", "column": f"theta{j}_counts", "role": "truth",
                          "joint": j, "unit": "counts", "step": 1.25e-4} for j in (1, 2, 3)],
            "analysis": {"requantize": {"steps": [1e-3]}}}


def make_workspace(work: Path, n: int, duration_s: float, bank: str, seed: int) -> list[str]:
    """N logs under work/logs, work/manifest.yaml and work/config.yaml; returns the log ids."""
    from enclab.core import atomic
    from enclab.propagation.simulate import phantom_protocol_run

    data = work / "logs"
    data.mkdir(parents=True)
    streams = np.random.SeedSequence(seed).spawn(n)
    ids = [f"log{k:04d}" for k in range(n)]
    for log_id, stream in zip(ids, streams):
        rng = np.random.default_rng(stream)
        centre = rng.uniform(-0.3, 0.3, size=3)
        log, _ = phantom_protocol_run(centre, rng, duration_s=duration_s)
        atomic.write_table(log, data / f"{log_id}.parquet")
    (work / "manifest.yaml").write_text(yaml.safe_dump(
        {"data_root": "logs", "logs": [_entry(i) for i in ids]}))
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["manifest"] = "manifest.yaml"
    if bank == "small":
        config["derivatives"]["bank"] = dict(SMALL_BANK)
    config["figures"]["fig7_group"] = "bench"
    (work / "config.yaml").write_text(yaml.safe_dump(config))
    return ids


def in_process(work: Path, out: Path, share: int = 0, shares: int = 1) -> None:
    """Every log's stages in this one Python (called in a child process by :func:`main`), or
    the ``share``-th of ``shares`` contiguous parts of the logs."""
    from enclab.propagation import pipeline
    from enclab.core import manifest, readers
    from enclab.runner import run_chunk

    config = yaml.safe_load((work / "config.yaml").read_text())
    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    manifest.check_document(config, schema, "config", "config.schema.yaml")
    os.chdir(work)
    data_root, entries = readers.read_manifest(config["manifest"], devices=config["devices"])
    size = math.ceil(len(entries) / shares)
    entries = entries[share * size:(share + 1) * size]
    status = run_chunk(entries, lambda e, folder: pipeline.quantization_log(e, folder, config,
                                                                          data_root), out)
    failed = [k for k, v in status.items() if v is not None]
    if failed:
        raise SystemExit(f"in-process run: {len(failed)} logs failed, e.g. {status[failed[0]]}")


def _timed(commands: list[list[str]], cwd: Path, logs: list[Path]) -> tuple[float, float, int]:
    """Wall and CPU (user + system of all children) of commands run side by side; their
    output goes to logs; the largest exit code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    handles = [open(log, "w") for log in logs]
    procs = [subprocess.Popen(command, cwd=cwd, stdout=handle, stderr=subprocess.STDOUT,
                              env=child_env(MPLBACKEND="Agg"))
             for command, handle in zip(commands, handles)]
    codes = [proc.wait() for proc in procs]
    wall = time.perf_counter() - start
    for handle in handles:
        handle.close()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, max(codes)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _jobs(log: Path) -> int | None:
    done = re.findall(r"(\d+) of (\d+) steps", log.read_text())
    return int(done[-1][1]) if done else None


def write_performance_rows(table: pd.DataFrame, path: Path) -> None:
    """The ``batch`` section of the project's performance table (bench_performance.py)."""
    rows = []
    for _, r in table.iterrows():
        workflow = not r["mode"].startswith("in-process")
        # A run's own non-stage CPU when it was measured (batched), else the difference to
        # the in-process run, which on a shared machine can come out below zero.
        own = r.get("own_cpu_per_log_s")
        measured = own if workflow and pd.notna(own) else (
            r["overhead_cpu_per_log_s"] if workflow else r["cpu_per_log_s"])
        rows.append({
            "section": "batch", "case": f"{int(r['n_logs'])} logs x {r['log_s']:g} s, "
                                        f"{r['mode']} (chunk {int(r['chunk_size'])})",
            "stage": "overhead per log" if workflow else "compute", "n_samples": None,
            "n_joints": 3, "reps": 1,
            "median_s": round(float(measured), 4),
            "samples_per_s": None, "ratio_to_read": None, "peak_rss_mb": None,
            "target": "overhead <= 0.5 s CPU per log" if workflow else "",
            "met": ("yes" if r["target_met"] else "no") if workflow else "",
            "notes": (("CPU s per log outside the stages (own_cpu_per_log_s); vs the in-process "
                       f"run {r['overhead_cpu_per_log_s']:.3f} s; " if workflow and pd.notna(own)
                       else "CPU s per log; ")
                      + f"wall {r['wall_per_log_s']:.3f} s per log, {int(r['jobs'])} "
                      f"jobs, outputs identical: {r['identical']}, {int(r['cores'])} cores, "
                      f"load {r['loadavg_1min']}")})
    write_performance_section(rows, path)


def main(argv: list[str] | None = None) -> pd.DataFrame:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=500, help="number of logs (default 500)")
    parser.add_argument("--duration", type=float, default=15.0, help="log length in s")
    parser.add_argument("--modes", default=",".join(MODES), help="per-rule,batched")
    parser.add_argument("--chunk-size", type=int, default=0,
                        help="logs per job in batched mode (default: N / (4 cores), >= 1)")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--bank", choices=["small", "full"], default="small",
                        help="derivative filter bank: small (16 filters, as the workflow "
                             "tests) or full (config.yaml's 48)")
    parser.add_argument("--seed", type=int, default=20261128)
    parser.add_argument("--out", type=Path, default=ROOT / "results/benchmarks/batch_overhead.csv")
    parser.add_argument("--keep", type=Path, default=None, help="keep the workspace here")
    parser.add_argument("--in-process", nargs=2, type=Path, metavar=("WORK", "OUT"),
                        help=argparse.SUPPRESS)
    parser.add_argument("--share", nargs=2, type=int, default=(0, 1), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.in_process:
        in_process(*args.in_process, *args.share)
        return pd.DataFrame()
    modes = [m for m in args.modes.split(",") if m]
    unknown = sorted(set(modes) - set(MODES))
    if unknown:
        parser.error(f"unknown mode(s) {unknown}; expected some of {list(MODES)}")
    chunk = args.chunk_size or max(1, math.ceil(args.n / (4 * args.cores)))

    work = Path(tempfile.mkdtemp(prefix="bench_batch_")) if args.keep is None else args.keep
    work.mkdir(parents=True, exist_ok=True)
    ids = make_workspace(work, args.n, args.duration, args.bank, args.seed)
    load = [os.getloadavg()[0]]
    rows = []

    wall, cpu, rc = _timed([module_argv("bench_batch") + ["--in-process", str(work),
                             str(work / "in_process")]], ROOT, [work / "in_process.log"])
    if rc != 0:
        raise SystemExit(f"in-process run failed, see {work / 'in_process.log'}")
    reference = {i: _digest(work / "in_process" / i / "summary.json") for i in ids}
    compute_wall, compute_cpu = wall, cpu
    rows.append({"mode": "in-process", "chunk_size": args.n, "jobs": 0, "wall_s": wall,
                 "cpu_s": cpu, "identical": True})
    load.append(os.getloadavg()[0])

    parallel = [work / f"in_process_{k}" for k in range(args.cores)]
    wall, cpu, rc = _timed([module_argv("bench_batch") + ["--in-process", str(work), str(out),
                             "--share", str(k), str(args.cores)]
                            for k, out in enumerate(parallel)], ROOT,
                           [out.with_suffix(".log") for out in parallel])
    if rc != 0:
        raise SystemExit(f"in-process x{args.cores} run failed, see {parallel[0]}.log")
    identical = all(_digest(out / i / "summary.json") == reference[i]
                    for out in parallel for i in ids if (out / i).exists())
    compute_parallel_cpu = cpu
    rows.append({"mode": f"in-process x{args.cores}", "chunk_size": math.ceil(args.n / args.cores),
                 "jobs": 0, "wall_s": wall, "cpu_s": cpu, "identical": identical})
    load.append(os.getloadavg()[0])

    # The chunked mode also writes every log's derivatives.parquet (the per-stage mode only
    # for the logs with figures): ask both modes for it, so that they do the same work.
    n = args.n
    targets = [f"results/{i}/{name}" for i in ids for name in ("summary.json",
                                                                "derivatives.parquet")]
    for mode in modes:
        size = chunk if mode == "batched" else 0
        own_cpu = work / f"snakemake_{mode}.cpu"
        command = [sys.executable, "-c", SNAKEMAKE_WITH_CPU, str(own_cpu),
                   "--snakefile", str(ROOT / "Snakefile"), "--workflow-profile", str(PROFILE),
                   "--directory", str(work), "--configfile", str(work / "config.yaml"),
                   "--cores", str(args.cores), "--config", f"chunk_size={size}", "--", *targets]
        shutil.rmtree(work / "results", ignore_errors=True)
        shutil.rmtree(work / ".snakemake", ignore_errors=True)
        log = work / f"snakemake_{mode}.log"
        wall, cpu, rc = _timed([command], work, [log])
        if rc != 0:
            raise SystemExit(f"{mode}: snakemake failed (exit {rc}), see {log}")
        identical = all(_digest(work / "results" / i / "summary.json") == reference[i]
                        for i in ids)
        snakemake_cpu = float(own_cpu.read_text())
        chunk_logs = [path.read_text() for path in
                      sorted((work / "results/logs/chunks").glob("chunk*.log"))]
        chunk_cpu = [float(m.group(1)) for text in chunk_logs
                     for m in [CHUNK_CPU.search(text)] if m]
        stages_cpu = [float(m) for text in chunk_logs for m in LOG_CPU.findall(text)]
        if len(chunk_cpu) != len(chunk_logs) or (chunk_logs and len(stages_cpu) != n):
            raise SystemExit(f"{mode}: {len(chunk_cpu)} CPU times of {len(chunk_logs)} chunk "
                             f"jobs and {len(stages_cpu)} of {n} logs in their logs")
        rows.append({"mode": mode, "chunk_size": size, "jobs": _jobs(log), "wall_s": wall,
                     "cpu_s": cpu, "identical": identical, "snakemake_cpu_s": snakemake_cpu,
                     "jobs_cpu_s": cpu - snakemake_cpu,
                     "chunk_jobs_cpu_s": sum(chunk_cpu) if chunk_logs else np.nan,
                     "stages_in_jobs_cpu_s": sum(stages_cpu) if chunk_logs else np.nan})
        load.append(os.getloadavg()[0])

    table = pd.DataFrame(rows)
    table.insert(1, "n_logs", n)
    table.insert(2, "log_s", args.duration)
    table["cores"] = args.cores
    table["wall_per_log_s"] = table["wall_s"] / n
    table["cpu_per_log_s"] = table["cpu_s"] / n
    table["overhead_cpu_per_log_s"] = (table["cpu_s"] - compute_cpu) / n
    table["overhead_wall_per_log_s"] = (table["wall_s"] - compute_wall / args.cores) / n
    table["overhead_cpu_vs_parallel_per_log_s"] = (table["cpu_s"] - compute_parallel_cpu) / n
    table["own_cpu_per_log_s"] = (table["cpu_s"] - table["stages_in_jobs_cpu_s"]) / n
    table.loc[table["mode"].str.startswith("in-process"),
              ["overhead_cpu_per_log_s", "overhead_wall_per_log_s",
               "overhead_cpu_vs_parallel_per_log_s"]] = np.nan
    table["target_met"] = [None if np.isnan(v) else bool(v <= 0.5 and not own > 0.5)
                           for v, own in zip(table["overhead_cpu_per_log_s"],
                                             table["own_cpu_per_log_s"])]
    table["bank"] = args.bank
    table["loadavg_1min"] = ",".join(f"{x:.1f}" for x in load)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.round(4).to_csv(args.out, index=False)
    write_performance_rows(table, args.out.parent / "performance.csv")
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(table.round(3).to_string(index=False))
    print(f"written {args.out}; workspace {work}"
          + ("" if args.keep else " (removed)"))
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)
    return table


if __name__ == "__main__":
    main()
