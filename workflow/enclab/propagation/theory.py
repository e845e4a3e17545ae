"""Propagation of encoder quantization error: Table II, an exact model, trajectory bounds.

Conventions
-----------
Quantizer: ``reading = step * floor((theta + a) / step)`` with ``a = offset_frac * step``
(``offset_frac = 0.5`` is rounding, the quantizer of Colonnese & Okamura). The error is
**measured - true**, ``e = reading - theta``, so ``e = a - step * frac((theta + a) / step)``
lies in ``(a - step, a]``. Operational space ``x = f(theta)``, ``x~ = f(theta^) - f(theta)``,
which is ``J e`` to first order. Derivative estimators are linear filters given by their
impulse response ``h`` (any units, e.g. 1/s for a velocity filter); every function here takes
plain arrays, so it describes exactly the filter that was applied (build ``h`` with
:func:`enclab.propagation.filters.impulse_response`).

Three layers
------------
1. **Table II** of the paper, re-derived (``worst_case_*``, ``pqn_*``). The printed paper has
   typos that are *not* reproduced here: eq. (1) defines the error as true - quantized while
   eq. (10) uses quantized - true (we use measured - true throughout; the sign does not affect
   any second moment); eq. (14) reads ``J theta^`` for ``J theta~``; eqs. (46) and (48)
   integrate over ``(-inf, inf)`` and drop the ``1/(2 pi)`` of eq. (44) (the discrete-time
   H2 inner product is ``(1/2pi) int_{-pi}^{pi} H_p^* H_q dw = sum_k h_p(k) h_q(k)`` by
   Parseval); eq. (47) has the index ``i`` for ``j``; Table II bounds ``phi~_i`` by
   ``|theta_i|max`` where ``|theta~_i|max`` is meant.
2. **Exact model** of the error of a quantized *sampled trajectory* (:class:`QuantizerErrorModel`
   and ``exact_*``; ``sinusoid_*`` for a sinusoid without samples). PQN assumes the error is
   white; at the paper's own conditions (1 kHz, 3 deg at 5 Hz, 1 mrad, i.e. at most ~1.6
   steps per sample) consecutive errors are correlated and PQN misses the derivative-noise
   standard deviation by about 1 % (exponential-smoothing filter) to 7 % (bilinear filter) at
   50 Hz. The model is the average over the sub-step position of the motion (its grid
   phase); pooled over runs whose centres cover one step it agrees with simulation to 0.02 %
   for every filter family (tests/test_theory.py resolves 0.3 %). One run of a
   constant-amplitude motion turns around at the same place on the grid in every cycle, so
   its own derivative noise departs from the average by up to a few percent (fast filters)
   to +-10 % (n = 3 at 25 Hz): :func:`sinusoid_run_autocovariance` gives it per grid phase.
3. **Trajectory worst case**: the centre-configuration bound ``1/2 |J(theta0)| step`` is
   exceeded when the Jacobian changes along the motion; ``worst_case_trajectory_*`` give
   bounds that hold at every sample (Taylor's theorem with an explicit remainder).

The exact model
---------------
The error is a periodic function ``g`` of the angle. When the motion sweeps many steps, the
phase ``theta(k) mod step`` is uniformly distributed given the increment
``delta = theta(k+m) - theta(k)``, so ``E[e(k) e(k+m)] = R_g(delta) =
(1/step) int_0^step g(u) g(u + delta) du``. For the continuous sawtooth the autocovariance is
``C(delta) = step^2 * B2(u) / 2 = step^2 (1/12 - u (1 - u) / 2)``, ``u = frac(delta/step)``,
``B2`` the second Bernoulli polynomial. When the truth is itself quantized with a fine step
``truth_step = step / r`` (integer ``r``) and the coarse reading is taken of the fine
reading, ``coarse = floor((k + offset_frac r) / r)`` for fine counts ``k``, the error is a
*discrete* sawtooth with ``r`` equally likely values ``(floor(c) - j) truth_step``,
``c = offset_frac r``, ``j = 0..r-1``: variance ``(step^2 - truth_step^2) / 12``, mean
``(floor(c) - (r - 1)/2) truth_step`` (the tie rule: ``+truth_step/2`` for rounding on both
grids), and circular autocovariance ``truth_step^2 ((r^2 - 1)/12 - j (r - j) / 2)`` for fine
increments ``delta = j truth_step`` (mod ``r``).

The trajectory-averaged autocovariance ``C_i(m) = mean_k C(theta_i(k+m) - theta_i(k))`` is
computed from the samples in ``O(N L)``; a filter ``h`` (length ``L``) then has output
variance ``sum_m r_h(m) C_i(m)`` (two-sided, ``r_h(m) = sum_l h_l h_{l+|m|}``). Joints move at
distinct frequencies and are treated as independent. In operational space the Jacobian
weights are kept inside the time average
(``C_xj(m) = mean_k sum_i J_ji(k) J_ji(k+m) C(theta_i(k+m) - theta_i(k))``), which is exact
for the filter-in-operational-space architecture up to edge effects. A non-zero error mean
(offset or tie rule) makes ``J(k) mean_e`` a slowly varying deterministic signal; its
filtered version is the exact mean, and its spread over the trajectory is added to the
variance, so ``exact_std`` is comparable with the standard deviation over the samples of a
log.

References
----------
.. [1] N. Colonnese and A. M. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives", Section III and Table II.
.. [2] B. Widrow and I. Kollar, *Quantization Noise*, Cambridge University Press, 2008
   (conditions for PQN; characteristic-function view of the quantization error).
.. [3] R. M. Gray, "Quantization noise spectra", IEEE Trans. Inf. Theory 36(6), 1990
   (the quantization error of a deterministic input as a periodic function of the input).
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from enclab.core.quantize import ratio_of

__all__ = [
    "QuantizerErrorModel",
    "impulse_autocorrelation",
    "worst_case_position",
    "worst_case_derivative",
    "worst_case_derivative_joint",
    "pqn_position_cov",
    "pqn_position_std",
    "pqn_derivative_std_joint",
    "pqn_derivative_cov_operational",
    "exact_joint_autocovariance",
    "exact_operational_autocovariance",
    "sinusoid_autocovariance",
    "sinusoid_run_autocovariance",
    "exact_std_joint",
    "exact_mean_joint",
    "exact_std_operational",
    "exact_mean_operational",
    "exact_std_joint_architecture",
    "exact_mean_joint_architecture",
    "worst_case_trajectory_position",
    "worst_case_trajectory_derivative",
    "worst_case_trajectory_derivative_joint",
]

# Increments of a quantized truth must be whole fine steps; float storage of
# counts * truth_step perturbs them by ~1e-16 * counts, far below this tolerance.
_GRID_TOL = 1e-6


def _positive_float(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite positive number, got {name}={value!r}")
    return float(value)


@dataclass(frozen=True)
class QuantizerErrorModel:
    """Exact statistics of the quantization error ``e = reading - true`` of one encoder.

    Parameters
    ----------
    step : float
        Quantization step of the measured channel (rad or m per count).
    offset_frac : float
        Quantizer offset as a fraction of ``step``, in ``[0, 1)``:
        ``reading = step * floor(theta / step + offset_frac)``; 0.5 is rounding.
    truth_step : float, optional
        Step of the truth channel when the truth is itself quantized and the measured reading
        is the coarse re-quantization of the fine reading,
        ``coarse_counts = floor((fine_counts + offset_frac * r) / r)`` with the integer ratio
        ``r = step / truth_step``; the error is then measured against the fine reading.
        ``None`` (default) means a continuous truth.

    Notes
    -----
    Continuous truth: ``e = a - step frac((theta + a)/step)`` in ``(a - step, a]``,
    ``a = offset_frac step``; mean ``a - step/2``, variance ``step^2/12``.

    Quantized truth: ``e / truth_step`` takes the ``r`` values ``floor(c) - j``,
    ``j = 0..r-1``, ``c = offset_frac r``, one per residue of the fine count mod ``r``: mean
    ``(floor(c) - (r-1)/2) truth_step``, variance ``(r^2 - 1) truth_step^2 / 12 =
    (step^2 - truth_step^2)/12``. With rounding on both grids and ``r = 8`` the values are
    ``{-3, ..., 4} truth_step`` and the mean is ``+truth_step/2``: a tie-rule bias that the
    continuous model does not have.

    The statistics are averages over the phase of the angle within one step; they describe a
    log when the motion sweeps many steps (see the module docstring).

    References
    ----------
    .. [1] Colonnese & Okamura, eqs. (2)-(9) (PQN: zero mean, variance step^2/12).
    """

    step: float
    offset_frac: float = 0.5
    truth_step: float | None = None

    def __post_init__(self):
        step = _positive_float("step", self.step)
        off = self.offset_frac
        if isinstance(off, bool) or not isinstance(off, numbers.Real) or not 0.0 <= off < 1.0:
            raise ValueError(f"offset_frac must be a number in [0, 1), got offset_frac={off!r}")
        object.__setattr__(self, "step", step)
        object.__setattr__(self, "offset_frac", float(off))
        if self.truth_step is not None:
            truth_step = _positive_float("truth_step", self.truth_step)
            ratio_of(step, truth_step)  # raises unless step is an integer multiple
            object.__setattr__(self, "truth_step", truth_step)

    @property
    def ratio(self) -> int | None:
        """``step / truth_step`` as an int, or ``None`` for a continuous truth."""
        return None if self.truth_step is None else round(self.step / self.truth_step)

    def levels(self) -> np.ndarray:
        """Error values ``e`` for fine counts ``k = 0..r-1`` (quantized truth only).

        Computed with the re-quantization formula itself,
        ``r floor((k + offset_frac r) / r) - k``, so the tie rule is exactly the one applied
        to the counts.
        """
        if self.truth_step is None:
            raise ValueError("levels() needs a quantized truth (truth_step is None)")
        r = self.ratio
        k = np.arange(r, dtype=np.float64)
        return (r * np.floor((k + self.offset_frac * r) / r) - k) * self.truth_step

    @property
    def mean(self) -> float:
        """Mean error (phase average)."""
        if self.truth_step is None:
            return (self.offset_frac - 0.5) * self.step
        return float(np.mean(self.levels()))

    @property
    def variance(self) -> float:
        """Error variance: ``step^2/12``, or ``(step^2 - truth_step^2)/12``."""
        if self.truth_step is None:
            return self.step**2 / 12.0
        return (self.ratio**2 - 1) * self.truth_step**2 / 12.0

    @property
    def std(self) -> float:
        """Error standard deviation."""
        return math.sqrt(self.variance)

    @property
    def bounds(self) -> tuple[float, float]:
        """``(lowest, highest)`` error: the supremum/infimum (continuous) or attained values."""
        if self.truth_step is None:
            a = self.offset_frac * self.step
            return a - self.step, a
        lv = self.levels()
        return float(lv.min()), float(lv.max())

    @property
    def max_abs(self) -> float:
        """``sup |e|``: ``step/2`` for rounding (with or without a quantized truth)."""
        lo, hi = self.bounds
        return max(abs(lo), abs(hi))

    def autocovariance(self, delta) -> np.ndarray:
        """Phase-averaged ``Cov(e(theta), e(theta + delta))`` (mean removed), vectorized.

        Parameters
        ----------
        delta : array_like
            Angle increments (same unit as ``step``). With a quantized truth they must be
            whole multiples of ``truth_step`` (increments of the fine reading).

        Returns
        -------
        ndarray, shape of ``delta``
            ``step^2 (1/12 - u(1-u)/2)`` with ``u = frac(delta/step)``, or for a quantized
            truth ``truth_step^2 ((r^2-1)/12 - j(r-j)/2)`` with ``j = delta/truth_step mod r``.
            Even and ``step``-periodic in ``delta``; equal to :attr:`variance` at 0.
        """
        delta = np.asarray(delta, dtype=np.float64)
        if self.truth_step is None:
            u = np.mod(delta / self.step, 1.0)
            return self.step**2 * (1.0 / 12.0 - 0.5 * u * (1.0 - u))
        fine = delta / self.truth_step
        whole = np.rint(fine)
        miss = np.abs(fine - whole)
        if miss.size and float(miss.max()) > _GRID_TOL:
            bad = float(delta.ravel()[np.flatnonzero(miss.ravel() > _GRID_TOL)[0]])
            raise ValueError(
                f"delta must be whole multiples of truth_step={self.truth_step!r} for a "
                f"quantized truth, got delta={bad!r}"
            )
        r = self.ratio
        j = np.mod(whole, r)
        return self.truth_step**2 * ((r * r - 1) / 12.0 - 0.5 * j * (r - j))


# ----------------------------------------------------------------------------- validation


def _impulse(h, name: str = "h") -> np.ndarray:
    h = np.asarray(h, dtype=np.float64)
    if h.ndim != 1 or h.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D impulse response, got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"{name} must be finite")
    return h


def _impulse_rows(h, rows: int, name: str = "h") -> np.ndarray:
    """``h`` as a ``(rows, L)`` array: one shared 1-D response or one row per coordinate."""
    h = np.asarray(h, dtype=np.float64)
    if h.ndim == 1:
        h = np.broadcast_to(_impulse(h, name), (rows, h.size))
    elif h.ndim != 2 or h.shape[0] != rows or h.shape[1] == 0:
        raise ValueError(f"{name} must have shape (L,) or ({rows}, L), got {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"{name} must be finite")
    return h


def _jacobian(J, name: str = "J") -> np.ndarray:
    J = np.asarray(J, dtype=np.float64)
    if J.ndim < 2:
        raise ValueError(f"{name} must have shape (..., m, n), got {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError(f"{name} must be finite")
    return J


def _per_joint(value, n: int, name: str, positive: bool = False) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)) if np.ndim(value) == 0 else np.asarray(value, dtype=np.float64)
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or (positive and np.any(arr == 0)):
        kind = "positive" if positive else "non-negative"
        raise ValueError(f"{name} must be finite and {kind}, got {arr.tolist()}")
    return arr


def _trajectory(theta, name: str = "theta") -> np.ndarray:
    theta = np.asarray(theta, dtype=np.float64)
    if theta.ndim == 1:
        theta = theta[:, None]
    if theta.ndim != 2 or theta.shape[0] < 2:
        raise ValueError(f"{name} must have shape (N,) or (N, n) with N >= 2, got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        row = int(np.flatnonzero(~np.all(np.isfinite(theta), axis=1))[0])
        raise ValueError(f"{name} must be finite; first non-finite sample at row {row}")
    return theta


def _models(models, n: int) -> list[QuantizerErrorModel]:
    if isinstance(models, QuantizerErrorModel):
        return [models] * n
    models = list(models) if isinstance(models, Sequence) else None
    if models is None or len(models) != n or not all(isinstance(m, QuantizerErrorModel) for m in models):
        raise ValueError(f"models must be a QuantizerErrorModel or a sequence of {n} of them")
    return models


def _samples_match(name: str, arr: np.ndarray, n_samples: int, tail: tuple) -> None:
    if arr.shape[0] != n_samples or arr.shape[1:] != tail:
        raise ValueError(f"{name} must have shape {(n_samples, *tail)}, got {arr.shape}")


# ----------------------------------------------------------------------------- Table II


def impulse_autocorrelation(h) -> np.ndarray:
    """``r_h(m) = sum_l h_l h_{l+m}`` for ``m = 0..L-1`` (one side; ``r_h(-m) = r_h(m)``).

    ``r_h(0)`` is the squared H2 norm (Parseval); the output variance of the filter for an
    input with autocovariance ``C`` is ``r_h(0) C(0) + 2 sum_{m>=1} r_h(m) C(m)``.
    """
    h = _impulse(h)
    import scipy.signal  # deferred, see enclab.propagation.filters.apply

    return scipy.signal.correlate(h, h, mode="full", method="direct")[h.size - 1 :]


def worst_case_position(J, max_abs_err) -> np.ndarray:
    """Table II worst case ``|x~| <= |J| |e|max`` (eq. 16; ``1/2 |J| step`` for rounding).

    Parameters
    ----------
    J : array_like, shape (..., m, n)
        Jacobian(s) at the configuration(s) of interest.
    max_abs_err : float or array_like, shape (n,)
        ``sup |e_i|`` per joint (:attr:`QuantizerErrorModel.max_abs`).

    Returns
    -------
    ndarray, shape (..., m)

    Notes
    -----
    First-order (affine) bound at the given configuration; it is exceeded when ``J``
    changes along the motion (see :func:`worst_case_trajectory_position`).
    """
    J = _jacobian(J)
    emax = _per_joint(max_abs_err, J.shape[-1], "max_abs_err")
    return np.abs(J) @ emax


def worst_case_derivative(h, max_abs_x) -> np.ndarray:
    """``|y~| <= ||H||_l1 |x~|max`` (eqs. 25-26): the l1 gain of the filter times the peak
    input error. Works for joint (``phi~``) and operational (``y~``) coordinates alike."""
    h = _impulse(h)
    x = np.asarray(max_abs_x, dtype=np.float64)
    if not np.all(np.isfinite(x)) or np.any(x < 0):
        raise ValueError("max_abs_x must be finite and non-negative")
    return float(np.sum(np.abs(h))) * x


def worst_case_derivative_joint(h, J, max_abs_err) -> np.ndarray:
    """Filter-in-joint-space worst case ``|y~_j| <= sum_i |J_ji| ||G||_l1 |e_i|max`` (eq. 27).

    Parameters
    ----------
    h : array_like, shape (L,) or (n, L)
        Joint filter impulse response(s) ``G_i``.
    J : array_like, shape (..., m, n)
    max_abs_err : float or array_like, shape (n,)

    Returns
    -------
    ndarray, shape (..., m)
    """
    J = _jacobian(J)
    n = J.shape[-1]
    hr = _impulse_rows(h, n)
    emax = _per_joint(max_abs_err, n, "max_abs_err")
    return np.abs(J) @ (np.sum(np.abs(hr), axis=1) * emax)


def pqn_position_cov(J, steps) -> np.ndarray:
    """PQN covariance ``Sigma_x = J diag(step_i^2/12) J^T`` (eq. 18).

    Parameters
    ----------
    J : array_like, shape (..., m, n)
    steps : float or array_like, shape (n,)

    Returns
    -------
    ndarray, shape (..., m, m)
    """
    J = _jacobian(J)
    steps = _per_joint(steps, J.shape[-1], "steps", positive=True)
    return np.einsum("...ji,i,...ki->...jk", J, steps**2 / 12.0, J)


def pqn_position_std(J, steps) -> np.ndarray:
    """Square root of the diagonal of :func:`pqn_position_cov`, shape (..., m)."""
    return np.sqrt(np.diagonal(pqn_position_cov(J, steps), axis1=-2, axis2=-1))


def pqn_derivative_std_joint(h, steps) -> np.ndarray:
    """PQN ``std(phi~_i) = ||G_i||_2 step_i / sqrt(12)`` (eq. 40).

    Parameters
    ----------
    h : array_like, shape (L,) or (n, L)
        Impulse response(s); ``||G||_2^2 = sum_k h_k^2``.
    steps : float or array_like, shape (n,)

    Returns
    -------
    ndarray, shape (n,)
    """
    h_arr = np.asarray(h)
    n = h_arr.shape[0] if h_arr.ndim == 2 else np.atleast_1d(np.asarray(steps)).shape[0]
    hr = _impulse_rows(h, n)
    steps = _per_joint(steps, n, "steps", positive=True)
    return np.sqrt(np.sum(hr**2, axis=1)) * steps / math.sqrt(12.0)


def pqn_derivative_cov_operational(h, J, steps, architecture: str = "operational") -> np.ndarray:
    """PQN covariance of the operational-space derivative error ``y~`` (Fig. 2 A or B).

    Parameters
    ----------
    h : array_like, shape (L,) or (rows, L)
        Impulse response(s): of the operational filters ``H_j`` (``rows = m``) for
        ``architecture="operational"``, of the joint filters ``G_i`` (``rows = n``) for
        ``"joint"``.
    J : array_like, shape (..., m, n)
    steps : float or array_like, shape (n,)
    architecture : {"operational", "joint"}

    Returns
    -------
    ndarray, shape (..., m, m)

    Notes
    -----
    Filter in operational space (corrected eqs. 46-49):
    ``Sigma_y(p, q) = <h_p, h_q> Sigma_x(p, q)`` with ``<h_p, h_q> = sum_k h_p(k) h_q(k)``
    and ``Sigma_x = J Sigma_theta J^T``; with one filter for all coordinates this is
    ``||H||_2^2 J Sigma_theta J^T``. Filter in joint space (eq. 41):
    ``Sigma_y = J diag(||G_i||_2^2 step_i^2/12) J^T``. With a shared filter the two coincide
    (to first order, PQN).
    """
    J = _jacobian(J)
    m, n = J.shape[-2:]
    if architecture == "operational":
        hr = _impulse_rows(h, m)
        gram = hr @ hr.T
        return gram * pqn_position_cov(J, steps)
    if architecture == "joint":
        hr = _impulse_rows(h, n)
        steps = _per_joint(steps, n, "steps", positive=True)
        var_phi = np.sum(hr**2, axis=1) * steps**2 / 12.0
        return np.einsum("...ji,i,...ki->...jk", J, var_phi, J)
    raise ValueError(f"architecture must be 'operational' or 'joint', got architecture={architecture!r}")


# ----------------------------------------------------------------------------- exact model


def _lagged_autocovariances(theta: np.ndarray, models: list[QuantizerErrorModel], max_lag: int):
    """Yield ``(m, G)`` for ``m = 0..max_lag`` with ``G[k, i] = C_i(theta_i(k+m) - theta_i(k))``,
    ``k = 0..N-1-m``: the phase-averaged error covariance of every sample pair at lag m."""
    n_samples, n = theta.shape
    if max_lag >= n_samples:
        raise ValueError(
            f"the trajectory ({n_samples} samples) must be longer than the filter memory "
            f"(max_lag={max_lag}); pass a longer theta or a shorter impulse response"
        )
    for m in range(max_lag + 1):
        delta = theta[m:] - theta[: n_samples - m]
        G = np.empty_like(delta)
        for i, model in enumerate(models):
            G[:, i] = model.autocovariance(delta[:, i])
        yield m, G


def _two_sided_sum(r_h: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``sum_{m=-(L-1)}^{L-1} r_h(|m|) c(|m|)`` along the last axis."""
    return r_h[0] * c[..., 0] + 2.0 * np.sum(r_h[1:] * c[..., 1:], axis=-1)


