"""Effect library: composable terms of the measured-channel model (method: docs/residuals.md).

The measured channel with step ``step`` reads the count ``k = floor(theta_eff / step + c)``
of an *effective* angle ``theta_eff``: the truth angle changed by the effects below, in the
order of their ``order`` attribute (mechanics first, then the sensor, then the counter).
``c`` is the quantizer offset in counts (a nuisance fitted with every model, see
:mod:`enclab.residuals.select`). Three kinds of effect exist:

``shift``
    ``apply(theta, t, velocity, aux, params)`` returns the modified angle (rad).
``noise``
    ``noise_std(theta, t, velocity, aux, params)`` returns an extra per-sample standard
    deviation of the angle (rad) that enters the likelihood's jitter.
``discrete``
    shifts whose parameters are found by a search (changepoint times, a wrap period), not by
    a continuous optimiser; they still provide ``apply``.

``aux`` is a dict of extra channels (e.g. ``{"torque": array}``) plus private entries the
selection fills: ``"_step"`` (measured step, rad), ``"_offset"`` (``c``, counts),
``"_counts"`` (measured counts), ``"_theta_ref"`` (reference angle of the scale term, rad),
``"_line_pitch"`` (rad), ``"_motion_sign"`` (direction of the last motion) and
``"_smooth_correction"`` (rad: a smooth reconstruction of the angle minus the truth reading,
zero for a continuous truth).

Each effect is one :class:`Effect` subclass listed in :data:`EFFECTS` (the order the selection
tries them) and found by name in :data:`REGISTRY`. The selection and the reports reach an
effect only through its attributes and methods; an effect that the low-resolution fit
(:mod:`enclab.lrde.effects`) also has declares that term as its ``counterpart``, and one that has
none says why (``lrde_no_term``) and which of that fit's estimates it biases (``lrde_biases``).
Adding an effect is adding a class and its test (docs/development.md, "Adding an effect").

Each effect documents its *signature*: what the residual ``measured - truth`` looks like
when the effect is present and not modelled. :meth:`Effect.signature` gives its linearisation
``d theta_eff / d params`` at the null (effect absent), which the selection regresses the
residual on for a starting guess.
"""
from __future__ import annotations

import math

import numpy as np

from enclab.residuals.calibration import TERMS, MapBasis

__all__ = [
    "Effect",
    "TruthQuantization",
    "Hysteresis",
    "Backlash",
    "AngleHarmonics",
    "HarmonicMap",
    "LinePitchHarmonics",
    "QuadratureEdges",
    "Latency",
    "TimestampJitter",
    "ScaleMismatch",
    "Compliance",
    "SofteningCompliance",
    "InertialTwist",
    "CalibrationMap",
    "SlowDrift",
    "LevelShift",
    "MissedCounts",
    "WrapAround",
    "EFFECTS",
    "REGISTRY",
    "play_operator",
    "motion_sign",
    "run_blocks",
]


def motion_sign(velocity) -> np.ndarray:
    """Sign of the last non-zero velocity (+1/-1), 0 before the first motion.

    A dwell keeps the direction of the motion that ended in it: the memory of a dead band
    or of a gear's play.
    """
    v = np.asarray(velocity, dtype=float)
    s = np.sign(v)
    idx = np.where(s != 0, np.arange(s.size), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where(idx >= 0, s[np.maximum(idx, 0)], 0.0)
    return out


def play_operator(x, width: float, y0: float | None = None) -> np.ndarray:
    """Play (backlash) operator of width ``width >= 0`` applied to the input ``x``.

    ``y_i = min(max(y_{i-1}, x_i - width/2), x_i + width/2)`` with ``y_0 = x_0`` (or ``y0``).
    The output stays still after a reversal until the input has moved ``width``, then follows
    it ``width/2`` behind.

    Notes
    -----
    Computed run by run: on a run where ``x`` does not decrease the recursion reduces to
    ``y_i = max(y_start, x_i - width/2)`` (``x_i + width/2`` never binds since ``x`` rose),
    and symmetrically on a non-increasing run, so the cost is one vectorised pass per
    monotone run rather than one Python step per sample.
    """
    x = np.asarray(x, dtype=float)
    if width < 0:
        raise ValueError(f"play width must be >= 0, got width={width!r}")
    n = x.size
    y = np.empty(n)
    if n == 0:
        return y
    half = 0.5 * width
    prev = x[0] if y0 is None else float(np.clip(y0, x[0] - half, x[0] + half))
    d = np.diff(x)
    nz = np.flatnonzero(d)
    # run boundaries: where the sign of the non-zero increments changes
    if nz.size == 0:
        y[:] = prev
        return y
    sgn = np.sign(d[nz])
    change = nz[1:][sgn[1:] != sgn[:-1]]  # index i of d[i] starting a new direction
    starts = np.concatenate(([1], change + 1))
    ends = np.concatenate((change + 1, [n]))
    dirs = np.concatenate(([sgn[0]], sgn[1:][sgn[1:] != sgn[:-1]]))
    y[0] = prev
    for s, e, dr in zip(starts, ends, dirs):
        seg = x[s:e]
        if dr > 0:
            y[s:e] = np.maximum(prev, seg - half)
        else:
            y[s:e] = np.minimum(prev, seg + half)
        prev = y[e - 1]
    return y


def run_blocks(truth, n_blocks: int) -> list:
    """``n_blocks`` contiguous index blocks of about equal length whose edges never split a run
    of one truth reading (an edge inside a run moves to the run's end).

    A dwell is one truth reading and one rounding error however many samples it lasts: split
    between a fitted and a scored block, the fit would predict the score from the same error.
    """
    truth = np.asarray(truth)
    n = truth.size
    edges = [0]
    for b in np.linspace(0, n, n_blocks + 1)[1:-1].round().astype(int):
        b = max(int(b), edges[-1])
        while 0 < b < n and truth[b] == truth[b - 1]:
            b += 1
        if b > edges[-1]:
            edges.append(b)
    if edges[-1] < n:
        edges.append(n)
    return [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:])]


def _span(ctx) -> float:
    """Half-range of the offset-like parameters: 20 steps, or twice the residual's range when
    that is larger (set by :func:`enclab.residuals.select._make_ctx`)."""
    return float(getattr(ctx, "priv", {}).get("_span", 20.0 * ctx.step))


