"""Derivative estimators of Colonnese & Okamura (Fig. 5) and their norms.

An input undergoes ``d`` back differences, scaled to physical units as
``(1 - z^-1)^d / T^d`` with ``T = 1/fs`` (so ``d = 1`` estimates velocity in rad/s or
m/s and ``d = 2`` acceleration), then ``n`` identical first-order low-pass stages
``w0 / (s + w0)`` with ``w0 = 2 pi fc`` and unit DC gain.

The paper does not say how the low-pass stage is discretized. Two choices are offered and
named, because they differ materially (the bilinear stage has a zero at Nyquist, which
removes about a third of the velocity noise standard deviation at the paper's 1 kHz /
50 Hz setting):

``"exponential"``
    Exponential smoothing, i.e. the matched pole ``exp(-w0 T)`` without a zero:
    ``y[k] = alpha x[k] + (1 - alpha) y[k-1]`` with ``alpha = 1 - exp(-w0 T)``.
``"bilinear"``
    Tustin's transform *without* frequency prewarping (the analog cutoff ``w0`` is used
    as is, so the digital -3 dB point lies slightly below ``fc``):
    ``K = w0 T / (2 + w0 T)``, ``b = [K, K]``, ``a = [1, (w0 T - 2) / (w0 T + 2)]``.

Every other quantity (state space, impulse response, norms, frequency response) is derived
from :func:`transfer_function`, so the theory always describes exactly the filter that
:func:`apply` ran.

References
----------
.. [1] M. Colonnese and A. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives", Fig. 5, Table II.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.special import gammaln

__all__ = [
    "DISCRETIZATIONS",
    "DerivativeFilter",
    "transfer_function",
    "apply",
    "impulse_response",
    "settle_samples",
    "state_space",
    "h2_norm_sq",
    "h2_norm_sq_closed_form",
    "l1_norm",
    "frequency_response",
    "lag_seconds",
]

DISCRETIZATIONS = ("exponential", "bilinear")
_SHORT = {"exponential": "exp", "bilinear": "bil"}
_MAX_D = 3
_DIFFERENCE = (np.array([1.0, -1.0]), np.array([1.0]))


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


@dataclass(frozen=True)
class DerivativeFilter:
    """A derivative estimator: ``d`` back differences, then ``n`` low-pass stages.

    Parameters
    ----------
    d : int
        Number of back differences (0 position, 1 velocity, 2 acceleration, 3 jerk).
    n : int
        Number of identical first-order low-pass stages, ``>= 1``.
    fc_hz : float
        Cutoff frequency of each stage in Hz (``w0 = 2 pi fc_hz``).
    discretization : {"exponential", "bilinear"}
        How each stage ``w0/(s + w0)`` is discretized (see the module docstring).
    """

    d: int
    n: int
    fc_hz: float
    discretization: str = "exponential"

    def __post_init__(self):
        if not _is_int(self.d) or not 0 <= self.d <= _MAX_D:
            raise ValueError(f"d must be an integer in 0..{_MAX_D} back differences, got d={self.d!r}")
        if not _is_int(self.n):
            raise ValueError(f"n must be an integer number of low-pass stages, got n={self.n!r}")
        if self.n < 1:
            raise ValueError(f"n must be >= 1 low-pass stages, got n={self.n!r}")
        if (
            not isinstance(self.fc_hz, numbers.Real)
            or isinstance(self.fc_hz, bool)
            or not math.isfinite(self.fc_hz)
            or self.fc_hz <= 0
        ):
            raise ValueError(f"fc_hz must be a finite positive number, got fc_hz={self.fc_hz!r}")
        if self.discretization not in DISCRETIZATIONS:
            raise ValueError(
                f"discretization must be one of {DISCRETIZATIONS}, got {self.discretization!r}"
            )
        # Normalise numpy scalars so that equality, hashing and JSON output are plain Python.
        object.__setattr__(self, "d", int(self.d))
        object.__setattr__(self, "n", int(self.n))
        object.__setattr__(self, "fc_hz", float(self.fc_hz))

    def to_dict(self) -> dict:
        """Return ``{"d", "n", "fc_hz", "discretization"}`` (the summary.json ``filter``)."""
        return {"d": self.d, "n": self.n, "fc_hz": self.fc_hz, "discretization": self.discretization}

    @classmethod
    def from_dict(cls, spec: dict) -> "DerivativeFilter":
        """Build a filter from a mapping with keys ``d``, ``n``, ``fc_hz`` and optionally
        ``discretization`` (default ``"exponential"``); unknown keys are rejected."""
        if not isinstance(spec, dict):
            raise ValueError(f"spec must be a dict, got {type(spec).__name__}")
        allowed = {"d", "n", "fc_hz", "discretization"}
        unknown = sorted(set(spec) - allowed)
        if unknown:
            raise ValueError(f"spec has unknown keys {unknown}; allowed are {sorted(allowed)}")
        missing = sorted({"d", "n", "fc_hz"} - set(spec))
        if missing:
            raise ValueError(f"spec is missing keys {missing}")
        return cls(**spec)

    def label(self) -> str:
        """Compact, file-name safe label, e.g. ``"d1_n2_fc12p5_exp"``.

        ``fc_hz`` is printed with the shortest representation that round-trips
        (``.`` -> ``p``, ``-`` -> ``m``), so :meth:`from_label` recovers the filter exactly.
        """
        fc = repr(self.fc_hz)
        if fc.endswith(".0"):
            fc = fc[:-2]
        fc = fc.replace("+", "").replace(".", "p").replace("-", "m")
        return f"d{self.d}_n{self.n}_fc{fc}_{_SHORT[self.discretization]}"

    @classmethod
    def from_label(cls, label: str) -> "DerivativeFilter":
        """Inverse of :meth:`label`."""
        parts = label.split("_") if isinstance(label, str) else []
        short_to_long = {v: k for k, v in _SHORT.items()}
        if (
            len(parts) != 4
            or not parts[0].startswith("d")
            or not parts[1].startswith("n")
            or not parts[2].startswith("fc")
            or parts[3] not in short_to_long
        ):
            raise ValueError(f"label must look like 'd1_n2_fc12p5_exp', got {label!r}")
        try:
            d, n = int(parts[0][1:]), int(parts[1][1:])
            fc = float(parts[2][2:].replace("p", ".").replace("m", "-"))
        except ValueError as exc:
            raise ValueError(f"label must look like 'd1_n2_fc12p5_exp', got {label!r}") from exc
        return cls(d=d, n=n, fc_hz=fc, discretization=short_to_long[parts[3]])


def _check_filter(filt) -> None:
    if not isinstance(filt, DerivativeFilter):
        raise ValueError(f"filt must be a DerivativeFilter, got {type(filt).__name__}")


def _check_fs(filt: DerivativeFilter, fs_hz) -> float:
    if isinstance(fs_hz, bool) or not isinstance(fs_hz, numbers.Real) or not math.isfinite(fs_hz) or fs_hz <= 0:
        raise ValueError(f"fs_hz must be a finite positive number, got fs_hz={fs_hz!r}")
    fs_hz = float(fs_hz)
    if filt.fc_hz >= fs_hz / 2:
        raise ValueError(
            f"cutoff fc_hz={filt.fc_hz!r} must be below the Nyquist frequency fs/2={fs_hz / 2!r}"
        )
    return fs_hz


def _stage(filt: DerivativeFilter, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """One low-pass stage (b, a) in powers of z^-1 whose stored coefficients have a DC gain
    of exactly 1 (``sum(b) == sum(a)`` in floating point).

    Of the pair (gain, pole) the one closer to 1 is computed from its formula and the other
    as its exact complement: for operands within a factor 2 of each other the subtraction
    is exact (Sterbenz), so no rounding breaks the unit DC gain.
    """
    w0T = 2.0 * math.pi * filt.fc_hz / fs_hz
    if filt.discretization == "exponential":
        if w0T <= math.log(2.0):
            pole = math.exp(-w0T)
            alpha = 1.0 - pole
        else:
            alpha = -math.expm1(-w0T)
            pole = 1.0 - alpha
        return np.array([alpha]), np.array([1.0, -pole])
    if w0T <= 2.0 / 3.0:
        pole = (2.0 - w0T) / (2.0 + w0T)
        twice_gain = 1.0 - pole
    else:
        twice_gain = 2.0 * w0T / (2.0 + w0T)
        pole = 1.0 - twice_gain
    gain = twice_gain / 2.0
    return np.array([gain, gain]), np.array([1.0, -pole])


def _pole(filt: DerivativeFilter, fs_hz: float) -> float:
    """The (n-fold repeated) pole of the low-pass cascade in the z-plane."""
    _, a_stage = _stage(filt, fs_hz)
    return -float(a_stage[1])


def _factors(filt: DerivativeFilter, fs_hz: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """First-order factors ``(b_i, a_i)`` in powers of ``z^-1`` whose product is
    ``H(z) T^d``: ``d`` unscaled back differences ``1 - z^-1``, then ``n`` low-pass stages.
    The ``1/T^d`` scale is applied once at the end, which keeps the state space balanced."""
    return [_DIFFERENCE] * filt.d + [_stage(filt, fs_hz)] * filt.n


def transfer_function(filt: DerivativeFilter, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator of ``H(z)`` as polynomials in ``z^-1``.

    ``H(z) = ((1 - z^-1)/T)^d * (b_stage(z)/a_stage(z))^n`` with ``T = 1/fs_hz``.

    Parameters
    ----------
    filt : DerivativeFilter
    fs_hz : float
        Sampling rate in Hz.

    Returns
    -------
    b, a : ndarray of float64
        Coefficients in increasing powers of ``z^-1``; ``a[0] == 1``.

    Raises
    ------
    ValueError
        If ``fc_hz >= fs_hz/2``.
    """
    _check_filter(filt)
    fs_hz = _check_fs(filt, fs_hz)
    b = np.array([1.0])
    a = np.array([1.0])
    for b_factor, a_factor in _factors(filt, fs_hz):
        b = np.convolve(b, b_factor)
        a = np.convolve(a, a_factor)
    return (b * fs_hz**filt.d).astype(np.float64), a.astype(np.float64)


