"""Results on disk: atomic writers (text, JSON, tables, Parquet, figures, thumbnails) and their
readers.

Every writer is atomic: it writes a temporary file in the target's directory and moves it into
place with :func:`os.replace`, so an interrupted job never leaves a partial output; the file gets
the mode a plain ``open()`` would give under the umask.
"""
from __future__ import annotations

import contextlib
import functools
import glob
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from enclab.core.errors import os_errno

__all__ = [
    "CANONICAL_METADATA_KEY",
    "atomic_folder",
    "read_json",
    "read_table",
    "read_texts",
    "save_figure",
    "save_thumbnail",
    "write_json",
    "write_parquet",
    "write_table",
    "write_text",
]

CANONICAL_METADATA_KEY = b"enclab"


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
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise _naming(err, tmp, path) from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _naming(err: OSError, tmp: Path, path: Path) -> OSError:
    """``err`` naming the output it failed to write, when it names no file or the temporary
    one (a write() on a full disk raises ``OSError(EFBIG)`` or ``OSError(ENOSPC)`` without a
    file name; pyarrow's errors quote the errno in their text only)."""
    if err.filename is not None and Path(err.filename) != tmp:
        return err
    code = os_errno(err)
    strerror = os.strerror(code) if code is not None else str(err)
    return OSError(code, strerror, str(path))


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
