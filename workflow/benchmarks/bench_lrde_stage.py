"""How long does the whole LRDE stage take per embedded log?

Wall time of the whole LRDE stage (fits, effect comparison, figures) per embedded log.

Every log of the manifest whose ``analysis.stages`` holds ``lrde`` is ingested and run through
:func:`enclab.lrde.pipeline.analyse_lrde_log` with ``config.yaml``'s ``lrde`` settings (and
the log's own ``analysis.lrde``), as the ``lrde_fit`` rule does, ``--repeats`` times; the
chosen model, the trust flags and a digest of the block are recorded with the time, and
beside it the mean of a 5M-iteration Python loop's wall time before and after the run
(``reference_s``): ``wall_s / reference_s`` compares across machines and loads.

Usage::

    PYTHONPATH=workflow python -m benchmarks.bench_lrde_stage --repeats 3
    PYTHONPATH=../other-checkout/workflow:workflow python -m benchmarks.bench_lrde_stage \\
        --label other   # the same logs with another version of the package
    PYTHONPATH=workflow python -m benchmarks.bench_lrde_stage --threads 2 --logs lrde_closed_r01

Writes ``<out>/lrde_stage.csv`` (appends rows).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import time
import zlib

import pandas as pd
import yaml

from .helpers import ROOT, reference_loop_seconds, stamp


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--manifest", default=str(ROOT / "data" / "manifest.yaml"))
    ap.add_argument("--config", default=str(ROOT / "config.yaml"))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--label", default="this")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    ap.add_argument("--threads", type=int, default=1,
                    help="processes for the before and after fits (analyse_lrde_log threads)")
    ap.add_argument("--logs", nargs="*", default=None, help="only these log ids")
    args = ap.parse_args(argv)
    import enclab
    from enclab.core import ingest, readers
    try:
        from enclab.core.allocator import keep_freed_memory
    except ImportError:  # older versions of the package
        pass
    else:
        keep_freed_memory()  # as the rule's job process does (enclab.runner.run)
    try:
        from enclab.core.parallel import limit_blas_threads
    except ImportError:  # older versions of the package run with BLAS's own default
        limit_blas_threads = None
    if limit_blas_threads is not None:
        limit_blas_threads(args.threads)  # as the rule's job process does
    from enclab.lrde.pipeline import analyse_lrde_log

    config = yaml.safe_load(pathlib.Path(args.config).read_text())
    devices = config.get("devices") or {}
    data_root, entries = readers.read_manifest(args.manifest, devices)
    rows = []
    for entry in entries:
        if "lrde" not in ((entry.get("analysis") or {}).get("stages") or []):
            continue
        if args.logs is not None and entry["id"] not in args.logs:
            continue
        df, meta = ingest.ingest_log(entry, data_root, devices)
        settings = dict(config.get("lrde") or {})
        settings.update((entry.get("analysis") or {}).get("lrde") or {})
        seed = [int(settings.pop("seed", 0)), zlib.crc32(meta["log_id"].encode())]
        for r in range(args.repeats):
            ref_before = reference_loop_seconds(clock=time.perf_counter)
            started = time.perf_counter()
            # Older versions of the package have no threads argument.
            extra = {} if args.threads == 1 else {"threads": args.threads}
            block, figures, _, _ = analyse_lrde_log(df, meta, seed, settings, **extra)
            wall = time.perf_counter() - started
            ref = 0.5 * (ref_before + reference_loop_seconds(clock=time.perf_counter))
            for fig in figures.values():
                fig.clear()
            model = (block.get("model") or {}).get("chosen")
            trust = block.get("trust") or {}
            # relative to the repository: another checkout's package shows as ../<checkout>/...
            package = os.path.relpath(pathlib.Path(enclab.__file__).parent, ROOT)
            rows.append({"label": args.label, "package": package,
                         "log_id": meta["log_id"], "samples": len(df), "threads": args.threads, "repeat": r,
                         "wall_s": wall, "reference_s": ref, "model": model,
                         "A12_trusted": (trust.get("A12") or {}).get("trusted"),
                         "converged": block["diagnostics"]["converged"],
                         # Same digest across repeats and thread counts: the block (and so
                         # summary.json) does not depend on timing or on the process layout.
                         "block_sha256": hashlib.sha256(json.dumps(
                             block, sort_keys=True, default=str).encode()).hexdigest()[:16]})
            print(rows[-1], flush=True)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "lrde_stage.csv"
    new = stamp(pd.DataFrame(rows))
    if path.exists():
        new = pd.concat([pd.read_csv(path), new], ignore_index=True)
    new.to_csv(path, index=False)


if __name__ == "__main__":
    main()
