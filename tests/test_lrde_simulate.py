"""Open-loop and closed-loop (PID, paper 002 Fig. 5) simulated LRDE logs."""
import numpy as np
import pytest

from enclab.lrde import dwell, model, simulate

STEP = simulate.ROS_DRILL_STEP


def test_open_loop_log_reproduces_the_encoder_model():
    rng = np.random.default_rng(2)
    df, p = simulate.open_loop_log(rng, A12=3.44 * STEP, bias=0.01, offset_frac=0.25,
                                   n_cycles=5, truth_step=STEP / 1000)
    assert list(df.columns) == ["t", "counts", "truth_counts"]
    assert df["counts"].dtype == np.int64 and df["truth_counts"].dtype == np.int64
    assert len(df) == 5 * 2000 // 20
    theta = model.sinusoid(df["t"].to_numpy(), p["A12"], p["bias"], p["f_hz"], p["phase"])
    np.testing.assert_array_equal(df["counts"], model.encoder_counts(theta, STEP, p["offset_a"]))
    # Fine truth: rounding to STEP/1000 errs by at most half its step.
    assert np.max(np.abs(df["truth_counts"] * STEP / 1000 - theta)) <= STEP / 2000 * (1 + 1e-9)
    assert p["a_eq"] == pytest.approx(p["offset_a"] + 0.01)
    assert p["E_b"] == pytest.approx(p["a_eq"] - STEP / 2)


def test_open_loop_offset_is_uniform_when_drawn():
    # a ~ U(0, step): over 400 seeds the mean fraction is 1/2 +- sqrt(1/12/400) = 0.014; 4 sd.
    fracs = [simulate.open_loop_log(np.random.default_rng(s), n_cycles=1)[1]["offset_a"] / STEP
             for s in range(400)]
    assert 0 <= min(fracs) and max(fracs) < 1
    assert abs(np.mean(fracs) - 0.5) < 4 * np.sqrt(1 / 12 / 400)


def test_open_loop_validates():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="offset_frac"):
        simulate.open_loop_log(rng, offset_frac=1.0)
    with pytest.raises(ValueError, match="rng"):
        simulate.open_loop_log(0)
    with pytest.raises(ValueError, match="noise_std"):
        simulate.open_loop_log(rng, noise_std=-1.0)


@pytest.mark.parametrize("offset_frac", [0.15, 0.6, 0.9])
def test_closed_loop_shows_fig6_bias_restoring(offset_frac):
    rng = np.random.default_rng(4)
    df, p = simulate.closed_loop_pid_log(rng, offset_frac=offset_frac, n_cycles=60)
    assert df["counts"].dtype == np.int64
    settled = df[df["t"] >= 20 / p["f_hz"]]  # drop 20 cycles of transient
    per_cycle = dwell.cycle_bias(settled["t"].to_numpy(), settled["theta"].to_numpy(),
                                    p["f_hz"])
    # Readings stay 2n = 4 steps peak to peak, symmetric about count 0 ...
    tab = dwell.cycle_table(settled["counts"].to_numpy(), settled["t"].to_numpy(), STEP,
                            f_hz=p["f_hz"])
    assert (tab["steps_pp"] == 4).all() and (tab["centre_count"] == 0).all()
    # ... the stroke is in the n = 2 band and, by Proposition 1, the bias stays inside
    # ideal bias +- epsilon/2 every cycle.
    assert np.all((per_cycle["A12"] > 3 * STEP) & (per_cycle["A12"] < 5 * STEP))
    dev = per_cycle["bias"].to_numpy() - p["ideal_bias"]
    half_eps = 0.5 * model.epsilon(per_cycle["A12"].to_numpy(), STEP)
    assert np.all(np.abs(dev) < half_eps)
    # The restoring mechanism of Prop. 2: integral action drives the readings' DC component to
    # zero; it must be an order of magnitude below the DC a pure sinusoid would show near the
    # band edge (E_b = 0.9 epsilon/2, eq. 20).
    whole = settled.iloc[: len(settled) // 100 * 100]  # 100 samples per cycle at 2 kHz / 20 Hz
    A12 = float(np.median(per_cycle["A12"]))
    c0_edge = model.dc_component(0.9 * 0.5 * model.epsilon(A12, STEP), A12, STEP, 2)
    assert abs(STEP * whole["counts"].mean()) < 0.1 * c0_edge
    # The bias moves (it is not pinned by the initial state): it visits both sides of the
    # ideal bias during the run.
    dev_all = dwell.cycle_bias(df["t"].to_numpy(), df["theta"].to_numpy(), p["f_hz"])
    dev_all = dev_all["bias"].to_numpy()[2:] - p["ideal_bias"]
    assert dev_all.min() < 0 < dev_all.max()


def test_cycle_bias_of_pure_sinusoid():
    t = np.arange(4000) / 2000.0
    theta = model.sinusoid(t, 0.3, 0.05, 20.0, 0.0)
    cb = dwell.cycle_bias(t, theta, 20.0)
    assert len(cb) == 39
    # 100 samples per period: the sampled extremes miss the crest by <= A (pi/100)^2/2 = 7e-4 A.
    np.testing.assert_allclose(cb["A12"], 0.3, atol=0.15 * (np.pi / 100) ** 2)
    np.testing.assert_allclose(cb["bias"], 0.05, atol=0.15 * (np.pi / 100) ** 2)
