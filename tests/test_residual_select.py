"""Tests for enclab.residuals.select: likelihood, boundary nulls, recovery, clean logs."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import log_ndtr

from enclab.core.ingest import grid_step
from enclab.residuals import select as sel
from enclab.residuals.select import select_effects
from enclab.residuals.simulate import random_map, random_motion, random_torque, simulate_log

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8
Z90 = stats.norm.ppf(0.95)


def _log(seed, effects=None, duration=6.0, amplitude=0.5, kind="sine"):
    rng = np.random.default_rng(seed)
    motion = random_motion(rng, kind, duration, amplitude)
    return simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP, effects=effects or {})


# ------------------------------------------------------------------------ likelihood pieces
def _ug_density_neg(x, half, sig):
    """Density of U(-half, half) + N(0, sig^2) at x <= 0 from log-CDFs (no 1 - 1 cancellation)."""
    lo, up = log_ndtr((x - half) / sig), log_ndtr((x + half) / sig)
    return np.exp(up) * -np.expm1(lo - up) / (2 * half)


@pytest.mark.parametrize("sig", [1e-3, 0.02, 0.3])
@pytest.mark.parametrize("a", [-4.0, -1.0, -0.2, -0.03, 0.0, 0.4, 2.5])
def test_uniform_gaussian_interval_probability_matches_quadrature(a, sig):
    half = 1 / 16
    b = a + 1.0
    # integrate the density over the mirror interval (the law is symmetric), away from 1 - 1
    ref = integrate.quad(_ug_density_neg, -b, -a, args=(half, sig), points=[-half] if -b < -half < -a else None,
                         epsabs=0, epsrel=1e-12, limit=200)[0] if -a <= 0 else None
    got = sel._log_interval_ug(np.array([a]), np.array([b]), half, np.array([sig]))[0]
    if ref is None:  # a < 0 < b: compare the probability itself
        ref = integrate.quad(lambda x: _ug_density_neg(-abs(x), half, sig), a, b, points=[-half, 0.0, half],
                             epsabs=0, epsrel=1e-12, limit=200)[0]
    if ref > 1e-300:
        # quad's requested 1e-12 relative on the probability is 1e-12 absolute on its log;
        # log_ndtr and expm1 hold a few ulp; abs=1e-10 allows quad's error estimate to be 100
        # times optimistic at the density's kinks (+-half)
        assert got == pytest.approx(math.log(ref), rel=1e-8, abs=1e-10)
    else:  # beyond double precision: the log must still be finite and very negative
        assert np.isfinite(got) and got < -700


def test_loglik_derivatives_match_finite_differences():
    rng = np.random.default_rng(0)
    n = 300
    ctx = type("C", (), {"truth_step": 1 / 8, "step": 1.0})()
    ctx.counts = rng.integers(-1, 3, n)
    mu, s = rng.uniform(-2, 3, n), rng.uniform(0.01, 0.5, n)
    idx = np.arange(n)
    ll, dmu, ds = sel._loglik_terms(ctx, mu, s, idx)
    h = 1e-6
    fd_mu = (sel._loglik_terms(ctx, mu + h, s, idx)[0] - sel._loglik_terms(ctx, mu - h, s, idx)[0]) / (2 * h)
    fd_s = (sel._loglik_terms(ctx, mu, s + h, idx)[0] - sel._loglik_terms(ctx, mu, s - h, idx)[0]) / (2 * h)
    ok = ll > -200  # where the finite difference itself is well conditioned
    # central differences: truncation h^2 |d3 ll| / 6 <= 1e-12 / s_min^3 / 6 = 2e-7 (s >= 0.01),
    # rounding eps |ll| / h <= 2.2e-16 * 200 / 1e-6 = 4.4e-8: 1e-5 is 20 times both
    np.testing.assert_allclose(dmu[ok], fd_mu[ok], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ds[ok], fd_s[ok], rtol=1e-5, atol=1e-5)


def test_floor_probabilities_uniform_limit():
    # sigma -> 0: P(count = floor(mu) + 1) is the part of [mu - h, mu + h) above the next threshold
    mu = np.array([0.98, 0.5, 0.02])
    P = sel._floor_probs(mu, 0.05, 1e-9, np.array([-1, 0, 1]))
    np.testing.assert_allclose(P[2], [0.3, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(P[0], [0.0, 0.0, 0.3], atol=1e-9)
    np.testing.assert_allclose(P.sum(axis=0), 1.0, atol=1e-12)


# ------------------------------------------------------------------------ boundary nulls
def test_boundary_pvalue_is_half_chi2_mixture():
    # chi2_1 critical value at 10 % gives p = 5 % under the 50:50 mixture with chi2_0
    crit = stats.chi2.ppf(0.90, 1)
    assert sel._lr_pvalue(crit, 1, 1) == pytest.approx(0.05)
    assert sel._lr_pvalue(crit, 1, 0) == pytest.approx(0.10)
    assert sel._lr_pvalue(0.0, 1, 1) == pytest.approx(1.0)
    # k = 2 with one boundary parameter: 0.5 chi2_1 + 0.5 chi2_2
    assert sel._lr_pvalue(4.0, 2, 1) == pytest.approx(0.5 * stats.chi2.sf(4, 1) + 0.5 * stats.chi2.sf(4, 2))


def test_jitter_on_clean_log_sits_at_its_boundary_and_is_not_selected():
    log = _log(11)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         candidates=["timestamp_jitter"])
    assert res.effects == []
    ctx = res._ctx
    base = res._fitted
    new = sel._extend(base, sel.fx.TimestampJitter(), ctx)
    lr = 2 * (new.ll - base.ll)
    assert lr >= -1e-6
    assert sel._lr_pvalue(lr, 1, 1) > 0.01


# ------------------------------------------------------------------------ end to end
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_clean_log_gets_no_effect(seed):
    log = _log(seed, kind=["sine", "multisine", "smooth"][seed % 3])
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert res.effects == []
    assert res.explained
    assert "no effect" in res.message
    lo, hi = res.after["floor_ci"]
    assert lo <= res.after["std"] <= hi


@pytest.mark.parametrize(
    "name, params",
    [
        ("latency", {"tau": 1e-3}),
        ("backlash", {"w": -2 * STEP}),
        ("scale_mismatch", {"g": 2e-3}),
        ("hysteresis", {"h": 0.6 * STEP}),
    ],
)
def test_round_trip_recovers_parameters_within_their_standard_error(name, params):
    log = _log(21, {name: params}, duration=8.0)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    names = [e.name for e in res.effects]
    assert names[0] == name
    e = res.effects[0]
    (pname, true), = params.items()
    lo, hi = e.ci[pname]
    se = (hi - lo) / (2 * Z90)
    # the interval is informative (a few % of the effect) and the estimate within 4 se
    assert se < 0.05 * abs(true)
    assert abs(e.params[pname] - true) <= 4 * se
    assert e.delta_bic > 10 and e.delta_heldout > 0
    assert res.after["std"] < 0.5 * res.before["std"]
    assert res.explained
    # at these magnitudes every swap-in alternative loses by more than the margin
    assert e.alternatives and e.indistinguishable == []
    assert min(a["delta_bic"] for a in e.alternatives) > e.distinguish_bic
    assert "not distinguishable" not in res.message


def test_hysteresis_below_the_truth_step_is_reported_indistinguishable_from_a_play():
    # h = 0.06 measured steps (half a truth step): a play of width w = h differs from the
    # hysteresis only while the input travels w after a reversal, and on this seeded log no
    # measured transition falls there, so both predict the same counts (equal likelihoods)
    log = _log(21, {"hysteresis": {"h": 0.06 * STEP}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    (e,) = res.effects
    assert e.name in ("hysteresis", "backlash")
    other = {"hysteresis": "backlash", "backlash": "hysteresis"}[e.name]
    (alt,) = [a for a in e.indistinguishable if a["name"] == other]
    assert abs(alt["delta_bic"]) < 1.0
    (p_chosen,), (p_alt,) = e.params.values(), alt["params"].values()
    assert p_alt == pytest.approx(p_chosen, rel=0.05)
    assert f"{e.name} not distinguishable from {other}" in res.message
    block = json.loads(json.dumps(res.to_summary()))
    d = block["effects"][0]
    assert {"name", "params", "ci", "delta_bic"} <= set(d)
    assert [a["name"] for a in d["indistinguishable_from"]] == [other] and d["distinguish_bic"] == 10.0
    with pytest.raises(ValueError, match="distinguish_bic"):
        select_effects(log["t"], log["truth"], log["measured"], STEP, distinguish_bic=-1.0)


@pytest.mark.slow
def test_backward_check_drops_an_effect_that_a_later_one_made_redundant():
    # A challenge-benchmark log (seed 3580810742: a random smooth path, angle harmonics at 3x
    # their own threshold), its draws replayed as challenge_residuals._make_log makes them.
    # Forward selection takes a scale mismatch first, then the harmonic, whose once-per-turn
    # term also carries the slope; refitted without the scale the final model loses less than
    # the criterion, so the scale goes. The harmonic's step-2 addition moves the angle by less
    # than the default practical size (the scale already carries most of it): the practical
    # size is switched off here so the backward check itself is what is tested.
    rng = np.random.default_rng(3580810742)
    duration = float(rng.uniform(10.0, 15.0))
    kind = str(rng.choice(["sine", "multisine", "smooth"]))
    amplitude = float(rng.uniform(0.5, 3.0))
    centre = float(rng.uniform(-np.pi, np.pi))
    motion = random_motion(rng, kind, duration, amplitude, centre)
    rng.choice([-1.0, 1.0])
    p1, p2 = rng.uniform(0, 2 * np.pi, 2)
    a1, a2 = 0.5 * STEP * 0.2927746000827006, 0.2 * STEP * 0.2927746000827006
    eff = {"a1": a1 * math.sin(p1), "b1": a1 * math.cos(p1), "a2": a2 * math.sin(p2), "b2": a2 * math.cos(p2)}
    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP,
                       effects={"angle_harmonics": eff})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         line_pitch=16 * STEP, min_effect_floor_fraction=0.0)
    picked = [r["effect"] for r in res.steps if r.get("delta_heldout", -1.0) > 0]
    assert picked == ["scale_mismatch", "angle_harmonics"]
    (dropped,) = [r for r in res.steps if r["step"] == "backward"]
    assert dropped["effect"] == "scale_mismatch" and dropped["delta_bic"] <= 10.0
    assert [e.name for e in res.effects] == ["angle_harmonics"]
    assert res.effects[0].delta_bic_final > 10.0 and res.explained


def test_missed_counts_and_wrap_are_found():
    log = _log(5, {"missed_counts": {"times": [3.0], "jumps": [2]}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["missed_counts"]
    assert res.effects[0].params["n_1"] == 2
    assert res.effects[0].params["t_1"] == pytest.approx(3.0, abs=0.05)

    rng = np.random.default_rng(6)
    log = simulate_log(rng, lambda t: 2.8 + 1.0 * np.sin(2 * np.pi * 0.7 * t), duration=5.0, step=STEP,
                       truth_step=TRUTH_STEP, effects={"wrap_around": {"period": 2 * np.pi}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["wrap_around"]
    assert res.effects[0].params["period"] == 2 * np.pi
    assert res.explained


def test_summary_block_and_prediction():
    log = _log(8, {"latency": {"tau": 1e-3}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    block = json.loads(json.dumps(res.to_summary()))
    assert set(block) >= {"metric", "before", "after", "effects"}
    assert block["effects"][0]["name"] == "latency"
    assert set(block["effects"][0]) >= {"name", "params", "ci", "delta_bic"}
    pred = res.model_prediction()
    r = log["measured"] - pred
    assert np.std(r) == pytest.approx(res.after["std"])
    # the same model applied to the same trajectory through the public arguments
    np.testing.assert_allclose(res.model_prediction(log["t"], log["truth"]), pred)


def test_truth_step_is_estimated_from_the_truth_grid():
    log = _log(9)
    assert grid_step(log["truth"]) == pytest.approx(TRUTH_STEP, rel=1e-9)
    assert grid_step(np.sin(np.linspace(0, 1, 100))) == 0.0


# ------------------------------------------------------------------------ input errors
def test_bad_inputs_name_the_row():
    t = np.arange(100) / 1000.0
    truth = np.zeros(100)
    meas = np.zeros(100)
    t_bad = t.copy()
    t_bad[40] = t_bad[39]
    with pytest.raises(ValueError, match="row 40"):
        select_effects(t_bad, truth, meas, STEP)
    truth_bad = truth.copy()
    truth_bad[7] = np.nan
    with pytest.raises(ValueError, match="truth.*row 7"):
        select_effects(t, truth_bad, meas, STEP)
    meas_bad = meas + np.where(np.arange(100) >= 50, 0.3 * STEP, 0.0)
    with pytest.raises(ValueError, match="not on a grid"):
        select_effects(t, truth, meas_bad, STEP)
    with pytest.raises(ValueError, match="unknown candidate"):
        select_effects(t, truth, meas, STEP, candidates=["gremlins"])


def test_long_log_is_fitted_on_a_subsample_with_full_statistics(monkeypatch):
    monkeypatch.setattr(sel, "_MAX_FIT_SAMPLES", 2000)
    log = _log(12, {"latency": {"tau": 1e-3}}, duration=6.0)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects][0] == "latency"
    assert res.effects[0].params["tau"] == pytest.approx(1e-3, rel=0.05)
    # the statistics are of the full log
    assert np.std(log["measured"] - res.model_prediction()) == pytest.approx(res.after["std"])
    assert res.model_prediction().size == log["t"].size


def test_flickering_truth_keeps_its_direction_through_a_dwell():
    t = np.arange(600) / 1000.0
    ramp = np.concatenate([np.linspace(0, 0.1, 200), np.full(200, 0.1), np.linspace(0.1, 0.2, 200)])
    truth = TRUTH_STEP * np.round(ramp / TRUTH_STEP)
    rng = np.random.default_rng(0)
    truth[200:400] += TRUTH_STEP * rng.integers(-1, 2, 200)  # one-count flicker while at rest
    ctx = sel._make_ctx(t, truth, np.zeros(600, np.int64), STEP, TRUTH_STEP, {}, 0.0, None)
    assert np.all(ctx.priv["_motion_sign"][20:580] == 1)
    # a clean quantized truth gets no dead zone: the direction flips at the reversal itself
    tri = TRUTH_STEP * np.round(np.concatenate([np.linspace(0, 0.1, 300), np.linspace(0.1, 0, 300)]) / TRUTH_STEP)
    ctx = sel._make_ctx(t, tri, np.zeros(600, np.int64), STEP, TRUTH_STEP, {}, 0.0, None)
    flip = np.flatnonzero(np.diff(ctx.priv["_motion_sign"]) != 0)
    assert flip.size == 1 and abs(int(flip[0]) - 299) <= 2


def test_message_names_effects_whose_interval_spans_their_range():
    from enclab.residuals.select import FittedEffect, _message
    pinned = FittedEffect("backlash", {"w": 0.027}, {"w": (0.0267, 0.0273)}, 5e4, 10.0,
                          derived={"confounded": 0.0})
    loose = FittedEffect("scale_mismatch", {"g": 0.1}, {"g": (-0.1, 0.1)}, 600.0, 1.0,
                         derived={"confounded": 1.0})
    before = {"std": 1.0, "floor_ci": (0.1, 0.2)}
    msg = _message([pinned, loose], False, before)
    assert "scale_mismatch not pinned down" in msg and "backlash not" not in msg
    assert "not pinned down" not in _message([pinned], True, before)


def test_message_says_unexplained_and_names_indistinguishable_alternatives():
    from enclab.residuals.select import FittedEffect, _message
    alts = [{"name": "backlash", "delta_bic": 1.7, "params": {"w": 1e-4}},
            {"name": "latency", "delta_bic": 25.0, "params": {"tau": 1e-4}}]
    e = FittedEffect("hysteresis", {"h": 1e-4}, {"h": (0.9e-4, 1.1e-4)}, 60.0, 5.0, alternatives=alts)
    assert [a["name"] for a in e.indistinguishable] == ["backlash"]
    before = {"std": 1.0e-3, "floor_std": 1e-4, "floor_ci": (0.9e-4, 1.1e-4)}
    after = {"std": 1.8e-3 / 2, "floor_std": 1e-4, "floor_ci": (0.9e-4, 1.1e-4)}
    msg = _message([e], False, before, after)
    assert "the rest is unexplained" in msg and "9x the exact-model floor" in msg
    assert "hysteresis not distinguishable from backlash (swap-in delta BIC 1.7)" in msg
    assert "latency" not in msg
    # A reduced form that reads the log better than the pick says so.
    better = [{"name": "slow_drift", "delta_bic": -4.2, "params": {"c1": 1e-3}, "form": "linear"}]
    e = FittedEffect("scale_mismatch", {"g": 4e-5}, {"g": (3.9e-5, 4.1e-5)}, 80.0, 9.0,
                     alternatives=better)
    assert ("scale_mismatch not distinguishable from slow_drift (linear; swap-in delta BIC -4.2: "
            "reads the log better)") in _message([e], True, before, after)
    assert e.to_dict()["indistinguishable_from"][0]["form"] == "linear"
    assert _message([], False, before).startswith("unexplained: the residual std 0.001 rad is 10x")


# ------------------------------------------------------------ compliance, map, merge, floor
def test_softening_compliance_is_found_with_its_values():
    rng = np.random.default_rng(8)
    duration = 6.0
    motion = random_motion(rng, "multisine", duration, 1.0)
    t = np.arange(int(duration * 1000)) / 1000.0
    torque = random_torque(rng, motion, t, 3.0)
    k1 = 4e-3 / 3.0
    k2 = -0.4 * k1 / 3.0   # the play taken up gradually: 40 % less twist at the peak torque
    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP,
                       effects={"compliance_softening": {"k1": k1, "k2": k2}}, torque=torque)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         aux={"torque": torque})
    assert [e.name for e in res.effects] == ["compliance_softening"]
    (e,) = res.effects
    for name, true in (("k1", k1), ("k2", k2)):
        lo, hi = e.ci[name]
        se = (hi - lo) / (2 * Z90)
        assert abs(e.params[name] - true) <= 4 * se and se < 0.2 * abs(true)
    assert e.derived["softening"] > 0   # k2 opposite to k1
    # a straight line in the torque loses by more than the margin
    assert {a["name"] for a in e.alternatives} >= {"compliance"}
    assert e.indistinguishable == []
    assert res.explained


def test_calibration_map_is_found_and_matches_the_true_map():
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(12)
    duration = 8.0
    motion = random_motion(rng, "sine", duration, 0.5)
    t = np.arange(int(duration * 1000)) / 1000.0
    th = motion(t)
    m = random_map(rng, float(th.min()), float(th.max()), 3e-3, float(np.ptp(th)) / 6)
    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP,
                       effects={"calibration_map": m})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["calibration_map"]
    assert res.after["std"] < 0.5 * res.before["std"]
    e = next(x for x in res._fitted.model.effects if x.name == "calibration_map")
    # against the simulated map over the stroke, both without constant and slope (a quantizer
    # offset and a scale): the fitted curve is within a tenth of a count
    grid = np.linspace(th.min() + 0.02, th.max() - 0.02, 500)
    true = CubicSpline(m["knots"], m["values"])(grid)
    fit = e.curve(res.effects[0].params, grid)
    diff = true - fit
    diff = diff - np.polyval(np.polyfit(grid, diff, 1), grid)
    assert np.sqrt(np.mean(diff**2)) < 0.1 * STEP


def test_multiple_correlation_is_the_correlation_for_single_parameters_and_sees_spans():
    rng = np.random.default_rng(3)
    # estimates of (a, b1, b2) whose covariance makes a nearly b1 + b2: no single pair shows it
    z = rng.normal(size=(3, 4000))
    est = np.vstack([z[1] + z[2] + 0.05 * z[0], z[1], z[2]])
    cov = np.cov(est)
    r_pair = [abs(np.corrcoef(est[0], est[j])[0, 1]) for j in (1, 2)]
    assert max(r_pair) < 0.8
    r = sel._multiple_correlation(cov, slice(0, 1), slice(1, 3))
    # R^2 = 1 - var(0.05 z0) / var(a)
    assert r == pytest.approx(math.sqrt(1 - 0.05**2 / (2 + 0.05**2)), abs=2e-3)
    assert sel._multiple_correlation(cov, slice(1, 2), slice(0, 1)) == pytest.approx(r_pair[0], rel=1e-9)


def test_linear_columns_give_the_finite_difference_gradient():
    rng = np.random.default_rng(5)
    log = _log(5, duration=3.0, amplitude=0.8)
    counts = np.round(log["measured"] / STEP).astype(np.int64)
    torque = rng.normal(size=log["t"].size)
    ctx = sel._make_ctx(log["t"], log["truth"], counts, STEP, TRUTH_STEP, {"torque": torque}, 0.0, None)
    cmap = sel.fx.CalibrationMap()
    cmap._set_basis(float(ctx.truth.min()), float(ctx.truth.max()), 0.2)
    effects = [sel.fx.SofteningCompliance(), cmap, sel.fx.SlowDrift()]
    for e in effects:
        assert e.applicable(ctx)
    model = sel._Model(effects)
    x = np.concatenate([[0.5, -1.0], rng.normal(0, 1e-4, model.size - 2)])
    scales = model.scales(ctx)
    assert set(model.linear_columns(ctx)) == set(range(2, 4)) | set(range(4, 4 + len(cmap.param_names)))
    _, g = sel._scores(model, ctx, x, scales, ctx.fit_idx)
    model.linear_columns = lambda ctx: {}
    _, g_fd = sel._scores(model, ctx, x, scales, ctx.fit_idx)
    # A forward difference of a shift exactly linear in x_j differs from the exact column only
    # by the rounding of mu_p - mu: 2 eps |mu| <= 2.3e-13 counts (|mu| <= 522) against a change
    # of 1e-4 scale_j |dmu/dx_j| >= 5e-5 counts where the column is not near zero: < 5e-9
    # relative (4e-9 seen); samples where it is near zero fall under atol. A wrong exact
    # column is wrong by O(1): rtol=1e-5 keeps a wide margin above rounding.
    np.testing.assert_allclose(g, g_fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(g_fd)))


def test_floor_interval_counts_a_repeated_pass_once():
    # A log that passes the same angles three times (its first 3 s repeated exactly) holds no
    # more information about the floor than the first pass: the truth's rounding flips the same
    # samples each time. The floor is the same and so is its standard error (the time blocks
    # alone gave 1/sqrt(3) of it).
    log = _log(9, duration=3.0, amplitude=0.8, kind="multisine")
    counts = np.round(log["measured"] / STEP).astype(np.int64)
    n = log["t"].size
    out = {}
    for k in (1, 3):
        t = np.arange(k * n) / 1000.0
        ctx = sel._make_ctx(t, np.tile(log["truth"], k), np.tile(counts, k), STEP, TRUTH_STEP, {}, 0.0, None)
        model = sel._Model([])
        x, ll = sel._fit(model, ctx, sel._base_start(ctx))
        out[k] = sel.residual_stats(sel._Fitted(model, x, ll), ctx)
    # Each fit is an L-BFGS-B optimum, which stops at a relative decrease of ftol = 2.2e-9
    # (scipy's factr 1e7 times eps): with -loglik |f| = 2.3 (7.0 tiled) and its curvature in
    # the offset H = 2.3e6 (7.0e6) per count, the offset lies within sqrt(2 ftol |f| / H) =
    # 6.6e-8 counts of the optimum in both fits, and the floor moves by 1.1e4 (relative) per
    # count of offset: 7e-4 per fit, 1.4e-3 for the two; rel=2e-3. Rounding decides where
    # within that the optimizer stops (2e-6 apart on one machine, 1e-12 on another).
    assert out[3]["floor_std"] == pytest.approx(out[1]["floor_std"], rel=2e-3)
    assert out[3]["std"] == pytest.approx(out[1]["std"], rel=2e-3)
    half_width = {k: out[k]["floor_limit"] ** 2 - out[k]["floor_std"] ** 2 for k in (1, 3)}
    assert half_width[3] == pytest.approx(half_width[1], rel=0.1)


# ------------------------------------------------------------------------ any length
def _bench_log(n, seed, h=None):
    """The residual-length benchmark's logs (workflow/benchmarks/residual_length.py)."""
    rng = np.random.default_rng([seed, n])
    kind = ("sine", "multisine", "smooth")[seed % 3]
    motion = random_motion(rng, kind, n / 1000.0, rng.uniform(0.3, 1.0))
    return simulate_log(rng, motion, duration=n / 1000.0, step=STEP, truth_step=TRUTH_STEP,
                        effects={"hysteresis": {"h": h}} if h else {})