def _state_length(b: np.ndarray, a: np.ndarray) -> int:
    return max(len(a), len(b)) - 1


def apply(filt: DerivativeFilter, x, fs_hz: float, axis: int = 0, zi=None, return_state: bool = False):
    """Filter ``x`` along ``axis`` with ``scipy.signal.lfilter``.

    Parameters
    ----------
    filt : DerivativeFilter
    x : array_like
        Real input (rad or m; integer counts are accepted and converted to float64).
    fs_hz : float
        Sampling rate in Hz.
    axis : int
        Time axis.
    zi : array_like, optional
        Filter state in the ``scipy.signal.lfilter`` convention (direct form II
        transposed), of shape ``x.shape`` with ``x.shape[axis]`` replaced by
        ``max(len(a), len(b)) - 1``. A 1-D state of that length is broadcast along the
        other axes. ``None`` starts from rest (zero state).
    return_state : bool
        Also return the final state, to continue filtering the next chunk of a long log;
        chunk-by-chunk filtering then equals whole-signal filtering.

    Returns
    -------
    y : ndarray of float64
    zf : ndarray of float64
        Final state, only when ``return_state`` is true.
    """
    b, a = transfer_function(filt, fs_hz)
    x = np.asarray(x)
    if x.ndim == 0:
        raise ValueError("x must have at least one dimension")
    if not (np.issubdtype(x.dtype, np.integer) or np.issubdtype(x.dtype, np.floating)):
        raise ValueError(f"x must be a real numeric array, got dtype {x.dtype}")
    x = x.astype(np.float64, copy=False)
    bad = np.flatnonzero(~np.isfinite(x.ravel()))
    if bad.size:
        idx = np.unravel_index(bad[0], x.shape)
        raise ValueError(f"x must be finite; first non-finite value at index {tuple(int(i) for i in idx)}")
    if not -x.ndim <= axis < x.ndim:
        raise ValueError(f"axis={axis} is out of range for x with {x.ndim} dimensions")
    axis = axis % x.ndim
    n_state = _state_length(b, a)
    state_shape = list(x.shape)
    state_shape[axis] = n_state
    state_shape = tuple(state_shape)
    if zi is None:
        zi = np.zeros(state_shape)
    else:
        zi = np.asarray(zi, dtype=np.float64)
        if zi.ndim == 1 and x.ndim > 1 and zi.shape[0] == n_state:
            along = [1] * x.ndim
            along[axis] = n_state
            zi = np.broadcast_to(zi.reshape(along), state_shape).copy()
        if zi.shape != state_shape:
            raise ValueError(f"zi must have shape {state_shape} (or ({n_state},)), got {zi.shape}")
    import scipy.signal  # deferred: ~0.6 s of import that ingest-only jobs need not pay

    y, zf = scipy.signal.lfilter(b, a, x, axis=axis, zi=zi)
    return (y, zf) if return_state else y


