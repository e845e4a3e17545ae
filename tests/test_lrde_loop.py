"""The loop motion model (enclab.lrde.loop): the logged error through a low-order filter."""
import copy

import numpy as np
import pandas as pd
import pytest

from enclab.core import parallel
from enclab.lrde import effects, loop, pipeline, report, simulate

STEP = simulate.ROS_DRILL_STEP


def _theta_from_columns(df, p, taps):
    """Least squares of the true angle on the loop's columns at the pole ``p``."""
    counts = df["counts"].to_numpy()
    cols = loop._Columns(loop.error_steps(counts, df["reference"].to_numpy(), STEP),
                         loop.LoopFilter(taps))
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


def test_many_rows_motion_matches_the_filter_row_by_row():
    # The series about the grid's poles (many rows at once) against scipy's filter per row,
    # over the pole's whole range and across cell edges: the series' truncation is of order
    # 1e-16 of the lag column's bound max|e| / (1 - p), so 1e-12 of it is rounding's margin
    # over 2000-sample sums, far below the hundredth-of-a-step floor of the jitter.
    rng = np.random.default_rng(11)
    e = np.cumsum(rng.normal(0.0, 0.3, 2000))
    e -= e.mean()
    cols = loop._Columns(e, loop.LoopFilter(1))
    lo, hi = loop._P_BOUNDS
    p = np.concatenate((rng.uniform(lo, hi, 40), 1.0 - rng.uniform(1 - hi, 0.05, 40)))
    x = np.column_stack((rng.normal(size=(p.size, 2)), p, rng.normal(size=(p.size, 6))))
    together = cols.motion(x)
    alone = np.array([cols.motion(row)[0] for row in x])
    bound = np.abs(x[:, 7:8]) * np.abs(e).max() / (1.0 - p[:, None]) + np.abs(alone)
    assert np.max(np.abs(together - alone) / bound) < 1e-12
    # The cells in use are kept, and the cache stays bounded.
    assert len(cols._lag_cache) <= cols._lag_cache_cells


def test_the_transient_powers_match_numpy_power():
    # exp(j log p) against p ** j over the transient (j |log p| below 42 + |log p|): the
    # rounding of log p (half an ulp) moves the exponent by at most ~42 ulp, 1e-14 relatively.
    p = np.array(loop._P_BOUNDS + (0.5, 0.9, 0.99))
    for pk in p:
        k = loop._transient_length(pk, 10_000)
        j = np.arange(k, dtype=float)
        got = loop._powers(np.array([pk]), j)[0]
        np.testing.assert_allclose(got, pk ** j, rtol=1e-13, atol=0)


def test_the_lag_terms_of_every_cell_in_use_are_filtered_once(monkeypatch):
    # A loosely held pole spreads the walkers over many cells of the grid: every cell's
    # terms stay cached within the byte budget, so a second pass over the same rows filters
    # nothing; under a tight budget the least recently used cell goes first.
    rng = np.random.default_rng(5)
    e = np.cumsum(rng.normal(0.0, 0.3, 2000))
    cols = loop._Columns(e - e.mean(), loop.LoopFilter(1))
    p = 1.0 - np.exp(-np.linspace(0.1, 5.0, 64))  # 64 rows over 98 cells of log(1 - p)
    x = np.column_stack((np.zeros((p.size, 2)), p, rng.normal(size=(p.size, 6))))
    calls = []
    real = loop.lfilter
    monkeypatch.setattr(loop, "lfilter", lambda *a: calls.append(1) or real(*a))
    first = cols.motion(x)
    n_cells = len(np.unique(np.rint(np.log1p(-p) / loop._LAG_CELL)))
    assert n_cells > loop._LAG_CACHE and len(calls) == n_cells * loop._LAG_TERMS
    calls.clear()
    np.testing.assert_array_equal(cols.motion(x), first)
    assert calls == []
    tight = loop._Columns(e - e.mean(), loop.LoopFilter(1))
    tight._lag_cache_cells = 2
    for cell in (1.0, 2.0, 1.0, 3.0):
        tight._series_basis(cell)
    assert list(tight._lag_cache) == [1.0, 3.0]

