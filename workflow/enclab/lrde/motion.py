"""Motion models of the low-resolution fit: the paper's sinusoid and its periodic extensions.

Every model is a periodic motion in the phase ``phi`` of its fundamental,

``theta(t) - mean = A12_f / 2 sin(phi) + sum_k (c_k cos(k phi) + s_k sin(k phi))``,

and differs from the others only in which orders ``k`` it adds (``harmonics``), how its
coefficients start and how its point fit is refined. The likelihoods
(:mod:`enclab.lrde.fit`, :mod:`enclab.lrde.effects`) and the comparison
(:mod:`enclab.lrde.compare`) take the orders; nothing there depends on which class gave them.

``Sinusoid``
    The paper's motion (eq. 1a), no added order.
``Harmonics``
    A few chosen orders (``harmonic3``: a servo that flattens its turning points, a cam).
    Signature when present and not modelled: the dwells at the turning points are longer or
    shorter than the sinusoid's eq. (4) allows, by the same amount every cycle.
``FourierSeries``
    A motion of free periodic shape: every order ``2 .. K`` (``fourierK``), for a motion
    set by a control loop (paper 002's own setting), whose shape follows the gains, the
    steps and the reference rather than a sine. Its coefficients start at the least-squares
    fit of the readings on the series, and its point fit is a gradient method (L-BFGS-B): with
    ``2 (K - 1)`` extra columns a simplex stops far from the optimum within its budget.
    Signature when present and not modelled: dwell ends early or late at fixed places of the
    cycle, every cycle, at several counts at once (the misfit trace's dwell rows).

Definitions for a motion that is not a sinusoid (paper 002 eq. 2, per cycle): the stroke
``A12 = A1 + A2`` is the distance between the turning points, ``max theta - min theta``
over the cycle, and the bias ``A_{12-b} = b`` the mean of the turning points,
``(max theta + min theta) / 2``; ``E_b = a + b - step/2`` and ``a_eq = a + b`` refer to that
bias. Only these two numbers decide which counts one cycle reads
(``floor((min theta + a) / step)`` to ``floor((max theta + a) / step)``), so Proposition 1
holds for any periodic shape with them; Proposition 2 (the mean reading odd in ``E_b``) needs
the shape to be half-wave symmetric (odd orders only), as the sine is.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

__all__ = ["MotionModel", "Sinusoid", "Harmonics", "FourierSeries", "motion_model",
           "from_harmonics", "drift_phase", "distorted_sinusoid"]


class MotionModel(ABC):
    """A periodic motion model: the orders it adds to the fundamental and how it starts.

    Subclasses set :attr:`harmonics` and :attr:`label`; :meth:`start` and
    :attr:`gradient_point_fit` have defaults (coefficients at 0, the simplex point fit).
    """

    #: Orders ``k >= 2`` added to the fundamental, increasing.
    harmonics: tuple = ()
    #: The point fit runs L-BFGS-B instead of Nelder-Mead (:func:`enclab.lrde.fit.map_fit`).
    gradient_point_fit: bool = False

    @property
    @abstractmethod
    def label(self) -> str:
        """The model's name in reports (``sinusoid``, ``harmonic3``, ``fourier6``)."""

    @property
    def n_coefficients(self) -> int:
        """Sampled columns the model adds (``c_k, s_k`` per order)."""
        return 2 * len(self.harmonics)

    def start(self, t, counts, centre, f_hz, phase, t_ref) -> np.ndarray:
        """Starting ``c_k, s_k`` per order in steps (interleaved, the fit's column order)."""
        return np.zeros(self.n_coefficients)

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and self.harmonics == other.harmonics

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.harmonics))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.label!r})"


class Sinusoid(MotionModel):
    """The paper's sinusoid (eq. 1a)."""

    @property
    def label(self) -> str:
        return "sinusoid"


class Harmonics(MotionModel):
    """The sinusoid plus chosen harmonic orders, each ``c_k cos(k phi) + s_k sin(k phi)``."""

    def __init__(self, orders) -> None:
        self.harmonics = _check_orders(orders)
        if not self.harmonics:
            raise ValueError("Harmonics needs at least one order (use Sinusoid)")

    @property
    def label(self) -> str:
        return "+".join(f"harmonic{k}" for k in self.harmonics)


