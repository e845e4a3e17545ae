"""Bayesian LRDE fit: likelihood numerics, recovery, identifiability, seeding."""
import emcee
import numpy as np
import pytest
from scipy.special import ndtr

from enclab.lrde import fit, model, simulate

STEP = simulate.ROS_DRILL_STEP
SMALL = {"n_ensembles": 2, "n_walkers": 16, "n_steps": 200, "n_burn": 120}


def test_log_interval_prob_matches_direct_and_tails():
    rng = np.random.default_rng(0)
    lower = rng.uniform(-6, 6, 2000)
    upper = lower + rng.uniform(0.5, 10, 2000)
    direct = np.log(ndtr(upper) - ndtr(lower))
    # Away from the tails the direct difference is accurate to ~1e-16 / p; p >= 1e-10 here.
    ok = (ndtr(upper) - ndtr(lower)) > 1e-6
    np.testing.assert_allclose(fit._log_interval_prob(lower, upper)[ok], direct[ok], rtol=1e-9)
    # Far upper tail: Phi(u) - Phi(l) = Phi(-l) - Phi(-u) ~ phi(l)/l for l = 40, u = 60;
    # Mills ratio asymptotics give log p = -l^2/2 - log(l sqrt(2 pi)) - 1/l^2 + O(l^-4).
    l_, u_ = np.array([40.0]), np.array([60.0])
    expected = -800.0 - np.log(40.0 * np.sqrt(2 * np.pi)) - 1 / 1600
    assert fit._log_interval_prob(l_, u_)[0] == pytest.approx(expected, abs=1e-5)
    assert fit._log_interval_prob(-u_, -l_)[0] == pytest.approx(expected, abs=1e-5)
    # Deep inside: 0.
    assert fit._log_interval_prob(np.array([-30.0]), np.array([30.0]))[0] == 0.0


def test_sine_on_grid_matches_numpy_sine_on_long_logs():
    # 1e6 samples (500 s at 2 kHz): the block rotation takes no recurrence, so its error stays
    # at the angle's rounding (|angle| <= 2 pi f (t_max - t_ref) ~ 6e4 rad, ulp ~ 7e-12).
    rng = np.random.default_rng(4)
    t = 3.0 + np.arange(1_000_000) / 2000.0
    grid = fit.uniform_grid(t)
    assert grid is not None and grid[2] == t.size
    omega = 2 * np.pi * rng.uniform(15, 25, 4)
    phase = rng.uniform(-np.pi, np.pi, 4)
    t_ref = 0.5 * (t[0] + t[-1])
    direct = np.sin(np.multiply.outer(omega, t - t_ref) + phase[:, None])
    angle_ulp = np.spacing(np.max(omega) * (t[-1] - t_ref))
    np.testing.assert_allclose(fit._sine_on_grid(omega, phase, grid, t_ref), direct, rtol=0,
                               atol=8 * angle_ulp)
    # Timestamp jitter (here 1e-6 s on a 0.5 ms grid) takes the direct path.
    jittered = t[:5000] + rng.normal(0, 1e-6, 5000)
    assert fit.uniform_grid(np.sort(jittered)) is None


