"""Rig fit (enclab.rig, with enclab.residuals.calibration) on small simulated rigs.

The simulated rig (``rig.simulate_rig``) has a known scale, calibration map, softening
compliance against two torques, and per-run play widths and latencies; the truth is read on the
MRDLab motor grid (0.0428 mrad) and the measured side on an 8192-cpr grid (0.767 mrad).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from enclab.residuals import calibration as cal
from enclab.rig import fit as rig

STEP = 2 * math.pi / 8192
TRUTH_STEP = 2 * math.pi / 146860
COMP = {"torque_back:linear": 0.09, "torque_back:signed_square": -0.9, "torque_front:linear": -0.2}
SPEC_COMP = {"torque_back": ["linear", "signed_square"], "torque_front": ["linear"]}
CONDS = [{"frequency_hz": f, "load": L} for f in (0.5, 0.75, 1.0) for L in (0.0, 0.3, 0.6)]


def true_map(y):
    return 0.003 * np.sin(2 * np.pi * y / 0.25) + 0.002 * np.cos(2 * np.pi * y / 0.6)


@pytest.fixture(scope="module")
def sim_rig():
    runs = rig.simulate_rig(np.random.default_rng(7), CONDS, step=STEP, truth_step=TRUTH_STEP,
                            scale=0.02, map_fn=true_map, compliance=COMP,
                            play_width=[0.02, 0.025, 0.03], latency=0.001)
    return runs


@pytest.fixture(scope="module")
def sim_fit(sim_rig):
    spec = rig.RigSpec(spacing=0.05, compliance=SPEC_COMP)
    return rig.fit_rig(sim_rig[:7], spec)


# ----------------------------------------------------------------------------- calibration


def test_map_basis_has_no_constant_or_linear_part_and_reproduces_splines():
    basis = cal.MapBasis(0.0, 1.0, 0.1)
    grid = np.linspace(0.0, 1.0, basis.n_grid)
    D = basis.design(grid)
    # 11 intervals of cubic B-splines: 13 functions, minus the constant and the slope
    assert D.shape[1] == len(basis.knots) - 4 - 2
    lin = np.column_stack([np.ones_like(grid), grid])
    assert np.max(np.abs(lin.T @ D)) < 1e-8 * grid.size
    # a cubic spline on these knots, with its constant and linear part removed, is reproduced
    rng = np.random.default_rng(0)
    from scipy.interpolate import BSpline

    spl = BSpline(basis.knots, rng.standard_normal(len(basis.knots) - 4), 3)(grid)
    c, *_ = np.linalg.lstsq(lin, spl, rcond=None)
    target = spl - lin @ c
    coef, *_ = np.linalg.lstsq(D, target, rcond=None)
    assert np.max(np.abs(basis.curve(coef, grid) - target)) < 1e-10
    # clamped outside the range
    assert np.allclose(basis.design([-1.0, 2.0]), basis.design([0.0, 1.0]))
    # a reference range: no linear part there, and no shape lost at the ends
    inner = cal.MapBasis(0.0, 1.0, 0.1, ref=(0.2, 0.8))
    ref = np.linspace(0.2, 0.8, inner.n_grid)
    Dr = inner.design(ref)
    assert inner.n_columns == D.shape[1]
    assert np.max(np.abs(np.column_stack([np.ones_like(ref), ref]).T @ Dr)) < 1e-8 * ref.size


def test_map_basis_rejects_bad_ranges():
    with pytest.raises(ValueError, match="lo < hi"):
        cal.MapBasis(1.0, 1.0, 0.1)
    with pytest.raises(ValueError, match="spacing"):
        cal.MapBasis(0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="reference range"):
        cal.MapBasis(0.0, 1.0, 0.1, ref=(-0.1, 0.5))


def test_map_basis_continues_along_its_end_slopes():
    b = cal.MapBasis(-1.0, 2.0, 0.5, extrapolate="linear")
    held = cal.MapBasis(-1.0, 2.0, 0.5)
    inside = np.linspace(-1.0, 2.0, 31)
    assert np.allclose(b.design(inside), held.design(inside))
    for end, out in ((-1.0, np.array([-1.0, -1.5, -2.0, -3.0])), (2.0, np.array([2.0, 2.5, 3.0, 4.0]))):
        D = b.design(out)
        slope = (D[1] - D[0]) / (out[1] - out[0])
        # linear beyond the end, with the slope of the spline at the end (one-sided difference)
        assert np.allclose(D, D[0] + np.outer(out - end, slope), atol=1e-9)
        near = end - 1e-6 * np.sign(end - 0.5)
        fd = (held.design([end])[0] - held.design([near])[0]) / (end - near)
        assert np.allclose(fd, slope, rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="extrapolation"):
        cal.MapBasis(0.0, 1.0, 0.1, extrapolate="cubic")


def test_compliance_columns_and_curve():
    T = np.array([-0.1, 0.0, 0.05])
    cols = cal.compliance_columns({"tb": ["linear", "signed_square"]}, {"tb": T})
    assert np.allclose(cols, np.column_stack([T, T * np.abs(T)]))
    assert np.allclose(cal.compliance_curve([0.09, -0.9], {"tb": ["linear", "signed_square"]}, "tb", T),
                       0.09 * T - 0.9 * T * np.abs(T))
    with pytest.raises(ValueError, match="cubic"):
        cal.compliance_names({"tb": ["cubic"]})
    with pytest.raises(ValueError, match="torque channel 'tf'"):
        cal.compliance_columns({"tf": ["linear"]}, {"tb": T})


# ----------------------------------------------------------------------------- masks, folds


def test_steady_mask_fraction_of_a_sine():
    # After a turning point of A sin, the travel A (1 - cos phi) exceeds d once
    # phi > arccos(1 - d / A): that fraction of each half cycle is missing.
    A, d, f = 0.5, 0.06, 0.5
    t = np.arange(0, 40.0, 1e-3)
    theta = A * np.sin(2 * np.pi * f * t)
    mask = rig.steady_mask(t, theta, travel=d, t_skip=2.0)
    expected = 1 - math.acos(1 - d / A) / math.pi
    assert mask[t >= 2.0].mean() == pytest.approx(expected, abs=2e-3)
    assert not mask[t < 2.0].any()


def test_make_folds_by_condition_and_leave_one_out(sim_rig):
    folds = rig.make_folds(sim_rig, [
        {"name": "freq", "by": "frequency_hz", "train": [0.5, 1.0], "test": [0.75]},
        {"name": "load", "by": "load"},
        {"name": "loro", "leave_one_run_out": True}])
    freq = [f for f in folds if f["split"] == "freq"]
    assert len(freq) == 1 and len(freq[0]["train"]) == 6 and len(freq[0]["test"]) == 3
    load = [f for f in folds if f["split"] == "load"]
    assert len(load) == 3 and all(len(f["test"]) == 3 and not set(f["test"]) & set(f["train"]) for f in load)
    loro = [f for f in folds if f["split"] == "loro"]
    assert len(loro) == len(sim_rig) and all(len(f["train"]) == len(sim_rig) - 1 for f in loro)
    with pytest.raises(ValueError, match="condition 'torque'"):
        rig.make_folds(sim_rig, [{"name": "x", "by": "torque"}])
    with pytest.raises(ValueError, match="no run with frequency_hz"):
        rig.make_folds(sim_rig, [{"by": "frequency_hz", "train": [9.0], "test": [0.5]}])


# ----------------------------------------------------------------------------- the fit


def test_per_run_effects_recovered(sim_fit):
    widths = [0.02, 0.025, 0.03]
    for i, run_id in enumerate(sim_fit.train_ids):
        per = sim_fit.per_run[run_id]
        # the reading is scaled by 1 + scale (+ the map's slope) relative to the output angle
        assert per["play_width"] == pytest.approx(widths[i % 3], rel=0.05)
        assert per["latency"] == pytest.approx(1e-3, rel=0.1)


def test_softening_compliance_recovered_within_its_interval(sim_fit):
    ci = sim_fit.ci()
    shared = sim_fit.shared()
    for name, true in COMP.items():
        lo, hi = ci[name]
        sd = (hi - lo) / (2 * 1.6449)
        # the delete-one-run jackknife is the error estimate: 3 sd (99.7 %) around the estimate
        assert abs(shared[name] - true) < 3 * sd, (name, shared[name], true, sd)
        # and the interval is informative: the sign of each term is pinned down
        assert hi - lo < abs(true)


def test_calibration_map_recovered_within_its_band(sim_fit):
    lo, hi = sim_fit.basis.lo, sim_fit.basis.hi
    a = np.linspace(lo + 0.02, hi - 0.02, 400)
    curve, band_lo, band_hi = sim_fit.map_curve(a)
    # The fitted map is a function of the reading a = g(y) = y + s (y - A) + m(y): the truth is
    # r(a) = a - g^-1(a), with its constant and linear part (over the reference range) removed.
    y = np.linspace(-0.2, 1.2, 20001)
    g = y + 0.02 * (y - 0.5) + true_map(y)
    grid = np.linspace(*sim_fit.basis.ref, 2001)
    r_grid = np.interp(grid, g, g - y)
    lin = np.column_stack([np.ones_like(grid), grid])
    c, *_ = np.linalg.lstsq(lin, r_grid, rcond=None)
    target = np.interp(a, g, g - y) - np.column_stack([np.ones_like(a), a]) @ c
    sd = (band_hi - band_lo) / (2 * 1.6449)
    # the map has 5 mrad of shape; it is recovered to a fraction of that, and within 4 sd of the
    # jackknife band everywhere (400 correlated points: a simultaneous, not pointwise, level)
    assert np.std(target) > 1.5e-3
    assert np.sqrt(np.mean((curve - target) ** 2)) < 0.1 * np.std(target)
    assert np.all(np.abs(curve - target) < 4 * sd + 2e-5)
    # scale: the linear part of r(a)
    assert sim_fit.shared()["scale"] == pytest.approx(c[1], abs=5e-4)


def test_held_out_runs_reach_the_quantization_floor(sim_rig, sim_fit):
    spec = sim_fit.spec
    floor = rig.floor_std(STEP, TRUTH_STEP)
    for run in sim_rig[7:]:
        pred, per = rig.predict_run(sim_fit, run)
        sc = rig.score_run(run, pred, spec)
        # uniform quantization error: std estimate over ~2000 correlated samples within 15 %
        assert sc["steady_std"] == pytest.approx(floor, rel=0.15)
        assert sc["all_std"] < 2 * floor


def test_held_out_scoring_is_honest(sim_rig, sim_fit):
    # A held-out run whose map differs from the rig's must show the difference: the shared
    # terms are not refitted on it (only its offset, play and latency are).
    run = sim_rig[8]
    bump = 0.002 * np.sin(2 * np.pi * run.measured / 0.3)
    odd = rig.Run(run.run_id, run.t, run.truth, STEP * np.round((run.measured + bump) / STEP), STEP,
                  TRUTH_STEP, run.torques, run.conditions)
    pred, _ = rig.predict_run(sim_fit, odd)
    sc = rig.score_run(odd, pred, sim_fit.spec)
    floor = rig.floor_std(STEP, TRUTH_STEP)
    expected = math.sqrt(floor**2 + np.var(bump))
    assert sc["all_std"] == pytest.approx(expected, rel=0.2)


def test_map_and_compliance_improve_held_out_score(sim_rig):
    folds = rig.make_folds(sim_rig, [{"name": "freq", "by": "frequency_hz", "train": [0.5, 1.0], "test": [0.75]}])
    full = rig.RigSpec(spacing=0.05, compliance=SPEC_COMP)
    rows_full, out = rig.evaluate(sim_rig, full, folds)
    rows_bare, _ = rig.evaluate(sim_rig, full.with_(spacing=None, compliance={}), folds)
    p_full, p_bare = rig.pooled(rows_full), rig.pooled(rows_bare)
    floor = rig.floor_std(STEP, TRUTH_STEP)
    assert p_full["steady_std"] < 1.15 * floor < p_bare["steady_std"]
    assert all(r["steady_std"] < r["before_steady_std"] for r in rows_full)
    spread = rig.fold_spread(out)
    assert set(spread) == {"scale", *COMP}


def test_knot_spacing_chosen_on_held_out_runs(sim_rig):
    spec = rig.RigSpec(spacing=0.05, compliance=SPEC_COMP)
    best, scores = rig.choose_spacing(sim_rig[:6], spec, [0.5, 0.2, 0.05])
    # a 0.25 rad period needs knots closer than about a quarter period
    assert best == 0.05
    assert scores[0.5] > 2 * scores[0.05]


def test_run_rejects_bad_input():
    t = np.arange(5) * 1e-3
    with pytest.raises(ValueError, match="measured has shape"):
        rig.Run("r", t, np.zeros(5), np.zeros(4), STEP)
    with pytest.raises(ValueError, match="truth is not finite at row 2"):
        rig.Run("r", t, np.array([0, 0, np.nan, 0, 0.0]), np.zeros(5), STEP)


def test_reversal_travel_of_a_sine():
    t = np.arange(0, 4.0, 1e-3)
    theta = 0.5 * np.sin(2 * np.pi * 0.5 * t)
    travel, direction = rig.reversal_travel(theta)
    # after the peak at t = 0.5 s, travel is 0.5 (1 - cos(pi (t - 0.5)))
    sel = (t > 0.6) & (t < 1.4)
    assert np.allclose(travel[sel], 0.5 * (1 - np.cos(np.pi * (t[sel] - 0.5))), atol=1e-6)
    assert np.all(direction[sel] == -1) and np.all(direction[(t > 1.6) & (t < 2.4)] == 1)


def test_reversal_transient_recovered(sim_rig):
    # a mean motion inside the play, the same after every reversal: a 2 mrad bump over the first
    # 0.04 rad of travel, odd in the direction
    def bump(run):
        travel, direction = rig.reversal_travel(run.truth)
        return direction * np.where(travel < 0.04, 2e-3 * np.sin(np.pi * travel / 0.04) ** 2, 0.0)

    runs = [rig.Run(r.run_id, r.t, r.truth, STEP * np.round((r.measured + bump(r)) / STEP), STEP,
                    TRUTH_STEP, r.torques, r.conditions) for r in sim_rig]
    spec = rig.RigSpec(spacing=0.05, compliance=SPEC_COMP)
    with_t = spec.with_(transient=0.005)
    fit0, fit1 = rig.fit_rig(runs[:7], spec), rig.fit_rig(runs[:7], with_t)
    s0 = [rig.score_run(r, rig.predict_run(fit0, r)[0], spec)["all_std"] for r in runs[7:]]
    s1 = [rig.score_run(r, rig.predict_run(fit1, r)[0], with_t)["all_std"] for r in runs[7:]]
    floor = rig.floor_std(STEP, TRUTH_STEP)
    # 2 x 2000 samples: the std of a uniform error is known to a few per cent
    assert max(s1) < 1.05 * floor and min(s0) > 1.3 * floor


def test_shared_latency_recovered(sim_rig):
    spec = rig.RigSpec(spacing=0.05, compliance=SPEC_COMP, latency="shared")
    fit = rig.fit_rig(sim_rig[:7], spec)
    # every run has 1 ms; the reading's slope (1.02 and the map's) scales it by a few per cent
    assert fit.shared()["latency"] == pytest.approx(1e-3, rel=0.1)
    assert all(v["latency"] == 0.0 for v in fit.per_run.values())
    lo, hi = fit.ci()["latency"]
    assert lo < fit.shared()["latency"] < hi


def test_rig_report_tables_figures_and_words(sim_rig):
    from enclab.rig import pipeline as rig_pipeline

    runs = [sim_rig[i] for i in (0, 1, 3, 4)]
    spec = rig.RigSpec(spacing=0.1, compliance=SPEC_COMP, latency="shared", transient=0.01)
    out = rig_pipeline.report_rig("sim", "theta_out", runs, spec,
                                [{"name": "freq", "by": "frequency_hz", "train": [0.5], "test": [0.75]}],
                                [0.3, 0.05], truth_counts_per_rev=146860)
    block = out["block"]
    assert [s["split"] for s in block["splits"]] == ["freq"]
    split = block["splits"][0]
    assert split["test_runs"] == 2 and split["after_all"] < split["before_all"]
    assert block["final"]["spacing"] == 0.05
    assert len(block["final"]["map"]["curve"]) == 101
    cond = out["tables"]["conditions"]
    assert set(cond["condition"]) == {"frequency_hz", "load"}
    assert set(cond[cond["condition"] == "load"]["value"]) == {0.0, 0.3}
    rem = block["remains"]["freq"]
    assert 0 < rem["window_share"] < 1 and rem["window_fraction"] < 0.5
    assert [len(f.axes) for f in out["figures"].values()] == [1, 2, 1, 1]
    text = out["markdown"]
    assert "## Held out" in text and "## What remains" in text and "counts per" in text


def test_remains_separates_repeatable_from_random_motion_in_the_play(sim_rig):
    from enclab.rig.report import remains

    spec = rig.RigSpec()
    rng = np.random.default_rng(0)
    same, random = {}, {}
    for run in sim_rig[:4]:
        travel, direction = rig.reversal_travel(run.truth)
        win = travel < spec.travel
        same[run.run_id] = np.where(win, direction * 1e-3 * np.sin(np.pi * travel / spec.travel), 0.0)
        random[run.run_id] = np.where(win, 1e-3 * rng.standard_normal(run.t.size), 0.0)
    assert remains(sim_rig[:4], same, spec)["repeatable_share"] > 0.95
    assert remains(sim_rig[:4], random, spec)["repeatable_share"] < 0.1
    assert remains(sim_rig[:4], same, spec)["window_share"] > 0.99


# ----------------------------------------------------------------------------- play take-up

TAKEUP = {"torque_back:linear": 0.02, "torque_back:saturating": 0.004, "torque_front:linear": -0.2}


@pytest.fixture(scope="module")
def takeup_rig():
    """Runs whose twist takes the play up over 0.01 N m of back torque: ``0.004 tanh(T/0.01)``."""
    return rig.simulate_rig(np.random.default_rng(7), CONDS, step=STEP, truth_step=TRUTH_STEP,
                            compliance=TAKEUP, torque_scales={"torque_back": 0.01},
                            play_width=[0.02, 0.025, 0.03], latency=0.001)


def test_saturating_term_is_tanh_and_needs_a_scale():
    T = np.linspace(-0.1, 0.1, 11)
    cols = cal.compliance_columns({"tb": ["linear", "saturating"]}, {"tb": T}, {"tb": 0.02})
    assert np.allclose(cols[:, 1], np.tanh(T / 0.02), rtol=0, atol=1e-15)
    assert np.allclose(cal.compliance_curve([0.1, 0.003], {"tb": ["linear", "saturating"]}, "tb", T, {"tb": 0.02}),
                       0.1 * T + 0.003 * np.tanh(T / 0.02), rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="torque scale"):
        cal.compliance_columns({"tb": ["saturating"]}, {"tb": T})
    with pytest.raises(ValueError, match="saturating"):
        cal.compliance_names({"tb": ["cubic"]})


def test_heldout_rms_matches_refitting_without_each_group(sim_rig):
    # Brute force: fit the shared terms on the other groups, predict the left-out runs with
    # their own offset refitted; the pooled rms is what heldout_rms gets from one set of
    # normal equations.
    runs = sim_rig[:6]
    spec = rig.RigSpec(play=False, latency=False, spacing=None, compliance=SPEC_COMP)
    groups = rig.inner_groups(runs, "load")
    assert len(set(groups.values())) == 3
    ss, n = 0.0, 0
    for key in set(groups.values()):
        fit = rig.fit_rig([r for r in runs if groups[r.run_id] != key], spec)
        for r in (r for r in runs if groups[r.run_id] == key):
            pred, _ = rig.predict_run(fit, r)
            e = (r.measured - pred)[r.t >= r.t[0] + spec.t_skip]
            ss += float(np.sum((e - e.mean()) ** 2))
            n += e.size
    zero = {r.run_id: 0.0 for r in runs}
    assert rig.heldout_rms(runs, spec, zero, groups) == pytest.approx(np.sqrt(ss / n), rel=1e-9)
    # one group per run when a condition has a single value
    assert rig.inner_groups(runs[:3], "frequency_hz") == {r.run_id: r.run_id for r in runs[:3]}
    with pytest.raises(ValueError, match="2 groups"):
        rig.heldout_rms(runs[:1], spec, zero)


def test_play_takeup_chosen_on_training_runs_and_extrapolates_in_load(takeup_rig):
    # Declared softening T + T|T|; trained on the two low loads, tested on the high one. The
    # choice sees only the training runs (one load held out at a time).
    spec = rig.RigSpec(spacing=None, compliance=SPEC_COMP)
    folds = rig.make_folds(takeup_rig, [{"name": "load", "by": "load", "train": [0.0, 0.3], "test": [0.6]}])
    poly, _ = rig.evaluate(takeup_rig, spec, folds)
    rows, out = rig.evaluate(takeup_rig, spec, folds, variants="takeup")
    fit = out[0]["fit"]
    assert fit.spec.compliance["torque_back"] == ["linear", "saturating"]
    assert 0.5 < fit.spec.torque_scales["torque_back"] / 0.01 < 2.0
    assert fit.shared()["torque_back:T0"] == fit.spec.torque_scales["torque_back"]
    floor = rig.floor_std(STEP, TRUTH_STEP)
    after, before = rig.pooled(rows)["steady_std"], rig.pooled(poly)["steady_std"]
    assert after < 1.5 * floor < before / 4
    # the front torque's linear compliance is untouched by the choice and recovered
    assert fit.shared()["torque_front:linear"] == pytest.approx(-0.2, rel=0.05)


def test_takeup_variants_scale_with_the_torque_and_keep_the_declared_form_first(takeup_rig):
    spec = rig.RigSpec(compliance=SPEC_COMP, transient=0.004)
    forms = rig.takeup_variants(takeup_rig, spec, relative=(0.5,))
    sd = np.std(np.concatenate([r.torques["torque_back"] for r in takeup_rig]))
    assert forms[0] == {} and forms[4] == {"transient": None}
    assert forms[1]["torque_scales"] == {"torque_back": pytest.approx(0.5 * sd)}
    assert forms[1]["compliance"]["torque_front"] == ["linear"]
    # the declared form without each channel in turn
    assert forms[2]["compliance"] == {"torque_front": ["linear"]}
    assert forms[3]["compliance"] == {"torque_back": ["linear", "signed_square"]}
    assert len(forms) == 8
    assert len(rig.takeup_variants(takeup_rig, spec, relative=(0.5,), drop_channels=False)) == 4
    # nothing to replace: only the transient is a choice
    assert rig.takeup_variants(takeup_rig, rig.RigSpec(compliance={"torque_back": ["linear"]})) == [{}]


def test_rig_report_shows_the_chosen_takeup(takeup_rig):
    from enclab.rig import pipeline as rig_pipeline

    runs = [takeup_rig[i] for i in (0, 1, 2, 4, 5)]
    spec = rig.RigSpec(spacing=None, compliance=SPEC_COMP)
    out = rig_pipeline.report_rig("sim", "theta_out", runs, spec,
                                [{"name": "load", "by": "load", "train": [0.0, 0.3], "test": [0.6]}],
                                None, variants="takeup")
    fold = out["block"]["folds"][0]
    assert fold["compliance"]["torque_back"] == ["linear", "saturating"]
    assert len(fold["variant_scores"]) == 7 and "torque_back:T0" in fold["shared"]
    text = out["markdown"]
    assert "Model form per fold" in text and "tanh(T/" in text
    ax = out["figures"]["compliance"].axes[0]
    assert "tanh(T/" in ax.get_title()
    # the fit on all runs, its curve, and the fold's curve
    assert len(ax.lines) == 3


# ----------------------------------------------------------------------------- input-side map


def input_error(phi):
    """Error of the truth reading (rad, output side) periodic in the input angle."""
    return 3e-4 * np.sin(phi + 0.4) + 1.5e-4 * np.cos(2 * phi)


def test_input_columns_are_the_harmonics():
    phi = np.linspace(0, 2 * np.pi, 7)
    D = rig.input_columns(phi, 2)
    assert np.allclose(D, np.column_stack([np.cos(phi), np.cos(2 * phi), np.sin(phi), np.sin(2 * phi)]),
                       rtol=0, atol=1e-15)


def test_input_side_map_recovered():
    # A 35:1 gear, the truth read through it with an error periodic per input turn; the
    # measured side carries a slow output-side map and a scale as well. Knots every 0.2 rad of
    # the output angle cannot follow a period of 2 pi / 35 = 0.18 rad, the harmonics can (finer
    # knots trade with them: both are functions of nearly the same angle).
    runs = rig.simulate_rig(np.random.default_rng(3), CONDS, step=STEP, truth_step=TRUTH_STEP,
                            scale=0.02, map_fn=lambda y: 0.002 * np.cos(2 * np.pi * y / 0.6),
                            play_width=0.02, gear_ratio=35.0, input_map_fn=input_error)
    spec = rig.RigSpec(spacing=0.2, gear_ratio=35.0, input_harmonics=2)
    fit = rig.fit_rig(runs, spec)
    phi = np.linspace(0, 2 * np.pi, 200)
    curve, lo, hi = fit.input_curve(phi)
    # The reading minus the truth carries minus the truth's error while the play is engaged;
    # inside the play it holds the value of the last engaged instant, which harmonics of the
    # truth's own angle do not follow (a bias of a few per cent on these 2-5 s runs).
    target = -input_error(phi)
    assert np.max(np.abs(curve - target)) < 0.1 * np.max(np.abs(target))
    assert np.all(hi >= lo) and np.max(hi - lo) < 0.1 * np.max(np.abs(target))
    assert all(not n.startswith("input") for n in fit.shared())
    # without the harmonics the held-out residual keeps the error
    folds = rig.make_folds(runs, [{"name": "f", "by": "frequency_hz", "train": [0.5, 1.0], "test": [0.75]}])
    with_map, _ = rig.evaluate(runs, spec, folds)
    without, _ = rig.evaluate(runs, spec.with_(input_harmonics=0), folds)
    assert rig.pooled(with_map)["steady_std"] < 0.9 * rig.pooled(without)["steady_std"]
    with pytest.raises(ValueError, match="gear ratio"):
        rig.fit_rig(runs[:2], rig.RigSpec(input_harmonics=1))


def test_rig_report_shows_the_input_side_map():
    from enclab.rig import pipeline as rig_pipeline

    runs = rig.simulate_rig(np.random.default_rng(4), CONDS[:4], step=STEP, truth_step=TRUTH_STEP,
                            play_width=0.02, gear_ratio=35.0, input_map_fn=input_error)
    spec = rig.RigSpec(spacing=0.2, gear_ratio=35.0, input_harmonics=2)
    out = rig_pipeline.report_rig("sim", "theta_out", runs, spec,
                                [{"name": "f", "by": "frequency_hz", "train": [0.5], "test": [0.75]}], None)
    block = out["block"]["final"]["input_map"]
    assert len(block["curve"]) == 101 and block["gear_ratio"] == 35.0
    # the curve over one revolution is the one the fit gives, within its band
    assert all(lo <= c <= hi for c, lo, hi in zip(block["curve"], block["band_lo"], block["band_hi"]))
    assert len(out["figures"]["map"].axes) == 2
    assert "input-side map (2 harmonics" in out["markdown"]


# ----------------------------------------------------------------------------- torque map


def test_torque_range_is_the_range_every_group_covers():
    t = np.arange(2001) / 1000.0
    runs = [rig.Run(f"r{i}", t, t, t, STEP, torques={"tb": np.linspace(lo, lo + 0.1, t.size)},
                    conditions={"load": lo}) for i, lo in enumerate((0.0, 0.03))]
    groups = {"r0": "a", "r1": "b"}
    lo, hi = rig.torque_range(runs, "tb", groups, q=0.0)
    assert (lo, hi) == (pytest.approx(0.03), pytest.approx(0.1))
    # each run its own group by default; quantiles trim the ends
    lo, hi = rig.torque_range(runs, "tb", q=0.1)
    assert (lo, hi) == (pytest.approx(0.03 + 0.01), pytest.approx(0.1 - 0.01))
    far = [runs[0], rig.Run("r2", t, t, t, STEP, torques={"tb": np.linspace(0.5, 0.6, t.size)})]
    with pytest.raises(ValueError, match="share no range"):
        rig.torque_range(far, "tb")
    spec = rig.resolve_torque_map(runs, rig.RigSpec(torque_map={"tb": 8}, t_skip=0.0), groups)
    assert spec.torque_map["tb"][2] == 8 and spec.torque_map["tb"][0] > 0.03
    with pytest.raises(ValueError, match="no range"):
        rig._shared_columns(runs[0], rig.RigSpec(torque_map={"tb": 8}, scale=False), None, 0.0)


def test_torque_map_recovers_the_takeup_curve(takeup_rig):
    # The take-up 0.004 tanh(T/0.01) is no polynomial: a spline of the torque (linear part = the
    # linear compliance) follows it; its resolution is chosen on held-out training runs.
    spec = rig.RigSpec(spacing=None, compliance={"torque_back": ["linear"], "torque_front": ["linear"]},
                       torque_map={"torque_back": 8})
    folds = rig.make_folds(takeup_rig, [{"name": "f", "by": "frequency_hz", "train": [0.5, 0.75],
                                         "test": [1.0]}])
    rows, out = rig.evaluate(takeup_rig, spec, folds, torque_knots=[4, 16])
    poly, _ = rig.evaluate(takeup_rig, spec.with_(compliance=SPEC_COMP, torque_map={}), folds)
    fit = out[0]["fit"]
    lo, hi, n = fit.spec.torque_map["torque_back"]
    # 4 intervals over ~0.14 N m cannot bend over 0.01 N m: the finer map is chosen
    assert n == 16 and set(out[0]["spacing_scores"]["torque_knots"]) == {4, 16}
    T = np.linspace(lo, hi, 201)
    curve = fit.shared()["torque_back:linear"] * T + fit.torque_map_curve("torque_back", T)
    true = 0.02 * T + 0.004 * np.tanh(T / 0.01)
    dev = (curve - true) - np.mean(curve - true)  # the constant is each run's offset
    floor = rig.floor_std(STEP, TRUTH_STEP)
    # the curve rests on ~24000 samples whose error is ``floor``: it is off by far less
    assert np.max(np.abs(dev)) < 0.5 * floor
    assert fit.shared()["torque_front:linear"] == pytest.approx(-0.2, rel=0.05)
    after, before = rig.pooled(rows)["steady_std"], rig.pooled(poly)["steady_std"]
    assert after < 1.2 * floor < before


def test_declared_map_term_becomes_a_torque_map_beside_the_linear_term():
    out = rig.declared_compliance({"tb": ["map"], "tf": ["linear", "signed_square"]}, 4)
    assert out == {"compliance": {"tb": ["linear"], "tf": ["linear", "signed_square"]},
                   "torque_map": {"tb": 4}}
    assert rig.declared_compliance({"tb": ["linear", "map"]})["compliance"] == {"tb": ["linear"]}


def test_rig_report_shows_the_torque_map(takeup_rig):
    from enclab.rig import pipeline as rig_pipeline

    runs = [takeup_rig[i] for i in (0, 1, 2, 4, 5)]
    spec = rig.RigSpec(spacing=None, **rig.declared_compliance(
        {"torque_back": ["linear", "map"], "torque_front": ["linear"]}, 4))
    out = rig_pipeline.report_rig("sim", "theta_out", runs, spec,
                                [{"name": "load", "by": "load", "train": [0.0, 0.3], "test": [0.6]}],
                                None, variants="takeup", torque_knots=[4, 16])
    fold = out["block"]["folds"][0]
    tmap = fold["torque_map"]["torque_back"]
    assert tmap["intervals"] in (4, 16) and tmap["lo"] < 0 < tmap["hi"]
    assert set(fold["spacing_scores"]["torque_knots"]) == {4, 16}
    json.dumps(out["block"])  # the block is plain JSON
    assert "torque map of torque_back" in out["markdown"]
    ax = out["figures"]["compliance"].axes[0]
    assert "map (" in ax.get_title()
    # the twist curve drawn bends (the map), where the linear term alone would be straight
    T, drawn = ax.lines[0].get_xdata(), ax.lines[0].get_ydata()
    straight = np.polyval(np.polyfit(T, drawn, 1), T)
    assert np.max(np.abs(drawn - straight)) > 0.1 * np.ptp(drawn)


@pytest.mark.parametrize("front, kept", [(0.0, False), (-0.2, True)])
def test_choose_variant_leaves_out_a_torque_channel_the_runs_do_not_support(front, kept):
    # Both torques declared; the front one twists the rig (kept) or does not (left out: its
    # correlation with the back torque would let it take any value the training runs favour).
    comp = {"torque_back:linear": 0.05, **({"torque_front:linear": front} if front else {})}
    runs = rig.simulate_rig(np.random.default_rng(11), CONDS, step=STEP, truth_step=TRUTH_STEP,
                            compliance=comp, play_width=[0.02, 0.025, 0.03], latency=0.001)
    spec = rig.RigSpec(spacing=None, compliance={"torque_back": ["linear"], "torque_front": ["linear"]})
    variants = rig.takeup_variants(runs, spec)
    assert len(variants) == 3
    chosen, scores = rig.choose_variant(runs, spec, variants, groups=rig.inner_groups(runs, "load"))
    assert len(scores) == 3 and min(scores) > 0
    assert ("torque_front" in chosen.compliance) is kept
    assert "torque_back" in chosen.compliance
    if not kept:
        from enclab.rig import pipeline as rig_pipeline

        out = rig_pipeline.report_rig("sim", "theta_out", runs, spec,
                                    [{"name": "load", "by": "load", "train": [0.0, 0.3], "test": [0.6]}],
                                    None, variants="takeup")
        assert "torque_front left out" in out["markdown"]
        assert "Left out: torque_front (kept by 0 of 1 folds)" in out["markdown"]
        assert "torque_front" not in out["block"]["final"]["compliance"]


def test_fold_spread_counts_the_folds_that_keep_a_term(sim_rig):
    runs = sim_rig
    spec = rig.RigSpec(spacing=None, compliance={"torque_back": ["linear"], "torque_front": ["linear"]})
    a = rig.fit_rig(runs[:6], spec)
    b = rig.fit_rig(runs[6:], spec.with_(compliance={"torque_back": ["linear"]}))
    spread = rig.fold_spread([{"fit": a}, {"fit": b}])
    assert spread["torque_front:linear"]["kept_in"] == 1 and spread["torque_front:linear"]["folds"] == 2
    assert spread["torque_back:linear"]["kept_in"] == 2
    assert "torque_front:linear" in rig.loose_parameters(spread, 0.15)
    assert rig.loose_parameters(spread, np.inf) == ["torque_front:linear"]


# ----------------------------------------------------------------------------- extrapolation


def test_term_groups_gather_a_torques_terms_and_maps():
    names = ["scale", "latency", "map0", "map1", "torque_back:linear", "torque_back:signed_square",
             "tmap_torque_back0", "tmap_torque_back1", "torque_front:linear", "transient0", "input_cos1",
             "input_sin1"]
    groups = rig.term_groups(names)
    assert groups == {"scale": [0], "latency": [1], "map": [2, 3], "torque_back compliance": [4, 5, 6, 7],
                      "torque_front compliance": [8], "transient": [9], "input": [10, 11]}


def test_refit_shared_of_every_term_on_the_training_runs_is_the_fit(sim_rig, sim_fit):
    # Refitting every shared term on the runs it was fitted on, the play widths held at the
    # fit's own, is the fit's least-squares problem without the widths' linearised step: the
    # coefficients agree within a fraction of their jackknife sd (the fit's widths come from the
    # exact play operator's search after the Gauss-Newton passes, not from their fixed point:
    # a difference of a few micro-rad that moves the coefficients by ~0.1 sd here).
    widths = {k: v["play_width"] for k, v in sim_fit.per_run.items()}
    again = rig.refit_shared(sim_fit, sim_rig[:7], widths=widths)
    sd = np.sqrt(np.diag(sim_fit.cov))
    assert np.all(np.abs(again.coef - sim_fit.coef) < 0.25 * sd)
    # refitting no term changes nothing
    assert np.array_equal(rig.refit_shared(sim_fit, sim_rig[:7], [], widths).coef, sim_fit.coef)


def test_coverage_lists_conditions_and_ranges(sim_rig):
    cov = rig.coverage(sim_rig[:3], t_skip=1.5)
    assert cov["conditions"] == {"frequency_hz": [0.5], "load": [0.0, 0.3, 0.6]}
    lo, hi = cov["torques"]["torque_back"]
    assert lo < 0 < hi
    after = np.concatenate([r.measured[r.t >= 1.5] for r in sim_rig[:3]])
    assert cov["angle"] == [after.min(), after.max()]


def test_a_split_that_does_not_extrapolate_is_flagged_and_its_term_blamed(takeup_rig):
    # The twist takes the play up as tanh(T / 0.01 N m); a softening polynomial T + T|T| fitted on
    # the two low loads bends the wrong way at the high one (the load split), while the frequency
    # split sees every load in training. The load split must be flagged, the back torque's
    # compliance blamed; the frequency split must not be flagged.
    spec = rig.RigSpec(spacing=None, compliance=SPEC_COMP)
    splits = [{"name": "frequency", "by": "frequency_hz", "train": [0.5, 1.0], "test": [0.75]},
              {"name": "load", "by": "load", "train": [0.0, 0.3], "test": [0.6]}]
    folds = rig.make_folds(takeup_rig, splits)
    rows, out = rig.evaluate(takeup_rig, spec, folds)
    ext = {e["split"]: e for e in rig.extrapolation(takeup_rig, rows, out, ratio=2.0)}
    assert ext["frequency"]["extrapolates"]
    assert not ext["load"]["extrapolates"] and "training runs' own" in ext["load"]["reason"]
    assert ext["load"]["blame"] == "torque_back compliance"
    assert ext["load"]["excess_share"]["torque_back compliance"] > 0.5
    assert ext["load"]["coverage"]["train"]["conditions"]["load"] == [0.0, 0.3]
    assert ext["load"]["coverage"]["test"]["conditions"]["load"] == [0.6]
    # the play take-up, chosen on the training runs, extrapolates (bounded)
    rows, out = rig.evaluate(takeup_rig, spec, folds, variants="takeup")
    ext = {e["split"]: e for e in rig.extrapolation(takeup_rig, rows, out, ratio=2.0)}
    assert ext["load"]["extrapolates"]
    with pytest.raises(ValueError, match="ratio"):
        rig.extrapolation(takeup_rig, rows, out, ratio=1.0)


def test_flat_torque_map_is_a_bounded_takeup_beside_the_stiffness():
    # zero slope at both ends (central differences of step h: the second derivative's O(h)),
    # only the constant removed, held at the end values beyond the range; one column fewer
    # than the map continued along its end slopes (the slope is not removed, two ends merged)
    flat = rig.torque_map_basis(-0.1, 0.2, 6, "flat")
    linear = rig.torque_map_basis(-0.1, 0.2, 6)
    assert flat.n_columns == linear.n_columns - 1
    h = 1e-7
    for end in (-0.1, 0.2):
        slope = (flat.design([end + h]) - flat.design([end - h])) / (2 * h)
        inner = (flat.design([0.05 + h]) - flat.design([0.05 - h])) / (2 * h)
        assert np.max(np.abs(slope)) < 1e-4 * np.max(np.abs(inner))
    assert np.array_equal(flat.design([-1.0, 1.0]), flat.design([-0.1, 0.2]))
    grid = np.linspace(-0.1, 0.2, flat.n_grid)
    assert np.max(np.abs(flat.design(grid).sum(axis=0))) < 1e-8 * grid.size
    with pytest.raises(ValueError, match="form"):
        rig.torque_map_basis(-0.1, 0.2, 6, "cubic")


def test_takeup_variants_offer_the_flat_torque_map(takeup_rig):
    spec = rig.RigSpec(compliance={"torque_back": ["linear"], "torque_front": ["linear"]},
                       torque_map={"torque_back": (-0.05, 0.08, 4)}, torque_map_forms=("linear", "flat"))
    forms = rig.takeup_variants(takeup_rig, spec, transient=False)
    maps = [f.get("torque_map", spec.torque_map) for f in forms]
    assert {v.get("torque_back", (0, 0, 0, "none"))[3:] or ("linear",) for v in maps} == \
        {("linear",), ("flat",), ("none",)}
    # the form survives the range's resolution on other runs and the number of intervals' choice
    flat = spec.with_(torque_map={"torque_back": (-0.05, 0.08, 4, "flat")})
    assert rig.resolve_torque_map(takeup_rig, flat, None, 8).torque_map["torque_back"][2:] == (8, "flat")
    fit = rig.fit_rig(takeup_rig[:4], rig.resolve_torque_map(takeup_rig[:4], flat))
    assert len([n for n in fit.names if n.startswith("tmap")]) == rig.torque_map_basis(0, 1, 4, "flat").n_columns
