"""Pipeline, report block and figure structure for the LRDE analysis (no pixel tests)."""
import json

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from enclab.lrde import dwell, fit, model, pipeline, plots, report, simulate
from enclab.lrde import loop as lrde_loop

STEP = simulate.ROS_DRILL_STEP
FAST = {"n_ensembles": 2, "n_walkers": 16, "n_steps": 120, "n_burn": 80, "ppc_draws": 8,
        "motion_models": [[], [3]]}


def _canonical(seed=21, with_measured=True):
    df, p = simulate.open_loop_log(np.random.default_rng(seed), A12=3.44 * STEP,
                                   bias=0.1 * STEP, offset_frac=0.35, n_cycles=4,
                                   noise_std=0.02 * STEP, truth_step=STEP / 100)
    channels = [{"name": "fine", "role": "truth", "joint": 1, "unit": "rad",
                 "storage": "counts", "step": STEP / 100}]
    out = df.rename(columns={"counts": "coarse", "truth_counts": "fine"})
    if with_measured:
        channels.append({"name": "coarse", "role": "measured", "joint": 1, "unit": "rad",
                         "storage": "counts", "step": STEP})
    else:
        out = out.drop(columns="coarse")
    return out, {"log_id": "sim_lrde", "channels": channels}, p


@pytest.mark.slow
def test_analyse_lrde_log_block_matches_design_contract():
    df, meta, p = _canonical()
    block, figures, md, cycles = pipeline.analyse_lrde_log(df, meta, seed=5, settings=FAST)
    for key in ("A12", "a_eq", "E_b", "f_hz", "offset_a", "bias_b"):
        assert set(block[key]) == {"median", "q05", "q95"}
        assert block[key]["q05"] <= block[key]["median"] <= block[key]["q95"]
    assert set(block["diagnostics"]) == {"rhat_max", "ess_min", "tau_max", "converged"}
    assert block["dwell_formula_A12"] == pytest.approx(p["A12"], rel=0.05)
    assert block["A12"]["q05"] < p["A12"] < block["A12"]["q95"]
    # The truth channel identifies the offset (to the truth's 0.01-step rounding).
    assert block["offset_a"]["median"] == pytest.approx(p["offset_a"], abs=0.02 * STEP)
    json.dumps(block)  # JSON-serialisable
    assert set(figures) == {"corner", "dwell_ppc", "bias_cycles", "misfit"}
    assert all(isinstance(f, Figure) for f in figures.values())
    assert "stroke A12" in md and "Sampler diagnostics" in md
    # The held-out comparison of motion, encoder and clock effects ran (a clean sinusoid:
    # compare.py's own tests check which model wins) and fills the residuals block
    # (docs/output-contract.md).
    labels = [m["label"] for m in block["model"]["models"]]
    assert labels[:2] == ["sinusoid", "harmonic3"]
    assert set(labels) >= {"hysteresis", "drift", "count_jump", "time_jitter"}
    assert set(block["residuals"]) == {"metric", "before", "after", "effects"}
    assert "What the sinusoid misses" in md
    # Before/after and a trust flag with its reason for every reported quantity.
    assert block["before"]["model"] == "sinusoid"
    assert block["after"]["model"] == block["model"]["chosen"]
    for key in ("A12", "E_b", "a_eq", "f_hz", "offset_a", "bias_b"):
        assert set(block["trust"][key]) == {"trusted", "reason"}
        assert block["trust"][key]["trusted"] == (block["trust"][key]["reason"] is None)
    assert list(cycles.columns) == dwell.CYCLE_COLUMNS and len(cycles) >= 3


@pytest.mark.slow
def test_batch_rows_carry_posterior_and_diagnostics():
    df, meta, p = _canonical()
    block, _, _, _ = pipeline.analyse_lrde_log(df, meta, seed=5, settings=FAST)
    rows = {r["quantity"]: r for r in report.batch_rows("sim_lrde", block)}
    assert set(rows) == {"A12", "E_b", "a_eq", "offset_a", "bias_b", "f_hz", "sigma"}
    assert rows["A12"]["median"] == block["A12"]["median"]
    assert rows["A12"]["dwell_formula_A12"] == block["dwell_formula_A12"]
    assert rows["E_b"]["dwell_formula_A12"] is None
    assert all(r["converged"] == block["diagnostics"]["converged"] for r in rows.values())
    assert rows["offset_a"]["reason"] is None  # identified through the truth channel
    unidentified = dict(block, offset_a=None, bias_b=None, reason="no truth channel")
    rows = {r["quantity"]: r for r in report.batch_rows("x", unidentified)}
    assert rows["bias_b"]["median"] is None and rows["bias_b"]["reason"] == "no truth channel"
    assert rows["A12"]["reason"] is None


