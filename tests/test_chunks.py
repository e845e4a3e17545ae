"""Chunked mode (config chunk_size > 0, the default): several logs per job, same contract as
one job per stage.

The unit tests drive :func:`enclab.runner.run_chunk` directly. The end-to-end tests read the
test session's runs of the standard workspace (conftest.py): two good logs, a log with a NaN (fails
at ingest) and a log too short for the filters (fails after ingest, in the moments/theory
stages) in one chunk, next to a low-resolution encoder log that keeps its own rules, through the two passes
of ``make run``: the bad logs fail alone with their one error line and leave no output, and
every other output is byte-identical to a run with one job per stage and log.
"""
import errno
import json
import logging
import os
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from enclab import runner
from enclab.core import atomic
from enclab.core.errors import EnclabInputError, failure_line
from enclab.propagation import pipeline
from enclab.propagation.simulate import phantom_protocol_run
from workspace import (
    copy_workspace,
    phantom_entry,
    result_digests,
    run_workflow,
    write_workspace,
)


def _process(entry, folder):
    # Writes a first output, then fails as the entry asks: a failure after some outputs exist.
    atomic.write_json({"id": entry["id"]}, folder / "first.json")
    if entry.get("fail") == "input":
        raise EnclabInputError("logs/x.csv", "empty or NaN value", column="angle", row=12,
                               row_label="line", expected="a finite number")
    if entry.get("fail") == "bug":
        raise KeyError("no such key")
    atomic.write_json({"id": entry["id"]}, folder / "second.json")


def test_run_chunk_isolates_each_failure_and_leaves_no_partial_output(tmp_path):
    entries = [{"id": "a"}, {"id": "bad", "fail": "input"}, {"id": "bug", "fail": "bug"},
               {"id": "c"}]
    status = runner.run_chunk(entries, _process, tmp_path / "chunk")
    assert status["a"] is None and status["c"] is None
    assert status["bad"] == "logs/x.csv: column 'angle', line 12: empty or NaN value; expected a finite number."
    assert "KeyError: 'no such key'" in status["bug"]
    chunk = tmp_path / "chunk"
    for ok in ("a", "c"):
        assert sorted(p.name for p in (chunk / ok).iterdir()) == ["first.json", "second.json"]
        assert not (chunk / f"{ok}.failed").exists()
        assert re.search(rf"\[{ok}\] done in [0-9.]+ s, [0-9.]+ s CPU",
                         (chunk / f"{ok}.log").read_text())
    for failed in ("bad", "bug"):
        assert not (chunk / failed).exists(), "a failed log must leave no output"
        assert (chunk / f"{failed}.failed").read_text().strip() == status[failed]
        assert "ERROR" in (chunk / f"{failed}.log").read_text()
    # The one-line message is the log's line in its own log file, and nothing else is left.
    assert f"ERROR [bad] {status['bad']}" in (chunk / "bad.log").read_text()
    assert "\n" not in status["bad"]
    assert sorted(p.name for p in chunk.iterdir()) == [
        "a", "a.log", "bad.failed", "bad.log", "bug.failed", "bug.log", "c", "c.log"]


def _io_process(data):
    """A stage that fails as the entry asks: an unreadable data file, one that vanished, a
    full disk while writing an output, bad input raised without a file name."""
    def process(entry, folder):
        path = data / entry["file"]
        if entry["fail"] == "unreadable":
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        if entry["fail"] == "vanished":
            path.unlink()
            path.read_bytes()
        if entry["fail"] == "disk_full":
            def full(tmp):
                raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))  # write() names no file
            atomic.write_json({"id": entry["id"]}, folder / "first.json")
            with pytest.MonkeyPatch.context() as patch:
                patch.setattr(Path, "write_text", lambda self, *a, **k: full(self))
                atomic.write_json({"id": entry["id"]}, folder / "moments.json")
        if entry["fail"] == "short":
            raise ValueError("need at least 50 samples, got 3")
    return process


