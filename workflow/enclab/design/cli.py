"""Command line of design mode: ``python -m enclab.design [--configfile config.yaml] [--out DIR]``.

Reads the ``design:`` block of the configuration (and ``devices``, ``derivatives``; for a
logged workspace the manifest and the log), runs :func:`enclab.design.pipeline.run_design` and
writes ``design.json`` (``{"design": ...}``), ``designs.csv`` and ``pareto.png`` into ``--out``.
Prints the chosen design in one line. Exit status 1 with a one-line message on bad input.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main"]


def _read_config(path: str) -> dict:
    import yaml

    try:
        with open(path, encoding="utf-8") as handle:
            config = yaml.safe_load(handle)
    except FileNotFoundError:
        raise ValueError(f"{path}: configuration file not found") from None
    if not isinstance(config, dict) or not isinstance(config.get("design"), dict):
        raise ValueError(f"{path}: no design: block (see docs/design.md)")
    return config


def load_trajectory(config: dict) -> "object | None":
    """The logged truth of ``design.workspace.log`` (None for a box workspace)."""
    log_id = (config["design"].get("workspace") or {}).get("log")
    if log_id is None:
        return None
    from enclab.core import ingest, readers
    from enclab.design.pipeline import truth_trajectory

    data_root, manifest = readers.read_manifest(config["manifest"], devices=config.get("devices") or {})
    entries = {e["id"]: e for e in manifest}
    if log_id not in entries:
        raise ValueError(f"design.workspace.log {log_id!r} is not a log of {config['manifest']}")
    df, meta = ingest.ingest_log(entries[log_id], data_root, config.get("devices") or {})
    return truth_trajectory(df, meta)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m enclab.design", description=__doc__.split("\n")[0])
    parser.add_argument("--configfile", default="config.yaml", help="configuration with a design: block")
    parser.add_argument("--out", default="results/design", help="output folder (default results/design)")
    parser.add_argument("--trajectories", type=int, help="override design.check.trajectories (0: no check)")
    args = parser.parse_args(argv)
    from enclab.core import atomic
    from enclab.core.errors import EnclabInputError

    try:
        config = _read_config(args.configfile)
        design = dict(config["design"])
        if args.trajectories is not None:
            design["check"] = {**(design.get("check") or {}), "trajectories": args.trajectories}
        from enclab.design.pipeline import run_design

        block, table, figure = run_design(design, config.get("devices"), config.get("derivatives"),
                                          load_trajectory(config))
    except (EnclabInputError, ValueError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    out = Path(args.out)
    atomic.write_json(block, out / "design.json")
    atomic.write_table(table, out / "designs.csv")
    atomic.save_figure(figure, out / "pareto.png")
    chosen = block["design"]["chosen"]
    summary = {"chosen": None if chosen is None else {
        "resolution": chosen["resolution"], "filters": [f["label"] for f in chosen["filters"]],
        "cost": chosen["cost"], "margin": round(chosen["margin"], 4)},
        "check": {k: v.get("pass_rate") for k, v in block["design"].get("check", {}).items()
                  if isinstance(v, dict)}}
    print(json.dumps(summary))
    return 0
