"""The bad-input corpus: every way a lab's log, manifest or configuration can be wrong.

Each :class:`Case` writes its files into a directory and returns either a manifest entry (a log
that must fail alone, or pass with a report) or a change to the manifest/config (which must be
rejected before any job runs). ``expect`` is a list of fragments the one-line error must
contain (file, column, row or key, and what was expected), ``None`` for cases that must pass.

Used by tests/test_corpus.py (through the real workflow) and workflow/benchmarks/corpus_report.py
(the table in the README's troubleshooting section). Files are small and generated here, so the
corpus needs no binary fixtures.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

FS = 1000.0
N = 2000
STEP = 1e-4  # rad per count of the good log's grid


def good_table(n: int = N) -> pd.DataFrame:
    t = np.arange(n) / FS
    counts = np.floor(0.05 / STEP * np.sin(2 * np.pi * 5.0 * t) + 0.5).astype(np.int64)
    return pd.DataFrame({"t": t, "angle": counts * STEP})


def good_entry(log_id: str, file: str, fmt: str = "csv") -> dict:
    return {"id": log_id, "file": file, "format": fmt, "device": "lrde_axis",
            "time": {"column": "t", "unit": "s", "nominal_rate_hz": FS},
            "channels": [{"name": "theta", "column": "angle", "role": "truth", "joint": 1,
                          "unit": "rad", "native_step": STEP}]}


def write_csv(table: pd.DataFrame, path: Path) -> None:
    table.to_csv(path, index=False, float_format="%.10g")


@dataclass
class Case:
    name: str
    what: str
    build: Callable[[Path, str], dict]
    expect: list[str] | None
    scope: str = "log"  # "log": one manifest entry; "manifest"/"config": a broken document
    stage: str | None = None  # where the error is raised (a per-log config case runs its
    #                           log; None: at ingest for logs, else before any job runs)
    extra: dict = field(default_factory=dict)

    @property
    def up_front(self) -> bool:
        return self.scope != "log" and self.stage is None


def _csv_case(mutate: Callable[[pd.DataFrame], pd.DataFrame], entry_mut=None):
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}.csv"
        write_csv(mutate(good_table()), path)
        entry = good_entry(log_id, path.name)
        if entry_mut:
            entry_mut(entry)
        return entry
    return build


def _text_case(text: str, entry_mut=None):
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}.csv"
        path.write_text(text)
        entry = good_entry(log_id, path.name)
        if entry_mut:
            entry_mut(entry)
        return entry
    return build


def _set(table, row, column, value):
    table = table.astype({column: object})
    table.loc[row, column] = value
    return table


def _csv_lines_case(edit: Callable[[list[str]], list[str]], entry_mut=None):
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}.csv"
        write_csv(good_table(), path)
        lines = path.read_text().splitlines()
        path.write_text("\n".join(edit(lines)) + "\n")
        entry = good_entry(log_id, path.name)
        if entry_mut:
            entry_mut(entry)
        return entry
    return build


def _parquet_case(transform: Callable[[bytes], bytes]):
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}.parquet"
        good_table().to_parquet(path, index=False)
        path.write_bytes(transform(path.read_bytes()))
        return good_entry(log_id, path.name, "parquet")
    return build


def _mat_case(root: Path, log_id: str) -> dict:
    import scipy.io

    path = root / f"{log_id}.mat"
    table = good_table()
    scipy.io.savemat(path, {"t": table["t"].to_numpy(), "position": table["angle"].to_numpy()})
    entry = good_entry(log_id, path.name, "mat")
    return entry  # the channel names column 'angle', the file holds 'position'


def _with(**changes):
    def mutate(entry):
        for dotted, value in changes.items():
            target = entry
            *path, last = dotted.split(".")
            for key in path:
                target = target[int(key)] if isinstance(target, list) else target[key]
            target[last] = value
    return mutate


def _wrapped_counts(table: pd.DataFrame) -> pd.DataFrame:
    counts = np.round(table["angle"].to_numpy() / STEP).astype(np.int64)
    return pd.DataFrame({"t": table["t"], "angle": np.mod(counts, 256)})


def _walk_back(lines):
    lines[101], lines[102] = lines[102], lines[101]
    return lines


def _repeat_stamp(lines):
    t_prev = lines[300].split(",")[0]
    lines[301] = t_prev + "," + lines[301].split(",")[1]
    return lines


def _gap(lines):
    return lines[:500] + lines[520:]


def _bytes_case(make: Callable[[pd.DataFrame], bytes], suffix: str = ".csv", entry_mut=None):
    """A good table written as bytes (another encoding, separators, compression)."""
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}{suffix}"
        path.write_bytes(make(good_table()))
        entry = good_entry(log_id, path.name)
        if entry_mut:
            entry_mut(entry)
        return entry
    return build


def _csv_text(table: pd.DataFrame) -> str:
    return table.to_csv(index=False, float_format="%.10g")


def _latin1_header(table: pd.DataFrame) -> bytes:
    # A Windows logger's header: "angle [°]" in Latin-1, the degree sign one byte 0xb0.
    return _csv_text(table.rename(columns={"angle": "angle [\u00b0]"})).encode("latin-1")


def _german_locale(table: pd.DataFrame) -> bytes:
    # Excel or a logger under a German locale: fields separated by ';', decimal commas.
    return table.to_csv(index=False, sep=";", decimal=",", float_format="%.10g").encode()


def _gzipped(table: pd.DataFrame) -> bytes:
    import gzip

    return gzip.compress(_csv_text(table).encode(), mtime=0)


def _gzip_cut(table: pd.DataFrame) -> bytes:
    data = _gzipped(table)
    return data[: len(data) // 2]


def _ms_as_seconds(table: pd.DataFrame) -> pd.DataFrame:
    return table.assign(t=table["t"] * 1000.0)  # a 1 kHz log in ms, declared in s


def _pair_in_ms(root: Path, log_id: str) -> dict:
    """A truth/measured pair (the residual stage alone) whose time column is in ms."""
    t = np.arange(N) / FS
    truth = 0.05 * np.sin(2 * np.pi * 5.0 * t)
    measured = np.floor(truth / (4 * STEP) + 0.5) * 4 * STEP
    path = root / f"{log_id}.csv"
    pd.DataFrame({"t": t * 1000.0, "truth": truth, "measured": measured}).to_csv(
        path, index=False, float_format="%.17g")
    return {"id": log_id, "file": path.name, "format": "csv", "device": "lrde_axis",
            "time": {"column": "t", "unit": "s"},
            "channels": [{"name": "truth", "column": "truth", "role": "truth", "joint": 1},
                         {"name": "measured", "column": "measured", "role": "measured", "joint": 1}]}


def _lrde_glitch(root: Path, log_id: str) -> dict:
    """A low-resolution log (paper 002) whose count leaps by 38 for one sample: a glitch."""
    t = np.arange(N) / FS
    counts = np.floor(1.8 * np.sin(2 * np.pi * 20.0 * t) + 0.3).astype(np.int64)
    counts[1000] += 38
    path = root / f"{log_id}.csv"
    pd.DataFrame({"t": t, "counts": counts}).to_csv(path, index=False, float_format="%.17g")
    return {"id": log_id, "file": path.name, "format": "csv", "device": "lrde_axis",
            "time": {"column": "t", "unit": "s"},
            "channels": [{"name": "coarse", "column": "counts", "role": "measured", "joint": 1,
                          "unit": "counts", "step": 0.0015707963267948964}],
            "analysis": {"stages": ["lrde"]}}


def _deg_as_rad(table):
    return table.assign(angle=np.rad2deg(table["angle"]) * 20)


def _never_moves(table):
    return table.assign(angle=0.0123)


CASES: list[Case] = [
    Case("empty_file", "a 0-byte file", _text_case(""), ["empty_file.csv", "empty"]),
    Case("header_only", "a header line and no data", _text_case("t,angle\n"),
         ["header_only.csv", "no data"]),
    Case("misspelled_column", "the channel's column is spelled differently in the file",
         _csv_case(lambda t: t.rename(columns={"angle": "angel"})),
         ["misspelled_column.csv", "'angle'", "angel"]),
    Case("text_in_numeric", "text in a numeric column",
         _csv_case(lambda t: _set(t, 56, "angle", "n/a")), ["text_in_numeric.csv", "'angle'", "line 58"]),
    Case("nan_value", "an empty (NaN) value inside the log",
         _csv_case(lambda t: _set(t, 1234, "angle", np.nan)), ["nan_value.csv", "'angle'", "line 1236"]),
    Case("inf_value", "an infinite value",
         _csv_case(lambda t: _set(t, 77, "angle", np.inf)), ["inf_value.csv", "'angle'", "line 79"]),
    Case("non_monotonic_time", "two time stamps swapped", _csv_lines_case(_walk_back),
         ["non_monotonic_time.csv", "'t'", "line 103", "0.1 s after 0.101 s"]),
    Case("repeated_time", "one repeated time stamp (reported, not rejected)",
         _csv_lines_case(_repeat_stamp), None,
         extra={"report": {"n_repeated": 1}, "warning": "repeated time stamps: 1 row of"}),
    Case("gapped_time", "20 missing samples (reported, not rejected)", _csv_lines_case(_gap), None,
         extra={"report": {"n_gaps": 1}}),
    Case("rate_contradicts_stamps", "nominal_rate_hz 500 for 1 kHz time stamps",
         _csv_case(lambda t: t, _with(**{"time.nominal_rate_hz": 500.0})),
         ["rate_contradicts_stamps.csv", "500", "1000"]),
    Case("degrees_labelled_radians", "degrees (times 20) declared as rad",
         _csv_case(_deg_as_rad, _with(**{"channels.0.native_step": None})),
         ["degrees_labelled_radians.csv", "'angle'", "deg"]),
    Case("counts_without_resolution", "unit counts without counts_per_rev or step",
         _csv_case(lambda t: t, _with(**{"channels.0.unit": "counts", "channels.0.native_step": None})),
         ["logs[0].channels[0].counts_per_rev", "counts_per_rev or step"], scope="manifest"),
    Case("counter_wrap_around", "an 8-bit counter that wraps (must be unwrapped, not rejected)",
         _csv_case(_wrapped_counts, _with(**{"channels.0.unit": "counts", "channels.0.native_step": None,
                                             "channels.0.step": STEP, "channels.0.wrap_bits": 8})),
         None),
    Case("truncated_parquet", "a Parquet file cut in half",
         _parquet_case(lambda b: b[: len(b) // 2]), ["truncated_parquet.parquet", "Parquet"]),
    Case("corrupt_parquet", "random bytes with a .parquet name",
         _parquet_case(lambda b: bytes(np.random.default_rng(0).integers(0, 256, len(b), dtype=np.uint8))),
         ["corrupt_parquet.parquet", "Parquet"]),
    Case("mat_without_variable", "a .mat file without the named variable", _mat_case,
         ["mat_without_variable.mat", "'angle'", "position"]),
    Case("too_short_for_filters", "40 samples: shorter than the slowest derivative filter",
         _csv_case(lambda t: t.iloc[:40]), ["too_short_for_filters", "40 samples",
                                            "filter's memory", "higher cutoffs"],
         stage="quantization"),
    Case("missing_file", "the entry's file does not exist",
         _csv_case(lambda t: t, _with(file="no_such_log.csv")), ["no_such_log.csv", "not found"]),
    Case("never_moves", "a joint that never moves", _csv_case(_never_moves),
         ["never_moves.csv", "'angle'", "never moves"]),
    Case("lrde_count_glitch", "a low-resolution log whose count leaps by 38 for one sample",
         _lrde_glitch, ["lrde_count_glitch.csv", "'coarse'", "sample 1000", "t = 1 s", "+38"],
         stage="lrde_fit"),
    # files as labs have them: each form is read when declared, or names the key to set
    Case("latin1_header", "a Latin-1 degree sign in the header (a Windows logger)",
         _bytes_case(_latin1_header, entry_mut=_with(**{"channels.0.column": "angle [\u00b0]"})),
         ["latin1_header.csv", "line 1", "not a UTF-8 text file", "reader.encoding", "latin-1"]),
    Case("latin1_header_declared", "the same file with reader.encoding: latin-1",
         _bytes_case(_latin1_header, entry_mut=_with(**{"channels.0.column": "angle [\u00b0]",
                                                        "reader": {"encoding": "latin-1"}})), None),
    Case("decimal_comma", "semicolons and decimal commas (a German locale), not declared",
         _bytes_case(_german_locale), ["decimal_comma.csv", "'angle'",
                                       "decimal commas: set reader.decimal: ','"]),
    Case("decimal_comma_declared", "the same file with reader.decimal: ','",
         _bytes_case(_german_locale, entry_mut=_with(reader={"decimal": ","})), None),
    Case("gzipped_csv", "a gzip-compressed CSV (run1.csv.gz)", _bytes_case(_gzipped, ".csv.gz"),
         None),
    Case("truncated_gzip", "a gzip file cut in half", _bytes_case(_gzip_cut, ".csv.gz"),
         ["truncated_gzip.csv.gz", "not a complete gzip file", "copy it again"]),
    Case("time_in_ms_as_seconds", "a 1 kHz log whose time column is in ms, declared s",
         _csv_case(_ms_as_seconds, _with(**{"time.nominal_rate_hz": None})),
         ["time_in_ms_as_seconds", "Nyquist", "1 Hz",
                                     "is the time column 't' in ms? (set time.unit: ms)"],
         stage="quantization"),
    Case("pair_time_in_ms", "a truth/measured pair with its time column in ms (completes, "
         "warned)", _pair_in_ms, None,
         extra={"warning": "is the time column 't' in ms? (set time.unit: ms)"}),
]


# Files a batch loses or cannot read, logs too short for a later stage, a full disk: each costs
# its log alone and a one-line reason naming the file; a fault (extra "fault") is then fixed and
# the same workspace rerun, which must complete with no cleaning.


def _unreadable(root: Path, log_id: str) -> dict:
    """A good log that the workflow's user may not read (mode 000; tests/corpus/run.py drops
    the capability that lets root read it anyway)."""
    path = root / f"{log_id}.csv"
    write_csv(good_table(), path)
    path.chmod(0)
    return good_entry(log_id, path.name)


def _vanished(root: Path, log_id: str) -> dict:
    """The log's file was moved away after the manifest was written: its link stayed."""
    path = root / f"{log_id}.csv"
    path.symlink_to(f"{log_id}.moved_away.csv")
    return good_entry(log_id, path.name)


