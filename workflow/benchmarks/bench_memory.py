"""What peak memory does the whole workflow reach on one long truth/measured log?

Peak memory of the whole workflow on one long truth/measured log, per job and end to end.

For each ``--samples`` value this script

1. writes (once; reused when present) a clean simulated two-channel log under
   ``results/benchmarks/memory/``: a 1 kHz multisine, the truth on a 1/8-step grid and the
   measured channel a 12-bit encoder, in rad, as the CSV a lab would have (``t, truth,
   measured``, 17 significant digits: 146 MB for 3e6 samples; never commit it);
2. runs the workflow on it alone (``snakemake --cores 1``: one job at a time, so no two jobs'
   memory adds up) under GNU ``time -v``, whose maximum resident set size is the largest of
   Snakemake's own process and every job it ran;
3. reads each job's own peak (``max_rss`` of the rule's Snakemake benchmark file).

Rows go to ``results/benchmarks/performance.csv`` (section ``workflow``, one case per log
length; :func:`benchmarks.helpers.write_performance_section`), with the 1.5 GB target. A run that fails
(e.g. a refused log) is recorded with the one-line reason of its job log.

With ``--ingest-only`` only the ingest stage runs, in a child process under GNU ``time``
(for a log whose whole run takes too long to measure here).

Usage::

    PYTHONPATH=workflow nice python -m benchmarks.bench_memory --samples 3000000
    PYTHONPATH=workflow nice python -m benchmarks.bench_memory --samples 30000000 --ingest-only
"""
from __future__ import annotations

import argparse
import csv
import pathlib
import re
import shutil
import subprocess
import sys

import numpy as np
import yaml

from .helpers import RESULTS as OUT_DIR
from .helpers import ROOT, TARGET_RSS_MB, write_performance_section

WORK = OUT_DIR / "memory"
FS_HZ = 1000.0
STEP = 2 * np.pi / 4096


def ensure_log(path: pathlib.Path, n: int, seed: int) -> None:
    """A clean truth/measured CSV of ``n`` samples (written in blocks of 1e6 rows)."""
    if path.exists():
        return
    from enclab.residuals.simulate import random_motion

    rng = np.random.default_rng(seed)
    motion = random_motion(rng, "multisine", n / FS_HZ, 0.8)
    offset = rng.uniform(0.0, 1.0)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", encoding="utf-8") as handle:
        handle.write("t,truth,measured\n")
        for start in range(0, n, 1_000_000):
            t = np.arange(start, min(n, start + 1_000_000)) / FS_HZ
            theta = motion(t)
            truth = (STEP / 8) * np.round(theta / (STEP / 8))
            measured = STEP * np.floor(theta / STEP + offset)
            np.savetxt(handle, np.column_stack([t, truth, measured]), fmt=["%.6f", "%.17g", "%.17g"],
                       delimiter=",")
    tmp.replace(path)


def run_workflow(work: pathlib.Path, log: pathlib.Path, log_id: str) -> tuple[int, float, float, str]:
    """Run the workflow on one log; return (exit code, wall s, end-to-end peak MB, error)."""
    work.mkdir(parents=True, exist_ok=True)
    _write_inputs(work, log, log_id)
    snakemake = pathlib.Path(sys.executable).with_name("snakemake")
    command = ["/usr/bin/time", "-v", str(snakemake), "--snakefile", str(ROOT / "Snakefile"),
               "--directory", str(work), "--configfile", str(work / "config.yaml"),
               "--cores", "1", "--keep-going"]
    proc = subprocess.run(command, cwd=work, capture_output=True, text=True)
    peak, seconds = _gnu_time(proc.stderr)
    error = ""
    for path in sorted((work / "results" / log_id / "logs").glob("*.log")):
        for line in path.read_text(errors="replace").splitlines():
            if " ERROR " in line:
                error = line.split(" ERROR ", 1)[1].strip()
    return proc.returncode, seconds, peak, error