@pytest.mark.slow
def test_requantized_truth_and_unidentified_offset():
    df, meta, p = _canonical(with_measured=False)
    settings = dict(FAST, requantize={"step": STEP, "offset_frac": 0.35}, use_truth=False)
    block, _, md, _ = pipeline.analyse_lrde_log(df, meta, seed=1, settings=settings)
    assert block["channels"]["requantized"] is True
    assert block["offset_a"] is None and block["bias_b"] is None
    assert "a_eq = a + b" in block["reason"] and "not identified" in md
    with pytest.raises(ValueError, match="requantize"):
        pipeline.analyse_lrde_log(df, meta, seed=1, settings=FAST)
    with pytest.raises(ValueError, match="unknown lrde settings"):
        pipeline.analyse_lrde_log(df, meta, seed=1, settings={"n_walker": 3})


def test_figures_structure():
    df, meta, p = _canonical()
    t = df["t"].to_numpy()
    r = fit.fit_sinusoid(t, df["coarse"].to_numpy(), STEP, seed=2, n_ensembles=2, n_walkers=16,
                         n_steps=80, n_burn=60)
    fig = plots.corner_plot(r, truths={"A12": p["A12"], "E_b": p["E_b"]})
    assert len(fig.axes) == 25
    assert fig.axes[20].get_xlabel() == r"$A_{12}$ [deg]"
    cycles = dwell.cycle_table(df["coarse"].to_numpy(), t, STEP)
    pred = plots.posterior_predictive_dwell(r, t, seed=0, n_draws=5)
    assert set(pred["draw"]) == set(range(5))
    fig2 = plots.dwell_ppc_plot(cycles, pred)
    ax = fig2.axes[0]
    assert ax.get_ylabel() == "dwell half-width [ms]"
    # Observed markers carry exactly the observed widths (ms).
    observed = [line for line in ax.get_lines() if line.get_label() == "top dwell $w_1$, observed"]
    np.testing.assert_allclose(observed[0].get_ydata(), 1e3 * cycles["w1"])
    cl_df, cl_p = simulate.closed_loop_pid_log(np.random.default_rng(0), n_cycles=10)
    fig3 = plots.closed_loop_plot(cl_df, cl_p)
    assert fig3.axes[0].get_ylabel() == "bias deviation [deg]"
    dev_line = fig3.axes[0].get_lines()[0]
    cb = dwell.cycle_bias(cl_df["t"].to_numpy(), cl_df["theta"].to_numpy(), cl_p["f_hz"])
    np.testing.assert_allclose(dev_line.get_ydata(),
                               np.rad2deg(cb["bias"] - cl_p["ideal_bias"]))


def test_truth_bias_deviation_matches_the_dwell_estimate_on_a_sinusoid():
    df, p = simulate.open_loop_log(np.random.default_rng(3), A12=3.6 * STEP, bias=0.05 * STEP,
                                   offset_frac=0.5, n_cycles=30)
    t = df["t"].to_numpy()
    theta = p["bias"] + 0.5 * p["A12"] * np.sin(2 * np.pi * p["f_hz"] * t + p["phase"])
    truth = plots.truth_bias_deviation(t, theta, p["f_hz"], STEP, p["offset_a"], 0)
    np.testing.assert_allclose(truth["E_b"], p["E_b"], atol=1e-12 * STEP)
    # Independent method: the readings' dwell half-widths (eq. 4/14). A half-width is resolved
    # to half a sample (0.25 ms at 2 kHz); the level crossing moves by A pi f sin(pi f w) dw
    # ~ 1.8 step * 63 /s * 0.2 * 0.25 ms ~ 0.006 step, so E_b agrees to 0.01 step.
    cycles = dwell.cycle_table(df["counts"].to_numpy(), t, STEP, f_hz=p["f_hz"])
    sym = cycles[cycles["symmetric"] & (cycles["centre_count"] == 0)]
    assert len(sym) >= 25
    assert sym["E_b_dwell"].mean() == pytest.approx(p["E_b"], abs=0.01 * STEP)
    fig = plots.bias_cycles_plot(cycles, STEP, truth)
    top, bottom = fig.axes
    labels = [line.get_label() for line in top.get_lines()]
    assert "$E_b$ of the true angle (truth channel)" in labels
    np.testing.assert_array_equal(bottom.get_lines()[0].get_ydata(), cycles["steps_pp"])
    with pytest.raises(ValueError, match="lacks columns"):
        plots.bias_cycles_plot(cycles.drop(columns="E_b_dwell"), STEP)


