"""Tiny workflow workspaces for the end-to-end tests (test_workflow.py, test_reruns.py)."""
from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import yaml

from enclab.lrde import simulate as lrde_sim

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
    config["lrde"].update(n_ensembles=2, n_walkers=16, n_steps=100, n_burn=100, ppc_draws=5,
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
