"""Run the bad-input corpus (tests/corpus/cases.py) through the real Snakemake workflow.

``run_corpus(work)`` builds every case under ``work``, runs the workflow once over all log
cases (plus a clean control log) with ``--keep-going``, once per broken manifest or config
(those must stop before any job), twice per run fault (``extra["fault"]``: once with the fault,
once after it was lifted, in the same workspace), and returns one :class:`Outcome` per case with
the message the user got. Input checksums are taken before and compared after everything ran.

An unreadable file stays readable to root: run as root, the workflow runs without the
capabilities that let root read any file (``setpriv``), as an ordinary user's would.
"""
from __future__ import annotations

import copy
import hashlib
import os
import resource
import shutil
import signal
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from enclab.core.atomic import read_texts
from enclab.report import failure_of

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES, Case, good_entry, good_table, write_csv  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SNAKEMAKE = Path(sys.executable).with_name("snakemake")
SMALL_BANK = {"d": [1, 2], "n": [1, 2], "fc_hz": [50, 100], "discretization": ["exponential"]}


@dataclass
class Outcome:
    case: Case
    message: str  # the one-line error the user got, or "" when the log completed
    completed: bool  # the log produced a summary.json (log cases) / the run passed (others)
    leftovers: list[str]  # outputs of a failed log that should not exist
    report: dict | None  # time_report of a completed log
    warnings: list[str] = field(default_factory=list)  # summary.json warnings of a completed log

    @property
    def passed(self) -> bool:
        if self.case.extra.get("fault"):  # the fault's line, then a rerun that completes
            return (self.completed and not self.leftovers
                    and all(f in self.message for f in self.case.expect))
        if self.case.expect is None:
            wanted = self.case.extra.get("report", {})
            warning = self.case.extra.get("warning")
            return (self.completed and all(self.report.get(k) == v for k, v in wanted.items())
                    and (warning is None or any(warning in w for w in self.warnings)))
        return (not self.completed and not self.leftovers
                and all(f in self.message for f in self.case.expect))


def _config(manifest: str, changes: dict | None = None) -> dict:
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["manifest"] = manifest
    config["derivatives"]["bank"] = dict(SMALL_BANK)
    config["derivatives"]["export"] = [{"d": 1, "n": 1, "fc_hz": 50, "discretization": "exponential"}]
    config["figures"]["fig7_group"] = "none"
    for dotted, value in (changes or {}).items():
        target = config
        *path, last = dotted.split(".")
        for key in path:
            target = target[key]
        target[last] = value
    return config


# Root reads a mode-000 file anyway; without these capabilities it reads as a user would.
_AS_A_USER = ["setpriv", "--inh-caps=-dac_override,-dac_read_search",
              "--bounding-set=-dac_override,-dac_read_search"]
def disk_full_limit() -> int:
    """Bytes past which a write fails, for a simulated full disk.

    Snakemake's source cache copies the workflow's own files (schemas, rule files, scripts)
    before any job runs, so the limit leaves the largest of them room (a quarter more than its
    size, and never under 20 kB): a limit fixed by hand fails the run itself once a schema grows
    past it. A log's staged outputs (its Parquet tables and figures) are larger.
    """
    sources = [ROOT / "Snakefile", *(ROOT / "workflow" / "schemas").glob("*"),
               *(ROOT / "workflow" / "rules").glob("*.smk"), *(ROOT / "scripts").glob("*.py")]
    return max(20_000, int(1.25 * max(p.stat().st_size for p in sources)))


# A full disk, simulated: writes past this many bytes fail with EFBIG ("File too large"), as
# on a full disk or a quota (SIGXFSZ ignored).
FILE_SIZE_LIMIT = disk_full_limit()


def unreadable_files_possible() -> bool:
    """Whether a mode-000 file is unreadable to the workflow (not root, or root and setpriv)."""
    return os.geteuid() != 0 or shutil.which("setpriv") is not None


def file_size_limit() -> None:
    """``preexec_fn`` of a workflow run on a full disk (:data:`FILE_SIZE_LIMIT`)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_SIZE_LIMIT, FILE_SIZE_LIMIT))


def _snakemake(work: Path, config: dict, *extra: str, disk_full: bool = False
               ) -> subprocess.CompletedProcess:
    (work / "config.yaml").write_text(yaml.safe_dump(config))
    command = [str(SNAKEMAKE), "--snakefile", str(ROOT / "Snakefile"), "--directory", str(work),
               "--configfile", str(work / "config.yaml"), "--cores", "2", "--keep-going", *extra]
    if os.geteuid() == 0 and shutil.which("setpriv"):
        command = _AS_A_USER + command
    return subprocess.run(command, cwd=work, capture_output=True, text=True, timeout=1200,
                          env=dict(os.environ, MPLBACKEND="Agg"),
                          preexec_fn=file_size_limit if disk_full else None)


def _error_line(text: str) -> str:
    """The enclab error line of a rule log or of snakemake's output (first match)."""
    for line in text.splitlines():
        if " ERROR " in line:
            return line.split(" ERROR ", 1)[1].strip()
    for line in text.splitlines():
        if ("expected" in line or "Error" in line) and ":" in line:
            return line.strip()
    return ""