def _write_inputs(work: pathlib.Path, log: pathlib.Path, log_id: str) -> None:
    """The one-log manifest and the configuration naming it, in ``work``."""
    manifest = {"data_root": str(log.parent), "logs": [{
        "id": log_id, "file": log.name, "format": "csv", "device": "lrde_axis",
        "time": {"column": "t", "unit": "s"},
        "channels": [{"name": "truth", "column": "truth", "role": "truth", "joint": 1},
                     {"name": "measured", "column": "measured", "role": "measured", "joint": 1}]}]}
    (work / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["manifest"] = str(work / "manifest.yaml")
    (work / "config.yaml").write_text(yaml.safe_dump(config))


def run_ingest(work: pathlib.Path, log: pathlib.Path, log_id: str) -> tuple[int, float, float, str]:
    """The ingest stage alone in a child process under GNU time (for logs whose whole run is too
    long to measure here); same return as :func:`run_workflow`."""
    work.mkdir(parents=True, exist_ok=True)
    code = (
        "import sys, yaml\n"
        "from enclab.core.manifest import validate_manifest\n"
        "from enclab.core.ingest import ingest_to_canonical\n"
        f"config = yaml.safe_load(open({str(ROOT / 'config.yaml')!r}))\n"
        f"doc = yaml.safe_load(open({str(work / 'manifest.yaml')!r}))\n"
        "root, (entry,) = validate_manifest(doc, config['devices'], 'manifest.yaml')\n"
        f"ingest_to_canonical(entry, root, config['devices'], {str(work / 'canonical.parquet')!r})\n")
    _write_inputs(work, log, log_id)
    proc = subprocess.run(["/usr/bin/time", "-v", sys.executable, "-c", code], cwd=work,
                          capture_output=True, text=True)
    peak, seconds = _gnu_time(proc.stderr)
    lines = [line for line in proc.stderr.splitlines() if line.strip() and not line.startswith("\t")]
    return proc.returncode, seconds, peak, "" if proc.returncode == 0 else (lines[-1] if lines else "")


def _gnu_time(stderr: str) -> tuple[float, float]:
    """(maximum resident set size MB, wall seconds) of GNU ``time -v`` output."""
    peak = float(re.search(r"Maximum resident set size \(kbytes\): (\d+)", stderr).group(1)) / 1024
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", stderr).group(1)
    return peak, sum(float(x) * 60 ** i for i, x in enumerate(reversed(wall.split(":"))))


def job_peaks(work: pathlib.Path) -> list[tuple[str, float, float]]:
    """(job, max_rss MB, seconds) of every Snakemake benchmark file the run wrote."""
    rows = []
    for path in sorted((work / "results").rglob("benchmarks/*.tsv")):
        with open(path, encoding="utf-8") as handle:
            record = next(csv.DictReader(handle, delimiter="\t"))
        job = f"{path.parent.parent.name}/{path.stem}"
        rss = record.get("max_rss", "NA")
        rows.append((job, float(rss) if rss not in ("NA", "-") else float("nan"), float(record["s"])))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--samples", type=int, nargs="+", default=[3_000_000])
    p.add_argument("--seed", type=int, default=20261204)
    p.add_argument("--out", type=pathlib.Path, default=OUT_DIR / "performance.csv")
    p.add_argument("--keep", action="store_true", help="keep the run's results directory")
    p.add_argument("--ingest-only", action="store_true",
                   help="measure the ingest stage alone (a log whose whole run is too long here)")
    p.add_argument("--label", default="", help="added to the case, e.g. the package's commit when "
                   "PYTHONPATH points at another checkout")
    args = p.parse_args(argv)
    rows = []
    for n in args.samples:
        log_id = f"pair_{n}"
        log = WORK / "logs" / f"{log_id}.csv"
        log.parent.mkdir(parents=True, exist_ok=True)
        ensure_log(log, n, args.seed)
        work = WORK / "runs" / log_id
        shutil.rmtree(work, ignore_errors=True)
        case = f"truth+measured, {n:,} samples" + (f", {args.label}" if args.label else "")
        if args.ingest_only:
            code, seconds, peak, error = run_ingest(work, log, log_id)
            rows.append({"section": "workflow", "case": case, "stage": "ingest alone (GNU time)",
                         "n_samples": n, "n_joints": 1, "reps": 1, "median_s": round(seconds, 1),
                         "samples_per_s": round(n / seconds), "ratio_to_read": "",
                         "peak_rss_mb": round(peak), "target": "", "met": "",
                         "notes": f"{log.stat().st_size / 1e6:.0f} MB CSV; "
                                  + ("completed" if code == 0 else f"failed: {error}")})
            print(rows[-1])
            shutil.rmtree(work, ignore_errors=True)
            continue
        code, seconds, peak, error = run_workflow(work, log, log_id)
        note = "completed" if code == 0 else f"failed: {error}"
        rows.append({"section": "workflow", "case": case, "stage": "end to end (snakemake --cores 1)",
                     "n_samples": n, "n_joints": 1, "reps": 1, "median_s": round(seconds, 1),
                     "samples_per_s": round(n / seconds), "ratio_to_read": "",
                     "peak_rss_mb": round(peak), "target": TARGET_RSS_MB,
                     "met": bool(code == 0 and peak <= TARGET_RSS_MB), "notes": note})
        for job, rss, s in job_peaks(work):
            rows.append({"section": "workflow", "case": case, "stage": job, "n_samples": n,
                         "n_joints": 1, "reps": 1, "median_s": round(s, 1),
                         "samples_per_s": "", "ratio_to_read": "", "peak_rss_mb": round(rss),
                         "target": "", "met": "",
                         "notes": "the job's max_rss in its Snakemake benchmark file (sampled)"})
        for row in rows[-(1 + len(job_peaks(work))):]:
            print(f"{row['stage']:45s} {row['peak_rss_mb']:>7} MB {row['median_s']:>8} s {row['notes']}")
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    write_performance_section(rows, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
