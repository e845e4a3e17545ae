"""Encoder quantizer on integer counts, exact re-quantization, and labels for steps.

Quantizer (rounding for the quantization-error analysis, an offset for the low-resolution
encoder)::

    counts = floor(theta / step + offset_frac),   reading = step * counts

``offset_frac = 0.5`` is the rounding quantizer of Colonnese & Okamura; any other fraction in
``[0, 1)`` is the offset encoder of Zhang & Gao (offset ``a = offset_frac * step``). The
quantization error is ``reading - theta`` (measured - true) and lies in
``(a - step, a]``.

Quantized signals are kept as int64 counts plus a step. Re-quantizing a fine channel to a
coarser step is done on the integer counts (:func:`requantize_counts`), never by rounding
float readings again, which is not idempotent.

References
----------
.. [1] N. Colonnese and A. M. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives", Section II.
.. [2] Z. Zhang and Q. Gao, "Characterization of extreme low-resolution digital encoder
   for control system with sinusoidal reference signal": the encoder's initial position
   (offset angle).
"""
from __future__ import annotations

import math
import numbers
from fractions import Fraction

import numpy as np

__all__ = ["quantize", "requantize_counts", "ratio_of", "level_label", "multiple_label"]

# |theta / step| must stay well inside int64 and inside the range where float64 still
# resolves a unit step (2**52), otherwise floor() no longer sees the fractional part.
_MAX_COUNTS = 2.0**52
_RATIO_RTOL = 1e-9
# SI prefixes for labels, ASCII "u" for micro so that labels are file-name safe.
_PREFIXES = ((1.0, ""), (1e-3, "m"), (1e-6, "u"), (1e-9, "n"))


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _check_step(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {name}={value!r}")
    return float(value)


def _check_offset(offset_frac) -> float:
    if (
        isinstance(offset_frac, bool)
        or not isinstance(offset_frac, numbers.Real)
        or not 0.0 <= offset_frac < 1.0
    ):
        raise ValueError(f"offset_frac must be a number in [0, 1), got offset_frac={offset_frac!r}")
    return float(offset_frac)


def _check_ratio(ratio) -> int:
    if not _is_int(ratio) or ratio < 1:
        raise ValueError(f"ratio must be a positive integer, got ratio={ratio!r}")
    return int(ratio)


def quantize(theta, step: float, offset_frac: float = 0.5) -> np.ndarray:
    """Counts of an encoder with quantization step ``step`` reading the angle ``theta``.

    Parameters
    ----------
    theta : array_like
        True angle (rad) or position (m); must be finite.
    step : float
        Quantization step, SI unit per count, ``> 0``.
    offset_frac : float
        Quantizer offset as a fraction of ``step``, in ``[0, 1)``; 0.5 is rounding.

    Returns
    -------
    ndarray of int64, shape of ``theta``
        ``floor(theta / step + offset_frac)``; the reading is ``step * counts``.

    Raises
    ------
    ValueError
        For a non-positive step, an offset outside ``[0, 1)``, non-finite ``theta``, or
        counts beyond ``2**52`` in magnitude (float64 no longer resolves the step there).

    Examples
    --------
    >>> quantize([0.0, 0.49e-3, 0.5e-3, -0.5e-3], 1e-3).tolist()
    [0, 0, 1, 0]
    >>> quantize([0.0, 0.99e-3], 1e-3, offset_frac=0.0).tolist()
    [0, 0]
    """
    step = _check_step("step", step)
    offset_frac = _check_offset(offset_frac)
    theta = np.asarray(theta, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(theta.ravel()))
    if bad.size:
        idx = tuple(int(i) for i in np.unravel_index(bad[0], theta.shape))
        raise ValueError(f"theta must be finite; first non-finite value at index {idx}")
    scaled = theta / step + offset_frac
    if scaled.size and float(np.max(np.abs(scaled))) >= _MAX_COUNTS:
        raise ValueError(
            f"theta / step reaches {float(np.max(np.abs(scaled))):.3g} counts, beyond 2**52 "
            f"where float64 cannot resolve one step (step={step!r})"
        )
    return np.floor(scaled).astype(np.int64)


def requantize_counts(counts, ratio: int, offset_frac: float = 0.5) -> np.ndarray:
    """Re-quantize fine counts to a step ``ratio`` times larger, exactly, in integers.

    Parameters
    ----------
    counts : array_like of int
        Fine counts ``k`` (reading ``k * fine_step``).
    ratio : int
        Coarse step / fine step, a positive integer (see :func:`ratio_of`).
    offset_frac : float
        Offset of the coarse quantizer as a fraction of the coarse step, in ``[0, 1)``.

    Returns
    -------
    ndarray of int64
        ``(k + floor(offset_frac * ratio)) // ratio``.

    Notes
    -----
    This equals ``quantize(k * fine_step, ratio * fine_step, offset_frac) = floor(k / r + o)
    = floor((k + o r) / r)`` without any float error: write ``o r = c + phi`` with
    ``c = floor(o r)``, ``0 <= phi < 1``; for the integer ``N = k + c`` the values ``N / r``
    and ``(N + phi) / r`` lie in the same interval ``[j, j + 1)``, because
    ``N + phi >= r (j + 1)`` would force the integer ``N > r (j + 1) - 1``, i.e.
    ``N >= r (j + 1)``. Hence ``floor((k + o r)/r) = (k + c) // r``. ``c`` is computed from
    the exact rational value of the float ``offset_frac``, so a product such as
    ``0.29 * 100`` cannot round up across an integer. With rounding on both grids the tie
    of a fine count exactly half-way between two coarse levels goes up, which gives the
    error a mean of ``+fine_step/2`` for even ``ratio`` (see
    :class:`enclab.propagation.theory.QuantizerErrorModel`).

    Examples
    --------
    >>> requantize_counts([-5, -4, -1, 0, 3, 4, 11, 12], 8).tolist()
    [-1, 0, 0, 0, 0, 1, 1, 2]
    """
    ratio = _check_ratio(ratio)
    offset_frac = _check_offset(offset_frac)
    counts = np.asarray(counts)
    if not np.issubdtype(counts.dtype, np.integer):
        raise ValueError(f"counts must be an integer array, got dtype {counts.dtype}")
    shift = math.floor(Fraction(offset_frac) * ratio)
    shifted = counts.astype(np.int64) + shift
    if ratio & (ratio - 1) == 0:
        # An arithmetic right shift is floor division by a power of two, also for negative
        # counts, at a third of the cost of numpy's int64 floor_divide.
        return shifted >> (ratio.bit_length() - 1)
    return shifted // ratio


def ratio_of(step: float, fine_step: float) -> int:
    """The integer ratio ``step / fine_step``.

    Raises
    ------
    ValueError
        If either step is not finite and positive, or if the ratio is not a positive
        integer to within ``1e-9`` relative (float steps such as ``2 pi / 4096`` and
        ``2 pi / 32768`` give ratios like ``7.999999999999999``).
    """
    step = _check_step("step", step)
    fine_step = _check_step("fine_step", fine_step)
    ratio = step / fine_step
    whole = round(ratio)
    if whole < 1 or abs(ratio - whole) > _RATIO_RTOL * ratio:
        raise ValueError(
            f"step / fine_step must be a positive integer, got step={step!r}, "
            f"fine_step={fine_step!r} (ratio {ratio!r})"
        )
    return int(whole)


def level_label(step: float, unit: str = "rad") -> str:
    """Short, file-name safe label of a quantization step, e.g. ``"1mrad"``.

    The prefix is the largest of ``"", "m", "u", "n"`` for which the mantissa is at least
    0.1; the mantissa is printed with up to six significant digits.

    Examples
    --------
    >>> level_label(1e-3), level_label(1.25e-4), level_label(5e-7, unit="m")
    ('1mrad', '0.125mrad', '0.5um')
    """
    step = _check_step("step", step)
    if not isinstance(unit, str) or not unit.isalpha():
        raise ValueError(f"unit must be a non-empty alphabetic string such as 'rad' or 'm', got unit={unit!r}")
    scale, prefix = _PREFIXES[-1]
    for candidate_scale, candidate_prefix in _PREFIXES:
        if step / candidate_scale >= 0.1:
            scale, prefix = candidate_scale, candidate_prefix
            break
    return f"{step / scale:.6g}{prefix}{unit}"


def multiple_label(ratio: int) -> str:
    """Label of a re-quantization by an integer multiple of the native step, e.g. ``"8x"``."""
    return f"{_check_ratio(ratio)}x"
