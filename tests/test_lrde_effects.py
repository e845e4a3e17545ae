"""Each effect's likelihood against a brute-force simulation of the readings on a small grid."""
import numpy as np
import pytest

from enclab.lrde import effects, fit

STEP = 1.0e-3
F_HZ = 20.0
A12 = 3.0 * STEP
A_EQ = 0.4 * STEP
PHASE = 0.3


def _row(noise_steps, extra=(), harmonics=()):
    """Internal parameter row with centre 0: ``E_b = a_eq/step - 1/2``."""
    return np.array([A12 / STEP, A_EQ / STEP - 0.5, F_HZ, PHASE, np.log10(noise_steps)]
                    + [v for pair in harmonics for v in pair] + list(extra))


def _sequence_frequencies(sims):
    seqs, freq = np.unique(sims, axis=0, return_counts=True)
    return seqs, freq / sims.shape[0]


def _check(prob, freq, n):
    """Model probabilities against Monte Carlo frequencies: 5 binomial standard errors."""
    se = np.sqrt(prob * (1 - prob) / n) + 1.0 / n
    assert np.all(np.abs(freq - prob) < 5 * se), np.column_stack((prob, freq, se))


def test_no_effect_matches_the_fit_likelihood():
    t = np.linspace(0.0, 0.05, 101)
    c = effects.simulate_counts(np.random.default_rng(0), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                noise_std=0.05 * STEP)
    row = _row(0.05)
    ours = effects.log_likelihood(row[None, :], t, c, STEP, 0.0, 0.0)
    ref = fit.log_likelihood(row[None, :], t, c, STEP, 0.0, 0.0)
    np.testing.assert_allclose(ours, ref, rtol=1e-10)


def test_hysteresis_transition_probabilities_match_a_relay_simulation():
    # Three samples across a rising level: P(k1, k2 | k0) of the relay with a dead band.
    w, noise = 0.4, 0.3
    t = np.array([0.0, 0.004, 0.008]) + 0.0
    n = 200_000
    sims = effects.simulate_counts(np.random.default_rng(1), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                   noise_std=noise * STEP, hysteresis=w * STEP, n_rep=n)
    row = _row(noise, extra=[w])
    no_hyst = _row(noise)
    checked = 0
    for k0 in np.unique(sims[:, 0]):
        sub = sims[sims[:, 0] == k0]
        if sub.shape[0] < 5000:
            continue
        seqs, freq = _sequence_frequencies(sub)
        keep = freq > 0.01
        prob = np.array([np.exp(effects.pointwise_log_likelihood(
            row, t, s, STEP, 0.0, 0.0, effects=("hysteresis",))[0, 1:].sum()) for s in seqs])
        _check(prob[keep], freq[keep], sub.shape[0])
        # The same readings without the dead band are far from the relay's frequencies.
        plain = np.array([np.exp(effects.pointwise_log_likelihood(
            no_hyst, t, s, STEP, 0.0, 0.0)[0, 1:].sum()) for s in seqs])
        assert np.max(np.abs(plain[keep] - freq[keep])) > 0.05
        checked += 1
    assert checked >= 2