def exact_joint_autocovariance(theta, model: QuantizerErrorModel, max_lag: int) -> np.ndarray:
    """Trajectory-averaged autocovariance of a joint's quantization error.

    ``C(m) = mean_k model.autocovariance(theta(k+m) - theta(k))``, ``m = 0..max_lag``.

    Parameters
    ----------
    theta : array_like, shape (N,)
        True joint angle at each sample. With a quantized truth (``model.truth_step``), pass
        the truth channel's readings (their increments are whole fine steps).
    model : QuantizerErrorModel
    max_lag : int
        Largest lag ``L`` (samples), ``0 <= L < N``.

    Returns
    -------
    ndarray, shape (L + 1,)
    """
    theta = _trajectory(theta)
    if theta.shape[1] != 1:
        raise ValueError(f"theta must be 1-D (one joint), got shape {theta.shape}")
    if isinstance(max_lag, bool) or not isinstance(max_lag, numbers.Integral) or max_lag < 0:
        raise ValueError(f"max_lag must be a non-negative integer, got max_lag={max_lag!r}")
    models = _models(model, 1)
    out = np.empty(int(max_lag) + 1)
    for m, G in _lagged_autocovariances(theta, models, int(max_lag)):
        out[m] = G[:, 0].mean()
    return out


def exact_std_joint(theta, model: QuantizerErrorModel, h=None) -> float:
    """Exact standard deviation of a joint's error (``h=None``) or of its filtered error.

    Parameters
    ----------
    theta : array_like, shape (N,)
        True (or fine-quantized truth) joint angle samples.
    model : QuantizerErrorModel
    h : array_like, shape (L,), optional
        Impulse response of the derivative estimator ``G``.

    Returns
    -------
    float
        ``sqrt(sum_m r_h(m) C(m))`` (two-sided), or ``model.std`` for ``h=None``.
    """
    if h is None:
        _trajectory(theta)
        return _models(model, 1)[0].std
    r_h = impulse_autocorrelation(h)
    c = exact_joint_autocovariance(theta, model, r_h.size - 1)
    return math.sqrt(max(float(_two_sided_sum(r_h, c)), 0.0))


