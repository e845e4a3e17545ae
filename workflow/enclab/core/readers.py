"""Raw log readers: the manifest, and the numbers of the columns a manifest entry needs.

Readers return :class:`RawLog` and know, for every sample, where it sits in its file (text line,
table row, or sample of a one-value-per-line file), so that every
:class:`~enclab.core.errors.EnclabInputError` names the exact place. The conversions to SI, the
time base and the checks on it are pure functions in :mod:`enclab.core.ingest`.

Files come as labs have them: any of the formats may be gzip-compressed (read transparently,
recognised by their first bytes), text files may be in another encoding than UTF-8
(``reader.encoding``, e.g. ``latin-1`` for a degree sign written by a Windows logger), and
semicolon-separated files with decimal commas are read when declared (``reader.delimiter: ";"``,
``reader.decimal: ","``). When a file does not match what the entry declares, the error says
which key to set.
"""
from __future__ import annotations

import codecs
import contextlib
import gzip
import hashlib
import io as _stdio
import os
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from enclab.core.errors import EnclabInputError
from enclab.core.manifest import validate_manifest

__all__ = [
    "RawLog",
    "require_finite",
    "entry_files",
    "file_sha256",
    "is_gzip",
    "read_bytes",
    "read_manifest",
    "read_raw",
]

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
        Normalised log entries (see :func:`enclab.core.manifest.validate_manifest`).

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
        (by :func:`enclab.core.ingest.canonicalize`).
    columns : dict of str to str
        Source column label of each channel, for messages.
    locations : ndarray of int64
        User-facing location of each sample in ``file`` (``locations[i]`` for sample ``i``).
    row_label : {"line", "row", "sample"}
        How ``locations`` count (see :mod:`enclab.core.errors`).
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
        # With a crop, only the kept samples must be finite: enclab.core.ingest checks them.
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
    # Memory: the lines are split one column at a time (getter), never all at once: a list of
    # fields per line costs ~10 times the file (a 3e6-line log: 1.8 GB instead of 0.7).
    texts = [text.strip() if delimiter == "whitespace" else text for _, text in content]
    del content, lines
    rows = [split(texts[0])]
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
    lengths = np.fromiter((len(split(text)) for text in texts), dtype=np.int64, count=len(texts))
    ragged = np.flatnonzero(lengths != width)
    if ragged.size:
        i = int(ragged[0])
        raise EnclabInputError(display, f"{lengths[i]} values on this line", row=int(numbers[i]),
                               row_label="line", expected=f"{width} values like the first data line")

    def getter(j: int) -> np.ndarray:
        return _parse_numbers([split(text)[j] for text in texts], names[j], numbers, "line", display,
                              decimal)

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