def test_error_and_cycles_checks():
    with pytest.raises(ValueError, match="shape of counts"):
        loop.error_steps(np.zeros(5, dtype=int), np.zeros(4), STEP)
    with pytest.raises(ValueError, match="fewer than two whole cycles"):
        loop.reference_cycles(np.sin(np.linspace(0, 3 * np.pi, 100)))
    reference = np.sin(np.arange(400) / 10.0)
    reference[77] = np.nan
    with pytest.raises(ValueError, match="not finite at sample 77"):
        loop.error_steps(np.zeros(400, dtype=int), reference, STEP)
    # A log too short for two whole cycles is named as such by every fit, even when empty.
    for n in (0, 1, 40):
        t = np.arange(n) / 2000.0
        args = (t, np.zeros(n, dtype=int), 0.002 * np.sin(2 * np.pi * 20 * t), STEP)
        with pytest.raises(ValueError, match="fewer than two whole cycles"):
            loop.point_fit(*args)
        with pytest.raises(ValueError, match="fewer than two whole cycles"):
            loop.fit_loop(*args, seed=1)
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


def test_a_command_that_cannot_drive_the_loop():
    t = np.arange(400) / 2000.0
    meta = {"channels": [{"name": "c", "role": "measured", "joint": 1, "storage": "counts",
                          "step": STEP},
                         {"name": "r", "role": "command", "joint": 1, "storage": "float"}]}
    info = {"measured": "c"}
    cycling = pd.DataFrame({"t": t, "c": 0, "r": 0.002 * np.sin(2 * np.pi * 20 * t)})
    command, why = pipeline.loop_command(cycling, meta, info, "log.csv")
    np.testing.assert_array_equal(command, cycling["r"].to_numpy())
    assert why is None
    # A held set point (a quantized loop may cycle around it): the periodic models stay, and
    # the block says why the loop structures were not offered.
    held = cycling.assign(r=0.001)
    command, why = pipeline.loop_command(held, meta, info, "log.csv")
    assert command is None and "'r'" in why and "fewer than two whole cycles" in why
    # A sample that is not finite is bad input: file, column and row.
    broken = cycling.copy()
    broken.loc[123, "r"] = np.inf
    with pytest.raises(ValueError, match=r"log.csv: column 'r', row 123: the command is not"):
        pipeline.loop_command(broken, meta, info, "log.csv")
    assert pipeline.loop_command(cycling, {"channels": meta["channels"][:1]}, info) == (None,
                                                                                       None)
    # The report says so beside the comparison of the periodic models.
    block = {"models": [{"label": "sinusoid", "elpd_per_cycle": -1.0}], "rule": "a rule",
             "chosen": "sinusoid", "loop_not_offered": why}
    assert f"Loop structures not offered: {why}." in report._effect_lines({"model": block})


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


def test_a_log_read_without_noise_keeps_the_true_filter_inside_its_posterior():
    # Soft gains, no noise, 20 cycles after the pull-in (the closed-loop benchmark's draw
    # 20291227): the readings' edges are hard, and the posterior's jitter sits at its floor.
    # Edges softened by 0.01 step put the true filter 9 nats below the posterior's 5 %
    # quantile of the log-posterior (and its stroke 2.3 half-widths outside the 90 % interval);
    # at the floor the true filter must score like a posterior draw, which it falls below
    # with probability 0.05.
    df, prm = simulate.closed_loop_pid_log(
        np.random.default_rng(0), amplitude=1.7869 * STEP, f_hz=20.0, fs_hz=2000.0,
        n_cycles=50, offset_frac=0.0503, kp=400.0, ki=1500.0)
    df = df.iloc[3000:].reset_index(drop=True)
    t, counts, ref = df["t"].to_numpy(), df["counts"].to_numpy(), df["reference"].to_numpy()
    structure = loop.loop_structure("loop-pi")
    cols = loop._Columns(loop.error_steps(counts, ref, STEP), structure, counts)
    pole = np.exp(-1.0 / (prm["fs_hz"] * prm["tau"]))
    lag, trans = cols.lag(pole)
    design = np.column_stack((np.ones(cols.n), cols.fixed, lag, trans))
    coef, *_ = np.linalg.lstsq(design, df["theta"].to_numpy() / STEP, rcond=None)
    bounds = loop._bounds(structure)
    true_row = np.concatenate(([coef[0] + prm["offset_a"] / STEP, bounds[1, 0] + 1e-9, pole],
                               coef[1:]))
    assert np.array_equal(np.floor(cols.motion(true_row)[0] + true_row[0]), counts)
    res = loop.fit_loop(t, counts, ref, STEP, 1, threads=2)
    assert res.converged
    posterior = loop._log_post(res.loop_samples, cols, counts, bounds)
    truth = loop._log_post(true_row[None, :], cols, counts, bounds)[0]
    assert truth >= np.quantile(posterior, 0.05), (truth, np.quantile(posterior, 0.05))