class Effect:
    """Base class of an effect term.

    Attributes
    ----------
    name : str
        Identifier used in reports and in ``candidates``.
    param_names : tuple of str
        Names of the free parameters (SI units: rad, s, 1).
    kind : {"shift", "noise", "discrete"}
    additive : bool
        The shift does not depend on the angle it is applied to (``theta + f(t, aux)``): a
        parameter of an earlier effect passes through it unchanged.
    order : int
        Position in the composition (lower is applied first).
    boundary : tuple of str
        Parameters whose null value (0) lies on the boundary of their range: the likelihood
        ratio there follows a 50:50 mixture of chi2 with one degree of freedom fewer and
        chi2 (Self & Liang 1987).
    default : bool
        Tried when the caller names no candidates; an effect off by default is tried only
        when named in ``candidates``.
    reads_counts : bool
        The effect needs the measured counts (``aux["_counts"]``): it is left out of a
        prediction on another trajectory.
    counterpart : str or None
        The low-resolution fit's term of the same physics (:data:`enclab.lrde.effects.REGISTRY`,
        whose class lists this effect among its ``counterparts``), or None.
    counterpart_param : str or None
        This effect's parameter that is the counterpart's (same SI unit; its magnitude is
        taken, the low-resolution terms being unsigned).
    lrde_no_term : str
        Without a counterpart: what the effect does to the low-resolution fit's estimates.
    lrde_biases : tuple of str
        Without a counterpart: the low-resolution estimates whose assumptions it breaks (an
        effect that only shifts the motion's phase, rescales the stroke as read, or distorts
        the motion as a harmonic would, which the comparison's motion terms cover, breaks none).
    test : str
        The test (``path::name``) that checks the effect against a brute-force simulation.
    """

    name = "effect"
    param_names: tuple = ()
    kind = "shift"
    additive = False
    order = 50
    boundary: tuple = ()
    default = True
    reads_counts = False
    counterpart = None
    counterpart_param = None
    lrde_no_term = "no term of the low-resolution model describes it"
    lrde_biases: tuple = ()
    test = ""
    #: The effect is an error of the measured angle (a calibration a controller's lookup table
    #: holds, :mod:`enclab.residuals.lookup_table`); the others are fitted beside such a table.
    angle_map = False

    def applicable(self, ctx) -> bool:
        """Whether the effect can be fitted with the data in ``ctx`` (default: yes)."""
        return True

    def null(self) -> np.ndarray:
        """Parameter values at which the effect vanishes."""
        return np.zeros(len(self.param_names))

    def bounds(self, ctx) -> list[tuple[float, float]]:
        """Search range of each parameter, from the scales of the log in ``ctx``.

        Default: +-:func:`_span` for every parameter (offset-like parameters in rad);
        effects with other units override it.
        """
        lim = _span(ctx)
        return [(-lim, lim)] * len(self.param_names)

    def fd_steps(self, ctx) -> np.ndarray:
        """Finite-difference steps of the parameters (a small fraction of the range)."""
        return np.array([1e-4 * (hi - lo) for lo, hi in self.bounds(ctx)])

    def apply(self, theta, t, velocity, aux, params):
        """Modified angle (rad); identity for noise effects."""
        return theta

    def noise_std(self, theta, t, velocity, aux, params):
        """Extra per-sample angle jitter (rad); zero for shift effects."""
        return None

    def signature(self, theta, t, velocity, aux, ctx) -> np.ndarray:
        """Columns ``d theta_eff / d p`` at the null, shape (N, n_params), by central differences."""
        p0 = self.null()
        h = self.fd_steps(ctx)
        cols = []
        for j in range(p0.size):
            up, dn = p0.copy(), p0.copy()
            up[j] += h[j]
            dn[j] -= h[j]
            cols.append((self.apply(theta, t, velocity, aux, up) - self.apply(theta, t, velocity, aux, dn)) / (2 * h[j]))
        return np.column_stack(cols) if cols else np.zeros((np.size(theta), 0))

    def derived(self, params: dict) -> dict:
        """Extra derived quantities for reports (e.g. amplitude and phase)."""
        return {}

    @classmethod
    def propose(cls, ctx, mu):
        """A discrete effect found by its search on the current model, or None.

        ``mu`` is the current model's continuous count prediction (counts). Only for
        ``kind == "discrete"``: their parameters are found here, not by the optimiser."""
        raise NotImplementedError(f"{cls.name} is not a discrete effect")

    def found_params(self) -> dict:
        """The parameters a discrete effect's search found (JSON-ready)."""
        return {}

    def describe(self, params: dict) -> str:
        """The fitted values in words for the verdict (default: each parameter and its value)."""
        return ", ".join(f"{k} {v:.3g}" for k, v in params.items())

    #: What a reduced form (:meth:`reduced`) keeps, in words (None for the full form).
    form = None

    def reduced(self):
        """The same effect with fewer parameters (its leading terms), or None.

        An alternative is weighed against a chosen effect at matched complexity too: a
        three-term drift loses to a one-parameter scale by its two extra parameters' BIC
        penalty even where its linear term alone reads the log as well (a steadily rotating
        axis, whose angle is a ramp in time)."""
        return None

    #: The motion that tells this effect apart from others it can trade off against (words).
    separated_by = "a longer, more varied motion"

    def caveat(self, ctx) -> str | None:
        """What this log's motion cannot tell about the effect's parameters (words), or None."""
        return None

    @classmethod
    def lrde_finding(cls, params: dict, ci: dict) -> dict:
        """The effect's findings (``params``, ``ci`` of a ``residuals.json`` effect) as the
        low-resolution fit's term.

        Returns ``{"term", "value", "ci"}`` (the counterpart, the magnitude of
        ``counterpart_param`` and its interval of magnitudes) or, without a counterpart,
        ``{"why", "biases"}`` (:attr:`lrde_no_term`, :attr:`lrde_biases`).
        """
        if cls.counterpart is None:
            return {"why": cls.lrde_no_term, "biases": list(cls.lrde_biases)}
        key = cls.counterpart_param
        if key not in params:
            raise ValueError(f"residual effect {cls.name!r} has no parameter {key!r}: "
                             f"{sorted(params)}")
        return {"term": cls.counterpart, "value": abs(float(params[key])),
                "ci": magnitude_interval((ci or {}).get(key))}

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


def magnitude_interval(ci) -> list[float] | None:
    """The interval ``[lo, hi]`` of ``|p|`` for a signed parameter's interval ``ci`` (None
    passes through): a signed width whose interval spans zero starts at zero width."""
    if ci is None:
        return None
    lo, hi = sorted(abs(float(v)) for v in ci)
    if float(ci[0]) * float(ci[1]) < 0:
        lo = 0.0
    return [lo, hi]


class TruthQuantization(Effect):
    """Quantization of the truth channel with step ``truth_step``: no free parameter.

    The true angle lies in ``truth + U(-truth_step/2, truth_step/2)``, so the predicted
    count flips near the measured thresholds and the residual against the exact model gets
    the variance of those flips. Signature: residual non-zero only where the truth is within
    ``truth_step/2`` of a measured threshold. The selection always includes it in the exact-model
    floor (it is part of the exact model, not hardware); it adds ``truth_step**2 / 12`` to
    the angle's jitter.
    """

    name = "truth_quantization"
    kind = "noise"
    order = 0
    lrde_no_term = "the reference channel's own quantization"
    test = "tests/test_residual_effects.py::test_truth_quantization_std_is_that_of_a_simulated_truth_rounding"

    def applicable(self, ctx) -> bool:
        return bool(ctx.truth_step)

    def bounds(self, ctx):
        return []

    def noise_std(self, theta, t, velocity, aux, params):
        return np.full(np.shape(theta), aux.get("_truth_step", 0.0) / math.sqrt(12.0))


class Hysteresis(Effect):
    """Dead band / hysteresis of width ``h`` (rad): ``theta_eff = theta - (h/2) sign(v)``.

    ``sign(v)`` is the direction of the last motion (memory through dwells). Signature:
    residual ``measured - truth`` is ``-h/2`` on rising motion and ``+h/2`` on falling motion,
    a step at each reversal. ``h`` is signed: positive means the measured channel lags the
    truth, negative that it leads; ``h = 0`` is therefore an interior point (regular chi2_1).
    """

    name = "hysteresis"
    additive = True
    param_names = ("h",)
    order = 10
    counterpart, counterpart_param = "hysteresis", "h"
    test = "tests/test_residual_select.py::test_round_trip_recovers_parameters_within_their_standard_error"

    separated_by = "slow reversals (the play's ramp against the dead band's step)"

    def bounds(self, ctx):
        lim = _span(ctx)
        return [(-lim, lim)]

    def apply(self, theta, t, velocity, aux, params):
        return theta - 0.5 * params[0] * aux["_motion_sign"]

    def derived(self, params):
        return {"band_width": abs(params["h"]), "measured_lags": float(params["h"] >= 0)}

    def describe(self, params):
        h = params["h"]
        return f"width {abs(h):.3g} rad, the measured channel {'lags' if h >= 0 else 'leads'}"