def _tail_envelope(b: np.ndarray, pole_radius: float, n: int, length: int) -> tuple[float, float]:
    """Envelope ``u`` and decay ratio ``q`` bounding the impulse response beyond ``length``.

    The cascade's impulse response is ``h = b * g`` with ``g_k = C(k+n-1, n-1) p^k`` (n-fold
    pole ``p``, ``|p| = pole_radius``). With ``u_k = sum_j |b_j| |g_{k-j}|`` we have
    ``|h_k| <= u_k``, and because ``|g_{m+1}/g_m| = rho (m+n)/(m+1) =: q_m`` decreases in
    ``m``, ``u_{k+1} <= q_{k-M} u_k`` (``M = len(b) - 1``). Hence for ``k >= N``:
    ``|h_k| <= u_N q^(k-N)`` with ``q = q_{N-M}``, giving the tail bounds
    ``sum_{k>=N} h_k^2 <= u_N^2 / (1 - q^2)`` and ``sum_{k>=N} |h_k| <= u_N / (1 - q)``.
    Returns ``(u_N, q)``; ``q >= 1`` means ``N`` is too short for the bound to apply.
    """
    m = len(b) - 1
    if pole_radius == 0.0:
        # No recursion left: h is the FIR numerator itself.
        return (0.0, 0.0) if length > m else (math.inf, math.inf)
    if length <= m:
        return math.inf, math.inf
    k = length - np.arange(m + 1)
    log_g = gammaln(k + n) - gammaln(n) - gammaln(k + 1) + k * math.log(pole_radius)
    nonzero = b != 0
    envelope = float(np.sum(np.abs(b[nonzero]) * np.exp(log_g[nonzero])))
    ratio = pole_radius * (length - m + n) / (length - m + 1)
    return envelope, ratio