def test_likelihood_paths_and_sigma_prior_agree_with_definitions():
    df, p = _log(21, n_cycles=4)
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    init = fit.initial_guess(t, c, STEP)
    rng = np.random.default_rng(5)
    x0 = np.array([init["A12"] / STEP, init["E_b"] / STEP, init["f_hz"], init["phase"], -2.0])
    rows = x0 + np.array([0.01, 0.01, 1e-3, 0.01, 0.8]) * rng.standard_normal((12, 5))
    kw = dict(t=t, counts=c, step=STEP, centre_count=init["centre_count"], t_ref=init["t_ref"])
    direct = fit.log_likelihood(rows, **kw)
    on_grid = fit.log_likelihood(rows, grid=fit.uniform_grid(t), **kw)
    np.testing.assert_allclose(on_grid, direct, rtol=1e-10)
    # Definition: sum of log(Phi(u) - Phi(l)) over every sample, no deep-interval shortcut.
    A, eb, f, ph, ls = rows[0]
    z = init["centre_count"] + 0.5 + eb + 0.5 * A * np.sin(2 * np.pi * f * (t - init["t_ref"]) + ph)
    s = 10.0 ** ls
    reference = fit._log_interval_prob((c - z) / s, (c + 1 - z) / s).sum()
    assert direct[0] == pytest.approx(reference, rel=1e-12, abs=1e-9)
    bounds = np.array([[-10, 10], [-10, 10], [0, 100], [-50, 50], [-5, 0]], dtype=float)
    lu = fit.log_probability(rows, bounds=bounds, sigma_prior="log-uniform", **kw)
    un = fit.log_probability(rows, bounds=bounds, sigma_prior="uniform", **kw)
    np.testing.assert_allclose(un - lu, np.log(10.0) * rows[:, 4], rtol=1e-12)
    with pytest.raises(ValueError, match="sigma_prior"):
        fit.log_probability(rows, bounds=bounds, sigma_prior="flat", **kw)


def _log(seed, n_cycles=5, noise=0.02, offset_frac=0.4, E_frac=0.3, truth_step=None):
    A12 = 3.44 * STEP
    E_b = E_frac * 0.5 * model.epsilon(A12, STEP)
    bias = E_b + 0.5 * STEP - offset_frac * STEP
    return simulate.open_loop_log(np.random.default_rng(seed), A12=A12, bias=bias,
                                  offset_frac=offset_frac, n_cycles=n_cycles,
                                  noise_std=noise * STEP, truth_step=truth_step)


def test_small_fit_recovers_stroke_and_bias_deviation():
    df, p = _log(11, truth_step=STEP / 100)
    truth = df["truth_counts"].to_numpy() * STEP / 100
    r = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=3,
                         truth=truth, **SMALL)
    s = r.summary
    assert s["A12"]["q05"] < p["A12"] < s["A12"]["q95"]
    assert s["E_b"]["q05"] < p["E_b"] < s["E_b"]["q95"]
    assert s["a_eq"]["q05"] < p["a_eq"] < s["a_eq"]["q95"]
    assert s["f_hz"]["q05"] < p["f_hz"] < s["f_hz"]["q95"]
    # The posterior is far tighter than the step-count band (2 steps wide) it starts from.
    assert s["A12"]["q95"] - s["A12"]["q05"] < 0.1 * STEP
    # The truth channel identifies b (to its 0.01-step rounding) and hence a = a_eq - b.
    assert r.bias_b["median"] == pytest.approx(p["bias"], abs=0.01 * STEP)
    # b's interval comes from the truth's residual: non-degenerate, and of the order of the
    # residual's white-noise value: the truth reads the jittered angle (0.02 step) with a
    # 0.01-step rounding, over sqrt(N) (N = 500 samples here).
    b_width = r.bias_b["q95"] - r.bias_b["q05"]
    residual_std = STEP * np.sqrt(0.02**2 + 0.01**2 / 12)
    white_width = 2 * 1.645 * residual_std / np.sqrt(len(df))
    assert 0.3 * white_width < b_width < 5 * white_width
    assert r.offset_a["q05"] - 0.01 * STEP < p["offset_a"] < r.offset_a["q95"] + 0.01 * STEP
    assert r.samples.shape == (2 * 16 * 200, 5)
    assert set(r.rhat) == set(fit.PARAM_NAMES) and all(np.isfinite(list(r.tau.values())))