def test_closed_loop_bias_stays_in_proposition_1_band():
    """Paper 002 Fig. 6: in the PID loop the bias wanders about the ideal bias inside
    +- epsilon/2 while the readings stay 2n steps peak to peak."""
    cl_df, cl_p = simulate.closed_loop_pid_log(np.random.default_rng(4), n_cycles=40)
    settled = cl_df[cl_df["t"] >= 0.5]
    t, theta = settled["t"].to_numpy(), settled["theta"].to_numpy()
    truth = plots.truth_bias_deviation(t, theta, cl_p["f_hz"], STEP, cl_p["offset_a"], 0)
    per_period = dwell.cycle_bias(t, theta, cl_p["f_hz"])
    np.testing.assert_allclose(truth["E_b"], per_period["bias"] - cl_p["ideal_bias"],
                               atol=1e-15)
    half_eps = 0.5 * np.asarray(model.epsilon(truth["A12"].to_numpy(), STEP))
    assert np.all(np.abs(truth["E_b"]) < half_eps)
    assert truth["E_b"].std() > 0.01 * STEP  # it wanders; it is not locked to the ideal bias
    cycles = dwell.cycle_table(settled["counts"].to_numpy(), t, STEP, f_hz=cl_p["f_hz"])
    assert set(cycles["steps_pp"]) == {4}


def test_run_summary_names_untrusted_lrde_quantities():
    from enclab import report as run_report

    q = {"median": 5.18e-3, "q05": 5.15e-3, "q95": 5.21e-3}
    reason = "no candidate model explains the readings"
    block = {"A12": q, "E_b": q, "offset_a": None, "bias_b": None, "reason": "not identified",
             "diagnostics": {"converged": True, "rhat_max": 1.002, "ess_min": 2456.0},
             "model": {"chosen": "hysteresis"},
             "trust": {"A12": {"trusted": False, "reason": reason},
                       "E_b": {"trusted": False, "reason": reason},
                       "offset_a": {"trusted": False, "reason": "not identified"}}}
    rows = run_report._lrde([{"log_id": "l", "lrde": block}])["rows"]
    assert rows[0]["untrusted"] == {"A12": reason, "E_b": reason}
    text = run_report.summary_text(run_report.run_summary(
        [{"log_id": "l", "warnings": [], "lrde": block}], ["l"], {}, ratios=None,
        violations=None, written={}))
    assert "model hysteresis" in text and f"l: UNTRUSTED A12, E_b: {reason}" in text
    # Pooled estimates name the models they come from.
    pooled = dict(block, after={"model": "hysteresis"},
                  averaged={"model": "averaged: hysteresis, harmonic3"})
    row = run_report._lrde([{"log_id": "l", "lrde": pooled}])["rows"][0]
    assert row["model"] == "averaged: hysteresis, harmonic3"


def _hysteresis_log(seed, width, n_cycles=40):
    from enclab.lrde import effects

    rng = np.random.default_rng(seed)
    f_hz, a, b, A12, phase = 20.3, 0.3 * STEP, 0.22 * STEP, 3.7 * STEP, 0.4
    t = np.arange(int(n_cycles * 2000.0 / f_hz)) / 2000.0
    counts = effects.simulate_counts(rng, t, STEP, A12, a + b, f_hz, phase,
                                     noise_std=0.005 * STEP, hysteresis=width)
    theta = b + 0.5 * A12 * np.sin(2 * np.pi * f_hz * t + phase)
    df = pd.DataFrame({"t": t, "coarse": counts,
                       "fine": np.floor(theta / (STEP / 100) + 0.5).astype(np.int64)})
    meta = {"log_id": "sim_hysteresis", "channels": [
        {"name": "fine", "role": "truth", "joint": 1, "unit": "rad", "storage": "counts",
         "step": STEP / 100},
        {"name": "coarse", "role": "measured", "joint": 1, "unit": "rad", "storage": "counts",
         "step": STEP}]}
    return df, meta, {"offset_a": a, "bias_b": b, "A12": A12}


