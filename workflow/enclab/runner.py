"""Run pipeline work: log to the rule's log file, turn bad input into one clear line.

Every ``scripts/<rule>.py`` ends with ``run(snakemake, main)``. A user-fixable problem
(:class:`enclab.core.errors.EnclabInputError`, or a ``ValueError`` raised while checking a log's
contents) is printed as a single line naming the log, and the job exits non-zero, so that
``snakemake --keep-going`` finishes every other log. Outputs are written atomically by
:mod:`enclab.core.atomic`, and Snakemake removes the outputs of a failed job, so nothing partial stays.

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
from enclab.core.errors import EnclabInputError
from enclab.progress import QUIET_JOBS_ENV

__all__ = ["run", "run_chunk", "error_line"]

_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


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


def run(smk: Any, main: Callable[[Any], None]) -> None:
    """Call ``main(smk)`` with logging set up and errors reported as one line.

    Messages go to the rule's log file and to stderr; to the log file only under the
    progress display of ``make run`` (:data:`enclab.progress.QUIET_JOBS_ENV`), which prints the
    failed job's line itself.
    """
    keep_freed_memory()
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
    except ValueError as err:
        logger.error("%s%s", where, error_line(err))
        logger.debug("%s", traceback.format_exc())
        sys.exit(1)
    except Exception as err:
        # A bug, not bad input: its last line first (what a progress display shows), then
        # the traceback, in the log file too.
        logger.error("%s%s", where, traceback.format_exception_only(err)[-1].strip())
        logger.error("%s", traceback.format_exc().rstrip())
        raise
    # CPU of the whole job process, imports included, so that what a job costs beyond its work
    # can be measured (workflow/benchmarks/bench_batch.py reads it from the chunk jobs' logs).
    logger.info("%sdone in %.2f s, %.2f s CPU", where, time.perf_counter() - start,
                time.process_time())


def run_chunk(entries: Iterable[Mapping], process: Callable[[Mapping, Path], None],
              staging: str | os.PathLike, rule: str = "quantization") -> dict[str, str | None]:
    """Process several logs in one job, each on its own, into ``staging``.

    For every entry, ``process(entry, folder)`` writes the log's outputs into a temporary
    folder, renamed to ``staging/<log_id>/`` only when every stage succeeded, so a failed
    log leaves no output. Each log's messages go to ``staging/<log_id>.log``; a failed log
    also gets ``staging/<log_id>.failed`` holding its one error line (a traceback for an
    unexpected error), and the next log goes on.

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
        handler = logging.FileHandler(staging / f"{log_id}.log", mode="w")
        handler.setFormatter(logging.Formatter(_FORMAT))
        root.addHandler(handler)
        start, cpu = time.perf_counter(), time.process_time()
        try:
            with atomic.atomic_folder(staging / log_id) as tmp:
                process(entry, tmp)
        except Exception as err:  # noqa: BLE001 - whatever fails one log fails it alone
            line = error_line(err)
            if line is None:
                line = traceback.format_exc().rstrip()
                logger.error("[%s] %s", log_id, traceback.format_exception_only(err)[-1].strip())
                logger.error("%s", line)
            else:
                logger.error("[%s] %s", log_id, line)
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