class FourierSeries(MotionModel):
    """A periodic motion of free shape: the fundamental and every order ``2 .. order``.

    Parameters
    ----------
    order : int
        Highest order (>= 2).
    """

    gradient_point_fit = True

    def __init__(self, order) -> None:
        if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 2:
            raise ValueError(f"a Fourier series needs an order >= 2, got {order!r}")
        self.order = int(order)
        self.harmonics = tuple(range(2, self.order + 1))

    @property
    def label(self) -> str:
        return f"fourier{self.order}"

    def start(self, t, counts, centre, f_hz, phase, t_ref) -> np.ndarray:
        """Least-squares coefficients of the readings' centred counts on the series at the
        given fundamental (the reading is the motion to within one step; its quantization
        error is what the likelihood then removes), each clipped to the prior's
        ``+-0.45`` step."""
        phi = 2.0 * np.pi * f_hz * (np.asarray(t, dtype=float) - t_ref) + phase
        columns = [np.ones_like(phi), np.sin(phi), np.cos(phi)]
        for k in self.harmonics:
            columns += [np.cos(k * phi), np.sin(k * phi)]
        y = np.asarray(counts, dtype=float) + 0.5 - centre
        coef, *_ = np.linalg.lstsq(np.column_stack(columns), y, rcond=None)
        return np.clip(coef[3:], -0.45, 0.45)


def _check_orders(orders) -> tuple:
    h = tuple(orders)
    if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2 for k in h) \
            or len(set(h)) != len(h) or list(h) != sorted(h):
        raise ValueError(f"harmonic orders must be increasing distinct integers >= 2, got "
                         f"{orders!r}")
    return tuple(int(k) for k in h)


def from_harmonics(harmonics) -> MotionModel:
    """The model of a tuple of added orders: ``()`` the sinusoid, every order ``2 .. K``
    with ``K >= 4`` a Fourier series, anything else the chosen harmonics."""
    h = _check_orders(harmonics)
    if not h:
        return Sinusoid()
    if len(h) >= 3 and h == tuple(range(2, h[-1] + 1)):
        return FourierSeries(h[-1])
    return Harmonics(h)


def motion_model(spec) -> MotionModel:
    """A model from its configuration: a list of orders (``[]``, ``[3]``) or a label
    (``"sinusoid"``, ``"fourier6"``)."""
    if isinstance(spec, MotionModel):
        return spec
    if isinstance(spec, str):
        if spec == "sinusoid":
            return Sinusoid()
        if spec.startswith("fourier") and spec[len("fourier"):].isdigit():
            return FourierSeries(int(spec[len("fourier"):]))
        raise ValueError(f"unknown motion model {spec!r}: give a list of harmonic orders, "
                         "'sinusoid' or 'fourier<K>' (K >= 2)")
    return from_harmonics(spec)


def drift_phase(t, f0_hz: float, phase: float, drift_hz_per_s: float = 0.0, t_ref: float = 0.0):
    """Phase of a sinusoid with linear frequency drift.

    ``phi(t) = phase + 2 pi (f0 (t - t_ref) + drift (t - t_ref)^2 / 2)``, so the
    instantaneous frequency is ``f0 + drift (t - t_ref)`` Hz.
    """
    tau = np.asarray(t, dtype=float) - t_ref
    return phase + 2.0 * np.pi * (f0_hz * tau + 0.5 * drift_hz_per_s * tau**2)


def distorted_sinusoid(
    t,
    bias: float,
    amplitude: float,
    f0_hz: float,
    phase: float,
    drift_hz_per_s: float = 0.0,
    a3: float = 0.0,
    psi3: float = 0.0,
    a2: float = 0.0,
    psi2: float = 0.0,
    t_ref: float = 0.0,
):
    """Sinusoidal motion with harmonic distortion and frequency drift.

    ``theta(t) = b + A sin(phi) + A2 sin(2 phi + psi2) + A3 sin(3 phi + psi3)`` with ``phi``
    from :func:`drift_phase`. With ``a2 = a3 = drift = 0`` it is the pure sinusoid of the
    paper's model (:class:`Sinusoid`). The terms are linear in ``(b, A, A2 cos psi2, A2 sin psi2, A3 cos psi3,
    A3 sin psi3)`` for a fixed phase law, so a least-squares fit of them is exact given
    ``f0``, ``phase`` and ``drift``.
    """
    phi = drift_phase(t, f0_hz, phase, drift_hz_per_s, t_ref)
    return bias + amplitude * np.sin(phi) + a2 * np.sin(2 * phi + psi2) + a3 * np.sin(3 * phi + psi3)
