"""Figures of the quantization-error analysis.

Every function takes the workflow's tables (or arrays) and returns a
:class:`matplotlib.figure.Figure` built without :mod:`matplotlib.pyplot`, so nothing global is
created or needs closing and any backend works; the caller (a workflow script) saves it.
Figures are deterministic for a given input and their layout is computed once and frozen
before they are returned: save them with ``metadata={"Software": None}`` to get byte-identical
PNGs, however often and in whatever order they are saved.

Values in the tables are SI (rad, m, s). Each panel rescales them to a readable unit chosen from
the largest value it shows (e.g. µm, mm/s, mrad/s²); the unit appears in the axis label.

Conventions shared by all figures:

* standard deviation: PQN theory dashed, exact (non-white) theory solid, measured values as
  markers with their confidence interval (``emp_std_lo`` .. ``emp_std_hi``);
* worst case: Table II centre-configuration bound dash-dotted, bound over the trajectory dotted,
  measured ``max |error|`` as crosses;
* a series whose values are all missing (NaN) is not drawn and gets no legend entry; single
  missing values leave a gap.

References
----------
.. [1] Colonnese, N. and Okamura, A. M., "Propagation of joint space quantization error to
       operational space coordinates and their derivatives", Figs. 5-7, Table II and Section IV.
"""
from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import NullFormatter

__all__ = [
    "fig6_position_error",
    "fig7_derivative_error",
    "ratio_figure",
    "real_log_figure",
    "error_trace_figure",
]

_OPERATIONAL = ("x", "y", "z")
_ORDER_NAMES = {0: "position", 1: "velocity", 2: "acceleration"}
_ORDER_SUFFIX = {0: "", 1: "/s", 2: "/s²"}
_DISCRETIZATION_PREFERENCE = ("exponential", "bilinear")
# Largest prefix whose value does not exceed the panel's largest value; errors never need "k".
_PREFIXES = ((1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"))
# Two decades or more between the smallest and largest positive value: a log axis reads better.
_LOG_RANGE = 100.0
# Up to this many distinct x values (cutoffs, steps) are labelled one by one on a log axis.
_MAX_VALUE_TICKS = 8

_STRING_COLUMNS = ("log_id", "group", "tags", "device", "level", "centre_deg", "signal",
                   "discretization", "architecture", "unit")
_NUMERIC_COLUMNS = ("order", "d", "n", "fc_hz", "emp_mean", "emp_std", "emp_std_lo",
                    "emp_std_hi", "emp_max_abs", "n_samples", "pqn_std", "exact_std",
                    "worst_case", "worst_case_trajectory", "n_runs", "ratio_pqn", "ratio_pqn_lo",
                    "ratio_pqn_hi", "ratio_exact", "ratio_exact_lo", "ratio_exact_hi")
_STD_COLUMNS = ("emp_std", "emp_std_lo", "emp_std_hi", "pqn_std", "exact_std")
_WORST_COLUMNS = ("emp_max_abs", "worst_case", "worst_case_trajectory")

# Series styles (colour is given separately where it encodes something else).
_PQN = dict(linestyle="--", linewidth=1.4)
_EXACT = dict(linestyle="-", linewidth=1.4)
_MEASURED = dict(marker="o", markersize=5, linestyle="none", capsize=3, elinewidth=1.0)
_WORST = dict(linestyle="-.", linewidth=1.4)
_WORST_TRAJ = dict(linestyle=":", linewidth=1.8)
_MAX = dict(marker="x", markersize=7, markeredgewidth=1.5, linestyle="none")

_STD_COLOUR = "tab:blue"
_WORST_COLOUR = "tab:red"
_PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink",
            "tab:olive", "tab:cyan", "tab:gray", "tab:red")

_LEVEL_MULTIPLE = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*x\s*$")
_LEVEL_STEP = re.compile(r"^\s*(\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)\s*(n|u|µ|m)?(rad|m)\s*$")
_STEP_PREFIX = {None: 1.0, "m": 1e-3, "u": 1e-6, "µ": 1e-6, "n": 1e-9}


# --------------------------------------------------------------------------------------------
# helpers


def _parse_unit(unit: str, argument: str = "unit") -> tuple[str, int]:
    """Split an SI unit such as ``'m/s^2'`` into its base (``'rad'`` or ``'m'``) and the order."""
    compact = str(unit).replace(" ", "").replace("²", "^2")
    for base in ("rad", "m"):
        for order, suffix in ((0, ""), (1, "/s"), (2, "/s^2"), (2, "/s2")):
            if compact == base + suffix:
                return base, order
    raise ValueError(f"{argument}={unit!r} is not one of rad, m, rad/s, m/s, rad/s^2, m/s^2")


def _display_unit(base: str, order: int, values) -> tuple[float, str]:
    """Scale factor (SI per displayed unit) and unit label for the values shown on one axis."""
    magnitudes = np.abs(np.asarray(values, dtype=float)).ravel()
    magnitudes = magnitudes[np.isfinite(magnitudes) & (magnitudes > 0)]
    reference = magnitudes.max() if magnitudes.size else 1.0
    for factor, prefix in _PREFIXES:
        if reference >= factor:
            break
    return factor, f"{prefix}{base}{_ORDER_SUFFIX[order]}"


def _apply_yscale(ax: Axes, values) -> None:
    """Log y axis when the positive values span two decades or more, else linear from zero."""
    arr = np.asarray(values, dtype=float).ravel()
    positive = arr[np.isfinite(arr) & (arr > 0)]
    if positive.size and positive.max() / positive.min() >= _LOG_RANGE:
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0.0)