def _impulse(b: np.ndarray, a: np.ndarray, length: int) -> np.ndarray:
    impulse = np.zeros(length)
    impulse[0] = 1.0
    import scipy.signal

    return scipy.signal.lfilter(b, a, impulse)


def _shortest_length(b, a, pole_radius, n, accept) -> int:
    """Smallest length on a geometric grid, starting from the one-pole estimate, for which
    ``accept(u_N, q)`` holds."""
    m = len(b) - 1
    length = m + 1
    if pole_radius > 0.0:
        length += max(1, math.ceil(math.log(1e-16) / math.log(pole_radius) / 2))
    while True:
        envelope, ratio = _tail_envelope(b, pole_radius, n, length)
        if ratio < 1.0 and accept(envelope, ratio):
            return length
        length = math.ceil(1.25 * length) + 1


def _check_tol(tol) -> float:
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not 0 < tol < 1:
        raise ValueError(f"tol must be a number in (0, 1), got tol={tol!r}")
    return float(tol)


def _reference_response(filt, fs_hz):
    """``(b, a, rho, h_ref)`` with ``h_ref`` a leading part of the impulse response; its
    energy, l1 norm and peak are lower bounds of the full response's, so criteria relative
    to them are conservative."""
    b, a = transfer_function(filt, fs_hz)
    rho = abs(_pole(filt, fs_hz))
    ref_len = _shortest_length(b, a, rho, filt.n, lambda u, q: True)
    return b, a, rho, _impulse(b, a, ref_len)