def test_dead_band_on_every_other_cycle_reads_each_sample_after_its_true_predecessor():
    # A dead band's state is the reading just before each sample in the log. Every other cycle
    # joined into one array (a held-out fold) has a seam per cycle, where the array's previous
    # element is a reading from a cycle earlier: with the true predecessors each sample scores
    # as in the whole log, whatever the cycle origin; the array's own predecessors can read a
    # transition that never happened.
    w, noise = 0.3, 0.02
    t = np.arange(int(40 * 2000.0 / F_HZ) + 37) / 2000.0
    c = effects.simulate_counts(np.random.default_rng(4), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                noise_std=noise * STEP, hysteresis=w * STEP)
    row = _row(noise, extra=[w])
    whole = effects.pointwise_log_likelihood(row, t, c, STEP, 0.0, 0.0,
                                             effects=("hysteresis",))[0]
    prev = np.concatenate((c[:1], c[:-1]))
    losses = []
    for origin in np.linspace(0.0, 1.0, 40, endpoint=False):
        fold = np.floor(t * F_HZ + origin).astype(int) % 2 == 0
        joined = effects.pointwise_log_likelihood(row, t[fold], c[fold], STEP, 0.0, 0.0,
                                                  effects=("hysteresis",),
                                                  prev_counts=prev[fold])[0]
        np.testing.assert_allclose(joined, whole[fold], rtol=1e-12, atol=1e-300)
        total = effects.log_likelihood(row, t[fold], c[fold], STEP, 0.0, 0.0,
                                       effects=("hysteresis",), prev_counts=prev[fold])
        assert total == pytest.approx(whole[fold].sum(), rel=1e-12)
        own = effects.pointwise_log_likelihood(row, t[fold], c[fold], STEP, 0.0, 0.0,
                                               effects=("hysteresis",))[0]
        losses.append(whole[fold].sum() - own.sum())
    # Where noise moved a switch by a sample, a seam reads a switch back into the band.
    assert max(losses) > 20.0
    with pytest.raises(ValueError, match="prev_counts"):
        effects.pointwise_log_likelihood(row, t, c, STEP, 0.0, 0.0, effects=("hysteresis",),
                                         prev_counts=prev[1:])


def test_drift_reading_probabilities_match_simulation():
    kappa = 0.5  # 1/s: the frequency grows by 50 % per second
    noise = 0.2
    t = np.array([0.6, 0.61, 0.62, 0.635])
    n = 100_000
    sims = effects.simulate_counts(np.random.default_rng(2), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                   noise_std=noise * STEP, drift=kappa, n_rep=n)
    row = _row(noise, extra=[kappa])
    for j in range(t.size):
        values, freq = np.unique(sims[:, j], return_counts=True)
        freq = freq / n
        prob = np.exp([effects.pointwise_log_likelihood(row, t[j:j + 1], [v], STEP, 0.0, 0.0,
                                                        effects=("drift",))[0, 0]
                       for v in values])
        _check(prob, freq, n)
    # Without the drift term the samples are read at the wrong phase.
    gaps = []
    for j in range(t.size):
        values, freq = np.unique(sims[:, j], return_counts=True)
        prob0 = np.exp([effects.pointwise_log_likelihood(_row(noise), t[j:j + 1], [v], STEP,
                                                         0.0, 0.0)[0, 0] for v in values])
        gaps.append(np.max(np.abs(prob0 - freq / n)))
    assert max(gaps) > 0.1


def test_time_jitter_reading_probabilities_match_simulation():
    # sigma_t = 0.6 ms: omega sigma_t = 0.075, so the neglected curvature term is below
    # (omega sigma_t)^2 A / 2 = 0.004 step, far below the probabilities' resolution here.
    sig_t, noise = 6e-4, 0.02
    t = np.array([0.0, 0.003, 0.006, 0.009, 0.0125])
    dt = float(np.median(np.diff(t)))
    n = 100_000
    sims = effects.simulate_counts(np.random.default_rng(3), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                   noise_std=noise * STEP, time_jitter=sig_t, n_rep=n)
    row = _row(noise, extra=[sig_t / dt])
    for j in range(t.size):
        values, freq = np.unique(sims[:, j], return_counts=True)
        # The likelihood takes dt from the times it is given: evaluate on the whole grid.
        prob = []
        for v in values:
            c = sims[0].copy()
            c[j] = v
            prob.append(np.exp(effects.pointwise_log_likelihood(
                row, t, c, STEP, 0.0, 0.0, effects=("time_jitter",))[0, j]))
        _check(np.array(prob), freq / n, n)


