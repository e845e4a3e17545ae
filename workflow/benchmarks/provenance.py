"""Date, machine and command for every row a benchmark script writes.

``docs/benchmarks.md`` is generated from ``results/benchmarks/*.csv`` by
``render_benchmarks.py``; every table row there says when, where and how it was measured, so a
number is never quoted without the run that produced it.
"""
from __future__ import annotations

import datetime
import os
import platform
import shlex
import sys
from pathlib import Path

import pandas as pd

PROVENANCE = ("date", "machine", "command")
ROOT = Path(__file__).resolve().parents[2]


def machine() -> str:
    """``<CPU model>, <n> cores, load <1-min average>`` of the machine running the script."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as handle:
            for line in handle:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load = f", load {os.getloadavg()[0]:.1f}"
    except OSError:
        load = ""
    return f"{model}, {os.cpu_count()} cores{load}"


def command(argv: list[str] | None = None) -> str:
    """The command line that ran the script, with paths relative to the repository."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0]).resolve() if argv else Path("?")
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(script), *argv[1:]])


def stamp(frame: pd.DataFrame, argv: list[str] | None = None,
          when: datetime.datetime | None = None) -> pd.DataFrame:
    """``frame`` with ``date`` (UTC, minutes), ``machine`` and ``command`` columns first.

    Rows that already carry a value keep it (a table that merges older rows)."""
    when = when or datetime.datetime.now(datetime.timezone.utc)
    values = {"date": when.strftime("%Y-%m-%d %H:%M UTC"), "machine": machine(),
              "command": command(argv)}
    out = frame.copy()
    for name in reversed(PROVENANCE):
        if name in out.columns:
            out[name] = out[name].fillna(values[name])
            out.insert(0, name, out.pop(name))
        else:
            out.insert(0, name, values[name])
    return out
