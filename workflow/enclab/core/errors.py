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
"""
from __future__ import annotations

from typing import Any

__all__ = ["EnclabInputError", "ROW_LABELS"]

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