def test_without_extra_information_a_and_b_are_not_reported():
    df, p = _log(12, n_cycles=3)
    kwargs = dict(SMALL, n_steps=100, n_burn=60)
    r = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=1, **kwargs)
    assert r.offset_a is None and r.bias_b is None
    assert "a_eq = a + b" in r.reason
    assert "offset_a" not in r.summary
    # A known rest position identifies a = a_eq - b exactly as a shift of a_eq's posterior.
    r2 = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=1,
                          rest_position=p["bias"], **kwargs)
    assert r2.offset_a["median"] == pytest.approx(r2.summary["a_eq"]["median"] - p["bias"])
    # Same seed, same draws: the ensembles are seeded explicitly.
    np.testing.assert_array_equal(r.samples, r2.samples)


def test_fit_validates():
    t = np.arange(100) / 1000.0
    with pytest.raises(ValueError, match="counts"):
        fit.fit_sinusoid(t, np.zeros(100), STEP, seed=0)
    with pytest.raises(ValueError, match="n_walkers"):
        fit.fit_sinusoid(t, np.zeros(100, dtype=np.int64), STEP, seed=0, n_walkers=15)
    with pytest.raises(ValueError, match="no complete oscillation"):
        fit.fit_sinusoid(t, np.zeros(100, dtype=np.int64), STEP, seed=0)
    with pytest.raises(ValueError, match=r"moves must be one of \['de', 'stretch'\]"):
        fit.fit_sinusoid(t, np.zeros(100, dtype=np.int64), STEP, seed=0, moves="de+snooker")


def test_sigma_range_bounds_the_jitter_posterior():
    df, p = _log(13, n_cycles=4)
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    kwargs = dict(SMALL, n_steps=100, n_burn=60)
    r = fit.fit_sinusoid(t, c, STEP, seed=2, sigma_range=(0.01, 0.02), **kwargs)
    sigma_steps = r.samples[:, 4] / STEP
    assert sigma_steps.min() > 0.01 and sigma_steps.max() < 0.02
    for bad in [(0.02, 0.01), (0.0, 0.1), (-1.0, 0.1), (0.1, 1.0)]:
        with pytest.raises(ValueError, match="sigma_range"):
            fit.fit_sinusoid(t, c, STEP, seed=2, sigma_range=bad, **kwargs)


@pytest.mark.slow
def test_posterior_intervals_are_calibrated_on_simulated_draws():
    # 40 independent draws (a ~ U(0, step), A12 ~ U(3, 5) step, E_b inside Prop. 1's band),
    # 4-cycle logs with 0.02-step noise. The number of 90 % intervals covering A12 is
    # Binomial(40, 0.9): mean 36, sd 1.9; accept [30, 40] (a 3.2-sd lower bound: a
    # calibrated posterior fails with probability < 0.1 %, one covering only 75 % of the
    # time passes with probability ~ 4 %).
    root = np.random.SeedSequence(2024)
    covered = {"A12": 0, "E_b": 0}
    for child in root.spawn(40):
        sim, fit_seed = child.spawn(2)
        rng = np.random.default_rng(sim)
        A12 = rng.uniform(3.0, 5.0) * STEP
        E_b = rng.uniform(-0.5, 0.5) * model.epsilon(A12, STEP)
        a_frac = rng.uniform()
        df, p = simulate.open_loop_log(rng, A12=A12, bias=E_b + 0.5 * STEP - a_frac * STEP,
                                       offset_frac=a_frac, n_cycles=4, noise_std=0.02 * STEP)
        r = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=fit_seed,
                             n_ensembles=2, n_walkers=16, n_steps=150, n_burn=100)
        for name, true in (("A12", A12), ("E_b", E_b)):
            covered[name] += r.summary[name]["q05"] < true < r.summary[name]["q95"]
    assert 30 <= covered["A12"] <= 40
    assert 30 <= covered["E_b"] <= 40


def _gaussian_log_prob(x):
    return -0.5 * np.sum(x**2, axis=1)


