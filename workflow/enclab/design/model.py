"""The error model behind a design: per-joint noise terms and workspace weights.

Everything the search needs is split along the structure of the problem:

* **per joint, per candidate step, per filter** (no workspace): the variance of the filtered
  quantization error of one joint, from the exact model of a sampled sinusoid
  (:func:`enclab.propagation.theory.sinusoid_autocovariance`, averaged over the grid phase, and
  :func:`enclab.propagation.theory.sinusoid_run_autocovariance`, the worst grid phase of one run),
  and the PQN value ``step^2/12 ||h||_2^2``;
* **per workspace point, no step, no filter**: the Jacobian weights ``mean J_ji^2`` over the
  local motion (operational-space variance is linear in them: ``var_j = sum_i W_ji V_i``),
  the Hessian terms of the joint-space architecture, and the region bounds of ``|J|`` and
  ``|H|`` for the worst case (Taylor's theorem with the third-derivative bound, so the bound
  holds for every trajectory whose centre lies in a grid cell).

The search (:mod:`enclab.design.search`) combines them for every combination of steps; nothing
here depends on the combination.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from enclab.design.problem import DesignProblem
from enclab.propagation import filters as flt
from enclab.propagation import theory as th
from enclab.propagation.analysis import third_derivative_bound

__all__ = ["Candidate", "JointTerms", "WorkspaceTerms", "candidates", "joint_terms",
           "workspace_terms", "motion_phases"]

# Motion phases per workspace point at which the Jacobian weights are averaged.
_MOTION_SAMPLES = 64


@dataclass(frozen=True)
class Candidate:
    """A derivative estimator in one architecture (``filt`` None: the position, order 0)."""

    filt: flt.DerivativeFilter | None
    architecture: str | None

    @property
    def order(self) -> int:
        return 0 if self.filt is None else self.filt.d

    def label(self) -> str:
        return "position" if self.filt is None else f"{self.filt.label()}_{self.architecture}"


def candidates(problem: DesignProblem) -> list[Candidate]:
    """Position (order 0, when budgeted) and every filter of a budgeted derivative order in
    every architecture (the joint-space architecture for velocities only, as Colonnese & Okamura)."""
    orders = problem.orders
    out = [Candidate(None, None)] if 0 in orders else []
    for f in problem.filters:
        if f.d not in orders:
            continue
        for arch in problem.architectures:
            if arch == "joint" and f.d != 1:
                continue
            out.append(Candidate(f, arch))
    return out


@dataclass
class JointTerms:
    """Per joint ``i``, candidate step ``r`` and candidate ``k`` (:func:`candidates`).

    ``var`` (n, R, K): the design variance of joint i's filtered error (the worst grid phase
    or the grid-phase average, as ``problem.std_criterion`` says), worst frequency of the band;
    ``var_average`` the grid-phase average; ``var_pqn`` the PQN value; ``var0`` (n, R) the
    unfiltered error variance in the same sense (the joint architecture's ``c e`` term);
    ``l1`` (K,) the filters' l1 norms; ``lag`` (K,) their lags (s); ``phi_max`` (K, n) the
    amplitude of the joint filter's estimate of the motion (for the joint architecture).
    """

    var: np.ndarray
    var_average: np.ndarray
    var_pqn: np.ndarray
    var0: np.ndarray
    var0_average: np.ndarray
    l1: np.ndarray
    lag: np.ndarray
    phi_max: np.ndarray


def _impulses(cands, fs_hz):
    out = []
    for c in cands:
        out.append(np.array([1.0]) if c.filt is None else
                   flt.impulse_response(c.filt, fs_hz, tol=1e-12))
    return out


def _two_sided_matrix(cands, impulses):
    """(K, L+1) weights w with ``var = w @ C`` for an autocovariance C(0..L)."""
    r_hs = [th.impulse_autocorrelation(h) for h in impulses]
    max_lag = max(r.size for r in r_hs) - 1
    w = np.zeros((len(cands), max_lag + 1))
    for k, r in enumerate(r_hs):
        w[k, : r.size] = r
        w[k, 1 : r.size] *= 2.0
    return w


def _l1(c, h, fs_hz):
    return 1.0 if c.filt is None else flt.l1_norm(c.filt, fs_hz)


def joint_terms(problem: DesignProblem, cands: list[Candidate]) -> JointTerms:
    """Noise terms of every joint, step and candidate (see :class:`JointTerms`).

    For the sinusoid motion the autocovariances come in closed form (phase average) and from
    one FFT per grid phase (worst phase); motions that share amplitude and frequency share
    them. For a logged workspace the joint terms are trajectory averages computed in
    :func:`workspace_terms` instead (this function returns the PQN and filter terms only).
    """
    fs = problem.fs_hz
    impulses = _impulses(cands, fs)
    weights = _two_sided_matrix(cands, impulses)
    max_lag = weights.shape[1] - 1
    n, n_steps, n_cands = problem.n_joints, problem.steps.size, len(cands)
    h2 = np.array([float(np.sum(h**2)) for h in impulses])
    var_pqn = (problem.steps**2 / 12.0)[None, :, None] * h2[None, None, :] * np.ones((n, 1, 1))
    l1 = np.array([_l1(c, h, fs) for c, h in zip(cands, impulses)])
    lag = np.array([0.0 if c.filt is None else flt.lag_seconds(c.filt, fs) for c in cands])
    phi_max = np.zeros((n_cands, n))
    var = np.zeros((n, n_steps, n_cands))
    var_avg = np.zeros_like(var)
    var0 = np.zeros((n, n_steps))
    var0_avg = np.zeros_like(var0)
    if problem.motion is None:
        return JointTerms(var, var_avg, var_pqn, var0, var0_avg, l1, lag, phi_max)
    freqs = problem.motion.freqs()
    for k, c in enumerate(cands):
        if c.filt is not None and c.filt.d == 1:
            gain = np.abs(flt.frequency_response(c.filt, fs, freqs))
            phi_max[k] = problem.motion.amplitude * gain.max()
    phases = (np.arange(problem.phases) + 0.5) / problem.phases
    cache = {}
    for i in range(n):
        amp = float(problem.motion.amplitude[i])
        for r, step in enumerate(problem.steps):
            key = (amp, float(step))
            if key not in cache:
                model = th.QuantizerErrorModel(float(step), problem.offset_frac)
                best_avg = np.full(n_cands, -np.inf)
                best_run = np.full(n_cands, -np.inf)
                best0 = -np.inf
                for f in freqs:
                    c_avg = th.sinusoid_autocovariance(amp, f, fs, model, max_lag)
                    best_avg = np.maximum(best_avg, weights @ c_avg)
                    if problem.std_criterion == "worst_phase":
                        c_run, _ = th.sinusoid_run_autocovariance(amp, f, fs, model, max_lag, phases)
                        per_phase = c_run @ weights.T  # (phases, K)
                        best_run = np.maximum(best_run, per_phase.max(axis=0))
                        best0 = max(best0, float(c_run[:, 0].max()))
                if problem.std_criterion == "worst_phase":
                    cache[key] = (best_run, best_avg, best0, model.variance)
                else:
                    cache[key] = (best_avg, best_avg, model.variance, model.variance)
            var[i, r], var_avg[i, r], var0[i, r], var0_avg[i, r] = cache[key]
    return JointTerms(var, var_avg, var_pqn, var0, var0_avg, l1, lag, phi_max)


def motion_phases(n_joints: int, samples: int = _MOTION_SAMPLES, seed: int = 0) -> np.ndarray:
    """(P, n) motion phases ``psi`` at which a local motion ``c + A sin psi`` is averaged: a
    Latin hypercube (each joint's phases evenly spread, in independent random orders), so
    that every joint's motion is sampled uniformly over its cycle."""
    rng = np.random.default_rng(seed)
    cols = [(rng.permutation(samples) + 0.5) / samples for _ in range(n_joints)]
    return 2 * np.pi * np.stack(cols, axis=1)


@dataclass
class WorkspaceTerms:
    """Per workspace point ``g`` (grid centre or logged sample), output ``j``, joint ``i``.

    ``w2`` (G, m, n): ``mean J_ji^2`` over the local motion (exact-model weights);
    ``j0`` (G, m, n): ``|J_ji|`` at the centre (Table II and PQN);
    ``q`` (G, m, n, n, n): ``mean H_jil H_jil' cos psi_l cos psi_l'`` (joint architecture's
    ``c_ji = sum_l H_jil phi_l`` with ``phi_l = a_l cos psi_l``);
    ``j_hat`` (B, m, n), ``h_hat`` (B, m, n, n): bounds of ``|J|``, ``|H|`` over the cells
    of the bound grid (which cover the box); ``t3`` the third-derivative bound.
    For a logged workspace ``g`` runs over the log's samples, the exact terms are in
    ``traj_var`` (n, R, K, m) and ``traj_var0`` (n, R, m) (trajectory averages, Jacobian
    weighted) and the region is the sample itself.
    """

    w2: np.ndarray
    j0: np.ndarray
    q: np.ndarray
    j_hat: np.ndarray
    h_hat: np.ndarray
    t3: float
    traj_var: np.ndarray | None = None
    traj_var0: np.ndarray | None = None
    traj_cross: np.ndarray | None = None
    phi_abs: np.ndarray | None = None
    traj_var_average: np.ndarray | None = None
    traj_var0_average: np.ndarray | None = None


def workspace_terms(problem: DesignProblem, cands: list[Candidate] | None = None) -> WorkspaceTerms:
    """Jacobian/Hessian weights and region bounds at every workspace point.

    Box workspace: at each grid centre ``c`` the local motion ``c + A sin psi`` is sampled at
    :func:`motion_phases`; ``w2`` and ``q`` are its averages. The worst case covers the whole
    box: on the cell ``|theta_i - b_i| <= rho_i`` of each point ``b`` of
    :meth:`DesignProblem.bound_grid`,
    ``|J_ji| <= |J_ji(b)| + sum_l |H_jil(b)| rho_l + T (sum rho)^2/2`` and
    ``|H_jil| <= |H_jil(b)| + T sum rho`` (Taylor with the Lagrange remainder, ``T`` the
    third-derivative bound of :func:`enclab.propagation.analysis.third_derivative_bound`), so the worst
    case built from them holds at every sample of every trajectory inside the box.
    """
    device = problem.device
    t3 = third_derivative_bound(device)
    if problem.trajectory is not None:
        return _trajectory_terms(problem, cands, t3)
    centres = problem.centres()
    psi = motion_phases(problem.n_joints)
    amp = problem.motion.amplitude
    theta = centres[:, None, :] + amp * np.sin(psi)[None]          # (G, P, n)
    flat = theta.reshape(-1, problem.n_joints)
    J = device.jacobian(flat).reshape(centres.shape[0], psi.shape[0], device.n_outputs, -1)
    H = device.hessian(flat).reshape(centres.shape[0], psi.shape[0], device.n_outputs,
                                     problem.n_joints, problem.n_joints)
    w2 = np.mean(J**2, axis=1)
    cos = np.cos(psi)
    q = np.einsum("gpjil,gpjim,pl,pm->gjilm", H, H, cos, cos) / psi.shape[0]
    J0 = device.jacobian(centres)
    # Worst case: a grid over the whole box, each point standing for its cell (half-width rho).
    points, rho = problem.bound_grid()
    Jb, Hb = device.jacobian(points), device.hessian(points)
    s = float(np.sum(rho))
    j_hat = np.abs(Jb) + np.einsum("gjil,l->gji", np.abs(Hb), rho) + 0.5 * t3 * s * s
    h_hat = np.abs(Hb) + t3 * s
    return WorkspaceTerms(w2=w2, j0=np.abs(J0), q=q, j_hat=j_hat, h_hat=h_hat, t3=t3)


def _trajectory_terms(problem: DesignProblem, cands, t3) -> WorkspaceTerms:
    """Logged workspace: Jacobian-weighted trajectory averages of the exact model for every
    joint and candidate step (``var_j = sum_i traj_var[i, r_i, k, j]``), at each sample the
    bounds of the trajectory worst case."""
    device, fs = problem.device, problem.fs_hz
    theta = problem.trajectory
    n_samples, n = theta.shape
    J = device.jacobian(theta)
    H = device.hessian(theta)
    cands = cands or []
    impulses = _impulses(cands, fs) if cands else [np.array([1.0])]
    weights = _two_sided_matrix(cands, impulses) if cands else np.ones((1, 1))
    max_lag = weights.shape[1] - 1
    if max_lag >= n_samples:
        raise ValueError(f"the logged trajectory ({n_samples} samples) is shorter than the longest "
                         f"filter memory ({max_lag + 1} samples)")
    n_steps, m_out = problem.steps.size, device.n_outputs
    traj_var = np.zeros((n, n_steps, len(cands), m_out))
    traj_var0 = np.zeros((n, n_steps, m_out))
    traj_cross = np.zeros((n, n_steps, len(cands), m_out))
    # Joint architecture: c_ji = sum_l H_jil phi_l with phi the joint filter of the truth.
    joint_k = [k for k, c in enumerate(cands) if c.architecture == "joint"]
    cs = {k: np.einsum("kjil,kl->kji", H, flt.apply(cands[k].filt, theta, fs)) for k in joint_k}
    for r, step in enumerate(problem.steps):
        model = th.QuantizerErrorModel(float(step), problem.offset_frac)
        c_x = np.zeros((n, m_out, max_lag + 1))
        cross = np.zeros((n, len(cands), m_out))
        for m in range(max_lag + 1):
            G = model.autocovariance(theta[m:] - theta[: n_samples - m])      # (N-m, n)
            c_x[:, :, m] = np.einsum("kji,ki->ij", J[m:] * J[: n_samples - m], G) / (n_samples - m)
            for k in joint_k:
                h = impulses[k]
                if m < h.size:
                    cross[:, k] += h[m] * np.einsum("kji,ki->ij", J[m:] * cs[k][m:], G) / (n_samples - m)
        traj_var[:, r] = np.einsum("kl,ijl->ikj", weights, c_x)
        traj_var0[:, r] = np.mean(J**2, axis=0).T * model.variance
        for k in joint_k:
            c2 = np.mean(cs[k] ** 2, axis=0).T * model.variance               # (n, m)
            traj_cross[:, r, k] = 2.0 * cross[:, k] + c2
    traj_var_average, traj_var0_average = traj_var.copy(), traj_var0.copy()
    if problem.std_criterion == "worst_phase":
        factor, factor0 = _phase_factors(problem, cands)
        traj_var *= factor[..., None]
        traj_cross *= factor[..., None]
        traj_var0 *= factor0[..., None]
    phi_abs = np.zeros((len(cands), n))
    for k in joint_k:
        phi_abs[k] = np.abs(flt.apply(cands[k].filt, theta, fs)).max(axis=0)
    # Table II evaluates the Jacobian at the centre configuration (the mean of the motion).
    j0 = np.abs(device.jacobian(theta.mean(axis=0)))[None]
    return WorkspaceTerms(w2=J**2, j0=j0, q=np.zeros((1,)), j_hat=np.abs(J),
                          h_hat=np.abs(H), t3=t3, traj_var=traj_var, traj_var0=traj_var0,
                          traj_cross=traj_cross, phi_abs=phi_abs,
                          traj_var_average=traj_var_average, traj_var0_average=traj_var0_average)


def _phase_factors(problem: DesignProblem, cands) -> tuple[np.ndarray, np.ndarray]:
    """Largest over the grid phase / average over it, of one joint's (filtered) error variance
    on the logged trajectory: (n, R, K) and (n, R).

    The log is replayed shifted by ``problem.phases`` positions spread over one step and each
    joint's error filtered directly (brute force: for one trajectory the error at a given
    phase is deterministic). The Jacobian weighting changes little along a log, so the
    operational terms are scaled by these joint-space factors.
    """
    fs, theta = problem.fs_hz, problem.trajectory
    shifts = (np.arange(problem.phases) + 0.5) / problem.phases
    factor = np.ones((theta.shape[1], problem.steps.size, len(cands)))
    factor0 = np.ones((theta.shape[1], problem.steps.size))
    for i in range(theta.shape[1]):
        for r, step in enumerate(problem.steps):
            y = theta[:, i:i + 1] / step + shifts[None, :]
            err = step * (np.floor(y + problem.offset_frac) - y)              # (N, phases)
            v0 = err.var(axis=0)
            factor0[i, r] = v0.max() / v0.mean()
            for k, cand in enumerate(cands):
                if cand.filt is None:
                    factor[i, r, k] = factor0[i, r]
                    continue
                skip = min(flt.settle_samples(cand.filt, fs), theta.shape[0] - 2)
                v = flt.apply(cand.filt, err, fs, axis=0)[skip:].var(axis=0)
                factor[i, r, k] = v.max() / v.mean()
    return factor, factor0
