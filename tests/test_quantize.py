"""Tests for enclab.core.quantize: the encoder quantizer on integer counts."""
from __future__ import annotations

import math

import numpy as np
import pytest
from enclab.core.quantize import (
    level_label,
    multiple_label,
    quantize,
    ratio_of,
    requantize_counts,
)
from hypothesis import given, settings
from hypothesis import strategies as st

STEP = 1e-3


# ---------------------------------------------------------------------------------- quantize
def test_rounding_quantizer_on_exact_grid_points():
    # Multiples of a power of two are exact in float, so the tie rule is visible: half-way
    # points go up (floor(x + 0.5)), for negative angles too.
    step = 2.0**-10
    theta = np.array([-1.5, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.5]) * step
    np.testing.assert_array_equal(quantize(theta, step), [-1, 0, 0, 0, 0, 1, 1, 2])
    assert quantize(theta, step).dtype == np.int64


def test_offset_quantizer_is_floor_of_shifted_angle():
    step = 2.0**-8
    theta = np.array([-0.01, 0.0, 0.2, 0.7, 0.76, 0.99]) * step
    # offset_frac = 0.25: reading jumps when theta/step crosses 0.75 (mod 1).
    np.testing.assert_array_equal(quantize(theta, step, offset_frac=0.25), [0, 0, 0, 0, 1, 1])
    np.testing.assert_array_equal(quantize(theta, step, offset_frac=0.0), [-1, 0, 0, 0, 0, 0])


@pytest.mark.parametrize("offset_frac", [0.0, 0.25, 0.5, 0.9])
def test_error_lies_in_the_documented_interval(offset_frac):
    rng = np.random.default_rng(11)
    theta = rng.uniform(-3.0, 3.0, 20_000)
    err = quantize(theta, STEP, offset_frac) * STEP - theta
    a = offset_frac * STEP
    # (a - step, a] up to the float rounding of theta/step (~1e-16 * 3000 steps).
    slack = 1e-12 * STEP
    assert err.min() > a - STEP - slack and err.max() <= a + slack


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"step": 0.0}, "step must be"),
        ({"step": -1e-3}, "step must be"),
        ({"step": float("nan")}, "step must be"),
        ({"step": 1e-3, "offset_frac": 1.0}, "offset_frac must be"),
        ({"step": 1e-3, "offset_frac": -0.1}, "offset_frac must be"),
    ],
)
def test_quantize_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        quantize([0.0], **kwargs)


def test_quantize_rejects_non_finite_and_huge_angles():
    with pytest.raises(ValueError, match=r"index \(2,\)"):
        quantize([0.0, 1.0, np.inf], STEP)
    with pytest.raises(ValueError, match="2\\*\\*52"):
        quantize([1e14], STEP)


# ------------------------------------------------------------------------ requantize_counts
def test_requantize_counts_worked_example():
    # ratio 8, rounding: coarse = (k + 4) // 8; ties (k = -12, -4, 4, 12) go up.
    k = np.array([-13, -12, -5, -4, -1, 0, 3, 4, 11, 12])
    np.testing.assert_array_equal(requantize_counts(k, 8), [-2, -1, -1, 0, 0, 0, 0, 1, 1, 2])


