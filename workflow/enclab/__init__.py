"""enclab: logged encoder experiments, from the log to the answer.

All scientific logic lives in this package; Snakemake rules and scripts are thin adapters.
Subpackages (each with its entry points in its docstring):

- :mod:`enclab.core`         shared: errors, manifest, readers, ingest, canonical log, atomic
  writes, the quantizer; imports no analysis
- :mod:`enclab.propagation`  paper 000 (Colonnese & Okamura): quantization error of positions,
  velocities and accelerations, measured, predicted (Table II, exact model) and bounded
- :mod:`enclab.lrde`         paper 002 (Zhang & Gao): extreme low-resolution encoder, offset and
  bias from dwell patterns (emcee)
- :mod:`enclab.residuals`    what the exact model misses on a measured channel, and which effect
  explains it
- :mod:`enclab.design`       encoder resolution and derivative filter for an error budget

Workflow glue: :mod:`enclab.log_summary` (a log's summary.json), :mod:`enclab.runner` (script
runner), :mod:`enclab.report` (run summary), :mod:`enclab.progress` (progress lines), :mod:`enclab.cli`
(the ``enclab`` command).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

__version__ = "0.1.0"

__all__ = ["__version__", "code_digest"]


def code_digest() -> str:
    """SHA-256 of the package's source files.

    Rules pass it as a ``params:`` value so that editing the library makes Snakemake
    rerun the jobs it affects (``--rerun-triggers params``), instead of keeping stale
    results computed by the old code.
    """
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]
