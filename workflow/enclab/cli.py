"""``enclab``: one file, one command, for a lab that wants to try one log before a manifest.

::

    enclab residuals rig1.csv --truth motor_angle --measured output_angle
    enclab lrde drill.csv --counts counts --step 0.0015708

Each analysis command writes a one-entry manifest for the file and a configuration (the
project's ``config.yaml``, or ``--configfile``) into an output folder (default
``enclab-<log id>/`` in the current directory), runs the Snakemake workflow there and prints
where the results are and what they say. The file is read in place and never modified. The
workflow is the checkout's, or the copy a plain install carries
(:func:`enclab.core.resources.workflow_root`).

Subcommands live in :data:`COMMANDS` (built here) and :data:`EXTERNAL_COMMANDS` (a module's
``main(argv)``, imported when called): a new analysis adds one entry.
"""
from __future__ import annotations

import argparse
import importlib
import os
import re
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import yaml

import enclab
from enclab import report
from enclab.core import atomic
from enclab.core.errors import EnclabInputError
from enclab.core.manifest import validate_manifest
from enclab.core.resources import workflow_root

__all__ = ["COMMANDS", "EXTERNAL_COMMANDS", "build_entry", "main"]

# Snakefile, config.yaml, workflow/ and scripts/: the checkout's, or the installed copy.
ROOT = workflow_root()
_FORMATS = {".csv": "csv", ".txt": "text", ".dat": "text", ".tsv": "text", ".parquet": "parquet",
            ".mat": "mat"}

# name -> (module, function, one-line help): ``function(argv)`` runs the subcommand.
EXTERNAL_COMMANDS: dict[str, tuple[str, str, str]] = {
    "design": ("enclab.design.cli", "main",
               "design mode: the resolution and filter that meet an error budget"),
}


def _log_id(path: Path) -> str:
    name = path.name
    for suffix in (".gz", *_FORMATS):
        name = name.removesuffix(suffix) if name.endswith(suffix) else name
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", name).lstrip("_.-")
    return name or "log"


def _channel_name(column: str, fallback: str) -> str:
    name = re.sub(r"\W+", "_", column).strip("_")
    return name if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name or "") else fallback


def _format_of(path: Path, declared: str | None) -> str:
    if declared:
        return declared
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    if suffixes and suffixes[-1] in _FORMATS:
        return _FORMATS[suffixes[-1]]
    raise ValueError(f"{path}: cannot tell the format from the name; give --format "
                     f"({', '.join(sorted(set(_FORMATS.values())))})")


def build_entry(command: str, args: argparse.Namespace) -> dict:
    """The one manifest entry of ``enclab <command> FILE ...`` (not yet validated).

    ``file`` is the file's name; its folder becomes the manifest's ``data_root``.
    """
    path = Path(args.file)
    fmt = _format_of(path, args.format)
    entry = {"id": args.id or _log_id(path), "file": path.name, "format": fmt,
             "device": {"kind": "single_joint"}}
    if args.time_unit == "samples":  # a sample-index column: the rate gives the seconds
        if args.rate is None:
            raise ValueError("--time-unit samples needs --rate (the sample rate in Hz)")
        entry["time"] = {"column": args.time, "unit": "samples", "rate_hz": args.rate}
    elif args.rate is not None:
        entry["time"] = {"rate_hz": args.rate}
    else:
        entry["time"] = {"column": args.time, "unit": args.time_unit}
    reader = {k: v for k, v in (("delimiter", args.delimiter), ("decimal", args.decimal),
                                ("encoding", args.encoding)) if v is not None}
    if reader:
        entry["reader"] = reader
    if command == "residuals":
        truth = _channel_name(args.truth, "truth")
        measured = _channel_name(args.measured, "measured")
        if measured == truth:
            measured = f"{measured}_measured"
        measured_channel = {"name": measured, "column": args.measured, "role": "measured",
                            "joint": 1, "unit": args.unit}
        if args.measured_step is not None:
            measured_channel.update(unit="counts", step=args.measured_step)
        entry["channels"] = [
            {"name": truth, "column": args.truth, "role": "truth", "joint": 1, "unit": args.unit},
            measured_channel]
        entry["analysis"] = {"stages": ["residuals"]}
    elif command == "lrde":
        channels = [{"name": _channel_name(args.counts, "counts"), "column": args.counts,
                     "role": "measured", "joint": 1, "unit": "counts", "step": args.step}]
        if args.truth is not None:
            channels.append({"name": _channel_name(args.truth, "truth"), "column": args.truth,
                             "role": "truth", "joint": 1, "unit": args.truth_unit})
        entry["channels"] = channels
        entry["analysis"] = {"stages": ["lrde"]}
    else:
        raise ValueError(f"unknown analysis command {command!r}")
    return entry


