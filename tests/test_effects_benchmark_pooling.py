"""Pooling an earlier summary of the effects benchmark with new draws gives the summary of all
draws: counts add, intervals come from the sums, the earlier threshold is kept."""
import numpy as np
import pandas as pd

from benchmarks import bench_lrde_effects as bench


def _draws(rng, n_per_case):
    rows = []
    for cycles in (20, 100):
        for case in ("clean", "hysteresis", "harmonic"):
            for _ in range(n_per_case):
                size = float(np.exp(rng.uniform(np.log(0.02), np.log(0.2))))
                named = bool(rng.uniform() < (0.95 if case == "clean" else
                                              1 / (1 + (0.05 / size) ** 3)))
                row = {"cycles": cycles, "case": case, "size": size,
                       "chosen": "sinusoid" if named == (case == "clean") else "harmonic3",
                       "named": named, "identified": named or bool(rng.uniform() < 0.3),
                       "trusted": bool(rng.uniform() < 0.97), "pooled": bool(rng.uniform() < 0.4),
                       "after_converged": bool(rng.uniform() < 0.98),
                       "wall_s": float(rng.uniform(5, 30))}
                for label in ("before", "after"):
                    for name in ("A12", "E_b"):
                        row[f"{name}_{label}_cover"] = bool(rng.uniform() < 0.9)
                        row[f"{name}_{label}_confident_miss"] = bool(rng.uniform() < 0.02)
                rows.append(row)
    return pd.DataFrame(rows)


def test_pooled_rows_equal_the_summary_of_all_draws():
    rng = np.random.default_rng(7)
    first, second = _draws(rng, 60), _draws(rng, 45)
    # A case whose later draws confuse nothing: no empty name may join the pooled list.
    second.loc[second["case"] == "clean", ["named", "chosen"]] = [True, "sinusoid"]
    # The earlier summary as the page keeps it: 4 significant digits.
    earlier = bench.summarise(first).map(
        lambda v: float(f"{v:.4g}") if isinstance(v, float) else v)
    pooled = bench.pool_summaries(earlier, second).set_index(["cycles", "case"])
    thresholds = {(int(r.cycles), r.case): r.threshold for r in earlier.itertuples()
                  if np.isfinite(r.threshold)}
    whole = bench.summarise(pd.concat([first, second], ignore_index=True),
                            thresholds).set_index(["cycles", "case"])
    assert set(pooled.index) == set(whole.index)
    assert thresholds  # the hysteresis and harmonic rows carry a threshold to pool against
    columns = [c for c in whole.columns if c not in ("median_wall_s", "threshold")]
    for key in whole.index:
        for name in columns:
            want, got = whole.loc[key, name], pooled.loc[key, name]
            if isinstance(want, str) or isinstance(got, str):
                assert want == got, (key, name)
            elif np.isfinite(want):
                assert got == want if name in ("n", "n_at_3x") else abs(got - want) < 1e-12, \
                    (key, name, got, want)
            else:
                assert not np.isfinite(got), (key, name)
        assert np.isnan(pooled.loc[key, "median_wall_s"])
