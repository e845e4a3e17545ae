"""Tests for enclab.propagation.batch: pooling of repeat runs, ratio summaries and bound violations."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.stats
from enclab.propagation import batch

T_975_DF2 = 4.302652729911275  # Student t 97.5 % quantile, 2 degrees of freedom (tables)


def _row(log_id: str, group, *, signal: str = "x", order: int = 0, emp_std: float = 1.0,
         pqn_std: float = 1.0, exact_std: float = 1.0, level: str = "1mrad", **extra) -> dict:
    """A batch-table row; position rows have no filter (NaN keys, architecture 'none')."""
    if order == 0:
        filter_keys = dict(d=np.nan, n=np.nan, fc_hz=np.nan, discretization="",
                           architecture="none")
        unit = "m"
    else:
        filter_keys = dict(d=order, n=2, fc_hz=50.0, discretization="exponential",
                           architecture="operational")
        unit = "m/s" if order == 1 else "m/s^2"
    row = dict(log_id=log_id, group=group, tags="", device="phantom_premium_1_5", level=level,
               step=1e-3, centre_deg="0,0,0", signal=signal, order=order, **filter_keys,
               emp_mean=0.0, emp_std=emp_std, emp_std_lo=0.9 * emp_std, emp_std_hi=1.1 * emp_std,
               emp_max_abs=2.0 * emp_std, n_samples=15000, pqn_std=pqn_std, exact_std=exact_std,
               exact_mean=0.0, worst_case=3.0 * emp_std, worst_case_trajectory=3.5 * emp_std,
               unit=unit)
    row.update(extra)
    return row


def _group_table(emp_stds, *, group="g", **common) -> pd.DataFrame:
    return pd.DataFrame([_row(f"{group}_run{r}", group, emp_std=s, **common)
                         for r, s in enumerate(emp_stds)])


# --------------------------------------------------------------------------- pool_runs


def test_known_variances_give_known_ratios_and_intervals():
    # Runs with std sqrt(3), 2, sqrt(5) and exact std 1: variance ratios 3, 4, 5, mean 4,
    # standard error std([3, 4, 5]) / sqrt(3) = 1 / sqrt(3); 95 % t-interval 4 -+ t * se.
    table = _group_table(np.sqrt([3.0, 4.0, 5.0]), pqn_std=2.0, exact_std=1.0)
    (pooled,) = batch.pool_runs(table).to_dict("records")
    half = T_975_DF2 / np.sqrt(3.0)
    assert pooled["n_runs"] == 3
    assert pooled["ratio_exact"] == pytest.approx(2.0)
    assert pooled["ratio_exact_lo"] == pytest.approx(np.sqrt(4.0 - half))
    assert pooled["ratio_exact_hi"] == pytest.approx(np.sqrt(4.0 + half))
    # PQN std 2: every variance ratio is a quarter, the ratio and its ends halve.
    assert pooled["ratio_pqn"] == pytest.approx(1.0)
    assert pooled["ratio_pqn_lo"] == pytest.approx(np.sqrt(4.0 - half) / 2)
    assert pooled["ratio_pqn_hi"] == pytest.approx(np.sqrt(4.0 + half) / 2)
    # The pooled std is the rms of the run stds, with the same interval (model std 1).
    assert pooled["emp_std"] == pytest.approx(2.0)
    assert pooled["emp_std_lo"] == pytest.approx(np.sqrt(4.0 - half))
    assert pooled["emp_std_hi"] == pytest.approx(np.sqrt(4.0 + half))
    # Bounds and peaks pool as maxima: 3.5 * sqrt(5) is the largest trajectory bound.
    assert pooled["worst_case_trajectory"] == pytest.approx(3.5 * np.sqrt(5.0))
    assert pooled["emp_max_abs"] == pytest.approx(2.0 * np.sqrt(5.0))
    assert (pooled["centre_deg"], pooled["unit"], pooled["device"]) == (
        "0,0,0", "m", "phantom_premium_1_5")


def test_lower_end_is_clipped_at_zero_and_model_stds_pool_as_rms():
    # Variance ratios 1, 4, 9: mean 14/3, standard error exactly 7/3, and 14/3 - t * 7/3 < 0.
    table = _group_table([1.0, 2.0, 3.0])
    table["pqn_std"] = [1.0, 1.0, 1.0]
    table["exact_std"] = [1.0, 1.0, 1.0]
    (pooled,) = batch.pool_runs(table).to_dict("records")
    assert pooled["ratio_exact"] == pytest.approx(np.sqrt(14 / 3))
    assert pooled["ratio_exact_lo"] == 0.0
    assert pooled["ratio_exact_hi"] == pytest.approx(np.sqrt(14 / 3 + T_975_DF2 * 7 / 3))
    # Different model stds per run: each run is divided by its own model, and the reported
    # model std is the rms over runs.
    table["exact_std"] = [1.0, 2.0, 3.0]
    (pooled,) = batch.pool_runs(table).to_dict("records")
    assert pooled["ratio_exact"] == pytest.approx(1.0)
    assert pooled["ratio_exact_lo"] == pytest.approx(1.0) == pooled["ratio_exact_hi"]
    assert pooled["exact_std"] == pytest.approx(np.sqrt(14 / 3))


def test_ci_level_sets_the_t_quantile():
    table = _group_table(np.sqrt([3.0, 4.0, 5.0, 6.0]))
    (pooled,) = batch.pool_runs(table, ci_level=0.8).to_dict("records")
    # Mean 4.5, std(ddof=1) sqrt(5/3), four runs: 3 degrees of freedom.
    half = scipy.stats.t.ppf(0.9, 3) * np.sqrt(5 / 3) / 2
    assert pooled["ratio_exact_lo"] == pytest.approx(np.sqrt(4.5 - half))
    assert pooled["ratio_exact_hi"] == pytest.approx(np.sqrt(4.5 + half))


def test_single_run_uses_its_own_interval():
    table = pd.DataFrame([_row("solo", None, emp_std=2.0, pqn_std=4.0, exact_std=2.5)])
    (pooled,) = batch.pool_runs(table).to_dict("records")
    assert pooled["group"] == "solo"  # no group: the log is its own group
    assert pooled["n_runs"] == 1
    assert (pooled["emp_std"], pooled["emp_std_lo"], pooled["emp_std_hi"]) == pytest.approx(
        (2.0, 1.8, 2.2))
    assert (pooled["ratio_pqn"], pooled["ratio_pqn_lo"], pooled["ratio_pqn_hi"]) == (
        pytest.approx((0.5, 0.45, 0.55)))
    assert (pooled["ratio_exact"], pooled["ratio_exact_lo"], pooled["ratio_exact_hi"]) == (
        pytest.approx((0.8, 0.72, 0.88)))


def test_nan_filter_keys_pool_together_and_groups_stay_apart():
    rows = [
        # Two runs of group A: positions (NaN d, n, fc_hz) and one velocity filter.
        _row("a1", "A", emp_std=1.0), _row("a2", "A", emp_std=3.0),
        _row("a1", "A", order=1, emp_std=10.0), _row("a2", "A", order=1, emp_std=10.0),
        # Logs without a group are each their own group, even with the same configuration.
        _row("b", np.nan, emp_std=5.0), _row("c", "", emp_std=7.0),
        # Another level of group A is another pooled row.
        _row("a1", "A", emp_std=2.0, level="2mrad"),
    ]
    table = pd.DataFrame(rows)
    # A CSV round trip turns the empty discretization of positions into NaN: same key.
    table.loc[1, "discretization"] = np.nan
    pooled = batch.pool_runs(table)
    assert list(zip(pooled["group"], pooled["level"], pooled["order"], pooled["n_runs"])) == [
        ("A", "1mrad", 0, 2), ("A", "1mrad", 1, 2), ("b", "1mrad", 0, 1), ("c", "1mrad", 0, 1),
        ("A", "2mrad", 0, 1)]
    assert pooled.loc[0, "emp_std"] == pytest.approx(np.sqrt(5.0))  # rms of 1 and 3
    assert pooled.loc[0, ["d", "n", "fc_hz"]].isna().all()
    assert pooled.loc[1, ["d", "n", "fc_hz"]].tolist() == [1.0, 2.0, 50.0]
    # Identical runs: zero spread, so the interval collapses onto the ratio.
    assert pooled.loc[1, ["ratio_exact", "ratio_exact_lo", "ratio_exact_hi"]].tolist() == (
        pytest.approx([10.0, 10.0, 10.0]))
    for column in ("group", "level", "signal", "order", "d", "n", "fc_hz", "discretization",
                   "architecture", "centre_deg", "unit", "device", "n_runs", "emp_std",
                   "emp_std_lo", "emp_std_hi", "pqn_std", "exact_std", "worst_case",
                   "worst_case_trajectory", "emp_max_abs", "ratio_pqn", "ratio_pqn_lo",
                   "ratio_pqn_hi", "ratio_exact", "ratio_exact_lo", "ratio_exact_hi"):
        assert column in pooled.columns


def test_missing_theory_in_one_run_gives_nan_not_a_partial_pool():
    table = _group_table([1.0, 2.0, 3.0])
    table.loc[1, ["pqn_std", "worst_case_trajectory"]] = np.nan
    table.loc[2, "exact_std"] = 0.0  # no model variance: the ratio is undefined
    (pooled,) = batch.pool_runs(table).to_dict("records")
    for column in ("pqn_std", "ratio_pqn", "ratio_pqn_lo", "ratio_pqn_hi",
                   "worst_case_trajectory", "ratio_exact", "ratio_exact_lo", "ratio_exact_hi"):
        assert np.isnan(pooled[column]), column
    assert pooled["emp_std"] == pytest.approx(np.sqrt(14 / 3))
    assert pooled["worst_case"] == pytest.approx(9.0)


def test_pool_runs_argument_checks():
    table = _group_table([1.0, 2.0])
    with pytest.raises(ValueError, match="ci_level=1.5"):
        batch.pool_runs(table, ci_level=1.5)
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['exact_std'\]"):
        batch.pool_runs(table.drop(columns="exact_std"))
    with pytest.raises(ValueError, match="repeat a log"):
        batch.pool_runs(pd.concat([table, table.iloc[:1]], ignore_index=True))
    with pytest.raises(ValueError, match="different units"):
        batch.pool_runs(table.assign(unit=["m", "rad"]))
    with pytest.raises(ValueError, match="order must be 0, 1 or 2, got 3"):
        batch.pool_runs(table.assign(order=[0, 3]))
    with pytest.raises(TypeError, match="DataFrame"):
        batch.pool_runs(table.to_dict("records"))


def test_ratio_interval_covers_one_at_nominal_rate():
    # Runs drawn from N(0, sigma): each run's std from M samples, R runs per group, G groups.
    # With sigma as the exact model the true variance ratio is 1, so each group's interval
    # should contain 1 with probability ci_level. G independent groups: the observed coverage
    # has binomial standard error sqrt(p (1 - p) / G) = 0.0049 for p = 0.95, G = 2000; four of
    # them (0.02) make a false failure negligible (p < 1e-4). M = 200 samples keep the run
    # variances close to normal (chi-square skewness sqrt(8 / 199) = 0.2), where the t
    # interval is exact to well within that tolerance.
    rng = np.random.default_rng(20251122)
    groups, runs, samples, sigma = 2000, 5, 200, 3e-5
    stds = rng.normal(0.0, sigma, size=(groups, runs, samples)).std(axis=2, ddof=1)
    table = pd.DataFrame([
        _row(f"g{g}_r{r}", f"g{g}", emp_std=stds[g, r], pqn_std=sigma, exact_std=sigma)
        for g in range(groups) for r in range(runs)])
    for ci_level in (0.95, 0.8):
        pooled = batch.pool_runs(table, ci_level=ci_level)
        assert len(pooled) == groups and (pooled["n_runs"] == runs).all()
        covered = (pooled["ratio_exact_lo"] <= 1.0) & (1.0 <= pooled["ratio_exact_hi"])
        tolerance = 4 * np.sqrt(ci_level * (1 - ci_level) / groups)
        assert abs(covered.mean() - ci_level) < tolerance
        # The std interval is the same construction on sigma itself.
        covered_std = (pooled["emp_std_lo"] <= sigma) & (sigma <= pooled["emp_std_hi"])
        assert covered_std.mean() == covered.mean()


# --------------------------------------------------------------------------- ratio_table


def test_ratio_table_reports_range_and_worst_interval_ends():
    pooled = pd.DataFrame({
        "order": [0, 0, 1, 1],
        "level": ["1mrad"] * 4,
        "architecture": ["none", "none", "operational", "operational"],
        "ratio_pqn": [0.99, 1.01, 0.90, np.nan],
        "ratio_pqn_lo": [0.98, 1.00, 0.85, np.nan],
        "ratio_pqn_hi": [1.00, 1.03, 0.95, np.nan],
        "ratio_exact": [0.999, 1.002, 1.004, 0.998],
        "ratio_exact_lo": [0.990, 0.995, 0.999, 0.980],
        "ratio_exact_hi": [1.010, 1.009, 1.010, 1.020],
    })
    summary = batch.ratio_table(pooled)
    assert summary[["order", "architecture", "n_rows"]].values.tolist() == [
        [0, "none", 2], [1, "operational", 2]]
    position, velocity = summary.to_dict("records")
    assert (position["ratio_pqn_min"], position["ratio_pqn_max"]) == (0.99, 1.01)
    assert (position["ratio_pqn_lo_min"], position["ratio_pqn_hi_max"]) == (0.98, 1.03)
    assert (velocity["ratio_pqn_min"], velocity["ratio_pqn_max"]) == (0.90, 0.90)  # NaN skipped
    assert (velocity["ratio_exact_lo_min"], velocity["ratio_exact_hi_max"]) == (0.980, 1.020)
    by_order = batch.ratio_table(pooled, by=["order"])
    assert by_order["n_rows"].tolist() == [2, 2]
    with pytest.raises(ValueError, match="by"):
        batch.ratio_table(pooled, by=[])


def test_ratio_table_accepts_pool_runs_output():
    table = pd.concat([_group_table([1.0, 1.2], group="A"),
                       _group_table([1.0], group="B", order=1)], ignore_index=True)
    summary = batch.ratio_table(batch.pool_runs(table))
    assert summary["order"].tolist() == [0, 1]
    assert summary["ratio_exact_max"].tolist() == pytest.approx([np.sqrt(1.22), 1.0])


# --------------------------------------------------------------------------- bound_violations


def test_bound_violations_lists_only_rows_above_the_trajectory_bound():
    table = pd.DataFrame([_row(f"r{i}", "g") for i in range(4)])
    table["worst_case_trajectory"] = [1.0, 1.0, 0.5, np.nan]
    table["emp_max_abs"] = [0.9, 1.0 + 1e-13, 0.6, 5.0]
    violations = batch.bound_violations(table)
    # Row 1 touches the bound within rounding, row 3 has no bound: only row 2 violates.
    assert violations["log_id"].tolist() == ["r2"]
    assert violations["excess"].tolist() == pytest.approx([0.2])
    assert list(violations.columns) == list(table.columns) + ["excess"]
    clean = batch.bound_violations(table.iloc[:2])
    assert clean.empty and list(clean.columns) == list(table.columns) + ["excess"]
    with pytest.raises(ValueError, match="rtol=-1"):
        batch.bound_violations(table, rtol=-1)