def test_requantize_by_powers_of_two_equals_integer_floor_division():
    # The power-of-two path shifts instead of dividing; Python's // on ints is the reference.
    k = np.concatenate([np.arange(-300, 300), [-(2**50) - 7, 2**50 + 5]])
    for ratio in (1, 2, 8, 32, 1024, 3, 12):
        for offset in (0.0, 0.5, 0.3):
            shift = int(np.floor(offset * ratio))
            expected = [(int(v) + shift) // ratio for v in k]
            np.testing.assert_array_equal(requantize_counts(k, ratio, offset), expected)


def test_requantize_tie_rule_gives_half_fine_step_mean():
    # Over one period of residues the error (coarse reading - fine reading) takes the
    # values {-3..4} fine steps for ratio 8 with rounding: mean +1/2 fine step.
    k = np.arange(-800, 800)
    err_fine_steps = 8 * requantize_counts(k, 8) - k
    assert err_fine_steps.min() == -3 and err_fine_steps.max() == 4
    assert err_fine_steps.mean() == 0.5


def test_requantize_uses_the_exact_value_of_the_offset():
    # 0.29 * 100 rounds to 28.999999999999996 in float, and the double nearest 0.29 is
    # below 0.29, so the exact shift floor(0.28999999999999998 * 100) is 28.
    assert requantize_counts([71], 100, offset_frac=0.29)[0] == 0
    assert requantize_counts([72], 100, offset_frac=0.29)[0] == 1


def test_requantize_is_composable():
    # Re-quantizing by 2 then by 4 (rounding at each stage) differs from by 8 at once only
    # through the tie rule; with offset 0 (truncation) both are floor(k/8).
    k = np.arange(-1000, 1000)
    two_stage = requantize_counts(requantize_counts(k, 2, 0.0), 4, 0.0)
    np.testing.assert_array_equal(two_stage, requantize_counts(k, 8, 0.0))
    np.testing.assert_array_equal(two_stage, np.floor_divide(k, 8))


@settings(max_examples=300, deadline=None)
@given(
    k=st.integers(min_value=-(2**40), max_value=2**40),
    ratio=st.integers(min_value=1, max_value=4096),
    offset_frac=st.floats(min_value=0.0, max_value=1.0, exclude_max=True),
    fine_exponent=st.integers(min_value=-20, max_value=-3),
)
def test_requantize_matches_float_quantizer_away_from_ties(k, ratio, offset_frac, fine_exponent):
    # Proof in the docstring; here against quantize(k * fine, ratio * fine, o) with a fine step
    # that is not a power of two. The float version evaluates k*fine/(ratio*fine) + o with a
    # relative error of a few eps, i.e. an absolute error <= 8 eps (|k|/ratio + 1); it is only
    # trusted when the exact value x = k/ratio + o is farther than that from an integer.
    fine_step = 3.0 * 10.0**fine_exponent
    exact = requantize_counts(np.array([k]), ratio, offset_frac)[0]
    x = k / ratio + offset_frac
    margin = 8 * np.finfo(float).eps * (abs(k) / ratio + 1)
    if abs(x - round(x)) <= margin:
        return
    via_float = quantize(np.array([k * fine_step]), ratio * fine_step, offset_frac)[0]
    assert exact == via_float


def test_requantize_rejects_bad_arguments():
    with pytest.raises(ValueError, match="ratio must be a positive integer"):
        requantize_counts([1], 0)
    with pytest.raises(ValueError, match="ratio must be a positive integer"):
        requantize_counts([1], 2.0)
    with pytest.raises(ValueError, match="counts must be an integer array"):
        requantize_counts([1.5], 2)
    with pytest.raises(ValueError, match="offset_frac must be"):
        requantize_counts([1], 2, offset_frac=1.5)


# ---------------------------------------------------------------------------------- labels
def test_ratio_of_accepts_float_ratios_of_encoder_steps():
    assert ratio_of(2 * math.pi / 4096, 2 * math.pi / 32768) == 8
    assert ratio_of(1e-3, 1.25e-4) == 8
    assert ratio_of(1e-3, 1e-3) == 1
    with pytest.raises(ValueError, match="must be a positive integer"):
        ratio_of(1e-3, 3e-4)
    with pytest.raises(ValueError, match="must be a positive integer"):
        ratio_of(1e-4, 1e-3)
    with pytest.raises(ValueError, match="fine_step must be"):
        ratio_of(1e-3, 0.0)


@pytest.mark.parametrize(
    "step, unit, label",
    [
        (1e-3, "rad", "1mrad"),
        (1.25e-4, "rad", "0.125mrad"),
        (5e-7, "m", "0.5um"),
        (8e-3, "rad", "8mrad"),
        (0.05, "rad", "50mrad"),
        (0.5, "rad", "0.5rad"),
        (2 * math.pi / 4096, "rad", "1.53398mrad"),
        (2e-11, "m", "0.02nm"),
    ],
)
def test_level_label(step, unit, label):
    assert level_label(step, unit) == label


def test_labels_reject_bad_arguments():
    assert multiple_label(8) == "8x"
    with pytest.raises(ValueError, match="ratio must be"):
        multiple_label(0)
    with pytest.raises(ValueError, match="unit must be"):
        level_label(1e-3, unit="m/s")
    with pytest.raises(ValueError, match="step must be"):
        level_label(-1e-3)
