"""Which motion model explains the coarse readings? Held-out comparison of LRDE fits.

The paper's model is a pure sinusoid. A real drive adds harmonic distortion (a servo that
flattens its turning points, a cam, a nonlinear amplifier); the dwell pattern then differs from
the sinusoid's in a way the 5-parameter fit absorbs into a biased stroke. Candidate models add
harmonics ``c_k cos(k phi) + s_k sin(k phi)`` of the fundamental's phase
(:func:`enclab.lrde.fit.fit_sinusoid` ``harmonics=``).

Method
------
:func:`compare_effect_models` fits each candidate, a motion (:mod:`enclab.lrde.motion`) with
encoder and clock terms (:mod:`enclab.lrde.effects`), by point fits on interleaved folds of
cycles and scores the held-out readings by their plug-in log predictive density per cycle; a
candidate must beat the sinusoid there by ``min_z`` standard errors, in no fold worse, and on
the full-log BIC. :func:`predictive_check` and :func:`misfit_trace` then ask whether the chosen
model explains the readings as well as its own simulations, and where it does not.

References
----------
.. [1] A. Vehtari, A. Gelman, J. Gabry, "Practical Bayesian model evaluation using leave-one-out
   cross-validation and WAIC", Statistics and Computing 27 (2017) 1413-1432 (pointwise elpd
   and its standard error).
"""
from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from enclab.core import parallel
from enclab.lrde import effects as lrde_effects
from enclab.lrde import fit as lrde_fit
from enclab.lrde.effects import model_label

__all__ = ["compare_effect_models", "predictive_check", "misfit_trace", "dwell_ranks",
           "model_label", "alternative_terms", "DEFAULT_CANDIDATES", "DEFAULT_TRUST_Z",
           "DEFAULT_LOCAL_Z"]


# ---------------------------------------------------------------------------------------------
# Encoder, clock and motion effects: held-out comparison of point fits
# ---------------------------------------------------------------------------------------------

#: Predictive check: below this z (whole log) the estimates are untrusted.
DEFAULT_TRUST_Z = -4.0
#: Localized check (:func:`misfit_trace`): below this z in any one bin they are untrusted.
DEFAULT_LOCAL_Z = -5.0

#: Default candidates of :func:`compare_effect_models`: ``(harmonics, effects)`` pairs.
DEFAULT_CANDIDATES = (((), ()), ((2,), ()), ((3,), ())) + tuple(
    ((), (name,)) for name in lrde_effects.EFFECTS)


def alternative_terms(comparison: dict) -> list:
    """``(label, harmonics, effects, point fit)`` of each model ``comparison``
    (:func:`compare_effect_models`) cannot tell from its pick or, when it keeps the
    sinusoid, does not rule out."""
    by_label = {m["label"]: m for m in comparison["models"]}
    labels = comparison["indistinguishable"] + comparison.get("not_ruled_out", [])
    return [(label, tuple(by_label[label]["harmonics"]), tuple(by_label[label]["effects"]),
             comparison["full_fits"][label]) for label in labels]


def _pointwise(m, t, counts, offset=0, prev_counts=None):
    """Held-out pointwise log predictive density of a point fit, blurred in time by an eighth
    of a sample interval: a fit whose jitter collapsed on its own fold must not score the
    other fold's edges as impossible when they sit a fraction of a sample off (the same blur
    for every model, so the comparison stays fair; half a sample hid a 1/8-step dead band)."""
    return lrde_effects.pointwise_log_likelihood(
        m["x"][None, :], t, counts, m["step"], m["centre"], m["t_ref"], m["harmonics"],
        m["effects"], offset=offset, time_blur=0.125 * m["dt"], prev_counts=prev_counts)[0]


def _predict(m, t, counts, t_train, counts_train, prev=None, prev_train=None):
    """Plug-in log predictive density of held-out samples: total and per sample.

    ``prev`` and ``prev_train`` are the readings just before each held-out and each training
    sample in the whole log (the dead band's state; None: the previous array element).

    Without a jump term, the product of the pointwise probabilities. With one, the training
    fit's most probable jump (:func:`enclab.lrde.effects.jump_posterior`) sets the count offset
    of each held-out sample by time; held-out samples between the two training samples that
    bracket the jump take it before any of them with equal probability (a mixture; the
    per-sample values follow its most probable component, shifted to add up to its total).
    """
    if not lrde_effects.offsets_counts(m["effects"]):
        lp = _pointwise(m, t, counts, prev_counts=prev)
        return float(lp.sum()), lp
    index, delta, _, offsets = lrde_effects.jump_posterior(
        m["x"], t_train, counts_train, m["step"], m["centre"], m["t_ref"], m["harmonics"],
        m["effects"], prev_counts=prev_train)
    before_offset, after_offset = int(offsets[index - 1]), int(offsets[index])
    t_lo, t_hi = t_train[index - 1], t_train[index]
    lp_before = _pointwise(m, t, counts, before_offset, prev)
    lp_after = _pointwise(m, t, counts, after_offset, prev)
    gap = np.flatnonzero((t > t_lo) & (t < t_hi))
    n_before = int(np.searchsorted(t, t_lo, side="right"))
    splits = n_before + np.arange(gap.size + 1)
    c_b = np.concatenate(([0.0], np.cumsum(lp_before)))
    c_a = np.concatenate(([0.0], np.cumsum(lp_after)))
    totals = c_b[splits] + (c_a[-1] - c_a[splits])
    total = float(logsumexp(totals) - np.log(totals.size))
    split = int(splits[int(np.argmax(totals))])
    lp = np.concatenate((lp_before[:split], lp_after[split:]))
    return total, lp + (total - lp.sum()) / lp.size