@pytest.mark.slow
def test_hysteresis_with_a_truth_channel_is_named_and_a_b_hold_after():
    """A dead band of 1/8 step read beside a fine truth channel: the comparison names the
    hysteresis, and with it in the model the offset a and bias b intervals hold the truth."""
    df, meta, true = _hysteresis_log(31, STEP / 8)
    settings = dict(FAST, motion_models=[[], [3]], effects=["hysteresis", "drift"],
                    n_steps=150, n_burn=60)
    block, _, md, _ = pipeline.analyse_lrde_log(df, meta, seed=3, settings=settings)
    assert block["model"]["chosen"] == "hysteresis"
    w = block["model"]["params"]["hysteresis"]
    assert w["q05"] < STEP / 8 < w["q95"]
    for key, value in true.items():
        assert block["after"][key]["q05"] < value < block["after"][key]["q95"], key
    assert block["before"]["model"] == "sinusoid" and block["after"]["model"] == "hysteresis"
    assert "before (sinusoid)" in md and "after (hysteresis)" in md


def test_reference_terms_are_confirmed_or_named_as_standing_for_the_motion():
    model_block = {"effects": ["hysteresis", "drift"],
                   "params": {"hysteresis": {"median": 2e-4, "q05": 1.8e-4, "q95": 2.2e-4}}}
    found = {"truth": "fine", "explained": True, "effects": ["hysteresis"],
             "found": [{"term": "hysteresis", "residual_effect": "backlash", "value": 2.1e-4,
                        "ci": [2.05e-4, 2.15e-4]}], "not_modelled": []}
    ref = report.reference_block(found, model_block, added=[])
    assert [(r["term"], r["status"], r["consistent"]) for r in ref["terms"]] == [
        ("hysteresis", "found by both", True)]
    far = dict(found, found=[dict(found["found"][0], value=9e-4, ci=[8.9e-4, 9.1e-4])])
    assert report.reference_block(far, model_block, added=[])["terms"][0]["consistent"] is False
    clean = dict(found, effects=[], found=[])
    row = report.reference_block(clean, model_block, added=[])["terms"][0]
    assert row["status"] == "not confirmed by the truth channel" and "motion" in row["note"]
    assert report.reference_block(None, model_block, added=[]) is None


def test_a_truth_channel_term_joins_a_loop_structure_with_room_for_it():
    assert pipeline._loop_with_reference("loop-pi", ["hysteresis", "time_jitter"]) == (
        "loop-pi+hysteresis", ["hysteresis"])
    assert pipeline._loop_with_reference("loop-pid", ["count_jump", "hysteresis"]) == (
        "loop-pid+count_jump", ["count_jump"])
    # One encoder term per structure: a second one has no room, and the report says so.
    assert pipeline._loop_with_reference("loop-pi+count_jump", ["hysteresis"]) == (
        "loop-pi+count_jump", [])
    found = {"truth": "fine", "explained": True, "effects": ["hysteresis"],
             "found": [{"term": "hysteresis", "residual_effect": "backlash", "value": 2.1e-4,
                        "ci": [2.05e-4, 2.15e-4]}], "not_modelled": []}
    model_block = {"effects": ["count_jump"], "params": {}, "check": {}}
    ref = report.reference_block(found, model_block, added=[])
    assert [(r["term"], r["status"]) for r in ref["terms"]] == [
        ("hysteresis", "not in this fit"), ("count_jump", "not confirmed by the truth channel")]
    from types import SimpleNamespace
    fit_stub = SimpleNamespace(converged=True, summary={k: {"median": 0.0} for k in
                                                        ("A12", "E_b", "a_eq", "f_hz",
                                                         "offset_a", "bias_b")})
    trust = report.trust_block(fit_stub, dict(model_block, reference=ref))
    assert not any(v["trusted"] for v in trust.values())
    assert all("shows hysteresis, which this fit has no term for" in v["reason"]
               for v in trust.values())


def test_a_loop_fit_at_its_jitter_floor_says_so():
    from types import SimpleNamespace

    step = 1e-3
    loop_cmp = {"chosen": "loop-pi", "models": [{"label": "loop-pi", "delta_bic": 12.0}],
                "check": {"z": 0.1}, "rule": "a rule"}

    def note(sigma_q05):
        fit_stub = SimpleNamespace(step=step, loop_params={},
                                   summary={"sigma": {"q05": sigma_q05}})
        return pipeline._loop_model_block({"chosen": "harmonic3"}, loop_cmp, fit_stub)["note"]

    floor = lrde_loop.JITTER_FLOOR_STEPS * step
    assert "lies at its floor" in note(1.01 * floor)
    assert "floor" not in note(3.0 * floor)