def _ensembles_chain(seeds, starts, n_steps, inner="DEMove"):
    import emcee

    randoms = [np.random.RandomState(s) for s in seeds]
    move = fit._EnsemblesMove(getattr(emcee.moves, inner)(), randoms)
    sampler = emcee.EnsembleSampler(starts.shape[0], starts.shape[1], _gaussian_log_prob,
                                    vectorize=True, moves=[(move, 1.0)])
    sampler.random_state = np.random.RandomState(0).get_state()
    sampler.run_mcmc(starts, n_steps, progress=False)
    return sampler.get_chain()


def test_ensembles_side_by_side_never_exchange_information():
    """Ensemble 0's chain is bit for bit the same next to two different other ensembles:
    its proposals, complements and acceptances use only its own walkers and random state."""
    rng = np.random.default_rng(1)
    mine = rng.normal(size=(16, 3))
    chain_b = _ensembles_chain([11, 12], np.vstack([mine, rng.normal(size=(16, 3)) + 5]), 60)
    chain_c = _ensembles_chain([11, 99], np.vstack([mine, rng.normal(size=(16, 3)) - 3]), 60)
    np.testing.assert_array_equal(chain_b[:, :16], chain_c[:, :16])
    assert not np.array_equal(chain_b[:, 16:], chain_c[:, 16:])


@pytest.mark.parametrize("inner", ["DEMove", "StretchMove"])
def test_ensembles_side_by_side_sample_the_target(inner):
    """Three ensembles of 20 walkers on a 3-D standard normal, with each of the moves the fit
    offers (the stretch move's proposal carries a Hastings factor; emcee 3.1.6's snooker move
    is not offered: alone it gives variances of about 0.78 here): each ensemble's mean and
    variance are those of the target within 4 standard errors (ESS from the autocorrelation
    time, variance of s^2 about 2/ESS for a normal)."""
    import emcee

    rng = np.random.default_rng(2)
    chain = _ensembles_chain([1, 2, 3], rng.normal(size=(60, 3)) * 0.1, 2500, inner)[500:]
    for g in range(3):
        block = chain[:, 20 * g:20 * (g + 1)]
        tau = float(np.max(emcee.autocorr.integrated_time(block, quiet=True)))
        ess = block.shape[0] * block.shape[1] / tau
        values = block.reshape(-1, 3)
        assert np.all(np.abs(values.mean(axis=0)) < 4 / np.sqrt(ess))
        assert np.all(np.abs(values.var(axis=0) - 1) < 4 * np.sqrt(2 / ess))


def test_chains_go_on_until_converged_up_to_max_steps():
    # 2 ensembles x 16 walkers x 50 steps hold 1600 draws per parameter: ESS >= 1000 would
    # need an autocorrelation time below 1.6 steps, which the DE moves never reach here, so the
    # short fit stops unconverged and the extended one goes on in blocks of n_steps.
    df, _ = _log(11)
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    kwargs = dict(SMALL, n_steps=50, n_burn=60)
    short = fit.fit_sinusoid(t, c, STEP, seed=5, **kwargs)
    assert short.chains.shape[1] == 50 and not short.converged
    longer = fit.fit_sinusoid(t, c, STEP, seed=5, max_steps=400, **kwargs)
    kept = longer.chains.shape[1]
    assert kept % 50 == 0 and 50 < kept <= 400
    assert longer.converged or kept == 400
    # the first block is the short fit's chain: the extension only appends
    np.testing.assert_array_equal(longer.chains[:, :50], short.chains)
    with pytest.raises(ValueError, match="max_steps"):
        fit.fit_sinusoid(t, c, STEP, seed=5, max_steps=40, **kwargs)


