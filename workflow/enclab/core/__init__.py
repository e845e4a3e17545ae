"""Shared core of enclab: what every analysis needs, and nothing of any analysis.

- :mod:`enclab.core.errors`     :class:`~enclab.core.errors.EnclabInputError`: file, column, row
- :mod:`enclab.core.manifest`   manifest and configuration validation and normalisation
- :mod:`enclab.core.readers`    raw log readers (CSV, text exports, Parquet, MATLAB, gzip)
- :mod:`enclab.core.ingest`     pure conversions of raw logs to the canonical form (units,
  counters, time base); :func:`~enclab.core.ingest.ingest_log` reads and converts one entry
- :mod:`enclab.core.canonical`  the canonical log (Parquet + metadata), whole or streamed
- :mod:`enclab.core.atomic`     atomic writers of results (text, JSON, tables, figures) and readers
- :mod:`enclab.core.quantize`   the encoder/quantizer model on integer counts
- :mod:`enclab.core.resources`  where the workflow's files are (checkout or installed copy)

Only :mod:`~enclab.core.readers`, :mod:`~enclab.core.canonical` and :mod:`~enclab.core.atomic`
touch disk. Nothing here imports an analysis package (``propagation``, ``lrde``, ``residuals``,
``design``); ``tests/test_imports.py`` checks it.
"""

__all__ = ["errors", "manifest", "readers", "ingest", "canonical", "atomic", "quantize", "resources"]