def exact_mean_joint(model: QuantizerErrorModel, h=None) -> float:
    """Exact mean of a joint's error (``model.mean``) or of ``h * e`` (``model.mean sum h``,
    zero for derivative filters)."""
    model = _models(model, 1)[0]
    return model.mean if h is None else model.mean * float(np.sum(_impulse(h)))


# ----------------------------------------------------------------------------- sinusoids


def _sinusoid_args(amplitude, freq_hz, fs_hz, max_lag):
    amplitude = _positive_float("amplitude", amplitude)
    freq_hz = _positive_float("freq_hz", freq_hz)
    fs_hz = _positive_float("fs_hz", fs_hz)
    if freq_hz >= fs_hz / 2:
        raise ValueError(f"freq_hz={freq_hz!r} must be below the Nyquist frequency fs_hz/2={fs_hz / 2!r}")
    if isinstance(max_lag, bool) or not isinstance(max_lag, numbers.Integral) or max_lag < 0:
        raise ValueError(f"max_lag must be a non-negative integer, got max_lag={max_lag!r}")
    return amplitude, freq_hz, fs_hz, int(max_lag)


def _arcsine_mean_b2(x: np.ndarray) -> np.ndarray:
    """``E[b(x cos psi)]`` for ``psi ~ U(0, 2 pi)``, ``b(y) = 1/12 - frac(y)(1 - frac(y))/2``.

    ``u = x cos psi`` has the arcsine density ``1/(pi sqrt(x^2 - u^2))`` on ``[-x, x]`` and
    ``b`` is even, so the mean is ``(2/pi) int_0^x b(u) / sqrt(x^2 - u^2) du``. On each unit
    band ``[k, k+1]`` ``b`` is the quadratic ``1/12 - (u-k)/2 + (u-k)^2/2`` and the integral
    is closed form with ``S0 = arcsin(u/x)``, ``S1 = -sqrt(x^2 - u^2)`` and
    ``S2 = x^2/2 S0 + u/2 S1``, the antiderivatives of ``u^p / sqrt(x^2 - u^2)``.
    """
    x = np.abs(np.asarray(x, dtype=np.float64))
    out = np.full(x.shape, 1.0 / 12.0)
    pos = x > 0
    if not np.any(pos):
        return out
    xv = x[pos]
    n_bands = int(np.ceil(xv.max()))
    k = np.arange(n_bands, dtype=np.float64)[None, :]
    lo = np.minimum(k, xv[:, None])
    hi = np.minimum(k + 1.0, xv[:, None])

    def antiderivatives(u):
        ratio = np.clip(u / xv[:, None], 0.0, 1.0)
        s0 = np.arcsin(ratio)
        s1 = -xv[:, None] * np.sqrt(np.maximum(1.0 - ratio * ratio, 0.0))
        s2 = 0.5 * xv[:, None] ** 2 * s0 + 0.5 * u * s1
        return s0, s1, s2

    a_lo, a_hi = antiderivatives(lo), antiderivatives(hi)
    d0, d1, d2 = (h_ - l_ for h_, l_ in zip(a_hi, a_lo))
    # Moments about the band's left end: int (u-k)^p du / sqrt(x^2 - u^2), p = 0, 1, 2.
    m0 = d0
    m1 = d1 - k * d0
    m2 = d2 - 2.0 * k * d1 + k * k * d0
    bands = m0 / 12.0 - 0.5 * m1 + 0.5 * m2
    out[pos] = (2.0 / np.pi) * np.sum(bands, axis=1)
    return out


