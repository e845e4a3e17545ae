"""Across logs: pool repeat runs, compare measured with predicted error, check the bounds.

The input is the batch table (``results/batch/quantization.csv``, one row per log, level,
signal, filter and architecture; see :func:`enclab.propagation.analysis.summary_table`). A *repeat group*
is the set of logs that share ``group`` (a log whose group is missing is its own group,
named by its ``log_id``): the same configuration and protocol run several times. Runs are
independent, so the spread of their variances gives a confidence interval that holds however
strongly the samples inside one run are correlated.

All values are SI (rad, m, s); ratios are dimensionless.

References
----------
.. [1] Colonnese, N. and Okamura, A. M., "Propagation of joint space quantization error to
       operational space coordinates and their derivatives", Table II and Section IV.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
import scipy.stats

__all__ = ["POOL_KEYS", "pool_runs", "ratio_table", "bound_violations"]

#: Columns that identify one pooled quantity. Positions have no filter: their ``d``, ``n``,
#: ``fc_hz`` are NaN, and NaN keys must group together rather than be dropped.
POOL_KEYS = ("group", "level", "signal", "order", "d", "n", "fc_hz", "discretization",
             "architecture")

_NUMERIC_KEYS = ("order", "d", "n", "fc_hz")
_TEXT_KEYS = ("group", "level", "signal", "discretization", "architecture")
_RMS_COLUMNS = ("pqn_std", "exact_std")
_MAX_COLUMNS = ("worst_case", "worst_case_trajectory", "emp_max_abs")
_REQUIRED = (("log_id",) + POOL_KEYS + ("emp_std", "emp_std_lo", "emp_std_hi", "unit")
             + _RMS_COLUMNS + _MAX_COLUMNS)
_CARRIED = ("centre_deg", "unit", "device")
_MODELS = ("pqn", "exact")


def _check_ci_level(ci_level) -> float:
    if not (isinstance(ci_level, (int, float, np.floating)) and 0.0 < ci_level < 1.0):
        raise ValueError(f"ci_level={ci_level!r} must be a number in (0, 1)")
    return float(ci_level)


def _check_table(table, argument: str, required: Sequence[str]) -> None:
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"{argument} must be a pandas DataFrame, got {type(table).__name__}")
    missing = [column for column in required if column not in table.columns]
    if missing:
        raise ValueError(f"{argument} lacks column(s) {missing}")


def _normalized(table: pd.DataFrame) -> pd.DataFrame:
    """Copy with numeric keys and measures as float and missing text keys as ``''``.

    A table read back from CSV turns empty strings into NaN; normalizing keeps ``''`` and NaN
    in one group. A missing ``group`` becomes the log's own id.
    """
    out = table.reset_index(drop=True).copy()
    log_id = out["log_id"].astype(object)
    if log_id.isna().any():
        raise ValueError(f"table: log_id is missing in row(s) "
                         f"{np.flatnonzero(log_id.isna()).tolist()}")
    out["log_id"] = log_id.astype(str)
    group = out["group"].astype(object)
    group = group.where(group.notna() & (group.astype(str).str.strip() != ""), out["log_id"])
    out["group"] = group.astype(str)
    for column in _TEXT_KEYS[1:] + tuple(c for c in _CARRIED if c in out.columns):
        values = out[column].astype(object)
        out[column] = values.where(values.notna(), "").astype(str)
    numeric = (_NUMERIC_KEYS + ("emp_std", "emp_std_lo", "emp_std_hi") + _RMS_COLUMNS
               + _MAX_COLUMNS)
    for column in numeric:
        out[column] = pd.to_numeric(out[column], errors="coerce").astype(float)
    bad_order = ~out["order"].isin((0, 1, 2))
    if bad_order.any():
        row = int(np.flatnonzero(bad_order)[0])
        raise ValueError(f"table: order must be 0, 1 or 2, got {table['order'].iloc[[row]].tolist()[0]!r} in "
                         f"row {row}")
    out["order"] = out["order"].astype(np.int64)
    return out


def _complete(aggregate: pd.Series, n_valid: pd.Series, n_runs: pd.Series) -> np.ndarray:
    """An aggregate over runs is only meaningful when no run is missing the value."""
    return np.where(n_valid.to_numpy() == n_runs.to_numpy(), aggregate.to_numpy(), np.nan)


def pool_runs(table: pd.DataFrame, ci_level: float = 0.95) -> pd.DataFrame:
    """Pool the runs of each repeat group and compare the pooled std with the models.

    Rows are grouped by :data:`POOL_KEYS` (``group``, ``level``, ``signal``, ``order``, ``d``,
    ``n``, ``fc_hz``, ``discretization``, ``architecture``); NaN filter fields of position rows
    form their own key instead of being dropped. Within a group each log contributes one run.

    For runs ``r = 1..R`` with measured std ``s_r`` and model std ``m_r`` (PQN or exact), the
    per-run variance ratio is ``v_r = s_r**2 / m_r**2`` and the pooled ratio is
    ``sqrt(mean(v_r))``. Its interval is the Student-t interval (``R - 1`` degrees of freedom)
    of ``mean(v_r)`` with standard error ``std(v_r, ddof=1) / sqrt(R)``, mapped through the
    square root (lower end clipped at 0). The pooled ``emp_std`` and its interval are the same
    construction on ``s_r**2``. A single run has no spread across runs: its own interval
    (``emp_std_lo``, ``emp_std_hi``, from within the run) is used, divided by the model std
    for the ratios.

    Parameters
    ----------
    table : pandas.DataFrame
        The batch table. Required columns: ``log_id``, the pool keys, ``emp_std``,
        ``emp_std_lo``, ``emp_std_hi``, ``emp_max_abs``, ``pqn_std``, ``exact_std``,
        ``worst_case``, ``worst_case_trajectory``, ``unit``; ``centre_deg`` and ``device``
        are carried along when present. A missing ``group`` means the log is its own group.
    ci_level : float, default 0.95
        Confidence level of the intervals, in (0, 1).

    Returns
    -------
    pandas.DataFrame
        One row per pool key, in order of first appearance, with the keys, ``centre_deg``,
        ``device``, ``unit``, ``n_runs``, ``emp_std`` (rms of the run stds), ``emp_std_lo``,
        ``emp_std_hi``, ``pqn_std`` and ``exact_std`` (rms over runs), ``worst_case``,
        ``worst_case_trajectory`` and ``emp_max_abs`` (max over runs), ``ratio_pqn``,
        ``ratio_pqn_lo``, ``ratio_pqn_hi``, ``ratio_exact``, ``ratio_exact_lo``,
        ``ratio_exact_hi``. A value missing in any run of a group, or a model std that is not
        positive, gives NaN for the quantities that depend on it.

    Raises
    ------
    ValueError
        Missing columns, a bad ``ci_level``, a missing ``log_id``, a log that appears twice
        under one pool key, or a pool key whose runs disagree on the unit.

    References
    ----------
    .. [1] Colonnese and Okamura, Section IV (repeated runs of the Phantom protocol).
    """
    ci_level = _check_ci_level(ci_level)
    _check_table(table, "table", _REQUIRED)
    rows = _normalized(table)
    keys = list(POOL_KEYS)

    duplicated = rows.duplicated(keys + ["log_id"], keep=False)
    if duplicated.any():
        first = rows.loc[duplicated, keys + ["log_id"]].iloc[0].to_dict()
        raise ValueError(f"table holds {int(duplicated.sum())} rows that repeat a log under one "
                         f"pool key, e.g. {first}")

    rows["emp_var"] = rows["emp_std"] ** 2
    for column in _RMS_COLUMNS:
        rows[f"{column}_sq"] = rows[column] ** 2
    for model in _MODELS:
        model_std = rows[f"{model}_std"].where(rows[f"{model}_std"] > 0)
        rows[f"v_{model}"] = rows["emp_var"] / model_std ** 2
        # Single runs divide their own interval by the model std.
        rows[f"single_{model}_lo"] = rows["emp_std_lo"] / model_std
        rows[f"single_{model}_hi"] = rows["emp_std_hi"] / model_std

    grouped = rows.groupby(keys, dropna=False, sort=False)
    units = grouped["unit"].nunique()
    if (units > 1).any():
        bad = units[units > 1].index[0]
        raise ValueError(f"table: the runs of pool key {dict(zip(keys, bad))} have different "
                         f"units {sorted(grouped.get_group(bad)['unit'].unique())}")

    n_runs = grouped.size()
    count, mean, spread = grouped.count(), grouped.mean(numeric_only=True), grouped.std(
        numeric_only=True, ddof=1)
    first = grouped.first()
    pooled = n_runs.index.to_frame(index=False)
    for column in _CARRIED:
        if column in rows.columns:
            pooled[column] = first[column].to_numpy()
    pooled["n_runs"] = n_runs.to_numpy()

    multi = pooled["n_runs"].to_numpy() >= 2
    # t quantile per group; single runs get NaN (no degrees of freedom) and use their own CI.
    degrees = np.where(multi, pooled["n_runs"].to_numpy() - 1, 1)
    quantile = np.where(multi, scipy.stats.t.ppf(0.5 + ci_level / 2.0, degrees), np.nan)
    sqrt_runs = np.sqrt(pooled["n_runs"].to_numpy())

    def pooled_sqrt_interval(column: str, single_lo, single_hi):
        centre = _complete(mean[column], count[column], n_runs)
        half_width = quantile * spread[column].to_numpy() / sqrt_runs
        lo = np.sqrt(np.clip(centre - half_width, 0.0, None))
        hi = np.sqrt(centre + half_width)
        return (np.sqrt(centre), np.where(multi, lo, single_lo),
                np.where(multi, hi, single_hi))

    (pooled["emp_std"], pooled["emp_std_lo"], pooled["emp_std_hi"]) = pooled_sqrt_interval(
        "emp_var", first["emp_std_lo"].to_numpy(), first["emp_std_hi"].to_numpy())
    for column in _RMS_COLUMNS:
        pooled[column] = np.sqrt(_complete(mean[f"{column}_sq"], count[f"{column}_sq"], n_runs))
    maxima = grouped[list(_MAX_COLUMNS)].max()
    for column in _MAX_COLUMNS:
        pooled[column] = _complete(maxima[column], count[column], n_runs)
    for model in _MODELS:
        (pooled[f"ratio_{model}"], pooled[f"ratio_{model}_lo"],
         pooled[f"ratio_{model}_hi"]) = pooled_sqrt_interval(
            f"v_{model}", first[f"single_{model}_lo"].to_numpy(),
            first[f"single_{model}_hi"].to_numpy())
    return pooled


_RATIO_BY = ("order", "level", "architecture")


def ratio_table(pooled: pd.DataFrame, by: Sequence[str] = _RATIO_BY) -> pd.DataFrame:
    """Range of the measured / model std ratios, with the worst interval ends, per cell.

    Parameters
    ----------
    pooled : pandas.DataFrame
        Output of :func:`pool_runs` (columns ``ratio_pqn``, ``ratio_pqn_lo``, ``ratio_pqn_hi``
        and the same for ``exact``, plus the ``by`` columns).
    by : sequence of str, default ('order', 'level', 'architecture')
        Columns that define one summary row.

    Returns
    -------
    pandas.DataFrame
        One row per ``by`` cell (sorted), with ``n_rows`` (pooled rows in the cell) and, for
        ``kind`` in ``pqn`` and ``exact``: ``ratio_<kind>_min``, ``ratio_<kind>_max``,
        ``ratio_<kind>_lo_min`` (lowest lower interval end) and ``ratio_<kind>_hi_max``
        (highest upper interval end). Missing ratios are ignored; a cell without any gives NaN.

    Raises
    ------
    ValueError
        Missing columns or an empty ``by``.
    """
    by = list(by)
    if not by:
        raise ValueError("by=[] must name at least one column")
    ratio_columns = [f"ratio_{model}{end}" for model in _MODELS for end in ("", "_lo", "_hi")]
    _check_table(pooled, "pooled", by + ratio_columns)
    values = pooled[by + ratio_columns].copy()
    for column in ratio_columns:
        values[column] = pd.to_numeric(values[column], errors="coerce").astype(float)
    grouped = values.groupby(by, dropna=False, sort=True)
    out = grouped.size().rename("n_rows").to_frame()
    for model in _MODELS:
        ratio = f"ratio_{model}"
        out[f"{ratio}_min"] = grouped[ratio].min()
        out[f"{ratio}_max"] = grouped[ratio].max()
        out[f"{ratio}_lo_min"] = grouped[f"{ratio}_lo"].min()
        out[f"{ratio}_hi_max"] = grouped[f"{ratio}_hi"].max()
    return out.reset_index()


def bound_violations(table: pd.DataFrame, rtol: float = 1e-9) -> pd.DataFrame:
    """Rows whose measured max |error| exceeds the worst case over the trajectory.

    The trajectory bound holds for every sample, so this table should be empty; a row here
    points at a wrong Jacobian, step or filter gain. Rows whose bound is missing cannot be
    checked and are not reported.

    Parameters
    ----------
    table : pandas.DataFrame
        The batch table (or any table with ``emp_max_abs`` and ``worst_case_trajectory``).
    rtol : float, default 1e-9
        Relative margin for floating-point rounding: a sample exactly on the bound (e.g. a
        position error of exactly half a step) must not count as a violation.

    Returns
    -------
    pandas.DataFrame
        The violating rows with all their columns plus ``excess`` =
        ``emp_max_abs / worst_case_trajectory - 1``; no rows (same columns) when the bound
        holds everywhere.

    Raises
    ------
    ValueError
        Missing columns or a negative or non-finite ``rtol``.
    """
    if not (np.isfinite(rtol) and rtol >= 0):
        raise ValueError(f"rtol={rtol!r} must be a finite non-negative fraction")
    _check_table(table, "table", ("emp_max_abs", "worst_case_trajectory"))
    measured = pd.to_numeric(table["emp_max_abs"], errors="coerce").astype(float)
    bound = pd.to_numeric(table["worst_case_trajectory"], errors="coerce").astype(float)
    violating = (measured > bound * (1.0 + rtol)).to_numpy()
    out = table.loc[violating].copy()
    out["excess"] = (measured / bound - 1.0)[violating]
    return out.reset_index(drop=True)
