"""Shared helpers of the benchmarks: provenance, CSV rows, intervals, reference timing, draws.

``docs/benchmarks.md`` is generated from ``results/benchmarks/*.csv`` by
:mod:`benchmarks.render_benchmarks`; every table row there says when, where and how it was
measured (:func:`stamp`), so a number is never quoted without the run that produced it. The
command recorded is the one that reruns the script from the repository root
(:func:`command`).
"""
from __future__ import annotations

import datetime
import math
import os
import platform
import re
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from enclab.lrde import model, simulate

PROVENANCE = ("date", "machine", "command")
PACKAGE = Path(__file__).resolve().parent
ROOT = PACKAGE.parents[1]
RESULTS = ROOT / "results" / "benchmarks"
#: How a benchmark is run from the repository root (``workflow/`` holds the package).
RUN_PREFIX = ("PYTHONPATH=workflow", "python", "-m")

# The performance table (``performance.csv``) is shared by several scripts, one section each.
PERFORMANCE_COLUMNS = ["section", "case", "stage", "n_samples", "n_joints", "reps", "median_s",
                       "samples_per_s", "ratio_to_read", "peak_rss_mb", "target", "met", "notes"]
#: Peak-memory target of the streamed long-log path and of the whole workflow (MB).
TARGET_RSS_MB = 1536.0


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


def module_command(name: str, args=()) -> str:
    """The command that runs benchmark ``name`` with ``args`` from the repository root.

    Examples
    --------
    >>> module_command("bench_lrde", ["--draws", "10"])
    'PYTHONPATH=workflow python -m benchmarks.bench_lrde --draws 10'
    """
    return shlex.join([*RUN_PREFIX, f"{PACKAGE.name}.{name}", *map(str, args)])


def module_argv(name: str) -> list[str]:
    """The argv prefix that runs benchmark ``name`` in a child Python (see :func:`child_env`)."""
    return [sys.executable, "-m", f"{PACKAGE.name}.{name}"]


def child_env(**extra: str) -> dict:
    """This process's environment with the package's directory first on ``PYTHONPATH``, so a
    child started with :func:`module_argv` finds the package whatever its working directory."""
    path = os.pathsep.join(p for p in (str(PACKAGE.parent), os.environ.get("PYTHONPATH")) if p)
    return dict(os.environ, PYTHONPATH=path, **extra)


def command(argv: list[str] | None = None) -> str:
    """The command line that ran the script, as rerun from the repository root.

    A module of this package (``argv[0]`` its file, as ``python -m`` sets it) gives
    :func:`module_command`; any other program its path relative to the repository.
    """
    argv = list(sys.argv if argv is None else argv)
    program = Path(argv[0]).resolve() if argv else Path("?")
    if program.parent == PACKAGE and program.suffix == ".py":
        return module_command(program.stem, argv[1:])
    try:
        program = program.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(program), *argv[1:]])


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


# A command recorded before the benchmarks were a package: ``python workflow/benchmarks/x.py``
# (the script's path), or ``x.py`` alone (the script's name).
_SCRIPT_COMMAND = re.compile(r"^(?:python3? )?(?:\S*/)?(?:workflow/benchmarks/)?(\w+)\.py(?=\s|$)")


def rerun_command(text: str) -> str:
    """A recorded command in the form that reruns it from the repository root.

    A command that ran a script of this package by its path or its name becomes the
    package's module form (:func:`module_command`), with the same arguments; any other
    command is returned as it is.

    Examples
    --------
    >>> rerun_command("python workflow/benchmarks/bench_lrde.py --draws 10")
    'PYTHONPATH=workflow python -m benchmarks.bench_lrde --draws 10'
    >>> rerun_command("design_search.py --repeats 3")
    'PYTHONPATH=workflow python -m benchmarks.design_search --repeats 3'
    """
    match = _SCRIPT_COMMAND.match(text)
    if not match or not (PACKAGE / f"{match.group(1)}.py").is_file():
        return text
    return " ".join([*RUN_PREFIX, f"{PACKAGE.name}.{match.group(1)}"]) + text[match.end():]


def provenance(args: list[str] | None = None) -> dict:
    """This run's ``date``, ``machine`` and ``command`` as a row's first columns.

    ``args`` are the script's arguments as its ``main`` received them (``None``: the command
    line's); the command is :func:`command` of the program that runs."""
    argv = sys.argv if args is None else [sys.argv[0], *args]
    row = stamp(pd.DataFrame(index=[0]), argv)
    return {name: row.at[0, name] for name in PROVENANCE}


