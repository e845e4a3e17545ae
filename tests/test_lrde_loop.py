"""The loop motion model (enclab.lrde.loop): the logged error through a low-order filter."""
import numpy as np
import pandas as pd
import pytest

from enclab.lrde import loop, pipeline, simulate

STEP = simulate.ROS_DRILL_STEP


def _theta_from_columns(df, p, taps):
    """Least squares of the true angle on the loop's columns at the pole ``p``."""
    counts = df["counts"].to_numpy()
    cols = loop._Columns(loop.error_steps(counts, df["reference"].to_numpy(), STEP), taps)
    lag, trans = cols.lag(p)
    design = np.column_stack((np.ones(cols.n), cols.fixed, lag, trans))
    # From the second sample on: the pole at 0's own start (the error before the piece) acts
    # on the first sample only.
    y = df["theta"].to_numpy()[1:] / STEP
    coef, *_ = np.linalg.lstsq(design[1:], y, rcond=None)
    return y, design[1:] @ coef


@pytest.mark.parametrize("kd, taps", [(0.0, 0), (0.5, 1)])
def test_columns_reproduce_the_simulated_loop(kd, taps):
    # The simulator's own PID loop (quantized feedback, no noise), started mid-run so that
    # the state at the start of the piece is not zero: with the true plant pole the angle is
    # exactly in the span of the columns (PI: poles 1, 1, p; PID adds the pole at 0, one
    # tap), so the least-squares residual is rounding (1e-9 step is ~1e6 times double
    # precision's relative error on the columns' sums over 2000 samples).
    df, prm = simulate.closed_loop_pid_log(np.random.default_rng(3), n_cycles=30, kd=kd * 1e-3,
                                           offset_frac=0.3)
    piece = df.iloc[1000:].reset_index(drop=True)
    p = np.exp(-1.0 / (prm["fs_hz"] * prm["tau"]))
    y, fitted = _theta_from_columns(piece, p, taps)
    assert np.max(np.abs(y - fitted)) < 1e-9
    # A wrong pole leaves a visible error (the pole is identified by the angle's shape).
    _, off = _theta_from_columns(piece, 0.9 * p, taps)
    assert np.max(np.abs(y - off)) > 1e-3


def test_error_and_cycles_checks():
    with pytest.raises(ValueError, match="shape of counts"):
        loop.error_steps(np.zeros(5, dtype=int), np.zeros(4), STEP)
    with pytest.raises(ValueError, match="fewer than two whole cycles"):
        loop.reference_cycles(np.sin(np.linspace(0, 3 * np.pi, 100)))
    with pytest.raises(ValueError, match="unknown loop structure"):
        loop.loop_structure("loop-p")


def test_command_channel_only_when_declared():
    df = pd.DataFrame({"t": [0.0, 1.0], "c": [0, 1], "r": [0.0, 0.1]})
    meta = {"channels": [{"name": "c", "role": "measured", "joint": 1, "storage": "counts",
                          "step": STEP}]}
    info = {"measured": "c"}
    assert pipeline.select_command(df, meta, info) is None
    meta["channels"].append({"name": "r", "role": "command", "joint": 2, "storage": "float"})
    assert pipeline.select_command(df, meta, info) is None  # another joint's command
    meta["channels"][-1]["joint"] = 1
    np.testing.assert_array_equal(pipeline.select_command(df, meta, info), [0.0, 0.1])


@pytest.mark.slow
def test_fit_recovers_the_fine_channels_stroke_and_bias():
    # A closed-loop log (noise 0.02 step) after its pull-in; the fine channel's per-cycle
    # stroke and bias over the reference's cycles are the targets. A calibrated 90 % interval
    # holds them 9 times in 10; the test allows a miss by one interval width on either side
    # (5 standard deviations of a normal posterior: a failure is a bias, not bad luck).
    df, prm = simulate.closed_loop_pid_log(np.random.default_rng(11), n_cycles=45,
                                           noise_std=0.02 * STEP, truth_step=STEP / 100)
    df = df.iloc[3000:].reset_index(drop=True)
    t, counts, ref = df["t"].to_numpy(), df["counts"].to_numpy(), df["reference"].to_numpy()
    fine = df["truth_counts"].to_numpy() * STEP / 100
    res = loop.fit_loop(t, counts, ref, STEP, 5, truth=fine, truth_step=STEP / 100)
    starts = loop.reference_cycles(ref)
    top, bottom = loop._cycle_extremes(fine[None, :], starts)
    stroke = float((top - bottom).mean())
    e_b = float(prm["offset_a"] + (0.5 * (top + bottom)).mean()
                - (res.centre_count + 0.5) * STEP)
    for name, true in (("A12", stroke), ("E_b", e_b)):
        q = res.summary[name]
        width = q["q95"] - q["q05"]
        assert q["q05"] - width <= true <= q["q95"] + width, (name, true, q)
    a = res.summary["offset_a"]
    assert a["q05"] - (a["q95"] - a["q05"]) <= prm["offset_a"] <= a["q95"] + (a["q95"] - a["q05"])


@pytest.mark.slow
def test_stage_with_a_command_channel_reports_the_loop_fit():
    # A closed-loop log with its reference declared as a command channel: the loop structure
    # replaces the periodic pick, its posterior is the reported one (converged, as every
    # ensemble starts at the point fit), the periodic pick is not sampled, and the stroke's
    # interval holds the simulated angle's per-cycle stroke within one width (a miss by more
    # is a bias, not the 1-in-10 of a calibrated interval).
    df, prm = simulate.closed_loop_pid_log(np.random.default_rng(7), n_cycles=50,
                                           noise_std=0.02 * STEP, truth_step=STEP / 100)
    df = df.iloc[3000:].reset_index(drop=True)
    df["t"] -= df["t"].iloc[0]
    meta = {"log_id": "loop", "channels": [
        {"name": "counts", "role": "measured", "joint": 1, "unit": "counts",
         "storage": "counts", "step": STEP},
        {"name": "truth_counts", "role": "truth", "joint": 1, "unit": "counts",
         "storage": "counts", "step": STEP / 100},
        {"name": "reference", "role": "command", "joint": 1, "unit": "rad",
         "storage": "float", "step": None}]}
    settings = {"n_ensembles": 4, "n_walkers": 16, "n_steps": 250, "max_steps": 1000,
                "n_burn": 100, "effects": [], "effect_pairs": False}
    block, figures, _, _ = pipeline.analyse_lrde_log(df, meta, 3, settings, threads=2)
    assert block["model"]["chosen"] in loop.STRUCTURES
    assert block["model"]["periodic"]["params"] == {}
    assert block["diagnostics"]["converged"]
    assert "averaged" not in block
    ref = df["reference"].to_numpy()
    top, bottom = loop._cycle_extremes(df["theta"].to_numpy()[None, :],
                                       loop.reference_cycles(ref))
    stroke = float((top - bottom).mean())
    q = block["A12"]
    width = q["q95"] - q["q05"]
    assert q["q05"] - width <= stroke <= q["q95"] + width, (stroke, q)
    assert set(figures) == {"corner", "dwell_ppc", "bias_cycles", "misfit"}