def test_structure_labels_with_encoder_terms():
    s = loop.loop_structure("loop-pid+count_jump+hysteresis")
    assert (s.taps, s.effects) == (1, ("hysteresis", "count_jump"))
    assert s.label == "loop-pid+hysteresis+count_jump"
    assert loop.loop_structure("loop-pi").with_effect("hysteresis").label == "loop-pi+hysteresis"
    assert loop._bounds(s).shape == (3 + 6 + 1, 2)  # a0, log s, p, 6 weights, the band width
    with pytest.raises(ValueError, match="unknown loop structure"):
        loop.loop_structure("loop-pi+drift")


def test_dead_band_reading_probabilities_match_a_relay():
    # One sample, a relay of half width h in state c, driven by z + s N(0, 1): the
    # likelihood's interval probabilities of the readings c - 1, c, c + 1 against the
    # frequencies of a simulated relay (independent code: enclab.lrde.effects.relay). 2e5
    # draws: a probability's standard error is below 1.2e-3, the tolerance about 5 of them.
    structure = loop.LoopFilter(0, ("hysteresis",))
    e = np.zeros(50)
    cols = loop._Columns(e, structure, np.zeros(50, dtype=int))
    rng = np.random.default_rng(2)
    for z, s, w in ((0.95, 0.08, 0.2), (0.07, 0.05, 0.3), (0.5, 0.2, 0.1)):
        x = np.zeros(3 + 5 + 1)
        x[0], x[1], x[-1] = z, np.log10(s), w
        drive = z + s * rng.standard_normal(200_000)
        # each draw is a two-sample relay from the state 0: the second reading
        two = np.column_stack((np.full(drive.size, 0.5), drive))
        freq = {k: float(np.mean(effects.relay(two, 0.5 * w)[:, 1] == k)) for k in (-1, 0, 1)}
        for k in (-1, 0, 1):
            counts = np.zeros(50)
            counts[1] = k  # the reading after the state 0 (all weights 0: the angle is z)
            lower, upper = loop._interval_bounds(x[None, :], cols.for_counts(counts), counts)
            prob = float(np.exp(effects.log_interval_probability(lower[:, 1], upper[:, 1],
                                                                  "in_place"))[0])
            assert abs(prob - freq[k]) < 6e-3, (z, s, w, k, prob, freq[k])