def _prepare(table, argument: str, required: Sequence[str]) -> pd.DataFrame:
    """Check the columns and return a copy with clean string and numeric columns."""
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"{argument} must be a pandas DataFrame, got {type(table).__name__}")
    missing = [column for column in required if column not in table.columns]
    if missing:
        raise ValueError(f"{argument} lacks column(s) {missing}")
    out = table.reset_index(drop=True).copy()
    for column in _STRING_COLUMNS:
        if column in out.columns:
            values = out[column].astype(object)
            out[column] = values.where(values.notna(), "").astype(str).str.strip()
    for column in _NUMERIC_COLUMNS:
        if column in out.columns:
            out[column] = pd.to_numeric(out[column], errors="coerce").astype(float)
    return out


def _unique(values) -> list:
    """Distinct values in order of first appearance."""
    return list(dict.fromkeys(values))


def _single_base_unit(rows: pd.DataFrame, what: str) -> str:
    """The one base unit (rad or m) of ``rows``; mixed units cannot share an axis."""
    bases = _unique(_parse_unit(unit, f"unit of {what}")[0] for unit in rows["unit"])
    if len(bases) != 1:
        raise ValueError(f"{what} mixes units {bases}; select signals of one kind")
    return bases[0]


def _select_level(rows: pd.DataFrame, level, what: str) -> tuple[pd.DataFrame, str]:
    levels = _unique(rows["level"])
    if level is None:
        if len(levels) != 1:
            raise ValueError(f"{what} holds several levels {levels}; pass level= one of them")
        level = levels[0]
    elif level not in levels:
        raise ValueError(f"level={level!r} not found for {what}; available: {levels}")
    return rows[rows["level"] == level], level


def _configuration_label(centre_deg: str, group: str) -> str:
    """``'0,15,30'`` (or ``'0;15;30'``) -> ``'(0, 15, 30)°'``; the group name when no centre
    is given."""
    if not centre_deg:
        return group
    try:
        angles = [float(part) for part in re.split(r"[,;]", centre_deg)]
    except ValueError:
        return centre_deg
    return "(" + ", ".join(f"{angle:g}" for angle in angles) + ")°"


def _settled(fig: Figure) -> Figure:
    """Run the constrained layout once and freeze it.

    The constrained layout starts from the current axes positions, so its result shifts
    slightly from one draw to the next: an unfrozen figure saved twice (PDF then PNG, or at two
    dpi) would not give the same pixels. Frozen, every save at a given dpi is identical.
    """
    fig.draw_without_rendering()
    fig.set_layout_engine("none")
    return fig