def _snakemake() -> list[str]:
    exe = Path(sys.executable).with_name("snakemake")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "snakemake"]


def _write_workspace(entry: dict, data_root: Path, out: Path, configfile: Path) -> None:
    config = yaml.safe_load(configfile.read_text(encoding="utf-8"))
    config["manifest"] = "manifest.yaml"
    config["only_logs"] = []
    # Design mode answers the project's error budget, not a question about this file.
    config.pop("design", None)
    manifest = {"data_root": str(data_root), "logs": [entry]}
    # the entry is checked here, before Snakemake starts
    validate_manifest(manifest, config.get("devices") or {}, f"enclab {entry['id']}")
    atomic.write_text(yaml.safe_dump(manifest, sort_keys=False), out / "manifest.yaml")
    atomic.write_text(yaml.safe_dump(config, sort_keys=False), out / "config.yaml")


def _results_listing(out: Path, log_id: str) -> list[str]:
    folder = out / "results" / log_id
    files = [p for p in sorted(folder.rglob("*")) if p.is_file()
             and not {"logs", "benchmarks"} & set(p.relative_to(folder).parts)
             and p.suffix in (".json", ".csv", ".png", ".md")]
    report = out / "results" / "report.html"
    return [str(p) for p in files] + ([str(report)] if report.exists() else [])


def _run_analysis(command: str, args: argparse.Namespace) -> int:
    if not (ROOT / "Snakefile").is_file():
        print(f"enclab {command}: the workflow (Snakefile) is missing from {ROOT}; reinstall "
              "enclab from its repository (pip install .)", file=sys.stderr)
        return 2
    path = Path(args.file)
    if not path.is_file():
        print(f"enclab {command}: {path}: file not found", file=sys.stderr)
        return 2
    try:
        entry = build_entry(command, args)
        out = Path(args.out or f"enclab-{entry['id']}").resolve()
        _write_workspace(entry, path.resolve().parent, out,
                         Path(args.configfile) if args.configfile else ROOT / "config.yaml")
    except (ValueError, EnclabInputError) as err:
        print(f"enclab {command}: {err}", file=sys.stderr)
        return 2
    base = _snakemake() + ["--snakefile", str(ROOT / "Snakefile"), "--directory", str(out),
                           "--configfile", str(out / "config.yaml"), "--workflow-profile",
                           str(ROOT / "workflow/profiles/default"), "--logger", "enclab"]
    print(f"==> enclab {command}: {path} as log '{entry['id']}', results in {out}/results/",
          file=sys.stderr)
    env = dict(os.environ, MPLBACKEND=os.environ.get("MPLBACKEND", "Agg"))
    done = subprocess.run(base + ["--cores", str(args.cores), *args.snakemake_args], env=env)
    if {"--dry-run", "-n"} & set(args.snakemake_args):
        return done.returncode
    if done.returncode == 0 and not args.no_report:
        subprocess.run(base + ["--cores", "1", "--report", str(out / "results/report.html"),
                               "--report-metadata", str(out / "results/report/metadata.yaml"),
                               "--report-stylesheet", str(ROOT / "workflow/report/report.css")],
                       env=env)
    summary = out / "results" / "summary.txt"
    if done.returncode == 0 and summary.exists():
        print("==> results:\n" + "\n".join(f"    {p}" for p in _results_listing(out, entry["id"])))
        print(summary.read_text(encoding="utf-8"), end="")
        return 0
    if (out / "results" / entry["id"] / "summary.json").exists():
        print(f"==> enclab {command}: log '{entry['id']}' completed, but the run failed after it "
              "(messages above)", file=sys.stderr)
        return 1
    failure = report.failure_of(atomic.read_texts(out / "results" / entry["id"] / "logs", "*.log"))
    print(f"==> enclab {command}: log '{entry['id']}' failed [{failure['stage']}]: "
          f"{failure['error']}", file=sys.stderr)
    return 1


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="the log (csv, text, parquet or mat; .gz too); more "
                        "Snakemake arguments after --, e.g. -- --dry-run")
    time = parser.add_argument_group("time base")
    time.add_argument("--time", default="t", metavar="COL", help="time column (default: t)")
    time.add_argument("--time-unit", default="s", choices=["s", "ms", "us", "ns", "samples"],
                      help="unit of the time column (default: s)")
    time.add_argument("--rate", type=float, metavar="HZ",
                      help="sample rate: instead of a time column, or with --time-unit samples")
    read = parser.add_argument_group("reading the file (manifest keys format and reader.*)")
    read.add_argument("--format", choices=sorted(set(_FORMATS.values())),
                      help="default: from the file name")
    read.add_argument("--delimiter", help="field separator, e.g. ';' (default: auto)")
    read.add_argument("--decimal", choices=[".", ","], help="decimal mark (default: .)")
    read.add_argument("--encoding", help="text encoding, e.g. latin-1 (default: utf-8)")
    run = parser.add_argument_group("the run")
    run.add_argument("--id", help="log id, names results/<id>/ (default: from the file name)")
    run.add_argument("--out", metavar="DIR",
                     help="output folder (default: enclab-<id> in the current directory)")
    run.add_argument("--configfile", metavar="YAML",
                     help="analysis configuration (default: the project's config.yaml)")
    run.add_argument("--cores", type=int, default=2, help="cores (default: 2)")
    run.add_argument("--no-report", action="store_true", help="skip the HTML report")


