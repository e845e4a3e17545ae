"""How fast and how lean are the quantization-error stages, against reading the same file?

Throughput, time and peak memory of the quantization-error stages, against reading the same file.

In ONE run this script

1. generates (once; reused when present) a long and a small simulated 7-joint Franka Panda log
   at 10 kHz (:func:`enclab.propagation.stream.franka_motion_chunks`, Parquet row groups of 1e6 rows,
   under ``results/benchmarks/``; never commit them);
2. section ``stages``, small log, in a child process: median of ``--reps`` repetitions of
   ``pyarrow.parquet.read_table`` and of each in-memory stage function the rules call
   (``requantize``, ``kinematics``, ``derivatives``, ``moments``: :mod:`enclab.propagation.analysis`,
   without their file I/O) and of the streamed moments (:func:`enclab.propagation.stream.empirical_rows`,
   all stages from the file);
3. section ``stream``, long log, each in its own child process: ``read_table`` of the whole
   file (median of ``--reps``; pyarrow decodes with every CPU), a streamed read that only
   decodes the pieces, and the streamed analysis end to end (``python -m enclab.propagation.stream
   moments``, once per ``--workers`` value: it is the long case), with its time per stage
   (summed over its worker processes).

Times are ratios to the ``read_table`` median of the *same file* measured in this run. Peak
memory is each child's own ``getrusage(RUSAGE_SELF).ru_maxrss`` (so one case's peak cannot
leak into another's); for a streamed run with worker processes, the sum of the parent's and
every worker's own peak (an upper bound of what was resident at once). The table is printed
and written to ``results/benchmarks/performance.csv``.

Other benchmarks append their own rows to the same CSV: every row has a ``section`` and a
``case``; a run replaces only the rows of the (section, case) pairs it measured, so
``--only stream`` keeps ``stages``, and any other section (e.g. ``batch`` or ``mcmc`` from
another script, which calls :func:`benchmarks.helpers.write_performance_section`) stays.

Usage::

    PYTHONPATH=workflow nice python -m benchmarks.bench_performance                 # 1 h log, full bank
    PYTHONPATH=workflow nice python -m benchmarks.bench_performance --duration-s 60 --only stream
    PYTHONPATH=workflow nice python -m benchmarks.bench_performance --long-bank export   # long run: 2 filters
    PYTHONPATH=workflow python -m benchmarks.bench_performance --long-bank export --workers 1 2
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import pandas as pd

from .helpers import RESULTS as OUT_DIR
from .helpers import ROOT, TARGET_RSS_MB, child_env, module_argv, write_performance_section

TARGET_RATIO = 4.0


def _config() -> dict:
    import yaml

    with open(ROOT / "config.yaml", encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def _bank(config: dict, which: str):
    from enclab.propagation import analysis
    from enclab.propagation import filters as flt

    if which == "config":
        return analysis.filter_bank(config["derivatives"])
    return [flt.DerivativeFilter.from_dict(dict(s)) for s in config["derivatives"]["export"]]


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _median_time(func, reps: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(reps):
        t0 = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


# ----------------------------------------------------------------------------- child workers


def worker_read(path: str, reps: int, chunk_rows: int) -> dict:
    """Whole-file ``read_table`` (median of reps) or, with ``chunk_rows > 0``, a streamed
    read that decodes every piece to pandas and drops it."""
    import pyarrow.parquet as pq
    from enclab.core import canonical

    if chunk_rows > 0:
        def once():
            _, _, pieces = canonical.iter_canonical(path, batch_rows=chunk_rows)
            return sum(len(p) for p in pieces)
    else:
        def once():
            return pq.read_table(path).num_rows
    median, n = _median_time(once, reps)
    return {"median_s": median, "n_samples": n, "peak_rss_mb": _peak_mb()}


def worker_stages(path: str, reps: int, bank_name: str, chunk_rows: int) -> dict:
    """In-memory stage functions on the small log (median of reps each)."""
    import pyarrow.parquet as pq
    from enclab.core import canonical
    from enclab.propagation import analysis, stream

    config = _config()
    derivatives, moments = config["derivatives"], config["moments"]
    bank = _bank(config, bank_name)
    out = {}
    out["read"], _ = _median_time(lambda: pq.read_table(path), reps)
    df, meta = canonical.read_canonical(path)
    levels = analysis.plan_levels(meta, config["requantize"])
    out["requantize"], req = _median_time(lambda: analysis.requantize(df, meta, levels), reps)
    out["kinematics"], kin = _median_time(
        lambda: analysis.kinematics_table(req, meta, levels), reps)
    out["derivatives"], _ = _median_time(
        lambda: analysis.export_derivatives(req, meta, levels, derivatives["export"]), reps)
    out["moments"], rows = _median_time(lambda: analysis.empirical_rows(
        req, kin, meta, levels, bank, derivatives["architectures"],
        settle_tol=derivatives["settle_tol"], ci_level=moments["ci_level"],
        n_batches=moments["n_batches"]), reps)

    def streamed():
        m, _, pieces = canonical.iter_canonical(path, batch_rows=chunk_rows)
        return stream.empirical_rows(pieces, m, levels, bank, derivatives["architectures"],
                                     settle_tol=derivatives["settle_tol"],
                                     ci_level=moments["ci_level"],
                                     n_batches=moments["n_batches"])
    out["stream_end_to_end"], srows = _median_time(streamed, reps)
    worst = max(abs(a["empirical"]["std"] / b["empirical"]["std"] - 1) for a, b in zip(srows, rows))
    return {"stages_s": out, "n_samples": int(meta["n_samples"]), "n_rows": len(rows),
            "stream_vs_memory_max_rel_std": worst, "peak_rss_mb": _peak_mb()}


def _child(args: list[str]) -> tuple[dict, float]:
    """Run this script as a worker; returns its JSON answer and its wall time."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as handle:
        answer = handle.name
    cmd = module_argv("bench_performance") + ["--worker-out", answer] + args
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=child_env())
    wall = time.perf_counter() - t0
    with open(answer, encoding="utf-8") as handle:
        out = json.load(handle)
    os.unlink(answer)
    return out, wall