def test_clean_periodic_log_whose_dwells_fake_a_map_gets_no_effect():
    # A 4 s sine: every turning point dwells on the same truth readings each cycle, whose shared
    # rounding errors the per-sample likelihood counts as independent (plain delta BIC 47 for a
    # calibration map, confirmed on held-out blocks that dwell on the same readings). Grouped by
    # truth reading, the map's score varies 1.4 times more than independent samples would let
    # it: its calibrated delta BIC falls below the criterion.
    log = _bench_log(4000, 0)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert res.effects == [] and res.explained
    (tried,) = [r for r in res.steps if r["effect"] == "calibration_map"]
    assert tried["delta_bic"] > 10.0 and tried["inflation"] > 1.0
    assert tried["delta_bic_calibrated"] <= 10.0 and tried["rejected"] == "calibrated evidence"
    assert res.heldout["before"]["std"] == res.heldout["after"]["std"]


def test_inflation_counts_samples_that_share_one_truth_reading_once():
    # The same clean log with every sample repeated m = 4 times (at 4 kHz: four samples on one
    # truth reading and one rounding error each time) carries the evidence of the original,
    # not four times it: its score sums per unit are m times larger, so the inflation c is m
    # times the original's and the calibrated LR, 2 dll / c, is unchanged. Tolerance: c from
    # 40 blocks has a relative sampling error of about sqrt(2/40) = 0.22 (3 of them), though
    # the repeats move it far less.
    log = _log(3, duration=3.0)
    for e in (sel.fx.Hysteresis(), sel.fx.ScaleMismatch()):
        out = []
        for m in (1, 4):
            tr, ct = np.repeat(log["truth"], m), np.repeat(log["counts"], m)
            ctx = sel._make_ctx(np.arange(tr.size) / (1000.0 * m), tr, ct, STEP, TRUTH_STEP, {}, 0.0, None)
            base = sel._Model([])
            x, ll = sel._fit(base, ctx, sel._base_start(ctx))
            new = sel._extend(sel._Fitted(base, x, ll), e, ctx)
            out.append((sel._inflation(new, e, ctx), 2.0 * (new.ll - ll)))
        (c1, lr1), (c4, lr4) = out
        assert c1 > 1.0  # a 1 kHz sine: neighbouring samples share their truth reading
        assert c4 / c1 == pytest.approx(4.0, rel=3 * 0.22)
        assert lr4 / c4 == pytest.approx(lr1 / c1, rel=3 * 0.22, abs=1.0)