def _blurred_log_lik(m, t, counts) -> float:
    """Full-log log-likelihood of a point fit under the held-out score's time blur.

    Readings are intervals and the position noise of a point fit collapses: a model that
    threads every reading edge between two samples reaches ``log L = 0`` whatever its extra
    terms, so the plain maximum saturates and a BIC built on it only counts parameters. The
    same blur as the held-out score (an eighth of a sample interval) keeps the edges' placement
    in the score. With a jump term the jump is placed as in :func:`_predict`.
    """
    return _predict(m, t, counts, t, counts)[0]


def _si_params(m):
    """Simulator arguments of :func:`enclab.lrde.effects.simulate_counts` from a point fit."""
    x, step = m["x"], m["step"]
    out = {"A12": x[0] * step, "a_eq": (m["centre"] + 0.5 + x[1]) * step, "f_hz": x[2],
           "phase": x[3], "t_ref": m["t_ref"], "noise_std": step * 10.0 ** x[4],
           "harmonics": {k: (x[5 + 2 * j] * step, x[6 + 2 * j] * step)
                         for j, k in enumerate(m["harmonics"])}}
    col = 5 + 2 * len(m["harmonics"])
    for name, scale in zip(lrde_effects.effect_param_names(m["effects"]), m["extra_scale"][
            2 * len(m["harmonics"]):]):
        out[name] = x[col] * scale
        col += 1
    return out


_STROKE_PART = ("lower third", "middle third", "upper third")
_TENTHS = ("1st", "2nd", "3rd", "4th", "5th", "6th", "7th", "8th", "9th", "10th")


def _trace_covariates(m, t, prev):
    """``(covariate, bin per sample, description per bin, short label per bin)`` for
    :func:`misfit_trace`.

    Every covariate is known before the sample is read (the time, the fitted motion, the
    previous reading): binning by the reading itself would select the surprising outcomes and
    bias every bin low."""
    u = (t - t[0]) / max(t[-1] - t[0], np.finfo(float).tiny)
    tenth = np.minimum((u * 10).astype(np.int64), 9)
    time_words = [f"in the {_TENTHS[k]} tenth of the log ({t[0] + (t[-1] - t[0]) * k / 10:.3g} "
                  f"to {t[0] + (t[-1] - t[0]) * (k + 1) / 10:.3g} s)" for k in range(10)]
    drift_col = lrde_effects.parameter_column(m["harmonics"], m["effects"], "bends_phase")
    motion, speed = lrde_effects._motion_and_speed(np.atleast_2d(m["x"]), t, m["t_ref"],
                                                   tuple(m["harmonics"]), drift_col)
    motion, speed = motion[0], speed[0]
    lo, hi = motion.min(), motion.max()
    part = np.minimum(((motion - lo) / max(hi - lo, 1e-12) * 3).astype(np.int64), 2)
    stroke = 3 * (speed < 0) + part
    stroke_words = [f"while the motion {way} through the {_STROKE_PART[k]} of its stroke"
                    for way in ("rises", "falls") for k in range(3)]
    levels, level = np.unique(prev, return_inverse=True)
    level_words = [f"where the reading leaves or holds count {int(c)} (its edges)"
                   for c in levels]
    time_short = [f"{t[0] + (t[-1] - t[0]) * (k + 0.5) / 10:.3g}" for k in range(10)]
    stroke_short = [f"{way} {part}" for way in ("up", "down") for part in ("low", "mid", "high")]
    return [("time in the log", tenth, time_words, time_short),
            ("position and direction of the motion", stroke, stroke_words, stroke_short),
            ("count before the sample", level, level_words, [str(int(c)) for c in levels])]


