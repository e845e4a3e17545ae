"""enclab: quantization error of logged encoder experiments.

All scientific logic lives in this package; Snakemake rules and scripts are thin adapters.
Modules (one concern each):

- :mod:`enclab.quantize`   encoder/quantizer model on integer counts
- :mod:`enclab.filters`    derivative estimators of Colonnese & Okamura Fig. 5 and their norms
- :mod:`enclab.kinematics` devices: forward kinematics and Jacobians
- :mod:`enclab.theory`     Table II (worst case, PQN), exact non-white model, trajectory bound
- :mod:`enclab.moments`    empirical error moments with confidence intervals
- :mod:`enclab.ingest`     pure conversions of raw logs (units, counters, time base)
- :mod:`enclab.manifest`   manifest/config validation and normalisation
- :mod:`enclab.io`         the only module that touches disk
- :mod:`enclab.simulate`   simulated lab logs (Phantom Premium protocol)
- :mod:`enclab.analysis`   per-log stage functions used by the workflow scripts
- :mod:`enclab.stream`     the moments of logs too long for memory, piece by piece (CLI)
- :mod:`enclab.plots`      figures (return matplotlib Figures; scripts save them)
- :mod:`enclab.lrde`       extreme low-resolution encoder (Zhang & Gao): model, dwell, emcee fit
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
