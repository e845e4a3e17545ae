"""All disk I/O of enclab: manifest, raw log readers, canonical Parquet, atomic writers.

Readers return the raw numbers of the columns a manifest entry needs (:class:`RawLog`) and
know, for every sample, where it sits in its file (text line, table row, or sample of a
one-value-per-line file), so that every :class:`~enclab.errors.EnclabInputError` names the
exact place. The conversions to SI, the time base and the checks on it are pure functions
in :mod:`enclab.ingest`.

Files come as labs have them: any of the formats may be gzip-compressed (read transparently,
recognised by their first bytes), text files may be in another encoding than UTF-8
(``reader.encoding``, e.g. ``latin-1`` for a degree sign written by a Windows logger), and
semicolon-separated files with decimal commas are read when declared (``reader.delimiter: ";"``,
``reader.decimal: ","``). When a file does not match what the entry declares, the error says
which key to set.

Every writer is atomic: it writes a temporary file in the target's directory and moves it
into place with :func:`os.replace`, so an interrupted job never leaves a partial output.
"""
from __future__ import annotations

import codecs
import contextlib
import functools
import glob
import gzip
import hashlib
import io as _stdio
import json
import math
import os
import re
import shutil
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from enclab.errors import EnclabInputError
from enclab.manifest import validate_manifest

__all__ = [
    "CANONICAL_METADATA_KEY",
    "atomic_folder",
    "RawLog",
    "require_finite",
    "entry_files",
    "file_sha256",
    "ingest_log",
    "iter_canonical",
    "is_gzip",
    "read_bytes",
    "read_canonical",
    "read_json",
    "read_manifest",
    "read_raw",
    "read_table",
    "read_texts",
    "save_figure",
    "save_thumbnail",
    "write_canonical",
    "write_canonical_chunks",
    "write_json",
    "write_parquet",
    "write_table",
    "write_text",
]

CANONICAL_METADATA_KEY = b"enclab"
# libyaml's parser, when PyYAML has it, builds the same objects (same constructor) 5x faster:
# a 500-log manifest takes 0.14 s instead of 0.72 s, paid by every Snakemake start.
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


# --------------------------------------------------------------------------- manifest