def test_count_jump_marginal_matches_simulation_of_a_random_jump():
    # Five samples; the jump gap uniform over the four gaps, sign +-1; the shorter segment is
    # the offset one (the reference frame is the longer segment's).
    noise = 0.25
    t = np.array([0.0, 0.003, 0.006, 0.009, 0.012])
    n = 200_000
    rng = np.random.default_rng(4)
    base = effects.simulate_counts(rng, t, STEP, A12, A_EQ, F_HZ, PHASE, noise_std=noise * STEP,
                                   n_rep=n)
    gap = rng.integers(1, t.size, n)
    sign = rng.choice([-1, 1], n)
    idx = np.arange(t.size)
    first_short = gap < t.size - gap
    shorter = np.where(first_short[:, None], idx[None, :] < gap[:, None],
                       idx[None, :] >= gap[:, None])
    sims = base + sign[:, None] * shorter
    seqs, freq = _sequence_frequencies(sims)
    keep = freq > 0.003
    row = _row(noise)
    prob = np.exp([effects.log_likelihood(row, t, s, STEP, 0.0, 0.0, effects=("count_jump",))
                   for s in seqs[keep]])
    _check(prob, freq[keep], n)
    assert keep.sum() >= 5


def test_jump_posterior_finds_a_missed_count():
    t = np.arange(2000) / 2000.0
    c = effects.simulate_counts(np.random.default_rng(5), t, STEP, A12, A_EQ, F_HZ, PHASE,
                                noise_std=0.01 * STEP, jump=(1400, -1))
    row = _row(0.01)
    index, delta, mass, offsets = effects.jump_posterior(row, t, c, STEP, 0.0, 0.0,
                                                         effects=("count_jump",))
    # The jump is located to within the dwell that hides it (a reading change must show it).
    assert delta == -1 and abs(index - 1400) < 60
    assert offsets[-1] == -1 and offsets[0] == 0


def test_effect_names_are_checked():
    with pytest.raises(ValueError, match="effects"):
        effects.check_effects(("backlash",))
    assert effects.check_effects(("time_jitter", "hysteresis")) == ("hysteresis", "time_jitter")


@pytest.mark.parametrize("both_deep", [0.5, 0.0])
def test_interval_log_probability_matches_the_exact_form_in_every_regime(both_deep):
    # Bounds across both tails and widths from 1e-3 to 30 standard deviations, and a share
    # of entries with both bounds beyond 8: those are left out (value above -1.3e-15), the
    # others agree with the reflected two-bound form to rounding. With half the entries left
    # out the rest are gathered and evaluated by kind; with none, all are evaluated in place.
    rng = np.random.default_rng(11)
    lower = rng.uniform(-40.0, 40.0, (64, 400))
    upper = lower + 10.0 ** rng.uniform(-3.0, 1.5, lower.shape)
    deep = rng.uniform(size=lower.shape) < both_deep
    lower[deep] = -rng.uniform(8.01, 40.0, deep.sum())
    upper[deep] = rng.uniform(8.01, 40.0, deep.sum())
    if both_deep == 0.0:  # no wide interval reaches past both -8 and 8 either
        upper = np.where((lower < -8) & (upper > 8), 7.5, upper)
    keep, vals = effects._log_interval_near(lower, upper)
    assert (keep is None) == (both_deep == 0.0)
    full = effects._log_interval_full(lower, upper).ravel()
    exact = effects._log_interval(lower, upper).ravel()
    left_out = (lower.ravel() < -8) & (upper.ravel() > 8)
    assert np.all(full[left_out] == 0.0) and np.all(exact[left_out] > -1.3e-15)
    if keep is not None:
        np.testing.assert_array_equal(keep, np.flatnonzero(~left_out))
        np.testing.assert_array_equal(vals, full[keep])
    np.testing.assert_allclose(full[~left_out], exact[~left_out], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(effects._log_interval_rows(lower, upper),
                               full.reshape(lower.shape).sum(axis=1), rtol=1e-12)
