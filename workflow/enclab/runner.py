"""Run one pipeline script: log to the rule's log file, turn bad input into one clear line.

Every ``scripts/<rule>.py`` ends with ``run(snakemake, main)``. A user-fixable problem
(:class:`enclab.errors.EnclabInputError`, or a ``ValueError`` raised while checking a log's
contents) is printed as a single line naming the log, and the job exits non-zero, so that
``snakemake --keep-going`` finishes every other log. Outputs are written atomically by
:mod:`enclab.io`, and Snakemake removes the outputs of a failed job, so nothing partial stays.
"""
from __future__ import annotations

import logging
import sys
import time
import traceback
from collections.abc import Callable
from typing import Any

from enclab.errors import EnclabInputError

__all__ = ["run"]


def _log_path(smk: Any) -> str | None:
    log = getattr(smk, "log", None)
    return str(log[0]) if log else None


def run(smk: Any, main: Callable[[Any], None]) -> None:
    """Call ``main(smk)`` with logging set up and errors reported as one line."""
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    path = _log_path(smk)
    if path:
        handlers.append(logging.FileHandler(path, mode="w"))
    logging.basicConfig(level=logging.INFO, handlers=handlers, force=True,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    logger = logging.getLogger(f"enclab.{getattr(smk, 'rule', 'script')}")
    wildcards = dict(getattr(smk, "wildcards", {}) or {})
    where = f"[{wildcards['log_id']}] " if "log_id" in wildcards else ""
    start = time.perf_counter()
    try:
        main(smk)
    except EnclabInputError as err:
        logger.error("%s%s", where, err)
        sys.exit(1)
    except ValueError as err:
        # Library checks raise ValueError naming the argument and value; for a log they mean
        # its contents or its settings are unusable, which the user fixes, not a crash.
        logger.error("%s%s", where, " ".join(str(err).split()))
        logger.debug("%s", traceback.format_exc())
        sys.exit(1)
    logger.info("%sdone in %.2f s", where, time.perf_counter() - start)
