"""Shared terms of a rig: a smooth calibration map of an angle and a nonlinear compliance.

Both are *linear* in their coefficients, so a rig fit (:mod:`enclab.rig.fit`) stacks
their columns over many runs and solves one least-squares problem.

**Calibration map** (:class:`MapBasis`). A repeatable error of the measured side that depends on
its own angle ``a``: ``reading = a + s (a - a_mid) + m(a)``. ``m`` is a cubic spline with knots
every ``spacing`` rad over ``[lo, hi]``, with its constant and linear parts removed (on a uniform
grid over ``[lo, hi]`` or a reference range inside it): the constant is a counter's zero (fitted per run), the linear part is
the scale ``s`` (a counts-per-rev or gear-ratio mismatch), reported on its own. What is left,
``m``, is the shape no scale or offset can make: the curve a lab applies as a calibration.
*Signature* when present and not modelled: a residual that is the same function of the angle in
every run and both directions of motion, and is not periodic in the other side's angle.

**Nonlinear compliance** (:func:`compliance_columns`). The twist between the two sides of a
transmission against logged torques: ``k1 T + k2 T|T|`` for a torque ``T`` (a spring that
softens or stiffens with load: play taken up gradually shows as ``k2`` of sign opposite to
``k1``), and a linear term per further torque channel. *Signature*: a residual that follows the
torque, the same at every angle.

**Play take-up** (term ``saturating``): ``k tanh(T / T0)``, a twist that grows fast at small
torque and stops growing once the play is taken up (``T0``: the torque over which that happens,
a setting chosen on held-out runs). A play operator puts the output on the side of its last
motion; when the torque that loads the gear is near zero during a stroke (a load that nearly
balances the friction), the gear floats inside its play instead. A polynomial ``k1 T + k2 T|T|``
bends the wrong way outside the torques it was fitted on; ``tanh`` is bounded, so a fit on low
loads extrapolates to high loads as a constant. *Signature*: a residual inside the steady strokes
of magnitude up to half the play, where the torque is small, largest at the load that balances
the friction.

**Torque map** (a :class:`MapBasis` on a torque, ``extrapolate="linear"``; built by
:func:`enclab.rig.fit.torque_map_basis`): the take-up curve of the transmission as a
spline of the torque it carries, beside the ``linear`` term. A gear with backlash rests on the
side its torque pushes it to: where the torque stays near zero during a stroke (a load that
nearly balances the friction) the output floats partway across the play, a twist that a play
operator (a function of the travel since a reversal) does not give. Every run crosses zero
torque at its reversals, so runs at low loads carry the curve near zero that runs at high
loads need inside their strokes. Beyond the range it is fitted on it continues along its end
slopes (the stiffness once the play is taken up). *Signature*: at a load whose torque stays
near zero into a stroke, a residual of up to half the play that decays as the torque grows,
the same function of the torque in every run.

Every function is pure: arrays in, arrays out.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import BSpline

__all__ = ["MapBasis", "TERMS", "SCALED_TERMS", "compliance_columns", "compliance_names", "compliance_curve"]

#: Torque terms of the compliance: name -> function of the torque (N m) giving a column.
TERMS = {
    "linear": lambda T: T,
    "signed_square": lambda T: T * np.abs(T),
}
#: Terms with a torque scale ``T0`` (N m): name -> function of ``(T, T0)``.
SCALED_TERMS = {
    "saturating": lambda T, T0: np.tanh(T / T0),
}


@dataclass(frozen=True)
class MapBasis:
    """Cubic B-spline basis on ``[lo, hi]`` with knots every ``spacing`` (rad), constant and
    linear parts removed.

    The B-splines of one knot vector reproduce every linear function, so removing the span of
    ``{1, a}`` leaves ``n_basis - 2`` directions: the columns of :meth:`design` are those
    directions (orthonormal on the grid), full rank on data that cover the range. Outside
    ``[lo, hi]`` the argument is clamped to the range (the map is held at its end values).

    Parameters
    ----------
    lo, hi : float
        Range of the angle (rad), ``lo < hi``.
    spacing : float
        Knot spacing (rad); the interior knots divide ``[lo, hi]`` into
        ``ceil((hi - lo) / spacing)`` equal intervals.
    n_grid : int
        Points of the uniform grid on which the constant and linear parts are removed.
    ref : tuple of float or None
        ``(lo, hi)`` of that grid (default the whole range). The ends of a stroke are where a
        motion reverses and where the data say least about the map; the scale is better
        defined as the slope over the well-covered middle.
    extrapolate : {"hold", "linear", "flat"}
        Beyond ``[lo, hi]``: the map held at its end values (``"hold"``: an angle map), or
        continued along its end slopes (``"linear"``: a torque map, whose slope at the end of
        the range is a stiffness that holds beyond it, while the linear part removed on the
        grid is only the mean slope over the range), or (``"flat"``: a bounded take-up) splines
        whose slope is zero at both ends, only their constant removed, held at their end values
        beyond the range: beside a linear term, the curve's slope at both ends and beyond is
        that term's, one stiffness, and the map is the take-up between, bounded.
    """

    lo: float
    hi: float
    spacing: float
    n_grid: int = 2001
    ref: tuple | None = None
    extrapolate: str = "hold"

    def __post_init__(self):
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.hi > self.lo):
            raise ValueError(f"map range must satisfy lo < hi, got lo={self.lo!r}, hi={self.hi!r}")
        if self.ref is not None and not (self.lo <= self.ref[0] < self.ref[1] <= self.hi):
            raise ValueError(f"map reference range {self.ref!r} must lie inside [{self.lo!r}, {self.hi!r}]")
        if not (np.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"knot spacing must be positive, got spacing={self.spacing!r}")
        if self.extrapolate not in ("hold", "linear", "flat"):
            raise ValueError(f"map extrapolation {self.extrapolate!r}: expected 'hold', 'linear' or 'flat'")

    @property
    def knots(self) -> np.ndarray:
        n_int = max(int(np.ceil((self.hi - self.lo) / self.spacing - 1e-9)), 1)
        inner = np.linspace(self.lo, self.hi, n_int + 1)
        return np.concatenate(([self.lo] * 3, inner, [self.hi] * 3))

    def _raw(self, a) -> np.ndarray:
        a = np.clip(np.asarray(a, dtype=np.float64), self.lo, self.hi)
        B = BSpline.design_matrix(a, self.knots, 3).toarray()
        if self.extrapolate == "flat":
            # A clamped cubic's end slope is proportional to c1 - c0 (c[-1] - c[-2] at the other
            # end): equal coefficients there, zero slope.
            B = np.column_stack([B[:, 0] + B[:, 1], B[:, 2:-2], B[:, -2] + B[:, -1]])
        return B

    def _removed(self, a) -> np.ndarray:
        """The parts removed: the constant, and the slope unless the ends are flat."""
        a = np.asarray(a, dtype=np.float64)
        if self.extrapolate == "flat":
            return np.ones((a.size, 1))
        return np.column_stack([np.ones_like(a), a])

    @cached_property
    def _projection(self):
        ref = np.linspace(*(self.ref or (self.lo, self.hi)), self.n_grid)
        coef, *_ = np.linalg.lstsq(self._removed(ref), self._raw(ref), rcond=None)
        # Directions on the whole range: a B-spline outside the reference range is still a shape.
        grid = np.linspace(self.lo, self.hi, self.n_grid)
        resid = self._raw(grid) - self._removed(grid) @ coef
        _, sv, vt = np.linalg.svd(resid, full_matrices=False)
        keep = sv > sv[0] * 1e-9
        # Columns scaled to unit rms on the grid: coefficients are then in rad.
        rot = vt[keep].T / sv[keep] * np.sqrt(self.n_grid)
        return coef, rot

    @property
    def n_columns(self) -> int:
        return self._projection[1].shape[1]

    def design(self, a) -> np.ndarray:
        """Columns of the map at angles ``a``: shape ``(len(a), n_columns)``."""
        a = np.asarray(a, dtype=np.float64)
        if a.ndim == 1 and a.size > 64:
            # A quantized angle or torque takes few distinct values: evaluate on those (the
            # same rows, gathered), not once per sample.
            u, inv = np.unique(a, return_inverse=True)
            if 2 * u.size < a.size:
                return self._design(u)[inv]
        return self._design(a)

    def _design(self, a) -> np.ndarray:
        coef, rot = self._projection
        ac = np.clip(a, self.lo, self.hi)
        raw = self._raw(ac)
        if self.extrapolate == "linear":
            # B-splines of a clamped knot vector: the end slopes are those of the end pieces
            h = 1e-6 * (self.hi - self.lo)
            d_lo = (self._raw([self.lo + h]) - self._raw([self.lo])) / h
            d_hi = (self._raw([self.hi]) - self._raw([self.hi - h])) / h
            raw = raw + np.minimum(a - self.lo, 0.0)[:, None] * d_lo + np.maximum(a - self.hi, 0.0)[:, None] * d_hi
            ac = a
        return (raw - self._removed(ac) @ coef) @ rot

    def curve(self, coef, a) -> np.ndarray:
        """The map ``m(a)`` for coefficients ``coef`` (rad)."""
        return self.design(a) @ np.asarray(coef, dtype=np.float64)


def compliance_names(spec) -> list[str]:
    """``["torque_back:linear", "torque_back:signed_square", ...]`` of a term spec
    ``{channel: [term, ...]}`` (channel order as given)."""
    out = []
    for channel, terms in spec.items():
        for term in terms:
            if term not in TERMS and term not in SCALED_TERMS:
                raise ValueError(f"compliance term {term!r} of channel {channel!r}: expected one of "
                                 f"{sorted(TERMS) + sorted(SCALED_TERMS)}")
            out.append(f"{channel}:{term}")
    return out


def _term(channel, term, T, scales):
    if term in SCALED_TERMS:
        T0 = (scales or {}).get(channel)
        if T0 is None or not (np.isfinite(T0) and T0 > 0):
            raise ValueError(f"compliance term {term!r} of channel {channel!r} needs a positive torque "
                             f"scale, got {T0!r}")
        return SCALED_TERMS[term](T, float(T0))
    return TERMS[term](T)


def compliance_columns(spec, torques, scales=None) -> np.ndarray:
    """Columns of the compliance for a term spec ``{channel: [term, ...]}`` and the logged
    torques ``{channel: array (N m)}``: shape ``(N, n_terms)``. ``scales``: ``{channel: T0}``
    (N m) of the terms that have one (``saturating``)."""
    cols = []
    for name in compliance_names(spec):
        channel, term = name.split(":")
        if channel not in torques:
            raise ValueError(f"compliance needs torque channel {channel!r}; have {sorted(torques)}")
        cols.append(_term(channel, term, np.asarray(torques[channel], dtype=np.float64), scales))
    if not cols:
        return np.zeros((0, 0))
    return np.column_stack(cols)


def compliance_curve(coef, spec, channel, torque, scales=None) -> np.ndarray:
    """Twist (rad) against one torque channel alone: the sum of that channel's terms."""
    names = compliance_names(spec)
    torque = np.asarray(torque, dtype=np.float64)
    out = np.zeros_like(torque)
    for k, name in zip(coef, names):
        ch, term = name.split(":")
        if ch == channel:
            out += k * _term(ch, term, torque, scales)
    return out
