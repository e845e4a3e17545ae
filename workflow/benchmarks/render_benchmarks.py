"""Generate ``docs/benchmarks.md`` from the benchmark tables in ``results/benchmarks/*.csv``.

Every benchmark script writes its summary rows with ``date``, ``machine`` and ``command``
(:func:`benchmarks.helpers.stamp`). Here each table gets a ``run`` column whose key (``r1``, ``r2``, ...)
points to the run's date, machine and command listed under the table, so every number keeps
the run that produced it. Tables named in :data:`TABLES` come first, with their caption; any
other CSV with provenance follows under its file name; per-draw tables (more than
``--max-rows`` rows) are named, not printed.

``results/`` is not versioned, and a benchmark table can take hours to measure, so every table
rendered is also kept in ``docs/benchmarks/`` (the record, versioned with the page). Before
rendering, tables found in the record but not in ``results/benchmarks`` are copied back: a fresh
clone renders the same page, and a new run of one script adds to the others instead of erasing
them. A command recorded in an older form (the script's path, ``python
workflow/benchmarks/x.py``) is shown, and kept in the record, in the form that reruns it from
the repository root (:func:`benchmarks.helpers.rerun_command`). ``--from-markdown`` rebuilds the printed tables of an existing ``docs/benchmarks.md``
(the page holds every value of a printed table as rendered, so the page it renders again is the
same).

Usage::

    PYTHONPATH=workflow python -m benchmarks.render_benchmarks            # results/benchmarks -> docs/benchmarks.md
    PYTHONPATH=workflow python -m benchmarks.render_benchmarks --check    # exit 1 if docs/benchmarks.md is stale
    PYTHONPATH=workflow python -m benchmarks.render_benchmarks --from-markdown docs/benchmarks.md
"""
from __future__ import annotations

import argparse
import csv
import io
import re
import shutil
import sys
from pathlib import Path

import pandas as pd

from .helpers import PROVENANCE, ROOT, module_command, rerun_command