def dwell_ranks(log_p, c):
    """Mid-ranks of the dwells' ends under a fit: ``(s, var, key, start)`` per dwell.

    A dwell is a run of one reading. Under the fit the readings are a Markov chain, so a
    dwell that starts at sample ``a`` in count ``k`` ends at sample ``j > a`` with probability
    ``p_j = S_{j-1} (1 - q_j)``, where ``q_j`` is the probability of reading ``k`` again after
    ``k`` and ``S`` the running product of the ``q``. The mid-rank ``u = F(b - 1) + p_b / 2``
    of the observed end ``b`` has mean 1/2 and variance ``(1 - sum p_j^3) / 12`` exactly (a
    discrete probability integral transform) given everything before the dwell, so
    ``s = u - 1/2`` is a martingale difference in dwell order. The last dwell, cut by the end
    of the log, ends "after the log" (its remaining probability). ``key`` is ``3 k + e``, with
    ``e`` the side the count was entered from (+1 below, -1 above, 0 at the start), and
    ``start`` the dwell's first sample.
    ``log_p(readings, prev)`` is the fit's pointwise log-probability.
    """
    n = c.size
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    ends = np.r_[starts[1:], n]  # the sample that leaves the dwell; n: the log ends first
    # Minus the running log-probability of staying in each count: it never decreases, so
    # where a dwell's survival falls below e^-far (the rest is negligible) is a bisection.
    lost = {}
    for k in np.unique(c):
        same = np.full(n, k)
        lost[k] = np.concatenate(([0.0], np.cumsum(-np.minimum(log_p(same, same), 0.0))))
    s = np.empty(starts.size)
    var = np.empty(starts.size)
    far = 30.0
    for d, (a, b) in enumerate(zip(starts, ends)):
        run = lost[c[a]]
        stop = int(np.searchsorted(run, run[a + 1] + far)) - (a + 1)
        S = np.exp(run[a + 1] - run[a + 1:a + 2 + stop])  # survival at samples a, a+1, ...
        p = np.append(-np.diff(S), S[-1])  # ends at a+1 .. a+stop, then the rest
        i = b - (a + 1)
        u = 1.0 - S[i] + 0.5 * p[i] if i < p.size - 1 else 1.0 - 0.5 * p[-1]
        s[d] = u - 0.5
        var[d] = max(1.0 - np.sum(p ** 3), 0.0) / 12.0
    entered = np.r_[0, np.sign(c[starts[1:]] - c[starts[1:] - 1])]
    return s, var, c[starts] * 3 + entered, starts


_SUCCESSIVE_DWELLS = "dwell timing from cycle to cycle"


def _dwell_kind(key):
    """``(count, side it was entered from)`` of a :func:`dwell_ranks` key."""
    level, side = divmod(int(key) + 1, 3)
    return level, ("above", "the start of the log", "below")[side]


def _dwell_timing_rows(s, var, key, min_var=0.25) -> tuple:
    """Rows of :func:`misfit_trace` from the timing of the dwells (:func:`dwell_ranks`).

    Two sums of the dwells' centred mid-ranks ``s`` are standardised:

    * per count and the side it was entered from, ``sum s / sqrt(sum var)``: those dwells
      end systematically early or late (an edge off its place, a shape of the motion the fit
      lacks); groups holding less than ``min_var`` in all (3 fully uncertain dwells hold
      ``1/4``) are left out;
    * over successive dwells of one count and entry side, ``sum s_d s_d+1 /
      sqrt(sum s_d^2 var_d+1)`` (self-normalised): successive dwells end early or late
      together. Only a deterministic pattern does that: a slow change over the log, or a
      shape repeated every cycle. A fitted position noise that absorbs such a pattern
      widens each dwell's spread, but cannot make successive dwells independent.

    Returns rows ``{covariate, where, z}``, low ``z`` bad (the first as ``-|z|``), and the
    successive-dwell ``z`` (None without two dwells of one kind).
    """
    rows = []
    worst = None
    num = den = 0.0
    for k in np.unique(key):
        ds = np.flatnonzero(key == k)
        num += np.sum(s[ds[:-1]] * s[ds[1:]])
        den += np.sum(s[ds[:-1]] ** 2 * var[ds[1:]])
        spread = var[ds].sum()
        if spread < min_var:
            continue
        z = s[ds].sum() / np.sqrt(spread)
        if worst is None or -abs(z) < worst["z"]:
            level, side = _dwell_kind(k)
            worst = {"covariate": "dwell length per count",
                     "where": (f"in the dwells in count {level} entered from {side}, which "
                               f"end {'later' if z > 0 else 'earlier'} than the fit expects"),
                     "z": -abs(float(z))}
    if worst is not None:
        rows.append(worst)
    lag_z = float(num / np.sqrt(den)) if den > 0 else None
    if lag_z is not None:
        rows.append({"covariate": _SUCCESSIVE_DWELLS,
                     "where": ("in the dwell timing, where successive dwells of a count end "
                               "early or late together (a change slower than a cycle, or a "
                               "shape repeated every cycle, that the fit does not follow)"),
                     "z": -lag_z})
    return rows, lag_z