def checksums(folder: Path) -> dict[str, str]:
    """SHA-256 of every file (a file this user may not read: its size, mode and mtime)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            out[str(p.relative_to(folder))] = (
                hashlib.sha256(p.read_bytes()).hexdigest() if os.access(p, os.R_OK)
                else f"unreadable {p.stat().st_size} {p.stat().st_mode:o} {p.stat().st_mtime_ns}")
    return out


STAGE_OUTPUTS = {"ingest": "canonical.parquet", "requantize": "requantized.parquet",
                 "kinematics": "kinematics.parquet", "derivatives": "derivatives.parquet",
                 "moments": "moments.json", "theory": "theory.json", "lrde_fit": "lrde/lrde.json"}


def _log_outcome(work: Path, case: Case) -> Outcome:
    results = work / "results" / case.name
    summary = results / "summary.json"
    failure = failure_of(read_texts(results / "logs", "*.log"))
    message = failure["error"] if failure["stage"] else ""
    if summary.exists():
        block = yaml.safe_load(summary.read_text())
        return Outcome(case, message, True, [], block.get("time_report"), block.get("warnings") or [])
    # Outputs of the stages before the failing one are complete results and stay; the failing
    # stage's own output (and everything after it) must not exist. A chunked log's stages run
    # as one (quantization): it keeps nothing.
    names = list(STAGE_OUTPUTS)
    stage = failure["stage"]
    failing = names if stage == "quantization" else names[names.index(stage):] if stage in names else []
    leftovers = [STAGE_OUTPUTS[n] for n in failing if (results / STAGE_OUTPUTS[n]).exists()]
    return Outcome(case, message, False, leftovers, None)


def run_corpus(work: Path) -> tuple[list[Outcome], bool]:
    """Build and run every case under ``work``; return the outcomes and whether the inputs'
    checksums are unchanged after all runs."""
    data = work / "logs"
    data.mkdir(parents=True, exist_ok=True)
    log_cases = [c for c in CASES if c.scope == "log" and not c.extra.get("fault")]
    fault_cases = [c for c in CASES if c.extra.get("fault")]
    entries = [c.build(data, c.name) for c in log_cases]
    write_csv(good_table(), data / "control.csv")
    entries.append(good_entry("control", "control.csv"))
    up_front, per_log_config = [], []
    for case in CASES:
        if case.scope == "log":
            continue
        built = case.build(data, case.name)
        (up_front if case.up_front else per_log_config).append((case, built))
    before = checksums(data)
    outcomes = []

    (work / "manifest.yaml").write_text(yaml.safe_dump({"data_root": "logs", "logs": entries}))
    _snakemake(work, _config("manifest.yaml"))
    outcomes += [_log_outcome(work, c) for c in log_cases]

    def up_front_outcome(item) -> Outcome:
        case, built = item
        sub = work / "up_front" / case.name
        sub.mkdir(parents=True, exist_ok=True)
        os.symlink(data, sub / "logs")
        if case.scope == "manifest":
            logs = [built, copy.deepcopy(built)] if case.extra.get("duplicate") else [built]
            (sub / "manifest.yaml").write_text(yaml.safe_dump({"data_root": "logs", "logs": logs}))
            config = _config("manifest.yaml")
        else:
            (sub / "manifest.yaml").write_text(yaml.safe_dump(
                {"data_root": "logs", "logs": [good_entry("control", "control.csv")]}))
            config = _config("manifest.yaml", built)
        proc = _snakemake(sub, config, "--dry-run")
        text = proc.stdout + proc.stderr
        message = next((line.strip() for line in text.splitlines()
                        if any(f in line for f in case.expect)), _error_line(text))
        return Outcome(case, message, proc.returncode == 0, [], None)

    # Each is a Snakemake start that stops before any job: two at a time (a start is mostly
    # one core's imports and parsing).
    with ThreadPoolExecutor(max_workers=2) as pool:
        outcomes += list(pool.map(up_front_outcome, up_front))

    for case in fault_cases:
        sub = work / "faults" / case.name
        (sub / "logs").mkdir(parents=True, exist_ok=True)
        entry = case.build(sub / "logs", case.name)
        (sub / "manifest.yaml").write_text(yaml.safe_dump({"data_root": "logs", "logs": [entry]}))
        # The fault hits the log's chunk; then it is lifted and the workspace run again as it
        # is, with no cleaning: the log must complete.
        _snakemake(sub, _config("manifest.yaml"), "--", f"results/{case.name}/summary.json",
                   disk_full=case.extra["fault"] == "disk_full")
        failure = failure_of(read_texts(sub / "results" / case.name / "logs", "*.log"))
        _snakemake(sub, _config("manifest.yaml"))
        outcome = _log_outcome(sub, case)
        outcome.message = failure["error"] if failure["stage"] else ""
        outcomes.append(outcome)

    for case, built in per_log_config:
        sub = work / "per_log" / case.name
        sub.mkdir(parents=True, exist_ok=True)
        os.symlink(data, sub / "logs")
        (sub / "manifest.yaml").write_text(yaml.safe_dump(
            {"data_root": "logs", "logs": [good_entry(case.name, "control.csv")]}))
        _snakemake(sub, _config("manifest.yaml", built))
        outcomes.append(_log_outcome(sub, case))
    return outcomes, checksums(data) == before