class Backlash(Effect):
    """Backlash (play operator) of signed width ``w`` (rad) between truth and measured side.

    ``w > 0``: the measured side is driven through a play of width ``w``:
    ``theta_eff = play_w(theta)``; ``w < 0``: the measured side drives,
    ``theta_eff = 2 theta - play_|w|(theta)``. Signature: after each reversal the residual
    moves by ``w`` over an input travel of ``|w|`` (a ramp, unlike the instant step of the
    hysteresis) and then stays at ``-w/2`` (rising) or ``+w/2`` (falling). Both signs are
    physical and the two branches join smoothly at ``w = 0`` (interior null, regular chi2_1).

    The play acts on the physical angle, so its correction ``play_|w|(x) - x`` is computed on a
    smooth reconstruction ``x = theta + aux["_smooth_correction"]`` and added to ``theta``.
    Applied to a quantized truth reading instead, a play narrower than the truth's step would
    switch only when the reading leaves its plateau at a reversal, up to half a plateau after
    the reversal itself: a model of the truth channel's quantization, not of the gear (challenge
    benchmark: a 0.04-step play then lost to a hysteresis by 10-15 in delta BIC).
    """

    name = "backlash"
    param_names = ("w",)
    order = 11
    # the play operator is non-linear in w: the linearised guess can land in a worse basin
    multistart = True
    # a play before the encoder reads like a dead band of the same width
    counterpart, counterpart_param = "hysteresis", "w"
    test = "tests/test_residual_select.py::test_round_trip_recovers_parameters_within_their_standard_error"

    separated_by = "slow reversals over more than the play's width"

    def bounds(self, ctx):
        lim = _span(ctx)
        return [(-lim, lim)]

    def apply(self, theta, t, velocity, aux, params):
        w = float(params[0])
        d = aux.get("_smooth_correction")
        x = theta if d is None else theta + d
        corr = play_operator(x, abs(w)) - x
        return theta + corr if w >= 0 else theta - corr

    def derived(self, params):
        return {"play_width": abs(params["w"]), "measured_lags": float(params["w"] >= 0)}

    def describe(self, params):
        w = params["w"]
        return f"play {abs(w):.3g} rad, driven from the {'truth' if w >= 0 else 'measured'} side"


# An angle harmonic and a scale error differ only over a full turn: a harmonic returns, a
# scale error grows. Over a shorter stroke both are a smooth error of the angle there.
_FULL_TURN = "a motion over a full turn or more (a harmonic returns, a scale error grows)"


def _stroke_below_a_turn(ctx) -> float | None:
    """The truth's stroke (rad) when it is shorter than a turn, else None."""
    stroke = float(np.ptp(ctx.truth))
    return stroke if stroke < 2.0 * np.pi else None


class AngleHarmonics(Effect):
    """Once- and twice-per-revolution error (eccentricity, tilt): four coefficients (rad).

    ``theta_eff = theta + a1 cos(theta) + b1 sin(theta) + a2 cos(2 theta) + b2 sin(2 theta)``.
    Signature: residual periodic in ``theta mod 2 pi`` with one and two cycles per
    revolution. Linear coefficients (not amplitude/phase) keep the null interior and regular;
    amplitudes and phases are reported as derived values.
    """

    name = "angle_harmonics"
    param_names = ("a1", "b1", "a2", "b2")
    order = 20
    angle_map = True
    lrde_no_term = ("a once- or twice-per-turn error of the disc; over a stroke of a few "
                    "steps it acts as a scale and offset error of the reading")
    test = "tests/test_residual_select.py::test_backward_check_drops_an_effect_that_a_later_one_made_redundant"

    separated_by = _FULL_TURN

    def caveat(self, ctx):
        stroke = _stroke_below_a_turn(ctx)
        if stroke is None:
            return None
        return (f"over a stroke of {stroke:.2g} rad the harmonic coefficients describe a smooth error of "
                "the angle there, not the disc's run-out (a motion over a full turn pins them)")

    def applicable(self, ctx) -> bool:
        # a harmonic of the angle is only told apart from a constant on a travel of >= ~1 rad
        return float(np.ptp(ctx.truth)) >= 1.0

    def bounds(self, ctx):
        lim = _span(ctx)
        return [(-lim, lim)] * 4

    def apply(self, theta, t, velocity, aux, params):
        a1, b1, a2, b2 = params
        return theta + a1 * np.cos(theta) + b1 * np.sin(theta) + a2 * np.cos(2 * theta) + b2 * np.sin(2 * theta)

    def derived(self, params):
        return {
            "amp1": math.hypot(params["a1"], params["b1"]),
            "phase1": math.atan2(params["a1"], params["b1"]),
            "amp2": math.hypot(params["a2"], params["b2"]),
            "phase2": math.atan2(params["a2"], params["b2"]),
        }


class HarmonicMap(Effect):
    """Angle error of the measured side as harmonics ``1 .. K`` of the angle, ``K`` chosen on
    held-out data: the calibration form of interpolating magnetic encoders and resolvers.

    ``theta_eff = theta + sum_k a_k cos(k theta) + b_k sin(k theta)`` (rad), on the smooth angle.
    :meth:`prepare` fits the current exact-model residual with each order ``1 .. max_order`` on
    every other of ``n_blocks`` time blocks, scores it on the blocks between (both ways), and
    takes the order with the smallest held-out error; the map is not tried when that order is
    below 3 (the once- and twice-per-turn terms are :class:`AngleHarmonics`) or the motion does
    not cover a full turn (a periodic map is then no calibration; :class:`CalibrationMap` maps a
    partial stroke). Signature: a residual periodic in the angle with three or more cycles per
    turn beside the first two. Derived: ``order`` and ``amp1 .. ampK`` (rad).
    """

    name = "harmonic_map"
    additive = True
    order = 20
    angle_map = True
    max_order = 8
    n_blocks = 40
    heldout_interleave = 10
    lrde_no_term = ("an angle error of three or more cycles per turn; over a stroke of a few "
                    "steps it acts as a scale and offset error of the reading")
    test = "tests/test_residual_effects.py::test_harmonic_map_order_is_chosen_on_heldout_blocks"

    separated_by = _FULL_TURN

    def __init__(self):
        self.param_names = ()
        self.n_harmonics = 0

    def applicable(self, ctx) -> bool:
        return float(np.ptp(ctx.truth)) >= 2.0 * np.pi

    @staticmethod
    def design(a, order: int) -> np.ndarray:
        """``[cos a, sin a, ..., cos Ka, sin Ka]`` (N, 2K)."""
        a = np.asarray(a, dtype=float)
        return np.column_stack([f(k * a) for k in range(1, order + 1) for f in (np.cos, np.sin)])

    def prepare(self, ctx, resid) -> bool:
        idx = ctx.fit_idx
        a = (ctx.priv["_smooth"] if "_smooth" in ctx.priv else ctx.truth)[idx]
        y = np.asarray(resid, dtype=float)[idx]
        blocks = run_blocks(ctx.truth[idx], self.n_blocks)
        halves = (np.concatenate(blocks[0::2]), np.concatenate(blocks[1::2]))
        full = np.column_stack([np.ones(a.size), self.design(a, self.max_order)])
        errs = []
        for k in range(0, self.max_order + 1):
            D = full[:, :1 + 2 * k]
            err = 0.0
            for fit, test in (halves, halves[::-1]):
                coef, *_ = np.linalg.lstsq(D[fit], y[fit], rcond=None)
                err += float(np.sum((y[test] - D[test] @ coef) ** 2))
            errs.append(err)
        best = int(np.argmin(errs))
        if best < 3:
            return False
        self.n_harmonics = best
        self.param_names = tuple(f"{c}{k}" for k in range(1, best + 1) for c in ("a", "b"))
        self._cache = None
        return True

    def _design(self, aux):
        a = aux["_smooth"]
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] is not a or cached[1] != self.n_harmonics:
            self._cache = (a, self.n_harmonics, self.design(a, self.n_harmonics))
        return self._cache[2]

    def columns(self, aux):
        """``d theta_eff / d (a1, b1, ...)``: the harmonics at the smooth angle."""
        return self._design(aux).T

    def apply(self, theta, t, velocity, aux, params):
        return theta + self._design(aux) @ np.asarray(params, dtype=float)

    def derived(self, params):
        out = {"order": float(self.n_harmonics)}
        for k in range(1, self.n_harmonics + 1):
            out[f"amp{k}"] = math.hypot(params.get(f"a{k}", 0.0), params.get(f"b{k}", 0.0))
        return out