def _add_residuals(sub) -> None:
    p = sub.add_parser("residuals", help="residual of a measured channel against its truth",
                       description="The residual stage on one file: a measured encoder channel "
                       "against the exact quantizer model of a truth channel of the same joint, "
                       "and the effects that explain what is left.")
    p.add_argument("--truth", required=True, metavar="COL", help="truth (reference) column")
    p.add_argument("--measured", required=True, metavar="COL", help="measured encoder column")
    p.add_argument("--unit", default="rad", choices=["rad", "deg", "mrad"],
                   help="unit of both columns (default: rad)")
    p.add_argument("--measured-step", type=float, metavar="S",
                   help="the measured column holds integer counts of S rad")
    _common(p)


def _add_lrde(sub) -> None:
    p = sub.add_parser("lrde", help="stroke, bias and offset of a coarse encoder (Zhang & Gao)",
                       description="The low-resolution encoder analysis on one file: dwell "
                       "patterns and the Bayesian fit of stroke, bias and offset.")
    p.add_argument("--counts", required=True, metavar="COL", help="coarse encoder counts column")
    p.add_argument("--step", required=True, type=float, metavar="S", help="rad per count")
    p.add_argument("--truth", metavar="COL",
                   help="a finer reference channel (identifies the offset and the bias)")
    p.add_argument("--truth-unit", default="rad", choices=["rad", "deg", "mrad"],
                   help="unit of --truth (default: rad)")
    _common(p)


# name -> (add the subparser, run(command, args) -> exit code)
COMMANDS: dict[str, tuple[Callable, Callable[[str, argparse.Namespace], int]]] = {
    "residuals": (_add_residuals, _run_analysis),
    "lrde": (_add_lrde, _run_analysis),
}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="enclab", description="enclab: one file, one command. "
                                     "Analyses one log without a manifest (see each command's --help).")
    parser.add_argument("--version", action="version", version=f"enclab {enclab.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add, _ in COMMANDS.values():
        add(sub)
    for name, (_, _, help_text) in EXTERNAL_COMMANDS.items():
        sub.add_parser(name, help=help_text, add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``enclab`` console script; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in EXTERNAL_COMMANDS:
        module, function, _ = EXTERNAL_COMMANDS[argv[0]]
        try:
            target = getattr(importlib.import_module(module), function)
        except (ImportError, AttributeError):
            print(f"enclab {argv[0]}: not available in this installation ({module}.{function} "
                  "is missing)", file=sys.stderr)
            return 2
        return int(target(argv[1:]) or 0)
    # after "--": more Snakemake arguments, e.g. enclab residuals f.csv ... -- --dry-run
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    args = _parser().parse_args(argv[:len(argv) - len(extra) - 1] if "--" in argv else argv)
    args.snakemake_args = extra
    return COMMANDS[args.command][1](args.command, args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
