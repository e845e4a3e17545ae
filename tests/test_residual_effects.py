"""Tests for enclab.residuals.effects: each effect's signature against its analytic form."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from enclab.residuals import effects as fx
from enclab.residuals.simulate import simulate_log

STEP = 2 * np.pi / 4096


def _aux(**kw):
    base = {"_step": STEP, "_offset": 0.5, "_theta_ref": 0.0, "_line_pitch": 16 * STEP}
    base.update(kw)
    return base


def _play_reference(x, w):
    """Slow per-sample play operator (the textbook recursion) as an independent check."""
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, x.size):
        y[i] = min(max(y[i - 1], x[i] - w / 2), x[i] + w / 2)
    return y


# ------------------------------------------------------------------------ memory and play
def test_motion_sign_keeps_direction_through_dwells():
    v = np.array([0.0, 0.0, 1.0, 0.0, 0.0, -2.0, 0.0, 3.0])
    np.testing.assert_array_equal(fx.motion_sign(v), [0, 0, 1, 1, 1, -1, -1, 1])


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=2, max_size=200),
    w=st.floats(0.0, 1.5),
)
def test_play_operator_matches_per_sample_recursion(steps, w):
    x = np.cumsum(np.round(np.asarray(steps), 3))  # repeated values (dwells) included
    np.testing.assert_allclose(fx.play_operator(x, w), _play_reference(x, w), rtol=0, atol=1e-12)


def test_backlash_signature_is_half_width_by_direction_after_reversal():
    t = np.linspace(0, 4, 4001)
    theta = 0.3 * np.sin(2 * np.pi * 0.5 * t)
    w = 0.02
    r = fx.Backlash().apply(theta, t, None, {}, [w]) - theta
    v = np.gradient(theta, t)
    # once the input has travelled w since its last reversal the play is taken up
    p = fx.play_operator(theta, w)
    engaged = np.abs(theta - p) >= w / 2 - 1e-12
    rising, falling = engaged & (v > 0), engaged & (v < 0)
    assert rising.sum() > 1000 and falling.sum() > 1000
    np.testing.assert_allclose(r[rising], -w / 2, atol=1e-12)
    np.testing.assert_allclose(r[falling], w / 2, atol=1e-12)
    # negative width: the measured side leads by the same amount
    r_neg = fx.Backlash().apply(theta, t, None, {}, [-w]) - theta
    np.testing.assert_allclose(r_neg[rising], w / 2, atol=1e-12)
    np.testing.assert_allclose(r_neg[falling], -w / 2, atol=1e-12)


def test_backlash_and_hysteresis_share_the_first_order_term_at_zero():
    # both branches of the signed play join at w = 0 with slope -sign/2 (interior null)
    t = np.linspace(0, 2, 2001)
    theta = 0.2 * np.sin(2 * np.pi * t)
    v = np.gradient(theta, t)
    ctx = type("C", (), {"step": STEP})()
    J = fx.Backlash().signature(theta, t, v, {}, ctx)[:, 0]
    sign = fx.motion_sign(np.r_[0.0, np.diff(theta)])  # direction of the last sample-to-sample move
    # away from the reversals (input travel > fd step) the slope is exactly -sign/2
    far = np.abs(theta - fx.play_operator(theta, 1e-3)) >= 0.5e-3 - 1e-12
    np.testing.assert_allclose(J[far], -0.5 * sign[far], atol=1e-9)
    Jh = fx.Hysteresis().signature(theta, t, v, {"_motion_sign": sign}, ctx)[:, 0]
    np.testing.assert_allclose(Jh, -0.5 * sign, atol=1e-12)


def test_backlash_narrower_than_the_truth_step_switches_at_the_reversal():
    # A 1 Hz, 1 rad turn read by a truth with a 1 mrad step sits ~14 samples on its top level;
    # a play of 0.3 truth steps takes up within ~3 samples of the reversal. On the smooth
    # reconstruction (select._smooth_correction) the model's play switches within one sample of
    # the physical one at every phase of the truth grid; on the truth reading it switches when
    # the reading leaves its plateau (several samples off).
    from enclab.residuals import select as sel

    t = np.arange(2000) / 1000.0
    ts, w = 1e-3, 0.3e-3
    lags_model, lags_raw = [], []
    for phase in np.linspace(0.0, 1.0, 11):
        theta = np.cos(2 * np.pi * (t - 0.5)) + phase * ts
        truth = ts * np.round(theta / ts)
        aux = {"_smooth_correction": sel._smooth_correction(truth, ts)}

        def switch(corr):  # first sample after 0.8 s where the correction changes sign (reversal at 1.0 s)
            return 800 + int(np.flatnonzero(corr[800:] < 0)[0])

        physical = switch(fx.play_operator(theta, w) - theta)
        lags_model.append(switch(fx.Backlash().apply(truth, t, None, aux, [w]) - truth) - physical)
        lags_raw.append(switch(fx.play_operator(truth, w) - truth) - physical)
    assert max(abs(x) for x in lags_model) <= 1
    assert max(abs(x) for x in lags_raw) >= 3
    # a continuous truth has nothing to reconstruct
    np.testing.assert_array_equal(sel._smooth_correction(np.sin(t), 0.0), 0.0)


def test_latency_behind_a_play_is_the_delayed_output_of_the_play():
    # The measured side reads play(theta)(t - tau); the model composes effects by their order
    # (select._Model), latency first. Its only errors are the first-order time shift,
    # tau^2 max|a| / 2 = 6e-6 rad here, and the smoothed velocity: within 1e-5 rad. Delaying
    # after the play instead (play(theta) - tau v) moves the reading while the play is taken
    # up: tau v there reaches ~7e-4 rad (v = sqrt(2 w A) omega = 0.34 rad/s after a travel w).
    from enclab.residuals import select as sel

    t = np.arange(4000) / 1000.0
    tau, w, a, om = 2e-3, 0.02, 0.3, np.pi
    theta = a * np.sin(om * t)
    exact = fx.play_operator(a * np.sin(om * (t - tau)), w)
    ctx = sel._make_ctx(t, theta, np.zeros(t.size, np.int64), STEP, 0.0, {}, 0.0, None)
    model = sel._Model([fx.Backlash(), fx.Latency()])
    assert [e.name for e in model.effects] == ["latency", "backlash"]
    mu, _ = model.forward(ctx, np.array([0.0, -1.0, tau, w]))
    inner = slice(50, -50)  # the smoothed velocity's edge samples
    assert np.max(np.abs(mu * STEP - exact)[inner]) < 1e-5
    wrong = fx.play_operator(theta, w) - tau * ctx.velocity
    assert np.max(np.abs(wrong - exact)[inner]) > 5e-4


def test_play_operator_rejects_negative_width():
    with pytest.raises(ValueError, match="play width"):
        fx.play_operator([0.0, 1.0], -0.1)


# ------------------------------------------------------------------------ shift signatures
def test_hysteresis_signature_is_half_width_against_motion():
    t = np.linspace(0, 1, 1001)
    v = np.cos(2 * np.pi * t)
    theta = np.sin(2 * np.pi * t) / (2 * np.pi)
    sign = fx.motion_sign(v)
    r = fx.Hysteresis().apply(theta, t, v, {"_motion_sign": sign}, [0.004]) - theta
    np.testing.assert_allclose(r, -0.002 * sign)


def test_latency_signature_is_tau_times_velocity():
    t = np.linspace(0, 1, 101)
    v = np.linspace(-3, 3, 101)
    r = fx.Latency().apply(np.zeros(101), t, v, {}, [2e-3]) - 0.0
    np.testing.assert_allclose(r, -2e-3 * v)


def test_scale_mismatch_signature_ramps_with_angle():
    theta = np.linspace(-2, 2, 41)
    r = fx.ScaleMismatch().apply(theta, None, None, {"_theta_ref": 0.5}, [1e-3]) - theta
    np.testing.assert_allclose(r, 1e-3 * (theta - 0.5))


def test_angle_harmonics_periodic_and_derived_amplitude_phase():
    e = fx.AngleHarmonics()
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    p = [3e-4, -4e-4, 1e-4, 0.0]
    r1 = e.apply(theta, None, None, {}, p) - theta
    r2 = e.apply(theta + 2 * np.pi, None, None, {}, p) - (theta + 2 * np.pi)
    np.testing.assert_allclose(r1, r2, atol=1e-15)
    d = e.derived(dict(zip(e.param_names, p)))
    # a cos + b sin = amp sin(theta + phase)
    np.testing.assert_allclose(d["amp1"] * np.sin(theta + d["phase1"]), 3e-4 * np.cos(theta) - 4e-4 * np.sin(theta), atol=1e-15)
    assert d["amp1"] == pytest.approx(5e-4)


def test_line_pitch_harmonics_periodic_in_line_pitch():
    e = fx.LinePitchHarmonics()
    aux = _aux()
    theta = np.linspace(0, 1, 200)
    r1 = e.apply(theta, None, None, aux, [1e-4, 2e-4]) - theta
    r2 = e.apply(theta + aux["_line_pitch"], None, None, aux, [1e-4, 2e-4]) - (theta + aux["_line_pitch"])
    np.testing.assert_allclose(r1, r2, atol=1e-12)


def test_line_pitch_at_four_counts_is_not_a_separate_candidate():
    ctx = type("C", (), {"step": STEP, "priv": {"_line_pitch": 4 * STEP}})()
    assert not fx.LinePitchHarmonics().applicable(ctx)
    ctx.priv["_line_pitch"] = 16 * STEP
    assert fx.LinePitchHarmonics().applicable(ctx)


def test_quadrature_edges_model_matches_exact_edge_displacement():
    # the model's nearest-threshold shift must give the same counts as displacing each edge
    # (the independent construction of the simulator) for |e| < step / 2
    rng = np.random.default_rng(3)
    p = {"e0": 0.2 * STEP, "e1": -0.3 * STEP, "e2": 0.05 * STEP}
    c = 0.37
    log = simulate_log(rng, lambda t: 0.05 * np.sin(2 * np.pi * t), duration=2.0, step=STEP, truth_step=STEP / 64,
                       effects={"quadrature_edges": p}, offset_frac=c)
    aux = _aux(_offset=c)
    theta_eff = fx.QuadratureEdges().apply(log["theta"], log["t"], None, aux, list(p.values()))
    counts = np.floor(theta_eff / STEP + c).astype(np.int64)
    np.testing.assert_array_equal(counts, log["counts"])
    assert np.any(counts != np.floor(log["theta"] / STEP + c))


def test_quadrature_pattern_repeats_every_four_counts_and_sums_to_zero():
    e = fx.QuadratureEdges()
    aux = _aux(_offset=0.0)
    m = np.arange(12)
    theta = (m + 1e-3) * STEP  # at the threshold into count m (with c = 0 the count is floor(theta / step))
    shift = e.apply(theta, None, None, aux, [1e-4, 2e-4, -5e-5]) - theta
    pattern = -np.array([1e-4, 2e-4, -5e-5, -(1e-4 + 2e-4 - 5e-5)])
    np.testing.assert_allclose(shift, np.tile(pattern, 3))
    assert shift[:4].sum() == pytest.approx(0.0, abs=1e-18)


# ------------------------------------------------------------------------ noise effects
def test_timestamp_jitter_std_is_sigma_times_speed():
    v = np.array([-2.0, 0.0, 0.5])
    np.testing.assert_allclose(fx.TimestampJitter().noise_std(None, None, v, {}, [1e-3]), [2e-3, 0.0, 5e-4])
    assert fx.TimestampJitter.boundary == ("sigma_t",)


def test_truth_quantization_std_is_uniform_std():
    sd = fx.TruthQuantization().noise_std(np.zeros(3), None, None, {"_truth_step": 1e-3}, [])
    np.testing.assert_allclose(sd, 1e-3 / math.sqrt(12))


def test_truth_quantization_std_is_that_of_a_simulated_truth_rounding():
    # brute force: round a continuous angle to the truth's grid; the effect's jitter is the
    # std of the rounding error (relative standard error sqrt(0.2 / n) = 0.1 % at n = 2e5)
    truth_step = STEP / 8
    theta = np.random.default_rng(7).uniform(-1.0, 1.0, 200_000)
    truth = truth_step * np.round(theta / truth_step)
    sd = fx.TruthQuantization().noise_std(truth, None, None, {"_truth_step": truth_step}, [])
    assert np.std(theta - truth) == pytest.approx(sd[0], rel=5 * math.sqrt(0.2 / theta.size))


# ------------------------------------------------------------------------ counter effects
def test_missed_counts_detect_finds_time_and_integer_jump():
    rng = np.random.default_rng(0)
    t = np.arange(5000) / 1000
    r = rng.integers(0, 2, t.size) * 0.0 + (rng.random(t.size) < 0.03)  # sporadic 0/1 flips
    r = r - 2.0 * (t >= 3.1)  # measured lower by 2 after 3.1 s
    times, jumps = fx.MissedCounts.detect(t, r)
    assert len(times) == 1 and jumps == [2]
    assert times[0] == pytest.approx(3.1, abs=0.02)
    shift = fx.MissedCounts(times, jumps).apply(np.zeros(t.size), t, None, _aux(), None)
    np.testing.assert_allclose(shift, -2 * STEP * (t >= times[0]))


def test_wrap_detect_snaps_to_two_pi():
    truth = np.linspace(2.0, 4.5, 1000)
    measured = np.mod(truth + np.pi, 2 * np.pi) - np.pi
    assert fx.WrapAround.detect(truth, measured, STEP) == 2 * np.pi
    assert fx.WrapAround.detect(truth, truth, STEP) is None


def test_wrap_apply_brings_model_onto_wrapped_counts():
    truth = np.linspace(2.0, 4.5, 1000)
    measured = np.mod(truth + np.pi, 2 * np.pi) - np.pi
    counts = np.floor(measured / STEP + 0.5)
    aux = _aux(_offset=0.5, _counts=counts)
    theta = fx.WrapAround(2 * np.pi).apply(truth, None, None, aux, None)
    np.testing.assert_array_equal(np.floor(theta / STEP + 0.5), counts)


# ------------------------------------------------------------ softening compliance and map
def test_softening_compliance_is_k1_T_plus_k2_T_abs_T_about_their_means():
    rng = np.random.default_rng(4)
    tq = rng.uniform(-3.0, 3.0, 500)
    theta = rng.uniform(-1.0, 1.0, 500)
    k1, k2 = 1.2e-3, -2.5e-4
    e = fx.SofteningCompliance()
    got = e.apply(theta, None, None, {"torque": tq}, [k1, k2])
    want = theta + k1 * (tq - tq.mean()) + k2 * (tq * np.abs(tq) - np.mean(tq * np.abs(tq)))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    # the analytic columns are the derivatives of the shift; the central differences carry the
    # rounding of theta (|theta| <= 1) over their step h: eps / h, h = 1e-4 of the range
    ctx = _Ctx(tq)
    h = min(e.fd_steps(ctx))
    np.testing.assert_allclose(np.column_stack(e.columns({"torque": tq})),
                               e.signature(theta, None, None, {"torque": tq}, ctx), rtol=0,
                               atol=8 * np.finfo(float).eps / h)
    e.t_max = 3.0
    d = e.derived({"k1": k1, "k2": k2})
    assert d["softening"] == pytest.approx(-k2 * 3.0 / k1)
    assert d["twist_at_max_torque"] == pytest.approx(k1 * 3.0 + k2 * 9.0)


class _Ctx:
    """The few context fields an effect's bounds and signature read."""

    def __init__(self, torque, truth=None, step=STEP):
        self.aux = {"torque": torque}
        self.priv = {"_span": 20 * step}
        self.step = step
        self.truth = np.zeros_like(torque) if truth is None else truth
        self.t = np.arange(np.size(torque)) * 1e-3
        self.fit_idx = np.arange(np.size(torque))