class LinePitchHarmonics(Effect):
    """Interpolation / sub-division error periodic in the line pitch ``P`` (rad).

    ``theta_eff = theta + a cos(2 pi theta / P) + b sin(2 pi theta / P)``; ``P`` defaults to
    four counts (one line of a quadrature encoder) and can be given as ``line_pitch``
    (e.g. an interpolated encoder with 16 counts per line). At four counts it coincides with
    :class:`QuadratureEdges` on the thresholds and is not a separate candidate.
    Signature: residual periodic in ``theta mod P``.
    """

    name = "line_pitch_harmonics"
    param_names = ("a", "b")
    order = 30
    lrde_no_term = "an interpolation error far below one coarse step"
    test = "tests/test_residual_select.py::test_line_pitch_harmonics_are_found_with_their_values"

    def applicable(self, ctx) -> bool:
        # The count depends on the angle only at the thresholds; at a pitch of four counts a
        # harmonic of the line is the pattern e = (a, b, -a, -b) of QuadratureEdges, so the two
        # cannot be told apart and only the quadrature pattern (its superset) is a candidate.
        pitch = ctx.priv["_line_pitch"]
        return abs(pitch / ctx.step - 4.0) > 1e-6 and pitch > 2.0 * ctx.step

    def bounds(self, ctx):
        lim = 2.0 * ctx.step
        return [(-lim, lim)] * 2

    def apply(self, theta, t, velocity, aux, params):
        w = 2.0 * np.pi * theta / aux["_line_pitch"]
        return theta + params[0] * np.cos(w) + params[1] * np.sin(w)

    def derived(self, params):
        return {"amplitude": math.hypot(params["a"], params["b"]), "phase": math.atan2(params["a"], params["b"])}


class QuadratureEdges(Effect):
    """Quadrature edge-spacing error: the edge into count ``m`` is displaced by ``e_{m mod 4}``.

    Three free displacements ``e0, e1, e2`` (rad); ``e3 = -(e0 + e1 + e2)`` since a common
    shift of all four edges is the quantizer offset. Implemented as
    ``theta_eff = theta - e_{m mod 4}`` with ``m`` the nearest threshold index
    ``floor(theta/step + c + 1/2)``: exact for ``|e| < step/2``. Signature: residual that
    repeats every four counts of the measured channel.
    """

    name = "quadrature_edges"
    param_names = ("e0", "e1", "e2")
    order = 40
    lrde_no_term = ("unequal edge spacing: the levels of the reading are not evenly "
                    "spaced, which the model's uniform levels cannot represent")
    lrde_biases = ("A12", "a_eq", "E_b", "offset_a")  # the levels are evenly spaced there
    test = "tests/test_residual_effects.py::test_quadrature_edges_model_matches_exact_edge_displacement"

    def bounds(self, ctx):
        lim = 0.45 * ctx.step
        return [(-lim, lim)] * 3

    def apply(self, theta, t, velocity, aux, params):
        e = np.array([params[0], params[1], params[2], -(params[0] + params[1] + params[2])])
        m = np.floor(theta / aux["_step"] + aux["_offset"] + 0.5).astype(np.int64) % 4
        return theta - e[m]

    def derived(self, params):
        return {"e3": -(params["e0"] + params["e1"] + params["e2"])}


class Latency(Effect):
    """Latency or channel skew ``tau`` (s): the measured channel reads the angle ``tau`` late.

    ``theta_eff(t) = theta(t - tau)``, evaluated on a cubic spline of the smooth
    reconstruction of the angle (``aux["_smooth_spline"]``; ``theta - tau v`` without one).
    Signature: residual ``-tau v`` to first order, proportional to velocity, plus
    ``tau^2 a / 2``. ``tau`` is signed (the measured channel may lead).

    Applied first (``order`` 5): the reading is the whole measured side delayed, e.g.
    ``play(theta)(t - tau)`` behind a gear, and a rate-independent operator commutes with a time
    shift, ``play(theta)(t - tau) = play(theta(. - tau))(t)``, so the shift of the input is exact.
    Applied after the play (``play(theta) - tau v``) it would move the reading while the play is
    being taken up and the output stands still (challenge benchmark, backlash + latency: 3 of 10
    logs covered both parameters with their 90 % intervals; 8 of 10 in this order).
    """

    name = "latency"
    additive = True
    param_names = ("tau",)
    order = 5
    lrde_no_term = ("a constant delay shifts the phase of the motion only; A12, a_eq and E_b are "
                    "unaffected")
    test = "tests/test_residual_select.py::test_round_trip_recovers_parameters_within_their_standard_error"

    separated_by = "a range of speeds with dwells and slow reversals"

    def applicable(self, ctx) -> bool:
        return float(np.max(np.abs(ctx.velocity))) > 0

    def bounds(self, ctx):
        vmax = float(np.max(np.abs(ctx.velocity)))
        lim = _span(ctx) / vmax
        return [(-lim, lim)]

    def apply(self, theta, t, velocity, aux, params):
        tau = float(params[0])
        spline = aux.get("_smooth_spline")
        if spline is None:  # no reconstruction available: first order
            return theta - tau * velocity
        # the delayed sample itself, not its first-order expansion: theta(t - tau) - theta(t)
        # on the smooth reconstruction, added to the reading so the truth's own rounding stays
        # the exact model's (the curvature term tau^2 a / 2 of a 1.7 ms delay on a 1 Hz swing is
        # 5 % of a 4096-cpr step: a first-order model left it to a spurious timestamp jitter)
        return theta + (spline(t - tau) - aux["_smooth"])


class TimestampJitter(Effect):
    """Timestamp jitter of standard deviation ``sigma_t >= 0`` (s).

    A sample stamped at ``t`` was taken at ``t + N(0, sigma_t^2)``: the angle gets a jitter
    ``sigma_t |v|``. Signature: residual variance growing with ``v^2`` and zero mean. The null
    ``sigma_t = 0`` is on the boundary of the range (mixture null, see :class:`Effect`).
    """

    name = "timestamp_jitter"
    param_names = ("sigma_t",)
    kind = "noise"
    order = 26
    boundary = ("sigma_t",)
    counterpart, counterpart_param = "time_jitter", "sigma_t"
    test = "tests/test_residual_select.py::test_timestamp_jitter_is_found_with_its_value"

    separated_by = "a range of speeds"

    def applicable(self, ctx) -> bool:
        return float(np.max(np.abs(ctx.velocity))) > 0

    def bounds(self, ctx):
        vmax = float(np.max(np.abs(ctx.velocity)))
        return [(0.0, _span(ctx) / vmax)]

    def noise_std(self, theta, t, velocity, aux, params):
        return abs(params[0]) * np.abs(velocity)

    def signature(self, theta, t, velocity, aux, ctx):
        return np.zeros((np.size(theta), 1))


class ScaleMismatch(Effect):
    """Scale (counts-per-rev or gear-ratio) mismatch ``g`` (dimensionless).

    ``theta_eff = theta + g (theta - theta_ref)`` with ``theta_ref`` the mean truth angle, so
    that ``g`` does not trade off against the quantizer offset. Signature: residual a ramp
    in the angle.
    """

    name = "scale_mismatch"
    param_names = ("g",)
    order = 21
    angle_map = True
    lrde_no_term = ("a scale error of the reading rescales the stroke; the fit reports the "
                    "stroke as read")
    test = "tests/test_residual_select.py::test_round_trip_recovers_parameters_within_their_standard_error"

    separated_by = _FULL_TURN

    def caveat(self, ctx):
        stroke = _stroke_below_a_turn(ctx)
        if stroke is None:
            return None
        return (f"over a stroke of {stroke:.2g} rad the scale is the mean slope of the angle error there: "
                "a once-per-turn error adds its local slope (a motion over a full turn separates them)")

    def applicable(self, ctx) -> bool:
        return float(np.ptp(ctx.truth)) > 4.0 * ctx.step

    def bounds(self, ctx):
        lim = _span(ctx) / max(float(np.ptp(ctx.truth)), ctx.step)
        return [(-lim, lim)]

    def apply(self, theta, t, velocity, aux, params):
        return theta + params[0] * (theta - aux["_theta_ref"])