def _pair(n: int):
    """A truth/measured pair of ``n`` samples (the residual stage alone, after ingest)."""
    def build(root: Path, log_id: str) -> dict:
        entry = _pair_in_ms(root, log_id)
        path = root / entry["file"]
        table = pd.read_csv(path).iloc[:n]
        table.assign(t=table["t"] / 1000.0).to_csv(path, index=False, float_format="%.17g")
        return entry
    return build


CASES += [
    Case("unreadable_file", "a log the workflow may not read (chmod 000)", _unreadable,
         ["unreadable_file.csv", "permission denied", "read access"],
         extra={"unreadable": True}),
    Case("vanished_file", "the file was moved away, its link stayed", _vanished,
         ["vanished_file.csv", "not found"]),
    Case("three_rows", "a 3-row log (passes ingest, too short for the derivative filters)",
         _csv_case(lambda t: t.iloc[:3]), ["three_rows.csv", "3 samples", "filter's memory"],
         stage="quantization"),
    Case("pair_too_short", "a 40-sample truth/measured pair: fails in the residual stage",
         _pair(40), ["pair_too_short.csv", "samples", "40"],
         stage="residuals"),
    Case("disk_full_in_chunk", "the disk fills up (a file-size limit) while a chunk writes; "
         "the limit lifted, a rerun completes", _csv_case(lambda t: t),
         ["disk_full_in_chunk.csv", "the disk is full", "then rerun"],
         stage="quantization", extra={"fault": "disk_full"}),
]


