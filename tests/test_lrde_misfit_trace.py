"""The localized check of an LRDE fit: calibrated at the truth, and it places effects that no
candidate describes on the covariate where they act."""
import numpy as np
import pytest

from enclab.lrde import compare, effects, plots, report, simulate

STEP = simulate.ROS_DRILL_STEP
F_HZ, A12, A_EQ, PHASE = 20.3, 3.7 * STEP, 0.55 * STEP, 0.4


def _truth(noise_frac, hysteresis=0.0):
    """A point fit holding the simulator's own parameters."""
    x = [A12 / STEP, A_EQ / STEP - 0.5, F_HZ, PHASE, np.log10(noise_frac)]
    return {"x": np.array(x + ([hysteresis / STEP] if hysteresis else [])), "step": STEP,
            "centre": 0.0, "t_ref": 0.0, "harmonics": (),
            "effects": ("hysteresis",) if hysteresis else ()}


def _readings(rng, n_cycles, noise_frac, hysteresis=0.0):
    t = np.arange(int(n_cycles * 2000.0 / F_HZ)) / 2000.0
    c = effects.simulate_counts(rng, t, STEP, A12, A_EQ, F_HZ, PHASE,
                                noise_std=noise_frac * STEP, hysteresis=hysteresis)
    return t, c


@pytest.mark.parametrize("hysteresis", [0.0, STEP / 8])
def test_at_the_truth_every_bin_is_standard_normal(hysteresis):
    # A martingale sum over any predictable set of samples: mean 0, variance 1 when the model
    # is the truth. 60 logs: 3 standard errors of a mean (1/sqrt(60)) and of an sd
    # (1/sqrt(2 * 59)).
    rng = np.random.default_rng(5)
    n = 60
    z_all, z_tenth = [], []
    m = _truth(0.05, hysteresis)
    for _ in range(n):
        t, c = _readings(rng, 6, 0.05, hysteresis)
        out = compare.misfit_trace(m, t, c)
        z_all.append(out["z_all"])
        # One fixed bin, not the worst one: the third tenth of the log.
        prev = np.concatenate((c[:1], c[:-1]))
        covariates = compare._trace_covariates(m, t, prev)
        assert covariates[0][0] == "time in the log"
        z_tenth.append(_bin_z(m, t, c, covariates[0][1] == 2))
    for z in (np.array(z_all), np.array(z_tenth)):
        assert abs(z.mean()) < 3 / np.sqrt(n)
        assert abs(z.std(ddof=1) - 1) < 3 / np.sqrt(2 * (n - 1))


def _bin_z(m, t, c, mask):
    """The z of one set of samples, from the alternatives written out one by one."""
    prev = np.concatenate((c[:1], c[:-1]))
    logp = {}
    for d in (-1, 0, 1):
        logp[d] = np.maximum(effects.pointwise_log_likelihood(
            m["x"], t, prev + d, STEP, 0.0, 0.0, m["harmonics"], m["effects"],
            prev_counts=prev)[0], -50.0)
    prob = {d: np.exp(v) for d, v in logp.items()}
    np.testing.assert_allclose(sum(prob.values()), 1.0, atol=1e-9)
    mean = sum(prob[d] * logp[d] for d in prob)
    var = sum(prob[d] * logp[d] ** 2 for d in prob) - mean ** 2
    observed = np.select([c - prev == d for d in prob], [logp[d] for d in prob])
    return (observed - mean)[mask].sum() / np.sqrt(var[mask].sum())


def test_a_misplaced_edge_is_placed_on_its_count():
    # The edge between counts 1 and 2 sits 0.3 step high: transitions out of count 1 and
    # into it come late and early. The sinusoid at its true parameters does not know.
    rng = np.random.default_rng(8)
    t = np.arange(int(20 * 2000.0 / F_HZ)) / 2000.0
    x = (0.5 * A12 * np.sin(2 * np.pi * F_HZ * t + PHASE) + A_EQ) / STEP
    x = x + rng.normal(0, 0.005, t.size)
    c = np.floor(x).astype(np.int64)
    c[(x >= 2) & (x < 2.3)] = 1
    out = compare.misfit_trace(_truth(0.005), t, c)
    assert out["z"] < -10
    assert out["covariate"] == "count before the sample"
    assert out["where"].endswith("count 1 (its edges)") or out["where"].endswith(
        "count 2 (its edges)")


def test_a_second_missed_count_is_placed_in_time():
    rng = np.random.default_rng(9)
    t, c = _readings(rng, 20, 0.005)
    c[int(0.72 * t.size):] -= 1
    out = compare.misfit_trace(_truth(0.005), t, c)
    assert out["covariate"] == "time in the log" and out["z"] < -10
    # The log from the tenth the count was lost in on: 0.7 of the log, in seconds.
    assert out["where"] == f"from {0.7 * t[-1]:.3g} s to the end of the log"


def test_the_report_flags_a_misfit_no_candidate_describes():
    # A 5th harmonic of 0.15 step: outside the candidates, which absorb it as best they can.
    rng = np.random.default_rng(12)
    t = np.arange(int(30 * 2000.0 / F_HZ)) / 2000.0
    phi = 2 * np.pi * F_HZ * t + PHASE
    x = (0.5 * A12 * np.sin(phi) + 0.15 * STEP * np.sin(5 * phi) + A_EQ) / STEP
    c = np.floor(x + rng.normal(0, 0.005, t.size)).astype(np.int64)
    out = compare.compare_effect_models(t, c, STEP, 3)
    check = out["check"]
    assert check["localized"] and not check["trusted"]
    assert check["trace"]["z"] < check["local_z"]
    block = report.effect_model_block(out)
    reason = report.trust_block(_Fit(), block)["A12"]["reason"]
    assert "leaves a misfit" in reason and check["trace"]["where"] in reason
    text = "\n".join(report._effect_lines({"model": block}))
    assert "may stand in for an effect outside the catalogue" in text
    assert f"FAILED: the misfit acts {check['trace']['where']}" in text