def sinusoid_autocovariance(amplitude, freq_hz, fs_hz, model: QuantizerErrorModel, max_lag: int) -> np.ndarray:
    """Exact error autocovariance of a sampled sinusoid, averaged over its grid phase.

    The motion ``theta(k) = c + A sin(2 pi f k / fs + phi)`` read by a quantizer with a
    continuous truth: over a long run the motion phase at the samples is equidistributed, so
    the increment at lag ``m`` is ``a_m cos psi`` with ``psi`` uniform and
    ``a_m = 2 A |sin(pi f m / fs)|``, and (averaging over the sub-step position ``c mod step``
    as in :meth:`QuantizerErrorModel.autocovariance`)
    ``C(m) = step^2 E[b(a_m cos(psi) / step)]`` with ``b(y) = 1/12 - frac(y)(1-frac(y))/2``,
    evaluated in closed form band by band. It is what :func:`exact_joint_autocovariance`
    computes from the samples of a long run, without the samples.

    Parameters
    ----------
    amplitude : float
        ``A`` (rad or m), > 0.
    freq_hz, fs_hz : float
        Motion frequency and sample rate (Hz), ``0 < freq_hz < fs_hz / 2``.
    model : QuantizerErrorModel
        Continuous-truth model (``truth_step`` None); its offset does not enter a covariance.
    max_lag : int
        Largest lag ``L``.

    Returns
    -------
    ndarray, shape (L + 1,)

    Notes
    -----
    Equivalently ``C(m) = step^2/(2 pi^2) sum_k J0(2 pi k a_m / step) / k^2`` (the Fourier
    series of ``b`` and ``E cos(z cos psi) = J0(z)``; Gray 1990), which converges slowly; the
    band form is exact to rounding (about ``1e-16 x^2`` relative for ``x = a_m/step``).
    """
    amplitude, freq_hz, fs_hz, max_lag = _sinusoid_args(amplitude, freq_hz, fs_hz, max_lag)
    if not isinstance(model, QuantizerErrorModel) or model.truth_step is not None:
        raise ValueError("model must be a QuantizerErrorModel with a continuous truth (truth_step=None)")
    m = np.arange(max_lag + 1)
    a_m = 2.0 * amplitude * np.abs(np.sin(np.pi * freq_hz * m / fs_hz))
    return model.step**2 * _arcsine_mean_b2(a_m / model.step)