def test_count_jump_start_places_a_missed_count():
    # A closed-loop log with one count missed at 70 % of it (the shorter segment is the later
    # one, read one count low): the point fit of loop-pi+count_jump places the jump where the
    # counter lost it, to within the samples between two changes of the reading, and reads
    # the readings as well as the loop explains a log without a miss (jitter at its floor).
    first, n_cycles = 3000, 20
    at = first + int(0.7 * n_cycles * 100)
    df, prm = simulate.closed_loop_pid_log(np.random.default_rng(5), n_cycles=30 + n_cycles,
                                           offset_frac=0.4, missed_count=(at, -1))
    df = df.iloc[first:].reset_index(drop=True)
    t, counts, ref = df["t"].to_numpy(), df["counts"].to_numpy(), df["reference"].to_numpy()
    m = loop.point_fit(t, counts, ref, STEP, "loop-pi+count_jump")
    cols = loop._Columns(loop.error_steps(counts, ref, STEP), "loop-pi+count_jump", counts)
    gaps, delta, _, offsets = loop.jump_placement(m["x"], cols, counts)
    true_index = at - first
    changes = np.flatnonzero(np.diff(counts)) + 1
    before = changes[changes <= true_index].max() if np.any(changes <= true_index) else 0
    assert delta == -1
    assert before <= gaps[0] <= true_index + 1, (gaps, true_index, before)
    assert offsets[-1] == -1 and offsets[0] == 0
    plain = loop.point_fit(t, counts, ref, STEP, "loop-pi")
    assert 10.0 ** m["x"][1] < 0.05 < 10.0 ** plain["x"][1]
    # The sampler's marginal over the jump's window equals the marginal over every gap and
    # sign near the point fit (the gaps left out hold below 1e-12 of the mass).
    rows = m["x"] + 1e-4 * np.random.default_rng(0).standard_normal((16, m["x"].size))
    full = loop._log_lik_rows(rows, cols, counts)
    cols.jump_window = loop.jump_window(m["x"], cols, counts, margin=50)
    assert cols.jump_window is not None and cols.jump_window.hi - cols.jump_window.lo < 400
    np.testing.assert_allclose(loop._log_lik_rows(rows, cols, counts), full, rtol=0, atol=1e-6)


def _loop_log(seed, **kwargs):
    """A closed-loop log after its pull-in, its reference declared as a command channel."""
    df, prm = simulate.closed_loop_pid_log(np.random.default_rng(seed), n_cycles=50,
                                           noise_std=0.02 * STEP, truth_step=STEP / 100,
                                           **kwargs)
    df = df.iloc[3000:].reset_index(drop=True)
    df["t"] -= df["t"].iloc[0]
    meta = {"log_id": "loop", "channels": [
        {"name": "counts", "role": "measured", "joint": 1, "unit": "counts",
         "storage": "counts", "step": STEP},
        {"name": "truth_counts", "role": "truth", "joint": 1, "unit": "counts",
         "storage": "counts", "step": STEP / 100},
        {"name": "reference", "role": "command", "joint": 1, "unit": "rad",
         "storage": "float", "step": None}]}
    return df, meta


def _stroke(df):
    """The simulated angle's mean per-cycle stroke over the reference's cycles."""
    top, bottom = loop._cycle_extremes(df["theta"].to_numpy()[None, :],
                                       loop.reference_cycles(df["reference"].to_numpy()))
    return float((top - bottom).mean())


_LOOP_SETTINGS = {"n_ensembles": 4, "n_walkers": 16, "n_steps": 250, "max_steps": 1000,
                  "n_burn": 100, "effects": [], "effect_pairs": False}


@pytest.mark.slow
def test_stage_with_a_command_channel_reports_the_loop_fit():
    # A closed-loop log with its reference declared as a command channel: the loop structure
    # replaces the periodic pick, its posterior is the reported one (converged, as every
    # ensemble starts at the point fit), the periodic pick is not sampled, and the stroke's
    # interval holds the simulated angle's per-cycle stroke within one width (a miss by more
    # is a bias, not the 1-in-10 of a calibrated interval).
    df, meta = _loop_log(7)
    block, figures, _, _ = pipeline.analyse_lrde_log(df, meta, 3, _LOOP_SETTINGS, threads=2)
    assert block["model"]["chosen"] in loop.STRUCTURES
    assert block["model"]["periodic"]["params"] == {}
    assert block["diagnostics"]["converged"]
    assert "averaged" not in block
    stroke = _stroke(df)
    q = block["A12"]
    width = q["q95"] - q["q05"]
    assert q["q05"] - width <= stroke <= q["q95"] + width, (stroke, q)
    assert set(figures) == {"corner", "dwell_ppc", "bias_cycles", "misfit"}


