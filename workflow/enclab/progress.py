"""One line per finished job, one line per failure: the terminal output of ``make run``.

Snakemake's default output prints five to ten lines per job (rule, files, reason, resources,
progress). :class:`ProgressHandler` is a Snakemake logger plugin (``--logger enclab``; the
plugin package ``snakemake_logger_plugin_enclab`` next to this one only exports it) that
prints instead::

    enclab: 85 jobs: process_chunk 9, publish_log 68, lrde_fit 2, ...
    [  3/85]  process_chunk       chunk0002                       9.1 s
    [ 12/85]  FAILED ingest       bad: logs/bad.csv: column 'theta2', line 1236: ...

Bookkeeping jobs (the chunked mode's publish jobs, rule ``all``) count but print no line.
While the handler is active the jobs write their messages only to their log files
(``ENCLAB_QUIET_JOBS``, read by :mod:`enclab.runner`), so a failure shows once, with the
line read from the failed job's log. The complete Snakemake log stays in
``.snakemake/log/``.
"""
from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

__all__ = ["QUIET_JOBS_ENV", "ProgressHandler", "error_line_of", "job_label"]

QUIET_JOBS_ENV = "ENCLAB_QUIET_JOBS"
# Jobs that only move files or close the DAG: counted, not printed.
SILENT_RULES = ("all", "publish_log", "publish_figures")
_PLAIN_INFO = ("Nothing to be done", "Building DAG")

try:  # the plugin interface comes with Snakemake; without it this module still imports
    from snakemake_interface_logger_plugins.base import LogHandlerBase
    from snakemake_interface_logger_plugins.common import LogEvent
except ImportError:  # pragma: no cover - Snakemake is a dependency
    LogHandlerBase, LogEvent = logging.Handler, None


def job_label(rule: str, wildcards: Mapping[str, str] | None) -> str:
    """``rule  wildcard values`` of a job, e.g. ``residuals  res_clean_r01/output``."""
    values = "/".join(str(v) for v in (wildcards or {}).values())
    return f"{rule:<20s}{values}"


def error_line_of(log_texts: Sequence[str]) -> str | None:
    """The first enclab ``ERROR`` line in a failed job's logs (time stamp and log id removed),
    else the last non-empty line, else None."""
    last = None
    for text in log_texts:
        for line in text.splitlines():
            if " ERROR " in line:
                message = line.split(" ERROR ", 1)[1].strip()
                if message.startswith("[") and "] " in message:
                    message = message.split("] ", 1)[1]
                return message
            if line.strip():
                last = line.strip()
    return last


def _read_logs(paths: Sequence[str]) -> list[str]:
    texts = []
    for path in paths:
        try:
            texts.append(Path(path).read_text(encoding="utf-8", errors="replace"))
        except OSError:
            continue
    return texts


class ProgressHandler(LogHandlerBase):
    """Snakemake log handler: a line per finished job and per failure (see the module doc)."""

    def __init__(self, common_settings=None, settings=None, stream=None) -> None:
        self._stream = stream
        if LogEvent is None:  # pragma: no cover
            logging.Handler.__init__(self)
        else:
            super().__init__(common_settings, settings)

    def __post_init__(self) -> None:
        self.jobs: dict[int, tuple[str, dict, list, float]] = {}
        self.failures: set[tuple[str, str]] = set()
        self.done = 0
        self.total = 0
        # Inherited by the job processes this Snakemake starts (local execution).
        os.environ[QUIET_JOBS_ENV] = "1"

    # plugin interface
    @property
    def writes_to_stream(self) -> bool:
        return True

    @property
    def writes_to_file(self) -> bool:
        return False

    @property
    def has_filter(self) -> bool:
        return True

    @property
    def has_formatter(self) -> bool:
        return True

    @property
    def needs_rulegraph(self) -> bool:
        return False

    def _print(self, line: str) -> None:
        stream = self._stream or sys.stderr
        stream.write(line + "\n")
        stream.flush()

    def _counter(self) -> str:
        width = len(str(self.total)) if self.total else 1
        return f"[{self.done:>{width}d}/{self.total}]"

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._emit(record)
        except Exception:  # noqa: BLE001 - a logger must never stop the run
            self.handleError(record)

    def _emit(self, record: logging.LogRecord) -> None:
        event = getattr(record, "event", None)
        if event == LogEvent.RUN_INFO:
            stats = dict(getattr(record, "stats", None) or {})
            total = int(stats.pop("total", 0) or 0)
            if total:
                self.total = self.done + total if self.done else total
                counts = ", ".join(f"{rule} {n}" for rule, n in stats.items())
                self._print(f"enclab: {total} jobs: {counts}")
        elif event == LogEvent.JOB_INFO:
            self.jobs[int(record.jobid)] = (record.rule_name, dict(record.wildcards or {}),
                                            list(record.log or []), time.monotonic())
        elif event == LogEvent.JOB_FINISHED:
            self.done += 1
            rule, wildcards, _, start = self.jobs.pop(int(record.job_id), ("?", {}, [], None))
            if rule in SILENT_RULES:
                return
            took = "" if start is None else f"{time.monotonic() - start:8.1f} s"
            self._print(f"{self._counter()}  {job_label(rule, wildcards):<52s}{took}")
        elif event == LogEvent.JOB_ERROR:
            rule = record.rule_name
            wildcards = self.jobs.pop(int(record.jobid), (rule, {}, [], None))[1]
            logs = list(record.log or [])
            message = error_line_of(_read_logs(logs)) or "no message"
            # a chunked log that fails fails its publish jobs alike: one line for it
            key = ("/".join(map(str, wildcards.values())), message)
            if key in self.failures:
                return
            self.failures.add(key)
            where = f" (log: {logs[0]})" if logs else ""
            self._print(f"{self._counter()}  FAILED {job_label(rule, wildcards).rstrip()}: "
                        f"{message}{where}")
        elif event == LogEvent.GROUP_ERROR:
            self._print(f"{self._counter()}  FAILED group job: {record.getMessage()}")
        elif event is None:
            message = record.getMessage() if record.msg is not None else ""
            if record.levelno >= logging.WARNING or message.startswith(_PLAIN_INFO):
                self._print(message.rstrip())