def impulse_response(filt: DerivativeFilter, fs_hz: float, n_samples: int | None = None, tol: float = 1e-14) -> np.ndarray:
    """Impulse response ``h_k`` of the filter (physical units, e.g. 1/s for velocity).

    Parameters
    ----------
    filt : DerivativeFilter
    fs_hz : float
    n_samples : int, optional
        Length. By default the shortest length (on a geometric grid) whose neglected tail
        energy is provably below ``tol`` times the total energy, from the envelope bound
        of the repeated pole (see ``_tail_envelope``); the bound is conservative, so the
        returned response is somewhat longer than strictly needed.
    tol : float
        Relative tail-energy tolerance in (0, 1).

    Returns
    -------
    h : ndarray of float64
    """
    if n_samples is not None:
        if not _is_int(n_samples) or n_samples < 1:
            raise ValueError(f"n_samples must be a positive integer, got n_samples={n_samples!r}")
        b, a = transfer_function(filt, fs_hz)
        return _impulse(b, a, int(n_samples))
    tol = _check_tol(tol)
    b, a, rho, h_ref = _reference_response(filt, fs_hz)
    energy = float(np.sum(h_ref**2))
    length = _shortest_length(b, a, rho, filt.n, lambda u, q: u * u / (1 - q * q) < tol * energy)
    return _impulse(b, a, length)


def settle_samples(filt: DerivativeFilter, fs_hz: float, tol: float = 1e-9) -> int:
    """Samples after which ``|h_k| < tol * max|h|`` for every later ``k``.

    Used to discard the start-up transient of a filtered log before computing moments.

    Parameters
    ----------
    filt : DerivativeFilter
    fs_hz : float
    tol : float
        Relative amplitude threshold in (0, 1).

    Returns
    -------
    int
        The smallest ``S`` with ``|h_k| < tol * max|h|`` for all ``k >= S`` (samples
        beyond the computed response are covered by the envelope bound).
    """
    tol = _check_tol(tol)
    b, a, rho, h_ref = _reference_response(filt, fs_hz)
    peak = float(np.max(np.abs(h_ref)))
    # u_N bounds |h_k| for every k >= N because the envelope decays (q < 1).
    length = _shortest_length(b, a, rho, filt.n, lambda u, q: u < tol * peak)
    h = _impulse(b, a, length)
    peak = float(np.max(np.abs(h)))
    above = np.flatnonzero(np.abs(h) >= tol * peak)
    return int(above[-1]) + 1


def _section_realization(b: np.ndarray, a: np.ndarray):
    """Controllable-canonical realization of one low-order section (padded ``tf2ss``)."""
    size = max(len(a), len(b))
    b_pad = np.concatenate([b, np.zeros(size - len(b))])
    a_pad = np.concatenate([a, np.zeros(size - len(a))])
    import scipy.signal

    return scipy.signal.tf2ss(b_pad, a_pad)


