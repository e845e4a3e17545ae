"""Reruns: a run killed with SIGKILL in the middle of a job, or a chunk job that hit a full disk,
then rerun with no cleaning, ends with exactly the results of an uninterrupted run; so two runs of
one configuration are byte-identical (every output of the broken workspace is computed again, by
other processes, before or after the fault).

The uninterrupted run is the test session's default run of the standard workspace (conftest.py);
this one builds the same workspace afresh (same seeds, same bytes), kills it once published
outputs exist and jobs are running, unlocks and reruns the two passes of ``make run``.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from workspace import (result_digests, run_two_passes, run_workflow, snakemake_command,
                       standard_workspace)

sys.path.insert(0, str(Path(__file__).parent / "corpus"))
from run import file_size_limit  # noqa: E402

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


# A full disk, simulated: a file-size limit (RLIMIT_FSIZE, `ulimit -f`) with SIGXFSZ ignored, so
# that a write past it fails with EFBIG ("File too large") as on a full disk or a quota
# (tests/corpus/run.py: the limit leaves Snakemake's copies of the workflow's files room).


@pytest.fixture(scope="module")
def disk_full_and_rerun(tmp_path_factory):
    work, params = standard_workspace(tmp_path_factory.mktemp("disk_full"))
    # Only the chunk (and its publish jobs) under the limit: that is the fault under test.
    full = subprocess.run(snakemake_command(work, "--keep-going", "--", "results/good1/summary.json",
                                            "results/good2/summary.json"),
                          cwd=work, capture_output=True, text=True, timeout=900,
                          preexec_fn=file_size_limit, env=dict(os.environ, MPLBACKEND="Agg"))
    logs = {k: (work / f"results/{k}/logs/quantization.log").read_text() for k in ("good1", "good2")}
    # The limit lifted, the two passes of `make run`, with no cleaning and no --unlock.
    rerun = run_two_passes(work, params)
    return full, logs, rerun


def test_disk_full_in_a_chunk_names_the_file_then_a_rerun_completes(disk_full_and_rerun,
                                                                    default_run):
    full, logs, rerun = disk_full_and_rerun
    assert full.returncode != 0
    assert "Traceback" not in full.stdout + full.stderr
    for log_id, text in logs.items():
        (line,) = [t.split(" ERROR ", 1)[1] for t in text.splitlines() if " ERROR " in t]
        assert line.startswith(f"[{log_id}] logs/{log_id}.parquet: results/.chunks/chunk0000/")
        assert "the disk is full, or a file-size limit or disk quota was reached" in line
    assert rerun.first.returncode != 0  # bad and short fail as in every run of the workspace
    assert rerun.second.returncode == 0, rerun.second.stderr[-3000:]
    reference = default_run.digests()
    again = result_digests(rerun.work)
    assert set(again) == set(reference)
    differ = sorted(k for k in reference if reference[k] != again[k])
    assert not differ, f"outputs differ from an uninterrupted run: {differ}"
