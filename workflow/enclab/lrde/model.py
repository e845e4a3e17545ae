"""Offset-encoder model of an extreme low-resolution digital encoder (Zhang & Gao).

Conventions (SI inside: rad, s, Hz)
-----------------------------------
Motion
    ``theta(t) = b + A sin(omega (t - t0)) = b + A sin(omega t + phase)`` with
    ``omega = 2 pi f``, ``phase = -omega t0``, stroke ``A12 = 2 A`` (peak to peak).
    ``b`` is the paper's bias ``A_{12-b} = (A1 - A2) / 2`` (eq. 2) with the upper amplitude
    ``A1 = max theta = b + A`` and the lower amplitude ``A2 = -min theta = A - b`` (both
    positive for a motion that straddles 0, as in Fig. 2).
Encoder
    ``counts = floor((theta + a) / step)``, ``reading = step * counts``, offset angle
    ``0 < a < step`` (eq. 1b). The reading therefore steps up to ``k step`` when ``theta``
    rises through ``k step - a`` and down to ``(k - 1) step`` when it falls through that
    level: the trigger levels ``step - a, 2 step - a, ...`` and ``-a, -step - a, ...`` of
    Fig. 2, with count 0 on ``[-a, step - a)``. ``a = step / 2`` is the rounding quantizer.
Identifiability
    Only ``a_eq = a + b`` enters ``floor((A sin(.) + a_eq) / step)`` (eq. 13b), so readings
    alone identify ``a_eq`` (and ``A12``, ``f``, ``phase``), never ``a`` and ``b`` apart.
Bias descriptors
    ideal bias ``(step - 2 a) / 2`` (eq. 8); ``E_b = b - ideal_bias = a_eq - step / 2``
    (eqs. 12a, 14). ``E_b > 0`` means the motion sits high on the encoder grid: the reading
    spends more time on its upper levels and its mean over a cycle is positive (eq. 21a).
Step count
    ``n`` labels the band ``(2n - 1) step < A12 < (2n + 1) step`` (eq. 6) and
    ``epsilon`` (eq. 7) is the distance from ``A12`` to its nearest odd multiple of
    ``step``. Proposition 1: the readings span exactly ``-n .. n`` (``2n`` steps peak to peak,
    symmetric about count 0) iff ``|E_b| < epsilon / 2``; the floor convention makes the
    band half-open, ``-epsilon/2 <= E_b < epsilon/2`` (the boundary has measure zero).
    More generally the readings are ``2n`` steps peak to peak, symmetric about count ``m``,
    iff ``|E_b - m step| < epsilon / 2``; otherwise they are ``2n - 1`` steps (when
    ``A12 < 2n step``) or ``2n + 1`` steps (when ``A12 > 2n step``) peak to peak.

Errata of the paper handled here: eq. (19) as printed has the opposite sign and, like
eq. (20), lacks the factor ``step`` (the DC component is an angle); Section III.A's band
"between (n-1) step and (n+1) step" is eq. (6)'s ``(2n - 1) step`` to ``(2n + 1) step``.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal", eqs. (1)-(21), Figs. 2, 5, 6.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = [
    "encoder_counts",
    "sinusoid",
    "ideal_bias",
    "e_b",
    "epsilon",
    "band_n",
    "step_count_band",
    "prop1_bias_band",
    "extreme_counts",
    "expected_step_count",
    "dwell_half_widths",
    "stroke_and_midpoint",
    "dwell_stroke",
    "dwell_stroke_eq4",
    "dwell_a_eq",
    "mean_reading",
    "dc_component",
    "dc_component_numeric",
]


def _check_step(step) -> float:
    if not (np.isscalar(step) and np.isfinite(step) and step > 0):
        raise ValueError(f"step must be a finite positive scalar (rad), got {step!r}")
    return float(step)


def _check_positive_scalar(name: str, value) -> float:
    if not (np.isscalar(value) and np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive scalar, got {value!r}")
    return float(value)


def _finite_array(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return arr


def _scalar_or_array(arr: np.ndarray):
    return arr[()] if arr.ndim == 0 else arr


def encoder_counts(theta, step, offset) -> np.ndarray:
    """Counts of the offset encoder, ``floor((theta + offset) / step)``.

    Parameters
    ----------
    theta : array_like
        True angle in rad.
    step : float
        Encoder resolution ``Delta`` in rad per count (> 0).
    offset : float or array_like
        Offset angle ``a`` in rad (eq. 1b: ``0 < a < step`` for a physical encoder; any real
        value is accepted so that the equivalent offset ``a_eq = a + b`` can be passed).

    Returns
    -------
    numpy.ndarray of int64
        Counts; the reading is ``step * counts``.

    References
    ----------
    .. [1] Zhang & Gao, Fig. 2 and Fig. 3(b).
    """
    step = _check_step(step)
    theta = _finite_array("theta", theta)
    offset = _finite_array("offset", offset)
    return np.floor((theta + offset) / step).astype(np.int64)


def sinusoid(t, A12, bias, f_hz, phase) -> np.ndarray:
    """The motion ``bias + (A12 / 2) sin(2 pi f_hz t + phase)`` of eq. (1a), in rad.

    Parameters
    ----------
    t : array_like
        Time in s.
    A12 : float
        Peak-to-peak stroke in rad (>= 0).
    bias : float
        Bias ``b`` (the paper's ``A_{12-b}``) in rad.
    f_hz : float
        Frequency in Hz (> 0).
    phase : float
        Phase in rad; the paper's time shift is ``t0 = -phase / (2 pi f_hz)``.
    """
    if not (np.isscalar(A12) and np.isfinite(A12) and A12 >= 0):
        raise ValueError(f"A12 must be a finite non-negative scalar (rad), got {A12!r}")
    f_hz = _check_positive_scalar("f_hz", f_hz)
    t = _finite_array("t", t)
    return bias + 0.5 * A12 * np.sin(2.0 * np.pi * f_hz * t + phase)


def ideal_bias(step, a):
    """Ideal bias ``(step - 2 a) / 2`` of eq. (8), in rad.

    With this bias (``E_b = 0``) every stroke in ``((2n-1) step, (2n+1) step)`` reads
    exactly ``2n`` steps peak to peak, symmetric about count 0 (Proposition 1).

    Parameters
    ----------
    step : float
        Encoder resolution in rad.
    a : float or array_like
        Offset angle in rad, ``0 <= a <= step``.
    """
    step = _check_step(step)
    a = _finite_array("a", a)
    if np.any((a < 0) | (a > step)):
        raise ValueError(f"a must lie in [0, step] = [0, {step!r}], got {a!r}")
    return _scalar_or_array(0.5 * (step - 2.0 * a))


def e_b(a_eq, step):
    """Deviation of the bias from the ideal bias, ``E_b = a_eq - step / 2`` (eq. 14), rad."""
    step = _check_step(step)
    return _scalar_or_array(_finite_array("a_eq", a_eq) - 0.5 * step)


def _check_stroke(A12) -> np.ndarray:
    A12 = _finite_array("A12", A12)
    if np.any(A12 < 0):
        raise ValueError(f"A12 must be non-negative (rad), got {A12!r}")
    return A12


def epsilon(A12, step):
    """Distance of ``A12`` to its nearest odd multiple of ``step`` (eq. 7), rad, in [0, step]."""
    step = _check_step(step)
    A12 = _check_stroke(A12)
    nearest_odd = 2.0 * np.floor(A12 / (2.0 * step)) + 1.0
    return _scalar_or_array(np.abs(A12 - nearest_odd * step))


def band_n(A12, step):
    """The ``n`` of the band ``(2n - 1) step <= A12 < (2n + 1) step`` holding ``A12`` (eq. 6).

    ``n = 0`` for strokes below one step (the reading then toggles between at most two values).
    """
    step = _check_step(step)
    A12 = _check_stroke(A12)
    return _scalar_or_array(np.floor(0.5 * (A12 / step + 1.0)).astype(np.int64))


def step_count_band(n, step) -> tuple[float, float]:
    """Strokes compatible with ``2n``-step readings: ``((2n - 1) step, (2n + 1) step)`` (eq. 6).

    Parameters
    ----------
    n : int
        Half the peak-to-peak step count (>= 1).
    step : float
        Encoder resolution in rad.
    """
    step = _check_step(step)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    return ((2 * n - 1) * step, (2 * n + 1) * step)


def prop1_bias_band(A12, a, step):
    """Bias band of Proposition 1 (eq. 9): ``ideal_bias(step, a) -/+ epsilon(A12, step) / 2``.

    Returns
    -------
    (low, high) : tuple of float or numpy.ndarray
        The readings are ``2n`` steps peak to peak and symmetric about count 0 iff
        ``low <= b < high`` (eq. 9; half-open because of the floor convention).
    """
    centre = np.asarray(ideal_bias(step, a))
    half = 0.5 * np.asarray(epsilon(A12, step))
    return _scalar_or_array(centre - half), _scalar_or_array(centre + half)


def extreme_counts(A12, a_eq, step):
    """Lowest and highest count of a whole cycle of ``A12/2 sin(.)`` read with offset ``a_eq``.

    Returns
    -------
    (count_min, count_max) : int64 scalars or arrays
        ``floor((a_eq - A12/2) / step)`` and ``floor((a_eq + A12/2) / step)``.
    """
    step = _check_step(step)
    A = 0.5 * _check_stroke(A12)
    a_eq = _finite_array("a_eq", a_eq)
    lo = np.floor((a_eq - A) / step).astype(np.int64)
    hi = np.floor((a_eq + A) / step).astype(np.int64)
    return _scalar_or_array(lo), _scalar_or_array(hi)


def expected_step_count(A12, a_eq, step):
    """Peak-to-peak step count ``count_max - count_min`` of the readings of one full cycle.

    Equals ``2n`` (``n = band_n``) iff ``|E_b - m step| < epsilon/2`` for an integer ``m``
    (Proposition 1 when ``m = 0``), else ``2n - 1`` or ``2n + 1``.
    """
    lo, hi = extreme_counts(A12, a_eq, step)
    return _scalar_or_array(np.asarray(hi) - np.asarray(lo))


def dwell_half_widths(A12, a_eq, step, f_hz):
    """Exact half-widths ``(w1, w2)`` in s of the dwells at the highest and lowest readings.

    The reading sits at ``count_max`` while ``A sin(omega t) >= count_max step - a_eq`` and at
    ``count_min`` while ``A sin(omega t) < (count_min + 1) step - a_eq``. Around the crest
    ``A sin(omega t) = A cos(omega s)`` with ``s`` the time from the crest, so the top dwell is
    ``2 w1`` long with ``A cos(omega w1) = count_max step - a_eq``; likewise
    ``A cos(omega w2) = a_eq - (count_min + 1) step`` at the trough.

    Returns
    -------
    (w1, w2) : float or numpy.ndarray
        NaN where the readings are constant over the cycle (no dwell is delimited).
    """
    step = _check_step(step)
    f_hz = _check_positive_scalar("f_hz", f_hz)
    A = 0.5 * _check_stroke(A12)
    a_eq = _finite_array("a_eq", a_eq)
    lo, hi = (np.asarray(x) for x in extreme_counts(A12, a_eq, step))
    omega = 2.0 * np.pi * f_hz
    with np.errstate(divide="ignore", invalid="ignore"):
        c1 = (hi * step - a_eq) / A
        c2 = (a_eq - (lo + 1) * step) / A
        valid = hi > lo
        w1 = np.where(valid, np.arccos(np.clip(c1, -1.0, 1.0)) / omega, np.nan)
        w2 = np.where(valid, np.arccos(np.clip(c2, -1.0, 1.0)) / omega, np.nan)
    return _scalar_or_array(w1), _scalar_or_array(w2)


def _check_widths(w1, w2, f_hz):
    w1 = np.asarray(w1, dtype=float)
    w2 = np.asarray(w2, dtype=float)
    half_period = 0.5 / f_hz
    for name, w in (("w1", w1), ("w2", w2)):
        if np.any((w < 0) | (w > half_period) | np.isinf(w)):
            raise ValueError(
                f"{name} must lie in [0, 1/(2 f_hz)] = [0, {half_period!r}] s (NaN allowed), "
                f"got {w!r}"
            )
    return w1, w2


def dwell_stroke(w1, w2, f_hz, step, steps_pp):
    """Stroke from the dwell half-widths at the extreme readings (eq. 4 generalised).

    Derivation: in the centred frame ``A sin(omega t)`` the top reading ``count_max`` is
    entered at the level ``L1 = count_max step - a_eq`` and the sine stays above ``L1`` for
    ``2 w1`` with ``A cos(omega w1) = L1``; the bottom reading ``count_min`` is held below
    ``L2 = (count_min + 1) step - a_eq`` for ``2 w2`` with ``A cos(omega w2) = -L2``. Adding,
    ``A (cos omega w1 + cos omega w2) = (count_max - count_min - 1) step``, hence::

        A12 = 2 (steps_pp - 1) step / (cos(omega w1) + cos(omega w2)).

    The offset cancels, so this holds for any ``steps_pp >= 2``; for ``2n``-step readings it
    is ``2 (2n - 1) step / (...)``, and ``n = 2`` gives eq. (4), ``6 step / (...)``.

    Parameters
    ----------
    w1, w2 : float or array_like
        Half-widths in s of the dwells at the top and bottom readings, in ``[0, 1/(2 f)]``
        (NaN propagates).
    f_hz : float
        Motion frequency in Hz.
    step : float
        Encoder resolution in rad.
    steps_pp : int or array_like of int
        Peak-to-peak step count ``count_max - count_min`` (>= 2).

    Returns
    -------
    float or numpy.ndarray
        ``A12`` in rad.

    References
    ----------
    .. [1] Zhang & Gao, eq. (4).
    """
    step = _check_step(step)
    f_hz = _check_positive_scalar("f_hz", f_hz)
    w1, w2 = _check_widths(w1, w2, f_hz)
    steps_pp = np.asarray(steps_pp)
    if not np.issubdtype(steps_pp.dtype, np.integer) or np.any(steps_pp < 2):
        raise ValueError(f"steps_pp must be integers >= 2, got {steps_pp!r}")
    omega = 2.0 * np.pi * f_hz
    return _scalar_or_array(
        2.0 * (steps_pp - 1) * step / (np.cos(omega * w1) + np.cos(omega * w2))
    )


def dwell_stroke_eq4(w1, w2, f_hz, step):
    """Eq. (4) for readings 4 steps peak to peak: ``6 step / (cos omega w1 + cos omega w2)``."""
    return dwell_stroke(w1, w2, f_hz, step, 4)


def dwell_a_eq(w1, w2, f_hz, step, count_max, count_min):
    """Equivalent offset ``a_eq`` from the dwell half-widths (companion of eq. 4).

    Subtracting the two level equations of :func:`dwell_stroke` instead of adding them,
    ``A (cos omega w1 - cos omega w2) = (count_max + count_min + 1) step - 2 a_eq``, so::

        a_eq = ((count_max + count_min + 1) step - A (cos omega w1 - cos omega w2)) / 2

    with ``A`` from :func:`dwell_stroke`. For readings ``-n .. n`` this is
    ``E_b = -A (cos omega w1 - cos omega w2) / 2``: a longer top dwell means ``E_b > 0``.
    """
    count_max = np.asarray(count_max)
    count_min = np.asarray(count_min)
    if not (np.issubdtype(count_max.dtype, np.integer)
            and np.issubdtype(count_min.dtype, np.integer)):
        raise ValueError(
            f"count_max and count_min must be integers, got {count_max!r}, {count_min!r}"
        )
    A = 0.5 * np.asarray(dwell_stroke(w1, w2, f_hz, step, count_max - count_min))
    omega = 2.0 * np.pi * f_hz
    w1, w2 = np.asarray(w1, dtype=float), np.asarray(w2, dtype=float)
    return _scalar_or_array(
        0.5 * ((count_max + count_min + 1) * step
               - A * (np.cos(omega * w1) - np.cos(omega * w2)))
    )


def mean_reading(A12, a_eq, step):
    """Exact mean reading over one cycle, any offset (the general form of eq. 18), rad.

    Over a cycle the fraction of time with ``A sin(phi) >= L`` is
    ``1/2 - arcsin(L/A)/pi``, so with ``L_k = k step - a_eq``::

        mean(counts) = count_min + sum_{k = count_min + 1}^{count_max} (1/2 - arcsin(L_k / A) / pi)

    For readings ``-n .. n`` this reduces to eq. (20) (see :func:`dc_component`).
    """
    step = _check_step(step)
    A12 = _check_stroke(A12)
    a_eq = _finite_array("a_eq", a_eq)
    A12, a_eq = np.broadcast_arrays(A12, a_eq)
    lo, hi = (np.asarray(x) for x in extreme_counts(A12, a_eq, step))
    n_levels = hi - lo
    j = np.arange(1, int(n_levels.max(initial=0)) + 1)
    k = lo[..., None] + j
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.clip((k * step - a_eq[..., None]) / (0.5 * A12[..., None]), -1.0, 1.0)
    terms = np.where(j <= n_levels[..., None], 0.5 - np.arcsin(x) / np.pi, 0.0)
    return _scalar_or_array(step * (lo + terms.sum(axis=-1)))


def dc_component(E_b, A12, step, n):
    """DC component ``c0`` of the reading over one cycle (eq. 20, with the factor ``step``).

    ``c0 = (step / pi) * sum_lambda arcsin((lambda step + 2 E_b) / A12)`` over
    ``lambda = +-1, +-3, ..., +-(2n - 1)`` (``+-1, +-3`` for ``n = 2``). Derivation: with
    ``a_eq = step/2 + E_b`` the levels of :func:`mean_reading` are
    ``L_k / A = ((2k - 1) step - 2 E_b) / A12`` for ``k = -n + 1 .. n``; the ``1/2`` terms
    cancel ``count_min = -n`` and the odd ``lambda = 2k - 1`` run symmetrically, so
    ``arcsin`` oddness flips the sign. ``c0`` is odd in ``E_b`` and increasing in ``|E_b|``
    (eq. 21), the restoring signal of Proposition 2.

    Parameters
    ----------
    E_b : float or array_like
        Bias deviation in rad, within Proposition 1's band ``|E_b| <= epsilon/2``.
    A12 : float or array_like
        Stroke in rad, within ``[(2n - 1) step, (2n + 1) step)``.
    step : float
        Encoder resolution in rad.
    n : int
        Half the peak-to-peak step count (>= 1).

    Raises
    ------
    ValueError
        When ``A12`` is outside the band of ``n`` or ``E_b`` outside Proposition 1's band
        (the readings are then not ``-n .. n`` and eq. (20) does not apply; use
        :func:`mean_reading`).

    References
    ----------
    .. [1] Zhang & Gao, eqs. (18)-(21).
    """
    lo_band, hi_band = step_count_band(n, step)
    A12 = _check_stroke(A12)
    E_b = _finite_array("E_b", E_b)
    if np.any((A12 < lo_band) | (A12 >= hi_band)):
        raise ValueError(
            f"A12 must lie in [(2n-1) step, (2n+1) step) = [{lo_band!r}, {hi_band!r}) "
            f"for n={n}, got {A12!r}"
        )
    half_eps = 0.5 * np.asarray(epsilon(A12, step))
    if np.any(np.abs(E_b) > half_eps * (1.0 + 1e-12)):
        raise ValueError(
            f"E_b must satisfy |E_b| <= epsilon/2 = {half_eps!r} (Proposition 1), got {E_b!r}"
        )
    lambdas = np.arange(-(2 * n - 1), 2 * n, 2, dtype=float)
    x = np.clip((lambdas * step + 2.0 * E_b[..., None]) / A12[..., None], -1.0, 1.0)
    return _scalar_or_array(step / np.pi * np.arcsin(x).sum(axis=-1))


def dc_component_numeric(E_b, A12, step, n_points=200_000) -> float:
    """Mean reading over one cycle by direct quadrature (cross-check of eq. 20).

    Samples the phase at the ``n_points`` cell midpoints ``2 pi (j + 1/2) / n_points``, reads
    ``A12/2 sin(phi)`` with the offset ``a_eq = step/2 + E_b`` and averages. Each of the
    ``2 K`` reading jumps of the cycle (``K`` steps peak to peak) misplaces at most half a
    cell, so the error is at most ``K step / n_points``.

    Parameters
    ----------
    E_b, A12 : float
        Bias deviation and stroke in rad (any values: no band is assumed).
    step : float
        Encoder resolution in rad.
    n_points : int
        Number of quadrature cells (>= 16).
    """
    step = _check_step(step)
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 16:
        raise ValueError(f"n_points must be an integer >= 16, got {n_points!r}")
    for name, value in (("E_b", E_b), ("A12", A12)):
        if not (np.isscalar(value) and math.isfinite(value)):
            raise ValueError(f"{name} must be a finite scalar (rad), got {value!r}")
    if A12 < 0:
        raise ValueError(f"A12 must be non-negative (rad), got {A12!r}")
    phi = 2.0 * np.pi * (np.arange(n_points) + 0.5) / n_points
    counts = encoder_counts(0.5 * A12 * np.sin(phi), step, 0.5 * step + E_b)
    return float(step * counts.mean())


def stroke_and_midpoint(A12_fundamental, harmonics, c, s, n_grid=512, chunk=4096):
    """Peak-to-peak stroke and midpoint of the extremes of a distorted periodic motion.

    The motion about its mean is ``A12_fundamental / 2 sin(phi) + sum_k c_k cos(k phi) +
    s_k sin(k phi)``. Eq. (2) defines the stroke from the extremes, ``A12 = A1 + A2`` with
    ``A1 = max theta`` and ``A2 = -min theta``, and the bias as their midpoint; for a pure
    sine they are ``2 A`` and the mean, but harmonics move the turning points.

    Each row is searched on ``n_grid`` phases, then its maximum and minimum are refined by
    Newton steps on ``d theta / d phi = 0`` (each step clipped to one grid spacing, the refined
    value kept only when it improves on the grid's), which reaches machine precision for any
    extremum wider than a few grid spacings.

    Parameters
    ----------
    A12_fundamental : array_like, shape (n,)
        Twice the fundamental's amplitude.
    harmonics : sequence of int
        Harmonic orders ``k`` (each >= 2).
    c, s : array_like, shape (n, len(harmonics))
        Coefficients of ``cos(k phi)`` and ``sin(k phi)``, in the unit of ``A12_fundamental``.

    Returns
    -------
    (stroke, midpoint) : numpy.ndarray, shape (n,) each
        ``max - min`` and ``(max + min) / 2`` of the motion about its mean.
    """
    half_a = 0.5 * np.atleast_1d(np.asarray(A12_fundamental, dtype=float))
    orders = np.asarray(tuple(harmonics), dtype=float)
    c = np.asarray(c, dtype=float).reshape(half_a.size, orders.size)
    s = np.asarray(s, dtype=float).reshape(half_a.size, orders.size)
    if orders.size and orders.min() < 2:
        raise ValueError(f"harmonic orders must be >= 2, got {tuple(harmonics)}")
    dphi = 2.0 * np.pi / n_grid
    phi = dphi * np.arange(n_grid)
    basis = np.vstack([np.sin(phi)] + [np.cos(k * phi) for k in orders]
                      + [np.sin(k * phi) for k in orders])          # (1 + 2H, n_grid)
    coef = np.column_stack([half_a, c, s])                           # (n, 1 + 2H)

    def derivatives(x, rows):
        """theta, theta', theta'' at phases ``x`` of rows ``rows``."""
        kx = orders[None, :] * x[:, None]
        ck, sk = np.cos(kx), np.sin(kx)
        cr, sr = c[rows], s[rows]
        h = half_a[rows]
        f0 = h * np.sin(x) + (cr * ck + sr * sk).sum(axis=1)
        f1 = h * np.cos(x) + (orders * (sr * ck - cr * sk)).sum(axis=1)
        f2 = -h * np.sin(x) - (orders ** 2 * (cr * ck + sr * sk)).sum(axis=1)
        return f0, f1, f2

    top = np.empty(half_a.size)
    bottom = np.empty(half_a.size)
    for lo in range(0, half_a.size, chunk):
        rows = np.arange(lo, min(lo + chunk, half_a.size))
        motion = coef[rows] @ basis
        for out, pick, sign in ((top, np.argmax, 1.0), (bottom, np.argmin, -1.0)):
            at = pick(motion, axis=1)
            x, best = phi[at], motion[np.arange(rows.size), at]
            for _ in range(4):
                _, f1, f2 = derivatives(x, rows)
                with np.errstate(divide="ignore", invalid="ignore"):
                    move = np.where(sign * f2 < 0, -f1 / f2, 0.0)
                x = x + np.clip(np.nan_to_num(move), -dphi, dphi)
            value = derivatives(x, rows)[0]
            out[rows] = np.where(sign * value > sign * best, value, best)
    return top - bottom, 0.5 * (top + bottom)


# Evaluation of the sinusoid on a uniform time grid (the likelihoods of enclab.lrde.fit and
# enclab.lrde.effects share it).

def uniform_grid(t, rtol=1e-9):
    """``(t0, dt, n)`` when ``t`` is an arithmetic sequence to within ``rtol * dt``, else None.

    On such a grid the sinusoid is evaluated by complex rotation (:func:`_sine_on_grid`),
    about 4x faster than ``np.sin``; logs with timestamp jitter take the direct path.
    """
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return None
    dt = (t[-1] - t[0]) / (t.size - 1)
    if not dt > 0 or np.max(np.abs(t - (t[0] + dt * np.arange(t.size)))) > rtol * dt:
        return None
    return float(t[0]), float(dt), int(t.size)


_BLOCK = 64


def _phasor_on_grid(omega, phase, grid, t_ref):
    """``exp(i (omega (t - t_ref) + phase))`` for ``t = t0 + k dt``, one row per ``omega``.

    ``exp(i omega (t0 + (B j + m) dt))`` is the product of a block start
    ``exp(i omega (t0 + B j dt))`` and an in-block rotation ``exp(i omega m dt)``, so only
    ``n / B + B`` complex exponentials are taken per row. Each factor is evaluated directly
    (no recurrence), so the error stays at a few ulp of the angle for any log length
    (tests/test_lrde_fit.py compares it with ``np.sin``).
    """
    t0, dt, n = grid
    n_blocks = -(-n // _BLOCK)
    within = np.exp(1j * np.multiply.outer(omega, dt * np.arange(_BLOCK)))
    starts = np.exp(1j * (np.multiply.outer(omega, (t0 - t_ref) + dt * _BLOCK
                                            * np.arange(n_blocks)) + phase[:, None]))
    rot = starts[:, :, None] * within[:, None, :]
    return rot.reshape(omega.size, -1)[:, :n]


def _sine_on_grid(omega, phase, grid, t_ref):
    """``sin(omega (t - t_ref) + phase)`` on a uniform grid (see :func:`_phasor_on_grid`).

    Only the imaginary part of each product is formed, ``Im(s w) = Re s Im w + Im s Re w``:
    half the arithmetic and memory of the complex product.
    """
    t0, dt, n = grid
    n_blocks = -(-n // _BLOCK)
    within = np.exp(1j * np.multiply.outer(omega, dt * np.arange(_BLOCK)))[:, None, :]
    starts = np.exp(1j * (np.multiply.outer(omega, (t0 - t_ref) + dt * _BLOCK
                                            * np.arange(n_blocks)) + phase[:, None]))[:, :, None]
    sine = starts.real * within.imag
    sine += starts.imag * within.real
    return sine.reshape(omega.size, -1)[:, :n]