def test_calibration_map_spacing_is_chosen_on_heldout_data():
    from enclab.residuals.calibration import MapBasis

    rng = np.random.default_rng(11)
    n = 20000
    a = 0.6 * np.sin(2 * np.pi * 0.37 * np.arange(n) / 1000.0) + 0.1   # a 1.2 rad stroke, ~7 passes
    lo, hi = float(a.min()), float(a.max())
    true = MapBasis(lo, hi, (hi - lo) / 8, n_grid=801)
    coef = rng.normal(0.0, 1e-3, true.n_columns)
    # the quantization noise of a 4096-cpr reading: U(-step/2, step/2)
    resid = true.design(a) @ coef + rng.uniform(-STEP / 2, STEP / 2, n)
    ctx = _Ctx(np.zeros(n), truth=a)
    e = fx.CalibrationMap()
    assert e.applicable(ctx)
    e.prepare(ctx, resid)
    n_int = round((hi - lo) / e.basis.spacing)
    # a basis holding the true knots (8, 16 or 24 intervals) fits it; 3, 4, 6 or 12 do not
    assert n_int % 8 == 0
    assert e.param_names == tuple(f"m{j + 1}" for j in range(e.basis.n_columns))
    # the map acts on the smooth angle, its columns are its derivatives
    aux = {"_smooth": a}
    p = rng.normal(0.0, 1e-4, len(e.param_names))
    np.testing.assert_allclose(e.apply(a, None, None, aux, p) - a, e.basis.design(a) @ p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(e.columns(aux).T @ p, e.basis.design(a) @ p, rtol=0, atol=1e-15)
    assert e.derived(dict(zip(e.param_names, p)))["spacing"] == pytest.approx(e.basis.spacing)


class _ShiftCtx(_Ctx):
    """A context with times, a sensor noise entry and optional aux channels."""

    def __init__(self, n, aux=None, sensor_var=0.0, truth=None):
        super().__init__(np.zeros(n), truth=truth)
        self.aux = dict(aux or {})
        self.priv["_sensor_var"] = sensor_var


def test_level_shift_prepare_finds_the_time_and_leaves_whole_counts_to_missed_counts():
    rng = np.random.default_rng(4)
    n = 6000
    ctx = _ShiftCtx(n)
    noise = rng.uniform(-STEP / 2, STEP / 2, n)
    e = fx.LevelShift()
    assert e.applicable(ctx)
    # 0.37 step from sample 3700 on (t = 3.7 s)
    assert e.prepare(ctx, noise + 0.37 * STEP * (ctx.t >= 3.7))
    assert e.t_shift == pytest.approx(3.7, abs=2e-3)
    assert e.interval[0] <= 3.7 <= e.interval[1] + 1e-3
    np.testing.assert_array_equal(e.apply(np.zeros(n), ctx.t, None, {}, [0.37 * STEP]),
                                  0.37 * STEP * (ctx.t >= e.t_shift))
    # two whole counts on a hard quantizer: a missed count, not a level shift
    assert not fx.LevelShift().prepare(ctx, noise + 2 * STEP * (ctx.t >= 3.7))
    # the same on a noisy sensor is a level shift (its grid is no count of the sensor's)
    noisy = _ShiftCtx(n, sensor_var=STEP**2)
    assert fx.LevelShift().prepare(noisy, noise + 2 * STEP * (noisy.t >= 3.7))
    # nothing but noise: a split is proposed only when it gains more than ln N = 8.7 noise
    # variances. The largest split statistic of white noise over [5 %, 95 %] of the log exceeds
    # c with probability ~ P(chi2_1 > c) + sqrt(c) exp(-c/2) / sqrt(2 pi) ln(0.95^2 / 0.05^2)
    # (Andrews 1993), 0.092 at c = 8.7: of 40 white logs, 3.7 on average (binomial sd 1.8);
    # more than 10 would be 3.5 sd above it
    proposed = sum(fx.LevelShift().prepare(ctx, np.random.default_rng(100 + k).uniform(-STEP / 2, STEP / 2, n))
                   for k in range(40))
    assert proposed <= 10


def _ar1(rng, n, phi):
    e = rng.normal(size=n)
    out = np.empty(n)
    out[0] = e[0] / math.sqrt(1 - phi * phi)
    for j in range(1, n):
        out[j] = phi * out[j - 1] + e[j]
    return out


def test_long_run_inflation_is_one_for_white_noise_and_the_ar1_ratio_for_ar1():
    # batch means over 40 blocks: the estimate's relative sd is sqrt(2 / 40) = 0.22, so 3 sd
    # is a relative 0.67; AR(1) long-run / per-sample variance = (1 + phi) / (1 - phi)
    rng = np.random.default_rng(5)
    assert 1.0 <= fx.long_run_inflation(rng.normal(size=40_000)) <= 1.67
    phi = 0.9
    ratio = (1 + phi) / (1 - phi)
    assert fx.long_run_inflation(_ar1(rng, 40_000, phi)) == pytest.approx(ratio, rel=0.67)


def test_level_shift_interval_widens_on_a_residual_correlated_in_time():
    # the same shift on white and on AR(1) residuals of the same per-sample variance: the
    # time interval on the correlated one is wider (its profile is scaled by the long-run
    # variance, ~19x here), and both hold the true time
    rng = np.random.default_rng(6)
    n = 6000
    ctx = _ShiftCtx(n)
    sd = STEP / math.sqrt(12)
    white = rng.normal(0, sd, n)
    phi = 0.9
    red = _ar1(rng, n, phi) * sd * math.sqrt(1 - phi * phi)
    widths = []
    for noise in (white, red):
        e = fx.LevelShift()
        assert e.prepare(ctx, noise + 1.5 * STEP * (ctx.t >= 3.7))
        assert e.interval[0] <= 3.7 <= e.interval[1] + 1e-3
        widths.append(e.interval[1] - e.interval[0])
    assert widths[1] > 2 * widths[0]


def test_level_shift_at_the_torque_sign_changes_matches_the_simulated_preload():
    rng = np.random.default_rng(6)
    n = 8000
    t = np.arange(n) / 1000.0
    torque = np.sin(2 * np.pi * 0.25 * t) + 0.02 * rng.normal(size=n)   # three reversals, chatter at zero
    ctx = _ShiftCtx(n, aux={"torque": torque})
    size = 0.6 * STEP
    motion = lambda tt: 0.5 * np.sin(2 * np.pi * 0.7 * np.asarray(tt))  # noqa: E731
    log = simulate_log(rng, motion, duration=8.0, step=STEP, truth_step=STEP / 64,
                       effects={"level_shift": {"torque": torque, "size": size}}, offset_frac=0.5)
    clean = simulate_log(np.random.default_rng(6), motion, duration=8.0, step=STEP, truth_step=STEP / 64,
                         offset_frac=0.5)
    e = fx.LevelShift()
    resid = rng.uniform(-STEP / 2, STEP / 2, n) + 0.5 * size * fx.LevelShift.driver_sign(torque)
    assert e.prepare(ctx, resid)
    assert e.derived({"d": size})["at_sign_changes"] == 1.0 and e.n_shifts == 3
    # brute force: the simulator adds size/2 sign(torque) to the continuous angle; the effect's
    # shift differs from it by a constant (the quantizer offset) only, away from the dead zone
    theta = log["theta"]
    model = e.apply(theta, t, None, {"torque": torque}, [size])
    sim = theta + 0.5 * size * np.sign(torque)
    away = np.abs(torque) > 0.1
    diff = (model - sim)[away]
    assert np.ptp(diff) < 1e-15 + 1e-12 * size
    # and the readings it predicts are the simulator's wherever the angle is not within the
    # float rounding of a transition
    k_model = np.floor((model - diff[0]) / STEP + 0.5)
    assert np.mean(k_model[away] == log["counts"][away]) > 0.999
    assert not np.array_equal(log["counts"], clean["counts"])


@pytest.mark.slow
def test_level_shift_selected_on_a_brute_force_simulated_log():
    from enclab.residuals.select import select_effects

    rng = np.random.default_rng(3)
    motion = lambda tt: 0.8 * np.sin(2 * np.pi * 0.6 * np.asarray(tt)) + 0.2 * np.sin(2 * np.pi * 1.3 * np.asarray(tt))  # noqa: E731
    size, when = 0.37 * STEP, 3.3
    log = simulate_log(rng, motion, duration=6.0, step=STEP, truth_step=STEP / 64,
                       effects={"level_shift": {"time": when, "size": size}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=STEP / 64,
                         candidates=["level_shift", "slow_drift", "missed_counts", "hysteresis"])
    assert [e.name for e in res.effects] == ["level_shift"]
    e = res.effects[0]
    lo, hi = e.ci["d"]
    assert lo <= size <= hi
    # the time's profile interval, widened by one sample period (the split lies between samples)
    assert e.derived["t_lo"] - 1e-3 <= when <= e.derived["t_hi"] + 1e-3


def test_harmonic_map_order_is_chosen_on_heldout_blocks():
    rng = np.random.default_rng(8)
    n = 12000
    a = 2 * np.pi * 0.5 * np.arange(n) / 1000.0 + 0.6 * np.sin(2 * np.pi * 0.3 * np.arange(n) / 1000.0)  # 6 turns
    true = fx.HarmonicMap.design(a, 4) @ np.array([2e-3, -1e-3, 8e-4, 6e-4, -4e-4, 3e-4, 3e-4, 2e-4])
    ctx = _Ctx(np.zeros(n), truth=a)
    e = fx.HarmonicMap()
    assert e.applicable(ctx)
    assert e.prepare(ctx, true + rng.normal(0.0, 2e-4, n))
    assert e.n_harmonics >= 4
    assert e.param_names[:2] == ("a1", "b1")
    aux = {"_smooth": a}
    p = rng.normal(0.0, 1e-4, len(e.param_names))
    # (the sum with an angle of up to 25 rad is exact to its last bits: ~25 * 2.2e-16)
    np.testing.assert_allclose(e.apply(a, None, None, aux, p) - a, e.columns(aux).T @ p, rtol=0, atol=1e-13)
    # a twice-per-turn error alone is angle_harmonics' (the map declines), and a stroke short of
    # a turn is no revolution to map
    assert not fx.HarmonicMap().prepare(ctx, fx.HarmonicMap.design(a, 2) @ np.array([0, 0, 1e-3, 5e-4])
                                        + rng.normal(0.0, 2e-4, n))
    assert not fx.HarmonicMap().applicable(_Ctx(np.zeros(n), truth=np.linspace(0.0, 6.0, n)))


def test_level_shift_declines_a_transient_at_the_start():
    # a level that holds only for the first 1 % of the log: the best split is on the edge of the
    # searched range (5 %), a transient at the start and no shift
    rng = np.random.default_rng(9)
    n = 6000
    ctx = _ShiftCtx(n)
    resid = rng.uniform(-STEP / 2, STEP / 2, n) + 3.4 * STEP * (ctx.t < 0.06)
    assert not fx.LevelShift().prepare(ctx, resid)