class Compliance(Effect):
    """Compliance against a logged torque: ``theta_eff = theta + kappa (torque - mean)``.

    ``kappa`` in rad per torque unit. Applicable only with ``aux["torque"]``. Signature:
    residual proportional to the torque.
    """

    name = "compliance"
    additive = True
    param_names = ("kappa",)
    order = 12
    lrde_no_term = ("a torque-dependent lag between the motion and the encoder; it distorts "
                    "the motion the encoder sees, as a motion harmonic would")
    test = "tests/test_residual_pipeline.py::test_compliance_against_an_aux_torque_channel"

    separated_by = "the same angles and speeds at different loads"

    def applicable(self, ctx) -> bool:
        tq = ctx.aux.get("torque") if ctx.aux else None
        return tq is not None and float(np.ptp(tq)) > 0

    def bounds(self, ctx):
        lim = _span(ctx) / float(np.ptp(ctx.aux["torque"]))
        return [(-lim, lim)]

    def apply(self, theta, t, velocity, aux, params):
        tq = aux["torque"]
        return theta + params[0] * (tq - aux["_torque_ref"])


class SofteningCompliance(Effect):
    """Nonlinear compliance against a logged torque: ``theta_eff = theta + k1 T + k2 T|T|``.

    ``T`` is ``aux["torque"]`` (each column centred on its mean over the log, which the
    quantizer offset absorbs); ``k1`` in rad per torque unit, ``k2`` in rad per torque unit
    squared (the terms of :data:`enclab.residuals.calibration.TERMS`, as in a rig fit). A gear
    whose play is taken up gradually softens: the twist grows less than linearly with the load,
    ``k2`` of sign opposite to ``k1``. Signature: a residual that follows the torque, the same at
    every angle, with a slope that changes with ``|T|`` (a straight line against ``T`` is the
    linear :class:`Compliance`, which this effect contains). Both nulls are interior
    (regular chi2_2). Derived: ``twist_at_max_torque`` (rad at the largest ``|T|`` of the log, on
    the side of the larger twist) and ``softening``, the fraction of the linear twist that the
    ``T|T|`` term takes away there (``-k2 Tmax / k1``; positive when the compliance softens).
    """

    name = "compliance_softening"
    additive = True
    param_names = ("k1", "k2")
    order = 12
    test = "tests/test_residual_select.py::test_softening_compliance_is_found_with_its_values"

    separated_by = "a wider range of torques at the same angles and speeds"

    def applicable(self, ctx) -> bool:
        tq = ctx.aux.get("torque") if ctx.aux else None
        if tq is None or float(np.ptp(tq)) <= 0:
            return False
        self.t_max = float(np.max(np.abs(tq)))
        return True

    def bounds(self, ctx):
        tq = ctx.aux["torque"]
        lim = _span(ctx)
        return [(-lim / float(np.ptp(tq)), lim / float(np.ptp(tq))),
                (-lim / float(np.ptp(TERMS["signed_square"](tq))), lim / float(np.ptp(TERMS["signed_square"](tq))))]

    def _columns(self, aux):
        tq = aux["torque"]
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] is not tq:
            lin, sq = TERMS["linear"](tq), TERMS["signed_square"](tq)
            self._cache = (tq, lin - lin.mean(), sq - sq.mean())
        return self._cache[1], self._cache[2]

    def columns(self, aux):
        """``d theta_eff / d (k1, k2)``: the centred ``T`` and ``T|T|``."""
        return self._columns(aux)

    def apply(self, theta, t, velocity, aux, params):
        lin, sq = self._columns(aux)
        return theta + params[0] * lin + params[1] * sq

    def derived(self, params):
        k1, k2 = params["k1"], params["k2"]
        tmax = getattr(self, "t_max", float("nan"))
        twist = max(abs(k1 * tmax + k2 * tmax * tmax), abs(-k1 * tmax - k2 * tmax * tmax))
        return {"twist_at_max_torque": twist,
                "softening": -k2 * tmax / k1 if k1 != 0 else float("nan")}


class InertialTwist(Effect):
    """Twist of a compliant shaft that accelerates an inertia: ``theta_eff = theta - c (a - mean a)``.

    A shaft or coupling of stiffness ``k`` between the truth and the measured side, driving an
    inertia ``J`` on one of them, twists by ``J a / k`` under the angular acceleration ``a``
    (rad/s^2): ``c = J / k`` (s^2), signed (positive when the measured side is the driven
    inertia and lags while it is accelerated, negative when it drives). It is the compliance
    of :class:`Compliance` with the torque the inertia's own, for a log without a torque
    column. ``a`` is the time derivative of the truth's smoothed velocity, centred on its mean
    over the log (the quantizer offset holds a constant). Signature: the residual ``measured -
    truth`` follows the acceleration, largest where the motion turns and zero where it passes
    at constant speed (a latency's residual follows the speed instead). Interior null (regular
    chi2_1). The smoothed velocity's derivative is off by a few percent of the acceleration
    where the motion turns fastest, so a twist of several steps is read to within a few
    hundredths of a step, not to the exact-model floor.

    On a pure sinusoid about its mean the acceleration is ``-omega^2`` times the angle, so the
    twist is a scale error there (:class:`ScaleMismatch`): the effect is off by ``default``
    and tried only when named in ``candidates``.
    """

    name = "inertial_twist"
    additive = True
    param_names = ("c",)
    order = 13
    default = False
    lrde_no_term = ("a twist that follows the acceleration; on a sinusoid it is a fixed fraction "
                    "of the motion, so it rescales the stroke the encoder sees, which the fit "
                    "reports as read")
    test = "tests/test_residual_inertial_twist.py::test_inertial_twist_is_found_on_a_brute_force_simulated_log"

    separated_by = "a motion that is not one sinusoid (its acceleration then is no multiple of its angle)"

    @staticmethod
    def _acceleration(t, velocity):
        # the time derivative of the selection's smoothed velocity: the second derivative of
        # the cubic spline through every sample follows the truth's residual rounding instead
        # (it read a two-tone motion's twist at half its size)
        return np.gradient(np.asarray(velocity, dtype=float), t)

    def applicable(self, ctx) -> bool:
        return ctx.t.size > 2 and float(np.ptp(self._acceleration(ctx.t, ctx.velocity))) > 0

    def bounds(self, ctx):
        lim = _span(ctx) / float(np.ptp(self._acceleration(ctx.t, ctx.velocity)))
        return [(-lim, lim)]

    def _column(self, t, velocity):
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] is not velocity:
            acc = self._acceleration(t, velocity)
            self._cache = (velocity, acc - acc.mean())
        return self._cache[1]

    def apply(self, theta, t, velocity, aux, params):
        return theta - params[0] * self._column(t, velocity)


