"""Simulated lab logs of the Phantom Premium 1.5 protocol of Colonnese & Okamura, Section IV.

There is no public Phantom log, so the experiment is simulated: the device oscillates about
a centre configuration, each joint with amplitude 3 deg and its own frequency within 0.1 Hz
of 5 Hz, sampled at 1 kHz for 15 s. The truth channel is recorded at the robot's own encoder
resolution (0.125 mrad, by rounding), as in the real experiment. The coarse 1 mrad
"measured" channel is not produced here: the pipeline's re-quantize stage derives it exactly
from the truth counts.

References
----------
.. [1] N. Colonnese and A. M. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives", Section IV-A (protocol) and Fig. 6 (error vs configuration).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from enclab.propagation.kinematics import PhantomPremium15

__all__ = ["fig6_configurations_deg", "phantom_protocol_run", "sinusoid_motion"]

PHANTOM_JOINTS = PhantomPremium15.joint_names


def _positive(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(number) and number > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return number


def _vector(name: str, value: Any, length: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a 1-D array of numbers, got {value!r}") from None
    if arr.ndim != 1 or (length is not None and arr.size != length):
        expected = f"({length},)" if length is not None else "(n,)"
        raise ValueError(f"{name} must have shape {expected}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def sinusoid_motion(
    t: Any, centre: Any, amplitude: Any, freqs_hz: Any, phases_rad: Any
) -> np.ndarray:
    """Continuous joint motion ``theta_i(t) = c_i + A_i sin(2 pi f_i t + phi_i)``.

    Parameters
    ----------
    t : array_like, shape (N,)
        Times in s.
    centre : array_like, shape (n,)
        Centre configuration c in rad (or m).
    amplitude : float or array_like, shape (n,)
        Amplitude A, one for all joints or one per joint.
    freqs_hz : array_like, shape (n,)
        Frequencies f in Hz.
    phases_rad : array_like, shape (n,)
        Phases phi in rad.

    Returns
    -------
    numpy.ndarray, shape (N, n)
    """
    t = _vector("t", t)
    centre = _vector("centre", centre)
    n = centre.size
    freqs_hz = _vector("freqs_hz", freqs_hz, n)
    phases_rad = _vector("phases_rad", phases_rad, n)
    amp = np.asarray(amplitude, dtype=np.float64)
    if amp.ndim == 0:
        amp = np.full(n, float(amp))
    amp = _vector("amplitude", amp, n)
    return centre + amp * np.sin(2.0 * np.pi * t[:, np.newaxis] * freqs_hz + phases_rad)


def _distinct_frequencies(
    rng: np.random.Generator, n: int, centre_hz: float, halfwidth_hz: float, separation_hz: float
) -> np.ndarray:
    """n frequencies uniform in [centre - halfwidth, centre + halfwidth], pairwise >= separation.

    Rejection sampling: draw n independent uniforms, keep the draw if its closest pair is at
    least ``separation_hz`` apart. The accepted draws are uniform on the admissible set; the
    acceptance rate is (1 - (n - 1) s / w)^n (w the band width, s the separation), 0.51 at the
    paper's conditions (n=3, w=0.2 Hz, s=0.02 Hz).
    """
    width = 2.0 * halfwidth_hz
    slack = 1.0 - (n - 1) * separation_hz / width
    # Below an acceptance rate of 1e-4 the loop would be slow; refuse such requests instead.
    if slack <= 0.0 or slack**n < 1e-4:
        raise ValueError(
            f"min_freq_separation_hz={separation_hz} is too large for {n} frequencies in a "
            f"band of {width} Hz (need (n - 1) * separation well below the band width)"
        )
    max_draws = int(100 / slack**n)  # P(no acceptance) = (1 - p)^(100/p) < e^-100
    for _ in range(max_draws):
        freqs = rng.uniform(centre_hz - halfwidth_hz, centre_hz + halfwidth_hz, size=n)
        if n < 2 or np.min(np.diff(np.sort(freqs))) >= separation_hz:
            return freqs
    raise RuntimeError("rejection sampling of the frequencies did not accept any draw")


def phantom_protocol_run(
    centre_rad: Any,
    rng: np.random.Generator | int,
    *,
    duration_s: float = 15.0,
    fs_hz: float = 1000.0,
    amplitude_rad: float = float(np.deg2rad(3.0)),
    freq_centre_hz: float = 5.0,
    freq_halfwidth_hz: float = 0.1,
    truth_step: float = 1.25e-4,
    min_freq_separation_hz: float = 0.02,
) -> tuple[pd.DataFrame, dict]:
    """Simulate one run of the Section IV protocol on the Phantom Premium 1.5.

    Each joint moves as ``theta_i(t) = c_i + A sin(2 pi f_i t + phi_i)`` with ``f_i`` uniform
    in ``[freq_centre_hz - freq_halfwidth_hz, freq_centre_hz + freq_halfwidth_hz]`` and
    pairwise at least ``min_freq_separation_hz`` apart (rejection sampling), so that the joint
    errors are independent, and ``phi_i`` uniform in ``[0, 2 pi)``. The log records the truth
    at the robot's own encoder resolution by rounding:
    ``counts = floor(theta / truth_step + 1/2)``.

    Parameters
    ----------
    centre_rad : array_like, shape (3,)
        Centre configuration (theta1, theta2, theta3) in rad.
    rng : numpy.random.Generator or int
        Source of the random frequencies and phases (an int is used as a seed).
    duration_s, fs_hz : float
        Length of the run (s) and sample rate (Hz); ``round(duration_s * fs_hz)`` samples.
    amplitude_rad : float
        Amplitude A of every joint (rad); the paper's 3 deg by default.
    freq_centre_hz, freq_halfwidth_hz : float
        Band of the joint frequencies (Hz): the paper's "within 0.1 Hz of 5 Hz".
    truth_step : float
        Step of the truth encoder (rad per count): the paper's 0.125 mrad.
    min_freq_separation_hz : float
        Smallest allowed difference between two joint frequencies (Hz).

    Returns
    -------
    log : pandas.DataFrame
        Columns ``t`` (float64, ``k / fs_hz`` s) and ``theta1_counts``, ``theta2_counts``,
        ``theta3_counts`` (int64 truth counts of ``truth_step``).
    truth : dict
        JSON-friendly provenance: ``freqs_hz``, ``phases_rad``, ``centre_rad`` (lists),
        ``amplitude_rad``, ``truth_step``, ``fs_hz``, ``duration_s``, ``n_samples``,
        ``joint_names``.

    References
    ----------
    .. [1] Colonnese & Okamura, Section IV-A.
    """
    centre = _vector("centre_rad", centre_rad, len(PHANTOM_JOINTS))
    duration_s = _positive("duration_s", duration_s)
    fs_hz = _positive("fs_hz", fs_hz)
    amplitude_rad = _positive("amplitude_rad", amplitude_rad)
    freq_centre_hz = _positive("freq_centre_hz", freq_centre_hz)
    freq_halfwidth_hz = _positive("freq_halfwidth_hz", freq_halfwidth_hz)
    truth_step = _positive("truth_step", truth_step)
    try:
        min_freq_separation_hz = float(min_freq_separation_hz)
    except (TypeError, ValueError):
        raise ValueError(
            f"min_freq_separation_hz must be a number >= 0, got {min_freq_separation_hz!r}"
        ) from None
    if not (math.isfinite(min_freq_separation_hz) and min_freq_separation_hz >= 0.0):
        raise ValueError(
            f"min_freq_separation_hz must be a finite number >= 0, got {min_freq_separation_hz!r}"
        )
    if freq_halfwidth_hz >= freq_centre_hz:
        raise ValueError(
            f"freq_halfwidth_hz={freq_halfwidth_hz} must be below freq_centre_hz={freq_centre_hz} "
            "so that every frequency is positive"
        )
    nyquist = fs_hz / 2.0
    if freq_centre_hz + freq_halfwidth_hz >= nyquist:
        raise ValueError(
            f"frequencies up to {freq_centre_hz + freq_halfwidth_hz} Hz reach the Nyquist "
            f"frequency {nyquist} Hz of fs_hz={fs_hz}"
        )
    n_samples = int(round(duration_s * fs_hz))
    if n_samples < 2:
        raise ValueError(f"duration_s * fs_hz = {duration_s * fs_hz} gives fewer than 2 samples")
    rng = np.random.default_rng(rng)

    n = centre.size
    freqs = _distinct_frequencies(rng, n, freq_centre_hz, freq_halfwidth_hz, min_freq_separation_hz)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=n)
    t = np.arange(n_samples) / fs_hz
    theta = sinusoid_motion(t, centre, amplitude_rad, freqs, phases)
    counts = np.floor(theta / truth_step + 0.5).astype(np.int64)

    log = pd.DataFrame({"t": t})
    for j, joint in enumerate(PHANTOM_JOINTS):
        log[f"{joint}_counts"] = counts[:, j]
    truth = {
        "freqs_hz": freqs.tolist(),
        "phases_rad": phases.tolist(),
        "centre_rad": centre.tolist(),
        "amplitude_rad": amplitude_rad,
        "truth_step": truth_step,
        "fs_hz": fs_hz,
        "duration_s": duration_s,
        "n_samples": n_samples,
        "joint_names": list(PHANTOM_JOINTS),
    }
    return log, truth


def fig6_configurations_deg() -> np.ndarray:
    """Centre configurations (deg) for a Fig. 6-like sweep of the Phantom Premium 1.5.

    The paper does not list its configurations; this grid is chosen so that each Cartesian
    coordinate's sensitivity to each joint changes across the sweep (for the Phantom,
    ``dx/dtheta1 = cos t1 (l1 cos t2 + l2 sin t3)``, ``dy/dtheta2 = l1 cos t2``,
    ``dy/dtheta3 = l2 sin t3``, ``dz/dtheta3 = l2 cos t1 cos t3``, ...), with every angle
    within +-45 deg:

    ====  =================  =====================================================
    row   (t1, t2, t3)       purpose
    ====  =================  =====================================================
    0     (0, 0, 0)          zero position (Fig. 7's configuration); J diagonal
    1     (30, 0, 0)         base yaw: theta1 and theta3 couple into both x and z
    2     (0, 30, 0)         shoulder: y loses theta2 gain, x/z pick up theta2
    3     (0, 0, 30)         elbow: y gains theta3 gain, z loses it
    4     (0, -30, -30)      arm folded: shorter reach, smaller theta1 gain
    5     (-30, 20, 20)      mixed, negative yaw
    6     (45, 45, 45)       corner of the grid: strongest coupling
    ====  =================  =====================================================

    Returns
    -------
    numpy.ndarray, shape (7, 3)
        Configurations in degrees, (0, 0, 0) first.
    """
    return np.array(
        [
            [0.0, 0.0, 0.0],
            [30.0, 0.0, 0.0],
            [0.0, 30.0, 0.0],
            [0.0, 0.0, 30.0],
            [0.0, -30.0, -30.0],
            [-30.0, 20.0, 20.0],
            [45.0, 45.0, 45.0],
        ]
    )
