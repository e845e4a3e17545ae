"""Residual stage on logs where the one true effect must be found and credited: rotating axes,
large latencies, missed counts close together, a slow drift; and the bounds of every effect."""
from __future__ import annotations

import numpy as np
import pytest

from enclab.core.ingest import grid_step
from enclab.residuals import effects as fx
from enclab.residuals import select as sel
from enclab.residuals.select import select_effects
from enclab.residuals.simulate import random_motion, simulate_log

STEP = 2 * np.pi / 4096
TRUTH_STEP = STEP / 8


def _nine_digits(x):
    """Values as a CSV written with 9 significant digits holds them."""
    return np.array([float(f"{v:.9g}") for v in x])


def test_grid_step_of_a_rotating_axis_whose_jumps_are_32_or_33_steps():
    t = np.arange(10_000) / 1000.0
    x = TRUTH_STEP * np.round((0.3 + 2 * np.pi * t) / TRUTH_STEP)
    d = np.round(np.abs(np.diff(x)) / TRUTH_STEP)
    assert set(np.unique(d)) == {32.0, 33.0}  # no jump of one step: the smallest jump is not the step
    assert grid_step(x) == pytest.approx(TRUTH_STEP, rel=1e-9)
    # 9 significant digits of values up to 63 rad: |e| <= 5e-8 rad per value. The least-squares
    # step sum(k d) / sum(k^2) over jumps of k = 32 or 33 steps telescopes the errors except
    # where k changes: |error| <= 5e-8 (n + 66) / (n 32^2) = 4.9e-11 rad = 2.6e-7 relative
    assert grid_step(_nine_digits(x)) == pytest.approx(TRUTH_STEP, rel=1e-6)
    assert grid_step(np.sin(t) + 60.0) == 0.0


def test_rotating_axis_with_a_scale_error_is_explained_against_a_non_zero_floor():
    rng = np.random.default_rng(3)
    g = 1e-3
    log = simulate_log(rng, lambda t: 0.3 + 2 * np.pi * np.asarray(t), duration=10.0, step=STEP,
                       truth_step=TRUTH_STEP, effects={"scale_mismatch": {"g": g}})
    res = select_effects(log["t"], _nine_digits(log["truth"]), log["measured"], STEP, truth_step=None)
    # the floor of a 1/8-step truth: sqrt(step * truth_step / 4)
    assert res.after["floor_std"] == pytest.approx(np.sqrt(STEP * TRUTH_STEP / 4), rel=0.1)
    assert [e.name for e in res.effects] == ["scale_mismatch"]
    lo, hi = res.effects[0].ci["g"]
    assert lo <= g <= hi
    assert res.explained and "explains" in res.message


def test_latency_is_the_delayed_sample_itself():
    rng = np.random.default_rng(0)
    motion = random_motion(rng, "sine", 5.0, 1.0)
    t = np.arange(5000) / 1000.0
    theta = motion(t)
    ctx = sel._make_ctx(t, theta, np.zeros(t.size, np.int64), STEP, 0.0, {}, 0.0, None)
    aux = {**ctx.priv, "_offset": 0.0}
    tau = 1.7e-3
    got = fx.Latency().apply(theta, t, ctx.velocity, aux, np.array([tau]))
    inner = slice(10, -10)  # the cubic spline's end conditions are not the motion's
    # the curvature term tau^2 a / 2 is kept: the error is the spline's, not first order's
    first_order = theta - tau * ctx.velocity
    exact = motion(t - tau)
    assert np.max(np.abs(got - exact)[inner]) < 1e-9
    assert np.max(np.abs(first_order - exact)[inner]) > 1e-5


