"""The oracle point of the detectability analysis is the simulator's truth in the model's frame."""
import numpy as np
import pytest

from benchmarks import lrde_detectability as det
from benchmarks.bench_lrde_effects import STEP, simulate_case
from enclab.lrde import compare, fit


@pytest.mark.parametrize("case, seed", [("drift", 5), ("hysteresis", 6), ("harmonic", 7)])
def test_oracle_point_scores_its_readings_like_its_own_simulations(case, seed):
    # Readings simulated from the truth score like readings simulated from the oracle point
    # (predictive check z near 0); a point off in frame (phase origin, drift re-expansion,
    # units) scores its readings far below its own simulations.
    t, counts, truth = simulate_case(np.random.default_rng(seed), case, 20)
    sine = fit.map_fit(t, counts, STEP)
    point = det.true_point(truth, case, sine)
    check = compare.predictive_check(point, t, counts, np.random.default_rng(seed), n_sim=40)
    assert abs(check["z"]) < 4.0
    shifted = {**point, "x": point["x"] + np.r_[0, 0, 0, 0.05, np.zeros(point["x"].size - 4)]}
    assert compare.predictive_check(shifted, t, counts, np.random.default_rng(seed), n_sim=40)["z"] < -10