# ----------------------------------------------------------------------------- the run


def ensure_log(path: pathlib.Path, duration_s: float, fs_hz: float, seed: int) -> float:
    """Generate the log unless a file with the same parameters exists; returns seconds."""
    from enclab.core import canonical
    from enclab.propagation import stream

    if path.exists():
        meta, _, _ = canonical.iter_canonical(path)
        params = (meta.get("source") or {}).get("params") or {}
        if params.get("duration_s") == duration_s and params.get("fs_hz") == fs_hz and \
                params.get("seed") == seed:
            return 0.0
    t0 = time.perf_counter()
    meta, chunks = stream.franka_motion_chunks(duration_s, fs_hz, seed, chunk_rows=1_000_000,
                                               log_id=path.stem)
    canonical.write_canonical_chunks(chunks, meta, path)
    return time.perf_counter() - t0


def _row(section, case, stage, n, seconds, read_s, reps, rss=None, target="", met="",
         notes="") -> dict:
    return {"section": section, "case": case, "stage": stage, "n_samples": n, "n_joints": 7,
            "reps": reps, "median_s": round(seconds, 4),
            "samples_per_s": round(n / seconds) if seconds > 0 else None,
            "ratio_to_read": round(seconds / read_s, 2) if read_s else None,
            "peak_rss_mb": None if rss is None else round(rss, 1), "target": target,
            "met": met, "notes": notes}


def run_stages(small: pathlib.Path, args) -> list[dict]:
    out, _ = _child(["--worker", "stages", str(small), "--reps", str(args.reps),
                     "--bank", args.bank, "--chunk-rows", str(args.chunk_rows)])
    n, s = out["n_samples"], out["stages_s"]
    case = f"small {args.small_duration_s:g} s log, in memory"
    rows = [_row("stages", case, "read_table", n, s["read"], s["read"], args.reps,
                 notes="pyarrow.parquet.read_table of the same file")]
    for stage in ("requantize", "kinematics", "derivatives", "moments"):
        note = {"derivatives": "export filters", "moments": f"bank={args.bank}, "
                f"{out['n_rows']} rows"}.get(stage, "")
        rows.append(_row("stages", case, stage, n, s[stage], s["read"], args.reps, notes=note))
    rows.append(_row("stages", f"small {args.small_duration_s:g} s log, streamed",
                     "stream_end_to_end", n, s["stream_end_to_end"], s["read"], args.reps,
                     rss=out["peak_rss_mb"],
                     notes=f"read+requantize+kinematics+filters+moments; worker peak RSS "
                           f"(all stages); max |std rel diff| vs in memory "
                           f"{out['stream_vs_memory_max_rel_std']:.1e}"))
    return rows