@pytest.mark.slow
def test_a_dead_band_the_truth_channel_finds_joins_the_loop_structure():
    # A dead band of 0.15 step in the loop, the comparison offered no encoder term; the
    # residual stage's finding (a stub of enclab.reference_effects.lrde_reference) puts the
    # term into the loop structure: its width and the stroke within one interval width of
    # the truth, the report's status "added from the truth channel", every estimate trusted.
    band = 0.15 * STEP
    df, meta = _loop_log(12, dead_band=band)
    found = {"truth": "truth_counts", "explained": True, "effects": ["hysteresis"],
             "found": [{"term": "hysteresis", "residual_effect": "backlash", "value": band,
                        "ci": [0.95 * band, 1.05 * band]}], "not_modelled": []}
    block, _, _, _ = pipeline.analyse_lrde_log(df, meta, 3, _LOOP_SETTINGS,
                                               references={"counts": found}, threads=2)
    model = block["model"]
    assert model["chosen"] in loop.STRUCTURES and model["effects"] == ["hysteresis"]
    assert block["after"]["model"] == model["chosen"] + "+hysteresis"
    assert "joined it from the truth channel" in model["note"]
    assert [(r["term"], r["status"]) for r in model["reference"]["terms"]] == [
        ("hysteresis", "added from the truth channel")]
    for q, true in ((model["params"]["hysteresis"], band), (block["A12"], _stroke(df))):
        width = q["q95"] - q["q05"]
        assert q["q05"] - width <= true <= q["q95"] + width, (true, q)
    assert all(v["trusted"] for v in block["trust"].values()), block["trust"]


def _sum_of(*x):
    return float(np.sum(x))


def test_ensembles_beside_other_jobs_give_the_same_fit():
    # The first round of ensembles as calls in one pool with an unrelated job (2 processes)
    # and the fit run here (1 process) draw from the same random states: identical samples.
    df, _ = simulate.closed_loop_pid_log(np.random.default_rng(4), n_cycles=30,
                                         noise_std=0.02 * STEP)
    df = df.iloc[1000:].reset_index(drop=True)
    args = (df["t"].to_numpy(), df["counts"].to_numpy(), df["reference"].to_numpy(), STEP, 9)
    sizes = {"n_ensembles": 3, "n_walkers": 16, "n_steps": 10, "n_burn": 10, "max_steps": 20}
    here = loop.fit_loop(*args, **sizes, threads=1)
    plan = loop.plan_loop_fit(*args, **sizes)
    done = parallel.call_forked([(_sum_of, (1.0, 2.0))] + plan.calls, 2)
    beside = plan.finish(done[1:], threads=2)
    assert done[0] == 3.0
    np.testing.assert_array_equal(beside.loop_samples, here.loop_samples)
    np.testing.assert_array_equal(beside.samples, here.samples)
    assert (beside.rhat, beside.settings) == (here.rhat, here.settings)


def test_the_chains_are_checked_after_half_the_burn_in_then_as_one_run(monkeypatch):
    # The first round runs half the burn-in and a block; not converged, the chains go on to
    # the full burn-in and by blocks, and what is kept is the end of the one run the
    # ensembles would have made in one go (continued from their own random states).
    df, _ = simulate.closed_loop_pid_log(np.random.default_rng(4), n_cycles=30,
                                         noise_std=0.02 * STEP)
    df = df.iloc[1000:].reset_index(drop=True)
    args = (df["t"].to_numpy(), df["counts"].to_numpy(), df["reference"].to_numpy(), STEP, 9)
    sizes = {"n_ensembles": 2, "n_walkers": 16, "n_steps": 10, "n_burn": 10, "max_steps": 20}
    plan = loop.plan_loop_fit(*args, **sizes)
    assert all(call[1][2] == 5 + 10 for call in plan.calls)
    whole = [loop._sample_ensemble(*(job[:2] + (30,) + job[3:]))
             for job in (copy.deepcopy(call[1]) for call in plan.calls)]
    fit = plan.finish([f(*a) for f, a in copy.deepcopy(plan.calls)])
    assert not fit.converged and (fit.settings["n_burn"], fit.settings["n_steps"]) == (20, 10)
    rows = fit.loop_samples.shape
    np.testing.assert_array_equal(fit.loop_samples,
                                  np.stack([w.chain[-10:] for w in whole]).reshape(rows))
    # Converged at the first check: the block after half the burn-in is kept.
    monkeypatch.setattr(loop.lrde_fit, "_chain_diagnostics",
                        lambda chains, names: ({}, {"a0": 1.0}, {"a0": 5000.0}))
    fit = plan.finish([f(*a) for f, a in copy.deepcopy(plan.calls)])
    assert fit.converged and (fit.settings["n_burn"], fit.settings["n_steps"]) == (5, 10)
    np.testing.assert_array_equal(fit.loop_samples,
                                  np.stack([w.chain[5:15] for w in whole]).reshape(rows))