def misfit_trace(m, t, counts, min_var=1.0, floor=-50.0, local_z=DEFAULT_LOCAL_Z) -> dict:
    """Where the readings are explained worse than the fit itself expects: a localized check.

    Each reading's log-probability given the one before, ``l_j``, has under the fit an exact
    mean ``E_j`` and variance ``V_j`` over the readings it could have been (previous count and
    its two neighbours: no reading moves further in one sample at the rates this model is
    for). ``l_j - E_j`` is then a martingale difference, so over any set of samples
    ``z = sum(l_j - E_j) / sqrt(sum V_j)`` has mean 0 and variance 1 when the fit is right,
    whichever samples are summed, as long as which are summed is known before each is read.
    It is summed per bin of three such covariates: time in the log (tenths, and the log up to
    or from each tenth), position and direction of the fitted motion (thirds of the stroke,
    rising or falling) and the reading before the sample (transitions out of a count and
    dwell in it). Bins with ``sum V_j < min_var`` (a handful of uncertain readings) are left
    out, and log-probabilities are floored at ``floor`` (an impossible reading counts as very
    unlikely, not as infinitely so). The bin with the lowest ``z`` places the misfit in
    words: an effect no candidate names still shows where it acts (a part of the log, a part
    of the stroke, one count's edges).

    The same is asked of the dwells (:func:`_dwell_timing_rows`): whether one count's dwells
    end early or late, and whether successive dwells of a count do so together. The second
    finds what a fitted position noise absorbs: a drift of the bias or of the stroke, or a
    shape of the motion no candidate has, spreads every sample's surprise thinly enough to
    pass the bins above, but it repeats from cycle to cycle, and noise does not. That row
    says how the misfit acts, not where, so it heads the trace only when no row that places
    the misfit falls below ``local_z``.

    ``m`` is a point fit of :func:`compare_effect_models` (``full_fits``); with
    ``count_jump`` its most probable jump is taken out first (counts are then named in the
    frame of the reference segment). Returns ``covariate``, ``where``,
    ``z``, ``z_all`` (every sample), ``by_covariate`` (the worst bin of each covariate) and
    ``detail`` for a figure (:func:`enclab.lrde.plots.misfit_plot`): per covariate the short
    label and ``z`` of each bin (NaN where left out), the dwells' start times, centred
    mid-ranks and kinds (keys, and a label per key), the successive-dwell ``lag_z`` (high is
    bad) and ``local_z``.
    """
    offsets = 0
    if lrde_effects.offsets_counts(m["effects"]):
        *_, offsets = lrde_effects.jump_posterior(m["x"], t, counts, m["step"], m["centre"],
                                                  m["t_ref"], m["harmonics"], m["effects"])
    c = np.asarray(counts) - offsets
    prev = np.concatenate((c[:1], c[:-1]))

    def log_p(readings, before=prev):
        return np.maximum(lrde_effects.pointwise_log_likelihood(
            m["x"], t, readings, m["step"], m["centre"], m["t_ref"], m["harmonics"],
            m["effects"], prev_counts=before)[0], floor)

    alternatives = np.stack([log_p(prev + d) for d in (-1, 0, 1)])
    prob = np.exp(alternatives)
    mean = (prob * alternatives).sum(axis=0)
    var = np.maximum((prob * alternatives ** 2).sum(axis=0) - mean ** 2, 0.0)
    # The reading is one of the alternatives unless it moved by more than a count.
    moved = c - prev
    observed = (np.take_along_axis(alternatives, (moved + 1)[None, :], axis=0)[0]
                if np.all(np.abs(moved) <= 1) else log_p(c))
    centred = observed - mean
    rows, bins = [], {}
    for name, labels, words, short in _trace_covariates(m, t, prev):
        n_bins = len(words)
        total = np.bincount(labels, weights=centred, minlength=n_bins)
        spread = np.bincount(labels, weights=var, minlength=n_bins)
        if name == "time in the log":
            # A change that lasts (a missed count, a slipped part) shows best as the log
            # from some tenth on, or up to it: those sets join the tenths.
            edges = t[0] + (t[-1] - t[0]) * np.arange(1, 10) / 10
            total = np.concatenate((total, np.cumsum(total)[:9],
                                    np.cumsum(total[::-1])[:9][::-1]))
            spread = np.concatenate((spread, np.cumsum(spread)[:9],
                                     np.cumsum(spread[::-1])[:9][::-1]))
            words = (list(words) + [f"from the start of the log to {e:.3g} s" for e in edges]
                     + [f"from {e:.3g} s to the end of the log" for e in edges])
        ok = spread >= min_var
        z = np.where(ok, total / np.sqrt(np.where(ok, spread, 1.0)), np.inf)
        bins[name] = {"label": short, "z": np.where(ok, z, np.nan)[:len(short)]}
        if not ok.any():
            continue
        k = int(np.argmin(z))
        rows.append({"covariate": name, "where": words[k], "z": float(z[k])})
    s, dwell_var, key, start = dwell_ranks(log_p, c)
    dwell_rows, lag_z = _dwell_timing_rows(s, dwell_var, key)
    rows += dwell_rows
    rows.sort(key=lambda r: r["z"])
    z_all = float(centred.sum() / np.sqrt(var.sum())) if var.sum() > 0 else 0.0
    worst = rows[0] if rows else {}
    placing = [r for r in rows if r["covariate"] != _SUCCESSIVE_DWELLS and r["z"] < local_z]
    if worst.get("covariate") == _SUCCESSIVE_DWELLS and placing:
        # Successive dwells alike say how the misfit acts, not where: a part of the log, the
        # stroke or one count that fails too names it better.
        worst = placing[0]
    detail = {"bins": bins, "local_z": local_z, "lag_z": lag_z,
              "dwells": {"t": t[start], "s": s, "key": key,
                         "kind": {int(k): "count {} from {}".format(*_dwell_kind(k))
                                  for k in np.unique(key)}}}
    return {**worst, "z_all": z_all, "by_covariate": rows, "detail": detail}


