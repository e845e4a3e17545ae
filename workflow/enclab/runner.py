"""Run pipeline work: log to the rule's log file, turn every failure into one clear line.

Every ``scripts/<rule>.py`` ends with ``run(snakemake, main)``. Whatever a stage raises for a
log becomes one line naming the log's data file (:func:`enclab.core.errors.failure_line`): bad
input (:class:`enclab.core.errors.EnclabInputError`, or a ``ValueError`` raised while checking a
log's contents) as raised, an I/O failure (permissions, a vanished file, a full disk, a quota)
with the file it concerns and the fix, anything else as an internal error followed by its
traceback in the log file. The job then exits non-zero, so that ``snakemake --keep-going``
finishes every other log. Outputs are written atomically by :mod:`enclab.core.atomic`, and
Snakemake removes the outputs of a failed job, so nothing partial stays.

:func:`run_chunk` does the same for several logs inside one job (the chunked mode of
``workflow/rules/chunks.smk``): each log gets its own log file, a failing log is recorded
with its one line and the next log goes on.
"""
from __future__ import annotations

import logging
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from enclab.core import atomic
from enclab.core.allocator import keep_freed_memory
from enclab.core.errors import EnclabInputError, failure_line
from enclab.core.parallel import limit_blas_threads
from enclab.progress import QUIET_JOBS_ENV

__all__ = ["record_chunk", "run", "run_chunk", "error_line", "retry_token", "source_of"]

_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"
# A chunk's record beside its log (see retry_token): the token it ran with, its failures.
RETRY_SUFFIX = ".retry"
FAILED_SUFFIX = ".failed"


def _log_path(smk: Any) -> str | None:
    log = getattr(smk, "log", None)
    return str(log[0]) if log else None


def error_line(err: BaseException) -> str | None:
    """The one-line message of a user-fixable error, ``None`` for anything else (a bug).

    Library checks raise ``ValueError`` naming the argument and value; for a log they mean
    its contents or its settings are unusable, which the user fixes, not a crash.
    """
    if isinstance(err, EnclabInputError):
        return str(err)
    if isinstance(err, ValueError):
        return " ".join(str(err).split())
    return None


def source_of(smk: Any) -> str | None:
    """What a job's failure names first: its ``params.source`` (the log's data file), else
    the data file of its ``params.entry`` (rule ingest), else None (the line then starts
    with the log's id alone)."""
    params = getattr(smk, "params", None)
    source = getattr(params, "source", None) if params is not None else None
    if source:
        return str(source)
    entry = getattr(params, "entry", None) if params is not None else None
    data_root = getattr(params, "data_root", None) if params is not None else None
    if isinstance(entry, Mapping) and "file" in entry and data_root is not None:
        return str(Path(data_root) / entry["file"])
    return None


def _report(logger: logging.Logger, where: str, err: BaseException, source: Any) -> str:
    """Log the one-line reason of ``err`` (and, for a bug, its traceback after it)."""
    line, expected = failure_line(err, source)
    logger.error("%s%s", where, line)
    if not expected:
        logger.error("%s", traceback.format_exc().rstrip())
    return line


def run(smk: Any, main: Callable[[Any], None]) -> None:
    """Call ``main(smk)`` with logging set up and any failure reported as one line.

    Messages go to the rule's log file and to stderr; to the log file only under the
    progress display of ``make run`` (:data:`enclab.progress.QUIET_JOBS_ENV`), which prints the
    failed job's line itself. A failure exits with status 1 after its line (and, for a bug,
    its traceback) is logged. BLAS runs on at most the rule's ``threads``.
    """
    keep_freed_memory()
    limit_blas_threads(getattr(smk, "threads", 1) or 1)
    path = _log_path(smk)
    quiet = bool(path) and bool(os.environ.get(QUIET_JOBS_ENV))
    handlers: list[logging.Handler] = [] if quiet else [logging.StreamHandler(sys.stderr)]
    if path:
        handlers.append(logging.FileHandler(path, mode="w"))
    logging.basicConfig(level=logging.INFO, handlers=handlers, force=True, format=_FORMAT)
    logger = logging.getLogger(f"enclab.{getattr(smk, 'rule', 'script')}")
    wildcards = dict(getattr(smk, "wildcards", {}) or {})
    where = f"[{wildcards['log_id']}] " if "log_id" in wildcards else ""
    start = time.perf_counter()
    try:
        main(smk)
    except Exception as err:  # noqa: BLE001 - every failure is this job's one line
        _report(logger, where, err, source_of(smk))
        logging.shutdown()
        sys.exit(1)
    # CPU of the whole job process, imports included, so that what a job costs beyond its work
    # can be measured (workflow/benchmarks/bench_batch.py reads it from the chunk jobs' logs).
    logger.info("%sdone in %.2f s, %.2f s CPU", where, time.perf_counter() - start,
                time.process_time())