def test_an_encoder_term_must_beat_its_structure_even_when_that_lost_to_the_pick():
    labels = ["loop-pi", "loop-pid", "loop-pi+hysteresis", "loop-pi+count_jump"]
    variants = labels[2:]

    def stub(wins):
        return lambda a, b: (a, b) in wins

    # loop-pi loses to the periodic pick on a fold; its band variant beats the pick but not
    # loop-pi (a band of width 0 riding on a better fold fit): nothing is chosen.
    passed, chosen = loop._loop_choice(labels, "harmonic3", "loop-pi", variants,
                                       stub({("loop-pi+hysteresis", "harmonic3")}))
    assert chosen is None and not any(passed.values())
    # A real band beats both: chosen, although loop-pi did not pass.
    passed, chosen = loop._loop_choice(
        labels, "harmonic3", "loop-pi", variants,
        stub({("loop-pi+hysteresis", "harmonic3"), ("loop-pi+hysteresis", "loop-pi")}))
    assert chosen == "loop-pi+hysteresis" and passed == {
        "loop-pi": False, "loop-pid": False, "loop-pi+hysteresis": True,
        "loop-pi+count_jump": False}
    # Later labels replace an earlier choice only by beating it.
    wins = {("loop-pi", "h"), ("loop-pid", "h"), ("loop-pi+hysteresis", "h")}
    assert loop._loop_choice(labels, "h", "loop-pi", variants, stub(wins))[1] == "loop-pi"
    assert loop._loop_choice(labels, "h", "loop-pi", variants,
                             stub(wins | {("loop-pid", "loop-pi")}))[1] == "loop-pid"
    # The band variant beats loop-pi, its structure, but not loop-pid, chosen before it.
    assert loop._loop_choice(labels, "h", "loop-pi", variants, stub(
        wins | {("loop-pid", "loop-pi"), ("loop-pi+hysteresis", "loop-pi")}))[1] == "loop-pid"
    assert loop._loop_choice(labels, "h", "loop-pi", variants, stub(
        wins | {("loop-pid", "loop-pi"), ("loop-pi+hysteresis", "loop-pi"),
                ("loop-pi+hysteresis", "loop-pid")}))[1] == "loop-pi+hysteresis"


