"""How long does a newcomer's first ``make run`` (and ``make test``) take on a fresh clone?

A newcomer's first run: ``make run`` (and optionally ``make test``) on a fresh clone.

Clones the repository (``--repo``, default this one) at ``--commit`` (default HEAD) into a
temporary folder and times ``make run`` there, as a new user runs it: the virtual environment
and the pinned install included. The phases come from the files the run writes (the install
stamp, Snakemake's log, the report). Run it on an otherwise quiet machine: the full run is ~5-15
CPU-minutes.

Rows appended to ``results/benchmarks/first_run.csv`` (times in s): ``date``, ``machine``,
``command``, ``commit``, ``target`` (``run`` / ``test``), ``wall_s``, ``install_s``,
``workflow_s`` (first Snakemake start to the last Snakemake log line before the report),
``report_s``, ``report_mb``, ``jobs`` (of the workflow pass), ``exit_code``, ``load_start``,
``load_end`` (1-minute load average).

Usage::

    PYTHONPATH=workflow python -m benchmarks.bench_first_run
    PYTHONPATH=workflow python -m benchmarks.bench_first_run --commit 40d78c3 --test
    PYTHONPATH=workflow python -m benchmarks.bench_first_run --quick   # 4 logs, ~1 CPU-minute
    PYTHONPATH=workflow python -m benchmarks.bench_first_run --smk-args '--set-threads lrde_fit=1'
"""
from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .helpers import ROOT

QUICK_LOGS = "[phantom_c00_r01,phantom_c01_r01,res_clean_r01,lrde_open_r01]"
_STAMP = re.compile(r"^\[(\w{3} \w{3} +\d+ \d\d:\d\d:\d\d \d{4})\]$")


def _machine() -> str:
    return f"{platform.node()} ({os.cpu_count()} cores, {platform.machine()})"


def _load() -> float:
    return os.getloadavg()[0]


def _snakemake_span(clone: Path) -> tuple[float | None, int | None]:
    """Seconds from the first to the last time stamp of the first Snakemake log (the workflow
    pass), and its number of jobs."""
    logs = sorted((clone / ".snakemake/log").glob("*.snakemake.log"))
    if not logs:
        return None, None
    text = logs[0].read_text(errors="replace")
    stamps = [datetime.datetime.strptime(m.group(1), "%a %b %d %H:%M:%S %Y")
              for m in map(_STAMP.match, text.splitlines()) if m]
    jobs = re.search(r"^total\s+(\d+)$", text, flags=re.M)
    span = (stamps[-1] - stamps[0]).total_seconds() if len(stamps) > 1 else None
    return span, int(jobs.group(1)) if jobs else None


def measure(repo: Path, commit: str, target: str, quick: bool, keep: bool,
            smk_args: str = "") -> dict:
    work = Path(tempfile.mkdtemp(prefix="enclab-first-run-"))
    clone = work / "clone"
    subprocess.run(["git", "clone", "-q", str(repo), str(clone)], check=True)
    subprocess.run(["git", "-C", str(clone), "checkout", "-q", commit], check=True)
    rev = subprocess.run(["git", "-C", str(clone), "rev-parse", "--short", "HEAD"], check=True,
                         capture_output=True, text=True).stdout.strip()
    command = ["make", target]
    if quick and target == "run":
        command.append(f"CONFIG=only_logs={QUICK_LOGS}")
    if smk_args and target == "run":
        command.append(f"SMK_ARGS={smk_args}")
    load_start, start = _load(), time.time()
    with open(work / f"make_{target}.out", "w") as out:
        done = subprocess.run(command, cwd=clone, stdout=out, stderr=subprocess.STDOUT)
    wall = time.time() - start
    stamp = clone / ".venv/.installed"
    install = stamp.stat().st_mtime - start if stamp.exists() else None
    row = {"commit": rev, "target": target, "wall_s": round(wall, 1),
           "install_s": None if install is None else round(install, 1),
           "workflow_s": None, "report_s": None, "report_mb": None, "jobs": None,
           "exit_code": done.returncode, "load_start": round(load_start, 2),
           "load_end": round(_load(), 2),
           "command": f"git clone <this repository> && git checkout {rev} && {shlex.join(command)}"}
    if target == "run":
        span, jobs = _snakemake_span(clone)
        report = clone / "results/report.html"
        row.update(workflow_s=span, jobs=jobs)
        if report.exists():
            row["report_mb"] = round(report.stat().st_size / 1e6, 2)
            row["report_s"] = round(report.stat().st_mtime - (start + (install or 0) + (span or 0)), 1)
    print(f"{target} at {rev}: {row['wall_s']} s (install {row['install_s']} s, workflow "
          f"{row['workflow_s']} s, report {row['report_mb']} MB), exit {done.returncode}; "
          f"output in {work / f'make_{target}.out'}" + ("" if keep else " (clone removed)"))
    if not keep:
        subprocess.run(["rm", "-rf", str(clone)], check=False)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo", type=Path, default=ROOT)
    parser.add_argument("--commit", default="HEAD")
    parser.add_argument("--test", action="store_true", help="also time make test (a fresh clone too)")
    parser.add_argument("--quick", action="store_true", help="4 logs instead of 72")
    parser.add_argument("--keep", action="store_true", help="keep the clone")
    parser.add_argument("--smk-args", default="", metavar="ARGS",
                        help="extra Snakemake arguments of make run (SMK_ARGS), e.g. "
                             "'--set-threads lrde_fit=1'")
    parser.add_argument("--out", type=Path, default=ROOT / "results/benchmarks/first_run.csv")
    args = parser.parse_args(argv)
    rows = [measure(args.repo, args.commit, "run", args.quick, args.keep, args.smk_args)]
    if args.test:
        rows.append(measure(args.repo, args.commit, "test", False, args.keep))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fields = ["date", "machine", "command", "commit", "target", "wall_s", "install_s",
              "workflow_s", "report_s", "report_mb", "jobs", "exit_code", "load_start", "load_end"]
    new = not args.out.exists()
    with open(args.out, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        if new:
            writer.writeheader()
        for row in rows:
            writer.writerow({"date": datetime.datetime.now(datetime.timezone.utc).isoformat(
                timespec="seconds"), "machine": _machine(), **row})
    return 0


if __name__ == "__main__":
    sys.exit(main())