def _manifest_case(mutate: Callable[[dict], None]):
    """A good CSV log whose manifest entry (or entries) ``mutate`` breaks."""
    def build(root: Path, log_id: str) -> dict:
        path = root / f"{log_id}.csv"
        write_csv(good_table(), path)
        entry = good_entry(log_id, path.name)
        mutate(entry)
        return entry
    return build


def _config_case(change: dict):
    def build(root: Path, log_id: str) -> dict:
        return change
    return build


def _drop(key):
    def mutate(entry):
        entry.pop(key)
    return mutate


CASES += [
    Case("duplicate_id", "two manifest entries with the same id",
         _manifest_case(lambda e: None), ["logs[1].id", "already used"], scope="manifest",
         extra={"duplicate": True}),
    Case("path_outside_root", "the file path climbs out of the data root",
         _manifest_case(_with(file="../../etc/passwd")), ["logs[0].file", "data_root"],
         scope="manifest"),
    Case("unknown_key", "a misspelled key in a manifest entry",
         _manifest_case(_with(chanels=[])), ["chanels"], scope="manifest"),
    Case("wrong_type", "a string where the sample rate must be a number",
         _manifest_case(_with(**{"time.nominal_rate_hz": "1 kHz"})),
         ["logs[0].time.nominal_rate_hz", "1 kHz"], scope="manifest"),
    Case("zero_step", "native_step 0",
         _manifest_case(_with(**{"channels.0.native_step": 0})),
         ["logs[0].channels[0].native_step"], scope="manifest"),
    Case("negative_step", "a counts channel with step -1e-4",
         _manifest_case(_with(**{"channels.0.unit": "counts", "channels.0.native_step": None,
                                 "channels.0.step": -1e-4})),
         ["logs[0].channels[0].step"], scope="manifest"),
    Case("unknown_device", "a device name the configuration does not define",
         _manifest_case(_with(device="phantom_premium_3")), ["phantom_premium_3", "device"],
         scope="manifest"),
    Case("unknown_format", "format xlsx", _manifest_case(_with(format="xlsx")),
         ["logs[0].format", "xlsx"], scope="manifest"),
    Case("config_unknown_key", "a misspelled configuration key",
         _config_case({"requantise": {"multiples": [8]}}), ["requantise"], scope="config"),
    Case("config_filter_n_zero", "a derivative filter with n = 0 low-pass stages",
         _config_case({"derivatives.bank.n": [0, 1]}), ["derivatives.bank.n[0]", "minimum of 1"],
         scope="config"),
    Case("config_negative_requantize_step", "a negative re-quantization multiple",
         _config_case({"requantize.multiples": [-8]}), ["requantize.multiples[0]", "-8"],
         scope="config"),
    Case("config_cutoff_above_nyquist", "a 600 Hz cutoff for 1 kHz logs",
         _config_case({"derivatives.bank.fc_hz": [50, 600]}),
         ["derivatives.bank.fc_hz", "600 Hz", "Nyquist", "config_cutoff_above_nyquist"],
         scope="config", stage="quantization"),
]