def test_a_dead_band_the_held_out_cycles_do_not_rule_out_is_pooled_with_the_pick():
    # score(a, b) -> (delta, se, fold gains, passed) of a over b, from a table.
    table = {("loop-pi+hysteresis", "loop-pi"): (-1.0, 20.4, [-3.0, 2.0], False),
             ("loop-pi+hysteresis", "harmonic3"): (229.0, 29.8, [72.0, 157.0], False),
             ("loop-pi+count_jump", "loop-pi"): (-227.8, 21.9, [-230.0, 2.2], False),
             ("loop-pi+count_jump", "harmonic3"): (2.0, 220.0, [-146.0, 148.0], False)}
    def score(a, b):
        return table[(a, b)]

    variants = ["loop-pi+hysteresis", "loop-pi+count_jump"]
    # The band scores like the pick (within two standard errors): pooled. The jump is more
    # than two standard errors worse, and predicts a fold worse than the periodic pick.
    assert loop._loop_alternatives(variants, "loop-pi", "harmonic3", score, 2.0) == [
        "loop-pi+hysteresis"]
    # A jump is not pooled even when its loss on one cycle swells the standard error.
    jump_within = dict(table)
    jump_within[("loop-pi+count_jump", "loop-pi")] = (-580.0, 569.0, [-560.0, -20.0], False)
    jump_within[("loop-pi+count_jump", "harmonic3")] = (862.0, 570.0, [300.0, 562.0], False)
    assert loop._loop_alternatives(variants, "loop-pi", "harmonic3",
                                   lambda a, b: jump_within[(a, b)], 2.0) == [
        "loop-pi+hysteresis"]
    # Better than the pick counts too; two standard errors below it does not.
    table[("loop-pi+hysteresis", "loop-pi")] = (30.0, 10.0, [15.0, 15.0], False)
    assert loop._loop_alternatives(variants, "loop-pi", "harmonic3", score, 2.0) == [
        "loop-pi+hysteresis"]
    table[("loop-pi+hysteresis", "loop-pi")] = (-20.5, 10.0, [-10.0, -10.5], False)
    assert loop._loop_alternatives(variants, "loop-pi", "harmonic3", score, 2.0) == []
    # A variant that predicts a fold worse than the periodic pick is no alternative.
    table[("loop-pi+hysteresis", "loop-pi")] = (0.0, 10.0, [1.0, -1.0], False)
    table[("loop-pi+hysteresis", "harmonic3")] = (50.0, 10.0, [60.0, -10.0], False)
    assert loop._loop_alternatives(variants, "loop-pi", "harmonic3", score, 2.0) == []
    # Nothing chosen, nothing pooled; the chosen variant is not its own alternative.
    assert loop._loop_alternatives(variants, None, "harmonic3", score, 2.0) == []
    table[("loop-pi+hysteresis", "harmonic3")] = (229.0, 29.8, [72.0, 157.0], False)
    table[("loop-pi+hysteresis", "loop-pi+count_jump")] = (-300.0, 20.0, [-150.0, -150.0],
                                                           False)
    assert loop._loop_alternatives(variants, "loop-pi+count_jump", "harmonic3", score,
                                   2.0) == []


def test_fold_fits_start_at_the_whole_logs_and_a_tap_at_the_fit_without():
    # A soft loop read without noise (from the closed-loop benchmark's draws), where least
    # squares alone leaves a fold's loop-pi fit and the whole-log loop-pid fit at a pole near
    # 0 (the lag and the tap trading places), which loses them to the periodic pick.
    from benchmarks import lrde_closed_loop as bench

    df, _, _ = bench.simulate_log(np.random.default_rng(20291208), "soft", "none", 20)
    t, counts, ref = (df[c].to_numpy() for c in ("t", "coarse", "reference"))
    cycle = np.floor(t * bench.F_HZ + 1e-9).astype(np.int64)
    odd = (cycle % 2).astype(bool)
    folds, full = loop._fit_structures(t, counts, ref, STEP, [loop.loop_structure("loop-pi"),
                                                              loop.loop_structure("loop-pid")],
                                       [(~odd, odd), (odd, ~odd)], threads=1)
    pole = {label: m["x"][2] for label, m in full.items()}
    assert abs(pole["loop-pid"] - pole["loop-pi"]) < 0.05 and pole["loop-pi"] > 0.5
    for label, fits in folds.items():
        for m in fits:
            assert abs(m["x"][2] - pole[label]) < 0.05, (label, m["x"][2], pole[label])
    # loop-pid holds loop-pi (its tap at 0): its whole-log fit reads the log at least as well.
    lik = {label: loop._log_lik_rows(m["x"], loop._Columns(loop.error_steps(counts, ref, STEP),
                                                            label, counts), counts)[0]
           for label, m in full.items()}
    assert lik["loop-pid"] >= lik["loop-pi"] - 1e-6