def _log_x_axis(ax: Axes, values) -> None:
    """Log x axis ticked at the plotted values (cutoffs, steps) when there are few of them.

    Within about a decade matplotlib labels the minor ticks too, and those labels overlap.
    """
    ax.set_xscale("log")
    arr = np.asarray(values, dtype=float).ravel()
    ticks = np.unique(arr[np.isfinite(arr) & (arr > 0)])
    if 0 < ticks.size <= _MAX_VALUE_TICKS:
        ax.set_xticks(ticks, [f"{tick:g}" for tick in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())


def _has_data(values) -> bool:
    return bool(np.isfinite(np.asarray(values, dtype=float)).any())


def _line(ax: Axes, x, y, factor: float, **style) -> None:
    if _has_data(y):
        ax.plot(x, np.asarray(y, dtype=float) / factor, **style)


def _errorbar(ax: Axes, x, y, lo, hi, factor: float, **style) -> None:
    """Markers at ``y`` with asymmetric bars to the interval ``[lo, hi]`` (absolute bounds)."""
    y = np.asarray(y, dtype=float)
    if not _has_data(y):
        return
    lower = np.nan_to_num(y - np.asarray(lo, dtype=float), nan=0.0).clip(min=0.0)
    upper = np.nan_to_num(np.asarray(hi, dtype=float) - y, nan=0.0).clip(min=0.0)
    ax.errorbar(x, y / factor, yerr=np.vstack([lower, upper]) / factor, **style)


def _figure_legend(fig: Figure, axes: Sequence[Axes]) -> None:
    """One legend for the figure with every labelled artist of ``axes`` once, in order."""
    entries: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    if entries:
        fig.legend(list(entries.values()), list(entries.keys()), loc="outside right center",
                   fontsize="small")


def _style_legend(fig: Figure, colour_entries: Sequence[tuple[str, str]],
                  style_entries: Sequence[tuple[str, dict]]) -> None:
    """Figure legend made of proxies: colours (what colour encodes), then grey line styles."""
    handles = [Line2D([], [], color=colour, linewidth=3, label=label)
               for label, colour in colour_entries]
    for label, style in style_entries:
        style = {key: value for key, value in style.items()
                 if key not in ("capsize", "elinewidth")}
        handles.append(Line2D([], [], color="0.35", label=label, **style))
    fig.legend(handles=handles, loc="outside right center", fontsize="small")


def _std_panel(ax: Axes, x, rows: pd.DataFrame, factor: float, colour: str, tag: str) -> None:
    """PQN and exact std lines plus measured std with its confidence interval."""
    _line(ax, x, rows["pqn_std"], factor, color=colour, label=f"PQN std{tag}", **_PQN)
    _line(ax, x, rows["exact_std"], factor, color=colour, label=f"exact std{tag}", **_EXACT)
    _errorbar(ax, x, rows["emp_std"], rows["emp_std_lo"], rows["emp_std_hi"], factor,
              color=colour, label=f"measured std ± CI{tag}", **_MEASURED)


def _worst_panel(ax: Axes, x, rows: pd.DataFrame, factor: float, colour: str, tag: str) -> None:
    """Centre and trajectory worst-case bounds plus measured max |error|."""
    _line(ax, x, rows["worst_case"], factor, color=colour,
          label=f"worst case ½|J(θ₀)|Δ (Table II){tag}", **_WORST)
    _line(ax, x, rows["worst_case_trajectory"], factor, color=colour,
          label=f"worst case over trajectory{tag}", **_WORST_TRAJ)
    _line(ax, x, rows["emp_max_abs"], factor, color=colour, label=f"measured max |error|{tag}",
          **_MAX)


def _ordered_discretizations(values) -> list[str]:
    present = _unique(values)
    known = [name for name in _DISCRETIZATION_PREFERENCE if name in present]
    return known + sorted(name for name in present if name not in known)


def _filter_label(order: int, d: float, n: float, fc_hz: float, discretization: str) -> str:
    return (f"{_ORDER_NAMES[order]}: d={d:g}, n={n:g}, fc={fc_hz:g} Hz"
            + (f", {discretization}" if discretization else ""))


# --------------------------------------------------------------------------------------------
# Fig. 6


_POOLED_KEYS = ("group", "level", "signal", "order", "unit") + _STD_COLUMNS + _WORST_COLUMNS


def fig6_position_error(pooled: pd.DataFrame, level: str | None = None) -> Figure:
    """Operational-space position error per centre configuration (paper Fig. 6 equivalent).

    One panel per operational coordinate (x, y, z, those present). The x axis lists the
    configurations (one tick per group, in the table's order, labelled with ``centre_deg`` in
    degrees, or the group name when it is empty). Each panel shows the PQN and exact std
    (lines), the measured std with its confidence interval (markers), the Table II centre worst
    case and the worst case over the trajectory (lines) and the measured max |error| (crosses).

    Parameters
    ----------
    pooled : pandas.DataFrame
        The pooled batch table (``results/batch/pooled.csv``). Rows with ``order == 0`` and
        ``signal`` in x, y, z are used; position does not depend on the filter architecture, so
        duplicate rows of a group and coordinate keep the first.
    level : str, optional
        Quantization level to show (e.g. ``'1mrad'``); required when the table holds several.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        Missing columns, no operational position rows, or an absent or ambiguous ``level``.

    References
    ----------
    .. [1] Colonnese and Okamura, Fig. 6 and Table II.
    """
    table = _prepare(pooled, "pooled", _POOLED_KEYS + ("centre_deg",))
    rows = table[(table["order"] == 0) & table["signal"].isin(_OPERATIONAL)]
    if rows.empty:
        raise ValueError("pooled has no order-0 rows for the operational coordinates x, y, z")
    rows, level = _select_level(rows, level, "pooled (order 0, x/y/z)")
    rows = rows.drop_duplicates(["group", "signal"], keep="first")

    groups = _unique(rows["group"])
    centres = rows.drop_duplicates("group").set_index("group")["centre_deg"]
    labels = [_configuration_label(centres[group], group) for group in groups]
    signals = [signal for signal in _OPERATIONAL if signal in set(rows["signal"])]
    positions = np.arange(len(groups), dtype=float)

    fig = Figure(figsize=(3.5 + 0.9 * len(groups), 0.8 + 2.7 * len(signals)),
                 layout="constrained")
    axes = fig.subplots(len(signals), 1, sharex=True, squeeze=False)[:, 0]
    for ax, signal in zip(axes, signals):
        per_group = rows[rows["signal"] == signal].set_index("group").reindex(groups)
        shown = per_group[list(_STD_COLUMNS + _WORST_COLUMNS)].to_numpy(dtype=float)
        base = _single_base_unit(per_group.dropna(subset=["unit"]), f"signal {signal!r}")
        factor, unit_label = _display_unit(base, 0, shown)
        _std_panel(ax, positions, per_group, factor, _STD_COLOUR, "")
        _worst_panel(ax, positions, per_group, factor, _WORST_COLOUR, "")
        _apply_yscale(ax, shown)
        ax.set_ylabel(f"{signal} error ({unit_label})")
        ax.set_title(f"{signal}: std and worst case of the position error", fontsize="medium")
        ax.grid(True, alpha=0.3)
    rotate = len(groups) > 5
    axes[-1].set_xticks(positions, labels, rotation=30 if rotate else 0,
                        ha="right" if rotate else "center")
    axes[-1].set_xlabel("centre configuration (joint angles)")
    axes[-1].set_xlim(-0.5, len(groups) - 0.5)
    fig.suptitle(f"Operational-space position error from joint quantization, level {level}")
    _figure_legend(fig, axes)
    return _settled(fig)


# --------------------------------------------------------------------------------------------
# Fig. 7


def fig7_derivative_error(pooled: pd.DataFrame, group: str, signal: str = "x",
                          architecture: str = "operational", *,
                          level: str | None = None) -> Figure:
    """Derivative error against the filter cutoff (paper Fig. 7 equivalent).

    Columns: velocity (order 1) and acceleration (order 2), those present. For each
    discretization (exponential, bilinear, ...) two rows: the std (PQN dashed, exact solid,
    measured markers with CI) and the worst case (Table II bound dash-dotted, trajectory bound
    dotted, measured max |error| crosses). One colour per filter order ``n``. The x axis is the
    cutoff ``fc_hz`` on a log scale; panels of one column and row kind share their y axis so
    the discretizations compare directly.

    Parameters
    ----------
    pooled : pandas.DataFrame
        The pooled batch table (``results/batch/pooled.csv``).
    group : str
        Repeat group to show (e.g. the zero configuration).
    signal : str, default 'x'
        Coordinate whose derivative error is shown.
    architecture : str, default 'operational'
        Where the filter is applied: ``'operational'`` or ``'joint'`` (paper Fig. 2).
    level : str, optional
        Quantization level; required when the group holds several.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        Missing columns, or no derivative rows for ``group``/``signal``/``architecture``/
        ``level`` (the message lists what is available).

    References
    ----------
    .. [1] Colonnese and Okamura, Figs. 5 and 7, Table II.
    """
    table = _prepare(pooled, "pooled",
                     _POOLED_KEYS + ("d", "n", "fc_hz", "discretization", "architecture"))
    rows = table[table["order"].isin([1, 2])]
    for column, value in (("group", group), ("signal", signal), ("architecture", architecture)):
        available = _unique(rows[column])
        if value not in available:
            raise ValueError(f"{column}={value!r} has no derivative rows in pooled; "
                             f"available: {available}")
        rows = rows[rows[column] == value]
    rows, level = _select_level(rows, level, f"group {group!r}, signal {signal!r}")

    orders = [order for order in (1, 2) if order in set(rows["order"])]
    discretizations = _ordered_discretizations(rows["discretization"])
    filter_orders = sorted(_unique(rows["n"].dropna()))
    colours = {n: _PALETTE[i % len(_PALETTE)] for i, n in enumerate(filter_orders)}

    fig = Figure(figsize=(4.6 * len(orders) + 2.2, 2.6 * 2 * len(discretizations) + 0.8),
                 layout="constrained")
    axes = fig.subplots(2 * len(discretizations), len(orders), sharex=True, squeeze=False)
    for column, order in enumerate(orders):
        in_order = rows[rows["order"] == order]
        base = _single_base_unit(in_order, f"{_ORDER_NAMES[order]} rows")
        std_values = in_order[list(_STD_COLUMNS)].to_numpy(dtype=float)
        worst_values = in_order[list(_WORST_COLUMNS)].to_numpy(dtype=float)
        std_factor, std_unit = _display_unit(base, order, std_values)
        worst_factor, worst_unit = _display_unit(base, order, worst_values)
        name = _ORDER_NAMES[order]
        for r, discretization in enumerate(discretizations):
            ax_std, ax_worst = axes[2 * r, column], axes[2 * r + 1, column]
            if r:
                ax_std.sharey(axes[0, column])
                ax_worst.sharey(axes[1, column])
            subset = in_order[in_order["discretization"] == discretization]
            for n in filter_orders:
                curve = subset[subset["n"] == n].sort_values("fc_hz")
                if curve.empty:
                    continue
                fc = curve["fc_hz"].to_numpy()
                tag = f", n={n:g}"
                _std_panel(ax_std, fc, curve, std_factor, colours[n], tag)
                _worst_panel(ax_worst, fc, curve, worst_factor, colours[n], tag)
            ax_std.set_title(f"{signal} {name} error std, {discretization or 'no'} "
                             "discretization", fontsize="medium")
            ax_worst.set_title(f"{signal} {name} error worst case, {discretization or 'no'} "
                               "discretization", fontsize="medium")
            ax_std.set_ylabel(f"std ({std_unit})")
            ax_worst.set_ylabel(f"|error| ({worst_unit})")
            for ax in (ax_std, ax_worst):
                _log_x_axis(ax, rows["fc_hz"])
                ax.grid(True, which="both", alpha=0.3)
        _apply_yscale(axes[0, column], std_values)
        _apply_yscale(axes[1, column], worst_values)
        axes[-1, column].set_xlabel("low-pass cutoff fc (Hz)")
    fig.suptitle(f"{signal} derivative error from joint quantization vs filter cutoff: "
                 f"group {group}, level {level}, {architecture}-space filter")
    _style_legend(
        fig,
        [(f"filter order n = {n:g}", colours[n]) for n in filter_orders],
        [("PQN std", _PQN), ("exact std", _EXACT), ("measured std ± CI", _MEASURED),
         ("worst case (Table II)", _WORST), ("worst case over trajectory", _WORST_TRAJ),
         ("measured max |error|", _MAX)],
    )
    return _settled(fig)


# --------------------------------------------------------------------------------------------
# ratios


def _ratio_points(ax: Axes, x, rows: pd.DataFrame, kind: str, **style) -> None:
    _errorbar(ax, x, rows[f"ratio_{kind}"], rows[f"ratio_{kind}_lo"], rows[f"ratio_{kind}_hi"],
              1.0, linestyle="none", capsize=2, elinewidth=0.9, **style)


def _tolerance_band(ax: Axes, tolerance: float | None) -> None:
    ax.axhline(1.0, color="0.3", linewidth=0.8)
    if tolerance is not None:
        ax.axhspan(1.0 - tolerance, 1.0 + tolerance, color="tab:green", alpha=0.18,
                   label=f"±{100 * tolerance:g} % tolerance")


def _check_tolerance(value, argument: str) -> None:
    if value is not None and not (np.isfinite(value) and 0 < value < 1):
        raise ValueError(f"{argument}={value!r} must be a fraction in (0, 1) or None")


def ratio_figure(pooled: pd.DataFrame, *, position_pqn_tol: float | None = 0.015,
                 position_exact_tol: float | None = 0.005,
                 derivative_pqn_tol: float | None = None,
                 derivative_exact_tol: float | None = 0.01) -> Figure:
    """Measured / theory std ratios with confidence intervals for every pooled row.

    Left column: measured / PQN, right column: measured / exact. Rows: position (x axis = the
    configuration, i.e. the group, with its level when a group has several; one colour per
    signal, dodged sideways), velocity and acceleration (x axis = cutoff fc on a log scale, one
    colour per filter order n, marker per discretization, filled for operational-space and hollow
    for joint-space filters; all groups and signals overlaid). A shaded band shows the tolerance
    within which the theory is considered to hold; the line at 1 is perfect agreement.

    Parameters
    ----------
    pooled : pandas.DataFrame
        The pooled batch table with the ``ratio_*`` columns.
    position_pqn_tol, position_exact_tol : float or None
        Half-widths of the position bands (fractions; default ±1.5 % vs PQN, ±0.5 % vs exact).
    derivative_pqn_tol, derivative_exact_tol : float or None
        Half-widths of the derivative bands (default none vs PQN, which is known to miss the
        derivative noise by several percent, and ±1 % vs exact). ``None`` draws no band.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        Missing columns, an empty table, or a tolerance outside (0, 1).
    """
    for value, argument in ((position_pqn_tol, "position_pqn_tol"),
                            (position_exact_tol, "position_exact_tol"),
                            (derivative_pqn_tol, "derivative_pqn_tol"),
                            (derivative_exact_tol, "derivative_exact_tol")):
        _check_tolerance(value, argument)
    ratio_columns = tuple(f"ratio_{kind}{end}" for kind in ("pqn", "exact")
                          for end in ("", "_lo", "_hi"))
    table = _prepare(pooled, "pooled", ("group", "level", "signal", "order", "n", "fc_hz",
                                        "discretization", "architecture", "centre_deg")
                     + ratio_columns)
    orders = [order for order in (0, 1, 2) if order in set(table["order"])]
    if not orders:
        raise ValueError("pooled has no rows of order 0, 1 or 2")
    tolerances = {0: {"pqn": position_pqn_tol, "exact": position_exact_tol},
                  1: {"pqn": derivative_pqn_tol, "exact": derivative_exact_tol},
                  2: {"pqn": derivative_pqn_tol, "exact": derivative_exact_tol}}
    titles = {"pqn": "measured / PQN std", "exact": "measured / exact std"}

    n_groups = len(_unique(table.loc[table["order"] == 0, ["group", "level"]]
                           .itertuples(index=False)))
    fig = Figure(figsize=(max(11.0, 4.0 + 1.2 * n_groups), 0.8 + 3.0 * len(orders)),
                 layout="constrained")
    axes = fig.subplots(len(orders), 2, squeeze=False)
    for row, order in enumerate(orders):
        rows = table[table["order"] == order]
        for column, kind in enumerate(("pqn", "exact")):
            ax = axes[row, column]
            _tolerance_band(ax, tolerances[order][kind])
            if order == 0:
                _position_ratios(ax, rows, kind)
            else:
                _derivative_ratios(ax, rows, kind)
            ax.set_title(f"{_ORDER_NAMES[order]}: {titles[kind]}", fontsize="medium")
            ax.set_ylabel(f"{titles[kind]} (ratio)")
            ax.grid(True, which="both", alpha=0.3)
        if axes[row, 1].get_legend_handles_labels()[0]:
            axes[row, 1].legend(fontsize="x-small", loc="center left",
                                bbox_to_anchor=(1.02, 0.5))
    fig.suptitle("Where theory holds: measured quantization-error std over predicted std "
                 "(bars: confidence intervals)")
    return _settled(fig)


def _position_ratios(ax: Axes, rows: pd.DataFrame, kind: str) -> None:
    rows = rows.drop_duplicates(["group", "level", "signal"], keep="first")
    categories = _unique(rows[["group", "level"]].itertuples(index=False, name=None))
    levels_per_group = rows.groupby("group", sort=False)["level"].nunique()
    centres = rows.drop_duplicates("group").set_index("group")["centre_deg"]
    labels = [_configuration_label(centres[group], group)
              + (f"\n{level}" if levels_per_group[group] > 1 else "")
              for group, level in categories]
    where = {category: i for i, category in enumerate(categories)}
    signals = _unique(rows["signal"])
    width = 0.6 / max(len(signals), 1)
    for i, signal in enumerate(signals):
        subset = rows[rows["signal"] == signal]
        offset = (i - (len(signals) - 1) / 2) * width
        x = np.array([where[(g, lv)] for g, lv in zip(subset["group"], subset["level"])],
                     dtype=float) + offset
        _ratio_points(ax, x, subset, kind, marker="o", markersize=4,
                      color=_PALETTE[i % len(_PALETTE)], label=f"{signal}")
    rotate = len(categories) > 5
    ax.set_xticks(np.arange(len(categories)), labels, rotation=30 if rotate else 0,
                  ha="right" if rotate else "center", fontsize="small")
    ax.set_xlim(-0.5, len(categories) - 0.5)
    ax.set_xlabel("configuration")


def _derivative_ratios(ax: Axes, rows: pd.DataFrame, kind: str) -> None:
    filter_orders = sorted(_unique(rows["n"].dropna()))
    discretizations = _ordered_discretizations(rows["discretization"])
    markers = ("o", "s", "^", "D", "v")
    # Points of different n share the cutoff; a small multiplicative dodge keeps them apart.
    dodge = {n: 10 ** (0.015 * (i - (len(filter_orders) - 1) / 2))
             for i, n in enumerate(filter_orders)}
    for i, n in enumerate(filter_orders):
        colour = _PALETTE[i % len(_PALETTE)]
        for j, discretization in enumerate(discretizations):
            for architecture in _unique(rows["architecture"]):
                subset = rows[(rows["n"] == n) & (rows["discretization"] == discretization)
                              & (rows["architecture"] == architecture)]
                if subset.empty:
                    continue
                hollow = architecture == "joint"
                _ratio_points(ax, subset["fc_hz"].to_numpy() * dodge[n], subset, kind,
                              marker=markers[j % len(markers)], markersize=4, color=colour,
                              markerfacecolor="white" if hollow else colour,
                              label=f"n={n:g}, {discretization or 'no discretization'}, "
                                    f"{architecture or 'no'} filter")
    # Dodged points sit next to the cutoff they belong to: tick the cutoffs themselves.
    _log_x_axis(ax, rows["fc_hz"])
    ax.set_xlabel("low-pass cutoff fc (Hz)")


# --------------------------------------------------------------------------------------------
# real logs


def _step_axis(levels: Sequence[str], native_step: float | None,
               step_unit: str) -> tuple[dict[str, float], float, str]:
    """Map each level to a step for the x axis; return (steps in SI, display factor, label)."""
    multiples = [_LEVEL_MULTIPLE.match(level) for level in levels]
    explicit = [_LEVEL_STEP.match(level) for level in levels]
    if all(multiples):
        values = {level: float(m.group(1)) for level, m in zip(levels, multiples)}
        if native_step is None:
            return values, 1.0, "re-quantization step (multiples of the native step)"
        base, _ = _parse_unit(step_unit, "step_unit")
        steps = {level: value * native_step for level, value in values.items()}
        factor, unit = _display_unit(base, 0, list(steps.values()))
        return steps, factor, f"quantization step Δ ({unit})"
    if all(explicit):
        steps = {level: float(m.group(1)) * _STEP_PREFIX[m.group(2)]
                 for level, m in zip(levels, explicit)}
        bases = _unique(m.group(3) for m in explicit)
        if len(bases) != 1:
            raise ValueError(f"levels {list(levels)} mix step units {bases}")
        factor, unit = _display_unit(bases[0], 0, list(steps.values()))
        return steps, factor, f"quantization step Δ ({unit})"
    raise ValueError(f"levels {list(levels)} must all be multiples like '8x' or all steps "
                     "like '1mrad' / '10um'")


def _default_filters(rows: pd.DataFrame, fc_hz: float) -> list[dict]:
    """Per derivative order: cutoff nearest ``fc_hz`` (log distance), lowest n, preferred
    discretization."""
    chosen = []
    for order in (1, 2):
        candidates = rows[(rows["order"] == order) & np.isfinite(rows["fc_hz"])]
        if candidates.empty:
            continue
        distance = np.abs(np.log(candidates["fc_hz"].to_numpy() / fc_hz))
        candidates = candidates[np.isclose(distance, distance.min())]
        candidates = candidates[candidates["n"] == candidates["n"].min()]
        discretization = _ordered_discretizations(candidates["discretization"])[0]
        first = candidates[candidates["discretization"] == discretization].iloc[0]
        chosen.append({"order": order, "d": first["d"], "n": first["n"],
                       "fc_hz": first["fc_hz"], "discretization": discretization})
    return chosen


def _architecture_for(signal: str, available: Sequence[str]) -> str | None:
    """Operational coordinates prefer the operational-space filter, joints the joint one."""
    preference = ("operational", "", "joint") if signal in _OPERATIONAL else ("joint", "",
                                                                              "operational")
    for name in preference:
        if name in available:
            return name
    return available[0] if available else None


def real_log_figure(table_for_one_log: pd.DataFrame, title: str, *,
                    signals: Sequence[str] | None = None,
                    filters: Sequence[Mapping] | None = None, fc_hz: float = 50.0,
                    native_step: float | None = None, step_unit: str = "rad") -> Figure:
    """Measured error of one real log re-quantized at several steps, against theory (log-log).

    Columns: position, then one column per derivative filter. Top row: std (PQN dashed, exact
    solid, measured markers with CI); bottom row: worst case (Table II bound dash-dotted,
    trajectory bound dotted, measured max |error| crosses). The x axis is the re-quantization
    step; one colour per signal.

    Parameters
    ----------
    table_for_one_log : pandas.DataFrame
        Rows of ``results/batch/quantization.csv`` for one log (one ``log_id``).
    title : str
        Figure title (e.g. the log id and its sensor).
    signals : sequence of str, optional
        Signals to show; they must share one unit. Default: the signals whose unit is that of
        the first signal in the table (e.g. all joint angles, not x/y/z, of an arm).
    filters : sequence of mapping, optional
        Derivative filters, each with keys ``order`` (1 or 2), ``n``, ``fc_hz`` and optionally
        ``d``, ``discretization``. Default: for each derivative order, the cutoff nearest
        ``fc_hz``, the lowest ``n`` and the exponential discretization when present. The filter
        architecture is chosen per signal: operational-space for x, y, z, joint-space otherwise.
    fc_hz : float, default 50
        Preferred cutoff for the default filters.
    native_step : float, optional
        Native step (SI, ``step_unit``) of the log; with levels such as ``'8x'`` it puts the x
        axis in physical units instead of multiples of the native step.
    step_unit : str, default 'rad'
        Unit of ``native_step`` (``'rad'`` or ``'m'``).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        Several log ids, unknown signals or filters, mixed units, unparseable levels, or bad
        ``fc_hz`` / ``native_step``.
    """
    if not np.isfinite(fc_hz) or fc_hz <= 0:
        raise ValueError(f"fc_hz={fc_hz!r} must be a positive finite frequency")
    if native_step is not None and not (np.isfinite(native_step) and native_step > 0):
        raise ValueError(f"native_step={native_step!r} must be a positive finite step")
    table = _prepare(table_for_one_log, "table_for_one_log",
                     ("level", "signal", "order", "d", "n", "fc_hz", "discretization",
                      "architecture", "unit") + _STD_COLUMNS + _WORST_COLUMNS)
    if table.empty:
        raise ValueError("table_for_one_log is empty")
    if "log_id" in table.columns and len(_unique(table["log_id"])) > 1:
        raise ValueError(f"table_for_one_log holds several logs {_unique(table['log_id'])}")

    positions = table[table["order"] == 0]
    available = _unique((positions if not positions.empty else table)["signal"])
    base_of = {signal: _parse_unit(table.loc[table["signal"] == signal, "unit"].iloc[0])[0]
               for signal in _unique(table["signal"])}
    if signals is None:
        signals = [s for s in available if base_of[s] == base_of[available[0]]]
    else:
        signals = list(signals)
        unknown = [s for s in signals if s not in base_of]
        if not signals or unknown:
            raise ValueError(f"signals={signals!r}: unknown {unknown}; available: "
                             f"{_unique(table['signal'])}")
        if len(_unique(base_of[s] for s in signals)) != 1:
            raise ValueError(f"signals={signals!r} mix units; pass signals of one kind")
    table = table[table["signal"].isin(signals)]

    filters = _default_filters(table, fc_hz) if filters is None else _checked_filters(filters)
    columns: list[tuple[str, int, pd.DataFrame]] = [("position", 0,
                                                     table[table["order"] == 0])]
    for spec in filters:
        match = ((table["order"] == spec["order"]) & np.isclose(table["n"], spec["n"])
                 & np.isclose(table["fc_hz"], spec["fc_hz"]))
        if spec.get("d") is not None:
            match &= np.isclose(table["d"], spec["d"])
        if spec.get("discretization") is not None:
            match &= table["discretization"] == spec["discretization"]
        selected = table[match]
        if selected.empty:
            raise ValueError(f"filters: no rows for {dict(spec)} and signals {signals}")
        keep = [architecture == _architecture_for(signal, _unique(
                    selected.loc[selected["signal"] == signal, "architecture"]))
                for signal, architecture in zip(selected["signal"], selected["architecture"])]
        selected = selected[keep]
        first = selected.iloc[0]
        columns.append((_filter_label(int(spec["order"]), first["d"], first["n"],
                                      first["fc_hz"], first["discretization"]),
                        int(spec["order"]), selected))

    steps, step_factor, step_label = _step_axis(_unique(table["level"]), native_step,
                                                step_unit)
    colours = {signal: _PALETTE[i % len(_PALETTE)] for i, signal in enumerate(signals)}
    fig = Figure(figsize=(4.3 * len(columns) + 1.8, 6.6), layout="constrained")
    axes = fig.subplots(2, len(columns), sharex=True, squeeze=False)
    for column, (label, order, rows) in enumerate(columns):
        ax_std, ax_worst = axes[0, column], axes[1, column]
        base = base_of[signals[0]]
        std_values = rows[list(_STD_COLUMNS)].to_numpy(dtype=float)
        worst_values = rows[list(_WORST_COLUMNS)].to_numpy(dtype=float)
        std_factor, std_unit = _display_unit(base, order, std_values)
        worst_factor, worst_unit = _display_unit(base, order, worst_values)
        for signal in signals:
            curve = rows[rows["signal"] == signal].copy()
            if curve.empty:
                continue
            curve["step"] = curve["level"].map(steps) / step_factor
            curve = curve.sort_values("step")
            tag = f", {signal}" if len(signals) > 1 else ""
            _std_panel(ax_std, curve["step"].to_numpy(), curve, std_factor, colours[signal],
                       tag)
            _worst_panel(ax_worst, curve["step"].to_numpy(), curve, worst_factor,
                         colours[signal], tag)
        ax_std.set_title(f"{label}: std", fontsize="medium")
        ax_worst.set_title(f"{label}: worst case", fontsize="medium")
        ax_std.set_ylabel(f"{_ORDER_NAMES[order]} error std ({std_unit})")
        ax_worst.set_ylabel(f"|{_ORDER_NAMES[order]} error| ({worst_unit})")
        for ax in (ax_std, ax_worst):
            _log_x_axis(ax, np.array(list(steps.values())) / step_factor)
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
        ax_worst.set_xlabel(step_label)
    fig.suptitle(title)
    if len(signals) > 1:
        _style_legend(fig, [(signal, colours[signal]) for signal in signals],
                      [("PQN std", _PQN), ("exact std", _EXACT),
                       ("measured std ± CI", _MEASURED), ("worst case (Table II)", _WORST),
                       ("worst case over trajectory", _WORST_TRAJ),
                       ("measured max |error|", _MAX)])
    else:
        _figure_legend(fig, axes.ravel())
    return _settled(fig)


def _checked_filters(filters: Sequence[Mapping]) -> list[Mapping]:
    checked = []
    for spec in filters:
        if not isinstance(spec, Mapping):
            raise ValueError(f"filters: entry {spec!r} is not a mapping")
        missing = [key for key in ("order", "n", "fc_hz") if key not in spec]
        extra = sorted(set(spec) - {"order", "d", "n", "fc_hz", "discretization"})
        if missing or extra:
            raise ValueError(f"filters: entry {dict(spec)} lacks {missing} / has unknown keys "
                             f"{extra}")
        if spec["order"] not in (1, 2):
            raise ValueError(f"filters: entry {dict(spec)} has order {spec['order']!r}, "
                             "expected 1 or 2")
        checked.append(spec)
    return checked


# --------------------------------------------------------------------------------------------
# time traces


_TRACE_ORDERS = {"position": 0, "velocity": 1, "acceleration": 2}


def error_trace_figure(t, errors: Mapping[str, np.ndarray], title: str, unit: str, *,
                       step: float | None = None, window_s: float = 0.5,
                       bins: int = 60) -> Figure:
    """Time traces and histograms of the quantization error of one log.

    One row per entry of ``errors`` (position, velocity, acceleration order): the first
    ``window_s`` seconds of the error on the left, the histogram of the whole record on the
    right (sharing the error axis). For position and a given ``step``, the histogram is
    compared with the uniform density 1/Δ on [-Δ/2, Δ/2] of a rounding quantizer, and the
    trace shows the ±Δ/2 bounds.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps in seconds.
    errors : mapping of str to array_like, shape (N,)
        Error (measured - true) keyed by ``'position'``, ``'velocity'``, ``'acceleration'``
        (any non-empty subset), in SI units; NaN samples (e.g. filter start-up) are ignored.
    title : str
        Figure title (e.g. log id, signal, filter).
    unit : str
        SI unit of the position (``'rad'`` or ``'m'``); derivatives add /s and /s².
    step : float, optional
        Quantization step Δ of the position, in ``unit``.
    window_s : float, default 0.5
        Length of the time window shown, from the first sample.
    bins : int, default 60
        Number of histogram bins.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        Unknown keys, lengths that differ from ``t``, or bad ``unit``, ``step``, ``window_s``
        or ``bins``.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0 or not np.isfinite(t).all():
        raise ValueError(f"t must be a non-empty 1-D array of finite times, got shape {t.shape}")
    if not isinstance(errors, Mapping) or not errors:
        raise ValueError("errors must be a non-empty mapping of 'position', 'velocity', "
                         "'acceleration' to arrays")
    unknown = sorted(set(errors) - set(_TRACE_ORDERS))
    if unknown:
        raise ValueError(f"errors has unknown key(s) {unknown}; use {list(_TRACE_ORDERS)}")
    base, unit_order = _parse_unit(unit)
    if unit_order != 0:
        raise ValueError(f"unit={unit!r} must be the position unit 'rad' or 'm'")
    if step is not None and not (np.isfinite(step) and step > 0):
        raise ValueError(f"step={step!r} must be a positive finite step")
    if not (np.isfinite(window_s) and window_s > 0):
        raise ValueError(f"window_s={window_s!r} must be a positive duration in seconds")
    if int(bins) != bins or bins < 1:
        raise ValueError(f"bins={bins!r} must be a positive integer")
    series = {}
    for name in sorted(errors, key=_TRACE_ORDERS.get):
        values = np.asarray(errors[name], dtype=float)
        if values.shape != t.shape:
            raise ValueError(f"errors[{name!r}] has shape {values.shape}, t has {t.shape}")
        series[name] = values

    window = (t - t[0]) <= window_s
    fig = Figure(figsize=(10.0, 0.8 + 2.4 * len(series)), layout="constrained")
    axes = fig.subplots(len(series), 2, squeeze=False, width_ratios=(3, 1))
    for (name, values), (ax_trace, ax_hist) in zip(series.items(), axes):
        order = _TRACE_ORDERS[name]
        finite = values[np.isfinite(values)]
        reference = finite if finite.size else np.zeros(1)
        if order == 0 and step is not None:
            reference = np.append(reference, step / 2)
        factor, unit_label = _display_unit(base, order, reference)
        ax_trace.plot(t[window] - t[0], values[window] / factor, color=_STD_COLOUR,
                      linewidth=0.8, label=f"{name} error")
        ax_hist.sharey(ax_trace)
        if finite.size:
            ax_hist.hist(finite / factor, bins=int(bins), density=True, orientation="horizontal",
                         color=_STD_COLOUR, alpha=0.6, label="measured")
            summary = f"mean {finite.mean() / factor:.3g}, std {finite.std() / factor:.3g}"
        else:
            summary = "no finite samples"
        if order == 0 and step is not None:
            half = step / 2 / factor
            for ax in (ax_trace, ax_hist):
                ax.axhline(half, color=_WORST_COLOUR, linestyle=":", linewidth=1.2)
                ax.axhline(-half, color=_WORST_COLOUR, linestyle=":", linewidth=1.2)
            ax_hist.plot([1 / (2 * half)] * 2, [-half, half], color=_WORST_COLOUR,
                         linewidth=1.8, label="uniform ±Δ/2")
            ax_hist.legend(fontsize="x-small", loc="upper right")
        ax_trace.set_ylabel(f"{name} error ({unit_label})")
        ax_trace.set_title(f"{name} error: {summary} {unit_label}", fontsize="medium")
        ax_hist.set_xlabel(f"density (1/{unit_label})")
        ax_hist.tick_params(labelleft=False)
        for ax in (ax_trace, ax_hist):
            ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("time since log start (s)")
    fig.suptitle(title)
    return _settled(fig)