# Declarations the data contradict: a truth/measured pair (the residual stage alone) that
# completes with a warning in summary.json naming the file, the column and what fits.


def _declared_pair(measured, entry_mut=None, time_factor: float = 1.0, rows=None):
    """A truth/measured pair: ``measured(truth)`` gives the file's measured column, ``rows`` the
    order in which the logger wrote the samples, ``time_factor`` the time column's unit."""
    def build(root: Path, log_id: str) -> dict:
        t = np.arange(N) / FS
        truth = 0.2 * np.sin(2 * np.pi * 3.0 * t) + 0.05
        table = pd.DataFrame({"t": t * time_factor, "truth": truth, "measured": measured(truth)})
        if rows is not None:
            table = table.iloc[rows(N)]
        path = root / f"{log_id}.csv"
        table.to_csv(path, index=False, float_format="%.17g")
        entry = {"id": log_id, "file": path.name, "format": "csv", "device": "lrde_axis",
                 "time": {"column": "t", "unit": "s"},
                 "channels": [{"name": "truth", "column": "truth", "role": "truth", "joint": 1},
                              {"name": "measured", "column": "measured", "role": "measured",
                               "joint": 1}]}
        if entry_mut:
            entry_mut(entry)
        return entry
    return build


def _on_grid(theta, step=4 * STEP):
    return np.floor(theta / step + 0.5) * step