def test_run_chunk_names_the_file_for_any_failure(tmp_path):
    data = tmp_path / "logs"
    data.mkdir()
    kinds = ("unreadable", "vanished", "disk_full", "short")
    for kind in kinds:
        (data / f"{kind}.csv").write_text("t,angle\n0,0\n")
    entries = [{"id": kind, "file": f"{kind}.csv", "fail": kind} for kind in kinds]
    status = runner.run_chunk(entries, _io_process(data), tmp_path / "chunk", data_root=data)
    for kind in kinds:
        line = status[kind]
        assert line.startswith(f"{data / kind}.csv: ") and "\n" not in line, line
        assert "Traceback" not in (tmp_path / "chunk" / f"{kind}.log").read_text()
        assert not (tmp_path / "chunk" / kind).exists()
    assert "permission denied; give the workflow's user read access" in status["unreadable"]
    assert "no such file: moved, renamed or deleted" in status["vanished"]
    # the output being written is named, and what to do
    assert re.search(r"\.tmp/moments\.json: no space left for it: the disk is full, or a "
                     r"file-size limit or disk quota was reached \(File too large\); free space",
                     status["disk_full"])
    assert status["short"] == f"{data / 'short'}.csv: need at least 50 samples, got 3"


def test_failure_line_keeps_a_message_that_names_its_file():
    err = EnclabInputError("logs/x.csv", "empty or NaN value", column="angle", row=12,
                           row_label="line")
    assert failure_line(err, "logs/x.csv") == (str(err), True)
    line, expected = failure_line(MemoryError(), "logs/x.csv")
    assert expected and line.startswith("logs/x.csv: out of memory")
    # Arrow's I/O errors carry the errno in their text only
    arrow = OSError("Error writing bytes to file. Detail: [errno 28] No space left on device")
    assert "the disk is full" in failure_line(arrow, "logs/x.csv")[0]


def test_retry_token_changes_while_a_chunk_holds_failures(tmp_path):
    record = tmp_path / "chunk0000"
    assert runner.retry_token(record) == ""  # never ran
    runner.record_chunk(record, "", {"a": None, "b": None})
    assert runner.retry_token(record) == ""  # ran with "", nothing failed: no rerun
    runner.record_chunk(record, "", {"a": None, "b": "logs/b.csv: permission denied; ..."})
    assert (tmp_path / "chunk0000.failed").read_text() == "b: logs/b.csv: permission denied; ...\n"
    os.utime(tmp_path / "chunk0000.failed", ns=(10**18, 10**18))
    token = runner.retry_token(record)
    assert token == f"failed@{10**18}"  # differs from what it ran with: the next run retries
    # the second pass of `make run` keeps what the chunk ran with
    assert runner.retry_token(record, keep=True) == ""
    # the retried chunk, run with the token, fails again: a newer record, a new token
    runner.record_chunk(record, token, {"b": "logs/b.csv: permission denied; ..."})
    assert runner.retry_token(record, keep=True) == token
    os.utime(tmp_path / "chunk0000.failed", ns=(10**18 + 1, 10**18 + 1))
    assert runner.retry_token(record) not in ("", token)
    # fixed: the retried chunk completes, its token is the one it ran with: nothing to rerun
    runner.record_chunk(record, "failed@7", {"b": None})
    assert not (tmp_path / "chunk0000.failed").exists()
    assert runner.retry_token(record) == runner.retry_token(record, keep=True) == "failed@7"


def test_runner_one_line_errors():
    err = EnclabInputError("f.csv", "no data lines", expected="two samples")
    assert runner.error_line(err) == str(err)
    assert runner.error_line(ValueError("a\n   b")) == "a b"
    assert runner.error_line(RuntimeError("bug")) is None


@pytest.fixture
def root_logging():
    # runner.run replaces the root logger's handlers, as in a job of its own; restore them.
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for handler in root.handlers:
        if handler not in handlers:
            handler.close()
    root.handlers[:] = handlers
    root.setLevel(level)


def test_run_logs_wall_and_cpu_time_or_one_error_line(tmp_path, root_logging):
    # workflow/benchmarks/bench_batch.py reads the CPU time from a chunk job's log.
    def smk(name):
        return SimpleNamespace(log=[str(tmp_path / name)], rule="x", wildcards={"log_id": "a"})

    runner.run(smk("ok.log"), lambda s: None)
    assert re.search(r"\[a\] done in [0-9.]+ s, [0-9.]+ s CPU$",
                     (tmp_path / "ok.log").read_text().strip())

    def bad(s):
        raise ValueError("cutoff 600 Hz\n  is at or above Nyquist")
    with pytest.raises(SystemExit) as info:
        runner.run(smk("bad.log"), bad)
    assert info.value.code == 1
    lines = (tmp_path / "bad.log").read_text().strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith("ERROR [a] cutoff 600 Hz is at or above Nyquist")

    def bug(s):
        raise KeyError("channels")
    with pytest.raises(SystemExit) as info:
        runner.run(smk("bug.log"), bug)
    assert info.value.code == 1
    # a bug's one line comes first (the progress display and the run summary show it), then
    # its traceback
    lines = (tmp_path / "bug.log").read_text().splitlines()
    assert re.search(r"ERROR \[a\] internal error KeyError: 'channels' \(a bug in enclab",
                     lines[0])
    assert "Traceback" in lines[1]


