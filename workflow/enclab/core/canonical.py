"""The canonical log: Parquet with the log's metadata JSON under the schema key ``b"enclab"``,
read whole or streamed in row batches, and written from chunks for logs larger than memory;
and :class:`Channel`, one channel of it in SI with its step, grid and unit.
"""
from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from enclab.core.atomic import (
    CANONICAL_METADATA_KEY,
    _atomic_path,
    _jsonable,
    write_parquet,
)
from enclab.core.errors import EnclabInputError

__all__ = [
    "Channel",
    "iter_canonical",
    "read_canonical",
    "write_canonical",
    "write_canonical_chunks",
]

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
                               expected="a canonical log written by enclab.core.canonical.write_canonical")
    return table.to_pandas(), json.loads(raw_meta)


def _canonical_meta(path, schema: pa.Schema) -> dict:
    raw_meta = (schema.metadata or {}).get(CANONICAL_METADATA_KEY)
    if raw_meta is None:
        raise EnclabInputError(path, "Parquet file without enclab metadata",
                               expected="a canonical log written by enclab.core.canonical.write_canonical")
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


# --------------------------------------------------------------------------- channels


@dataclass(frozen=True)
class Channel:
    """One channel of a canonical log: its metadata, typed, and its stored column.

    A quantized channel is stored as int64 ``counts`` with an SI ``step`` (never as re-rounded
    floats); any other channel as SI floats. :attr:`values` is the channel in SI either way.
    Build one with :meth:`of` (a channel's metadata entry and a table holding its column) or
    :meth:`named` (a log's metadata and a channel name).

    Attributes
    ----------
    name : str
    unit : str
        SI unit of :attr:`values` and of the steps (``"rad"`` or ``"m"``).
    role : str or None
        ``"truth"``, ``"measured"`` or ``"aux"``.
    joint : int or None
    step : float or None
        Quantization step (SI) of a channel stored as counts; None for a float channel.
    native_step : float or None
        The grid a channel's values sit on (declared or detected at ingest; equal to ``step``
        for a counts channel), None when unknown.
    column : ndarray or None
        The stored column (int64 counts or float64 SI), None for metadata alone.
    """

    name: str
    unit: str
    role: str | None = None
    joint: int | None = None
    step: float | None = None
    native_step: float | None = None
    column: np.ndarray | None = None

    @classmethod
    def of(cls, chan: Mapping, df: pd.DataFrame | None = None, *,
           column: np.ndarray | None = None) -> Channel:
        """The channel of a metadata entry (``meta["channels"][k]``), with its column: of the
        table ``df`` or the stored ``column`` itself, when given."""
        counts = chan["storage"] == "counts"
        native = chan.get("native_step")
        if df is not None:
            column = df[chan["name"]].to_numpy()
        return cls(name=chan["name"], unit=chan.get("unit"), role=chan.get("role"),
                   joint=chan.get("joint"), step=float(chan["step"]) if counts else None,
                   native_step=None if native is None else float(native), column=column)

    @classmethod
    def named(cls, meta: Mapping, name: str, df: pd.DataFrame | None = None) -> Channel:
        """Channel ``name`` of a log's metadata, with its column of ``df`` when given.

        Raises
        ------
        ValueError
            When the log has no such channel (the message lists the log's channels).
        """
        chan = next((c for c in meta["channels"] if c["name"] == name), None)
        if chan is None:
            raise ValueError(f"log {meta.get('log_id')!r} has no channel {name!r}; channels "
                             f"{[c['name'] for c in meta['channels']]}")
        return cls.of(chan, df)

    @property
    def is_counts(self) -> bool:
        """Whether the channel is stored as integer counts (it then has a ``step``)."""
        return self.step is not None

    @property
    def grid(self) -> float | None:
        """The grid the values sit on: the step of a counts channel, else the native step."""
        return self.step if self.is_counts else self.native_step

    def _stored(self) -> np.ndarray:
        if self.column is None:
            raise ValueError(f"channel {self.name!r} was built without its column")
        return self.column

    @property
    def counts(self) -> np.ndarray | None:
        """The stored integer counts of a counts channel, None for a float channel."""
        return self._stored() if self.is_counts else None

    @property
    def values(self) -> np.ndarray:
        """The channel in SI (:attr:`unit`), float64: ``counts * step`` or the stored floats."""
        column = self._stored().astype(np.float64)
        return column * self.step if self.is_counts else column