def predictive_check(m, t, counts, rng, n_sim=20) -> dict:
    """Log-likelihood of the readings at a point fit against its distribution under the model.

    ``n_sim`` readings are simulated from the fit (:func:`enclab.lrde.effects.simulate_counts`;
    a jump at the fit's most probable index and sign) and scored like the data. The data's
    score is in-sample (the fit adapted to it), so it errs on the high side: a score far below
    the simulations' is a misfit the model cannot absorb. Returns ``observed``, ``sim_mean``,
    ``sim_sd`` and ``z = (observed - sim_mean) / sim_sd``.
    """
    def score(c):
        return float(lrde_effects.log_likelihood(m["x"], t, c, m["step"], m["centre"],
                                                 m["t_ref"], m["harmonics"], m["effects"]))

    observed = score(counts)
    kw = _si_params(m)
    offsets = 0
    if lrde_effects.offsets_counts(m["effects"]):
        *_, offsets = lrde_effects.jump_posterior(m["x"], t, counts, m["step"], m["centre"],
                                                  m["t_ref"], m["harmonics"], m["effects"])
    sims = lrde_effects.simulate_counts(rng, t, m["step"], n_rep=n_sim, **kw) + offsets
    scores = np.array([score(c) for c in sims])
    sd = float(scores.std(ddof=1))
    return {"observed": observed, "sim_mean": float(scores.mean()), "sim_sd": sd,
            "z": float((observed - scores.mean()) / sd) if sd > 0 else 0.0}


#: A model passes only if no fold's held-out gain lies below minus this many of that fold's
#: standard errors.
FOLD_SE = 2.0


def _sum_se(diff) -> float:
    """Standard error of the sum of per-cycle differences (``sqrt(n) sd``; inf below 2)."""
    return float(np.sqrt(diff.size) * diff.std(ddof=1)) if diff.size > 1 else np.inf


def _no_fold_worse(gains, ses, k=FOLD_SE) -> bool:
    """True unless a fold's held-out gain lies more than ``k`` of its standard errors below 0.

    The held-out cycles of one fold share one training fit, so the standard error of the
    pooled gain is optimistic and one fold's luck can carry it: a model must not predict
    either fold worse. Worse means significantly worse: a point fit on ten cycles places the
    sharp reading edges with errors of its own, and a clear effect (a 3rd harmonic of 1/20
    step gaining 60 nats on one fold) can lose a few nats on the other by that alone."""
    return all(g > -k * se for g, se in zip(gains, ses))


def _full_fit(t, counts, step, harmonics, effects, start, init, fit_kwargs):
    """Point fit of one model on the whole log, with the held-out score's time blur."""
    m = lrde_fit.map_fit(t, counts, step, harmonics=harmonics, effects=effects, start=start,
                         init=init, **fit_kwargs)
    return m | {"log_lik_blurred": _blurred_log_lik(m, t, counts)}


def _fold_fit(t, counts, prev, step, train, harmonics, effects, start, init, fit_kwargs):
    """Point fit of one model on one fold's training cycles."""
    return lrde_fit.map_fit(t[train], counts[train], step, harmonics=harmonics,
                            effects=effects, start=start, init=init, prev_counts=prev[train],
                            **fit_kwargs)