def test_before_and_after_fits_side_by_side_equal_the_sequential_ones():
    """The pipeline's emcee fits in forked workers give the same chains as in turn."""
    from enclab.lrde import pipeline

    df, _ = _log(23, n_cycles=4)
    t, c = df["t"].to_numpy(), df["counts"].to_numpy()
    small = {"n_ensembles": 2, "n_walkers": 16, "n_steps": 50, "n_burn": 10}
    rich = dict(small, harmonics=(3,), effects=("hysteresis",))
    other = dict(small, harmonics=(3,))

    def jobs():
        # Fresh seed sequences per run: spawning children advances a SeedSequence.
        return [(np.random.SeedSequence(1), small), (np.random.SeedSequence(3), other),
                (np.random.SeedSequence(2), rich)]

    one = pipeline._run_fits(t, c, STEP, jobs(), threads=1)
    two = pipeline._run_fits(t, c, STEP, jobs(), threads=2)
    three = pipeline._run_fits(t, c, STEP, jobs(), threads=3)
    for a, b, d in zip(one, two, three):
        np.testing.assert_array_equal(a.chains, b.chains)
        np.testing.assert_array_equal(a.chains, d.chains)
        assert a.summary == b.summary and a.param_names == b.param_names
    assert [r.param_names[5:] for r in one] == [(), ("c3", "s3"), ("c3", "s3", "hysteresis")]


def _stub_fit(samples, b=None, centre=0.0, converged=True, harmonics=()):
    n = samples.shape[0]
    a_eq = (centre + 0.5) * STEP + samples[:, 1]
    diag = {k: 1.0 for k in fit.PARAM_NAMES}
    return fit.FitResult(
        param_names=fit.PARAM_NAMES, samples=samples, chains=None, a_eq_samples=a_eq,
        summary={}, offset_a=None, bias_b=None, reason="r", tau=dict(diag, A12=5.0),
        rhat=dict(diag, A12=1.002), ess=dict(diag, A12=4000.0 + n), converged=converged,
        step=STEP, centre_count=centre, steps_pp=4, t_ref=0.0, init={}, acceptance=0.3,
        wall_time_s=1.0, settings={"n_walkers": 16, "harmonics": list(harmonics)},
        b_samples=None if b is None else np.full(n, b))


def test_pooled_posterior_is_the_equal_weight_mixture_of_the_fits():
    rng = np.random.default_rng(4)
    x = rng.standard_normal((4000, 5)) * 1e-4
    y = rng.standard_normal((2000, 5)) * 1e-4 + 3e-4
    a, b = _stub_fit(x, b=1e-3), _stub_fit(y, b=1e-3, converged=False, harmonics=(3,))
    pooled = fit.pool_fits([a, b])
    # Equal shares: every other sample of the longer fit, all of the shorter one.
    both = np.concatenate((x[np.round(np.linspace(0, 3999, 2000)).astype(int)], y))
    for j, name in enumerate(fit.PARAM_NAMES):
        q05, q50, q95 = np.quantile(both[:, j], [0.05, 0.5, 0.95])
        assert pooled.summary[name] == {"median": q50, "q05": q05, "q95": q95}
    # An equal mixture's 5 % point lies between those of its parts.
    assert np.quantile(x[:, 0], 0.05) < pooled.summary["A12"]["q05"] < np.quantile(y[:, 0], 0.05)
    a_eq = 0.5 * STEP + both[:, 1]
    assert pooled.summary["offset_a"]["median"] == pytest.approx(np.median(a_eq) - 1e-3)
    assert pooled.bias_b["q05"] == pooled.bias_b["q95"] == pytest.approx(1e-3)
    assert pooled.settings["pooled"] == ["sinusoid", "harmonic3"]
    assert pooled.settings["n_walkers"] == 16 and pooled.harmonics == ()
    assert not pooled.converged and pooled.ess["A12"] == 6000.0
    # Without b in every fit the offset is not identified; fits of other logs are refused.
    assert fit.pool_fits([a, _stub_fit(y)]).offset_a is None
    with pytest.raises(ValueError, match="different logs"):
        fit.pool_fits([a, _stub_fit(y, centre=1.0)])
    with pytest.raises(ValueError, match="at least two"):
        fit.pool_fits([a])
    # Fits whose diagnostics are of their own parameters (loop structures: the filter's,
    # one with a dead band's width too): the worst of each over the fits that sample it.
    plain, band = _stub_fit(x), _stub_fit(y)
    plain.tau, plain.rhat, plain.ess = {"p": 30.0}, {"p": 1.004}, {"p": 3000.0}
    band.tau = {"p": 20.0, "hysteresis": 90.0}
    band.rhat = {"p": 1.008, "hysteresis": 1.02}
    band.ess = {"p": 5000.0, "hysteresis": 900.0}
    loops = fit.pool_fits([plain, band])
    assert loops.tau == {"p": 30.0, "hysteresis": 90.0}
    assert loops.rhat == {"p": 1.008, "hysteresis": 1.02}
    assert loops.ess == {"p": 3000.0, "hysteresis": 900.0}