def read_manifest(path: str | os.PathLike, devices: dict) -> tuple[Path, list[dict]]:
    """Read and validate a manifest file.

    Parameters
    ----------
    path : str or path-like
        The manifest (YAML).
    devices : dict
        Device specifications by name (``config["devices"]``).

    Returns
    -------
    data_root : pathlib.Path
        ``data_root`` of the manifest, relative to the working directory as written.
    entries : list of dict
        Normalised log entries (see :func:`enclab.manifest.validate_manifest`).

    Raises
    ------
    EnclabInputError
        Missing file, YAML syntax error (with its line), or an invalid manifest.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise EnclabInputError(path, "manifest file not found", hint="Check config.yaml 'manifest'.") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise EnclabInputError(path, f"cannot read the manifest ({exc})") from None
    try:
        doc = yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        raise EnclabInputError(
            path,
            f"YAML syntax error: {problem}",
            row=None if mark is None else mark.line + 1,
            row_label="line",
        ) from None
    data_root, entries = validate_manifest(doc, devices, str(path))
    return Path(data_root), entries


def entry_files(entry: dict, data_root: str | os.PathLike) -> list[str]:
    """The data file and, if any, the time file of a manifest entry (``data_root`` joined)."""
    files = [str(Path(data_root) / entry["file"])]
    if "file" in entry["time"]:
        files.append(str(Path(data_root) / entry["time"]["file"]))
    return files


def file_sha256(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# --------------------------------------------------------------------------- raw logs


@dataclass
class RawLog:
    """The raw numbers a manifest entry needs, with their locations in the files.

    Attributes
    ----------
    file : str
        Data file as opened (``data_root`` joined), used in error messages.
    format : str
        Manifest format (csv, text, parquet, mat).
    channels : dict of str to ndarray
        float64 values in file units, keyed by channel ``name`` (manifest order). Finite,
        except when the entry has a crop: then only the samples the crop keeps are checked
        (by :func:`enclab.ingest.canonicalize`).
    columns : dict of str to str
        Source column label of each channel, for messages.
    locations : ndarray of int64
        User-facing location of each sample in ``file`` (``locations[i]`` for sample ``i``).
    row_label : {"line", "row", "sample"}
        How ``locations`` count (see :mod:`enclab.errors`).
    time : ndarray or None
        float64 time values in the manifest's time unit (None for the ``rate_hz`` form).
    time_file : str or None
        File that holds ``time`` (the data file or the separate time file).
    time_column : str or None
        Label of the time column (None for a separate time file).
    time_locations : ndarray of int64 or None
        Location of each time value in ``time_file``.
    time_row_label : str
        How ``time_locations`` count.
    trailing_empty_dropped : int
        Trailing rows without any channel value that were dropped (``skip_trailing_empty``).
    """

    file: str
    format: str
    channels: dict[str, np.ndarray]
    columns: dict[str, str]
    locations: np.ndarray
    row_label: str
    time: np.ndarray | None = None
    time_file: str | None = None
    time_column: str | None = None
    time_locations: np.ndarray | None = None
    time_row_label: str = "row"
    trailing_empty_dropped: int = 0

    @property
    def n_samples(self) -> int:
        """Number of samples (after dropping trailing empty rows)."""
        return int(self.locations.size)

    def where(self, index: int, *, time: bool = False) -> dict:
        """Keyword arguments ``file``, ``row``, ``row_label`` (and ``column`` for time) of sample
        ``index``, for :class:`EnclabInputError`."""
        if time:
            return {
                "file": self.time_file,
                "column": self.time_column,
                "row": int(self.time_locations[index]),
                "row_label": self.time_row_label,
            }
        return {"file": self.file, "row": int(self.locations[index]), "row_label": self.row_label}


@dataclass
class _Table:
    """Parsed columns of one file before the channel/time selection."""

    names: list[str]
    locations: np.ndarray
    row_label: str
    getter: Any  # callable(column index) -> float64 values, NaN where a field is empty


def read_raw(entry: dict, data_root: str | os.PathLike) -> RawLog:
    """Read the columns a normalised manifest entry needs.

    Parameters
    ----------
    entry : dict
        One normalised entry of :func:`read_manifest`.
    data_root : str or path-like
        Directory the entry's files are relative to.

    Returns
    -------
    RawLog

    Raises
    ------
    EnclabInputError
        Missing file, column or variable; text in a numeric column; NaN/inf (except trailing
        all-empty rows when ``reader.skip_trailing_empty``); ragged rows; a time file whose
        length differs from the data. The message names file, column and line/row/sample.
    """
    path = Path(data_root) / entry["file"]
    display = str(path)
    if not path.is_file():
        raise EnclabInputError(display, "data file not found", hint="Check data_root and the entry's 'file'.")
    fmt = entry["format"]
    reader = entry["reader"]
    if fmt in ("csv", "text"):
        table = _read_delimited(path, display, fmt, reader)
    elif fmt == "parquet":
        table = _read_parquet(path, display)
    elif fmt == "mat":
        table = _read_mat(path, display, entry)
    else:
        raise ValueError(f"entry format must be csv, text, parquet or mat, got {fmt!r}")

    kind = "variable" if fmt == "mat" and reader.get("variable") is None else "column"
    channels: dict[str, np.ndarray] = {}
    columns: dict[str, str] = {}
    for channel in entry["channels"]:
        index = _column_index(table, channel["column"], display, kind)
        channels[channel["name"]] = table.getter(index)
        columns[channel["name"]] = table.names[index]
    time_spec = entry["time"]
    time = time_column = None
    if "column" in time_spec:
        index = _column_index(table, time_spec["column"], display, kind)
        time = table.getter(index)
        time_column = table.names[index]

    raw = RawLog(
        file=display,
        format=fmt,
        channels=channels,
        columns=columns,
        locations=table.locations,
        row_label=table.row_label,
        time=time,
        time_file=display if time is not None else None,
        time_column=time_column,
        time_locations=table.locations if time is not None else None,
        time_row_label=table.row_label,
    )
    _drop_trailing_empty(raw, bool(reader.get("skip_trailing_empty", True)))
    if not entry.get("crop"):
        # With a crop, only the kept samples must be finite: enclab.ingest checks them.
        for name, values in raw.channels.items():
            require_finite(values, raw, raw.columns[name])
    if raw.n_samples == 0:
        raise EnclabInputError(display, "no data rows", expected="at least two samples")
    if raw.time is not None:
        require_finite(raw.time, raw, raw.time_column, time=True)
    if "file" in time_spec:
        _attach_time_file(raw, Path(data_root) / time_spec["file"], reader)
    return raw


def _column_index(table: _Table, column: str | int, display: str, kind: str) -> int:
    if isinstance(column, int):
        if column < len(table.names):
            return column
        raise EnclabInputError(
            display, f"column index {column} is out of range", column=column,
            expected=f"an index below {len(table.names)} (the file has {len(table.names)} columns)",
        )
    if column in table.names:
        return table.names.index(column)
    shown = table.names if len(table.names) <= 20 else table.names[:20] + ["..."]
    hint = None
    joined = [(mark, label) for mark, label in ((";", "';'"), ("\t", "'\\t'"), (",", "','"))
              if any(mark in str(name) for name in table.names)]
    if joined:
        mark, label = joined[0]
        hint = (f"The column names run together at {label}: the fields are separated by {label}; "
                f"set reader.delimiter: {label}" + (" (and reader.decimal: ',' for decimal commas)."
                                                     if mark == ";" else "."))
    raise EnclabInputError(display, f"{kind} not found", column=column, expected=f"one of {shown}",
                           hint=hint)


def _drop_trailing_empty(raw: RawLog, skip: bool) -> None:
    if not skip or not raw.channels:
        return
    empty = np.ones(raw.n_samples, dtype=bool)
    for values in raw.channels.values():
        empty &= np.isnan(values)
    # Count the run of all-empty rows at the end only; empty rows inside the log are errors.
    n_drop = int(np.argmin(empty[::-1])) if not empty.all() else int(empty.size)
    if n_drop == 0:
        return
    keep = raw.n_samples - n_drop
    raw.channels = {name: values[:keep] for name, values in raw.channels.items()}
    raw.locations = raw.locations[:keep]
    if raw.time is not None:
        raw.time = raw.time[:keep]
        raw.time_locations = raw.time_locations[:keep]
    raw.trailing_empty_dropped = n_drop


def require_finite(values: np.ndarray, raw: RawLog, column: str | None, *, time: bool = False,
                   index: np.ndarray | None = None) -> None:
    """Raise EnclabInputError at the first NaN/inf of ``values`` (a channel or the time).

    ``index`` maps positions in ``values`` to sample indices of ``raw`` (after a crop).
    """
    bad = ~np.isfinite(values)
    if not bad.any():
        return
    i = int(np.argmax(bad))
    value = values[i]
    if index is not None:
        i = int(index[i])
    problem = "empty or NaN value" if np.isnan(value) else f"infinite value {value}"
    hint = ("Crop the log (crop) or fix the file; only trailing all-empty rows are dropped "
            "(reader.skip_trailing_empty).")
    if time:
        raise EnclabInputError(problem=problem, expected="a finite number", hint=hint, **raw.where(i, time=True))
    raise EnclabInputError(problem=problem, column=column, expected="a finite number", hint=hint, **raw.where(i))


def _attach_time_file(raw: RawLog, path: Path, reader: dict) -> None:
    display = str(path)
    if not path.is_file():
        raise EnclabInputError(display, "time file not found", hint="Check the entry's time.file.")
    lines = _read_lines(path, display, reader.get("encoding") or "utf-8")
    decimal_comma = reader.get("decimal") == ","
    values, locations = [], []
    header_seen = False
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text:
            continue
        if decimal_comma:
            fields = [f.strip().replace(",", ".") for f in text.replace(";", " ").split()]
        else:
            fields = [f.strip() for f in text.replace(",", " ").split()]
        if len(fields) != 1:
            raise EnclabInputError(display, f"{len(fields)} values on one line", row=number, row_label="line",
                                   expected="one time value per line")
        try:
            values.append(float(fields[0]))
        except ValueError:
            if not values and not header_seen:
                header_seen = True  # a single-column CSV's header line
                continue
            raise EnclabInputError(display, f"text '{fields[0]}' in a numeric column", row=number,
                                   row_label="line", expected="a number",
                                   hint="Fix the line, or crop the log to exclude it.") from None
        locations.append(number)
    time = np.asarray(values, dtype=np.float64)
    if time.size != raw.n_samples + raw.trailing_empty_dropped and time.size != raw.n_samples:
        raise EnclabInputError(
            display, f"{time.size} time values for {raw.n_samples} samples of {raw.file}",
            expected="one time value per sample",
        )
    raw.time = time[: raw.n_samples]
    raw.time_file = display
    raw.time_column = None
    raw.time_locations = np.asarray(locations[: raw.n_samples], dtype=np.int64)
    raw.time_row_label = "line"
    require_finite(raw.time, raw, None, time=True)


GZIP_MAGIC = b"\x1f\x8b"
_UTF16_BOMS = (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)


def is_gzip(path: str | os.PathLike) -> bool:
    """Whether a file is gzip-compressed (its first two bytes, whatever its name)."""
    with open(path, "rb") as handle:
        return handle.read(2) == GZIP_MAGIC


def read_bytes(path: str | os.PathLike, display: str | None = None) -> bytes:
    """The bytes of a data file, decompressed when it is gzip-compressed.

    Raises
    ------
    EnclabInputError
        A gzip file that ends early or is damaged.
    """
    data = Path(path).read_bytes()
    if data[:2] != GZIP_MAGIC:
        return data
    try:
        return gzip.decompress(data)
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
        raise EnclabInputError(
            display or str(path), f"not a complete gzip file ({exc})",
            expected="a gzip-compressed file that decompresses whole",
            hint="The file ends early or is damaged: copy it again (gunzip -t checks it).",
        ) from None


def _read_lines(path: Path, display: str, encoding: str = "utf-8") -> list[str]:
    data = read_bytes(path, display)
    name = codecs.lookup(encoding).name
    try:
        # utf-8-sig also drops the byte-order mark some Windows tools write first.
        return data.decode("utf-8-sig" if name == "utf-8" else encoding).splitlines()
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        label = "UTF-8" if name == "utf-8" else encoding
        if data[:2] in _UTF16_BOMS:
            hint = "The file starts with a UTF-16 byte-order mark: set reader.encoding: utf-16."
        else:
            hint = ("Set reader.encoding to the file's encoding: latin-1 or cp1252 for most "
                    "files written on Windows (a degree sign is then byte 0xb0).")
        raise EnclabInputError(display, f"not a {label} text file (byte 0x{data[exc.start]:02x} "
                               f"cannot be decoded)", row=line, row_label="line",
                               expected=f"a {label} text file", hint=hint) from None


def _split_function(delimiter: str):
    if delimiter == "whitespace":
        return str.split
    if delimiter == "\\t":
        delimiter = "\t"
    return lambda line: [f.strip() for f in line.split(delimiter)]


_DECIMAL_COMMA = re.compile(r"[-+]?\d*,\d+([eE][-+]?\d+)?")


def _parse_numbers(fields: list[str], column_label: str, locations: np.ndarray, row_label: str,
                   display: str, decimal: str = ".") -> np.ndarray:
    """float64 array of text fields; empty fields become NaN, other text is an error.

    ``decimal`` is the decimal mark (``"."`` or ``","``, ``reader.decimal``).
    """
    numbers = [f.replace(",", ".") for f in fields] if decimal == "," else fields
    with contextlib.suppress(ValueError):  # fast path; the loop below locates the bad field
        return np.array(numbers, dtype=np.float64)
    out = np.empty(len(fields), dtype=np.float64)
    for i, text in enumerate(numbers):
        if text == "":
            out[i] = np.nan
            continue
        try:
            out[i] = float(text)
        except ValueError:
            shown = fields[i]
            if decimal == "." and _DECIMAL_COMMA.fullmatch(shown.strip()):
                hint = ("The file writes decimal commas: set reader.decimal: ',' (and "
                        "reader.delimiter: ';' if its fields are separated by semicolons).")
            else:
                hint = "Fix the value, or crop the log to exclude it (crop: t_start/t_end)."
            raise EnclabInputError(
                display, f"text '{shown}' in a numeric column", column=column_label,
                row=int(locations[i]), row_label=row_label, expected="a number", hint=hint,
            ) from None
    return out


def _read_delimited(path: Path, display: str, fmt: str, reader: dict) -> _Table:
    lines = _read_lines(path, display, reader.get("encoding") or "utf-8")
    decimal = reader.get("decimal") or "."
    comment = reader.get("comment")
    header = reader.get("header")
    names_option = reader.get("column_names")
    per_sample = reader.get("values_per_sample")
    last_comment = None
    content: list[tuple[int, str]] = []  # (line number, text) of non-comment, non-blank lines
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if comment is not None and stripped.startswith(comment):
            if not content:
                last_comment = (number, stripped[len(comment):])
            continue
        content.append((number, line))
    if header is not None:
        if header >= len(content):
            raise EnclabInputError(display, f"no header line (reader.header = {header})",
                                   expected="a header line",
                                   hint="The file is empty or shorter than expected: check that "
                                   "the logger finished writing it, or set reader.header.")
        header_number, header_text = content[header]
        content = content[header + 1:]
    if not content:
        raise EnclabInputError(display, "no data lines", expected="at least two samples",
                               hint="Check that the logger finished writing the file.")
    delimiter = reader.get("delimiter", "auto")
    if delimiter == "auto":
        delimiter = _auto_delimiter(content[0][1], decimal)
    split = _split_function(delimiter)

    if per_sample is not None:
        return _sample_major(content, split, per_sample, names_option, display, decimal)

    numbers = np.fromiter((n for n, _ in content), dtype=np.int64, count=len(content))
    rows = [split(text.strip()) if delimiter == "whitespace" else split(text) for _, text in content]
    width = len(rows[0])
    if header is not None:
        names = [_clean_name(f) for f in split(header_text.strip())]
        if len(names) != width:
            raise EnclabInputError(display, f"the header has {len(names)} names but the first data line "
                                   f"{len(rows[0])} values", row=header_number, row_label="line",
                                   expected="one name per column")
    elif names_option == "last_comment":
        if last_comment is None:
            raise EnclabInputError(display, "no comment line before the data to take column names from",
                                   expected=f"a '{comment}' line naming the columns")
        names = [_clean_name(f) for f in split(last_comment[1].strip())]
        if len(names) != width:
            raise EnclabInputError(display, f"the last comment line names {len(names)} columns but the data "
                                   f"has {width}", row=last_comment[0], row_label="line",
                                   expected="one name per column")
    elif isinstance(names_option, list):
        if len(names_option) != width:
            raise EnclabInputError(display, f"reader.column_names has {len(names_option)} names but the data "
                                   f"has {width} columns", row=int(numbers[0]), row_label="line",
                                   expected="one name per column")
        names = list(names_option)
    else:
        names = [str(j) for j in range(width)]
    lengths = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    ragged = np.flatnonzero(lengths != width)
    if ragged.size:
        i = int(ragged[0])
        raise EnclabInputError(display, f"{lengths[i]} values on this line", row=int(numbers[i]),
                               row_label="line", expected=f"{width} values like the first data line")

    def getter(j: int) -> np.ndarray:
        return _parse_numbers([r[j] for r in rows], names[j], numbers, "line", display, decimal)

    return _Table(names, numbers, "line", getter)


def _auto_delimiter(line: str, decimal: str) -> str:
    """``reader.delimiter: auto``: semicolon, else comma (unless it is the decimal mark),
    else whitespace, from the first data line."""
    if ";" in line:
        return ";"
    if "," in line and decimal != ",":
        return ","
    return "whitespace"


def _sample_major(content, split, per_sample: int, names_option, display: str,
                  decimal: str = ".") -> _Table:
    fields = []
    for number, text in content:
        parts = split(text.strip())
        if len(parts) != 1:
            raise EnclabInputError(display, f"{len(parts)} values on one line", row=number, row_label="line",
                                   expected="one value per line (reader.values_per_sample)")
        fields.append(parts[0])
    if len(fields) % per_sample:
        n_full = len(fields) // per_sample
        raise EnclabInputError(
            display, f"{len(fields)} values are not a whole number of samples of {per_sample}; the last "
            f"sample is incomplete (from line {content[n_full * per_sample][0]})", row=n_full + 1,
            row_label="sample", expected=f"a multiple of {per_sample} values",
        )
    n = len(fields) // per_sample
    names = list(names_option) if isinstance(names_option, list) else [str(j) for j in range(per_sample)]
    samples = np.arange(1, n + 1, dtype=np.int64)

    def getter(j: int) -> np.ndarray:
        return _parse_numbers(fields[j::per_sample], names[j], samples, "sample", display, decimal)

    return _Table(names, samples, "sample", getter)


def _clean_name(text: str) -> str:
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        text = text[1:-1]
    return text


def _read_parquet(path: Path, display: str) -> _Table:
    source = pa.BufferReader(read_bytes(path, display)) if is_gzip(path) else path
    try:
        table = pq.read_table(source)
    except (pa.ArrowException, OSError) as exc:
        raise EnclabInputError(display, f"not a readable Parquet file ({exc})",
                               expected="a complete Parquet file",
                               hint="Copy or export the file again; check format in the "
                               "manifest.") from None
    names = list(table.column_names)
    rows = np.arange(1, table.num_rows + 1, dtype=np.int64)

    def getter(j: int) -> np.ndarray:
        column = table.column(j)
        if not (pa.types.is_integer(column.type) or pa.types.is_floating(column.type)
                or pa.types.is_boolean(column.type)):
            raise EnclabInputError(display, f"column type {column.type} is not numeric", column=names[j],
                                   expected="an integer or floating-point column")
        return column.to_numpy(zero_copy_only=False).astype(np.float64)

    return _Table(names, rows, "row", getter)


def _read_mat(path: Path, display: str, entry: dict) -> _Table:
    import scipy.io

    source = _stdio.BytesIO(read_bytes(path, display)) if is_gzip(path) else path
    try:
        data = scipy.io.loadmat(source, squeeze_me=False)
    except NotImplementedError:
        raise EnclabInputError(display, "MATLAB v7.3 (HDF5) file", expected="a v5/v7 .mat file",
                               hint="Re-save it in MATLAB with save(..., '-v7').") from None
    except (ValueError, OSError, TypeError) as exc:
        raise EnclabInputError(display, f"not a readable MATLAB file ({exc})") from None
    variables = {k: v for k, v in data.items() if not k.startswith("__")}
    reader = entry["reader"]
    matrix_name = reader.get("variable")
    if matrix_name is not None:
        if matrix_name not in variables:
            raise EnclabInputError(display, "variable not found", column=matrix_name,
                                   expected=f"one of {sorted(variables)} (reader.variable)")
        matrix = _numeric_array(variables[matrix_name], matrix_name, display)
        if matrix.ndim != 2:
            raise EnclabInputError(display, f"variable has shape {matrix.shape}", column=matrix_name,
                                   expected="a 2-D matrix with one column per channel")
        names_option = reader.get("column_names")
        if isinstance(names_option, list):
            if len(names_option) != matrix.shape[1]:
                raise EnclabInputError(display, f"reader.column_names has {len(names_option)} names for "
                                       f"{matrix.shape[1]} columns", column=matrix_name,
                                       expected="one name per column")
            names = list(names_option)
        else:
            names = [str(j) for j in range(matrix.shape[1])]
        rows = np.arange(1, matrix.shape[0] + 1, dtype=np.int64)
        return _Table(names, rows, "row", lambda j: matrix[:, j].astype(np.float64))

    wanted = [c["column"] for c in entry["channels"]]
    if "column" in entry["time"]:
        wanted.append(entry["time"]["column"])
    vectors: dict[str, np.ndarray] = {}
    for name in wanted:
        if name not in variables:
            raise EnclabInputError(display, "variable not found", column=name,
                                   expected=f"one of {sorted(variables)}")
        array = _numeric_array(variables[name], name, display)
        if array.ndim > 2 or (array.ndim == 2 and min(array.shape) > 1):
            raise EnclabInputError(display, f"variable has shape {array.shape}", column=name,
                                   expected="a vector (n x 1 or 1 x n), or set reader.variable for a matrix")
        vectors[name] = array.reshape(-1).astype(np.float64)
    lengths = {name: v.size for name, v in vectors.items()}
    first = wanted[0]
    for name, size in lengths.items():
        if size != lengths[first]:
            raise EnclabInputError(display, f"{size} samples but variable '{first}' has {lengths[first]}",
                                   column=name, expected="vectors of equal length")
    names = list(vectors)
    rows = np.arange(1, lengths[first] + 1, dtype=np.int64)
    return _Table(names, rows, "row", lambda j: vectors[names[j]])


def _numeric_array(value: Any, name: str, display: str) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":
        raise EnclabInputError(display, f"variable of MATLAB type {array.dtype} is not numeric", column=name,
                               expected="a real numeric array")
    return array


def ingest_log(entry: dict, data_root: str | os.PathLike, devices: dict) -> tuple[pd.DataFrame, dict]:
    """Read one log and convert it to the canonical form (see :func:`enclab.ingest.canonicalize`).

    Also records the SHA-256 of the data file in ``meta["source"]["sha256"]``.
    """
    from enclab.ingest import canonicalize

    raw = read_raw(entry, data_root)
    df, meta = canonicalize(raw, entry, devices)
    meta["source"]["sha256"] = file_sha256(Path(data_root) / entry["file"])
    return df, meta


# --------------------------------------------------------------------------- canonical Parquet


def write_canonical(df: pd.DataFrame, meta: dict, path: str | os.PathLike) -> None:
    """Write a canonical log: Parquet with the metadata JSON under schema key ``b"enclab"``."""
    write_parquet(df, path, metadata=meta)


def read_canonical(path: str | os.PathLike) -> tuple[pd.DataFrame, dict]:
    """Read a canonical log written by :func:`write_canonical`; returns ``(df, meta)``."""
    table = pq.read_table(path)
    raw_meta = (table.schema.metadata or {}).get(CANONICAL_METADATA_KEY)
    if raw_meta is None:
        raise EnclabInputError(path, "Parquet file without enclab metadata",
                               expected="a canonical log written by enclab.io.write_canonical")
    return table.to_pandas(), json.loads(raw_meta)


def _canonical_meta(path, schema: pa.Schema) -> dict:
    raw_meta = (schema.metadata or {}).get(CANONICAL_METADATA_KEY)
    if raw_meta is None:
        raise EnclabInputError(path, "Parquet file without enclab metadata",
                               expected="a canonical log written by enclab.io.write_canonical")
    return json.loads(raw_meta)


def iter_canonical(path: str | os.PathLike, batch_rows: int = 262_144,
                   columns: list[str] | None = None, start: int = 0,
                   stop: int | None = None) -> tuple[dict, int, Iterator[pd.DataFrame]]:
    """Read a canonical log piece by piece, for logs too long to hold in memory.

    Parameters
    ----------
    path : str or path-like
        A canonical log (:func:`write_canonical` or :func:`write_canonical_chunks`).
    batch_rows : int
        Rows per yielded piece (at most; a row group's last piece may be shorter). Memory
        is bounded by about one decoded row group plus one piece.
    columns : list of str, optional
        Columns to read (default all).
    start, stop : int, optional
        Only rows ``start`` to ``stop - 1`` (default: all); row groups outside are not read.

    Returns
    -------
    meta : dict
        The log's metadata.
    n_rows : int
        Rows in the file (from the Parquet footer, before any data is read).
    pieces : iterator of DataFrame
        Consecutive pieces in file order.
    """
    if isinstance(batch_rows, bool) or not isinstance(batch_rows, int) or batch_rows < 1:
        raise ValueError(f"batch_rows must be a positive integer, got {batch_rows!r}")
    try:
        handle = pq.ParquetFile(path)
    except FileNotFoundError:
        raise EnclabInputError(path, "file not found") from None
    except (pa.ArrowInvalid, OSError) as exc:
        raise EnclabInputError(path, f"not a readable Parquet file ({exc})") from None
    meta = _canonical_meta(path, handle.schema_arrow)
    n_rows = int(handle.metadata.num_rows)
    stop = n_rows if stop is None else stop
    if not 0 <= start <= stop <= n_rows:
        raise ValueError(f"{path}: rows {start} to {stop} are not inside its {n_rows} rows")

    def pieces():
        # Row group by row group, not ParquetFile.iter_batches: with pyarrow 26 the latter
        # keeps every compressed row group it has read in Arrow's pool (bench_performance: a
        # decode-only pass over the one-hour 10 kHz log peaked at 946 MB, 366 MB this way).
        with handle:
            first = 0
            for i in range(handle.num_row_groups):
                size = handle.metadata.row_group(i).num_rows
                lo, hi = max(start - first, 0), min(stop - first, size)
                first += size
                if lo >= hi:
                    continue
                table = handle.read_row_group(i, columns=columns).slice(lo, hi - lo)
                for batch in table.to_batches(max_chunksize=batch_rows):
                    yield batch.to_pandas()
                del table

    return meta, n_rows, pieces()


def write_canonical_chunks(chunks, meta: dict, path: str | os.PathLike) -> int:
    """Write a canonical log from an iterable of DataFrames, one Parquet row group each.

    Only one chunk is held in memory at a time, so logs larger than memory can be
    written. The file appears atomically when every chunk is written (no partial output).

    Parameters
    ----------
    chunks : iterable of DataFrame
        Consecutive pieces with identical columns and dtypes.
    meta : dict
        Canonical metadata, stored as JSON under schema key ``b"enclab"``.
    path : str or path-like

    Returns
    -------
    int
        Rows written.
    """
    rows = 0
    with _atomic_path(path) as tmp:
        writer = None
        try:
            for chunk in chunks:
                table = pa.Table.from_pandas(chunk, preserve_index=False)
                if writer is None:
                    merged = dict(table.schema.metadata or {})
                    merged[CANONICAL_METADATA_KEY] = json.dumps(
                        _jsonable(meta), allow_nan=False).encode()
                    schema = table.schema.with_metadata(merged)
                    writer = pq.ParquetWriter(tmp, schema)
                writer.write_table(table.replace_schema_metadata(schema.metadata),
                                   row_group_size=max(table.num_rows, 1))
                rows += table.num_rows
        finally:
            if writer is not None:
                writer.close()
        if writer is None:
            raise ValueError(f"no chunks to write to {str(path)!r}")
    return rows


# --------------------------------------------------------------------------- atomic writers


@functools.cache
def _umask() -> int:
    # os.umask can only be read by setting it; once per process, before any writer runs.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it into place on success, remove on error.

    Temporary files of ``path`` left by a writer that was killed (SIGKILL, power cut: no
    ``except`` ran) are removed first, so rewriting an output also clears its leftovers.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*.tmp{glob.escape(path.suffix)}"):
        stale.unlink(missing_ok=True)
    handle, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    # mkstemp makes the file private (0600); the output gets the mode a plain open() would
    # give it, so that a lab's group can read results on a shared file system.
    os.fchmod(handle, 0o666 & ~_umask())
    os.close(handle)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary folder next to ``path``; rename it to ``path`` on success,
    remove it on error, so that ``path`` exists only complete (``path`` must not exist)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    tmp.chmod(0o777 & ~_umask())  # as os.mkdir would make it, not mkdtemp's 0700
    try:
        yield tmp
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def write_text(text: str, path: str | os.PathLike) -> None:
    """Write ``text`` (UTF-8) atomically."""
    with _atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json(obj: Any, path: str | os.PathLike) -> None:
    """Write JSON atomically (indent 2); NaN/inf become null, numpy scalars/arrays plain JSON."""
    write_text(json.dumps(_jsonable(obj), indent=2, allow_nan=False) + "\n", path)


def read_json(path: str | os.PathLike) -> Any:
    """Parse a JSON file."""
    with open(path, encoding="utf-8") as handle:
        return json.load(handle)


def read_texts(folder: str | os.PathLike, pattern: str = "*") -> dict[str, str]:
    """``{file name: text}`` of the files in ``folder`` matching ``pattern`` (none: ``{}``);
    bytes that are not UTF-8 are replaced (these are logs to show, not data to parse)."""
    folder = Path(folder)
    if not folder.is_dir():
        return {}
    return {p.name: p.read_text(encoding="utf-8", errors="replace")
            for p in sorted(folder.glob(pattern)) if p.is_file()}


def write_parquet(df: pd.DataFrame, path: str | os.PathLike, metadata: dict | None = None) -> None:
    """Write a DataFrame to Parquet atomically, with ``metadata`` as JSON under key ``b"enclab"``."""
    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata is not None:
        merged = dict(table.schema.metadata or {})
        merged[CANONICAL_METADATA_KEY] = json.dumps(_jsonable(metadata), allow_nan=False).encode()
        table = table.replace_schema_metadata(merged)
    with _atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def write_table(df: pd.DataFrame, path: str | os.PathLike) -> None:
    """Write a table atomically as CSV or Parquet, chosen by the suffix of ``path``."""
    suffix = Path(path).suffix.lower()
    if suffix == ".parquet":
        write_parquet(df, path)
    elif suffix == ".csv":
        with _atomic_path(path) as tmp:
            df.to_csv(tmp, index=False)
    else:
        raise ValueError(f"path must end in .csv or .parquet, got {str(path)!r}")


def read_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read a table written by :func:`write_table` (.csv or .parquet)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".parquet":
        return pd.read_parquet(path)
    if suffix == ".csv":
        return pd.read_csv(path)
    raise ValueError(f"path must end in .csv or .parquet, got {str(path)!r}")


def save_thumbnail(source: str | os.PathLike, path: str | os.PathLike, max_width: int = 480,
                   colors: int = 64) -> None:
    """A small copy of a PNG figure for the HTML report, written atomically.

    Scaled to at most ``max_width`` pixels wide (aspect kept, Lanczos) and reduced to a palette
    of ``colors`` colours: a tenth of the full figure's bytes, the same for the same input.
    """
    from PIL import Image

    if max_width < 16 or not 2 <= colors <= 256:
        raise ValueError(f"max_width must be >= 16 and colors in 2..256, got {max_width}, {colors}")
    with Image.open(source) as image:
        image = image.convert("RGB")
    if image.width > max_width:
        height = max(1, round(image.height * max_width / image.width))
        image = image.resize((max_width, height), Image.LANCZOS)
    image = image.quantize(colors=colors)
    with _atomic_path(path) as tmp:
        image.save(tmp, format="PNG", optimize=True)


# Date stamps that would make figure files differ between identical runs.
_NO_DATES = {"pdf": {"CreationDate": None, "ModDate": None}, "svg": {"Date": None}}


def save_figure(fig, path: str | os.PathLike, dpi: int = 150) -> None:
    """Save a matplotlib Figure atomically (format from the suffix, no date stamps) and close it."""
    import matplotlib.pyplot as plt

    fmt = Path(path).suffix.lower().lstrip(".")
    if not fmt:
        raise ValueError(f"path needs a suffix naming the format, got {str(path)!r}")
    try:
        with _atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=fmt, metadata=_NO_DATES.get(fmt))
    finally:
        plt.close(fig)