def test_practical_size_keeps_a_real_but_small_effect_out():
    # A dead band of 0.6 step moves the angle by h/2 = 0.3 step rms: found by default, and left
    # out when the practical size asked for is above that (min_effect_rad).
    log = _log(21, {"hysteresis": {"h": 0.6 * STEP}}, duration=8.0)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["hysteresis"]
    assert res.effects[0].size == pytest.approx(0.3 * STEP, rel=0.1)  # +-h/2 with the sign of motion
    big = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         min_effect_rad=0.5 * STEP)
    assert big.effects == [] and big.practical_size == 0.5 * STEP
    assert any(r.get("rejected", "").startswith("practical size") for r in big.steps)


def test_no_chosen_effect_leaves_the_residual_worse_and_heldout_is_reported():
    # the hard invariant over clean and effect logs of the benchmark's kinds; the held-out
    # figures of a found effect improve on their base model's
    for n, seed, h in ((4000, 0, None), (4000, 1, None), (4000, 2, 0.15 * STEP), (4000, 3, -0.15 * STEP)):
        log = _bench_log(n, seed, h)
        res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
        assert res.after["std"] <= res.before["std"]
        summary = res.to_summary()
        assert summary["heldout_before"]["std"] > 0 and summary["heldout_after"]["std"] > 0
        if res.effects:
            assert summary["heldout"]["improves"] and summary["heldout_after"]["std"] < summary["heldout_before"]["std"]