def sinusoid_run_autocovariance(amplitude, freq_hz, fs_hz, model: QuantizerErrorModel, max_lag: int,
                                centre_frac, points_per_step: int = 32):
    """Error autocovariance of *one* long run of a sampled sinusoid at a given grid phase.

    With a constant amplitude every cycle turns around at the same place on the grid, so the
    statistics of one run depend on the centre's position within a step, ``centre_frac =
    frac(c / step + offset_frac)``; :func:`sinusoid_autocovariance` is their average over
    ``centre_frac``. Over a long run the motion phase at the samples is equidistributed, so
    the run's error autocovariance (its own mean removed) is the circular autocovariance of
    the continuous-time error ``g(c + A sin psi)`` over one period, at shifts ``2 pi f m / fs``.

    Parameters
    ----------
    amplitude, freq_hz, fs_hz, model, max_lag
        As in :func:`sinusoid_autocovariance`.
    centre_frac : float or array_like
        Grid phase(s) in ``[0, 1)``.
    points_per_step : int
        Resolution of the period's quadrature grid in points per step at the fastest point of
        the motion (the error is piecewise linear with one jump per step; the quadrature's
        error falls like ``1/points_per_step``).

    Returns
    -------
    cov : ndarray, shape (..., L + 1)
        Per grid phase (leading shape of ``centre_frac``).
    mean : ndarray, shape (...)
        The run's mean error.

    Notes
    -----
    The period is sampled at ``M`` points (an FFT-friendly length) with ``M f / fs`` an
    integer ``s`` (the frequency is rounded to ``s fs / M``, a relative change below
    ``1/(2 M)``), so each lag is a whole shift of the grid and one FFT gives every lag. The largest variance over the grid
    phase, the quantity the design uses, is stable to 0.1 % from 32 points per step on.
    """
    amplitude, freq_hz, fs_hz, max_lag = _sinusoid_args(amplitude, freq_hz, fs_hz, max_lag)
    if not isinstance(model, QuantizerErrorModel) or model.truth_step is not None:
        raise ValueError("model must be a QuantizerErrorModel with a continuous truth (truth_step=None)")
    if isinstance(points_per_step, bool) or not isinstance(points_per_step, numbers.Integral) or points_per_step < 4:
        raise ValueError(f"points_per_step must be an integer >= 4, got {points_per_step!r}")
    frac = np.asarray(centre_frac, dtype=np.float64)
    if not np.all(np.isfinite(frac)) or np.any(frac < 0) or np.any(frac >= 1):
        raise ValueError("centre_frac must lie in [0, 1)")
    import scipy.fft  # deferred, as scipy.signal elsewhere

    target = max(points_per_step * 2.0 * np.pi * amplitude / model.step, 4.0 * fs_hz / freq_hz)
    first = max(1, int(np.ceil(target * freq_hz / fs_hz)))
    shift, n_points = first, int(round(first * fs_hz / freq_hz))
    for candidate in range(first, first + 256):  # an FFT-friendly length close to the target
        length = int(round(candidate * fs_hz / freq_hz))
        if scipy.fft.next_fast_len(length, real=True) == length:
            shift, n_points = candidate, length
            break
    swing = (amplitude / model.step) * np.sin(2.0 * np.pi * np.arange(n_points) / n_points)
    lags = (np.arange(max_lag + 1) * shift) % n_points
    flat = frac.ravel()
    cov = np.empty((flat.size, max_lag + 1))
    mean = np.empty(flat.size)
    per_block = max(1, 2_000_000 // n_points)  # bounded memory for long periods
    for start in range(0, flat.size, per_block):
        # Error of step*floor(theta/step + o) with theta/step = frac - o + (A/step) sin psi.
        y = (flat[start:start + per_block, None] - model.offset_frac) + swing
        err = model.step * (np.floor(y + model.offset_frac) - y)
        mean[start:start + per_block] = err.mean(axis=-1)
        err -= mean[start:start + per_block, None]
        spec = scipy.fft.rfft(err, axis=-1)
        circ = scipy.fft.irfft(spec.real**2 + spec.imag**2, n=n_points, axis=-1) / n_points
        cov[start:start + per_block] = circ[:, lags]
    return cov.reshape(frac.shape + (max_lag + 1,)), mean.reshape(frac.shape)


def _mean_signal_operational(J, models, H, h):
    """Deterministic part of ``x~`` (or ``h * x~``): ``J mean_e + 1/2 tr(H_j (Sigma + mu mu^T))``
    per sample, filtered with ``h`` in 'valid' mode (steady state)."""
    mu = np.array([mdl.mean for mdl in models])
    var = np.array([mdl.variance for mdl in models])
    signal = J @ mu
    if H is not None:
        second_moment = np.diag(var) + np.outer(mu, mu)
        signal = signal + 0.5 * np.einsum("kjil,il->kj", H, second_moment)
    if h is not None:
        h = _impulse(h)
        signal = np.stack(
            [np.convolve(signal[:, j], h, mode="valid") for j in range(signal.shape[1])], axis=1
        )
    return signal


def _check_operational(theta, J, models, H):
    theta = _trajectory(theta)
    n_samples, n = theta.shape
    J = _jacobian(J)
    if J.ndim != 3:
        raise ValueError(f"J must have shape (N, m, n), got {J.shape}")
    _samples_match("J", J, n_samples, (J.shape[1], n))
    models = _models(models, n)
    if H is not None:
        H = np.asarray(H, dtype=np.float64)
        _samples_match("H", H, n_samples, (J.shape[1], n, n))
        if not np.all(np.isfinite(H)):
            raise ValueError("H must be finite")
    return theta, J, models, H


def _operational_autocovariance(theta, J, models, max_lag):
    n_samples = theta.shape[0]
    c_x = np.empty((J.shape[1], max_lag + 1))
    for m, G in _lagged_autocovariances(theta, models, max_lag):
        c_x[:, m] = np.einsum("kji,ki->j", J[m:] * J[: n_samples - m], G) / (n_samples - m)
    return c_x


def exact_operational_autocovariance(theta, J, models, max_lag: int) -> np.ndarray:
    """Jacobian-weighted, trajectory-averaged error autocovariance in operational space.

    ``C_x,j(m) = mean_k sum_i J_ji(k) J_ji(k+m) C_i(theta_i(k+m) - theta_i(k))``, the input
    of every operational-space filter: a filter ``h`` has the output variance
    ``sum_m r_h(|m|) C_x(|m|)`` (see :func:`exact_std_operational`), so one call serves a
    whole filter bank.

    Parameters
    ----------
    theta : array_like, shape (N, n)
    J : array_like, shape (N, m, n)
    models : QuantizerErrorModel or sequence of n
    max_lag : int
        Largest lag, ``0 <= max_lag < N``.

    Returns
    -------
    ndarray, shape (m, max_lag + 1)
    """
    theta, J, models, _ = _check_operational(theta, J, models, None)
    if isinstance(max_lag, bool) or not isinstance(max_lag, numbers.Integral) or max_lag < 0:
        raise ValueError(f"max_lag must be a non-negative integer, got max_lag={max_lag!r}")
    return _operational_autocovariance(theta, J, models, int(max_lag))


def exact_std_operational(theta, J, models, h=None, H=None) -> np.ndarray:
    """Exact std of the operational-space error, filter in operational space (Fig. 2A).

    Parameters
    ----------
    theta : array_like, shape (N, n)
        True joint angles (or the fine-quantized truth readings for models with
        ``truth_step``).
    J : array_like, shape (N, m, n)
        Jacobian at every sample (at ``theta``).
    models : QuantizerErrorModel or sequence of n
        Error model per joint.
    h : array_like, shape (L,), optional
        Impulse response of the operational-space filter ``H`` (the same for all outputs);
        ``None`` gives the position error (order 0).
    H : array_like, shape (N, m, n, n), optional
        Hessians of the forward kinematics; adds the second-order mean
        ``1/2 tr(H_j (Sigma + mu mu^T))`` to the deterministic part.

    Returns
    -------
    ndarray, shape (m,)
        ``sqrt(sum_m r_h(m) C_x(m) + var_k(mean signal))`` with
        ``C_x,j(m) = mean_k sum_i J_ji(k) J_ji(k+m) C_i(theta_i(k+m) - theta_i(k))``.

    Notes
    -----
    Linearized in the error (``x~ = J e``), joints independent (distinct motion frequencies),
    phase average over ``theta mod step`` given the increment (module docstring). Edge
    effects (the first ``L`` samples of a filtered log) are ignored: discard the filter's
    start-up transient from the empirical statistics.
    """
    theta, J, models, H = _check_operational(theta, J, models, H)
    n_samples = theta.shape[0]
    if h is None:
        var = np.einsum("kji,i->j", J**2, np.array([mdl.variance for mdl in models])) / n_samples
    else:
        r_h = impulse_autocorrelation(h)
        var = _two_sided_sum(r_h, _operational_autocovariance(theta, J, models, r_h.size - 1))
    var = var + np.var(_mean_signal_operational(J, models, H, h), axis=0)
    return np.sqrt(np.maximum(var, 0.0))


def exact_mean_operational(J, models, h=None, H=None) -> np.ndarray:
    """Exact mean of the operational-space error (filter in operational space).

    ``mean_k J(k) mean_e`` (+ ``1/2 tr(H_j (Sigma + mu mu^T))`` when the Hessians ``H`` are
    given) for positions; its filtered version for derivatives (~0 for ``d >= 1``). With
    rounding and a quantized truth the tie-rule mean ``truth_step/2`` propagates as
    ``J 1 truth_step/2``.

    Parameters
    ----------
    J : array_like, shape (N, m, n)
    models : QuantizerErrorModel or sequence of n
    h : array_like, shape (L,), optional
    H : array_like, shape (N, m, n, n), optional

    Returns
    -------
    ndarray, shape (m,)
    """
    J = _jacobian(J)
    if J.ndim != 3:
        raise ValueError(f"J must have shape (N, m, n), got {J.shape}")
    n_samples, m_out, n = J.shape
    models = _models(models, n)
    if H is not None:
        H = np.asarray(H, dtype=np.float64)
        _samples_match("H", H, n_samples, (m_out, n, n))
    return np.mean(_mean_signal_operational(J, models, H, h), axis=0)


def _check_joint_architecture(theta, J, H, phi, models):
    theta, J, models, H = _check_operational(theta, J, models, H)
    if H is None:
        raise ValueError("H (Hessians, shape (N, m, n, n)) is required for the joint architecture")
    phi = np.asarray(phi, dtype=np.float64)
    _samples_match("phi", phi, theta.shape[0], (theta.shape[1],))
    if not np.all(np.isfinite(phi)):
        raise ValueError("phi must be finite")
    # c_ji = sum_l d J_jl / d theta_i phi_l: sensitivity of J(theta) phi to e_i.
    c = np.einsum("kjil,kl->kji", H, phi)
    return theta, J, models, c


def exact_std_joint_architecture(theta, J, H, phi, models, h) -> np.ndarray:
    """Exact std of the operational derivative error, filter in joint space (Fig. 2B).

    ``y~_j = J_j(theta^) phi^ - J_j(theta) phi ~= sum_i J_ji phi~_i + sum_i c_ji e_i`` with
    ``c_ji = sum_l (d^2 f_j / d theta_i d theta_l) phi_l``.

    Parameters
    ----------
    theta : array_like, shape (N, n)
        True (or fine-quantized truth) joint angles.
    J : array_like, shape (N, m, n)
    H : array_like, shape (N, m, n, n)
        Hessians of the forward kinematics at ``theta``.
    phi : array_like, shape (N, n), or (F, N, n) with a bank of F filters
        True joint derivative estimate, i.e. the joint filter applied to the truth.
    models : QuantizerErrorModel or sequence of n
    h : array_like, shape (L,), or a sequence of F such responses (a bank)
        Impulse response of the joint filter ``G`` (the same for every joint).

    Returns
    -------
    ndarray, shape (m,), or (F, m) for a bank (one pass over the lags serves every filter)

    Notes
    -----
    Per joint ``i`` (joints independent):
    ``sum_m r_h(m) mean_k[J_ji(k) J_ji(k+m) C_i(k, k+m)]
    + 2 mean_k[J_ji(k) c_ji(k) sum_l h_l C_i(k-l, k)] + mean_k[c_ji(k)^2] C_i(0)``,
    where ``C_i(k, k') = C(theta_i(k') - theta_i(k))``. The cross and ``c^2`` terms are exact
    sample by sample. In the first term the weight ``J(k)^2`` of the output sample is replaced
    by ``J(k-l) J(k-l')`` of the error pair, an error of relative order
    ``(dJ/dt * filter memory / J)^2`` (about 1e-4 at the paper's conditions); an exact weight
    would cost ``O(N L^2)``. The tie-rule mean adds ``var_k`` of the deterministic signal
    ``sum_i (J_ji sum(h) + c_ji) mean_i``.
    """
    bank = not (isinstance(h, np.ndarray) and h.ndim == 1) and isinstance(h, (Sequence, np.ndarray)) \
        and len(h) > 0 and np.ndim(h[0]) == 1
    hs = [_impulse(x) for x in h] if bank else [_impulse(h)]
    phis = np.asarray(phi, dtype=np.float64)
    if bank:
        if phis.ndim != 3 or phis.shape[0] != len(hs):
            raise ValueError(f"phi must have shape ({len(hs)}, N, n) for a bank of {len(hs)} filters, "
                             f"got {phis.shape}")
    else:
        phis = phis[None]
    checked = [_check_joint_architecture(theta, J, H, p, models) for p in phis]
    theta, J, models = checked[0][:3]
    cs = [chk[3] for chk in checked]
    n_samples = theta.shape[0]
    r_hs = [impulse_autocorrelation(x) for x in hs]
    max_lag = max(r.size for r in r_hs) - 1
    m_out = J.shape[1]
    filtered = np.empty((m_out, max_lag + 1))
    cross = np.zeros((len(hs), m_out))
    # h_f(m), zero beyond each response's length, and J_ji c_ji for every filter.
    weights = np.zeros((len(hs), max_lag + 1))
    for f, x in enumerate(hs):
        weights[f, : x.size] = x
    # J_ji c_ji laid out (F * m, N * n) so that the samples k >= m of every row are one
    # strided block: the cross term of every filter at lag m is one matrix-vector product.
    n = theta.shape[1]
    jc = np.ascontiguousarray(np.moveaxis(J[None] * np.array(cs), 1, 2)).reshape(
        len(hs) * m_out, n_samples * n)
    c0 = None
    for m, G in _lagged_autocovariances(theta, models, max_lag):
        filtered[:, m] = np.einsum("kji,ki->j", J[m:] * J[: n_samples - m], G) / (n_samples - m)
        # Pair (k-m, k): E[e(k-m) e(k)] enters phi~(k) with weight h_m, e(k) multiplies c(k).
        pairs = (jc[:, m * n:] @ G.ravel()).reshape(len(hs), m_out)
        cross += weights[:, m : m + 1] * pairs / (n_samples - m)
        if m == 0:
            c0 = np.einsum("fkji,ki->fj", np.array(cs) ** 2, G) / n_samples
    mu = np.array([mdl.mean for mdl in models])
    out = np.empty((len(hs), m_out))
    for f, (x, r_h, c) in enumerate(zip(hs, r_hs, cs)):
        var = _two_sided_sum(r_h, filtered[:, : r_h.size]) + 2.0 * cross[f] + c0[f]
        mean_signal = J @ (mu * float(np.sum(x))) + np.einsum("kji,i->kj", c, mu)
        out[f] = np.sqrt(np.maximum(var + np.var(mean_signal, axis=0), 0.0))
    return out if bank else out[0]


def exact_mean_joint_architecture(J, H, phi, models, h) -> np.ndarray:
    """Exact mean of the joint-architecture derivative error:
    ``mean_k sum_i (J_ji sum(h) + c_ji) mean_i`` (~0 for derivative filters).

    Shapes as in :func:`exact_std_joint_architecture`; returns shape (m,)."""
    J, H = _jacobians_and_hessians(J, H)
    n_samples, _, n = J.shape
    phi = np.asarray(phi, dtype=np.float64)
    _samples_match("phi", phi, n_samples, (n,))
    models = _models(models, n)
    mu = np.array([mdl.mean for mdl in models])
    c = np.einsum("kjil,kl->kji", H, phi)
    signal = J @ (mu * float(np.sum(_impulse(h)))) + np.einsum("kji,i->kj", c, mu)
    return np.mean(signal, axis=0)


# ----------------------------------------------------------------------------- trajectory bounds


def _jacobians_and_hessians(J, H):
    """Per-sample Jacobians (N, m, n) and Hessians (N, m, n, n), checked and as float arrays."""
    J = _jacobian(J)
    if J.ndim != 3:
        raise ValueError(f"J must have shape (N, m, n), got {J.shape}")
    n_samples, m_out, n = J.shape
    H = np.asarray(H, dtype=np.float64)
    _samples_match("H", H, n_samples, (m_out, n, n))
    if not np.all(np.isfinite(H)):
        raise ValueError("H must be finite")
    return J, H


def _check_bound_inputs(J, H, max_abs_err, third_derivative_bound):
    J, H = _jacobians_and_hessians(J, H)
    _, m_out, n = J.shape
    emax = _per_joint(max_abs_err, n, "max_abs_err")
    t3 = _per_joint(third_derivative_bound, m_out, "third_derivative_bound")
    return J, H, emax, t3


def worst_case_trajectory_position(J, H, max_abs_err, third_derivative_bound=0.0) -> np.ndarray:
    """Bound on ``|x~_j(k)| = |f_j(theta(k) + e) - f_j(theta(k))|`` at every sample.

    Parameters
    ----------
    J : array_like, shape (N, m, n)
        Jacobian at the true configuration of every sample.
    H : array_like, shape (N, m, n, n)
        Hessians of ``f`` at the same samples.
    max_abs_err : float or array_like, shape (n,)
        ``eps_i >= sup |e_i|`` (:attr:`QuantizerErrorModel.max_abs`).
    third_derivative_bound : float or array_like, shape (m,)
        ``T_j >= |d^3 f_j / d theta_i d theta_l d theta_p|`` for all ``i, l, p`` on the boxes
        ``theta(k) +- eps``.

    Returns
    -------
    ndarray, shape (N, m)
        ``B_j(k) = sum_i |J_ji| eps_i + 1/2 sum_il |H_j,il| eps_i eps_l + T_j (sum_i eps_i)^3 / 6``.
        The largest value over the trajectory is ``B.max(axis=0)``.

    Notes
    -----
    Rigour: Taylor's theorem with the Lagrange remainder at third order,
    ``f(theta + e) = f + J e + 1/2 e^T H e + R``, ``|R| <= T (sum |e_i|)^3 / 6``, makes the
    bound hold at every sample *provided* ``T`` is a valid third-derivative bound. For the
    position of any serial chain of revolute joints every partial derivative of any order is
    bounded by the sum of the link-vector lengths (each derivative turns a rotation ``R(q)``
    into ``R(q) [a]x`` of operator norm <= 1); for the Phantom Premium ``T = l1 + l2``. With
    the default ``T = 0`` the bound omits the third-order term, relatively
    ``O(|e|^2)`` ~ 1e-7 smaller than the first-order term at 1 mrad, and is then not
    rigorous. Unlike the centre-configuration bound ``1/2 |J(theta0)| step`` this uses the
    Jacobian where the robot actually is, which is what makes it hold over the motion.

    References
    ----------
    .. [1] Colonnese & Okamura, eq. (16) (the first-order, single-configuration bound).
    """
    J, H, emax, t3 = _check_bound_inputs(J, H, max_abs_err, third_derivative_bound)
    first = np.abs(J) @ emax
    second = 0.5 * np.einsum("kjil,i,l->kj", np.abs(H), emax, emax)
    third = t3 * float(np.sum(emax)) ** 3 / 6.0
    return first + second + third


def worst_case_trajectory_derivative(bound_x, h) -> np.ndarray:
    """Bound on the filtered error, filter in operational space: ``sum_l |h_l| B(k - l)``.

    Parameters
    ----------
    bound_x : array_like, shape (N,) or (N, m)
        Per-sample bound on the input error (e.g. :func:`worst_case_trajectory_position`).
    h : array_like, shape (L,)
        Impulse response of the filter.

    Returns
    -------
    ndarray, same shape as ``bound_x``

    Notes
    -----
    Samples before the start are given the bound of the first sample, which covers a filter
    started from rest (pre-start error 0) and one initialised in steady state at the first
    sample (pre-start error ``e(0)``). Rigorous given ``bound_x``: ``|sum h_l x~(k-l)| <=
    sum |h_l| |x~(k-l)|``. Its maximum is at most Table II's ``||H||_l1 max B``.
    """
    h = _impulse(h)
    bound = np.asarray(bound_x, dtype=np.float64)
    if bound.ndim not in (1, 2) or bound.shape[0] == 0:
        raise ValueError(f"bound_x must have shape (N,) or (N, m), got {bound.shape}")
    if not np.all(np.isfinite(bound)) or np.any(bound < 0):
        raise ValueError("bound_x must be finite and non-negative")
    padded = np.concatenate([np.repeat(bound[:1], h.size - 1, axis=0), bound], axis=0)
    import scipy.signal

    return scipy.signal.lfilter(np.abs(h), [1.0], padded, axis=0)[h.size - 1 :]


def worst_case_trajectory_derivative_joint(J, H, phi, h, max_abs_err, third_derivative_bound=0.0) -> np.ndarray:
    """Bound on ``|y~_j(k)|`` for the filter-in-joint-space architecture (Fig. 2B).

    ``y~ = J(theta^) phi~ + (J(theta^) - J(theta)) phi`` gives, with ``P_i = ||G||_l1 eps_i``
    (peak of ``|phi~_i|``), ``S = sum_i eps_i`` and ``c_jl = sum_i H_j,il phi_i``::

        B_j(k) = sum_i (|J_ji| + sum_l |H_j,il| eps_l + T_j S^2 / 2) P_i
                 + sum_l |c_jl| eps_l + T_j S^2 / 2 sum_i |phi_i|

    Parameters
    ----------
    J : array_like, shape (N, m, n)
    H : array_like, shape (N, m, n, n)
    phi : array_like, shape (N, n)
        True joint derivative estimate (the joint filter applied to the truth).
    h : array_like, shape (L,)
        Joint filter impulse response ``G``.
    max_abs_err : float or array_like, shape (n,)
    third_derivative_bound : float or array_like, shape (m,)
        As in :func:`worst_case_trajectory_position`; 0 drops the second-order remainders of
        ``J(theta^) - J(theta)`` (then not rigorous, see there).

    Returns
    -------
    ndarray, shape (N, m)

    Notes
    -----
    To first order this is Table II's eq. (27) evaluated along the motion plus the term
    ``|c| eps`` from the change of the Jacobian with the quantized angle, which eq. (27)
    omits. ``|phi~_i| <= ||G||_l1 eps_i`` holds for a filter started from rest or in steady
    state at the first sample.
    """
    J, H, emax, t3 = _check_bound_inputs(J, H, max_abs_err, third_derivative_bound)
    h = _impulse(h)
    phi = np.asarray(phi, dtype=np.float64)
    _samples_match("phi", phi, J.shape[0], (J.shape[2],))
    if not np.all(np.isfinite(phi)):
        raise ValueError("phi must be finite")
    peak_phi_err = float(np.sum(np.abs(h))) * emax
    s = float(np.sum(emax))
    remainder = 0.5 * t3 * s * s
    jac_hat = np.abs(J) + np.einsum("kjil,l->kji", np.abs(H), emax) + remainder[None, :, None]
    c = np.einsum("kjil,ki->kjl", H, phi)
    return (
        jac_hat @ peak_phi_err
        + np.abs(c) @ emax
        + remainder[None, :] * np.sum(np.abs(phi), axis=1)[:, None]
    )


def filtered_variance(r_h: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Variance of a stationary error through a linear filter, from their correlations.

    Parameters
    ----------
    r_h : numpy.ndarray
        The filter's impulse autocorrelation at lags ``0 .. L-1``
        (:func:`impulse_autocorrelation`).
    c : numpy.ndarray
        The error's autocovariance at lags ``0 .. L-1`` along the last axis (at least ``L``).

    Returns
    -------
    numpy.ndarray
        ``sum_{m=-(L-1)}^{L-1} r_h(|m|) c(|m|)`` along the last axis.
    """
    return _two_sided_sum(r_h, c)