def run_stream(long: pathlib.Path, args) -> list[dict]:
    read, _ = _child(["--worker", "read", str(long), "--reps", str(args.reps)])
    n, read_s = read["n_samples"], read["median_s"]
    case = f"long {args.duration_s:g} s log at {args.fs_hz:g} Hz, bank={args.long_bank}"
    rows = [_row("stream", case, "read_table", n, read_s, read_s, args.reps,
                 rss=read["peak_rss_mb"], notes="whole file into memory (the baseline)")]
    piece, _ = _child(["--worker", "read", str(long), "--reps", "1", "--streamed",
                       "--chunk-rows", str(args.chunk_rows)])
    rows.append(_row("stream", case, "read_streamed", n, piece["median_s"], read_s, 1,
                     rss=piece["peak_rss_mb"],
                     notes=f"row groups in pieces of {args.chunk_rows} rows to pandas, "
                           f"nothing else, one process"))
    for workers in args.workers:
        with tempfile.TemporaryDirectory(dir=OUT_DIR) as tmp:
            timings = pathlib.Path(tmp) / "timings.json"
            cmd = [sys.executable, "-m", "enclab.propagation.stream", "moments", str(long),
                   str(pathlib.Path(tmp) / "moments.json"), "--configfile",
                   str(ROOT / "config.yaml"), "--bank", args.long_bank, "--chunk-rows",
                   str(args.chunk_rows), "--workers", str(workers), "--timings", str(timings)]
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True)
            wall = time.perf_counter() - t0
            t = json.loads(timings.read_text())
        label = f"{t['workers']} worker{'s' if t['workers'] > 1 else ''}"
        for stage, seconds in t["stages_s"].items():
            if stage != "other":
                rows.append(_row("stream", case, f"stream:{stage} ({label})", n, seconds,
                                 read_s, 1, notes="seconds inside the streamed run, summed "
                                                  "over its workers"))
        rss = t["peak_rss_mb"]
        rows.append(_row(
            "stream", case, f"stream_end_to_end ({label})", n, wall, read_s, 1, rss=rss,
            target=f"ratio <= {TARGET_RATIO:g}; peak <= {TARGET_RSS_MB:g} MB",
            met=f"time {'yes' if wall <= TARGET_RATIO * read_s else 'no'}; "
                f"memory {'yes' if rss <= TARGET_RSS_MB else 'no'}",
            notes=f"python -m enclab.propagation.stream moments --workers {workers}, bank={args.long_bank} "
                  f"({t['n_filters']} filters, {t['n_levels']} levels, {t['n_rows']} rows), "
                  f"chunk {args.chunk_rows}; wall time incl. interpreter start; peak = sum of "
                  f"the processes' own peaks when there are workers"))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--duration-s", type=float, default=3600.0, help="long log length")
    p.add_argument("--small-duration-s", type=float, default=10.0, help="small log length")
    p.add_argument("--fs-hz", type=float, default=10_000.0)
    p.add_argument("--seed", type=int, default=20261128)
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--bank", choices=("config", "export"), default="config")
    p.add_argument("--long-bank", choices=("config", "export"),
                   help="filters of the long streamed run (default: --bank)")
    p.add_argument("--chunk-rows", type=int, default=16_384)
    p.add_argument("--workers", type=int, nargs="+", default=[0],
                   help="worker processes of the long streamed run, one run per value "
                        "(0: one per CPU, the command's default)")
    p.add_argument("--only", choices=("stages", "stream"), help="run one section only")
    p.add_argument("--out", type=pathlib.Path, default=OUT_DIR / "performance.csv")
    # internal: child workers
    p.add_argument("--worker", choices=("read", "stages"))
    p.add_argument("path", nargs="?")
    p.add_argument("--worker-out")
    p.add_argument("--streamed", action="store_true")
    args = p.parse_args(argv)

    if args.worker == "read":
        out = worker_read(args.path, args.reps, args.chunk_rows if args.streamed else 0)
    elif args.worker == "stages":
        out = worker_stages(args.path, args.reps, args.bank, args.chunk_rows)
    if args.worker:
        pathlib.Path(args.worker_out).write_text(json.dumps(out))
        return 0

    args.long_bank = args.long_bank or args.bank
    if args.reps < 1:
        p.error("--reps must be >= 1")
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    load_start = os.getloadavg()
    sections = {args.only} if args.only else {"stages", "stream"}
    tag = f"{args.fs_hz:g}hz_seed{args.seed}"
    rows = []
    if "stages" in sections:
        small = OUT_DIR / f"franka_{args.small_duration_s:g}s_{tag}.parquet"
        ensure_log(small, args.small_duration_s, args.fs_hz, args.seed)
        rows += run_stages(small, args)
    if "stream" in sections:
        long = OUT_DIR / f"franka_{args.duration_s:g}s_{tag}.parquet"
        gen_s = ensure_log(long, args.duration_s, args.fs_hz, args.seed)
        if gen_s:
            print(f"generated {long} in {gen_s:.1f} s", file=sys.stderr)
        rows += run_stream(long, args)
    load_end = os.getloadavg()
    load_note = f"load avg (1 min) {load_start[0]:.1f} at start, {load_end[0]:.1f} at end"
    for row in rows:
        row["notes"] = f"{row['notes']}; {load_note}" if row["notes"] else load_note
    table = write_performance_section(rows, args.out)
    with pd.option_context("display.max_columns", None, "display.width", 250,
                           "display.max_colwidth", 60):
        print(table.drop(columns=["notes"]).to_string(index=False))
    print(f"\nwritten: {args.out}  ({load_note})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