def test_a_play_and_a_dead_band_that_cancel_are_not_chosen_together():
    # backlash +w and hysteresis -w: after the play is taken up each shifts the angle by w/2
    # against / with the direction of motion, together by nothing
    log = _log(21, duration=6.0)
    grid, counts = sel._grid_and_counts(log["measured"], STEP)
    ctx = sel._make_ctx(log["t"], log["truth"], counts, STEP, TRUTH_STEP, {}, grid, None)
    b, hy = sel.fx.Backlash(), sel.fx.Hysteresis()
    model = sel._Model([b, hy])
    w = 3 * STEP
    x = np.zeros(model.size)
    x[model.slices[model.effects.index(b)]] = w
    x[model.slices[model.effects.index(hy)]] = -w
    cur = sel._Fitted(model, x, 0.0)
    chosen = [(b, 50.0, 1.0, 0.0), (hy, 40.0, 1.0, 0.0)]
    trial = [(50.0, 0, None, sel._shift_rms(sel._without(cur, b), cur, ctx)),
             (40.0, 1, None, sel._shift_rms(sel._without(cur, hy), cur, ctx))]
    assert trial[0][3] == pytest.approx(w / 2, rel=0.1) and trial[1][3] == pytest.approx(w / 2, rel=0.05)
    weak, other = sel._cancelling_pair(cur, chosen, trial, ctx)
    assert weak[1] == 1 and other == "backlash"
    # a dead band of +w beside the play adds to it: no cancelling pair
    x[model.slices[model.effects.index(hy)]] = w
    assert sel._cancelling_pair(sel._Fitted(model, x, 0.0), chosen, trial, ctx) is None