class CalibrationMap(Effect):
    """Smooth calibration map of the measured-side angle: ``theta_eff = theta + m(theta)``.

    ``m`` is a cubic spline over the log's stroke with knots every ``spacing`` rad, its constant
    and linear parts removed (:class:`enclab.residuals.calibration.MapBasis`: the constant is the
    quantizer offset, the slope a :class:`ScaleMismatch`); coefficients ``m1 ... mK`` in rad
    (columns of unit rms over the stroke). The spacing is chosen on held-out data each time the
    effect is tried (:meth:`prepare`; not tried when no spacing beats a constant and a slope
    there): the exact-model residual of the current model is fitted by
    least squares on every other of 40 time blocks for each candidate spacing (the stroke over
    3 to 24 equal intervals, none below ``min_spacing``) and scored on the blocks in
    between, both ways; the spacing with the smallest held-out error is taken. The map is
    evaluated on the smooth reconstruction of the angle (``aux["_smooth"]``), so its design is
    computed once per log. Signature: a residual that is the same smooth function of the angle
    on every pass and in both directions, with bends no slope or once-per-turn harmonic makes
    (a read head's calibration error, a disc's local pitch error). Derived: ``peak_to_peak``
    (rad, of the map over the stroke), ``spacing`` (rad) and ``n_intervals``.
    """

    name = "calibration_map"
    additive = True
    order = 22
    angle_map = True
    divisions = tuple(range(3, 25))
    min_spacing = 0.02
    min_stroke = 0.2
    #: blocks dealt alternately to the two halves of the spacing choice, and per held-out fold
    #: of the selection's confirmation: a random path visits one part of the stroke in one
    #: second and another in the next, and a spline fitted on blocks that missed a part is
    #: free there (contiguous folds scored such maps 1e5 nats worse than none)
    n_blocks = 40
    heldout_interleave = 10
    test = "tests/test_residual_select.py::test_calibration_map_is_found_and_matches_the_true_map"

    separated_by = _FULL_TURN

    def __init__(self):
        self.param_names = ()
        self.basis = None

    def caveat(self, ctx):
        return ("the map is the angle error over this stroke with its constant and slope removed (the slope "
                "is a scale mismatch); it says nothing outside the stroke")

    def applicable(self, ctx) -> bool:
        stroke = float(np.ptp(ctx.truth))
        return stroke >= self.min_stroke and stroke >= 40.0 * ctx.step

    def _set_basis(self, lo, hi, spacing):
        self.basis = MapBasis(lo, hi, spacing, n_grid=801)
        self.param_names = tuple(f"m{j + 1}" for j in range(self.basis.n_columns))
        self._cache = None

    def candidate_spacings(self, ctx) -> list:
        stroke = float(np.ptp(ctx.truth))
        return sorted({stroke / n for n in self.divisions if stroke / n >= self.min_spacing}, reverse=True)

    def prepare(self, ctx, resid) -> bool:
        """Choose the knot spacing on held-out blocks of ``resid`` (rad, the exact-model residual
        of the current model, whose mean over a stretch of angle is the unmodelled shift there)
        and set the basis and parameter names.

        Returns False (the map is not tried) when no spacing predicts the held-out blocks better
        than a constant and a slope. The likelihood counts every sample as independent: where a
        dwell left tens of samples on the wrong side of one transition (one truth reading, one
        rounding error), a flexible map could bend by a fraction of a truth step there and gain
        more than its parameters cost. Such a bend predicts nothing on the other blocks.
        """
        lo, hi = float(np.min(ctx.truth)), float(np.max(ctx.truth))
        idx = ctx.fit_idx
        a = (ctx.priv["_smooth"] if "_smooth" in ctx.priv else ctx.truth)[idx]
        y = np.asarray(resid, dtype=float)[idx]
        blocks = run_blocks(ctx.truth[idx], self.n_blocks)
        even = np.concatenate(blocks[0::2])
        odd = np.concatenate(blocks[1::2])

        def heldout_error(D):
            err = 0.0
            for fit, test in ((even, odd), (odd, even)):
                coef, *_ = np.linalg.lstsq(D[fit], y[fit], rcond=None)
                err += float(np.sum((y[test] - D[test] @ coef) ** 2))
            return err

        line = np.column_stack([np.ones(a.size), a])
        best = (heldout_error(line), None)
        for spacing in self.candidate_spacings(ctx):
            err = heldout_error(np.column_stack([line, MapBasis(lo, hi, spacing, n_grid=801).design(a)]))
            if err < best[0]:
                best = (err, spacing)
        if best[1] is None:
            return False
        self._set_basis(lo, hi, best[1])
        return True

    def _design(self, aux):
        a = aux["_smooth"]
        cached = getattr(self, "_cache", None)
        if cached is None or cached[0] is not a:
            self._cache = (a, self.basis.design(a))
        return self._cache[1]

    def bounds(self, ctx):
        lim = _span(ctx)
        return [(-lim, lim)] * len(self.param_names)

    def columns(self, aux):
        """``d theta_eff / d m_j``: the map's columns at the smooth angle."""
        return self._design(aux).T

    def apply(self, theta, t, velocity, aux, params):
        return theta + self._design(aux) @ np.asarray(params, dtype=float)

    def curve(self, params, a) -> np.ndarray:
        """The map ``m(a)`` (rad) at angles ``a`` for coefficients ``params`` (array or dict)."""
        if isinstance(params, dict):
            params = [params[k] for k in self.param_names]
        return self.basis.curve(params, a)

    def derived(self, params):
        grid = np.linspace(self.basis.lo, self.basis.hi, 401)
        return {"peak_to_peak": float(np.ptp(self.curve(params, grid))), "spacing": float(self.basis.spacing),
                "n_intervals": float(len(self.basis.knots) - 7)}


class SlowDrift(Effect):
    """Slow drift of the measured reading in time (thermal growth, creep, a drifting zero).

    ``theta_eff = theta + c1 P1(s) + c2 P2(s) + c3 P3(s)`` with ``P_k`` the Legendre
    polynomials of the normalised time ``s = 2 (t - t_mid) / T`` in ``[-1, 1]`` (``T`` the
    log's duration; ``P0`` is the quantizer offset). Coefficients in rad; a linear drift of
    ``rate`` rad/s is ``c1 = rate T / 2``. Derived: ``mean_rate`` (rad/s, end minus start over
    ``T``) and ``peak_to_peak`` (rad). Signature: the residual ``measured - truth`` wanders
    smoothly with time, the same at every angle and speed: a *ramp*, where missed counts give
    *steps* of whole counts (a 0.2 mrad/s drift read by a 1.5 mrad step is a staircase of
    "missed counts" every 7.7 s, each step off by up to half a count on both sides).
    """

    name = "slow_drift"
    additive = True
    order = 25
    lrde_no_term = ("a slow drift of the reading moves a_eq over the log; the model's a_eq is "
                    "constant, so its a_eq and E_b hold only as averages over the log")
    lrde_biases = ("a_eq", "E_b", "offset_a")  # a_eq is constant in the model
    test = "tests/test_residual_loop.py::test_a_slow_drift_is_a_drift_not_a_staircase_of_missed_counts"

    separated_by = "passes over the same angles spread over the whole log"

    def __init__(self, degree: int = 3):
        if degree not in (1, 2, 3):
            raise ValueError(f"SlowDrift degree must be 1, 2 or 3, got {degree!r}")
        self.degree = degree
        self.param_names = ("c1", "c2", "c3")[:degree]
        self.form = {1: "linear", 2: "quadratic", 3: None}[degree]

    def reduced(self):
        """The linear drift alone (``c1``)."""
        return SlowDrift(degree=1) if self.degree > 1 else None

    def applicable(self, ctx) -> bool:
        self.duration = float(ctx.t[-1] - ctx.t[0])
        return self.duration > 0

    def _basis(self, t, aux):
        t0, t1 = aux["_t_range"]
        s = (2.0 * np.asarray(t, dtype=float) - (t0 + t1)) / (t1 - t0)
        return (s, 0.5 * (3.0 * s * s - 1.0), 0.5 * (5.0 * s**3 - 3.0 * s))[:self.degree]

    def apply(self, theta, t, velocity, aux, params):
        out = theta
        for c, basis in zip(params, self._basis(t, aux)):
            out = out + c * basis
        return out

    def derived(self, params):
        c1, c2, c3 = (params.get(k, 0.0) for k in ("c1", "c2", "c3"))
        s = np.linspace(-1.0, 1.0, 401)
        curve = c1 * s + c2 * 0.5 * (3 * s * s - 1) + c3 * 0.5 * (5 * s**3 - 3 * s)
        out = {"peak_to_peak": float(np.ptp(curve))}
        duration = getattr(self, "duration", float("nan"))
        out["mean_rate"] = 2.0 * (c1 + c3) / duration if duration > 0 else float("nan")
        return out