class _Fit:
    """What trust_block reads of a fit: convergence and the summary's keys."""
    converged = True
    summary = {"A12": 1.0, "E_b": 0.0, "a_eq": 0.0, "f_hz": 20.0, "offset_a": None,
               "bias_b": None}


@pytest.mark.parametrize("hysteresis", [0.0, STEP / 8])
def test_dwell_ranks_at_the_truth_are_calibrated(hysteresis):
    # The mid-rank of each dwell's end has mean 1/2 and the stated variance under the model:
    # one fixed group's standardised sum and the successive-dwell sum are N(0, 1) over 60 logs
    # (3 standard errors of a mean and of an sd, as above).
    rng = np.random.default_rng(11)
    n = 60
    m = _truth(0.05, hysteresis)
    z_group, z_lag = [], []
    for _ in range(n):
        t, c = _readings(rng, 6, 0.05, hysteresis)
        prev = np.concatenate((c[:1], c[:-1]))

        def log_p(readings, before):
            return np.maximum(effects.pointwise_log_likelihood(
                m["x"], t, readings, STEP, 0.0, 0.0, m["harmonics"], m["effects"],
                prev_counts=before)[0], -50.0)

        s, var, key, _ = compare.dwell_ranks(log_p, c)
        assert np.all((s >= -0.5) & (s <= 0.5)) and np.all((var >= 0) & (var <= 1 / 12))
        group = key == 3 * 2 + 1  # count 2 entered from below: crossed by every stroke
        z_group.append(s[group].sum() / np.sqrt(var[group].sum()))
        num = den = 0.0
        for k in np.unique(key):
            ds = np.flatnonzero(key == k)
            num += np.sum(s[ds[:-1]] * s[ds[1:]])
            den += np.sum(s[ds[:-1]] ** 2 * var[ds[1:]])
        z_lag.append(num / np.sqrt(den))
    for z in (np.array(z_group), np.array(z_lag)):
        assert abs(z.mean()) < 3 / np.sqrt(n)
        assert abs(z.std(ddof=1) - 1) < 3 / np.sqrt(2 * (n - 1))


def test_dwell_rank_moments_are_exact():
    # The mid-rank's mean and variance, against the end-time distribution written out: a
    # chain that leaves count 0 with probability 0.3 per sample, with a cut at 4 samples.
    q = np.array([1.0, 0.7, 0.7, 0.7, 0.7])

    def log_p(readings, before):
        return np.log(q)

    p = np.array([0.3, 0.7 * 0.3, 0.49 * 0.3, 0.343 * 0.3, 0.7 ** 4])
    s_by_end = []
    for end in range(1, 6):
        c = np.zeros(5, dtype=np.int64)
        c[end:] = 1
        s, var, _, _ = compare.dwell_ranks(log_p, c)
        s_by_end.append(s[0])
    s_by_end = np.array(s_by_end)
    assert abs(np.sum(p * s_by_end)) < 1e-12
    np.testing.assert_allclose(np.sum(p * s_by_end ** 2), var[0], rtol=1e-12)
    np.testing.assert_allclose(var[0], (1 - np.sum(p ** 3)) / 12, rtol=1e-12)


def test_a_drifting_bias_absorbed_by_the_noise_is_flagged_by_the_dwell_timing():
    # The motion's bias moves 0.3 step over 20 cycles, a term no candidate has. The fitted
    # position noise takes it up (it passes every bin of the log-probability sums), but the
    # dwells end early at one end of the log and late at the other, successively.
    rng = np.random.default_rng(21)
    t = np.arange(int(20 * 2000.0 / F_HZ)) / 2000.0
    x = (0.5 * A12 * np.sin(2 * np.pi * F_HZ * t + PHASE) + A_EQ) / STEP
    x = x + 0.3 * (t / t[-1] - 0.5) + rng.normal(0, 0.005, t.size)
    comp = compare.compare_effect_models(t, np.floor(x).astype(np.int64), STEP, seed=3)
    trace = comp["check"]["trace"]
    assert trace["covariate"] == "dwell timing from cycle to cycle"
    assert trace["z"] < compare.DEFAULT_LOCAL_Z
    assert comp["check"]["localized"] and not comp["check"]["trusted"]
    # The figure shows what the trace says: the successive-dwell z in the dwell panel's
    # title, a bar per tenth of the log, a line per kind of dwell.
    detail = comp["trace_detail"]
    assert detail["lag_z"] == pytest.approx(-trace["z"])
    fig = plots.misfit_plot(detail)
    ax_time, ax_parts, ax_dwell = fig.axes
    assert len(ax_time.patches) == 10
    assert f"z = {detail['lag_z']:.1f}" in ax_dwell.get_title()
    kinds = np.unique(detail["dwells"]["key"])
    assert len(ax_dwell.get_lines()) == 1 + sum(
        (detail["dwells"]["key"] == k).sum() >= 2 for k in kinds)


def test_misfit_plot_without_a_comparison_says_so():
    fig = plots.misfit_plot(None)
    assert "no model comparison ran" in fig.axes[0].texts[0].get_text()