@pytest.mark.parametrize("amplitude_steps", [0.0, 0.3, 2.7, 40.0, 310.0])
def test_truth_rounding_bound_holds_the_phase_averaged_error_for_every_bias(amplitude_steps):
    """Brute force: the rounding error of b + A sin(phi), averaged over a fine phase grid, for
    biases across one step, never exceeds the bound, which is also at most half a step and
    not needlessly wide (within 3x of the worst bias's error: the sum of |terms| against the
    sum of terms of one phase)."""
    s = 1.0
    phi = np.linspace(0.0, 2.0 * np.pi, 100_000, endpoint=False)
    worst = 0.0
    for b in np.linspace(0.0, 1.0, 101):
        theta = b + amplitude_steps * np.sin(phi)
        worst = max(worst, abs(np.mean(s * np.round(theta / s) - theta)))
    bound = fit.truth_rounding_bound(amplitude_steps, s)
    assert worst <= bound <= 0.5 * s
    assert bound <= 3.0 * worst


@pytest.mark.parametrize("A12_steps, kw, terms", [
    (3.02, {"hysteresis": 0.136}, {"effects": ("hysteresis",)}),   # readings show A12 - w
    (4.99, {"noise_std": 0.1}, {}),                                   # noise reads past 5 steps
    (4.98, {"harmonics": {3: (0.08, 0.0)}}, {"harmonics": (3,)}),     # flattened turning points
])
def test_the_stroke_prior_holds_a_stroke_whose_readings_reach_another_count(A12_steps, kw,
                                                                            terms):
    """The eq. (6) band around the readings' peak-to-peak count is widened by what each term
    can do to where the readings turn, so that the truth is inside the prior."""
    from enclab.lrde import effects

    step = simulate.ROS_DRILL_STEP
    rng = np.random.default_rng(7)
    t = np.arange(int(20 * 2000 / 20.0)) / 2000.0
    scaled = {k: (v * step if k in ("hysteresis", "noise_std") else
                  {h: (c * step, s * step) for h, (c, s) in v.items()}) for k, v in kw.items()}
    counts = effects.simulate_counts(rng, t, step, A12_steps * step, 0.5 * step, 20.0, 0.3,
                                     **scaled)
    setup = fit._setup(t, counts, step, None, None, "uniform", terms.get("harmonics", ()),
                       terms.get("effects", ()))
    lo, hi = setup["bounds"][0]
    assert lo < A12_steps < hi


def test_walkers_are_raised_to_twice_the_parameters_of_a_rich_model():
    """Two harmonics make nine parameters: 16 walkers per ensemble would leave emcee's
    ensemble move on a subspace, so the fit takes 18."""
    df, _ = _log(23, n_cycles=4)
    r = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, 1, n_ensembles=2,
                         n_walkers=16, n_steps=50, n_burn=10, harmonics=(2, 3))
    assert len(r.param_names) == 9
    assert r.chains.shape[2] == 18 and r.settings["n_walkers"] == 18


