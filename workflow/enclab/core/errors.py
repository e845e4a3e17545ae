"""The one exception type for bad user input (logs, manifests, configuration).

Every problem a user can fix in their files is raised as :class:`EnclabInputError`, whose
``str()`` is one line naming the file, the place in it and what was expected, e.g.::

    data/run1.csv: column 'theta1', line 17: text 'n/a' in a numeric column; expected a number.

Location conventions
--------------------
``line``
    1-based line number in a text file (CSV or text export) *counting every line*: header,
    ``%`` comment and blank lines included, i.e. the number an editor shows.
``row``
    1-based data row of a binary table (Parquet, MATLAB ``.mat``): the first sample is row 1.
``sample``
    1-based sample number of a one-value-per-line, sample-major text file (several lines per
    sample): the value of column ``j`` (0-based) of sample ``s`` is on line ``(s-1)*k + j + 1``
    when the file has ``k`` values per sample and no header.
``key``
    dotted location in a YAML/JSON document (manifest, configuration), e.g.
    ``logs[3].channels[0].unit``.

Failures of a log at any stage
------------------------------
:func:`failure_line` turns *any* exception raised while a stage works on one log into the one
line the user reads (job log, run summary, report), naming the log's data file: bad input as
raised, an I/O failure (:func:`io_problem`: permissions, a vanished file, a full disk, a quota)
with the file it concerns and what to do, and anything else as an internal error.
"""
from __future__ import annotations

import errno
import re
from typing import Any

__all__ = ["EnclabInputError", "ROW_LABELS", "failure_line", "io_problem", "os_errno"]

ROW_LABELS = ("line", "row", "sample")


def _one_line(text: Any) -> str:
    return " ".join(str(text).split())


class EnclabInputError(ValueError):
    """Bad input that the user can fix, with where it is and what was expected.

    Parameters
    ----------
    file : str or path-like, optional
        The file that holds the problem (data file, time file, manifest or configuration).
    problem : str
        What is wrong, e.g. ``"NaN value"``.
    column : str or int, optional
        Column (or MATLAB variable) of a data file.
    row : int, optional
        1-based location in the file, counted as described by ``row_label``.
    row_label : {"row", "line", "sample"}
        How ``row`` is counted (see the module docstring); default ``"row"``.
    key : str, optional
        Dotted key in a manifest or configuration (used instead of column/row).
    expected : str, optional
        What a valid value looks like.
    hint : str, optional
        How to fix it.

    Examples
    --------
    >>> str(EnclabInputError("a.csv", "NaN value", column="theta1", row=12, row_label="line",
    ...                      expected="a finite number", hint="Crop the log (crop.t_end)."))
    "a.csv: column 'theta1', line 12: NaN value; expected a finite number. Crop the log (crop.t_end)."
    """

    def __init__(
        self,
        file: Any = None,
        problem: str = "invalid input",
        *,
        column: Any = None,
        row: int | None = None,
        row_label: str = "row",
        key: str | None = None,
        expected: str | None = None,
        hint: str | None = None,
    ) -> None:
        if row_label not in ROW_LABELS:
            raise ValueError(f"row_label must be one of {ROW_LABELS}, got {row_label!r}")
        self.file = None if file is None else str(file)
        self.problem = problem
        self.column = column
        self.row = None if row is None else int(row)
        self.row_label = row_label
        self.key = key
        self.expected = expected
        self.hint = hint
        super().__init__(self._message())

    def _message(self) -> str:
        where = []
        if self.key is not None:
            where.append(f"key '{self.key}'")
        if self.column is not None:
            where.append(f"column '{self.column}'")
        if self.row is not None:
            where.append(f"{self.row_label} {self.row}")
        head = ", ".join(where)
        if self.file is not None:
            head = f"{self.file}: {head}" if head else self.file
        text = f"{head}: {_one_line(self.problem)}" if head else _one_line(self.problem)
        if self.expected:
            text += f"; expected {_one_line(self.expected)}"
        text += "."
        if self.hint:
            hint = _one_line(self.hint)
            text += f" {hint}" if hint.endswith((".", "?", "!")) else f" {hint}."
        return text

    def __str__(self) -> str:
        return self._message()

    def __reduce__(self):
        # ValueError pickles as cls(*args); keep the structured fields instead (parallel jobs).
        return (
            _rebuild,
            (
                self.file,
                self.problem,
                {
                    "column": self.column,
                    "row": self.row,
                    "row_label": self.row_label,
                    "key": self.key,
                    "expected": self.expected,
                    "hint": self.hint,
                },
            ),
        )