def test_quantization_outputs_match_the_rules():
    # publish_log and publish_figures (workflow/rules/chunks.smk) declare these files: keep
    # the lists equal.
    text = (Path(__file__).resolve().parents[1] / "workflow/rules/chunks.smk").read_text()
    for name, file in {**pipeline.QUANTIZATION_OUTPUTS, **pipeline.FIGURE_OUTPUTS}.items():
        assert f'{name}="results/{{log_id}}/{file}"' in text


BANK = {"bank": {"d": [1], "n": [1, 2], "fc_hz": [50], "discretization": ["exponential"]},
        "export": []}


def test_check_cutoffs_names_the_time_base_fix_and_the_filter_memory():
    meta = {"log_id": "x", "fs_hz": 1000.0, "n_samples": 5000, "warnings": []}
    pipeline.check_cutoffs(BANK, meta)  # a 5 s log at 1 kHz suits a 50 Hz filter
    with pytest.raises(EnclabInputError, match=r"log 'x' has 20 samples, fewer than the longest "
                       r"derivative filter's memory \(\d+ samples\).*higher cutoffs"):
        pipeline.check_cutoffs(BANK, {**meta, "n_samples": 20})
    warning = ("time base: sampled at 1 Hz (median step 1 s), implausibly slow for a moving "
               "encoder (below 10 Hz): is the time column 't' in ms? (set time.unit: ms)")
    with pytest.raises(EnclabInputError) as info:
        pipeline.check_cutoffs(BANK, {**meta, "fs_hz": 1.0, "warnings": [warning]})
    text = str(info.value)
    assert "Nyquist" in text and text.endswith("is the time column 't' in ms? (set time.unit: ms).")
    assert "\n" not in text


# ----------------------------------------------------------------------------- end to end
# The test session's runs of the standard workspace (conftest.py): good1, good2, bad (NaN, fails at
# ingest) and short (fails after ingest, in the moments/theory stages) share one chunk; the
# low-resolution encoder log keeps its own rules.


@pytest.mark.slow
def test_bad_logs_fail_alone_with_their_line_and_no_output(default_run):
    work, first, second = default_run.work, default_run.first, default_run.second
    assert first.returncode != 0, "the bad logs must make the first pass fail"
    assert second.returncode == 0, second.stderr[-3000:]
    assert "leaving out 2 log(s) without a summary" in second.stderr
    assert "process_chunk" in first.stderr and "publish_log" in first.stderr
    message = (work / "results/bad/logs/quantization.log").read_text()
    assert "bad.csv" in message and "theta2_counts" in message and "line 1236" in message
    # Snakemake shows the line too (the failed job's stderr and log).
    assert "line 1236" in first.stderr
    assert "samples" in (work / "results/short/logs/quantization.log").read_text()
    for failed in ("bad", "short"):
        outputs = [p.name for p in (work / "results" / failed).iterdir()
                   if p.name not in ("logs", "benchmarks")]
        assert outputs == [], f"{failed} left {outputs}"
    assert {p.name: p.read_bytes() for p in (work / "logs").iterdir()} == default_run.raw_before