def test_an_effect_the_model_cannot_hold_flags_the_estimates_it_biases():
    from types import SimpleNamespace

    fit_stub = SimpleNamespace(converged=True, summary={k: {"median": 0.0} for k in
                                                        ("A12", "E_b", "a_eq", "f_hz",
                                                         "offset_a", "bias_b")})
    drift = {"residual_effect": "slow_drift", "why": "a_eq is constant",
             "biases": ["a_eq", "E_b", "offset_a"]}
    block = {"check": {}, "reference": {"truth": "fine", "explained": True,
                                        "not_modelled": [drift]}}
    trust = report.trust_block(fit_stub, block)
    assert [k for k, v in trust.items() if not v["trusted"]] == ["E_b", "a_eq", "offset_a"]
    assert "slow_drift" in trust["a_eq"]["reason"]
    # A dead band the truth channel does not confirm stands for the motion: the stroke.
    unconfirmed = {"term": "hysteresis", "status": "not confirmed by the truth channel"}
    block["reference"] = {"truth": "fine", "explained": True, "not_modelled": [],
                          "terms": [unconfirmed]}
    trust = report.trust_block(fit_stub, block)
    assert [k for k, v in trust.items() if not v["trusted"]] == ["A12"]
    assert "no dead band" in trust["A12"]["reason"]
    block["reference"]["terms"] = [dict(unconfirmed, status="found by both")]
    assert all(v["trusted"] for v in report.trust_block(fit_stub, block).values())
    block["reference"] = {"truth": "fine", "explained": False, "not_modelled": []}
    assert not any(v["trusted"] for v in report.trust_block(fit_stub, block).values())
    assert all(v["trusted"] for v in report.trust_block(fit_stub, {"check": {}}).values())


@pytest.mark.slow
def test_an_effect_found_against_the_truth_channel_enters_the_fit():
    """The readings alone are not compared (no candidate), but the residual stage found a
    dead band of 1/8 step against the truth channel: the fit adds it, and a, b hold after."""
    df, meta, true = _hysteresis_log(31, STEP / 8)
    reference = {"channel": "coarse", "truth": "fine", "explained": True,
                 "effects": ["hysteresis"],
                 "found": [{"term": "hysteresis", "residual_effect": "backlash",
                            "value": STEP / 8, "ci": [0.98 * STEP / 8, 1.02 * STEP / 8]}],
                 "not_modelled": [{"residual_effect": "latency", "why": "phase only",
                                   "biases": []}]}
    settings = dict(FAST, motion_models=[[]], effects=[], n_steps=150, n_burn=60)
    block, _, md, _ = pipeline.analyse_lrde_log(df, meta, seed=3, settings=settings,
                                                references={"coarse": reference})
    assert block["model"]["effects"] == ["hysteresis"]
    assert block["before"]["model"] == "sinusoid" and block["after"]["model"] == "hysteresis"
    row = block["model"]["reference"]["terms"][0]
    assert row["status"] == "added from the truth channel" and row["consistent"]
    for key, value in true.items():
        assert block["after"][key]["q05"] < value < block["after"][key]["q95"], key
    assert "Added to the fit from its findings: hysteresis" in md
    assert "latency (truth channel): no term here" in md
    json.dumps(block)


def _harmonic_log(seed, n_cycles=12):
    """The readings of a sinusoid with a small 3rd harmonic (0.02-0.04 step), coarse channel
    only."""
    from enclab.lrde import effects

    rng = np.random.default_rng(seed)
    amp = (0.02 + 0.02 * rng.random()) * STEP
    angle = rng.uniform(0.0, 2.0 * np.pi)
    t = np.arange(int(n_cycles * 2000.0 / 20.3)) / 2000.0
    counts = effects.simulate_counts(rng, t, STEP, 3.7 * STEP, 0.55 * STEP, 20.3, 0.4,
                                     noise_std=0.005 * STEP,
                                     harmonics={3: (amp * np.cos(angle), amp * np.sin(angle))})
    meta = {"log_id": "sim_harmonic", "channels": [
        {"name": "coarse", "role": "measured", "joint": 1, "unit": "rad", "storage": "counts",
         "step": STEP}]}
    return pd.DataFrame({"t": t, "coarse": counts}), meta


