"""Encoder and clock effects of an extreme low-resolution encoder log, as likelihood terms.

The paper's model reads ``count = floor(z + e)`` with ``z = a_eq/step + A/step sin(phi)`` and
``e`` white Gaussian position noise of ``s`` steps (:mod:`enclab.lrde.fit`). Each effect below
changes that reading model by one small term with its own signature in the readings. Each
term is one :class:`Effect` subclass in :data:`REGISTRY`; the likelihood, the fits, the
comparison and the reports reach a term only through its attributes and methods, so adding a
term is adding a class (docs/development.md, "Adding an effect").

Harmonic distortion of the motion (``harmonics`` in :func:`enclab.lrde.fit.fit_sinusoid`)
stays a motion term; any of these effects combine with it and with each other.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy.special import erfc, log_ndtr, logsumexp

from enclab.lrde import model
from enclab.lrde import motion as lrde_motion

__all__ = ["Effect", "Hysteresis", "Drift", "CountJump", "TimeJitter", "REGISTRY", "EFFECTS",
           "effect", "active", "parameter_column", "offsets_counts",
           "n_marginalised", "check_effects", "effect_param_names", "effect_bounds",
           "effect_scales", "pointwise_log_likelihood", "log_likelihood", "jump_posterior",
           "simulate_counts", "effect_signature", "model_label", "dead_band_bounds",
           "jump_log_terms", "jump_offsets", "relay", "JUMP_SIGNS"]

# Internal bounds: hysteresis in steps (a dead band above half a step would swallow the
# narrowest dwell of a 2n-step pattern), time jitter in sample intervals, drift as a total
# relative change over the fitted log (converted to 1/s with its duration).
_HYST_MAX = 0.5
_JITTER_MAX = 1.0
_DRIFT_MAX = 0.1
JUMP_SIGNS = (1, -1)  # a count jump's offsets of the shorter segment
_RELAY_ROWS_VECTOR = 16  # from this many simulated readings on, the relay runs vectorised


class Effect:
    """Base class of an encoder or clock term of the low-resolution reading model.

    A term is one small subclass: its ``name`` (the config's and the reports' word), its one
    sampled parameter (internal units, uniform prior within :meth:`bounds`, SI per internal
    unit :meth:`si_scale`, start values of the fits), its ``signature`` (what the readings
    look like when the term is present and not modelled, one line) and the role it plays in
    the likelihood (the flags below; the likelihood reads the flags, never the name).
    ``counterparts`` names the residual-stage effects (:mod:`enclab.residuals.effects`) of
    the same physics, which declare this term as theirs; ``test`` names the test that checks
    the term's likelihood against a brute-force simulation (:func:`simulate_counts`).

    Attributes
    ----------
    name : str
        The term's name; also the keyword of :func:`simulate_counts` that sets it (SI).
    sampled : bool
        The term has a sampled parameter (named ``name``); False for a term marginalised
        exactly in :func:`log_likelihood`.
    bends_phase : bool
        The parameter (1/s) changes the motion's frequency over the log.
    blurs_time : bool
        The parameter (sample intervals) is a standard deviation of the sample times.
    dead_band : bool
        The parameter (steps) is the width of a dead band of the reading.
    offsets_counts : bool
        The term offsets the counts of one segment of the log by one (a missed count): the
        likelihood is marginalised over where and which way; it counts as one parameter.
    stroke_reach : float
        How much of the stroke (steps) the term can hide at the turning points: it widens
        the prior of ``A12`` upwards.
    of_the_reading : bool
        A property of the reading (compared with the truth channel's findings); False for a
        term of the motion itself (the frequency's drift).
    unconfirmed : str or None
        What the term stands for when the truth channel shows no such effect.
    unconfirmed_biases : tuple or None
        ``(quantities, words)``: the estimates that rest on the term being the encoder's.
    display : tuple
        ``(factor, axis label)``: the SI value times ``factor`` in the label's unit, for plots.
    """

    name = "effect"
    sampled = True
    bends_phase = False
    blurs_time = False
    dead_band = False
    offsets_counts = False
    stroke_reach = 0.0
    of_the_reading = True
    signature = ""
    counterparts: tuple = ()
    unconfirmed = None
    unconfirmed_biases = None
    test = ""
    display = (1.0, "")
    #: start value of the parameter (internal units)
    start = 0.0

    # The four methods below describe a sampled parameter: every term with ``sampled = True``
    # defines them; a marginalised term (``sampled = False``, the count jump) has none to give.

    def _no_parameter(self):
        return NotImplementedError(f"{self.name!r} has no sampled parameter")

    def bounds(self, duration: float, dt: float) -> list:
        """Internal prior bounds ``[lo, hi]`` of the parameter for a log of ``duration`` s
        sampled every ``dt`` s."""
        raise self._no_parameter()

    def si_scale(self, step: float, dt: float) -> float:
        """SI value of one internal unit of the parameter."""
        raise self._no_parameter()

    def start_spread(self, duration: float, ratio: float) -> float:
        """Dispersion of the ensemble's start (internal units, before the common shrink)."""
        raise self._no_parameter()

    def simplex_step(self, duration: float) -> float:
        """First step of the point fit's simplex (internal units)."""
        raise self._no_parameter()

    def derived(self, summary: Mapping, duration_s: float | None) -> dict:
        """Extra reported quantities from the fitted parameter's ``{median, q05, q95}``."""
        return {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class Hysteresis(Effect):
    """Dead band of the reading of width ``w`` (parameter ``hysteresis``, steps; SI rad).

    The reading switches up to ``k`` when ``z + e`` rises through ``k + w/2`` and down to
    ``k - 1`` when it falls through ``k - w/2``: a dead band of width ``w`` centred on each
    nominal level (``a_eq`` refers to the band centre). A play of width ``w`` between the
    motion and the encoder gives the same readings (the encoder shaft lags the motion by
    ``w/2`` in the direction of travel), so the two physical causes are one effect here, and
    the residual stage's dead band and play are both this term.
    Signature: rising edges late and falling edges early by ``w/2`` each, i.e. every dwell
    at a turning point lengthened, the mid-stroke dwells unchanged in length but shifted.
    The state of a relay is its reading, so given the previous reading ``c`` the reading
    ``k`` has the interval ``[k + w/2, k + 1 + w/2)`` for ``k > c``, ``[k - w/2, k + 1 - w/2)``
    for ``k < c`` and ``[c - w/2, c + 1 + w/2)`` for ``k = c``; these partition the line, so
    the likelihood is exact for a relay driven by ``z + e`` (first sample: the stay interval).
    """

    name = "hysteresis"
    dead_band = True
    stroke_reach = _HYST_MAX
    start = 0.02
    signature = ("switch-up and switch-down levels differ by a width w (dead band of the "
                 "reading, or a play of the same width before the encoder)")
    counterparts = ("hysteresis", "backlash")
    unconfirmed = ("the encoder reads its truth channel without a dead band, so the term stands "
                   "for the motion (it lingers at its turning points, as a closed loop's does)")
    unconfirmed_biases = (("A12",), "the truth channel shows no dead band, so the model's "
                          "hysteresis stands for the motion at its turning points and the "
                          "fitted motion's stroke is not the shaft's")
    test = "tests/test_lrde_effects.py::test_hysteresis_transition_probabilities_match_a_relay_simulation"
    display = (180.0 / np.pi, "hysteresis w [deg]")

    def bounds(self, duration, dt):
        return [0.0, _HYST_MAX]

    def si_scale(self, step, dt):
        return step

    def start_spread(self, duration, ratio):
        return 0.01

    def simplex_step(self, duration):
        return 0.05


class Drift(Effect):
    """Linear drift of the motion's frequency, ``kappa`` (parameter ``drift``, 1/s).

    ``f(t) = f (1 + kappa (t - t_ref))``, phase ``omega (u + kappa u^2 / 2) + phase`` with
    ``u = t - t_ref``. Signature: the dwell pattern slides against a fixed-frequency sine,
    opposite in the two halves of the log. ``kappa`` times the log's duration is the drift over
    the log. A term of the motion, not of the reading: the residual stage, which compares the
    reading with the truth, has none.
    """

    name = "drift"
    bends_phase = True
    of_the_reading = False
    signature = "linear drift of the motion frequency over the log"
    test = "tests/test_lrde_effects.py::test_drift_reading_probabilities_match_simulation"
    display = (1.0, "drift [1/s]")

    def bounds(self, duration, dt):
        return [-_DRIFT_MAX / duration, _DRIFT_MAX / duration]

    def si_scale(self, step, dt):
        return 1.0

    def start_spread(self, duration, ratio):
        return 2e-4 / duration * ratio

    def simplex_step(self, duration):
        return 0.01 / duration

    def derived(self, summary, duration_s):
        """``drift_over_log``: the relative frequency change over the log."""
        if not duration_s:
            return {}
        return {"drift_over_log": {k: _num(v * duration_s) for k, v in summary.items()}}


class CountJump(Effect):
    """One missed (``-1``) or extra (``+1``) count at an unknown sample (no sampled parameter).

    The counts of the shorter of the two segments are offset by ``delta`` from those of the
    longer one, whose frame ``a_eq`` refers to. The jump index (uniform over the log) and
    ``delta`` (+-1, equally likely) are marginalised exactly from cumulative sums of the
    pointwise likelihood. Signature: the reading pattern is shifted by one whole step from a
    point on.
    """

    name = "count_jump"
    sampled = False
    offsets_counts = True
    signature = "one missed or extra count at an unknown time (a step in the count offset)"
    counterparts = ("missed_counts",)
    unconfirmed = ("the truth channel shows no missed count, so the term stands for a step of "
                   "the motion itself")
    test = "tests/test_lrde_effects.py::test_count_jump_marginal_matches_simulation_of_a_random_jump"


class TimeJitter(Effect):
    """Jitter of the sample times, standard deviation ``sigma_t`` (parameter ``time_jitter``,
    sample intervals; SI s).

    Each sample is taken at ``t + eta``, ``eta ~ N(0, sigma_t^2)``: to first order a position
    noise ``z'(t) eta``, so the noise of sample ``j`` is ``sqrt(s^2 + (z'(t_j) sigma_t)^2)``.
    Signature: noise proportional to the speed, none at the turning points (unlike the
    constant position noise ``s``). The second-order term ``z'' eta^2 / 2`` is below
    ``(omega sigma_t)^2 A / 2`` steps and neglected.
    """

    name = "time_jitter"
    blurs_time = True
    start = 0.05
    signature = "jitter of the sample times (noise proportional to the speed)"
    counterparts = ("timestamp_jitter",)
    unconfirmed = ("the truth channel shows no sample-time jitter, so the term stands for "
                   "noise of the motion")
    test = "tests/test_lrde_effects.py::test_time_jitter_reading_probabilities_match_simulation"
    display = (1e6, "time jitter [us]")

    def bounds(self, duration, dt):
        return [0.0, _JITTER_MAX]

    def si_scale(self, step, dt):
        return dt

    def start_spread(self, duration, ratio):
        return 0.02

    def simplex_step(self, duration):
        return 0.1


def _num(value):
    """JSON-safe float: NaN, infinities and None become None."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


#: The registry: every term by name, in the order models list them.
REGISTRY = {cls.name: cls() for cls in (Hysteresis, Drift, CountJump, TimeJitter)}

#: The names of the registered terms (the config's ``lrde.effects`` enum).
EFFECTS = tuple(REGISTRY)


def effect(name: str) -> Effect:
    """The registered term called ``name``."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; known: {EFFECTS}") from None


def active(effects) -> list:
    """The registered terms of a tuple of names (checked, in :data:`EFFECTS` order)."""
    return [REGISTRY[n] for n in check_effects(effects)]


def model_label(harmonics, effects) -> str:
    """``"sinusoid"`` or the terms joined by ``+`` (``"harmonic3"``, ``"fourier6"``,
    ``"hysteresis"``): the motion's label (:func:`enclab.lrde.motion.from_harmonics`), then
    the effects."""
    motion = lrde_motion.from_harmonics(harmonics)
    terms = ([] if not motion.harmonics else [motion.label]) + list(effects)
    return "+".join(terms) if terms else "sinusoid"


def check_effects(effects) -> tuple:
    """Validate a tuple of effect names (each once, in :data:`EFFECTS` order)."""
    e = tuple(effects)
    if any(x not in EFFECTS for x in e) or len(set(e)) != len(e):
        raise ValueError(f"effects must be distinct names from {EFFECTS}, got {effects!r}")
    return tuple(x for x in EFFECTS if x in e)


def effect_signature(name: str) -> str:
    """One-line description of an effect's physical reading and signature."""
    return effect(name).signature


def effect_param_names(effects) -> tuple:
    """Sampled parameter names of the effects (a marginalised term has none)."""
    return tuple(e.name for e in active(effects) if e.sampled)


def _sampled(effects) -> list:
    return [e for e in active(effects) if e.sampled]


def effect_bounds(effects, duration, dt) -> list:
    """Internal prior bounds of the effect parameters (uniform priors).

    ``hysteresis`` in steps ``(0, 0.5)``, ``drift`` in 1/s within ``+-0.1 / duration``,
    ``time_jitter`` in sample intervals ``(0, 1)`` (:meth:`Effect.bounds`).
    """
    return [e.bounds(duration, dt) for e in _sampled(effects)]


def effect_scales(effects, step, dt) -> list:
    """SI value per internal unit of each effect parameter (rad per step, 1, s per sample)."""
    return [e.si_scale(step, dt) for e in _sampled(effects)]


def parameter_column(harmonics, effects, flag: str):
    """Column of the parameter rows holding the sampled term with ``flag`` set (an
    :class:`Effect` attribute such as ``"bends_phase"``), or None."""
    for name, col in _columns(harmonics, effects).items():
        if getattr(REGISTRY[name], flag):
            return col
    return None


def offsets_counts(effects) -> bool:
    """Whether a term of ``effects`` offsets the counts of a segment (marginalised)."""
    return any(e.offsets_counts for e in active(effects))


def n_marginalised(effects) -> int:
    """Parameters of ``effects`` marginalised rather than sampled (each counts as one)."""
    return sum(not e.sampled for e in active(effects))


def _phase(p, t, t_ref, drift_col):
    u = t - t_ref
    omega = 2.0 * np.pi * p[:, 2:3]
    if drift_col is None:
        return omega * u + p[:, 3:4], omega * np.ones_like(u)
    kappa = p[:, drift_col:drift_col + 1]
    return omega * (u + 0.5 * kappa * u * u) + p[:, 3:4], omega * (1.0 + kappa * u)


def _motion_and_speed(p, t, t_ref, harmonics, drift_col, grid=None, speed=True):
    """Motion about the bias in steps and its time derivative (steps/s), rows of ``p``.

    Without drift on a uniform grid (``grid``, :func:`enclab.lrde.model.uniform_grid`) the
    phase factor ``exp(i phi)`` comes from block-wise rotation; otherwise from one ``sin`` and
    one ``cos`` per entry. The harmonics ``cos(k phi)``, ``sin(k phi)`` are the parts of its
    powers (one complex product per order instead of two transcendental functions). With
    ``speed=False`` the derivative is not formed and None is returned in its place.
    """
    half_a = 0.5 * p[:, 0:1]
    if drift_col is None and grid is not None:
        omega, phase = 2.0 * np.pi * p[:, 2], p[:, 3]
        if not harmonics and not speed:
            motion = model._sine_on_grid(omega, phase, grid, t_ref)
            motion *= half_a
            return motion, None
        phasor = model._phasor_on_grid(omega, phase, grid, t_ref)
        dphi = omega[:, None]
    else:
        phi, dphi = _phase(p, t, t_ref, drift_col)
        if not harmonics:
            motion = np.sin(phi)
            motion *= half_a
            return motion, (half_a * np.cos(phi) * dphi if speed else None)
        phasor = np.cos(phi) + 1j * np.sin(phi)
    motion = half_a * phasor.imag
    dmotion = half_a * phasor.real if speed else None
    power, order = phasor, 1
    for j, k in enumerate(harmonics):
        while order < k:
            power, order = power * phasor, order + 1
        c, s = p[:, 5 + 2 * j:6 + 2 * j], p[:, 6 + 2 * j:7 + 2 * j]
        ck, sk = power.real, power.imag
        motion += c * ck + s * sk
        if speed:
            dmotion += k * (s * ck - c * sk)
    return motion, (dmotion * dphi if speed else None)


def _columns(harmonics, effects):
    first = 5 + 2 * len(harmonics)
    return {name: first + i for i, name in enumerate(effect_param_names(effects))}


def _log_interval(lo, hi):
    """``log(Phi(hi) - Phi(lo))`` elementwise, accurate in both tails (reflect upper tail)."""
    flip = lo > 0
    lo, hi = np.where(flip, -hi, lo), np.where(flip, -lo, hi)
    log_hi = log_ndtr(hi)
    with np.errstate(divide="ignore"):
        return log_hi + np.log1p(-np.exp(log_ndtr(lo) - log_hi))


_DEEP = 8.0
_SQRT_HALF = np.sqrt(0.5)
# From this share of near entries on, every entry is evaluated in place: gathering them and
# sorting them by kind costs more than the special functions it saves
# (workflow/benchmarks/bench_lrde_interval.py).
_DENSE_SHARE = 0.5


def _log_interval_near(lower, upper):
    """``log(Phi(upper) - Phi(lower))`` at the entries where it differs from 0 noticeably.

    Returns ``(keep, vals)``: the flat indices of those entries and their values, or
    ``keep = None`` and ``vals`` of every entry in flat order (the entries not near are then
    0). An entry is near when ``lower >= -8`` or ``upper <= 8``; every other entry is above
    ``-1.3e-15``. Few near entries are gathered and evaluated by kind
    (:func:`_log_interval_sparse`); when most are near, all are evaluated in place
    (:func:`_log_interval_dense`), which saves the gathering and the masks by kind.
    """
    near = lower >= -_DEEP
    near |= upper <= _DEEP
    count = np.count_nonzero(near)
    if count < _DENSE_SHARE * near.size:
        keep = np.flatnonzero(near)
        return keep, _log_interval_sparse(lower.ravel()[keep], upper.ravel()[keep])
    vals = _log_interval_dense(lower.ravel(), upper.ravel())
    if count < near.size:
        vals = np.where(near.ravel(), vals, 0.0)
    return None, vals


def _log_interval_sparse(lo, up):
    """``log(Phi(up) - Phi(lo))`` of near entries (1-d), by kind:

    - one bound beyond 8 standard deviations and the interval reaching past 0
      (``lo < -8``, ``up >= 0``, or the mirror image): the far bound's
      ``Phi(-8) = 6.2e-16`` is dropped against a probability above 1/2, and
      ``log Phi(x) = log1p(-erfc(x / sqrt 2) / 2)`` for the near bound ``x >= 0``;
    - both bounds within 8: ``log`` of the difference of the two tail probabilities
      (``erfc``) on the side of 0 where both are smallest (``Q(l) - Q(u)`` when ``u > 0``,
      else ``Phi(u) - Phi(l)``), which keeps full relative precision (no tail value is below
      ``Phi(-8)``, so none underflows);
    - the rest (an interval entirely beyond 8 on one side): the exact reflected form
      :func:`_log_interval`.
    """
    lo_near, up_near = lo >= -_DEEP, up <= _DEEP
    both = lo_near & up_near
    single = ~both & np.where(lo_near, lo <= 0.0, up >= 0.0)
    vals = np.empty(lo.size)
    x = np.where(lo_near[single], -lo[single], up[single])
    vals[single] = np.log1p(-0.5 * erfc(x * _SQRT_HALF))
    up_pos = up[both] > 0.0
    a = np.where(up_pos, lo[both], -up[both])
    b = np.where(up_pos, up[both], -lo[both])
    with np.errstate(divide="ignore"):
        vals[both] = np.log(0.5 * (erfc(a * _SQRT_HALF) - erfc(b * _SQRT_HALF)))
    rest = ~(both | single)
    if np.any(rest):
        vals[rest] = _log_interval(lo[rest], up[rest])
    return vals


def _log_interval_dense(lo, up):
    """``log(Phi(up) - Phi(lo))`` of every entry (1-d): ``log`` of the difference of the two
    tail probabilities on the side of 0 where both are smallest, as
    :func:`_log_interval_sparse` for two near bounds. A tail beyond 8 on the far side of its
    bound is taken as 2 (or 0): that drops at most ``1.2e-15`` against a tail above 1/2 (the
    interval reaches past 0). An interval entirely beyond 8 on one side takes the exact
    reflected form :func:`_log_interval`.
    """
    up_pos = up > 0.0
    a = np.where(up_pos, lo, -up)
    b = np.where(up_pos, up, -lo)
    a *= _SQRT_HALF
    b *= _SQRT_HALF
    deep = _DEEP * _SQRT_HALF
    diff = _erfc_where(a, a >= -deep, 2.0)
    diff -= _erfc_where(b, (b <= deep) | (a > 0.0), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        vals = np.log(diff)
    vals += np.log(0.5)
    beyond = np.flatnonzero(a > deep)
    if beyond.size:
        vals[beyond] = _log_interval(lo[beyond], up[beyond])
    return vals


def _erfc_where(x, needed, fill):
    """``erfc(x)`` where ``needed``, ``fill`` elsewhere; only the needed entries are evaluated
    when they are few enough to pay for gathering them."""
    idx = np.flatnonzero(needed)
    if idx.size == x.size:
        return erfc(x)
    if idx.size >= _DENSE_SHARE * x.size:
        return np.where(needed, erfc(x), fill)
    out = np.full(x.shape, fill)
    out[idx] = erfc(x[idx])
    return out


def _log_interval_rows(lower, upper):
    """Row sums of ``log(Phi(upper) - Phi(lower))`` (2-d bounds), as :func:`_log_interval_near`."""
    keep, vals = _log_interval_near(lower, upper)
    if keep is None:
        return vals.reshape(lower.shape).sum(axis=1)
    return np.bincount(keep // lower.shape[1], weights=vals, minlength=lower.shape[0])


def _log_interval_full(lower, upper):
    """``log(Phi(upper) - Phi(lower))`` of every entry, as :func:`_log_interval_near`."""
    keep, vals = _log_interval_near(lower, upper)
    if keep is None:
        return vals.reshape(lower.shape)
    out = np.zeros(lower.shape)
    out.ravel()[keep] = vals
    return out


def _previous(counts, prev_counts):
    """The reading before each sample: ``prev_counts`` as given, else the array's own
    previous element (the first sample its own)."""
    if prev_counts is not None:
        prev = np.asarray(prev_counts, dtype=float)
        if prev.shape != np.shape(counts):
            raise ValueError(f"prev_counts must have the shape of counts {np.shape(counts)}, "
                             f"got {prev.shape}")
        return prev
    k = np.asarray(counts, dtype=float)
    return np.concatenate((k[:1], k[:-1]))


def _interval_bounds(p, t, counts, centre_count, t_ref, harmonics, effects, offset, time_blur,
                     grid, prev_counts=None):
    """Standardised interval bounds ``(lower, upper)`` of every reading, rows of ``p``."""
    drift_col = parameter_column(harmonics, effects, "bends_phase")
    jitter_col = parameter_column(harmonics, effects, "blurs_time")
    band_col = parameter_column(harmonics, effects, "dead_band")
    t = np.asarray(t, dtype=float)
    k = np.asarray(counts, dtype=float) - offset
    jitter = jitter_col is not None or time_blur > 0
    motion, speed = _motion_and_speed(p, t, t_ref, harmonics, drift_col,
                                      grid=grid if t.size > 1 else None, speed=jitter)
    # z - k, built in place: the reading k's interval is [k + lo_shift, k + hi_shift).
    zk = motion
    zk += (centre_count + 0.5) + p[:, 1:2]
    zk -= k
    log_s = p[:, 4:5]
    if jitter:
        sig_t2 = time_blur ** 2
        if jitter_col is not None:
            dt = np.median(np.diff(t)) if t.size > 1 else 1.0
            sig_t2 = sig_t2 + (p[:, jitter_col:jitter_col + 1] * dt) ** 2
        s = 10.0 ** log_s
        inv_s = 1.0 / np.sqrt(s * s + speed * speed * sig_t2)
    else:
        inv_s = 10.0 ** -log_s
    if band_col is not None:
        prev = _previous(counts, prev_counts) - offset
        lower, upper = dead_band_bounds(zk, k, prev, 0.5 * p[:, band_col:band_col + 1])
    else:
        lower = -zk
        upper = 1.0 - zk
    lower *= inv_s
    upper *= inv_s
    return lower, upper


def dead_band_bounds(zk, k, prev, half_w):
    """Bounds ``(lower, upper)`` of a reading's interval less the motion, ``z - k`` given
    (steps, not yet standardised), for a relay with dead band ``2 half_w`` whose previous
    reading is ``prev``.

    Previous reading c: ``k > c`` reads ``[k + w/2, k + 1 + w/2)``, ``k < c``
    ``[k - w/2, k + 1 - w/2)``, ``k = c`` ``[k - w/2, k + 1 + w/2)``.
    """
    lo_sign = np.where(k > prev, 1.0, -1.0)
    hi_sign = np.where(k < prev, -1.0, 1.0)
    lower = half_w * lo_sign - zk
    upper = half_w * hi_sign + 1.0
    upper = upper - zk
    return lower, upper


def jump_log_terms(base, shifted):
    """Log-likelihood of every jump gap from pointwise terms: ``base`` (rows, n) without an
    offset, ``shifted`` the same with the counts offset by each sign. Returns (rows, signs,
    n - 1): the gap ``i`` lies between samples ``i`` and ``i + 1``, and the shorter segment
    carries the offset."""
    n = base.shape[1]
    c0 = np.cumsum(base, axis=1)
    total0 = c0[:, -1:]
    idx = np.arange(1, n)  # the jump lies between samples idx - 1 and idx
    first_short = idx < n - idx
    out = []
    for one in shifted:
        cd = np.cumsum(one, axis=1)
        # Shorter segment offset by delta from the reference (longer) segment.
        before_short = cd[:, idx - 1] + (total0 - c0[:, idx - 1])
        after_short = c0[:, idx - 1] + (cd[:, -1:] - cd[:, idx - 1])
        out.append(np.where(first_short, before_short, after_short))
    return np.stack(out, axis=1)


def jump_offsets(n, index, delta):
    """Per-sample count offsets of a jump before sample ``index``: ``delta`` on the shorter
    segment, 0 on the longer one (the reference frame)."""
    offsets = np.zeros(int(n), dtype=np.int64)
    if index < n - index:
        offsets[:index] = delta
    else:
        offsets[index:] = delta
    return offsets


def pointwise_log_likelihood(params, t, counts, step, centre_count, t_ref, harmonics=(),
                             effects=(), offset=0, time_blur=0.0, grid=None,
                             prev_counts=None) -> np.ndarray:
    """``log p(count_j | previous count, theta)`` per parameter row and sample.

    Parameters
    ----------
    params : numpy.ndarray, shape (n_rows, n_params)
        Internal rows ``(A12/step, E_b/step, f_hz, phase, log10(s))``, then ``c_k, s_k`` per
        harmonic (steps), then the effect parameters (:func:`effect_param_names`).
    t, counts : numpy.ndarray
        Sample times (s) and integer counts.
    step, centre_count, t_ref :
        As :func:`enclab.lrde.fit.log_likelihood`.
    harmonics, effects : tuple
        Model terms; a count jump is ignored here (see :func:`log_likelihood`).
    offset : int
        Count offset subtracted from ``counts`` (and the previous counts) before reading.
    time_blur : float
        Extra timing uncertainty in s, added like ``time_jitter`` (prediction of held-out
        readings from a point fit, see :func:`enclab.lrde.compare.compare_effect_models`).
    grid : tuple, optional
        :func:`enclab.lrde.model.uniform_grid` of ``t`` (faster phase factor), or None.
    prev_counts : numpy.ndarray, optional
        The reading just before each sample in the whole log (the dead band's state). By
        default the previous element of ``counts``, which is right only when ``counts`` is
        the whole log or one contiguous piece of it: a subset joined from separate pieces
        (every other cycle) needs the true predecessors, or each seam reads a transition
        that never happened.

    Returns
    -------
    numpy.ndarray, shape (n_rows, len(t))
        Entries with both interval bounds beyond 8 standard deviations are 0 (their value is
        above ``-1.3e-15``).
    """
    p = np.atleast_2d(np.asarray(params, dtype=float))
    effects = check_effects(effects)
    lower, upper = _interval_bounds(p, t, counts, centre_count, t_ref, harmonics, effects,
                                    offset, time_blur, grid, prev_counts)
    return _log_interval_full(lower, upper)


def _jump_terms(params, t, counts, step, centre_count, t_ref, harmonics, effects, grid=None,
                prev_counts=None):
    """Log-likelihood of every jump index and sign: array (n_rows, 2, n - 1) and the signs."""
    base = pointwise_log_likelihood(params, t, counts, step, centre_count, t_ref, harmonics,
                                    effects, grid=grid, prev_counts=prev_counts)
    signs = JUMP_SIGNS
    shifted = [pointwise_log_likelihood(params, t, counts, step, centre_count, t_ref,
                                        harmonics, effects, offset=delta, grid=grid,
                                        prev_counts=prev_counts) for delta in signs]
    return jump_log_terms(base, shifted), signs


def log_likelihood(params, t, counts, step, centre_count, t_ref, harmonics=(), effects=(),
                   grid=None, prev_counts=None):
    """Total log-likelihood per parameter row; a count jump (:attr:`Effect.offsets_counts`)
    marginalised over index and sign.

    The jump's prior is uniform over the ``n - 1`` gaps between samples and the two signs.
    ``grid`` is :func:`enclab.lrde.model.uniform_grid` of ``t`` or None (same values, slower);
    ``prev_counts`` as :func:`pointwise_log_likelihood`.
    """
    effects = check_effects(effects)
    p = np.atleast_2d(np.asarray(params, dtype=float))
    if not offsets_counts(effects):
        lower, upper = _interval_bounds(p, t, counts, centre_count, t_ref, harmonics, effects,
                                        0, 0.0, grid, prev_counts)
        out = _log_interval_rows(lower, upper)
    else:
        terms, _ = _jump_terms(p, t, counts, step, centre_count, t_ref, harmonics, effects,
                               grid, prev_counts)
        flat = terms.reshape(p.shape[0], -1)
        out = logsumexp(flat, axis=1) - np.log(flat.shape[1])
    return out if np.ndim(params) == 2 else float(out[0])


def jump_posterior(params, t, counts, step, centre_count, t_ref, harmonics=(), effects=(),
                   prev_counts=None):
    """Posterior of the jump at one parameter row: ``(index, delta, probability, offsets)``.

    ``index`` is the first sample after the jump, ``delta`` the offset of the shorter segment,
    ``probability`` the posterior mass of that (index, sign) within +-1 sample, and ``offsets``
    the per-sample count offset under that mode (0 on the reference segment).
    """
    p = np.atleast_2d(np.asarray(params, dtype=float))[:1]
    terms, signs = _jump_terms(p, t, counts, step, centre_count, t_ref, harmonics,
                               tuple(e for e in effects), prev_counts=prev_counts)
    flat = terms[0]
    post = np.exp(flat - logsumexp(flat))
    sign_i, gap = np.unravel_index(int(np.argmax(post)), post.shape)
    index = int(gap) + 1
    mass = float(post[sign_i, max(gap - 1, 0):gap + 2].sum())
    return index, int(signs[sign_i]), mass, jump_offsets(np.size(t), index, signs[sign_i])


def simulate_counts(rng, t, step, A12, a_eq, f_hz, phase, t_ref=0.0, noise_std=0.0,
                    harmonics=None, hysteresis=0.0, drift=0.0, jump=None, time_jitter=0.0,
                    n_rep=None):
    """Brute-force readings of the effect model (the reference for the likelihood's tests).

    Sample times are perturbed (``time_jitter``, s), the motion evaluated there exactly (with
    ``drift`` in 1/s and ``harmonics`` ``{k: (c_k, s_k)}`` in rad), position noise added
    (``noise_std``, rad), and a relay with dead band ``hysteresis`` (rad) run sample by sample
    from the state ``floor(z_0 + e_0)``; ``jump = (index, delta)`` adds ``delta`` to the counts
    from ``index`` on.

    Returns
    -------
    numpy.ndarray of int64, shape (len(t),) or (n_rep, len(t))
    """
    t = np.asarray(t, dtype=float)
    reps = 1 if n_rep is None else int(n_rep)
    tt = t + (rng.normal(0.0, time_jitter, (reps, t.size)) if time_jitter > 0 else 0.0)
    u = tt - t_ref
    phi = 2.0 * np.pi * f_hz * (u + 0.5 * drift * u * u) + phase
    theta = 0.5 * A12 * np.sin(phi)
    for k, (c_k, s_k) in (harmonics or {}).items():
        theta = theta + c_k * np.cos(k * phi) + s_k * np.sin(k * phi)
    x = (theta + a_eq) / step
    x = np.broadcast_to(x, (reps, t.size)).copy()
    if noise_std > 0:
        x += rng.normal(0.0, noise_std / step, x.shape)
    out = relay(x, 0.5 * hysteresis / step)
    if jump is not None:
        out[:, int(jump[0]):] += int(jump[1])
    return out[0] if n_rep is None else out


def relay(x, half_w):
    """Readings (int64, rows x samples) of a relay with dead band ``2 half_w`` (steps) driven
    by ``x`` (steps, rows x samples), from the state ``floor(x_0)``; plain rounding down when
    ``half_w`` is 0."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    reps = x.shape[0]
    if half_w > 0:
        out = np.empty(x.shape, dtype=np.int64)
        if reps < _RELAY_ROWS_VECTOR:
            # Few readings: a plain loop over floats costs far less than numpy's per-call
            # overhead on rows this short (same IEEE arithmetic, same readings).
            for r, row in enumerate(x.tolist()):
                state = math.floor(row[0])
                states = [state]
                for xj in row[1:]:
                    if xj >= state + 1.0 + half_w:
                        state = math.floor(xj - half_w)
                    elif xj < state - half_w:
                        state = math.floor(xj + half_w)
                    states.append(state)
                out[r] = states
        else:
            state = np.floor(x[:, 0])
            out[:, 0] = state
            for j in range(1, x.shape[1]):
                xj = x[:, j]
                up = xj >= state + 1.0 + half_w
                down = xj < state - half_w
                state = np.where(up, np.floor(xj - half_w),
                                 np.where(down, np.floor(xj + half_w), state))
                out[:, j] = state
    else:
        out = np.floor(x).astype(np.int64)
    return out


#: Bound (standard deviations) beyond which an interval's far edge is dropped.
INTERVAL_DEPTH = _DEEP
#: Share of near entries from which the likelihood evaluates every entry in place.
INTERVAL_DENSE_SHARE = _DENSE_SHARE


def log_interval_probability(lower, upper, path: str = "rows"):
    """``log(Phi(upper) - Phi(lower))`` by one of the likelihood's evaluation paths.

    The likelihood of a reading is the probability of its interval; this exposes the paths
    that compute it so that their cost and agreement can be measured on their own.

    Parameters
    ----------
    lower, upper : numpy.ndarray
        Interval bounds in standard deviations, ``lower < upper``.
    path : {"rows", "gathered", "in_place"}
        ``"rows"``: row sums of 2-d bounds, by the path the likelihood picks from the share
        of near entries (an entry is near when ``lower >= -INTERVAL_DEPTH`` or
        ``upper <= INTERVAL_DEPTH``; every other entry is ~0); ``"gathered"``: every entry of
        1-d bounds of near entries, evaluated by kind; ``"in_place"``: every entry of 1-d
        bounds, evaluated in place.

    Returns
    -------
    numpy.ndarray
        One value per row (``"rows"``) or per entry.

    Raises
    ------
    ValueError
        For an unknown ``path``.
    """
    if path == "rows":
        return _log_interval_rows(lower, upper)
    if path == "gathered":
        return _log_interval_sparse(lower, upper)
    if path == "in_place":
        return _log_interval_dense(lower, upper)
    raise ValueError(f"path must be 'rows', 'gathered' or 'in_place', got {path!r}")