# (file name, title, caption): the order of docs/benchmarks.md.
TABLES = [
    ("first_run.csv", "First run",
     "`make run` and `make test` on a fresh clone, install included."),
    ("performance.csv", "Quantization error: throughput of the stages",
     "Per-stage throughput, time as a ratio to `pyarrow` reading the same file (same run), peak "
     "memory of the streamed long-log path (`bench_performance.py`), the per-log cost of "
     "Snakemake jobs in a batch (`bench_batch.py`), and the peak memory of the whole workflow on "
     "one long truth/measured log (section `workflow`, `bench_memory.py`)."),
    ("lrde_summary.csv", "Low-resolution encoder: accuracy and calibration",
     "Posterior and baseline estimators of paper 002 over simulated draws (`bench_lrde.py`)."),
    ("lrde_effects_summary.csv", "Low-resolution encoder: effects named and intervals kept",
     "Encoder, clock and motion effects on simulated logs (`bench_lrde_effects.py`)."),
    ("lrde_detectability.csv", "Low-resolution encoder: which logs hold the evidence",
     "Named rates at 3x the detection threshold, overall and among the logs whose readings favour "
     "the true model over the sinusoid's fit (oracle BIC gain > 0; `lrde_detectability.py`)."),
    ("lrde_misfit_trace.csv", "Low-resolution encoder: effects outside the catalogue",
     "The localized check on catalogued effects (false flags) and on effects no candidate "
     "describes (flagged, placed on the covariate where they act, or misnamed; "
     "`lrde_misfit_trace.py`). Rows with `flagged_headed_by_dwells` empty are of a check "
     "without the dwell rows; runs with the same command use the same seeds."),
    ("lrde_min_gain.csv", "Low-resolution encoder: which small gains to pool",
     "Coverage of the 90 % intervals after, when models not ruled out beside a kept sinusoid "
     "are pooled from a held-out gain of `min_gain` nats on (`lrde_min_gain.py`)."),
    ("lrde_fold_rule.csv", "Low-resolution encoder: the comparison's fold test",
     "Named rates when a model may predict a fold worse within `fold_se` of that fold's "
     "standard errors (2, the stage's) or not at all (0), on the effects benchmark's logs; "
     "the draws whose choice differs (`lrde_fold_rule.py`)."),
    ("lrde_calibration.csv", "Low-resolution encoder: the posterior's own calibration",
     "Coverage of the 90 % intervals when the true model is fitted (no comparison, no pooling), "
     "and of E_b's posterior with every other parameter at the truth (`lrde_calibration.py`)."),
    ("lrde_truth_loop.csv", "Low-resolution encoder: the truth channel's findings in the fit",
     "Hysteresis logs with a fine channel: named by the comparison alone and with the residual "
     "stage's findings, coverage of A12, E_b, a and b before and after (`lrde_truth_loop.py`)."),
    ("lrde_closed_loop.csv", "Low-resolution encoder: inside a PID loop",
     "The LRDE stage on closed-loop logs (paper 002 Fig. 5) per cell of gains and encoder "
     "effect: coverage of the 90 % intervals of A12 (the true angle's mean stroke over the "
     "reference's cycles, and the stroke of its cycle-averaged motion) and E_b, untrusted flags "
     "(also on the logs the model describes), wall time (`lrde_closed_loop.py`; machine "
     "loaded, see the command; `wall_over_reference` divides by a 5M-iteration Python loop "
     "timed beside each log) and the commits the rows ran (`code`; `earlier`: rows recorded "
     "before that column, by an older version of the stage)."),
    ("lrde_loop_burn_in.csv", "Low-resolution encoder: the loop posterior's burn-in",
     "The loop structure each closed-loop log's stage chose, fitted with the stage's burn-in "
     "(400 steps, checked after the first half) and with twice that, from the same seed: "
     "shifts of the A12 and E_b medians in half-widths, ratios of the 90 % intervals' widths, "
     "per group of chains that ended after half the burn-in or not (`lrde_loop_burn_in.py`)."),
    ("lrde_stage.csv", "Low-resolution encoder: stage cost",
     "Wall time of the whole LRDE stage of the embedded logs (`bench_lrde_stage.py`; target 30 s "
     "on 2 cores; `threads` is the stage's processes, 2 in the workflow)."),
    ("lrde_stage_earlier.csv", "Low-resolution encoder: stage cost of earlier versions",
     "The same benchmark on earlier versions of the package, one process each."),
    ("lrde_interval.csv", "Low-resolution encoder: interval probabilities",
     "Cost of the likelihood's interval probabilities, near entries gathered by kind or every "
     "entry in place, by position noise (`bench_lrde_interval.py`)."),
    ("lrde_oracle_summary.csv", "Low-resolution encoder: the information bound",
     "The best RMSE any estimator could reach on the same draws (`lrde_oracle_bound.py`)."),
    ("lrde_throughput_summary.csv", "Low-resolution encoder: MCMC cost",
     "Wall time, ESS and ESS/s of the emcee fit (`bench_lrde_throughput.py`)."),
    ("challenge_residuals_summary.csv", "Residual stage: undeclared effects",
     "Identification, false names on clean logs, interval coverage and after/floor "
     "(`challenge_residuals.py`)."),
    ("mrdlab_rig.csv", "Residual stage: the MRDLab rig, held out",
     "Residual std (mrad; steady strokes / all samples) of the CUI channel on held-out runs, per "
     "model, split and condition, against the targets and the independent study (`mrdlab_rig.py`)."),
    ("mrdlab_rig_params.csv", "Residual stage: the MRDLab rig's shared parameters",
     "Shared parameters per fold and their spread across folds (`mrdlab_rig.py`)."),
    ("mrdlab_rigs.csv", "Residual stage: the rig rule on both MRDLab run sets",
     "The rig rule's model on `Tool_4_Maryland_L_2` (20 runs, loads 10-40 %) and "
     "`Tool_4_Maryland_L_4` (50 runs, loads 10-100 %): held-out std (rad) per split and condition, "
     "the training runs' own held-out std, whether the split extrapolates and the term that "
     "carries its held-out excess, CPU seconds beside a 5M-iteration loop "
     "(`mrdlab_rig.py --rules`)."),
    ("exact_model_precision.csv", "Exact model: measured/predicted over pooled runs",
     "(`exact_model_precision.py`)."),
    ("design_check.csv", "Design mode: chosen designs against their budgets",
     "Simulated trajectories per budget, exact-model design and PQN-only design."),
    ("design_search.csv", "Design mode: search cost",
     "3 joints, 7^3 motion centres, the whole filter bank, 8 resolutions per joint "
     "(`design_search.py`; target 60 s)."),
    ("corpus.csv", "Bad input", "The bad-input corpus through the workflow (`corpus_report.py`)."),
]