def test_the_report_shows_the_loop_structures_scores_and_both_rules():
    rows = [{"label": "loop-pi", "over": "harmonic3", "elpd_per_cycle": -1.5,
             "delta_elpd": 67.6, "delta_se": 2.3, "z": 29.4, "delta_bic": 174.1,
             "passed": True},
            {"label": "loop-pi+hysteresis", "over": "harmonic3", "elpd_per_cycle": -1.5,
             "delta_elpd": 67.5, "delta_se": 2.3, "z": 29.3, "delta_bic": 166.5,
             "passed": False, "over_plain": {"label": "loop-pi", "delta_elpd": -0.1,
                                             "delta_se": 0.02, "passed": False}}]
    periodic_rows = [{"label": "sinusoid", "elpd_per_cycle": -9.0},
                     {"label": "harmonic3", "elpd_per_cycle": -5.0, "delta_elpd": 80.0,
                      "delta_se": 9.0, "z": 8.9, "delta_bic": 70.0}]
    chosen = {"models": periodic_rows, "chosen": "loop-pi", "rule": "the loop rule",
              "loop": rows, "periodic": {"chosen": "harmonic3", "rule": "the periodic rule"}}
    text = "\n".join(report._effect_lines({"model": chosen}))
    assert "Rule: the periodic rule." in text and "Rule: the loop rule." in text
    assert text.index("the periodic rule") < text.index("| loop structure |")
    assert "| loop-pi+hysteresis | -1.500 | 67.5 +- 2.3 | 29.3 | 166.5 | -0.1 +- 0.0 (loop-pi) " \
           "| no |" in text
    # Not chosen: the periodic pick's block with the loop rows and their rule beside it.
    kept = {"models": periodic_rows, "chosen": "harmonic3", "rule": "the periodic rule",
            "loop": rows[:1], "loop_rule": "the loop rule"}
    text = "\n".join(report._effect_lines({"model": kept}))
    assert text.count("Rule: ") == 2 and "| loop-pi | -1.500 | 67.6 +- 2.3 |" in text


def test_a_gain_held_by_one_cycle_does_not_cap_the_loop_rule():
    from enclab.lrde import compare

    # One unit d among n - 1 units g: the whole sum's z is 1 + n g / (d - g) exactly, below
    # 2 once d > (n + 1) g, however decisive d is.
    n, g = 19, 10.0
    for d in (300.0, 3000.0):
        diff = np.array([d] + [g] * (n - 1))
        z = diff.sum() / compare._sum_se(diff)
        assert z == pytest.approx(1 + n * g / (d - g), rel=1e-12) and z < 2
    # The held-out gains per cycle of loop-pid+count_jump over the periodic pick on the
    # closed-loop benchmark's draw 20491219 (soft gains, one count missed): all 19 positive,
    # the cycle holding the jump +540 nats; the whole sum's z is 1.49, the others' z over 10.
    diff = np.array([8.6, 8.7, 8.7, 8.7, 8.7, 11.1, 12.2, 12.2, 12.3, 14.7, 16.4, 17.0, 17.1,
                     17.1, 17.2, 17.2, 17.7, 18.5, 540.0])
    assert diff.sum() / compare._sum_se(diff) < 2
    assert loop._z_without_best(diff) > 10
    # A gain that rests on that one cycle alone does not pass without it: the others scatter
    # about 0 (z of 18 normal units: below 2 in 97.7 % of draws; this seed's is fixed).
    rest = np.random.default_rng(1).normal(0.0, 3.0, 18)
    assert loop._z_without_best(np.append(rest, 540.0)) == pytest.approx(
        rest.sum() / compare._sum_se(rest))
    assert loop._z_without_best(np.append(rest, 540.0)) < 2
    # Fewer than two units left: no z.
    assert loop._z_without_best(np.array([5.0, 1.0])) == 0.0


def test_the_encoder_terms_join_the_structure_the_rule_chooses_not_the_best_scoring_one():
    # passes(a, b): a beats b by the comparison's rule; totals: summed held-out scores.
    beats = {("loop-pi", "harmonic3"), ("loop-pid", "harmonic3")}
    totals = {"loop-pi": 100.0, "loop-pid": 104.0}
    labels = ["loop-pi", "loop-pid"]
    passes = lambda a, b: (a, b) in beats  # noqa: E731
    # The tap scores better but not by the rule against the structure without it.
    assert loop._plain_for_terms(labels, "harmonic3", passes, totals.get) == "loop-pi"
    # Once it passes against loop-pi, it carries the terms.
    beats.add(("loop-pid", "loop-pi"))
    assert loop._plain_for_terms(labels, "harmonic3", passes, totals.get) == "loop-pid"
    # Neither beats the periodic pick: the best-scoring one (a term may still pass).
    beats.clear()
    assert loop._plain_for_terms(labels, "harmonic3", passes, totals.get) == "loop-pid"
