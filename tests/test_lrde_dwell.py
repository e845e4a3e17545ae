"""Tests of dwell extraction and the eq. (4) baselines on noise-free sampled sinusoids."""
import numpy as np
import pandas as pd
import pytest

from enclab.lrde import dwell, model

STEP = np.deg2rad(0.09)


def _log(A12, E_b, f, fs, n_cycles, phase=0.4, a=0.3 * STEP):
    t = np.arange(int(round(n_cycles * fs / f))) / fs
    b = E_b + 0.5 * STEP - a
    counts = model.encoder_counts(model.sinusoid(t, A12, b, f, phase), STEP, a)
    return t, counts


def test_run_lengths_round_trip():
    c = np.array([0, 0, 1, 1, 1, -1, 0, 0], dtype=np.int64)
    values, starts, lengths = dwell.run_lengths(c)
    np.testing.assert_array_equal(values, [0, 1, -1, 0])
    np.testing.assert_array_equal(starts, [0, 2, 5, 6])
    np.testing.assert_array_equal(np.repeat(values, lengths), c)
    with pytest.raises(ValueError, match="integer dtype"):
        dwell.run_lengths(np.array([0.0, 1.0]))


def test_segment_cycles_counts_and_period():
    f, fs = 20.0, 5000.0
    t, c = _log(3.44 * STEP, 0.0, f, fs, 10.5)
    cycles, f_est = dwell.segment_cycles(c, t)
    # 10.5 cycles contain 9 or 10 complete upward-crossing-to-crossing cycles.
    assert len(cycles) in (9, 10)
    # Each crossing time is resolved to a sample interval: the mean period over k cycles is
    # within 2/(fs k) of the truth.
    assert 1 / f_est == pytest.approx(1 / f, abs=2 / fs / len(cycles))
    np.testing.assert_allclose(cycles["period"], 1 / f, atol=2 / fs)
    with pytest.raises(ValueError, match="t must be strictly increasing"):
        dwell.segment_cycles(c, t[::-1])


@pytest.mark.parametrize("A12_steps,E_frac", [(3.44, 0.0), (3.1, 0.7), (4.6, -0.8), (4.0, 0.3)])
def test_cycle_table_eq4_brackets_truth_per_cycle(A12_steps, E_frac):
    f, fs = 23.0, 10_000.0
    A12 = A12_steps * STEP
    E_b = E_frac * 0.5 * model.epsilon(A12, STEP)
    t, c = _log(A12, E_b, f, fs, 12.3)
    tab = dwell.cycle_table(c, t, STEP, f_hz=f)
    assert len(tab) >= 11
    assert tab["symmetric"].all() and (tab["steps_pp"] == 4).all()
    assert (tab["n_top_runs"] == 1).all() and (tab["n_bottom_runs"] == 1).all()
    w1, w2 = model.dwell_half_widths(A12, 0.5 * STEP + E_b, STEP, f)
    # Each dwell 2w is resolved to +-1/fs, so w to +-1/(2 fs).
    h = 0.5 / fs
    np.testing.assert_allclose(tab["w1"], w1, atol=h * (1 + 1e-9))
    np.testing.assert_allclose(tab["w2"], w2, atol=h * (1 + 1e-9))
    # Eq. (4) is increasing in both widths: evaluating it at w -+ h brackets the truth.
    lo = model.dwell_stroke_eq4(tab["w1"] - h, tab["w2"] - h, f, STEP)
    hi = model.dwell_stroke_eq4(tab["w1"] + h, tab["w2"] + h, f, STEP)
    assert np.all((lo <= A12) & (A12 <= hi))
    np.testing.assert_allclose(tab["A12_dwell"],
                               model.dwell_stroke_eq4(tab["w1"], tab["w2"], f, STEP))


def test_eq4_error_vanishes_as_sampling_refines():
    # Eq. (4) is exact for exact widths; sampled widths err by <= 1/(2 fs), so the error
    # shrinks at least linearly in 1/fs (bracket width ~ dA12/dw / fs).
    f = 20.0
    A12, E_b = np.deg2rad(0.31), 0.3 * 0.5 * model.epsilon(np.deg2rad(0.31), STEP)
    errors = []
    for fs in (2_000.0, 20_000.0, 200_000.0):
        t, c = _log(A12, E_b, f, fs, 5.2)
        tab = dwell.cycle_table(c, t, STEP, f_hz=f)
        errors.append(np.max(np.abs(tab["A12_dwell"] - A12)))
    assert errors[2] < errors[0] / 10
    assert errors[2] / A12 < 1e-3


def test_dwell_summary_averaged_eq4_and_props():
    f, fs = 20.0, 3_000.0
    A12 = np.deg2rad(0.31)
    E_b = 0.5 * 0.5 * model.epsilon(A12, STEP)
    t, c = _log(A12, E_b, f, fs, 40.37)
    tab = dwell.cycle_table(c, t, STEP, f_hz=f)
    s = dwell.dwell_summary(tab)
    assert s["n"] == 2 and s["centre_count"] == 0 and s["n_used"] == len(tab)
    h = 0.5 / fs
    # The mean widths are inside +-h of the true ones, so the averaged eq. (4) is bracketed.
    lo = model.dwell_stroke_eq4(s["w1_mean"] - h, s["w2_mean"] - h, f, STEP)
    hi = model.dwell_stroke_eq4(s["w1_mean"] + h, s["w2_mean"] + h, f, STEP)
    assert lo <= A12 <= hi
    assert s["prop1_in_band"] and s["prop1_fraction_cycles"] == 1.0
    # Prop. 2: with E_b > 0 the measured DC component is positive and matches eq. (20) within
    # the per-cycle sampling resolution.
    c0 = model.dc_component(E_b, A12, STEP, 2)
    assert c0 > 0
    assert np.all(np.abs(tab["dc_offset"] - c0) <= tab["dc_resolution"])
    assert s["prop2_n_tested"] > 0 and s["prop2_sign_agreement"] == 1.0
    assert s["E_b_dwell"] == pytest.approx(E_b, abs=0.05 * STEP)


def test_dwell_summary_of_no_cycles_is_nan():
    empty = dwell.cycle_table(np.zeros(100, dtype=np.int64), np.arange(100) / 1e3, STEP)
    s = dwell.dwell_summary(empty)
    assert s["n_used"] == 0 and np.isnan(s["dwell_formula_A12"])
    with pytest.raises(ValueError, match="lacks"):
        dwell.dwell_summary(pd.DataFrame({"x": [1]}))
