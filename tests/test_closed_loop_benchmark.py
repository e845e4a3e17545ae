"""The closed-loop benchmark's true values are those of the quantities the stage reports: per
cycle of the reference (between its upward crossings), on the true angle; a recorded draw
scored again from its seed keeps its intervals and gets the same true values as a fresh draw."""
import numpy as np
import pandas as pd

from benchmarks import lrde_closed_loop as bench
from enclab.lrde import loop

STEP = bench.STEP


def test_true_values_of_a_sinusoid_with_a_known_stroke_and_bias():
    per, n_cycles = 100, 12
    j = np.arange(per * n_cycles)
    reference = np.sin(2 * np.pi * j / per)
    amplitude, bias, lag = 1.7 * STEP, 0.3 * STEP, 0.1
    # Each cycle's own stroke and midpoint: the amplitude and bias step from cycle to cycle,
    # so a mean over other cycles than the reference's would differ.
    cycle = j // per
    amp = amplitude * (1.0 + 0.01 * cycle)
    mid = bias + 0.002 * STEP * cycle
    theta = mid + amp * np.sin(2 * np.pi * j / per - lag)
    a_eff = np.full(j.size, 0.25 * STEP)
    got = bench.true_values(theta, reference, a_eff)
    starts = loop.reference_cycles(reference)
    # The reference's crossings fall on a cycle's first sample or the one after (rounding of
    # sin(2 pi k)); the first cycle has no crossing before it, the last none after it.
    whole = starts[:-1] // per
    assert np.array_equal(whole, np.arange(1, n_cycles - 1))
    # 100 samples per cycle put a sample on each crest: the sampled extremes are the crests.
    want_stroke = np.mean(2 * amplitude * (1.0 + 0.01 * np.array(whole)))
    want_mid = np.mean(bias + 0.002 * STEP * np.array(whole)) + 0.25 * STEP
    tol = 2 * amplitude * (1 - np.cos(np.pi / per))  # a crest between samples
    assert abs(got["A12_true"] - want_stroke) <= tol
    assert abs(got["a_plus_b"] - want_mid) <= tol
    assert got["stroke_sd_steps"] > 0 and got["bias_sd_steps"] > 0


def test_rescoring_a_recorded_draw_gives_the_fresh_draws_true_values():
    seed, gains, effect, cycles = 20281212, "nominal", "none", 20
    _, _, truth = bench.simulate_log(np.random.default_rng(seed), gains, effect, cycles)
    centre = 2
    row = {"gains": gains, "effect": effect, "cycles": cycles, "seed": seed,
           "command_channel": True, "chosen": "loop-pi", "trusted": True, "converged": True,
           "wall_s": 1.0, "reference_loop_s": 0.1,
           "A12_median": truth["A12_true"], "A12_q05": truth["A12_true"] - 0.01 * STEP,
           "A12_q95": truth["A12_true"] + 0.01 * STEP}
    e_b = truth["a_plus_b"] - (centre + 0.5) * STEP
    # An interval beside the truth by three widths: a confident miss.
    row.update({"E_b_median": e_b + 0.035 * STEP, "E_b_q05": e_b + 0.03 * STEP,
                "E_b_q95": e_b + 0.04 * STEP})
    # A row recorded before centre_count was kept: an older truth and its E_b only.
    old = {**row, "a_plus_b": truth["a_plus_b"] + 0.004 * STEP,
           "E_b_true": e_b + 0.004 * STEP, "A12_true": 0.0}
    again = bench.rescored(pd.DataFrame([old])).iloc[0]
    assert again["centre_count"] == centre
    assert again["A12_true"] == truth["A12_true"] and again["A12_cover"]
    assert abs(again["E_b_true"] - e_b) < 1e-15
    assert not again["E_b_cover"] and again["E_b_confident_miss"]
    assert again["described"] == (truth["stroke_sd_steps"] < bench.PERIODIC_SD
                                  and truth["bias_sd_steps"] < bench.PERIODIC_SD)