def merge_rows(rows: list[dict], path: Path, key, columns=None) -> pd.DataFrame:
    """Add ``rows`` to the CSV at ``path``, replacing its rows with the same ``key`` values.

    New rows get this run's date, machine and command (:func:`stamp`); rows with other key
    values (another section, another script) are kept. The file is replaced atomically.

    Parameters
    ----------
    rows : list of dict
        The new rows.
    path : pathlib.Path
        The CSV, created when absent.
    key : sequence of str
        The columns that name a row (e.g. ``("section", "case")``).
    columns : list of str, optional
        The columns of the new rows, in order.

    Returns
    -------
    pandas.DataFrame
        The whole table as written.
    """
    key = list(key)
    new = stamp(pd.DataFrame(rows, columns=columns))
    path = Path(path)
    if path.exists():
        old = pd.read_csv(path)
        replaced = set(zip(*(new[k] for k in key)))
        old = old[[pair not in replaced for pair in zip(*(old[k] for k in key))]]
        new = pd.concat([old, new], ignore_index=True) if len(old) else new
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".csv.tmp")
    new.to_csv(tmp, index=False)
    os.replace(tmp, path)
    return new


def write_performance_section(rows: list[dict], path: Path) -> pd.DataFrame:
    """Add ``rows`` (of :data:`PERFORMANCE_COLUMNS`) to the performance table at ``path``,
    replacing the rows of the same (section, case) (:func:`merge_rows`)."""
    return merge_rows(rows, path, key=("section", "case"), columns=PERFORMANCE_COLUMNS)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (95 % by default).

    Parameters
    ----------
    k, n : int
        Successes and trials; ``n = 0`` gives ``(nan, nan)``.
    z : float
        Standard normal quantile of the interval (1.645 for 90 %).

    Returns
    -------
    tuple of float
        The lower and upper bound.

    Examples
    --------
    >>> lo, hi = wilson(5, 10)
    >>> round(lo, 3), round(hi, 3)
    (0.237, 0.763)
    """
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    d = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / d
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (centre - half, centre + half)


def reference_loop_seconds(n: int = 5_000_000, clock=time.process_time) -> float:
    """Seconds of an ``n``-iteration Python loop on ``clock``: the reference beside a timing.

    A time divided by it compares across machines and loads better than the time alone."""
    start = clock()
    [0 for _ in range(n)]
    return clock() - start


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One draw, uniform in ``log`` between ``lo`` and ``hi``."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def open_loop_draw(rng: np.random.Generator, n_cycles: int, fs_hz: float, f_nominal: float = 20.0,
                   noise_frac: float = 0.005, truth_frac: float | None = None):
    """One simulated low-resolution encoder log of the paper-002 setting: ``(df, params)`` of
    :func:`enclab.lrde.simulate.open_loop_log`.

    Ros-Drill step; frequency ``f_nominal x U(0.9, 1.1)``; offset ``a ~ U(0, step)``;
    ``A12 ~ U(3, 5) step``; ``E_b`` uniform in Proposition 1's band; position noise
    ``noise_frac`` step; ``n_cycles + 1`` periods at ``fs_hz``; a truth channel of
    ``truth_frac`` step when given. The draw order (frequency, offset, stroke, ``E_b``, then
    the simulator's own draws) is the contract that lets several benchmarks score the same
    draws from the same seed.
    """
    step = simulate.ROS_DRILL_STEP
    f_hz = f_nominal * rng.uniform(0.9, 1.1)
    a_frac = rng.uniform(0, 1)
    A12 = rng.uniform(3.0, 5.0) * step
    half_eps = 0.5 * float(model.epsilon(A12, step))
    E_b = rng.uniform(-half_eps, half_eps)
    bias = E_b + 0.5 * step - a_frac * step
    return simulate.open_loop_log(rng, A12=A12, bias=bias, f_hz=f_hz, fs_hz=fs_hz,
                                  n_cycles=n_cycles + 1, offset_frac=a_frac,
                                  noise_std=noise_frac * step,
                                  truth_step=None if truth_frac is None else truth_frac * step)


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` as ``(i, n)``: the ``i``-th of ``n`` shares of a run's draws."""
    import argparse

    i, n = (int(v) for v in text.split("/"))
    if not (n >= 1 and 0 <= i < n):
        raise argparse.ArgumentTypeError(f"--shard must be i/n with 0 <= i < n, got {text!r}")
    return i, n