def _cell(value) -> str:
    if isinstance(value, float):
        if value != value:  # NaN
            return ""
        return f"{value:.4g}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(frame: pd.DataFrame) -> str:
    """A GitHub-flavoured Markdown table of ``frame`` (no index)."""
    head = "| " + " | ".join(map(str, frame.columns)) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    body = ["| " + " | ".join(_cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([head, rule, *body])


def render_table(frame: pd.DataFrame) -> str:
    """The table with a ``run`` key per row, then the runs' date, machine and command."""
    frame = frame.assign(command=frame["command"].astype(str).map(rerun_command))
    runs = frame[list(PROVENANCE)].astype(str).drop_duplicates().reset_index(drop=True)
    runs["run"] = [f"r{i + 1}" for i in range(len(runs))]
    keyed = frame.merge(runs, on=list(PROVENANCE), how="left")
    shown = keyed.drop(columns=list(PROVENANCE))
    shown.insert(0, "run", shown.pop("run"))
    notes = [f"- `{r.run}`: {r.date}; {r.machine}; `{r.command}`" for r in runs.itertuples()]
    return markdown_table(shown) + "\n\n" + "\n".join(notes)


def _split_row(line: str) -> list[str]:
    """The cells of one Markdown table row, ``\\|`` read back as ``|``."""
    inner = line.strip()[1:-1]
    cells = re.split(r"(?<!\\)\|", inner)
    return [c.strip().replace("\\|", "|") for c in cells]


_RUN_NOTE = re.compile(r"^- `(r\d+)`: ([^;]*); (.*?); `(.*)`$")


def tables_from_markdown(text: str) -> dict[str, pd.DataFrame]:
    """The printed tables of a page :func:`render` wrote, by file name, with their provenance.

    Cells come back as the page shows them (floats to 4 significant digits), which render the
    same; tables the page names but does not print are not in the result."""
    names = {title: name for name, title, _ in TABLES}
    tables: dict[str, pd.DataFrame] = {}
    sections = re.split(r"^## ", text, flags=re.MULTILINE)[1:]
    for section in sections:
        title, _, body = section.partition("\n")
        rows = [line for line in body.splitlines() if line.startswith("| ")]
        notes = {m.group(1): m.group(2, 3, 4) for m in map(_RUN_NOTE.match, body.splitlines()) if m}
        if len(rows) < 2 or not notes:
            continue
        head = _split_row(rows[0])
        if head[0] != "run":
            continue
        records = []
        for line in rows[1:]:
            cells = _split_row(line)
            run = notes[cells[0]]
            records.append([*run, *cells[1:]])
        frame = pd.DataFrame(records, columns=[*PROVENANCE, *head[1:]])
        # Through CSV, so that the types are the ones a script's CSV gives when read back.
        buffer = io.StringIO()
        frame.replace("", None).to_csv(buffer, index=False)
        buffer.seek(0)
        tables[names.get(title, f"{title}.csv")] = pd.read_csv(buffer)
    return tables


def restore(bench_dir: Path, record_dir: Path) -> list[str]:
    """Copy the tables of ``record_dir`` that ``bench_dir`` lacks; the names copied."""
    bench_dir.mkdir(parents=True, exist_ok=True)
    copied = []
    for path in sorted(record_dir.glob("*.csv")) if record_dir.is_dir() else []:
        if not (bench_dir / path.name).exists():
            shutil.copyfile(path, bench_dir / path.name)
            copied.append(path.name)
    return copied


def record_table(source: Path, target: Path) -> None:
    """Copy the CSV ``source`` to ``target`` with its commands in the form that reruns them
    (:func:`benchmarks.helpers.rerun_command`); every other cell as it is (a table without
    such a command is copied byte for byte)."""
    text = source.read_text(encoding="utf-8")
    rows = list(csv.reader(io.StringIO(text)))
    column = rows[0].index("command") if rows and "command" in rows[0] else None
    if column is None:
        if source.resolve() != target.resolve():
            shutil.copyfile(source, target)
        return
    changed = False
    for row in rows[1:]:
        if column < len(row) and rerun_command(row[column]) != row[column]:
            row[column], changed = rerun_command(row[column]), True
    if not changed:
        if source.resolve() != target.resolve():
            shutil.copyfile(source, target)
        return
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    target.write_text(out.getvalue(), encoding="utf-8")


def keep_record(bench_dir: Path, record_dir: Path) -> None:
    """Copy every table of ``bench_dir`` into ``record_dir`` (:func:`record_table`)."""
    record_dir.mkdir(parents=True, exist_ok=True)
    for path in bench_dir.glob("*.csv"):
        record_table(path, record_dir / path.name)


def render(bench_dir: Path, max_rows: int = 80) -> str:
    """The whole ``docs/benchmarks.md`` text."""
    lines = ["# Benchmarks", "",
             f"Generated by `{module_command('render_benchmarks')}` from "
             "`results/benchmarks/*.csv` (kept in `docs/benchmarks/`); do not edit by hand. "
             "Each row's `run` names the date, machine and command that produced it; the "
             "commands run from the repository root. The scripts are the package "
             "`workflow/benchmarks/` (their docstrings say what they measure; "
             "[development](development.md#benchmarks) lists them); numbers quoted anywhere in "
             "the docs come from these tables.", ""]
    known = {name for name, _, _ in TABLES}
    files = [(name, title, caption) for name, title, caption in TABLES
             if (bench_dir / name).exists()]
    files += [(p.name, p.stem, "") for p in sorted(bench_dir.glob("*.csv")) if p.name not in known]
    skipped = []
    for name, title, caption in files:
        frame = pd.read_csv(bench_dir / name)
        missing = [c for c in PROVENANCE if c not in frame.columns]
        if missing:
            skipped.append(f"`{name}` (no {', '.join(missing)} column)")
            continue
        lines += [f"## {title}", ""]
        if caption:
            lines += [caption, ""]
        if len(frame) > max_rows:
            lines += [f"`results/benchmarks/{name}`: {len(frame)} rows (per draw or per log), "
                      "not printed.", ""]
            continue
        lines += [render_table(frame), ""]
    if skipped:
        lines += ["## Not rendered", "", "Tables without provenance: " + ", ".join(skipped) + ".", ""]
    return "\n".join(lines).rstrip() + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=ROOT / "results" / "benchmarks")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks.md")
    parser.add_argument("--record-dir", type=Path, default=ROOT / "docs" / "benchmarks",
                        help="the versioned copy of the tables (restored from, then updated)")
    parser.add_argument("--max-rows", type=int, default=80)
    parser.add_argument("--check", action="store_true",
                        help="exit 1 when --out differs from what the tables give")
    parser.add_argument("--from-markdown", type=Path, default=None, metavar="MD",
                        help="first write the printed tables of this page into --bench-dir "
                             "(tables already there are kept)")
    args = parser.parse_args(argv)
    if args.check:
        # The record alone, as a fresh clone sees it.
        text = render(args.record_dir, args.max_rows)
        current = args.out.read_text(encoding="utf-8") if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is stale: run {module_command('render_benchmarks')}", file=sys.stderr)
            return 1
        return 0
    if args.from_markdown:
        args.bench_dir.mkdir(parents=True, exist_ok=True)
        for name, frame in tables_from_markdown(
                args.from_markdown.read_text(encoding="utf-8")).items():
            if not (args.bench_dir / name).exists():
                frame.to_csv(args.bench_dir / name, index=False)
                print(f"rebuilt {args.bench_dir / name} from {args.from_markdown}")
    for name in restore(args.bench_dir, args.record_dir):
        print(f"restored {args.bench_dir / name} from {args.record_dir}")
    text = render(args.bench_dir, args.max_rows)
    args.out.write_text(text, encoding="utf-8")
    keep_record(args.bench_dir, args.record_dir)
    print(f"wrote {args.out} and the tables behind it in {args.record_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