@pytest.mark.slow
def test_models_the_comparison_cannot_tell_apart_are_pooled_in_the_reported_estimates():
    """A 3rd harmonic of 0.02 step that the comparison takes for a dead band, with the
    harmonic within two standard errors: both models are fitted and the headline estimates
    are their equal-weight pool, while ``after`` stays the pick's own posterior."""
    df, meta = _harmonic_log(25)
    settings = dict(FAST, motion_models=[[], [3]], effects=["hysteresis"], effect_pairs=False)
    block, _, md, _ = pipeline.analyse_lrde_log(df, meta, seed=2, settings=settings)
    m = block["model"]
    assert (m["chosen"], m["indistinguishable"]) == ("hysteresis", ["harmonic3"])
    assert m["averaged_over"] == ["hysteresis", "harmonic3"]
    assert block["averaged"]["models"] == ["hysteresis", "harmonic3"]
    assert block["after"]["model"] == "hysteresis"
    for key in ("A12", "E_b", "a_eq", "f_hz"):
        assert block[key] == block["averaged"][key]
    assert block["A12"] != block["after"]["A12"]
    assert "pool the posteriors of hysteresis and harmonic3" in m["note"]
    assert "These estimates pool the posteriors of hysteresis and harmonic3" in md
    assert "reported (averaged: hysteresis, harmonic3)" in md
    json.dumps(block)
    rows = {r["quantity"]: r for r in report.batch_rows("sim_harmonic", block)}
    assert rows["A12"]["median"] == block["averaged"]["A12"]["median"]
    assert rows["A12"]["model"] == "averaged: hysteresis, harmonic3"


@pytest.mark.slow
def test_an_effect_the_kept_sinusoid_does_not_rule_out_is_pooled_with_it():
    """A 3rd harmonic of a few hundredths of a step: below the rule's bar, so the sinusoid is
    kept, but the harmonic predicts each held-out fold better. It is listed as not ruled out
    and the reported estimates pool both posteriors; ``after`` is the sinusoid's own."""
    df, meta = _harmonic_log(0)
    settings = dict(FAST, motion_models=[[], [3]], effects=["hysteresis"], effect_pairs=False)
    block, _, md, _ = pipeline.analyse_lrde_log(df, meta, seed=2, settings=settings)
    m = block["model"]
    assert m["chosen"] == "sinusoid" and m["indistinguishable"] == []
    # Not ruled out: exactly the models that predict each fold better by 1 nat or more in all.
    expected = [r["label"] for r in m["models"] if r["label"] != "sinusoid"
                and min(r["delta_elpd_halves"]) > 0 and r["delta_elpd"] >= 1.0]
    assert m["not_ruled_out"] == expected == ["harmonic3"]
    assert m["averaged_over"] == ["sinusoid", "harmonic3"]
    assert block["after"]["model"] == "sinusoid" == block["before"]["model"]
    assert block["A12"] == block["averaged"]["A12"] != block["after"]["A12"]
    assert "harmonic3 predicts each held-out fold better than the sinusoid" in m["note"]
    assert "keeps the sinusoid but does not rule the others out" in md
    assert "the paper's model stands" not in md
    json.dumps(block)


def test_a_count_glitch_fails_with_the_file_the_column_and_the_time():
    df, meta, _ = _canonical()
    meta = dict(meta, source={"file": "rig/run3.csv"})
    glitched = df.copy()
    row = len(df) // 2
    glitched.loc[row, "coarse"] += 30
    with pytest.raises(ValueError, match=rf"^rig/run3\.csv: column 'coarse', sample {row} "
                                         r"\(t = [0-9.]+ s\): the count changes by \+30 in one "
                                         r"sample .*\(and 1 more such changes\).*crop"):
        pipeline.analyse_lrde_log(glitched, meta, seed=1, settings=FAST)
    # Two counts in one sample are accepted (an analog sensor's toggling levels do that).
    t = np.arange(6) / 1000.0
    pipeline.check_count_changes(t, np.array([0, 2, 0, 1, 3, 3]), "x")
    with pytest.raises(ValueError, match=r"^x, sample 2 \(t = 0\.002 s\): the count changes by -3"):
        pipeline.check_count_changes(t, np.array([0, 1, -2, -1, 0, 0]), "x")


def test_readings_too_short_to_fit_name_the_file_and_the_column():
    df, meta, _ = _canonical()
    meta = dict(meta, source={"file": "rig/run3.csv"})
    with pytest.raises(ValueError, match=r"^rig/run3\.csv: column 'coarse': .*no complete "
                                         r"oscillation cycle"):
        pipeline.analyse_lrde_log(df.iloc[:40], meta, seed=1, settings=FAST)
