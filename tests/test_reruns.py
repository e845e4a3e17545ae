"""Reruns: a run killed with SIGKILL in the middle of a job, then rerun, ends with exactly the
results of an uninterrupted run; so two runs of one configuration are byte-identical (every
output of the killed workspace is computed again, by other processes, before or after the kill).

The uninterrupted run is the test session's default run of the standard workspace (conftest.py);
this one builds the same workspace afresh (same seeds, same bytes), kills it once published
outputs exist and jobs are running, unlocks and reruns the two passes of ``make run``.
"""
import os
import signal
import subprocess
import time

import pytest

from workspace import (result_digests, run_two_passes, run_workflow, snakemake_command,
                       standard_workspace)

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def killed_and_rerun(tmp_path_factory):
    work, params = standard_workspace(tmp_path_factory.mktemp("killed"))
    proc = subprocess.Popen(snakemake_command(work, "--keep-going"), cwd=work,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=dict(os.environ, MPLBACKEND="Agg"))
    # Kill once some outputs exist and jobs are running: the middle of the per-log stages.
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if list((work / "results").glob("*/canonical.parquet")):
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    killed_state = {"batch_done": (work / "results/batch/quantization.csv").exists()}
    # After a SIGKILL the lock stays; --unlock is the documented first step of a rerun.
    unlock = run_workflow(work, "--unlock")
    assert unlock.returncode == 0, unlock.stderr[-3000:]
    rerun = run_two_passes(work, params, flags=("--rerun-incomplete",))
    return rerun, killed_state


def test_sigkill_mid_job_then_rerun_matches_an_uninterrupted_run(killed_and_rerun, default_run):
    rerun, killed_state = killed_and_rerun
    assert not killed_state["batch_done"]
    assert rerun.second.returncode == 0, rerun.second.stderr[-3000:]
    reference = default_run.digests()
    again = result_digests(rerun.work)
    assert set(again) == set(reference)
    differ = sorted(k for k in reference if reference[k] != again[k])
    assert not differ, f"outputs differ between the two runs: {differ}"
    assert any(k.endswith("summary.json") for k in reference)
    assert any(k.endswith(".csv") for k in reference)