def run_chunk(entries: Iterable[Mapping], process: Callable[[Mapping, Path], None],
              staging: str | os.PathLike, rule: str = "quantization",
              data_root: str | os.PathLike | None = None) -> dict[str, str | None]:
    """Process several logs in one job, each on its own, into ``staging``.

    For every entry, ``process(entry, folder)`` writes the log's outputs into a temporary
    folder, renamed to ``staging/<log_id>/`` only when every stage succeeded, so a failed
    log leaves no output. Each log's messages go to ``staging/<log_id>.log``; a failed log
    also gets ``staging/<log_id>.failed`` holding its one line (its traceback, for a bug,
    follows in its log), and the next log goes on. Whatever fails (bad input, an I/O error,
    a bug) fails that log alone (:func:`record_chunk` then makes the next run retry the chunk).

    Parameters
    ----------
    entries : iterable of dict
        Normalised manifest entries (key ``id``).
    process : callable
        ``process(entry, folder)`` runs every stage of one log into ``folder``.
    staging : path-like
        The chunk's folder (created if needed).
    rule : str
        Logger name suffix, as the rule name in the per-stage mode.
    data_root : path-like, optional
        The manifest's data root: a failure names ``data_root/<file>`` first.

    Returns
    -------
    dict
        ``{log_id: None}`` for a log that completed, ``{log_id: error line}`` otherwise.
    """
    keep_freed_memory()
    staging = Path(staging)
    staging.mkdir(parents=True, exist_ok=True)
    logger = logging.getLogger(f"enclab.{rule}")
    root = logging.getLogger()
    root.setLevel(logging.INFO)
    status: dict[str, str | None] = {}
    for entry in entries:
        log_id = entry["id"]
        source = Path(data_root) / entry["file"] if data_root is not None and "file" in entry \
            else None
        handler = logging.FileHandler(staging / f"{log_id}.log", mode="w")
        handler.setFormatter(logging.Formatter(_FORMAT))
        root.addHandler(handler)
        start, cpu = time.perf_counter(), time.process_time()
        try:
            with atomic.atomic_folder(staging / log_id) as tmp:
                process(entry, tmp)
        except Exception as err:  # noqa: BLE001 - whatever fails one log fails it alone
            line = _report(logger, f"[{log_id}] ", err, source)
            atomic.write_text(line + "\n", staging / f"{log_id}.failed")
            status[log_id] = line
        else:
            logger.info("[%s] done in %.2f s, %.2f s CPU", log_id, time.perf_counter() - start,
                        time.process_time() - cpu)
            status[log_id] = None
        finally:
            root.removeHandler(handler)
            handler.close()
    return status


def retry_token(record: str | os.PathLike, keep: bool = False) -> str:
    """The retry token of a chunk (``params.retry`` of rule ``process_chunk``).

    A chunk job succeeds when some of its logs failed (they fail alone), so its staging
    folder is a complete output although it holds failures. Snakemake reruns a job whose
    params differ from those of its last run: the job keeps a record of its failures
    (``<record>.failed``, outside its output, which Snakemake removes before a rerun) and of
    the token it ran with (``<record>.retry``). While failures are recorded the token is the
    record's modification time, which differs from the token the job ran with, so the next run
    retries the chunk (once a full disk, a permission or a file was fixed), and a chunk that
    fails again is retried again. Without failures, or with ``keep`` (the second pass of
    ``make run``, ``batch_scope=completed``, which must not redo the first pass's work), the
    token is the one the job ran with: nothing to rerun.

    Parameters
    ----------
    record : path-like
        The chunk's record, without suffix (``results/logs/chunks/<chunk>``).
    keep : bool
        Return the token the chunk ran with even if failures are recorded.

    Returns
    -------
    str
        ``"failed@<mtime ns>"``, or the stored token ("" if none).
    """
    record = Path(record)
    stored = record.with_name(record.name + RETRY_SUFFIX)
    token = stored.read_text(encoding="utf-8").strip() if stored.is_file() else ""
    failed = record.with_name(record.name + FAILED_SUFFIX)
    if keep or not failed.is_file():
        return token
    return f"failed@{failed.stat().st_mtime_ns}"


def record_chunk(record: str | os.PathLike, token: str, status: Mapping[str, str | None]) -> None:
    """Write a chunk's record (see :func:`retry_token`): the token it ran with and its failed
    logs' lines (``<log_id>: <line>``), or no failure file when every log completed."""
    record = Path(record)
    atomic.write_text(token + "\n", record.with_name(record.name + RETRY_SUFFIX))
    failed = record.with_name(record.name + FAILED_SUFFIX)
    lines = [f"{log_id}: {line}" for log_id, line in status.items() if line is not None]
    if lines:
        atomic.write_text("\n".join(lines) + "\n", failed)
    else:
        failed.unlink(missing_ok=True)
