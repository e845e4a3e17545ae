"""Reruns: two runs of one configuration are byte-identical, and a run killed with SIGKILL in
the middle of a job, then rerun, ends with exactly the results of an uninterrupted run.

The workspace is tiny (two short simulated Phantom runs and one low-resolution encoder log with
a short sampler), so each workflow run takes a few seconds of work plus Snakemake's start-up.
"""
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from enclab import io
from enclab.lrde import simulate as lrde_sim
from enclab.simulate import phantom_protocol_run
from workspace import lrde_entry, phantom_entry, result_digests, snakemake_command, write_workspace

pytestmark = pytest.mark.slow

def _workspace(path: Path) -> Path:
    data = path / "logs"
    data.mkdir(parents=True)
    entries = []
    for k in (1, 2):
        log, _ = phantom_protocol_run(np.zeros(3), np.random.default_rng(k), duration_s=3.0)
        io.write_table(log, data / f"run{k}.parquet")
        entries.append(phantom_entry(f"run{k}", f"run{k}.parquet", "g"))
    step = lrde_sim.ROS_DRILL_STEP
    log, _ = lrde_sim.open_loop_log(np.random.default_rng(9), n_cycles=6, noise_std=0.01 * step,
                                    truth_step=step / 100)
    io.write_table(log, data / "lrde.parquet")
    entries.append(lrde_entry("lrde", "lrde.parquet"))
    write_workspace(path, entries, fig7_group="g")
    return path


def _run(work: Path, *extra: str) -> subprocess.CompletedProcess:
    proc = subprocess.run(snakemake_command(work, *extra), cwd=work, capture_output=True, text=True,
                          timeout=900, env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr[-4000:]
    return proc


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    work = _workspace(tmp_path_factory.mktemp("reference"))
    _run(work)
    return result_digests(work)


def test_two_runs_are_byte_identical(reference, tmp_path):
    work = _workspace(tmp_path / "again")
    _run(work)
    again = result_digests(work)
    assert set(again) == set(reference)
    differ = sorted(k for k in reference if reference[k] != again[k])
    assert not differ, f"outputs differ between two runs: {differ}"
    assert any(k.endswith("summary.json") for k in reference)
    assert any(k.endswith(".csv") for k in reference)


def test_sigkill_mid_job_then_rerun_matches_an_uninterrupted_run(reference, tmp_path):
    work = _workspace(tmp_path / "killed")
    proc = subprocess.Popen(snakemake_command(work), cwd=work, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True,
                            env=dict(os.environ, MPLBACKEND="Agg"))
    # Kill once some outputs exist and jobs are running: the middle of the per-log stages.
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if len(list((work / "results").glob("*/requantized.parquet"))) >= 1:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (work / "results" / "batch" / "quantization.csv").exists()
    # After a SIGKILL the lock stays; --unlock is the documented first step of a rerun.
    _run(work, "--unlock")
    _run(work, "--rerun-incomplete")
    assert result_digests(work) == reference
