"""Tiny workflow workspaces for the end-to-end tests.

The *standard* workspace (:func:`standard_workspace`) is shared: ``conftest.py`` runs it once
per pytest session in the default mode and once with one job per stage, and test_workflow.py,
test_chunks.py and test_reruns.py read those runs instead of starting their own.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from enclab.core import atomic
from enclab.lrde import simulate as lrde_sim
from enclab.propagation.simulate import phantom_protocol_run

ROOT = Path(__file__).resolve().parents[1]
# Images carry no timestamps (save_figure strips them) but are compared only for existence:
# byte-identity of PNGs across matplotlib builds is not a contract.
COMPARED = {".json", ".csv", ".parquet", ".md"}
SNAKEMAKE = Path(sys.executable).with_name("snakemake")


def phantom_entry(name: str, file: str, group: str) -> dict:
    """A simulated Phantom run (phantom_protocol_run table), re-quantized to 1 mrad."""
    return {"id": name, "file": file, "format": "parquet", "device": "phantom_premium_1_5",
            "group": group, "time": {"column": "t", "unit": "s", "nominal_rate_hz": 1000.0},
            "channels": [{"name": f"theta{j}", "column": f"theta{j}_counts", "role": "truth",
                          "joint": j, "unit": "counts", "step": 1.25e-4} for j in (1, 2, 3)],
            "analysis": {"requantize": {"steps": [1e-3]}}}


def lrde_entry(name: str, file: str) -> dict:
    """A lrde_sim.open_loop_log table with a step/100 truth channel, paper-002 stage only."""
    step = lrde_sim.ROS_DRILL_STEP
    return {"id": name, "file": file, "format": "parquet", "device": "lrde_axis",
            "time": {"column": "t", "unit": "s"},
            "channels": [{"name": "coarse", "column": "counts", "role": "measured", "joint": 1,
                          "unit": "counts", "step": step},
                         {"name": "fine", "column": "truth_counts", "role": "truth", "joint": 1,
                          "unit": "counts", "step": step / 100}],
            "analysis": {"stages": ["lrde"]}}


def write_workspace(work: Path, entries: list[dict], fig7_group: str) -> None:
    """manifest.yaml and a config.yaml with a small filter bank and a short sampler."""
    (work / "manifest.yaml").write_text(yaml.safe_dump({"data_root": "logs", "logs": entries}))
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["manifest"] = "manifest.yaml"
    config["derivatives"]["bank"] = {"d": [1, 2], "n": [1, 2], "fc_hz": [50, 100],
                                     "discretization": ["exponential", "bilinear"]}
    config["figures"]["fig7_group"] = fig7_group
    config["lrde"].update(n_ensembles=2, n_walkers=16, n_steps=100, max_steps=100, n_burn=100, ppc_draws=5,
                          motion_models=[[], [3]])
    (work / "config.yaml").write_text(yaml.safe_dump(config))


def snakemake_command(work: Path, *extra: str) -> list[str]:
    return [str(SNAKEMAKE), "--snakefile", str(ROOT / "Snakefile"), "--directory", str(work),
            "--configfile", str(work / "config.yaml"), "--cores", "2", *extra]


def result_digests(work: Path) -> dict[str, str]:
    """SHA-256 of every result under ``work/results`` whose bytes are a contract.

    Keys are paths relative to ``results/``; images map to ``"exists"``. Per-rule logs,
    benchmark files, the chunked mode's staging folders and the HTML report are left out (they
    hold times and paths, or are not results).
    """
    results = work / "results"
    return {str(p.relative_to(results)): (hashlib.sha256(p.read_bytes()).hexdigest()
                                          if p.suffix in COMPARED else "exists")
            for p in sorted(results.rglob("*"))
            if p.is_file() and not {"logs", "benchmarks", ".chunks"} & set(p.parts)
            and p.name != "report.html"}


def standard_workspace(work: Path) -> tuple[Path, dict]:
    """good1, good2: 3 s simulated Phantom runs (repeat group ``g``, Fig. 7 group); bad: the
    same run as CSV with a NaN at table row 1234 (fails at ingest); short: 40 ms, too short for
    the derivative filters (fails after ingest); lrde: an 8-cycle paper-002 log, bias 0.1 step,
    with a step/100 truth channel. Returns the folder and the lrde log's true parameters."""
    data = work / "logs"
    data.mkdir(parents=True)
    entries = []
    for k in (1, 2):
        log, _ = phantom_protocol_run(np.zeros(3), np.random.default_rng(k), duration_s=3.0)
        atomic.write_table(log, data / f"good{k}.parquet")
        entries.append(phantom_entry(f"good{k}", f"good{k}.parquet", "g"))
    bad = log.astype({"theta2_counts": float})
    bad.loc[1234, "theta2_counts"] = np.nan
    bad.to_csv(data / "bad.csv", index=False)
    entries.append(phantom_entry("bad", "bad.csv", "g") | {"format": "csv"})
    short, _ = phantom_protocol_run(np.zeros(3), np.random.default_rng(4), duration_s=0.04)
    atomic.write_table(short, data / "short.parquet")
    entries.append(phantom_entry("short", "short.parquet", "g"))
    step = lrde_sim.ROS_DRILL_STEP
    lrde_log, lrde_params = lrde_sim.open_loop_log(np.random.default_rng(5), bias=0.1 * step,
                                                   n_cycles=8, noise_std=0.01 * step,
                                                   truth_step=step / 100)
    atomic.write_table(lrde_log, data / "lrde.parquet")
    entries.append(lrde_entry("lrde", "lrde.parquet"))
    write_workspace(work, entries, fig7_group="g")
    return work, lrde_params


def run_workflow(work: Path, *extra: str, timeout: int = 900) -> subprocess.CompletedProcess:
    """One Snakemake run in ``work`` with ``--keep-going`` (output captured)."""
    return subprocess.run(snakemake_command(work, "--keep-going", *extra), cwd=work,
                          capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ, MPLBACKEND="Agg"))


@dataclass
class Run:
    """The two passes of `make run` in a workspace: everything, then the batch over the logs
    that completed (``batch_scope=completed``)."""

    work: Path
    first: subprocess.CompletedProcess
    second: subprocess.CompletedProcess
    raw_before: dict
    lrde_params: dict

    def digests(self) -> dict[str, str]:
        return result_digests(self.work)


def run_two_passes(work: Path, lrde_params: dict, *config: str, flags: tuple = ()) -> Run:
    """The two passes with ``--config *config`` (and Snakemake ``flags``)."""
    raw_before = {p.name: p.read_bytes() for p in (work / "logs").iterdir()}
    first = run_workflow(work, *flags, *(("--config", *config) if config else ()))
    second = run_workflow(work, *flags, "--config", *config, "batch_scope=completed")
    return Run(work, first, second, raw_before, lrde_params)


def copy_workspace(source: Path, target: Path) -> Path:
    """A copy of a workspace that has run, with Snakemake's records and every mtime, so that
    Snakemake sees it as complete."""
    shutil.copytree(source, target, symlinks=True, copy_function=shutil.copy2)
    return target