def _rebuild(file: Any, problem: str, fields: dict) -> EnclabInputError:
    return EnclabInputError(file, problem, **fields)


# errno -> (what happened to the file, what to do); the disk-full family shares one fix.
_FULL = ("no space left for it: the disk is full, or a file-size limit or disk quota was reached",
         "free space (or raise the limit), then rerun")
_IO_PROBLEMS = {
    errno.EACCES: ("permission denied", "give the workflow's user read access to the data "
                   "and write access to results/, then rerun"),
    errno.EPERM: ("operation not permitted", "check the file's owner and permissions, then rerun"),
    errno.ENOENT: ("no such file: moved, renamed or deleted", "restore it (or fix the "
                   "manifest's 'file'), then rerun"),
    errno.EISDIR: ("is a directory, not a file", "name a file in the manifest"),
    errno.EIO: ("input/output error: the disk or network mount failed while reading or writing",
                "check the storage, then rerun"),
    errno.EROFS: ("read-only file system", "run where results/ is writable"),
    errno.ENOSPC: _FULL,
    errno.EFBIG: _FULL,
    errno.EDQUOT: _FULL,
}


def os_errno(err: OSError) -> int | None:
    """The system error number of ``err``; Arrow's I/O errors quote it in their text only."""
    if err.errno is not None:
        return err.errno
    found = re.search(r"\[errno (\d+)\]", str(err), flags=re.IGNORECASE)
    return int(found.group(1)) if found else None


def io_problem(err: OSError) -> str:
    """One line for an I/O failure: the file it concerns, what happened and what to do.

    Examples
    --------
    >>> io_problem(OSError(errno.EFBIG, "File too large", "results/a/derivatives.parquet"))
    'results/a/derivatives.parquet: no space left for it: the disk is full, or a file-size \
limit or disk quota was reached (File too large); free space (or raise the limit), then rerun'
    """
    what, fix = _IO_PROBLEMS.get(os_errno(err), (None, "check the file and the disk, then rerun"))
    detail = err.strerror or _one_line(err) or type(err).__name__
    text = detail if what is None else what if detail.lower() in what.lower() else f"{what} ({detail})"
    if err.filename is not None:
        text = f"{err.filename}: {text}"
    return f"{text}; {fix}"


def failure_line(err: BaseException, source: Any = None) -> tuple[str, bool]:
    """The one-line reason a log failed, and whether the failure is expected (not a bug).

    Parameters
    ----------
    err : BaseException
        What a stage raised while working on the log.
    source : str or path-like, optional
        The log's data file (or, without one, the log's id): put first unless the message
        names it already, so that every failure names the file it is about.

    Returns
    -------
    line : str
        :class:`EnclabInputError` and other ``ValueError`` (a library check on the log's
        contents or settings) as raised; an ``OSError`` as :func:`io_problem`; a
        ``MemoryError`` as such; anything else as an internal error with its type.
    expected : bool
        False for an internal error (a bug: the caller logs the traceback after the line).
    """
    expected = True
    if isinstance(err, ValueError):
        text = _one_line(err)
    elif isinstance(err, OSError):
        text = io_problem(err)
    elif isinstance(err, MemoryError):
        text = "out of memory; run fewer jobs at once (--cores) or on a larger machine"
    else:
        expected = False
        text = (f"internal error {type(err).__name__}: {_one_line(err)} (a bug in enclab, not "
                "in the file; the traceback follows in the job's log)")
    if source is not None and str(source) not in text:
        text = f"{source}: {text}"
    return text, expected
