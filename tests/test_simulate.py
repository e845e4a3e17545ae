"""Tests of enclab.propagation.simulate: the simulated Phantom Premium protocol logs."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from enclab.propagation.kinematics import PhantomPremium15
from enclab.propagation.simulate import (
    fig6_configurations_deg,
    phantom_protocol_run,
    sinusoid_motion,
)

STEP = 1.25e-4
CENTRE = np.deg2rad([10.0, -20.0, 30.0])
COUNT_COLUMNS = ["theta1_counts", "theta2_counts", "theta3_counts"]


@pytest.fixture(scope="module")
def run():
    return phantom_protocol_run(CENTRE, np.random.default_rng(12345))


def _truth_motion(log: pd.DataFrame, truth: dict) -> np.ndarray:
    return sinusoid_motion(
        log["t"].to_numpy(),
        truth["centre_rad"],
        truth["amplitude_rad"],
        truth["freqs_hz"],
        truth["phases_rad"],
    )


def test_log_layout_and_types(run):
    log, truth = run
    assert list(log.columns) == ["t", *COUNT_COLUMNS]
    assert len(log) == 15000 == truth["n_samples"]
    assert log["t"].dtype == np.float64
    np.testing.assert_array_equal(log["t"].to_numpy(), np.arange(15000) / 1000.0)
    for column in COUNT_COLUMNS:
        assert log[column].dtype == np.int64
    assert truth["truth_step"] == STEP
    assert truth["amplitude_rad"] == pytest.approx(math.radians(3.0), rel=1e-15)
    np.testing.assert_array_equal(truth["centre_rad"], CENTRE)


def test_same_seed_same_log_and_int_seed_accepted(run):
    log, truth = run
    log2, truth2 = phantom_protocol_run(CENTRE, np.random.default_rng(12345))
    log3, truth3 = phantom_protocol_run(CENTRE, 12345)
    pd.testing.assert_frame_equal(log, log2)
    pd.testing.assert_frame_equal(log, log3)
    assert truth == truth2 == truth3
    other, other_truth = phantom_protocol_run(CENTRE, np.random.default_rng(12346))
    assert other_truth["freqs_hz"] != truth["freqs_hz"]
    assert not other.equals(log)


def test_counts_round_the_motion(run):
    log, truth = run
    error = log[COUNT_COLUMNS].to_numpy() * STEP - _truth_motion(log, truth)
    # Rounding bounds the error by step/2; floating error of theta/step (|theta| < 1 rad, so
    # < 1e4 counts, ulp ~ 2e-12 counts) is far below the 1e-9 step slack allowed here.
    assert np.max(np.abs(error)) <= STEP / 2 * (1 + 1e-9)
    # A floor quantizer would give errors in (-step, 0]; rounding fills (-step/2, step/2].
    # The motion moves up to A 2 pi f / fs = 13 steps per sample, so both ends of the
    # interval are reached.
    assert np.all(error.max(axis=0) > 0.45 * STEP)
    assert np.all(error.min(axis=0) < -0.45 * STEP)


def test_centre_and_amplitude_from_extremes(run):
    log, truth = run
    theta = log[COUNT_COLUMNS].to_numpy() * STEP
    amplitude = truth["amplitude_rad"]
    # Sampling 5 Hz at 1 kHz misses a crest by at most pi f / fs in phase, i.e. by
    # A (1 - cos(pi f / fs)) in angle; quantization adds at most step/2 to each extreme.
    tol = amplitude * (1 - math.cos(math.pi * 5.1 / 1000)) + STEP
    np.testing.assert_allclose((theta.max(0) - theta.min(0)) / 2, amplitude, atol=tol)
    np.testing.assert_allclose((theta.max(0) + theta.min(0)) / 2, CENTRE, atol=tol)


def test_frequencies_distinct_and_in_band():
    # 200 runs: the sampler must never violate the band or the separation.
    for seed in range(200):
        _, truth = phantom_protocol_run(np.zeros(3), seed, duration_s=0.01)
        freqs = np.sort(truth["freqs_hz"])
        assert np.all((freqs >= 4.9) & (freqs <= 5.1))
        assert np.min(np.diff(freqs)) >= 0.02
        phases = np.asarray(truth["phases_rad"])
        assert np.all((phases >= 0) & (phases < 2 * np.pi))


def test_frequency_band_is_not_biased():
    # By symmetry of the band and the separation rule, E f = 5 Hz. A run's mean frequency
    # lies in [4.9, 5.1], so its standard deviation is at most 0.1 Hz (Popoviciu), and the
    # mean of 300 independent runs has standard error < 0.0058 Hz: 5 sigma = 0.029 Hz. A
    # sampler biased towards one edge of the band (e.g. by a one-sided rejection) fails.
    means = [
        np.mean(phantom_protocol_run(np.zeros(3), seed, duration_s=0.01)[1]["freqs_hz"])
        for seed in range(1000, 1300)
    ]
    assert abs(np.mean(means) - 5.0) < 0.029


def test_frequency_recovered_by_fft(run):
    log, truth = run
    theta = log[COUNT_COLUMNS].to_numpy() * STEP
    fs, n_fft = 1000.0, 2**21
    windowed = (theta - theta.mean(axis=0)) * np.hanning(len(theta))[:, np.newaxis]
    spectrum = np.abs(np.fft.rfft(windowed, n=n_fft, axis=0))
    peaks = np.fft.rfftfreq(n_fft, d=1 / fs)[np.argmax(spectrum, axis=0)]
    # Zero padding puts bins 1000 / 2**21 = 4.8e-4 Hz apart (peak within half a bin); the
    # negative-frequency image of a 75-cycle Hann-windowed sine shifts the peak by far less.
    # The tolerance of 1 mHz is 20 times below the 20 mHz separation, so each column's
    # peak identifies its own joint's frequency.
    np.testing.assert_allclose(peaks, truth["freqs_hz"], rtol=0, atol=1e-3)


def test_sinusoid_motion_values_and_shapes():
    t = np.array([0.0, 0.05, 0.1])
    motion = sinusoid_motion(t, [1.0, -1.0], [0.5, 0.25], [5.0, 2.5], [0.0, np.pi / 2])
    expected = np.array(
        [
            [1.0, -1.0 + 0.25],
            [1.0 + 0.5 * math.sin(0.5 * np.pi), -1.0 + 0.25 * math.cos(0.25 * np.pi)],
            [1.0 + 0.5 * math.sin(np.pi), -1.0 + 0.25 * math.cos(0.5 * np.pi)],
        ]
    )
    np.testing.assert_allclose(motion, expected, atol=1e-15)
    scalar = sinusoid_motion(t, [0.0, 0.0], 0.5, [5.0, 2.5], [0.0, 0.0])
    per_joint = sinusoid_motion(t, [0, 0], [0.5, 0.5], [5.0, 2.5], [0, 0])
    np.testing.assert_array_equal(scalar, per_joint)
    with pytest.raises(ValueError, match=r"freqs_hz must have shape \(2,\)"):
        sinusoid_motion(t, [0.0, 0.0], 0.5, [5.0], [0.0, 0.0])
    with pytest.raises(ValueError, match=r"t must have shape"):
        sinusoid_motion(np.zeros((3, 1)), [0.0], 0.5, [5.0], [0.0])


@pytest.mark.parametrize(
    ("args", "kwargs", "message"),
    [
        ((np.zeros(2),), {}, r"centre_rad must have shape \(3,\)"),
        ((np.zeros(3),), {"amplitude_rad": -0.1}, "amplitude_rad must be a positive"),
        ((np.zeros(3),), {"fs_hz": 10.0}, "Nyquist"),
        ((np.zeros(3),), {"min_freq_separation_hz": 0.1}, "separation_hz=0.1 is too large"),
        ((np.zeros(3),), {"min_freq_separation_hz": -1.0}, "min_freq_separation_hz must be"),
        ((np.zeros(3),), {"freq_halfwidth_hz": 6.0}, "freq_halfwidth_hz=6.0 must be below"),
        ((np.zeros(3),), {"duration_s": 0.0005}, "fewer than 2 samples"),
        (([0.0, np.nan, 0.0],), {}, "centre_rad must be finite"),
    ],
)
def test_invalid_arguments_are_reported(args, kwargs, message):
    with pytest.raises(ValueError, match=message):
        phantom_protocol_run(*args, np.random.default_rng(0), **kwargs)


def test_fig6_configurations():
    configs = fig6_configurations_deg()
    assert configs.shape == (7, 3)
    np.testing.assert_array_equal(configs[0], [0.0, 0.0, 0.0])
    assert np.all(np.abs(configs) <= 45.0)
    assert len(np.unique(configs, axis=0)) == len(configs)
    # Every Jacobian entry that is not structurally zero (dy/dtheta1 is) must change by at
    # least a quarter of its largest value across the sweep, so the sweep probes the
    # configuration dependence of every x, y, z sensitivity.
    jac = np.abs(PhantomPremium15().jacobian(np.deg2rad(configs)))
    largest = jac.max(axis=0)
    varying = largest > 0
    assert np.count_nonzero(~varying) == 1 and not varying[1, 0]
    spread = (largest - jac.min(axis=0))[varying] / largest[varying]
    assert np.all(spread >= 0.25)