def compare_effect_models(t, counts, step, seed, candidates=DEFAULT_CANDIDATES, min_z=2.0,
                          f_hz=None, n_sim=20, trust_z=DEFAULT_TRUST_Z, pairs=True,
                          sigma_range=None, sigma_prior="uniform", min_gain=1.0,
                          local_z=DEFAULT_LOCAL_Z, threads=1, fold_se=FOLD_SE) -> dict:
    """Held-out comparison of motion, encoder and clock effects by point fits (two folds).

    Each candidate ``(harmonics, effects)`` is fitted (:func:`enclab.lrde.fit.map_fit`) on the
    even cycles of the log and predicts the odd ones, and the other way round; the score is
    the plug-in log predictive density per held-out cycle. Interleaved folds make the
    prediction an interpolation: a frequency, drift or jump estimated on one fold applies to
    the other without extrapolating over half the log (a point estimate extrapolated over
    half the log misplaces the sharp reading edges and its score depends on luck). A
    candidate replaces the sinusoid when its summed gain exceeds
    ``min_z`` standard errors of the per-cycle differences, it predicts no fold worse by more
    than ``fold_se`` (default 2) of that fold's standard errors (:func:`_no_fold_worse`; 0:
    each fold better), and its full-log ``delta_bic = 2 (log L_model - log L_sine) - n_extra
    ln N`` is positive
    (``count_jump`` counts as one extra parameter besides its marginalised location); the
    largest ``delta_bic`` wins. The full-log likelihoods carry the held-out score's time blur
    (:func:`_blurred_log_lik`): without it a point fit's position noise collapses, every
    model that threads the reading edges between samples scores ``log L = 0``, and the BIC
    difference is only the parameter penalty. With ``pairs``, the winner plus the runner-up
    (largest ``delta_bic`` after it) is tried the same way against the winner.

    A dead band and a 3rd harmonic are confusable by construction: both move rising and
    falling edges of one level in opposite directions, the band by ``w/2`` at every level,
    the harmonic's ``cos 3 phi`` part by an amount that varies with the level, and the
    fundamental's phase absorbs the common part; on a symmetric three-level pattern the
    two are equivalent to first order. Against the sinusoid alone a narrow band is mostly a
    phase lag: what the sinusoid cannot absorb is the band's constant shift against the
    lag's ``cos phi`` profile over the levels, a tenth of ``w/2`` or less unless the pattern
    is lopsided or a level grazes a turning point. So every other candidate that predicts each fold
    better than the sinusoid and whose held-out score lies no more than two standard errors
    (paired per-cycle differences) below the pick's is listed in ``indistinguishable``, whether
    or not it cleared the bar against the sinusoid itself (a model holding the pick's terms
    and more is not an alternative to it); its ``delta_over_chosen`` and ``se_over_chosen``
    hold that evidence. That includes a model that predicts the held-out cycles better than
    the pick by more than two standard errors: the pick won on the full-log BIC, whose
    penalty for the extra parameter (a 3rd harmonic has two, a dead band one) the held-out
    score does not share, so the two criteria disagree and neither settles it.

    When the sinusoid is kept, every candidate that still predicts each fold better than it,
    by ``min_gain`` nats or more in all, is listed in ``not_ruled_out``: an effect too small
    to clear the bar (or one whose held-out gain the BIC penalty refused) moves the
    estimates all the same, by more than their width on a 20-cycle log (a third harmonic
    shifts the turning points the stroke is read from). Smaller gains (below a factor ``e`` in
    predictive density over the whole log at the default) are not listed: each listed model
    costs the stage an emcee fit.

    The chosen model is then checked (:func:`predictive_check`): its log-likelihood at the
    full-log point fit against the distribution of the same score on ``n_sim`` readings
    simulated from that fit. ``z < trust_z`` means even the best candidate explains the
    readings worse than it explains its own simulations: the estimates are flagged
    untrustworthy. The localized check (:func:`misfit_trace`) asks the same of every tenth of
    the log, every part of the stroke and every count left or held; a part scoring below
    ``local_z`` is a misfit the chosen model leaves (an effect outside the candidates, absorbed
    by the nearest ones): the estimates are flagged, and the trace says where it acts.

    ``threads`` processes fit the candidates' folds side by side
    (:func:`enclab.core.parallel.map_forked`); the point fits are deterministic, so the
    result is the same with any number.

    Returns
    -------
    dict
        ``models`` (per candidate: ``label, harmonics, effects, elpd_per_cycle, delta_elpd,
        delta_se, z, delta_elpd_halves, delta_se_halves, delta_bic`` (the ``_halves`` are per
        fold), and for alternatives to a chosen effect ``delta_over_chosen, se_over_chosen``),
        ``chosen`` (label), ``chosen_harmonics``, ``chosen_effects``, ``indistinguishable``
        and ``not_ruled_out`` (labels), ``check`` ``{z, observed, sim_mean, sim_sd, trusted}``,
        ``n_cycles``, ``rule``, ``full_fits`` (label -> point fit of the whole log; the
        sinusoid, every model tried on the full log, the chosen one and each one listed in
        ``indistinguishable`` or ``not_ruled_out``) and ``trace_detail`` (the localized check's
        bins and dwells, see :func:`misfit_trace`; ``check["trace"]`` holds the rest).
    """
    t = np.asarray(t, dtype=float)
    counts = np.asarray(counts)
    candidates = [(tuple(h), lrde_effects.check_effects(e)) for h, e in candidates]
    if not candidates or candidates[0] != ((), ()):
        raise ValueError(f"candidates must start with ((), ()) (the sinusoid), got {candidates!r}")
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rng = np.random.default_rng(root)
    fit_kwargs = {"sigma_range": sigma_range, "sigma_prior": sigma_prior}
    full = {"sinusoid": lrde_fit.map_fit(t, counts, step, f_hz=f_hz, **fit_kwargs)}
    init = full["sinusoid"]["init"]
    cycle = np.floor((t - t[0]) * full["sinusoid"]["x"][2]).astype(np.int64)
    odd = (cycle % 2).astype(bool)
    if min(np.unique(cycle[odd]).size, np.unique(cycle[~odd]).size) < 2:
        raise ValueError("cannot compare models: fewer than four cycles in the log")
    folds = [(~odd, odd), (odd, ~odd)]
    # A fold joins every other cycle: the dead band's state at a seam is the reading just
    # before it in the log, not the last reading of the fold's previous cycle.
    prev = np.concatenate((counts[:1], counts[:-1])).astype(float)

    def fold_jobs(harmonics, effects, base):
        return [(t, counts, prev, step, train, harmonics, effects, b["x"], init, fit_kwargs)
                for (train, _), b in zip(folds, base)]

    def scored(fits):
        units, totals = [], []
        for (train, test), m in zip(folds, fits):
            total, lp = _predict(m, t[test], counts[test], t[train], counts[train],
                                 prev[test], prev[train])
            _, unit = np.unique(cycle[test], return_inverse=True)
            units.append(np.bincount(unit, weights=lp))
            totals.append(total)
        return {"fits": fits, "units": units, "totals": totals}

    def evaluate(harmonics, effects, base):
        return scored(parallel.map_forked(_fold_fit, fold_jobs(harmonics, effects, base),
                                          threads))

    # The sinusoid of each fold starts at that of the whole log, every other model's at the
    # fold's sinusoid.
    sine = evaluate((), (), [full["sinusoid"], full["sinusoid"]])
    others = [c for c in candidates if c != ((), ())]
    fits = parallel.map_forked(_fold_fit, [job for c in others
                                           for job in fold_jobs(*c, sine["fits"])], threads)
    results = {model_label((), ()): (((), ()), sine)} | {
        model_label(*c): (c, scored(fits[2 * i:2 * i + 2])) for i, c in enumerate(others)}

    def score(res, ref):
        """``(delta, se, per-fold gains, per-fold se, units)`` of ``res`` over ``ref``."""
        n_fold = [min(len(a), len(b)) for a, b in zip(res["units"], ref["units"])]
        diffs = [a[:n] - b[:n] for a, b, n in zip(res["units"], ref["units"], n_fold)]
        diff = np.concatenate(diffs)
        delta = float(sum(res["totals"]) - sum(ref["totals"]))
        halves_gain = [float(a - b) for a, b in zip(res["totals"], ref["totals"])]
        return delta, _sum_se(diff), halves_gain, [_sum_se(d) for d in diffs], diff.size

    def full_fits(terms):
        """The whole-log fits of ``terms`` (label -> (harmonics, effects)) not yet made,
        side by side."""
        todo = {label: he for label, he in terms.items() if label not in full}
        full.update(zip(todo, parallel.map_forked(
            _full_fit, [(t, counts, step, *he, full["sinusoid"]["x"], init, fit_kwargs)
                        for he in todo.values()], threads)))

    def full_fit(label, harmonics, effects):
        full_fits({label: (harmonics, effects)})
        if "log_lik_blurred" not in full[label]:
            full[label]["log_lik_blurred"] = _blurred_log_lik(full[label], t, counts)
        return full[label]

    def n_extra(harmonics, effects):
        return (2 * len(harmonics) + len(lrde_effects.effect_param_names(effects))
                + lrde_effects.n_marginalised(effects))

    models = []
    n_cycles = 0
    for label, ((harmonics, effects), res) in results.items():
        delta, se, halves_gain, halves_se, n_cycles = score(res, sine)
        models.append({"label": label, "harmonics": list(harmonics), "effects": list(effects),
                       "elpd_per_cycle": float(sum(res["totals"]) / max(n_cycles, 1)),
                       "delta_elpd": delta if label != "sinusoid" else 0.0,
                       "delta_se": se if label != "sinusoid" else 0.0,
                       "z": (delta / se) if label != "sinusoid" and se > 0 else None,
                       "delta_elpd_halves": halves_gain, "delta_se_halves": halves_se,
                       "delta_bic": None})
    passing = [m for m in models[1:] if m["z"] is not None and m["z"] > min_z
               and _no_fold_worse(m["delta_elpd_halves"], m["delta_se_halves"], fold_se)]
    sine_ll = full_fit("sinusoid", (), ())["log_lik_blurred"]
    full_fits({m["label"]: (tuple(m["harmonics"]), tuple(m["effects"])) for m in passing})
    for m in passing:
        fm = full_fit(m["label"], tuple(m["harmonics"]), tuple(m["effects"]))
        m["delta_bic"] = float(2.0 * (fm["log_lik_blurred"] - sine_ll)
                               - n_extra(m["harmonics"], m["effects"]) * np.log(t.size))
    winners = [m for m in passing if m["delta_bic"] > 0]
    best = max(winners, key=lambda m: m["delta_bic"]) if winners else models[0]
    if pairs and best is not models[0] and len(winners) > 1:
        base_res = results[best["label"]][1]
        # The winner plus the runner-up only: each pair costs two more point fits.
        runner_up = max((m for m in winners if m is not best), key=lambda m: m["delta_bic"])
        for other in (runner_up,):
            if other is best:
                continue
            h = tuple(sorted(set(best["harmonics"]) | set(other["harmonics"])))
            e = lrde_effects.check_effects(set(best["effects"]) | set(other["effects"]))
            label = model_label(h, e)
            if label in results:
                continue
            res = evaluate(h, e, sine["fits"])
            results[label] = ((h, e), res)
            delta, se, halves_gain, halves_se, _ = score(res, base_res)
            d0, se0, halves0, halves_se0, _ = score(res, sine)
            entry = {"label": label, "harmonics": list(h), "effects": list(e),
                     "elpd_per_cycle": float(sum(res["totals"]) / max(n_cycles, 1)),
                     "delta_elpd": d0, "delta_se": se0, "z": d0 / se0 if se0 > 0 else None,
                     "delta_elpd_halves": halves0, "delta_se_halves": halves_se0,
                     "delta_bic": None,
                     "over": best["label"], "z_over": delta / se if se > 0 else None}
            models.append(entry)
            if (entry["z_over"] is not None and entry["z_over"] > min_z
                    and _no_fold_worse(halves_gain, halves_se, fold_se)):
                fm = full_fit(label, h, e)
                fb = full_fit(best["label"], tuple(best["harmonics"]), tuple(best["effects"]))
                gain = 2.0 * (fm["log_lik_blurred"] - fb["log_lik_blurred"]) - (
                    n_extra(h, e) - n_extra(best["harmonics"], best["effects"])) * np.log(t.size)
                entry["delta_bic"] = float(best["delta_bic"] + gain)
                if gain > 0 and entry["delta_bic"] > best["delta_bic"]:
                    best = entry
    best_res = results[best["label"]][1]
    best_terms = set(best["label"].split("+"))
    indistinguishable, not_ruled_out = [], []
    if best["label"] == "sinusoid":
        # The sinusoid kept, yet these models predict each fold better: effects below the
        # rule's bar (or refused by the BIC penalty) that the readings do not rule out;
        # their estimates may differ from the sinusoid's by more than their width.
        not_ruled_out = [m["label"] for m in models[1:] if min(m["delta_elpd_halves"]) > 0
                         and m["delta_elpd"] >= min_gain]
    for m in models if best["label"] != "sinusoid" else ():
        # An alternative explanation: it predicts each fold better than the sinusoid too,
        # and its held-out score is not two standard errors below the pick's (better counts:
        # the pick may owe its place to the BIC's parameter penalty alone). Whether it
        # also cleared the bar against the sinusoid does not matter here: near the detection
        # limit the pick clears it by luck as much as by its own signature. A model holding
        # the pick's terms and more is no alternative: scoring like the pick only says that
        # its extra term is not needed.
        if (m is best or m["label"] == "sinusoid" or min(m["delta_elpd_halves"]) <= 0
                or best_terms < set(m["label"].split("+"))):
            continue
        delta, se, _, _, _ = score(best_res, results[m["label"]][1])
        m["delta_over_chosen"] = -delta
        m["se_over_chosen"] = se
        if delta < 2.0 * se:
            indistinguishable.append(m["label"])
    chosen_fit = full_fit(best["label"], tuple(best["harmonics"]), tuple(best["effects"]))
    check = predictive_check(chosen_fit, t, counts, rng, n_sim=n_sim)
    trace = misfit_trace(chosen_fit, t, counts, local_z=local_z)
    trace_detail = trace.pop("detail")
    localized = bool(trace.get("z", 0.0) < local_z)
    check |= {"trusted": bool(check["z"] >= trust_z and not localized), "threshold_z": trust_z,
              "localized": localized, "local_z": local_z, "trace": trace}
    chosen_h, chosen_e = tuple(best["harmonics"]), tuple(best["effects"])
    full_fits({label: results[label][0] for label in indistinguishable + not_ruled_out})
    return {"models": models, "chosen": best["label"], "chosen_harmonics": list(chosen_h),
            "chosen_effects": list(chosen_e), "delta_bic": best["delta_bic"],
            "indistinguishable": indistinguishable, "not_ruled_out": not_ruled_out,
            "n_cycles": int(n_cycles),
            "check": check,
            "rule": (f"a model replaces the sinusoid when its held-out gain exceeds {min_z:g} "
                     "standard errors, it predicts no fold worse by more than "
                     f"{fold_se:g} of that fold's standard errors, and its full-log delta BIC "
                     "(likelihood with the held-out score's time blur) is positive (point "
                     "fits, even/odd cycles as folds, cycles as units); other models that "
                     "predict each fold better than the sinusoid and score no more than two "
                     "standard errors below the chosen one are not distinguishable from it; "
                     "when the sinusoid is kept, models that predict each fold better by "
                     f"{min_gain:g} nat or more in all are not ruled out; "
                     f"estimates are untrusted when the chosen model's log-likelihood lies "
                     f"more than {-trust_z:g} standard deviations below that of its own "
                     "simulated readings, or when on one tenth of the log, one part of the "
                     "stroke or one count left or held the readings' log-probability lies "
                     f"more than {-local_z:g} standard deviations below what the fit expects, "
                     "or the dwells of one count end early or late, or successive dwells of a "
                     f"count do so together, by more than {-local_z:g} standard deviations"),
            "full_fits": full, "trace_detail": trace_detail,
            # Per model, the held-out log predictive density per test cycle and per fold, and
            # the cycle of every sample: other models (a loop driven by logged signals,
            # enclab.lrde.loop) are scored on the same folds and units.
            "heldout": {label: {"units": res["units"], "totals": res["totals"]}
                        for label, (_, res) in results.items()},
            "cycle": cycle}


def blurred_log_likelihood(m, t, counts) -> float:
    """Full-log log-likelihood of a point fit under the held-out score's time blur.

    The score the comparison's penalised gains are built on (see :func:`_blurred_log_lik`):
    a point fit's position noise collapses onto the readings' edges, so the plain maximum
    saturates; the held-out score's blur (an eighth of a sample interval) keeps the edges'
    placement in the score.

    Parameters
    ----------
    m : dict
        A point fit, as :func:`enclab.lrde.fit.map_fit` returns it.
    t : numpy.ndarray
        Sample times (s).
    counts : numpy.ndarray of int
        The encoder's counts.

    Returns
    -------
    float
        The log-likelihood of ``counts`` under ``m``.
    """
    return _blurred_log_lik(m, t, counts)