def state_space(filt: DerivativeFilter, fs_hz: float):
    """A discrete state-space realization ``(A, B, C, D)`` of :func:`transfer_function`.

    ``x[k+1] = A x[k] + B u[k]``, ``y[k] = C x[k] + D u[k]``.

    The realization is a series connection of low-order sections built from the same
    factors that :func:`transfer_function` multiplies out: the ``max(d - n, 0)`` unpaired
    back differences (FIR), then ``min(d, n)`` low-pass stages that each absorb one back
    difference (band-pass sections), then the remaining plain low-pass stages; the
    ``1/T^d`` scale sits in ``C`` and ``D`` only. Pairing a difference with a stage keeps
    every state's variance comparable to the output's, whereas a companion form of the
    expanded polynomial (or differences and stages kept apart) makes ``C P C^T`` a
    difference of large numbers: for ``d = 2, n = 3, fc/fs = 5e-4`` those lose 3 to 6
    digits of the H2 norm.

    Returns
    -------
    A : (m, m) ndarray
    B : (m, 1) ndarray
    C : (1, m) ndarray
    D : (1, 1) ndarray
    """
    _check_filter(filt)
    fs_hz = _check_fs(filt, fs_hz)
    b_diff, a_diff = _DIFFERENCE
    b_stage, a_stage = _stage(filt, fs_hz)
    paired = min(filt.d, filt.n)
    sections = (
        [(b_diff, a_diff)] * (filt.d - paired)
        + [(np.convolve(b_diff, b_stage), a_stage)] * paired
        + [(b_stage, a_stage)] * (filt.n - paired)
    )
    A = np.zeros((0, 0))
    B = np.zeros((0, 1))
    C = np.zeros((1, 0))
    D = np.ones((1, 1))
    for b_sec, a_sec in sections:
        A2, B2, C2, D2 = _section_realization(b_sec, a_sec)
        m, m2 = A.shape[0], A2.shape[0]
        A = np.block([[A, np.zeros((m, m2))], [B2 @ C, A2]])
        B = np.vstack([B, B2 @ D])
        C = np.hstack([D2 @ C, C2])
        D = D2 @ D
    scale = fs_hz**filt.d
    return A, B, C * scale, D * scale


def h2_norm_sq(filt: DerivativeFilter, fs_hz: float, method: str = "lyapunov") -> float:
    """Squared H2 norm ``sum_k h_k^2``: the PQN variance gain of Table II.

    A white input of variance ``s^2`` gives output variance ``h2_norm_sq * s^2``.

    Parameters
    ----------
    filt : DerivativeFilter
    fs_hz : float
    method : {"lyapunov", "impulse"}
        ``"lyapunov"``: ``C P C^T + D D^T`` with ``P`` the controllability Gramian from
        ``scipy.linalg.solve_discrete_lyapunov``. ``"impulse"``: the sum of squares of
        :func:`impulse_response` (relative truncation below 1e-14).

    Returns
    -------
    float
        In (physical unit / s^d)^2 per (input unit)^2.
    """
    if method == "lyapunov":
        A, B, C, D = state_space(filt, fs_hz)
        gramian = scipy.linalg.solve_discrete_lyapunov(A, B @ B.T)
        return float((C @ gramian @ C.T + D @ D.T)[0, 0])
    if method == "impulse":
        h = impulse_response(filt, fs_hz)
        return float(np.sum(h**2))
    raise ValueError(f"method must be 'lyapunov' or 'impulse', got method={method!r}")