@pytest.mark.slow
def test_chunked_outputs_are_byte_identical_to_one_job_per_stage(default_run, per_rule_run):
    chunked = default_run.digests()
    per_rule = per_rule_run.digests()
    # The per-stage mode keeps the outputs of the stages of 'short' that succeeded (ingest
    # ...); the chunked mode publishes a log whole or not at all. The rest is file for file,
    # figures included (the chunk drew bad's figures in vain; good1's come from log_figures in
    # both modes: bad, its group's first log, failed).
    extra = set(per_rule) - set(chunked)
    assert extra and all(name.startswith("short/") for name in extra), extra
    assert set(chunked) <= set(per_rule)
    differ = sorted(k for k in chunked if chunked[k] != per_rule[k])
    assert differ == ["summary.json"], f"outputs differ between the modes: {differ}"
    # The run summary names the stage where each failed log stopped: its rule's log, which in
    # the chunked mode is the whole chain's (quantization). Everything else is equal.
    runs = [json.loads((r.work / "results/summary.json").read_text())
            for r in (default_run, per_rule_run)]
    stages = [{f["log_id"]: f.pop("stage") for f in run["failed"]} for run in runs]
    assert stages[0] == {"bad": "quantization", "short": "quantization"}
    assert stages[1]["bad"] == "ingest" and stages[1]["short"] in ("moments", "theory")
    assert runs[0] == runs[1]
    for name in ("good1/summary.json", "good2/summary.json", "lrde/summary.json",
                 "batch/quantization.csv", "batch/lrde.csv", "good1/figures/errors.png",
                 "summary.json", "report/thumbs/log_errors/good1.png"):
        assert name in chunked


@pytest.mark.slow
def test_chunked_rerun_has_nothing_to_do(default_run):
    work = default_run.work
    before = default_run.digests()
    again = run_workflow(work, "--config", "batch_scope=completed")
    assert again.returncode == 0, again.stderr[-3000:]
    assert "Nothing to be done" in again.stderr + again.stdout
    assert result_digests(work) == before


# ------------------------------------------------------- staleness and publishing, chunked

_SMALL_TARGETS = ("--config", "chunk_size=2", "--",
                  *(f"results/good{k}/summary.json" for k in (1, 2, 3)))


@pytest.fixture(scope="module")
def small_chunked(tmp_path_factory):
    """Three good logs in two chunks (chunk_size=2: good1 + good2, then good3), run once; each
    test gets a copy."""
    work = tmp_path_factory.mktemp("small_chunked")
    data = work / "logs"
    data.mkdir(parents=True)
    entries = []
    for k in (1, 2, 3):
        log, _ = phantom_protocol_run(np.zeros(3), np.random.default_rng(k), duration_s=2.0)
        atomic.write_table(log, data / f"good{k}.parquet")
        entries.append(phantom_entry(f"good{k}", f"good{k}.parquet", "g"))
    write_workspace(work, entries, fig7_group="g")
    first = run_workflow(work, *_SMALL_TARGETS)
    assert first.returncode == 0, first.stderr[-3000:]
    return work


@pytest.mark.slow
def test_chunked_changed_log_reruns_its_chunk_only(small_chunked, tmp_path):
    work = copy_workspace(small_chunked, tmp_path / "w")
    summaries = {k: work / f"results/good{k}/summary.json" for k in (1, 2, 3)}
    before = {k: (p.stat().st_ino, p.stat().st_mtime_ns, p.read_bytes())
              for k, p in summaries.items()}
    log, _ = phantom_protocol_run(np.full(3, 0.1), np.random.default_rng(7), duration_s=2.0)
    atomic.write_table(log, work / "logs/good3.parquet")
    again = run_workflow(work, *_SMALL_TARGETS)
    assert again.returncode == 0, again.stderr[-3000:]
    # Snakemake finds the changed input: good3's chunk and publish job run, the other chunk
    # and its logs' published files are left as they were.
    assert "chunk=chunk0001" in again.stderr and "chunk=chunk0000" not in again.stderr
    for k in (1, 2):
        p = summaries[k]
        assert (p.stat().st_ino, p.stat().st_mtime_ns, p.read_bytes()) == before[k]
    assert summaries[3].read_bytes() != before[3][2]


@pytest.mark.slow
def test_chunked_publish_that_fails_midway_leaves_no_output(small_chunked, tmp_path):
    work = copy_workspace(small_chunked, tmp_path / "w")
    # A staged file gone: publish_log links the others, then fails on this one; Snakemake
    # must remove what it linked (publish_log writes no temporary names of its own).
    (work / "results/.chunks/chunk0000/good1/theory.json").unlink()
    broken = run_workflow(work, "--force", *_SMALL_TARGETS[:2], "--",
                          "results/good1/summary.json")
    assert broken.returncode != 0
    assert "publish_log" in broken.stderr
    left = sorted(p.name for p in (work / "results/good1").iterdir()
                  if p.name not in ("logs", "benchmarks"))
    assert left == [], f"a failed publish left {left}"
    assert (work / "results/good2/summary.json").exists()