def long_run_inflation(e, n_blocks: int = 40) -> float:
    """Ratio (>= 1) of the long-run variance of the series ``e`` to its per-sample variance.

    Batch means: the variance of the sums over ``n_blocks`` contiguous blocks, divided by the
    block length, against the per-sample variance. A white series gives about 1; a series
    correlated over ``m`` samples about ``m`` (capped by the block length)."""
    e = np.asarray(e, dtype=float)
    e = e - e.mean()
    n_blocks = min(n_blocks, e.size // 2)
    per_sample = float(np.mean(e * e))
    if n_blocks < 2 or per_sample <= 0.0:
        return 1.0
    length = e.size // n_blocks
    sums = e[:n_blocks * length].reshape(n_blocks, length).sum(axis=1)
    return max(1.0, float(np.mean(sums * sums)) / length / per_sample)


class LevelShift(Effect):
    """A change of the reading's offset by ``d`` (rad, any size, not a whole number of steps).

    A torque reversal that takes up a preload, a coupling that slips: the measured side reads
    ``d`` more from some moment on. Two forms, chosen on the log by :meth:`prepare`:

    ``time``
        one shift at an unknown time ``t_shift``: ``theta_eff = theta + d [t >= t_shift]``; the
        time is the split of the current exact-model residual into two levels with the smallest
        sum of squares (at least ``min_fraction`` of the log on either side);
    ``sign changes``
        when a torque or command column is declared (``aux`` key in :attr:`drivers`), a shift at
        each of its sign changes: ``theta_eff = theta + (d / 2) (s - mean s)`` with ``s`` the
        sign of the column, held through a dead zone of 5 % of its largest magnitude (a torque
        that chatters about zero does not toggle the preload). With one reversal in the log it
        is the ``time`` form at the reversal; it is taken when it reads the residual within the
        cost of one parameter (``ln N`` in the sum of squares over the noise variance) of the
        best free time.

    ``d`` is the only continuous parameter. The free time is a searched parameter: the search
    declines (the effect is not tried) unless its split gains more than that parameter's BIC
    cost, ``ln N`` noise variances, over no shift, and when the best split lies on the edge of
    the searched range (a transient at the log's start or end). A shift within 0.1 step of a non-zero whole
    number of steps on a channel without sensor noise is a missed count
    (:class:`MissedCounts`), not a level shift. Derived: ``t_shift`` (s, the time, or the first
    sign change), ``t_lo``, ``t_hi`` (the times whose split is within the 90 % chi2_1 profile
    of the best, the profile scaled by the residual's long-run variance
    (:func:`long_run_inflation`), so a residual correlated in time widens the interval),
    ``at_sign_changes`` (1 for the second form) and ``n_shifts``. Signature: the residual
    ``measured - truth`` steps by ``d`` at one moment (or at every reversal of the torque) and
    keeps its level, at every angle and speed.
    """

    name = "level_shift"
    additive = True
    param_names = ("d",)
    order = 24
    drivers = ("torque", "command", "current")
    min_fraction = 0.05
    lrde_no_term = ("a change of the reading's offset during the log; the model's a_eq is "
                    "constant, so its a_eq and E_b hold only as averages over the log")
    lrde_biases = ("a_eq", "E_b", "offset_a")  # a_eq is constant in the model
    test = "tests/test_residual_effects.py::test_level_shift_selected_on_a_brute_force_simulated_log"

    separated_by = "passes over the same angles before and after the shift"

    def __init__(self):
        self.t_shift = None
        self.driver = None
        self.interval = (float("nan"), float("nan"))
        self.n_shifts = 0

    def applicable(self, ctx) -> bool:
        return ctx.t.size >= 4.0 / self.min_fraction

    @classmethod
    def driver_sign(cls, x) -> np.ndarray:
        """Sign of a torque or command column held through a dead zone of 5 % of its peak."""
        x = np.asarray(x, dtype=float)
        eps = 0.05 * float(np.max(np.abs(x))) if x.size else 0.0
        s = motion_sign(np.where(np.abs(x) > eps, x, 0.0))
        first = np.flatnonzero(s)
        if first.size:  # before the column first leaves the dead zone: the sign it leaves with
            s[:first[0]] = s[first[0]]
        return s

    def _driver(self, ctx):
        for key in self.drivers:
            if ctx.aux and ctx.aux.get(key) is not None:
                s = self.driver_sign(ctx.aux[key])
                if np.any(s[1:] != s[:-1]) and np.all(s != 0):
                    return key, s
        return None, None

    def prepare(self, ctx, resid) -> bool:
        """Find the time (or take the sign changes) from ``resid`` (rad, the exact-model residual
        of the current model); False when no split earns its cost or it is a missed count."""
        idx = ctx.fit_idx
        y = np.asarray(resid, dtype=float)[idx]
        t = ctx.t[idx]
        n = y.size
        y = y - y.mean()
        ss0 = float(np.sum(y * y))
        m = max(int(self.min_fraction * n), 2)
        cs = np.cumsum(y)[:-1]
        i = np.arange(1, n)
        # sum of squares removed by two levels split before sample i
        gain = cs * cs * n / (i * (n - i))
        gain[:m - 1] = -np.inf
        gain[n - m:] = -np.inf
        k = int(np.argmax(gain))
        if not np.isfinite(gain[k]) or k in (m - 1, n - m - 1):
            # a best split on the edge of the searched range would sit nearer the log's start or
            # end: a transient there (a motion that starts late, a settling sensor), no shift
            return False
        sse = ss0 - float(gain[k])
        var = max(sse / max(n - 2, 1), 1e-300)
        if gain[k] / var <= math.log(n):
            return False
        split = k + 1
        d = float(np.mean(y[split:]) - np.mean(y[:split]))
        sensor = float(ctx.priv.get("_sensor_var", 0.0)) > (0.25 * ctx.step) ** 2
        whole = round(d / ctx.step)
        if not sensor and whole != 0 and abs(d / ctx.step - whole) < 0.1:
            return False
        # the residual of a slow motion is correlated in time: the profile's width is measured
        # in the long-run variance of the two-level residual, not in its per-sample variance
        two_levels = np.where(np.arange(n) < split, np.mean(y[:split]), np.mean(y[split:]))
        ok = np.flatnonzero(gain >= gain[k] - 2.706 * var * long_run_inflation(y - two_levels)) + 1
        self.t_shift = 0.5 * float(t[split - 1] + t[split])
        self.interval = (float(t[ok.min() - 1]), float(t[ok.max()]))
        self.driver, self.n_shifts = None, 1
        key, s = self._driver(ctx)
        if key is not None:
            z = s[idx] - s[idx].mean()
            zz = float(np.dot(z, z))
            sse_sign = ss0 - float(np.dot(z, y)) ** 2 / zz if zz > 0 else ss0
            if (sse_sign - sse) / var < math.log(n):
                changes = np.flatnonzero(s[1:] != s[:-1]) + 1
                self.driver, self.n_shifts = key, int(changes.size)
                self.t_shift = float(ctx.t[changes[0]])
                self.interval = (float(ctx.t[changes[0] - 1]), float(ctx.t[changes[0]]))
        return True

    def column(self, t, aux) -> np.ndarray:
        """``d theta_eff / d d``: the step at ``t_shift`` or the half sign of the driver."""
        if self.driver is not None:
            s = self.driver_sign(aux[self.driver])
            return 0.5 * (s - s.mean())
        return (np.asarray(t, dtype=float) >= self.t_shift).astype(float)

    def apply(self, theta, t, velocity, aux, params):
        if self.t_shift is None:
            return theta
        return theta + float(params[0]) * self.column(t, aux)

    def derived(self, params):
        return {"t_shift": float("nan") if self.t_shift is None else float(self.t_shift),
                "t_lo": self.interval[0], "t_hi": self.interval[1],
                "at_sign_changes": float(self.driver is not None), "n_shifts": float(self.n_shifts)}


class MissedCounts(Effect):
    """Missed (or extra) counts: integer steps of the count at unknown times.

    Parameters ``t_1, n_1, ..., t_K, n_K``: after ``t_j`` the measured count is lower by
    ``n_j`` (an integer). Found by binary segmentation of the count residual (see
    :meth:`detect`); each changepoint costs two parameters in the BIC. Signature: the residual
    jumps by a whole number of steps and stays there.
    """

    name = "missed_counts"
    additive = True
    kind = "discrete"
    order = 60
    counterpart = "count_jump"
    lrde_biases = ("a_eq", "E_b", "offset_a")  # more than the one modelled jump
    test = "tests/test_residual_select.py::test_missed_counts_and_wrap_are_found"

    def __init__(self, times=(), jumps=()):
        self.times = tuple(float(x) for x in times)
        self.jumps = tuple(int(x) for x in jumps)
        self.param_names = tuple(p for j in range(len(self.times)) for p in (f"t_{j + 1}", f"n_{j + 1}"))

    def bounds(self, ctx):
        return []

    @classmethod
    def lrde_finding(cls, params, ci):
        """One step of one count is the low-resolution fit's ``count_jump`` (its time as the
        value, s); several steps, or a larger one, are beyond that term."""
        jumps = [v for k, v in params.items() if k.startswith("n_")]
        if len(jumps) != 1 or abs(round(float(jumps[0]))) != 1:
            return {"why": f"{len(jumps)} count steps found (sizes "
                           f"{', '.join(f'{float(j):+.0f}' for j in jumps)}); the model holds "
                           "one step of one count",
                    "biases": list(cls.lrde_biases)}
        return {"term": cls.counterpart, "value": float(params.get("t_1", float("nan"))),
                "ci": None, "unit": "s (time of the step)"}

    @classmethod
    def propose(cls, ctx, mu):
        resid = ctx.counts - (mu - 0.5)
        # samples farther than the truth's half step (in counts) from a transition of floor(mu)
        half = 0.5 * ctx.truth_step / ctx.step
        informative = np.abs(mu - np.round(mu)) > half
        times, jumps = cls.detect(ctx.t, resid, informative=informative)
        return cls(times, jumps) if times else None

    def found_params(self):
        out = {}
        for j, (tj, nj) in enumerate(zip(self.times, self.jumps)):
            out[f"t_{j + 1}"], out[f"n_{j + 1}"] = tj, float(nj)
        return out

    def apply(self, theta, t, velocity, aux, params=None):
        shift = np.zeros(np.shape(theta))
        for tj, nj in zip(self.times, self.jumps):
            shift = shift + nj * (t >= tj)
        return theta - aux["_step"] * shift

    @staticmethod
    def detect(t, resid_counts, max_changes: int = 6, min_len: int = 20, informative=None):
        """Changepoints of an integer level in ``resid_counts`` (counts).

        The level is the running median over ``2 min_len + 1`` samples rounded to whole
        counts: the isolated one-count flips of the exact model (the truth's own rounding)
        vanish in it, and every step that lasts at least ``min_len`` samples survives however
        close it is to the next (binary segmentation by cumulative sums merged steps a fraction
        of a second apart into one wrong jump, or found none). Returns ``(times, jumps)``; no
        change when there are more than ``max_changes`` (a residual that follows the motion is
        no missed count) or when a segment between changes does not sit on its level (at least
        80 % of its samples within half a count of its median).

        ``informative`` (boolean, optional) marks the samples whose predicted count the
        truth's own rounding cannot flip; a level between two changes must hold ``min_len`` of
        them. During a dwell next to a transition of the measured grid every sample flips
        together (one truth reading, one rounding error), which looks like a missed count and
        its return tens of ms later on a clean log: such a pulse is dropped.
        """
        from scipy.ndimage import median_filter

        r = np.asarray(resid_counts, dtype=float)
        t = np.asarray(t, dtype=float)
        if r.size < 2 * min_len + 1:
            return [], []
        m = median_filter(r, size=2 * min_len + 1, mode="nearest")
        # the levels sit a common fraction of a count off the integers (the offset fitted
        # without the changes lies between levels): round relative to that fraction, the
        # circular mean of the running median's fractional part
        ang = 2.0 * np.pi * m
        frac = math.atan2(float(np.mean(np.sin(ang))), float(np.mean(np.cos(ang)))) / (2.0 * np.pi)
        level = np.round(m - frac)
        idx = np.flatnonzero(np.diff(level) != 0) + 1
        # plateaus: runs of one level at least min_len long; a change is where the next
        # plateau of another level begins
        starts = np.concatenate(([0], idx))
        ends = np.concatenate((idx, [r.size]))
        plateaus = [(a, b, level[a]) for a, b in zip(starts, ends) if b - a >= min_len]
        if not plateaus:
            return [], []
        cps = []
        cur = plateaus[0]
        for p in plateaus[1:]:
            if p[2] != cur[2]:
                cps.append((int(p[0]), int(p[2] - cur[2])))
            cur = p
        if not cps or len(cps) > max_changes:
            return [], []
        # refine each change within the filter's reach: the split that puts the most samples
        # of the window on the level of their side
        rl = np.round(r - frac)
        refined = []
        for cp, jump in cps:
            a, b = max(cp - min_len, 1), min(cp + min_len, r.size - 1)
            lo_lev, hi_lev = level[max(cp - min_len - 1, 0)], level[min(cp + min_len, r.size - 1)]
            win = rl[a - 1:b + 1]
            left = np.cumsum(win == lo_lev)
            right = np.cumsum((win == hi_lev)[::-1])[::-1]
            score = left[:-1] + right[1:]
            refined.append((a + int(np.argmax(score)), jump))
        cps = refined
        if informative is not None:
            # a level held only by samples the truth's rounding can flip is no level: a pulse
            # over such a stretch (a change and its return) is dropped; any other change
            # bounding one means the residual is no staircase of missed counts
            inf = np.asarray(informative, dtype=bool)
            while True:
                edges = [0] + [cp for cp, _ in cps] + [r.size]
                weak = [i for i in range(1, len(edges) - 2) if inf[edges[i]:edges[i + 1]].sum() < min_len]
                if not weak:
                    break
                i = weak[0]
                if cps[i - 1][1] + cps[i][1] != 0:
                    return [], []
                del cps[i - 1:i + 1]
            if not cps:
                return [], []
        bounds = [0] + [cp for cp, _ in cps] + [r.size]
        for a, b in zip(bounds[:-1], bounds[1:]):
            seg = r[a:b]
            if np.mean(np.abs(seg - np.median(seg)) <= 0.5) < 0.8:
                return [], []
        times = [float(t[cp]) for cp, _ in cps]
        jumps = [-j for _, j in cps]  # measured lower by n after t: residual drops by n
        return times, jumps


class WrapAround(Effect):
    """Counter or angle wrap-around with period ``P`` (rad): modular jumps of the measured channel.

    ``theta_eff = theta - P round((theta/step + c - k) step / P)``: the model is compared with
    the counts modulo ``P``. ``P`` is snapped to ``2 pi`` or a counter range ``2**b`` counts
    when the observed jumps are within 1 % of one. Signature: the residual jumps by (nearly)
    a fixed large amount ``P`` and back.
    """

    name = "wrap_around"
    param_names = ("period",)
    kind = "discrete"
    order = 70
    reads_counts = True
    lrde_no_term = "a counter wrap; not expected on a stroke of a few steps"
    test = "tests/test_residual_select.py::test_missed_counts_and_wrap_are_found"

    def __init__(self, period: float | None = None):
        self.period = period

    def bounds(self, ctx):
        return []

    @classmethod
    def propose(cls, ctx, mu):
        period = cls.detect(ctx.truth, ctx.grid + ctx.step * ctx.counts, ctx.step)
        return cls(period) if period else None

    def found_params(self):
        return {"period": float(self.period)}

    def apply(self, theta, t, velocity, aux, params=None):
        step = aux["_step"]
        mu = theta / step + aux["_offset"]
        n = np.round((mu - aux["_counts"]) * step / self.period)
        return theta - self.period * n

    @staticmethod
    def detect(truth, measured, step: float):
        """Period from the jumps of ``measured`` that ``truth`` does not make, or None.

        A jump is a sample-to-sample change of ``measured - truth`` larger than 16 steps; the
        period is the median size of the jumps, snapped to ``2 pi`` or ``2**b`` steps within 1 %.
        """
        d = np.abs(np.diff(np.asarray(measured, float) - np.asarray(truth, float)))
        big = d[d > 16.0 * step]
        if big.size == 0:
            return None
        est = float(np.median(big))
        for cand in [2.0 * np.pi] + [step * 2.0**b for b in range(4, 33)]:
            if abs(est - cand) <= 0.01 * cand:
                return cand
        return round(est / step) * step


#: Candidate effects in the order the selection tries them (discrete ones last).
EFFECTS = (
    Hysteresis,
    Backlash,
    Compliance,
    SofteningCompliance,
    InertialTwist,
    ScaleMismatch,
    AngleHarmonics,
    HarmonicMap,
    CalibrationMap,
    Latency,
    TimestampJitter,
    SlowDrift,
    LevelShift,
    LinePitchHarmonics,
    QuadratureEdges,
    MissedCounts,
    WrapAround,
)

#: Every effect class by name: the candidates and the exact model's truth quantization.
REGISTRY = {cls.name: cls for cls in EFFECTS + (TruthQuantization,)}