def test_with_harmonics_A12_is_the_peak_to_peak_stroke_of_the_whole_motion():
    # sin(phi) + s3 sin(3 phi) peaks at phi = pi/2 for |s3| < A/18: a stroke of A12 - 2 s3,
    # 0.2 step above the fundamental's here.
    A12, s3 = 3.7 * STEP, -0.1 * STEP
    df, p = simulate.open_loop_log(np.random.default_rng(5), A12=A12, bias=0.15 * STEP,
                                   offset_frac=0.35, n_cycles=12, noise_std=0.005 * STEP,
                                   distortion={3: (0.0, s3)})
    r = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=2,
                         harmonics=(3,), **SMALL)
    names = list(r.param_names)
    stroke = model.stroke_and_midpoint(r.samples[:, 0], (3,), r.samples[:, [names.index("c3")]],
                                       r.samples[:, [names.index("s3")]])[0]
    np.testing.assert_array_equal(r.stroke, stroke)
    q05, q50, q95 = np.quantile(stroke, [0.05, 0.5, 0.95])
    assert r.summary["A12"] == {"median": q50, "q05": q05, "q95": q95}
    assert r.summary["A12_fundamental"]["median"] == np.median(r.samples[:, 0])
    # The reported stroke is near the true one and away from the fundamental's.
    width = q95 - q05
    assert abs(q50 - (A12 - 2 * s3)) < width < abs(q50 - A12)
    # A sine alone reports its A12 column as the stroke.
    sine = fit.fit_sinusoid(df["t"].to_numpy(), df["counts"].to_numpy(), STEP, seed=2, **SMALL)
    assert sine.stroke_samples is None and "A12_fundamental" not in sine.summary
    np.testing.assert_array_equal(sine.stroke, sine.samples[:, 0])
    # Pooled, each fit contributes its stroke; restricted, the per-sample arrays stay paired.
    pooled = fit.pool_fits([sine, r])
    picks = np.round(np.linspace(0, r.samples.shape[0] - 1, sine.samples.shape[0])).astype(int)
    both = np.concatenate((sine.samples[:, 0], stroke[picks]))
    assert pooled.summary["A12"]["median"] == np.median(both)
    np.testing.assert_array_equal(r.take([3, 1]).stroke, stroke[[3, 1]])


def test_a_walker_that_never_moved_leaves_the_chain_diagnostics_defined():
    # AR(1) walkers (tau = 19) in 4 ensembles; one walker of one ensemble holds its value the
    # whole window. Its autocorrelation is 0/0: the time is the other walkers' (emcee on them
    # alone), the same whatever the parameters' order, and the convergence flag with it.
    rng = np.random.default_rng(8)
    phi, n_steps, n_walkers = 0.9, 400, 16
    x = np.empty((4, n_steps, n_walkers, 2))
    x[:, 0] = rng.normal(0.0, 1.0 / np.sqrt(1 - phi**2), (4, n_walkers, 2))
    for j in range(1, n_steps):
        x[:, j] = phi * x[:, j - 1] + rng.normal(size=(4, n_walkers, 2))
    x[2, :, 5, :] = x[2, 0, 5, :]
    tau, rhat, ess = fit._chain_diagnostics(x, ["a", "b"])
    for i, name in enumerate("ab"):
        expected = max(
            float(emcee.autocorr.integrated_time(
                np.delete(x[e, :, :, i], 5, axis=1)[:, :, None] if e == 2
                else x[e, :, :, i:i + 1], quiet=True)[0]) for e in range(4))
        assert tau[name] == pytest.approx(expected, rel=1e-12)
        assert np.isfinite(rhat[name]) and ess[name] == pytest.approx(x[..., i].size / expected)
    flipped = fit._chain_diagnostics(x[..., ::-1], ["b", "a"])
    assert flipped[0] == pytest.approx(tau) and flipped[2] == pytest.approx(ess)
    # An ensemble none of whose walkers moved: no time is defined, and no sample counts.
    x[1] = x[1, :1]
    tau, _, ess = fit._chain_diagnostics(x, ["a", "b"])
    assert tau == {"a": np.inf, "b": np.inf} and ess == {"a": 0.0, "b": 0.0}