@pytest.mark.parametrize("seed", [1])
def test_a_large_latency_found_with_its_value_is_explained_without_jitter(seed):
    rng = np.random.default_rng(seed)
    motion = random_motion(rng, "sine", 10.0, 1.0)
    tau = 1.7e-3
    log = simulate_log(rng, motion, duration=10.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"latency": {"tau": tau}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["latency"]
    lo, hi = res.effects[0].ci["tau"]
    assert lo <= tau <= hi
    assert res.explained
    # the floor is the exact model's: no fitted noise inflates it above the residual
    assert res.after["std"] / res.after["floor_std"] > 0.9


def test_missed_counts_close_together_are_each_found():
    rng = np.random.default_rng(1)
    motion = random_motion(rng, "multisine", 12.0, 1.0)
    times, jumps = [4.0, 4.6, 5.3, 6.0], [1, 1, -1, 1]
    log = simulate_log(rng, motion, duration=12.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"missed_counts": {"times": times, "jumps": jumps}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["missed_counts"]
    p = res.effects[0].params
    assert [p[f"n_{j + 1}"] for j in range(4)] == jumps
    # each change within a few samples of its time: next to a change, a sample whose reading
    # flips with the truth's own rounding (3 % of samples) belongs to either side
    assert np.allclose([p[f"t_{j + 1}"] for j in range(4)], times, atol=5e-3)
    assert res.explained


def test_missed_count_detector_on_an_integer_residual_with_isolated_flips():
    rng = np.random.default_rng(2)
    t = np.arange(3000) / 1000.0
    r = np.zeros(t.size) + 0.45  # a level off the integers by nearly half a count
    r[t >= 1.0] += 2
    r[t >= 1.3] -= 1
    flips = rng.random(t.size) < 0.03
    r[flips] += rng.choice([-1.0, 1.0], flips.sum())
    times, jumps = fx.MissedCounts.detect(t, r + rng.uniform(-0.3, 0.3, t.size))
    assert jumps == [-2, 1] and np.allclose(times, [1.0, 1.3], atol=1.5e-3)
    # a residual that follows the direction of motion is no missed count
    assert fx.MissedCounts.detect(t, 0.5 * np.sign(np.sin(2 * np.pi * 3 * t)) + 0.2) == ([], [])


def test_a_slow_drift_is_a_drift_not_a_staircase_of_missed_counts():
    rng = np.random.default_rng(1)
    motion = random_motion(rng, "multisine", 20.0, 1.0)
    rate = 0.2e-3  # rad/s: 2.6 steps of 4096 cpr over the log
    log = simulate_log(rng, motion, duration=20.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"slow_drift": {"rate": rate}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["slow_drift"]
    e = res.effects[0]
    # c1 = rate T / 2 for a linear drift over T = 20 s; the uniform count noise averages out
    # over 2e4 samples to well under 1 % of a step
    assert e.params["c1"] == pytest.approx(rate * (log["t"][-1] - log["t"][0]) / 2, abs=0.02 * STEP)
    assert e.derived["mean_rate"] == pytest.approx(rate, rel=0.05)
    assert res.explained


def test_slow_drift_apply_matches_its_legendre_definition():
    t = np.linspace(2.0, 12.0, 101)
    aux = {"_t_range": (2.0, 12.0)}
    d = fx.SlowDrift()
    s = (t - 7.0) / 5.0
    got = d.apply(np.zeros(t.size), t, None, aux, np.array([1.0, 2.0, 3.0]))
    want = 1.0 * s + 2.0 * 0.5 * (3 * s**2 - 1) + 3.0 * 0.5 * (5 * s**3 - 3 * s)
    assert np.allclose(got, want, atol=1e-12)
    # The reduced form is the linear term alone.
    linear = d.reduced()
    assert linear.param_names == ("c1",) and linear.reduced() is None
    assert np.allclose(linear.apply(np.zeros(t.size), t, None, aux, np.array([1.0])), s, atol=1e-12)
    assert linear.derived({"c1": 1.0})["peak_to_peak"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="degree"):
        fx.SlowDrift(degree=4)


def test_on_a_steadily_rotating_axis_a_linear_drift_is_named_beside_a_scale():
    """The angle of a steady rotation is a ramp in time: a linear drift of the reading and a
    scale mismatch read the log alike. Whichever is chosen, the other is reported as not
    distinguishable; the drift in its linear form (the three-term form loses by its two
    extra parameters' BIC penalty alone)."""
    rng = np.random.default_rng(0)
    rate, duration = 2e-4, 10.0

    def motion(t):
        return 0.3 + 2 * np.pi * (0.8 * t + 0.01 * np.sin(np.pi * t))

    log = simulate_log(rng, motion, duration=duration, step=STEP, truth_step=TRUTH_STEP,
                       effects={"slow_drift": {"rate": rate, "quad": 0.0}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    (e,) = res.effects
    assert e.name in ("scale_mismatch", "slow_drift")
    if e.name == "scale_mismatch":
        (alt,) = [a for a in e.indistinguishable if a["name"] == "slow_drift"]
        assert set(alt["params"]) == {"c1"} and alt["form"] == "linear"
        assert "slow_drift (linear; swap-in delta BIC" in res.message
        assert alt["params"]["c1"] == pytest.approx(rate * duration / 2, rel=0.05)
    else:
        assert "scale_mismatch" in [a["name"] for a in e.indistinguishable]


def test_every_effect_has_a_range_that_holds_its_null():
    rng = np.random.default_rng(0)
    log = simulate_log(rng, random_motion(rng, "sine", 2.0, 1.0), duration=2.0, step=STEP, truth_step=TRUTH_STEP)
    counts = np.round(log["measured"] / STEP).astype(np.int64)
    torque = np.sin(log["t"])
    ctx = sel._make_ctx(log["t"], log["truth"], counts, STEP, TRUTH_STEP, {"torque": torque}, 0.0, 16 * STEP)
    for cls in fx.EFFECTS:
        if cls.kind == "discrete":
            continue
        e = cls()
        if not e.applicable(ctx):
            continue
        b = e.bounds(ctx)
        assert len(b) == len(e.param_names), cls.name
        for (lo, hi), p0, name in zip(b, e.null(), e.param_names):
            assert np.isfinite(lo) and np.isfinite(hi) and lo < hi, (cls.name, name)
            assert lo <= p0 <= hi, (cls.name, name)
            if name in e.boundary:  # a standard deviation: never negative
                assert lo == 0.0


# ------------------------------------------------------------------ outside the catalogue
def test_heldout_share_matches_the_variance_fraction_of_a_smooth_function():
    from enclab.residuals import diagnostics as dg

    rng = np.random.default_rng(4)
    n = 20_000
    x = rng.uniform(-1, 1, n)
    f, sigma = np.sin(2 * x), 0.3
    r = f + rng.normal(0, sigma, n)
    want = f.var() / (f.var() + sigma**2)
    # binned means over 16 bins leave ~ var(f') * width^2 / 12 of f unfitted: << sigma^2 here;
    # the held-out share's sampling error is ~ 1 / sqrt(n)
    assert dg.heldout_share(x, r) == pytest.approx(want, abs=0.02)
    assert dg.heldout_share(rng.uniform(-1, 1, n), r) < 0.01  # an unrelated covariate


def test_ranking_names_time_for_a_drift_and_says_it_in_words():
    from enclab.residuals import diagnostics as dg

    rng = np.random.default_rng(5)
    t = np.arange(20_000) / 1000.0
    truth = np.sin(2 * np.pi * 0.7 * t)
    r = 2e-4 * t + rng.uniform(-STEP / 2, STEP / 2, t.size) * 0.3
    ranking = dg.rank_covariates(r, dg.covariates_of(t, truth, {"torque": np.cos(t)}))
    assert ranking[0]["name"] == "time" and ranking[0]["share"] > 0.8
    assert {d["name"] for d in ranking} == {"time", "angle", "velocity", "acceleration", "direction", "torque"}
    text = dg.covariate_sentence(ranking)
    assert text.startswith("the rest follows time: ") and "a slow drift or creep" in text
    noise = dg.rank_covariates(rng.normal(size=t.size), dg.covariates_of(t, truth))
    assert dg.covariate_sentence(noise).startswith("the rest follows none of")


def test_unexplained_channel_says_what_the_rest_follows():
    import pandas as pd

    from enclab.residuals import pipeline

    rng = np.random.default_rng(1)
    motion = random_motion(rng, "multisine", 12.0, 1.0)
    log = simulate_log(rng, motion, duration=12.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"slow_drift": {"rate": 0.3e-3}})
    df = pd.DataFrame({"t": log["t"], "truth": np.round(log["truth"] / TRUTH_STEP).astype(np.int64),
                       "measured": log["counts"]})
    meta = {"log_id": "drift", "channels": [
        {"name": "truth", "role": "truth", "joint": 1, "storage": "counts", "step": TRUTH_STEP},
        {"name": "measured", "role": "measured", "joint": 1, "storage": "counts", "step": STEP}]}
    # the drift left out of the catalogue: the ranking must still point at time
    block, figures, _ = pipeline.analyse_channel(df, meta, {"measured": "measured", "truth": "truth"},
                                                 {"candidates": ["hysteresis", "latency"]})
    sel_ = block["selection"]
    assert not sel_["explained"]
    assert sel_["covariates"][0]["name"] == "time"
    assert sel_["outside_catalogue"].startswith("the rest follows time")
    assert sel_["outside_catalogue"] in sel_["message"]
    assert figures["covariates"].axes[0].get_xlabel() == "time"
    (row,) = pipeline.batch_rows({"log_id": "drift", "residuals": pipeline.summary_block([block])})
    assert row["outside_catalogue"] == sel_["outside_catalogue"] and row["verdict"].startswith("unexplained")


def test_merged_effects_are_printed_without_their_separate_values():
    from enclab.residuals import pipeline

    e = {"name": "scale_mismatch", "params": {"g": 0.1}, "ci": {"g": [-1.0, 1.0]}, "delta_bic": 50.0,
         "merged_with": ["angle_harmonics"], "derived": {"joint_peak_to_peak": 0.004}}
    text = pipeline.format_effects([e])
    assert text.startswith("scale_mismatch(merged with angle_harmonics: joint shift 0.004 rad")
    assert "g=" not in text


# ------------------------------------------------------------------ no meaningless numbers
def test_a_scale_and_a_harmonic_over_a_short_stroke_are_merged_into_their_joint_shift():
    rng = np.random.default_rng(0)
    motion = random_motion(rng, "sine", 10.0, 0.6, 0.7)  # a 1.2 rad stroke
    harm, g = {"a1": 3 * STEP, "b1": -2 * STEP, "a2": STEP}, 3e-3
    log = simulate_log(rng, motion, duration=10.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"angle_harmonics": harm, "scale_mismatch": {"g": g}})
    ctx = sel._make_ctx(log["t"], log["truth"], log["counts"], STEP, TRUTH_STEP, {}, 0.0, None)
    x, ll = sel._fit(sel._Model([]), ctx, sel._base_start(ctx))
    cur = sel._Fitted(sel._Model([]), x, ll)
    sc, ah = fx.ScaleMismatch(), fx.AngleHarmonics()
    cur = sel._extend(sel._extend(cur, sc, ctx), ah, ctx)
    _, cov = sel._intervals(cur, ctx, with_cov=True)
    fitted = [sel.FittedEffect(e.name, cur.model.params_of(cur.x, cur.model.effects.index(e)), {}, 0.0, 0.0)
              for e in (sc, ah)]
    sel._merge_confounded(fitted, [sc, ah], cur, cov, ctx)
    assert fitted[0].merged_with == ["angle_harmonics"] and fitted[1].merged_with == ["scale_mismatch"]
    # the joint shift is what the data determine: its peak to peak is the true one's
    th = log["theta"]
    te = th + g * (th - log["truth"].mean())
    true = te + harm["a1"] * np.cos(te) + harm["b1"] * np.sin(te) + harm["a2"] * np.cos(2 * te) - th
    assert fitted[0].derived["joint_peak_to_peak"] == pytest.approx(np.ptp(true), abs=0.02 * STEP)
    for f in fitted:
        f.separated_by = "a motion over a full turn or more"
    msg = sel._message(fitted, True, {"std": 1.0, "floor_ci": (0, 1)})
    assert "cannot be separated over this motion" in msg and "a motion over a full turn" in msg
    assert "g 0.00" not in msg and "a1" not in msg  # the separate values are not printed


def test_a_scale_over_a_short_stroke_carries_its_caveat():
    rng = np.random.default_rng(0)
    log = simulate_log(rng, random_motion(rng, "sine", 6.0, 0.4), duration=6.0, step=STEP, truth_step=TRUTH_STEP,
                       effects={"scale_mismatch": {"g": 2e-3}})
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert [e.name for e in res.effects] == ["scale_mismatch"]
    assert "mean slope of the angle error" in res.effects[0].caveat
    assert res.effects[0].to_dict()["caveat"] == res.effects[0].caveat
    assert "a motion over a full turn separates them" in res.message


def test_a_dwell_next_to_a_transition_is_no_missed_count():
    # a clean log whose motion stops for 60 ms a hair (a fifth of the truth's step) past a
    # transition of the measured grid: the truth reading, rounded, sits on the other side, so
    # the exact model misses all 60 samples together, a "missed count and its return"
    rng = np.random.default_rng(8)
    c = 0.37
    k = 40
    dwell = (k - c) * STEP + 0.2 * TRUTH_STEP
    t0, t1 = 3.0, 3.06

    def motion(t):
        t = np.asarray(t, dtype=float)
        tt = np.where(t < t0, t, np.where(t < t1, t0, t - (t1 - t0)))
        return dwell + 0.5 * np.sin(2 * np.pi * 0.4 * (tt - t0))

    log = simulate_log(rng, motion, duration=6.0, step=STEP, truth_step=TRUTH_STEP, offset_frac=c)
    ctx = sel._make_ctx(log["t"], log["truth"], log["counts"], STEP, TRUTH_STEP, {}, 0.0, None)
    x, _ = sel._fit(sel._Model([]), ctx, sel._base_start(ctx))
    mu, _ = sel._Model([]).forward(ctx, x)
    resid = ctx.counts - (mu - 0.5)
    assert fx.MissedCounts.detect(ctx.t, resid)[0]  # without the mask: a pulse of two changes
    res = select_effects(log["t"], log["truth"], log["measured"], STEP, truth_step=TRUTH_STEP)
    assert res.effects == [] and res.explained
