"""Simulated logs of an extreme low-resolution encoder (Zhang & Gao): open loop and PID loop.

Defaults follow the Ros-Drill example of the paper: resolution 0.09 deg, stroke
``A12 = 0.31 deg`` peak to peak (the paper's ``A12 = A1 + A2 = 2 A``, Fig. 6), a few tens of
Hz. The default sample rate is 2 kHz (100 samples per 20 Hz period, like the ~1 kHz lab
logs of the project): the dwell half-widths of eq. (4) are resolved to ``1/(2 fs) = 0.25 ms``,
0.5 % of the period (about 1 % error in a single-cycle eq. 4 stroke, the regime where pooling
cycles pays), a PID loop at that rate is far faster than the motion, and a 20-cycle Bayesian
fit stays within seconds.

Both simulators return ``(df, params)`` where ``df`` has the float64 column ``t`` (s) and the
int64 column ``counts`` (coarse encoder, reading ``step * counts``), plus ``truth_counts``
(int64, a fine encoder with step ``truth_step`` and rounding) when ``truth_step`` is given;
``params`` holds every value needed to score an inference (SI units).

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal", Figs. 2, 5, 6.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.linalg import expm

from enclab.lrde import model

__all__ = ["ROS_DRILL_STEP", "ROS_DRILL_A12", "open_loop_log", "closed_loop_pid_log"]

ROS_DRILL_STEP = float(np.deg2rad(0.09))
ROS_DRILL_A12 = float(np.deg2rad(0.31))


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


def _check_positive(name, value) -> float:
    if not (np.isscalar(value) and np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite positive scalar, got {value!r}")
    return float(value)


def _check_offset_frac(offset_frac) -> float:
    if not (np.isscalar(offset_frac) and np.isfinite(offset_frac) and 0 <= offset_frac < 1):
        raise ValueError(f"offset_frac must lie in [0, 1), got {offset_frac!r}")
    return float(offset_frac)


def _time_base(f_hz, fs_hz, n_cycles) -> np.ndarray:
    n = int(np.floor(n_cycles * fs_hz / f_hz))
    if n < 2:
        raise ValueError(f"n_cycles * fs_hz / f_hz must give at least 2 samples, got {n}")
    return np.arange(n) / fs_hz


def _frame(t, counts, theta, truth_step) -> pd.DataFrame:
    df = pd.DataFrame({"t": t, "counts": counts.astype(np.int64)})
    if truth_step is not None:
        truth_step = _check_positive("truth_step", truth_step)
        df["truth_counts"] = np.floor(theta / truth_step + 0.5).astype(np.int64)
    return df


def open_loop_log(rng, step=ROS_DRILL_STEP, A12=ROS_DRILL_A12, bias=0.0, f_hz=20.0,
                  fs_hz=2000.0, n_cycles=20, offset_frac=None, noise_std=0.0,
                  truth_step=None, distortion=None):
    """A sinusoid ``theta = bias + A12/2 sin(2 pi f t + phase)`` read by the offset encoder.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the phase (uniform), the offset when ``offset_frac`` is None (``a ~ U(0, step)``,
        eq. 1b) and the position noise.
    step : float
        Encoder resolution ``Delta`` in rad.
    A12 : float
        Peak-to-peak stroke in rad (``2 A``, the paper's ``A1 + A2``).
    bias : float
        Bias ``b`` (the paper's ``A_{12-b}``) in rad.
    f_hz, fs_hz : float
        Motion frequency and sample rate in Hz.
    n_cycles : float
        Length of the log in motion periods.
    offset_frac : float or None
        Offset angle as a fraction of the step, ``a = offset_frac * step`` in ``[0, 1)``.
    noise_std : float
        Standard deviation (rad) of white Gaussian position noise added to ``theta`` before it
        is read (the jitter the Bayesian fit's ``sigma`` models).
    truth_step : float or None
        When given, a fine rounding encoder of this step also reads ``theta``
        (column ``truth_counts``).
    distortion : dict, optional
        Harmonic distortion of the motion, ``{k: (c_k, s_k)}`` (rad): adds
        ``c_k cos(k phi) + s_k sin(k phi)`` with ``phi = 2 pi f t + phase``.

    Returns
    -------
    df : pandas.DataFrame
        ``t`` (s), ``counts`` (int64) and optionally ``truth_counts`` (int64).
    params : dict
        ``step, A12, bias, f_hz, phase, fs_hz, offset_a, a_eq (= a + b), E_b
        (= a_eq - step/2, eq. 14), noise_std, truth_step, n_cycles``.
    """
    rng = _check_rng(rng)
    step = _check_positive("step", step)
    A12 = _check_positive("A12", A12)
    f_hz = _check_positive("f_hz", f_hz)
    fs_hz = _check_positive("fs_hz", fs_hz)
    n_cycles = _check_positive("n_cycles", n_cycles)
    if not (np.isscalar(bias) and np.isfinite(bias)):
        raise ValueError(f"bias must be a finite scalar (rad), got {bias!r}")
    if not (np.isscalar(noise_std) and np.isfinite(noise_std) and noise_std >= 0):
        raise ValueError(f"noise_std must be a finite non-negative scalar, got {noise_std!r}")
    frac = rng.uniform(0.0, 1.0) if offset_frac is None else _check_offset_frac(offset_frac)
    a = frac * step
    phase = float(rng.uniform(-np.pi, np.pi))
    t = _time_base(f_hz, fs_hz, n_cycles)
    theta = model.sinusoid(t, A12, bias, f_hz, phase)
    for k, (c_k, s_k) in (distortion or {}).items():
        phi = k * (2.0 * np.pi * f_hz * t + phase)
        theta = theta + c_k * np.cos(phi) + s_k * np.sin(phi)
    if noise_std > 0:
        theta = theta + rng.normal(0.0, noise_std, t.size)
    counts = model.encoder_counts(theta, step, a)
    params = {"step": step, "A12": A12, "bias": float(bias), "f_hz": f_hz, "phase": phase,
              "fs_hz": fs_hz, "offset_a": a, "a_eq": a + bias, "E_b": a + bias - 0.5 * step,
              "noise_std": float(noise_std), "truth_step": truth_step,
              "n_cycles": n_cycles, "distortion": dict(distortion or {})}
    return _frame(t, counts, theta, truth_step), params


def _plant_matrices(tau, gain, dt):
    """Exact zero-order-hold discretisation of ``tau theta'' + theta' = gain u``."""
    a_cont = np.array([[0.0, 1.0], [0.0, -1.0 / tau]])
    b_cont = np.array([[0.0], [gain / tau]])
    block = np.zeros((3, 3))
    block[:2, :2] = a_cont * dt
    block[:2, 2:] = b_cont * dt
    e = expm(block)
    return e[:2, :2], e[:2, 2]


def closed_loop_pid_log(rng, step=ROS_DRILL_STEP, amplitude=float(np.deg2rad(0.145)),
                        f_hz=20.0, fs_hz=2000.0, n_cycles=60, offset_frac=None, kp=800.0,
                        ki=3000.0, kd=0.0, tau=0.002, gain=1.0,
                        disturbance=float(np.deg2rad(2.0)),
                        noise_std=0.0, truth_step=None, dead_band=0.0, missed_count=None):
    """PID servo tracking ``amplitude sin(2 pi f t)`` with the coarse encoder in the loop.

    The loop of paper 002 Fig. 5: reference ``theta_d``, error ``e = theta_d - reading`` with
    ``reading = step * counts``, PID ``u = kp e + ki int e + kd de/dt`` (derivative of the
    error by back difference) sampled at ``fs_hz`` with a zero-order hold, plant
    ``tau theta'' + theta' = gain (u + d)`` (a DC motor from voltage to angle) with a constant
    input disturbance ``d`` that the integrator must cancel (friction, gravity), so the
    motion's bias is set by the loop, not by the initial state. The shaft starts at rest at
    ``theta = 0``.

    Default tuning (found by simulation): crossover near 100 Hz, well above the 20 Hz
    reference, so at 2 kHz the stroke settles near 3.5 steps (about 0.315 deg, the paper's
    Fig. 6 has 0.31 deg) with a 0.145 deg reference amplitude; the small ``ki`` makes the bias
    wander slowly about the ideal bias instead of locking to it. The loop chatters by one
    count near reading changes (2-3 runs at the top reading per cycle), as real
    coarse-feedback servos do.

    The integral action removes the DC component of the error; with a symmetric reference
    that is the DC component of the reading, which by Proposition 2 vanishes only at the
    ideal bias: the bias oscillates about ``(step - 2a)/2`` within Proposition 1's band
    ``+- epsilon/2`` while the readings stay ``2n`` steps peak to peak (Fig. 6).

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the offset (when ``offset_frac`` is None) and the position noise.
    step : float
        Encoder resolution in rad.
    amplitude : float
        Reference amplitude in rad (reference stroke ``2 amplitude``).
    f_hz, fs_hz : float
        Reference frequency and loop/sample rate in Hz.
    n_cycles : float
        Log length in reference periods.
    offset_frac : float or None
        Encoder offset as a fraction of the step; ``a ~ U(0, step)`` when None.
    kp, ki, kd : float
        PID gains (per rad of error; ``ki`` per s, ``kd`` in s).
    tau, gain : float
        Plant time constant (s) and velocity gain (rad/s per unit input).
    disturbance : float
        Constant input disturbance (same units as ``u``).
    noise_std : float
        Standard deviation (rad) of white position noise seen by the encoder only.
    truth_step : float or None
        Fine rounding encoder step for a ``truth_counts`` column.
    dead_band : float
        Width ``w`` (rad) of a dead band of the coarse encoder (the reading switches up
        ``w/2`` late and down ``w/2`` early, :func:`enclab.lrde.effects.simulate_counts`);
        the controller acts on that reading.
    missed_count : (int, int) or None
        ``(index, delta)``: the counter reads ``delta`` counts off from sample ``index`` on
        (a missed or extra count); the controller acts on that reading, so the motion's bias
        moves by ``-delta`` steps and the readings stay where they were.

    Returns
    -------
    df : pandas.DataFrame
        ``t``, ``counts`` (int64), ``reference`` (float64, rad), ``theta`` (float64, rad, the
        simulated true angle) and optionally ``truth_counts``.
    params : dict
        ``step, offset_a, ideal_bias, f_hz, fs_hz, amplitude, kp, ki, kd, tau, gain,
        disturbance, noise_std, truth_step, n_cycles, dead_band, missed_count``.
    """
    rng = _check_rng(rng)
    step = _check_positive("step", step)
    amplitude = _check_positive("amplitude", amplitude)
    f_hz = _check_positive("f_hz", f_hz)
    fs_hz = _check_positive("fs_hz", fs_hz)
    n_cycles = _check_positive("n_cycles", n_cycles)
    tau = _check_positive("tau", tau)
    gain = _check_positive("gain", gain)
    for name, value in (("kp", kp), ("ki", ki), ("kd", kd)):
        if not (np.isscalar(value) and np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite non-negative scalar, got {value!r}")
    if not (np.isscalar(noise_std) and np.isfinite(noise_std) and noise_std >= 0):
        raise ValueError(f"noise_std must be a finite non-negative scalar, got {noise_std!r}")
    frac = rng.uniform(0.0, 1.0) if offset_frac is None else _check_offset_frac(offset_frac)
    a = frac * step
    dt = 1.0 / fs_hz
    t = _time_base(f_hz, fs_hz, n_cycles)
    reference = amplitude * np.sin(2.0 * np.pi * f_hz * t)
    noise = rng.normal(0.0, noise_std, t.size) if noise_std > 0 else np.zeros(t.size)
    phi, gam = _plant_matrices(tau, gain, dt)
    state = np.zeros(2)
    theta = np.empty(t.size)
    counts = np.empty(t.size, dtype=np.int64)
    if not (np.isscalar(dead_band) and np.isfinite(dead_band) and 0 <= dead_band < step):
        raise ValueError(f"dead_band must lie in [0, step), got {dead_band!r}")
    jump_at, jump_by = (t.size, 0) if missed_count is None else (int(missed_count[0]),
                                                                  int(missed_count[1]))
    half_w = 0.5 * dead_band / step
    integral = 0.0
    previous_error = 0.0
    state_count = None
    # The loop is inherently sequential (each command depends on the last reading).
    for j in range(t.size):
        theta[j] = state[0]
        x = (state[0] + noise[j] + a) / step
        if state_count is None or half_w == 0.0:
            state_count = int(np.floor(x))
        elif x >= state_count + 1.0 + half_w:
            state_count = int(np.floor(x - half_w))
        elif x < state_count - half_w:
            state_count = int(np.floor(x + half_w))
        counts[j] = state_count + (jump_by if j >= jump_at else 0)
        error = reference[j] - step * counts[j]
        integral += error * dt
        derivative = (error - previous_error) / dt if j > 0 else 0.0
        previous_error = error
        u = kp * error + ki * integral + kd * derivative + disturbance
        state = phi @ state + gam * u
    df = pd.DataFrame({"t": t, "counts": counts, "reference": reference, "theta": theta})
    if truth_step is not None:
        truth_step = _check_positive("truth_step", truth_step)
        df["truth_counts"] = np.floor(theta / truth_step + 0.5).astype(np.int64)
    params = {"step": step, "offset_a": a, "ideal_bias": 0.5 * (step - 2.0 * a),
              "f_hz": f_hz, "fs_hz": fs_hz, "amplitude": amplitude, "kp": float(kp),
              "ki": float(ki), "kd": float(kd), "tau": tau, "gain": gain,
              "disturbance": float(disturbance), "noise_std": float(noise_std),
              "truth_step": truth_step, "n_cycles": n_cycles, "dead_band": float(dead_band),
              "missed_count": None if missed_count is None else (jump_at, jump_by)}
    return df, params