def _counts_4096(theta):
    return np.floor(theta / (2 * np.pi / 4096) + 0.5).astype(np.int64)


def _twice(n):
    """Rows 700..739 written twice, each followed by its copy."""
    return np.concatenate((np.arange(700), np.repeat(np.arange(700, 740), 2), np.arange(740, n)))


CASES += [
    Case("measured_rad_declared_deg", "the measured channel in rad declared deg (completes, warned)",
         _declared_pair(_on_grid, _with(**{"channels.1.unit": "deg"})), None,
         extra={"warning": "column 'measured') moves 0.01745 times as far as the truth"}),
    Case("measured_deg_declared_mrad", "the measured channel in deg declared mrad (completes, "
         "warned)", _declared_pair(lambda th: np.rad2deg(_on_grid(th)), _with(**{"channels.1.unit": "mrad"})),
         None, extra={"warning": "is column 'measured' in deg? (set unit: deg)"}),
    Case("counts_per_rev_off_by_four", "a 4096-count encoder declared 1024 counts per rev "
         "(completes, warned)",
         _declared_pair(_counts_4096, _with(**{"channels.1.unit": "counts",
                                              "channels.1.counts_per_rev": 1024})), None,
         extra={"warning": "counts_per_rev 1024 declared, 4096 fits"}),
    Case("pair_time_in_ns", "a truth/measured pair with its time column in ns, declared s "
         "(completes, warned)", _declared_pair(_on_grid, time_factor=1e9), None,
         extra={"warning": "is the time column 't' in ns? (set time.unit: ns)"}),
    Case("pair_rows_written_twice", "a truth/measured pair whose logger wrote 40 rows twice "
         "(collapsed, completes, warned)", _declared_pair(_on_grid, rows=_twice), None,
         extra={"report": {"n_repeated": 40}, "warning": "repeated time stamps: 40 rows of"}),
]