def h2_norm_sq_closed_form(filt: DerivativeFilter, fs_hz: float) -> float:
    """Closed-form squared H2 norm of the first-difference, one-stage filter (d=1, n=1).

    Exponential (``alpha = 1 - exp(-w0 T)``): ``h_0 = alpha/T`` and
    ``h_k = -(alpha^2/T)(1-alpha)^(k-1)`` for ``k >= 1``, so
    ``||H||^2 = (alpha/T)^2 [1 + alpha^2 / (1 - (1-alpha)^2)] = (alpha/T)^2 * 2/(2 - alpha)``.

    Bilinear (``K = w0T/(2+w0T)``, pole ``beta = (2-w0T)/(2+w0T)``):
    ``H = (K/T) (1 - z^-2) / (1 - beta z^-1)``; the impulse response of
    ``(1 - z^-2)/(1 - beta z^-1)`` is ``1, beta, beta^k - beta^(k-2)`` (``k >= 2``), whose
    energy is ``1 + beta^2 + (1 - beta^2)^2 / (1 - beta^2) = 2``. Hence
    ``||H||^2 = 2 (K/T)^2``, independent of ``beta``.

    Raises
    ------
    ValueError
        Unless ``filt.d == 1`` and ``filt.n == 1``.
    """
    _check_filter(filt)
    if (filt.d, filt.n) != (1, 1):
        raise ValueError(f"closed form is only derived for d=1, n=1, got d={filt.d}, n={filt.n}")
    fs_hz = _check_fs(filt, fs_hz)
    # The stored stage coefficients (alpha or K), i.e. exactly the filter that is applied.
    b_stage, _ = _stage(filt, fs_hz)
    if filt.discretization == "exponential":
        alpha = float(b_stage[0])
        return (alpha * fs_hz) ** 2 * 2.0 / (2.0 - alpha)
    gain = float(b_stage[0])
    return 2.0 * (gain * fs_hz) ** 2


def l1_norm(filt: DerivativeFilter, fs_hz: float, tol: float = 1e-14) -> float:
    """``sum_k |h_k|``: the worst-case (l1) gain of Table II.

    The response is summed up to a length at which the envelope bound guarantees that the
    neglected tail is below ``tol`` times the returned sum.
    """
    tol = _check_tol(tol)
    b, a, rho, h_ref = _reference_response(filt, fs_hz)
    l1_ref = float(np.sum(np.abs(h_ref)))
    length = _shortest_length(b, a, rho, filt.n, lambda u, q: u / (1 - q) < tol * l1_ref)
    return float(np.sum(np.abs(_impulse(b, a, length))))


def frequency_response(filt: DerivativeFilter, fs_hz: float, freqs_hz) -> np.ndarray:
    """Complex frequency response ``H(exp(j 2 pi f / fs))`` at ``freqs_hz``.

    For ``d >= 1`` the magnitude tends to ``(2 pi f)^d`` at low frequency, as for a
    continuous-time differentiator.

    Returns
    -------
    ndarray of complex128, same shape as ``freqs_hz``.
    """
    b, a = transfer_function(filt, fs_hz)
    freqs = np.asarray(freqs_hz, dtype=np.float64)
    if not np.all(np.isfinite(freqs)):
        raise ValueError("freqs_hz must be finite")
    z_inv = np.exp(-2j * np.pi * freqs / fs_hz)
    return np.polynomial.polynomial.polyval(z_inv, b) / np.polynomial.polynomial.polyval(z_inv, a)


def lag_seconds(filt: DerivativeFilter, fs_hz: float) -> float:
    """Group delay at low frequency (s): the lag of the estimate behind the true derivative.

    Each back difference ``(1 - z^-1)/T`` delays by exactly half a sample at every frequency
    (``1 - e^{-jwT} = 2j sin(wT/2) e^{-jwT/2}``); a low-pass stage ``B(z)/A(z)`` with
    ``B(1), A(1) != 0`` has the DC group delay ``sum k b_k / sum b_k - sum k a_k / sum a_k``
    samples: ``p / (1 - p)`` for exponential smoothing with pole ``p`` and
    ``1/2 + p / (1 - p)`` for the bilinear stage. The cascade adds them:
    ``(d/2 + n tau_stage) / fs``.

    Parameters
    ----------
    filt : DerivativeFilter
    fs_hz : float

    Returns
    -------
    float
        Seconds; ``d/(2 fs) + n tau_stage / fs``. For ``fc << fs`` this tends to
        ``n / (2 pi fc)``, the analog stage's delay ``1/w0``.
    """
    _check_filter(filt)
    fs_hz = _check_fs(filt, fs_hz)
    b, a = _stage(filt, fs_hz)
    tau = float(np.dot(np.arange(b.size), b) / np.sum(b) - np.dot(np.arange(a.size), a) / np.sum(a))
    return (0.5 * filt.d + filt.n * tau) / fs_hz
