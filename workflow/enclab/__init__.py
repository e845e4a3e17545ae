"""enclab: logged encoder experiments, from the log to the answer.

All scientific logic lives in this package; Snakemake rules and scripts are thin adapters.
Subpackages (each with its entry points in its docstring):

- :mod:`enclab.core`         shared: errors, manifest, readers, ingest, canonical log, atomic
  writes, the quantizer; imports no analysis
- :mod:`enclab.propagation`  quantization error: of positions, velocities and accelerations,
  measured, predicted (Colonnese & Okamura's Table II, the exact model) and bounded
- :mod:`enclab.lrde`         low-resolution encoder: offset and bias of an extreme
  low-resolution encoder from dwell patterns (emcee; after Zhang & Gao)
- :mod:`enclab.residuals`    residual effects: what the exact model misses on a measured
  channel, and which effect explains it
- :mod:`enclab.rig`          rig fit: several runs of one rig fitted together, the effects they
  share proven on held-out runs (builds on :mod:`enclab.residuals`)
- :mod:`enclab.design`       design: encoder resolution and derivative filter for an error budget
  (builds on :mod:`enclab.propagation`)

Workflow glue: :mod:`enclab.plan` (what a run does: logs, chunks, targets, report figures),
:mod:`enclab.log_summary` (a log's summary.json), :mod:`enclab.runner` (script runner),
:mod:`enclab.report` (run summary), :mod:`enclab.progress` (progress lines), :mod:`enclab.cli`
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