def test_a_lagging_start_is_cropped_and_reported_not_modelled():
    # the measured channel creeps up to the angle over its first 30 samples (8 steps behind at
    # first); the rest of the log holds a 1 ms latency
    log = _log(5, {"latency": {"tau": 1e-3}}, duration=6.0)
    m = log["measured"].copy()
    m[:30] = m[0] - 8 * STEP * np.linspace(1.0, 0.0, 30)
    res = select_effects(log["t"], log["truth"], m, STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["latency"]
    (tr,) = res.transients
    assert tr["edge"] == "start" and tr["n_samples"] == 30 and tr["t_end"] == pytest.approx(0.029)
    assert res.kept == slice(30, log["t"].size) and res.model_prediction().size == log["t"].size - 30
    assert "transient at the start of the log (0-0.029 s, 30 samples) was cropped" in res.message
    clean = _log(5, duration=6.0)
    assert select_effects(clean["t"], clean["truth"], clean["measured"], STEP, truth_step=TRUTH_STEP).transients == []


def test_an_effect_of_one_part_of_the_log_that_worsens_the_heldout_error_is_dropped():
    # a dead band in the even tenths of the log only: over the whole log it reads as a dead band
    # of about half the width, but fitted on the even tenths (held-out training) it predicts a
    # full band where there is none, so the held-out std rises above the offset-only model's
    def log(effects):
        rng = np.random.default_rng(1)
        motion = random_motion(rng, "sine", 6.0, 0.5)
        return simulate_log(rng, motion, duration=6.0, step=STEP, truth_step=TRUTH_STEP, effects=effects)
    clean, banded = log({}), log({"hysteresis": {"h": 0.6 * STEP}})
    assert np.array_equal(clean["truth"], banded["truth"])
    t = clean["t"]
    tenth = np.minimum((10 * (t - t[0]) / (t[-1] - t[0])).astype(int), 9)
    measured = np.where(tenth % 2 == 0, banded["measured"], clean["measured"])
    res = select_effects(t, clean["truth"], measured, STEP, truth_step=TRUTH_STEP)
    dropped = [s for s in res.steps if s.get("step") == "heldout"]
    assert [s["effect"] for s in dropped] == ["hysteresis"]
    summary = res.to_summary()
    assert summary["heldout_after"]["std"] <= summary["heldout_before"]["std"]
    assert not res.explained


def test_line_pitch_harmonics_are_found_with_their_values():
    pitch = 16 * STEP
    a, b = 0.25 * STEP, -0.15 * STEP
    rng = np.random.default_rng(31)
    log = simulate_log(rng, random_motion(rng, "sine", 6.0, 0.5), duration=6.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"line_pitch_harmonics": {"a": a, "b": b, "pitch": pitch}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         candidates=["line_pitch_harmonics", "hysteresis"], line_pitch=pitch)
    assert [e.name for e in res.effects] == ["line_pitch_harmonics"]
    (e,) = res.effects
    for name, true in (("a", a), ("b", b)):
        lo, hi = e.ci[name]
        se = (hi - lo) / (2 * Z90)
        assert abs(e.params[name] - true) <= 4 * se and se < 0.2 * abs(true)


def test_timestamp_jitter_is_found_with_its_value():
    sigma_t = 3e-4
    log = _log(32, {"timestamp_jitter": {"sigma_t": sigma_t}}, duration=6.0)
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP,
                         candidates=["timestamp_jitter", "latency"])
    assert [e.name for e in res.effects] == ["timestamp_jitter"]
    (e,) = res.effects
    lo, hi = e.ci["sigma_t"]
    assert lo <= sigma_t <= hi and hi - lo < 0.5 * sigma_t

