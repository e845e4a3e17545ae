"""Bayesian fit of a sinusoid to extreme low-resolution encoder counts (emcee).

Model
-----
``theta(t) = b + A12/2 sin(2 pi f (t - t_ref) + phase)`` plus white Gaussian position noise of
standard deviation ``sigma`` is read as ``count = floor((theta + noise + a) / step)``. Only
``a_eq = a + b`` enters (eq. 13b), so the sampled parameters are

- ``A12`` (rad), peak-to-peak stroke;
- ``E_b`` (rad), ``a_eq - (m + 1/2) step`` with ``m`` the modal centre count of the cycles
  (``m = 0`` for readings symmetric about 0, then this is eq. 14's ``E_b``);
- ``f_hz``; ``phase`` (rad, at ``t_ref``, the middle of the log, which decorrelates it from
  ``f``); ``sigma`` (rad, sampled as ``log10(sigma / step)``).

Harmonic distortion (``harmonics``) adds ``c_k cos(k phi) + s_k sin(k phi)``; the sampled
``A12`` is then twice the fundamental's amplitude, and the reported ``A12`` is the peak-to-peak
stroke of the whole motion, eq. (2)'s ``A1 + A2`` (the turning points the readings see).
``E_b`` and ``a_eq`` refer to the bias of eq. (2), the mean of the motion's turning points
(per sample: the sampled ``E_b`` column, about the motion's mean, plus the turning points'
midpoint about it), which is the mean for a sine and odd harmonics but not for even ones;
the truth channel's ``b`` is moved the same way, so ``a = a_eq - b`` does not change.

Likelihood
----------
Each reading is an interval: ``P(count = k) = Phi(u) - Phi(l)``, ``u = (k + 1 - z)/s``,
``l = (k - z)/s``, with ``z = (a_eq + A12/2 sin(.)) / step`` and ``s = sigma / step``. It is
evaluated as ``log_ndtr(u) + log1p(-exp(log_ndtr(l) - log_ndtr(u)))`` after reflecting
intervals that lie in the upper tail (``l > 0``: ``Phi(u) - Phi(l) = Phi(-l) - Phi(-u)``), so
both tails keep full relative precision. A bound beyond 8 standard deviations is dropped
(``Phi(-8) = 6.2e-16``): samples deep inside their interval contribute 0 and samples near one
edge cost one ``log_ndtr``, changing the log-likelihood by less than ``1.3e-15`` per sample.

Priors (uniform): ``A12`` in the step-count band ``((K - 1) step, (K + 1) step)`` of the modal
peak-to-peak count ``K`` (eq. 6 for ``K = 2n``), widened by the most that position noise (four
times the largest jitter), harmonics (their amplitudes) and a dead band (its largest width) can
move the readings' turning points; ``E_b`` in ``(-step, step)`` (the likelihood
itself confines it to Proposition 1's band); ``f`` within ``[0.8, 1.25]`` of the initial
estimate; ``phase`` in ``(-pi, pi]`` around the initial phase; ``sigma`` in
``(1e-4, 10**-0.5)`` steps (or ``sigma_range``), uniform in ``sigma`` by default. The
log-uniform (Jeffreys) alternative, ``sigma_prior="log-uniform"``, puts most of its mass on
jitter far below what the readings can resolve; when they show little jitter the posterior
then collapses onto a hard-edged model and the intervals of ``A12`` and ``E_b`` cover the
truth too rarely (workflow/benchmarks/bench_lrde.py: 84 % / 82 % at 20 cycles).

Cost
----
The log-likelihood is vectorised over walkers (``vectorize=True``) and over the independent
ensembles, which move side by side in one sampler (``_EnsemblesMove``: one call per
half-step for all of them, evaluated in cache-sized slices of walkers). On a uniform time
grid the sine comes from block-wise complex rotation instead of ``np.sin``, and only samples
within 8 standard deviations of an interval edge reach a special function
(workflow/benchmarks/bench_lrde_throughput.py measures both against ``np.sin`` and a
``log_ndtr`` of every sample): one ``erfc`` where a single edge is near, two where both are.
When most samples are near (a wide jitter, or the held-out comparison's time blur), all are
evaluated in place instead of being gathered and sorted by kind
(:func:`enclab.lrde.effects._log_interval_near`; workflow/benchmarks/bench_lrde_interval.py).
The effect models' likelihood
(:mod:`enclab.lrde.effects`) shares both, and takes the harmonics ``cos k phi, sin k phi``
as powers of the phase factor.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal", eqs. (4), (6), (13b), (14).
.. [2] D. Foreman-Mackey et al., "emcee: The MCMC Hammer", PASP 125 (2013) 306.
"""
from __future__ import annotations

import contextlib
import logging
import math
import time
from dataclasses import dataclass, field

import emcee
import numpy as np
from scipy.special import log_ndtr

from enclab.lrde import diagnostics, dwell, model
from enclab.lrde import effects as lrde_effects
from enclab.lrde import motion as lrde_motion
from enclab.lrde.model import _phasor_on_grid, _sine_on_grid, uniform_grid

__all__ = ["PARAM_NAMES", "FitResult", "log_likelihood", "log_probability", "initial_guess",
           "fit_sinusoid", "pool_fits", "truth_rounding_bound"]

_log = logging.getLogger(__name__)

PARAM_NAMES = ("A12", "E_b", "f_hz", "phase", "sigma")
_HARMONIC_BOUND = 0.5  # |c_k|, |s_k| < step / 2: distortion well below the stroke
_DISPERSION_CYCLES = 20.0  # log length (cycles) up to which the start dispersion is fixed


def param_names(harmonics=(), effects=()) -> tuple:
    """Names of the sampled parameters: :data:`PARAM_NAMES`, ``c_k, s_k`` per harmonic, then
    the effect parameters (:func:`enclab.lrde.effects.effect_param_names`)."""
    return (PARAM_NAMES + tuple(f"{x}{k}" for k in harmonics for x in ("c", "s"))
            + lrde_effects.effect_param_names(effects))


def _check_harmonics(harmonics) -> tuple:
    h = tuple(harmonics)
    if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 2 for k in h) \
            or len(set(h)) != len(h) or list(h) != sorted(h):
        raise ValueError(f"harmonics must be increasing distinct integers >= 2, got {harmonics!r}")
    return tuple(int(k) for k in h)
_DEEP = 8.0
_LOG_SIGMA_BOUNDS = (-4.0, -0.5)
_CACHE_ENTRIES = 65_536
_UNIDENTIFIED = ("readings identify only a_eq = a + b (Zhang & Gao eq. 13b); the offset a and "
                 "the bias b separate only with a truth channel or a known rest position")


def _log_interval_prob(lower, upper):
    """``log(Phi(upper) - Phi(lower))`` for ``lower < upper``, accurate in both tails.

    Where one bound is deep (``|bound| > 8``, ``Phi(-8) = 6.2e-16``) the other alone decides:
    ``log Phi(upper)`` or ``log Phi(-lower)``; this halves the special-function calls of a fit
    with small noise. The shortcut needs intervals at least a few standard deviations wide:
    for ``lower = b > 8`` it drops ``Phi(-upper) / Phi(-b) ~ exp(-b w - w^2 / 2)`` with
    ``w = upper - lower``, below ``1e-11`` for ``w >= 3``. The fit's intervals are
    ``1 / s >= 10**0.5 = 3.2`` wide (the jitter prior stops at ``s = 10**-0.5`` steps); narrower
    intervals need the exact difference.
    """
    out = np.zeros(np.broadcast(lower, upper).shape)
    lower_deep = lower < -_DEEP
    upper_deep = upper > _DEEP
    only_upper = lower_deep & ~upper_deep
    only_lower = upper_deep & ~lower_deep
    both = ~lower_deep & ~upper_deep
    out[only_upper] = log_ndtr(upper[only_upper])
    out[only_lower] = log_ndtr(-lower[only_lower])
    if np.any(both):
        lo, up = lower[both], upper[both]
        flip = lo > 0
        lo, up = np.where(flip, -up, lo), np.where(flip, -lo, up)
        log_up = log_ndtr(up)
        out[both] = log_up + np.log1p(-np.exp(log_ndtr(lo) - log_up))
    return out


def _motion_steps(p, t, t_ref, grid, harmonics):
    """``A/2 sin(phi) + sum_k (c_k cos(k phi) + s_k sin(k phi))`` in steps, rows of ``p``."""
    A, f, phase = p[:, 0:1], p[:, 2], p[:, 3]
    omega = 2.0 * np.pi * f
    if not harmonics:
        if grid is None:
            sine = np.multiply.outer(omega, t - t_ref)
            sine += phase[:, None]
            np.sin(sine, out=sine)
        else:
            sine = _sine_on_grid(omega, phase, grid, t_ref)
        sine *= 0.5 * A
        return sine
    if grid is None:
        phasor = np.exp(1j * (np.multiply.outer(omega, t - t_ref) + phase[:, None]))
    else:
        phasor = _phasor_on_grid(omega, phase, grid, t_ref)
    motion = 0.5 * A * phasor.imag
    power, order = phasor, 1
    for j, k in enumerate(harmonics):
        while order < k:
            power, order = power * phasor, order + 1
        motion += p[:, 5 + 2 * j:6 + 2 * j] * power.real + p[:, 6 + 2 * j:7 + 2 * j] * power.imag
    return motion


def log_likelihood(params, t, counts, step, centre_count, t_ref, grid=None, harmonics=(),
                   effects=(), prev_counts=None):
    """Log-likelihood of the counts for parameter rows in internal units.

    Parameters
    ----------
    params : numpy.ndarray, shape (n_walkers, 5) or (5,)
        Rows ``(A12 / step, E_b / step, f_hz, phase, log10(sigma / step))``.
    t : numpy.ndarray
        Sample times in s.
    counts : numpy.ndarray of int
        Coarse encoder counts.
    step : float
        Encoder resolution in rad.
    centre_count : float
        The ``m`` of ``a_eq = (m + 1/2 + E_b/step) step``.
    t_ref : float
        Time origin of the phase, s.
    grid : tuple, optional
        ``uniform_grid(t)`` when ``t`` is uniformly sampled (faster sine), else None.
    harmonics : tuple of int
        Orders ``k >= 2`` of harmonic distortion of the motion; each adds the columns
        ``c_k / step, s_k / step`` (after the five above) of ``c_k cos(k phi) + s_k sin(k phi)``
        with ``phi`` the fundamental's phase.
    effects : tuple of str
        Encoder and clock effects (:mod:`enclab.lrde.effects`); their parameters follow the
        harmonics' columns. With effects the general (slower) likelihood of that module is used.
    prev_counts : numpy.ndarray, optional
        The reading before each sample, for the dead band's state
        (:func:`enclab.lrde.effects.pointwise_log_likelihood`); needed when ``counts`` joins
        separate pieces of a log.

    Returns
    -------
    numpy.ndarray, shape (n_walkers,) (or float for a single row)
    """
    if effects:
        return lrde_effects.log_likelihood(params, t, counts, step, centre_count, t_ref,
                                           harmonics, effects, grid=grid,
                                           prev_counts=prev_counts)
    p = np.atleast_2d(params)
    eb, log_s = p[:, 1:2], p[:, 4:5]
    inv_s = 10.0 ** -log_s
    # lower = (k - z) / s with z = m + 1/2 + E_b + motion, built in place (memory-bound).
    lower = _motion_steps(p, t, t_ref, grid, harmonics)
    lower *= -1.0
    lower += counts
    lower -= centre_count + 0.5 + eb
    lower *= inv_s
    ll = _log_interval_prob_scaled(lower, inv_s)
    return ll if np.ndim(params) == 2 else float(ll[0])


def _log_interval_prob_scaled(lower, inv_s):
    """Row sums of ``log(Phi(lower + inv_s) - Phi(lower))`` (intervals of width ``1/s``).

    Entries with both bounds beyond ``_DEEP`` of 0 count as 0 (each is above ``-1.3e-15``),
    see :func:`enclab.lrde.effects._log_interval_near`.
    """
    return lrde_effects._log_interval_rows(lower, lower + inv_s)


def log_probability(params, t, counts, step, centre_count, t_ref, bounds, grid=None,
                    sigma_prior="log-uniform", harmonics=(), effects=(), prev_counts=None):
    """Log-posterior (uniform priors on ``bounds``, rows outside get ``-inf``); vectorised.

    ``sigma_prior`` is the prior of the jitter inside its bounds: ``"log-uniform"`` (flat in
    the sampled ``log10(sigma / step)``) or ``"uniform"`` (flat in ``sigma``: the Jacobian
    ``ln 10 * log10(sigma / step)`` is added).
    """
    p = np.atleast_2d(params)
    inside = np.all((p > bounds[:, 0]) & (p < bounds[:, 1]), axis=1)
    out = np.full(p.shape[0], -np.inf)
    if np.any(inside):
        rows = p[inside]
        # Rows in slices of about _CACHE_ENTRIES walker-samples: the intermediates of one
        # slice stay in the core's cache (64 walkers x 2000 samples in one piece cost twice
        # as much as two slices of 32).
        per_slice = max(1, _CACHE_ENTRIES // max(np.size(t), 1))
        out[inside] = np.concatenate([
            log_likelihood(rows[i:i + per_slice], t, counts, step, centre_count, t_ref, grid,
                           harmonics, effects, prev_counts)
            for i in range(0, rows.shape[0], per_slice)])
        if sigma_prior == "uniform":
            out[inside] += np.log(10.0) * p[inside, 4]
        elif sigma_prior != "log-uniform":
            raise ValueError(f"sigma_prior must be 'log-uniform' or 'uniform', got {sigma_prior!r}")
    return out if np.ndim(params) == 2 else float(out[0])


def _ls_phase(t, counts, f_hz, t_ref):
    """Phase of the least-squares sinusoid ``c + alpha sin + beta cos`` at frequency ``f``."""
    w = 2.0 * np.pi * f_hz * (t - t_ref)
    design = np.column_stack((np.ones_like(t), np.sin(w), np.cos(w)))
    coef, *_ = np.linalg.lstsq(design, counts.astype(float), rcond=None)
    return float(np.arctan2(coef[2], coef[1])), float(2.0 * np.hypot(coef[1], coef[2]))


def initial_guess(t, counts, step, f_hz=None) -> dict:
    """Starting point from the dwell baselines (eq. 4 averaged) and a least-squares phase.

    Returns
    -------
    dict
        ``A12, E_b, f_hz, phase, sigma`` (SI), ``centre_count``, ``steps_pp`` (modal
        peak-to-peak count), ``t_ref``, ``dwell`` (the :func:`enclab.lrde.dwell.dwell_summary`),
        ``cycles`` (the cycle table) and ``A12_ls`` (least-squares stroke of the readings).
    """
    table = dwell.cycle_table(counts, t, step, f_hz=f_hz)
    summary = dwell.dwell_summary(table)
    if len(table) == 0:
        raise ValueError("counts contain no complete oscillation cycle; cannot fit a sinusoid")
    pp = table["steps_pp"].to_numpy()
    steps_pp = int(np.bincount(pp).argmax())
    if steps_pp < 1:
        raise ValueError(f"the modal peak-to-peak step count is {steps_pp}; need >= 1")
    f0 = float(table["f_hz"].iloc[0])
    t_ref = 0.5 * (t[0] + t[-1])
    phase0, A12_ls = _ls_phase(t, counts, f0, t_ref)
    lo, hi = (steps_pp - 1) * step, (steps_pp + 1) * step
    if summary["n"] is not None and np.isfinite(summary["dwell_formula_A12"]):
        A12_0 = summary["dwell_formula_A12"]
        centre = float(summary["centre_count"])
        eb0 = summary["E_b_dwell"]
    else:
        A12_0 = A12_ls * step
        centre = float(np.floor(0.5 * (table["count_min"].median() + table["count_max"].median())))
        eb0 = 0.0
    A12_0 = float(np.clip(A12_0, lo + 0.02 * step, hi - 0.02 * step))
    half_eps = 0.5 * float(model.epsilon(A12_0, step))
    eb0 = float(np.clip(eb0, -0.9 * half_eps, 0.9 * half_eps)) if np.isfinite(eb0) else 0.0
    return {"A12": A12_0, "E_b": eb0, "f_hz": f0, "phase": phase0, "sigma": 0.03 * step,
            "centre_count": centre, "steps_pp": steps_pp, "t_ref": t_ref, "dwell": summary,
            "cycles": table, "A12_ls": A12_ls * step}


@dataclass
class FitResult:
    """Posterior of :func:`fit_sinusoid` (SI units: rad, Hz).

    Attributes
    ----------
    param_names : tuple of str
        ``("A12", "E_b", "f_hz", "phase", "sigma")``.
    samples : numpy.ndarray, shape (n_samples, 5)
        Pooled post-burn-in samples of all ensembles (columns as ``param_names``).
    chains : numpy.ndarray, shape (n_ensembles, n_steps, n_walkers, 5), or None
        The same, per ensemble and step (SI units); None for a pooled posterior
        (:func:`pool_fits`).
    a_eq_samples : numpy.ndarray
        ``a_eq = (centre_count + 1/2) step + E_b`` per sample, with ``E_b`` about the mean of
        the turning points (the sampled column plus their midpoint, see the module notes).
    summary : dict
        Per quantity (``A12, E_b, a_eq, f_hz, phase, sigma`` and, when identified,
        ``offset_a, bias_b``): ``{"median", "q05", "q95"}``.
    offset_a, bias_b : dict or None
        ``{"median", "q05", "q95"}`` when identified, else None.
    reason : str or None
        Why ``offset_a`` / ``bias_b`` are None (or how they were identified).
    tau, rhat, ess : dict
        Per parameter: the largest emcee integrated autocorrelation time over ensembles (in
        steps), split R-hat across ensembles
        (:func:`enclab.lrde.diagnostics.split_rhat_ensembles`) and ESS (total samples over
        ``tau``).
    converged : bool
        ``max R-hat <= 1.01`` and ``min ESS >= 1000``.
    b_samples : numpy.ndarray or None
        Draws of the bias ``b`` paired with ``a_eq_samples`` when it is identified (truth
        channel or rest position), else None.
    stroke_samples : numpy.ndarray or None
        Peak-to-peak stroke of the motion per sample when harmonics distort it
        (:func:`enclab.lrde.model.stroke_and_midpoint`), else None: the ``A12`` column, twice
        the fundamental's amplitude, is then the stroke itself.
    midpoint_samples : numpy.ndarray or None
        With harmonics, the midpoint of the motion's turning points about its mean per sample
        (what ``E_b`` and ``a_eq`` add to the sampled ``E_b`` column), else None.
    """

    param_names: tuple
    samples: np.ndarray
    chains: np.ndarray
    a_eq_samples: np.ndarray
    summary: dict
    offset_a: dict | None
    bias_b: dict | None
    reason: str | None
    tau: dict
    rhat: dict
    ess: dict
    converged: bool
    step: float
    centre_count: float
    steps_pp: int
    t_ref: float
    init: dict
    acceptance: float
    wall_time_s: float
    settings: dict = field(default_factory=dict)
    b_samples: np.ndarray | None = None
    stroke_samples: np.ndarray | None = None
    midpoint_samples: np.ndarray | None = None

    def take(self, rows) -> "FitResult":
        """The same posterior restricted to the sample rows ``rows`` (per-sample arrays alike;
        summary and diagnostics are the full posterior's)."""
        per_sample = {k: (None if v is None else v[rows])
                      for k, v in (("samples", self.samples), ("a_eq_samples", self.a_eq_samples),
                                   ("b_samples", self.b_samples),
                                   ("stroke_samples", self.stroke_samples),
                                   ("midpoint_samples", self.midpoint_samples))}
        return FitResult(**{**self.__dict__, **per_sample})

    @property
    def stroke(self) -> np.ndarray:
        """Peak-to-peak stroke per sample (eq. 2's ``A12 = A1 + A2``), rad."""
        return self.samples[:, 0] if self.stroke_samples is None else self.stroke_samples

    @property
    def harmonics(self) -> tuple:
        """Orders of the harmonic-distortion terms of the motion model (empty: a pure sine)."""
        return tuple(self.settings.get("harmonics", ()))

    @property
    def effects(self) -> tuple:
        """Encoder and clock effects of the reading model (:mod:`enclab.lrde.effects`)."""
        return tuple(self.settings.get("effects", ()))

    @property
    def label(self) -> str:
        """The model's label (:func:`enclab.lrde.effects.model_label`)."""
        return lrde_effects.model_label(self.harmonics, self.effects)

    def to_internal(self, si) -> np.ndarray:
        """SI sample rows in the internal units of :func:`log_likelihood`."""
        return _to_internal(np.asarray(si, dtype=float), self.step,
                            self.settings.get("extra_scale"))

    def motion(self, t, row) -> np.ndarray:
        """Motion about the bias, ``theta(t) - b``, in rad, for one SI sample row."""
        t = np.asarray(t, dtype=float)
        internal = self.to_internal(np.asarray(row, dtype=float)[None, :])
        drift_col = lrde_effects.parameter_column(self.harmonics, self.effects, "bends_phase")
        if drift_col is not None:
            motion, _ = lrde_effects._motion_and_speed(
                internal, t, self.t_ref, self.harmonics, drift_col)
            return self.step * motion[0]
        return self.step * _motion_steps(internal, t, self.t_ref, None, self.harmonics)[0]

    def simulate_counts(self, t, row, rng) -> np.ndarray:
        """Readings of the fitted model at one SI sample row (motion, noise and the reading
        effects; a marginalised count jump is not drawn)."""
        names = list(self.param_names)
        kw = {"A12": row[0], "a_eq": (self.centre_count + 0.5) * self.step + row[1],
              "f_hz": row[2], "phase": row[3], "t_ref": self.t_ref, "noise_std": row[4],
              "harmonics": {k: (row[names.index(f"c{k}")], row[names.index(f"s{k}")])
                            for k in self.harmonics}}
        for name in lrde_effects.effect_param_names(self.effects):
            kw[name] = row[names.index(name)]
        return lrde_effects.simulate_counts(rng, t, self.step, **kw)

    @property
    def medians(self) -> dict:
        return {k: v["median"] for k, v in self.summary.items()}

    @property
    def intervals(self) -> dict:
        """90 % central credible intervals ``(q05, q95)``."""
        return {k: (v["q05"], v["q95"]) for k, v in self.summary.items()}


@contextlib.contextmanager
def _quiet_emcee():
    """Silence emcee's "chain is shorter than 50 tau" log warning (we report tau and ESS)."""
    logger = logging.getLogger("emcee")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _quantiles(x) -> dict:
    q05, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
    return {"median": float(q50), "q05": float(q05), "q95": float(q95)}


def _to_si(internal, step, extra_scale=None):
    """Internal rows to SI; the columns after the fifth scale by ``extra_scale`` (default
    ``step``: harmonic coefficients)."""
    out = internal.copy()
    out[..., 0] *= step
    out[..., 1] *= step
    out[..., 4] = step * 10.0 ** internal[..., 4]
    out[..., 5:] *= step if extra_scale is None else np.asarray(extra_scale, dtype=float)
    return out


def _to_internal(si, step, extra_scale=None):
    out = np.array(si, dtype=float, copy=True)
    out[..., 0] /= step
    out[..., 1] /= step
    out[..., 4] = np.log10(si[..., 4] / step)
    out[..., 5:] /= step if extra_scale is None else np.asarray(extra_scale, dtype=float)
    return out


# No DESnookerMove: emcee 3.1.6 (the newest release) scales its direction by sqrt(|delta|)
# instead of |delta| (dfm/emcee#531, fixed after that release), and it does not sample its
# target: on a 3-D standard normal it gives variances of about 0.78.
_MOVES = {
    "de": lambda: [(emcee.moves.DEMove(), 1.0)],
    "stretch": lambda: [(emcee.moves.StretchMove(), 1.0)],
}


class _EnsemblesMove(emcee.moves.RedBlueMove):
    """An emcee red-blue move applied to several independent ensembles side by side.

    The sampler's walkers are ``n_groups`` blocks of equal size; each block is one ensemble.
    Every block is split, proposed (``inner.get_proposal`` with its complement taken from the
    same block only) and accepted with its own random state, so the blocks never exchange
    information and are independent chains for split R-hat; only the log-probability is
    evaluated for all blocks in one vectorised call. One call for four ensembles of 16
    walkers costs about a quarter of the four calls' Python overhead (emcee's proposal and
    bookkeeping and the log-probability wrapper took a third of a fit's time).

    Parameters
    ----------
    inner : emcee.moves.RedBlueMove
        The move each ensemble makes (its ``nsplits``, ``setup`` and ``get_proposal``).
    randoms : list of numpy.random.RandomState
        One per ensemble (emcee's moves draw from the ``RandomState`` interface).
    """

    def __init__(self, inner: emcee.moves.RedBlueMove, randoms: list) -> None:
        super().__init__(nsplits=inner.nsplits, randomize_split=True)
        self.inner, self.randoms = inner, randoms

    def propose(self, model, state):
        n_total, ndim = state.coords.shape
        n_groups = len(self.randoms)
        size = n_total // n_groups
        if size < 2 * ndim:
            # emcee's own check, per ensemble: fewer walkers stay on a subspace.
            raise RuntimeError(f"{size} walkers per ensemble are fewer than twice the "
                               f"{ndim} dimensions")
        self.inner.setup(state.coords)
        labels = []
        for random in self.randoms:
            split = np.arange(size) % self.nsplits
            random.shuffle(split)
            labels.append(split)
        labels = np.concatenate(labels)
        accepted = np.zeros(n_total, dtype=bool)
        for part in range(self.nsplits):
            subset = labels == part
            proposals, factors = [], []
            for g, random in enumerate(self.randoms):
                block = slice(g * size, (g + 1) * size)
                coords, split = state.coords[block], labels[block]
                sets = [coords[split == j] for j in range(self.nsplits)]
                q, f = self.inner.get_proposal(sets[part], sets[:part] + sets[part + 1:],
                                               random)
                proposals.append(q)
                factors.append(f)
            q = np.concatenate(proposals)
            new_log_probs, new_blobs = model.compute_log_prob_fn(q)
            log_u = np.concatenate([np.log(random.rand(int(np.count_nonzero(
                subset[g * size:(g + 1) * size])))) for g, random in enumerate(self.randoms)])
            lnpdiff = np.concatenate(factors) + new_log_probs - state.log_prob[subset]
            accepted[subset] = lnpdiff > log_u
            new_state = emcee.State(q, log_prob=new_log_probs, blobs=new_blobs)
            state = self.update(state, new_state, accepted, subset)
        return state, accepted


def _setup(t, counts, step, f_hz, sigma_range, sigma_prior, harmonics, effects,
           init=None) -> dict:
    """Names, prior bounds, starting point, start dispersion and likelihood arguments."""
    if sigma_range is None:
        log_sigma_bounds = _LOG_SIGMA_BOUNDS
    else:
        lo, hi = (float(v) for v in sigma_range)
        if not (0 < lo < hi <= 10.0 ** _LOG_SIGMA_BOUNDS[1]):
            raise ValueError(f"sigma_range must be (lo, hi) steps with 0 < lo < hi <= "
                             f"{10.0 ** _LOG_SIGMA_BOUNDS[1]:.3f} (jitter beyond a third of a step "
                             f"hides the readings' pattern), got {sigma_range!r}")
        log_sigma_bounds = (np.log10(lo), np.log10(hi))
    if sigma_prior not in ("uniform", "log-uniform"):
        raise ValueError(f"sigma_prior must be 'uniform' or 'log-uniform', got {sigma_prior!r}")
    harmonics = _check_harmonics(harmonics)
    effects = lrde_effects.check_effects(effects)
    names = param_names(harmonics, effects)
    if init is None:
        init = initial_guess(t, counts, step, f_hz=f_hz)
    K = init["steps_pp"]
    duration = t[-1] - t[0]
    dt = float(np.median(np.diff(t)))
    # Eq. (6): a noise-free sinusoid read over K steps peak to peak has A12 within one step
    # of K. Each term that moves where the readings turn widens that band by the most it can:
    # a dead band hides up to its width of the stroke; harmonics move the turning points by
    # up to their amplitudes; position noise reads a few sigma beyond them.
    reach = 2.0 * np.sqrt(2.0) * _HARMONIC_BOUND * len(harmonics)
    longer = reach + sum(e.stroke_reach for e in lrde_effects.active(effects))
    shorter = reach + 4.0 * 10.0 ** log_sigma_bounds[1]
    bounds = np.array([
        [max(K - 1.0 - shorter, 0.05), K + 1.0 + longer],
        [-1.0, 1.0],
        [0.8 * init["f_hz"], 1.25 * init["f_hz"]],
        [init["phase"] - np.pi, init["phase"] + np.pi],
        list(log_sigma_bounds),
    ] + [[-_HARMONIC_BOUND, _HARMONIC_BOUND]] * (2 * len(harmonics))
        + lrde_effects.effect_bounds(effects, duration, dt))
    if lrde_effects.offsets_counts(effects):
        # The modal centre count may be the shorter segment's: E_b of the longer one's frame
        # then lies a step further out.
        bounds[1] = [-2.0, 2.0]
    log_sigma0 = np.log10(init["sigma"] / step)
    if not log_sigma_bounds[0] < log_sigma0 < log_sigma_bounds[1]:
        log_sigma0 = 0.5 * (log_sigma_bounds[0] + log_sigma_bounds[1])
    sampled = [e for e in lrde_effects.active(effects) if e.sampled]
    # Posterior widths shrink as 1/sqrt(cycles), the frequency's also as 1/duration and the
    # drift's as 1/duration**2: the start dispersion follows (from 20 cycles on), so that the
    # walkers start inside the posterior. Started wider, a few walkers of a long log's narrow
    # posterior stay far out for the whole chain (R-hat 1.05 after 1000 steps at 100 cycles).
    ratio = min(1.0, _DISPERSION_CYCLES / max(duration * init["f_hz"], 1.0))
    shrink = np.sqrt(ratio)
    motion = lrde_motion.from_harmonics(harmonics)
    x0 = np.array([init["A12"] / step, init["E_b"] / step, init["f_hz"], init["phase"],
                   log_sigma0]
                  + list(motion.start(t, counts, init["centre_count"], init["f_hz"],
                                      init["phase"], init["t_ref"]))
                  + [e.start for e in sampled])
    # Dispersion of the start: a few tenths of the expected posterior widths, so that
    # independent ensembles start apart and R-hat can detect non-mixing.
    scale = shrink * np.array([0.005, 0.003, 0.002 / duration, 0.005, 0.05]
                              + [0.003] * (2 * len(harmonics)) + [e.start_spread(duration, ratio) for e in sampled])
    extra_scale = [step] * (2 * len(harmonics)) + lrde_effects.effect_scales(effects, step, dt)
    kwargs = {"t": t, "counts": counts, "step": step, "centre_count": init["centre_count"],
              "t_ref": init["t_ref"], "bounds": bounds, "grid": uniform_grid(t),
              "sigma_prior": sigma_prior, "harmonics": harmonics, "effects": effects}
    return {"harmonics": harmonics, "effects": effects, "names": names, "bounds": bounds,
            "init": init, "x0": x0, "scale": scale, "kwargs": kwargs, "extra_scale": extra_scale,
            "centre": init["centre_count"], "t_ref": init["t_ref"]}


def _check_int_counts(counts, n):
    c = np.asarray(counts)
    if c.ndim != 1 or c.size != n or not np.issubdtype(c.dtype, np.integer):
        raise ValueError(f"counts must be a 1-D integer array with the length of t ({n}), "
                         f"got shape {c.shape} and dtype {c.dtype}")
    return c.astype(np.int64)


def _chain_diagnostics(internal: np.ndarray, names) -> tuple[dict, dict, dict]:
    """Integrated autocorrelation time (largest over ensembles), split R-hat across ensembles
    and ESS per parameter of chains shaped (n_ensembles, n_steps, n_walkers, ndim).

    A walker that holds one value over the whole window (every move it was offered was
    rejected) has no autocorrelation function (emcee's is 0/0 there): the time is that of the
    ensemble's other walkers, and infinite when none moved. Without this, one such walker
    made the time NaN, and the largest and smallest over parameters, and so the convergence
    flag, depended on the parameters' order."""
    tau, rhat, ess = {}, {}, {}
    for i, name in enumerate(names):
        tau_i = max(_integrated_time(internal[e, :, :, i]) for e in range(internal.shape[0]))
        tau[name] = tau_i
        rhat[name] = diagnostics.split_rhat_ensembles(internal[:, :, :, i])
        ess[name] = float(internal[:, :, :, i].size / max(tau_i, 1.0))
    return tau, rhat, ess


def _integrated_time(x) -> float:
    """emcee's integrated autocorrelation time of one ensemble's chain ``(steps, walkers)``,
    over the walkers that moved (infinite when none did)."""
    moved = np.ptp(x, axis=0) > 0
    if not moved.any():
        return math.inf
    with _quiet_emcee():
        return float(emcee.autocorr.integrated_time(x[:, moved, None], quiet=True)[0])


def truth_rounding_bound(amplitude, truth_step, n_terms=4000) -> float:
    """Bound of the mean rounding error of a sine read by a uniform quantizer of step ``s``.

    The error ``s round(theta/s) - theta`` is the sawtooth ``sum_k (s / (pi k)) (-1)^k
    sin(2 pi k theta / s)``; averaged over the phase of ``theta = b + A sin(phi)`` each term
    becomes ``J0(2 pi k A / s) sin(2 pi k b / s)``, so whatever ``b`` the mean error is at most
    ``(s / pi) sum_k |J0(2 pi k A / s)| / k`` (the series converges as ``k^-3/2``; the tail
    after ``n_terms`` is bounded by its asymptote and added), and never more than ``s / 2``.
    """
    from scipy.special import j0

    amplitude, s = abs(float(amplitude)), float(truth_step)
    if not (np.isfinite(amplitude) and np.isfinite(s) and s > 0):
        raise ValueError(f"amplitude and truth_step must be finite, truth_step > 0; got "
                         f"{amplitude!r}, {truth_step!r}")
    k = np.arange(1, int(n_terms) + 1)
    head = float(np.sum(np.abs(j0(2.0 * np.pi * k * amplitude / s)) / k))
    # |J0(x)| <= sqrt(2 / (pi x)) for large x: the tail sum_{k > n} k^-3/2 < 2 / sqrt(n).
    tail = (np.sqrt(2.0 / (np.pi * 2.0 * np.pi * amplitude / s)) * 2.0 / np.sqrt(n_terms)
            if amplitude > 0 else 0.0)
    return min(s / np.pi * (head + tail), 0.5 * s)  # never more than half a step


def fit_sinusoid(t, counts, step, seed, n_ensembles=4, n_walkers=32, n_steps=250, n_burn=150,
                 f_hz=None, truth=None, rest_position=None, sigma_range=None,
                 sigma_prior="uniform", moves="de", harmonics=(), effects=(),
                 start=None, max_steps=None, truth_step=None) -> FitResult:
    """Posterior of stroke, bias deviation, frequency, phase and noise from coarse counts.

    Parameters
    ----------
    t : array_like
        Sample times in s (strictly increasing).
    counts : array_like of int
        Coarse encoder counts.
    step : float
        Encoder resolution in rad.
    seed : int or numpy.random.SeedSequence or numpy.random.Generator
        Root of the randomness; each ensemble gets its own child of
        ``SeedSequence(seed).spawn(n_ensembles)`` (a Generator is used to draw the root
        entropy).
    n_ensembles, n_walkers, n_steps, n_burn : int
        Independent emcee ensembles, walkers per ensemble (>= 10, even; raised to twice the
        number of parameters when the model has more than half as many), production steps and
        discarded burn-in steps per ensemble.
    max_steps : int, optional
        When the chains have not converged after ``n_steps`` (R-hat > 1.01 or ESS < 1000),
        they go on in blocks of ``n_steps`` up to ``max_steps`` production steps, all kept
        (the burn-in stays discarded). Default ``n_steps``: no extension.
    f_hz : float, optional
        Known motion frequency (initialisation and cycle segmentation); estimated if None.
    truth : array_like, optional
        True angle in rad at ``t`` (a fine truth channel). Identifies the bias ``b`` (least
        squares intercept at the posterior median frequency) and hence ``a = a_eq - b``.
    rest_position : float, optional
        The motion centre ``b`` in the encoder's frame when it is known by construction (e.g.
        0 when the drive oscillates about the angle where the counter was zeroed); gives
        ``a = a_eq - rest_position``. Ignored when ``truth`` is given.
    truth_step : float, optional
        Step (rad) of a quantized truth channel. The mean of its rounding error over the
        motion is a bias of ``b``, not noise, so it is not in the residual's standard error;
        ``b``'s interval is widened by its bound (:func:`truth_rounding_bound`).
    sigma_range : (float, float), optional
        Prior range of the position jitter ``sigma`` in steps, default ``(1e-4, 10**-0.5)``.
        A lab that knows its jitter closely can give it here.
    sigma_prior : {"uniform", "log-uniform"}
        Prior density of ``sigma`` inside its range (see the module notes: the log-uniform
        prior gives too narrow intervals when the readings show little jitter).
    harmonics : tuple of int
        Orders of harmonic distortion of the motion to fit (e.g. ``(3,)``): each adds
        ``c_k cos(k phi) + s_k sin(k phi)`` (rad, uniform prior on ``+-step/2``), reported as
        ``c<k>``, ``s<k>``. The reported ``A12`` is then the motion's peak-to-peak stroke
        (eq. 2; ``stroke_samples``) and ``A12_fundamental`` twice the fundamental's amplitude
        (the ``A12`` column of ``samples``). See
        :func:`enclab.lrde.compare.compare_effect_models` for choosing them on held-out data.
    effects : tuple of str
        Encoder and clock effects of the reading model (:mod:`enclab.lrde.effects`), reported
        under their parameter names in SI units (``hysteresis`` rad, ``drift`` 1/s,
        ``time_jitter`` s; ``count_jump`` is marginalised and has no column).
    start : array_like, optional
        Internal parameter row to start the ensembles around (e.g. :func:`map_fit`'s optimum);
        default the dwell baselines of :func:`initial_guess`.
    moves : {"de", "stretch"}
        emcee moves. Differential evolution mixes about twice as fast as the stretch move on
        this posterior.

    Returns
    -------
    FitResult

    References
    ----------
    .. [1] Zhang & Gao, eqs. (4), (6), (13b), (14).
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 16 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError("t must be a finite, strictly increasing 1-D array of >= 16 samples")
    counts = _check_int_counts(counts, t.size)
    step = model._check_step(step)
    max_steps = n_steps if max_steps is None else max_steps
    for name, value, low in (("n_ensembles", n_ensembles, 2), ("n_walkers", n_walkers, 10),
                             ("n_steps", n_steps, 50), ("n_burn", n_burn, 0),
                             ("max_steps", max_steps, n_steps)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if n_walkers % 2:
        raise ValueError(f"n_walkers must be even (emcee's red-blue split), got {n_walkers}")
    if moves not in _MOVES:
        raise ValueError(f"moves must be one of {sorted(_MOVES)}, got {moves!r}")
    if isinstance(seed, np.random.Generator):
        root = np.random.SeedSequence(int(seed.integers(2**63)))
    elif isinstance(seed, np.random.SeedSequence):
        root = seed
    else:
        root = np.random.SeedSequence(seed)
    started = time.perf_counter()
    setup = _setup(t, counts, step, f_hz, sigma_range, sigma_prior, harmonics, effects)
    harmonics, effects = setup["harmonics"], setup["effects"]
    names, bounds, init, kwargs = setup["names"], setup["bounds"], setup["init"], setup["kwargs"]
    ndim = len(names)
    if n_walkers < 2 * ndim:
        # emcee's ensemble moves need at least twice as many walkers as parameters (fewer stay
        # on a subspace); a model with harmonics and effects can have more than the setting
        # was chosen for.
        _log.info("%d walkers per ensemble raised to %d for the %d parameters of %s",
                  n_walkers, 2 * ndim, ndim, "+".join(names[5:]))
        n_walkers = 2 * ndim
    K, centre, t_ref = init["steps_pp"], setup["centre"], setup["t_ref"]
    x0, scale = setup["x0"], setup["scale"]
    if start is not None:
        x0 = np.clip(np.asarray(start, dtype=float), bounds[:, 0] + 1e-6 * np.ptp(bounds, axis=1),
                     bounds[:, 1] - 1e-6 * np.ptp(bounds, axis=1))
    # Every ensemble starts and moves from a child seed of its own (SeedSequence.spawn), all
    # side by side in one sampler (_EnsemblesMove): independent chains, one likelihood call.
    starts, randoms = [], []
    for child in root.spawn(n_ensembles):
        rng = np.random.default_rng(child)
        start = x0 + scale * rng.standard_normal((n_walkers, ndim))
        starts.append(np.clip(start, bounds[:, 0] + 1e-9 * np.ptp(bounds, axis=1),
                              bounds[:, 1] - 1e-9 * np.ptp(bounds, axis=1)))
        randoms.append(np.random.RandomState(int(rng.integers(2**32))))
    # Differential-evolution moves mix about twice as fast as the default stretch move on
    # this nearly Gaussian 5-D posterior (emcee docs, "Using different moves").
    sampler = emcee.EnsembleSampler(
        n_ensembles * n_walkers, ndim, log_probability, kwargs=kwargs, vectorize=True,
        moves=[(_EnsemblesMove(move, randoms), weight) for move, weight in _MOVES[moves]()])
    # emcee's own RandomState only picks the move of each step (one for every ensemble).
    sampler.random_state = np.random.RandomState(
        int(root.spawn(1)[0].generate_state(1)[0])).get_state()
    sampler.run_mcmc(np.concatenate(starts), n_burn + n_steps, progress=False)
    kept = n_steps
    while True:
        chain = sampler.get_chain(discard=n_burn)  # (kept, n_ens * n_walkers, ndim)
        internal = chain.reshape(kept, n_ensembles, n_walkers, ndim).transpose(1, 0, 2, 3)
        tau, rhat, ess = _chain_diagnostics(internal, names)
        converged = bool(max(rhat.values()) <= 1.01 and min(ess.values()) >= 1000)
        if converged or kept >= max_steps:
            break
        more = min(n_steps, max_steps - kept)
        sampler.run_mcmc(None, more, progress=False)
        kept += more
    acceptance = sampler.acceptance_fraction
    si = _to_si(internal, step, setup["extra_scale"])
    samples = si.reshape(-1, ndim)
    summary = {name: _quantiles(samples[:, i]) for i, name in enumerate(names)}
    stroke, midpoint = _stroke_samples(samples, names, harmonics)
    # A distorted motion's bias is the mean of its turning points (eq. 2), not its mean:
    # a_eq and E_b move by the turning points' midpoint about the mean (0 for a sine).
    a_eq = (centre + 0.5) * step + samples[:, 1] + midpoint
    summary["a_eq"] = _quantiles(a_eq)
    summary["E_b"] = _quantiles(samples[:, 1] + midpoint)
    _report_stroke(summary, stroke)
    offset_a = bias_b = b_draws = None
    reason = _UNIDENTIFIED
    if truth is not None:
        truth = np.asarray(truth, dtype=float)
        if truth.shape != t.shape or not np.all(np.isfinite(truth)):
            raise ValueError(f"truth must be finite with the shape of t {t.shape}, "
                             f"got {truth.shape}")
        w = 2.0 * np.pi * summary["f_hz"]["median"] * (t - t_ref)
        design = np.column_stack((np.ones_like(t), np.sin(w), np.cos(w)))
        coef, *_ = np.linalg.lstsq(design, truth, rcond=None)
        b_hat = float(coef[0])
        # Standard error of the intercept from the truth's own residual (its quantization and
        # any unmodelled motion) by batch means, since the quantization error of a sampled
        # sine is correlated from sample to sample (a white-noise se covered b in 83 % of
        # 60 draws at the 90 % level); Student t with n_batches - 1 degrees of freedom.
        resid = truth - design @ coef
        n_batches = int(min(20, max(2, t.size // 10)))
        batch_means = np.array([chunk.mean() for chunk in np.array_split(resid, n_batches)])
        b_se = float(batch_means.std(ddof=1) / np.sqrt(n_batches))
        rng = np.random.default_rng(root.spawn(1)[0])
        b_draws = b_hat + b_se * rng.standard_t(n_batches - 1, a_eq.size) + midpoint
        if truth_step is not None:
            # Unknown within its bound: uniform over it, on top of the statistical part.
            bound = truth_rounding_bound(float(np.hypot(coef[1], coef[2])), truth_step)
            b_draws = b_draws + bound * rng.uniform(-1.0, 1.0, a_eq.size)
        bias_b = _quantiles(b_draws)
        offset_a = _quantiles(a_eq - b_draws)
        reason = ("bias b from the truth channel (least-squares intercept at the posterior "
                  "median frequency, interval from its residual), offset a = a_eq - b")
    elif rest_position is not None:
        if not (np.isscalar(rest_position) and np.isfinite(rest_position)):
            raise ValueError(f"rest_position must be a finite scalar (rad), got {rest_position!r}")
        b = float(rest_position)
        b_draws = np.full(a_eq.size, b)
        bias_b = {"median": b, "q05": b, "q95": b}
        offset_a = _quantiles(a_eq - b)
        reason = "bias b = the known rest position, offset a = a_eq - b"
    if offset_a is not None:
        summary["offset_a"] = offset_a
        summary["bias_b"] = bias_b
    return FitResult(
        param_names=names, samples=samples, chains=si, a_eq_samples=a_eq,
        summary=summary, offset_a=offset_a, bias_b=bias_b, reason=reason, tau=tau, rhat=rhat,
        ess=ess, converged=converged, step=step, centre_count=centre, steps_pp=K, t_ref=t_ref,
        init={k: v for k, v in init.items() if k not in ("cycles",)},
        acceptance=float(np.mean(acceptance)), wall_time_s=time.perf_counter() - started,
        settings={"n_ensembles": n_ensembles, "n_walkers": n_walkers, "n_steps": n_steps,
                  "n_burn": n_burn, "bounds_internal": bounds.tolist(),
                  "harmonics": list(harmonics), "effects": list(effects),
                  "extra_scale": list(setup["extra_scale"]), "sigma_prior": sigma_prior},
        b_samples=b_draws, stroke_samples=stroke,
        midpoint_samples=None if stroke is None else midpoint,
    )


def _stroke_samples(samples, names, harmonics):
    """``(stroke, midpoint)`` per SI sample row: the peak-to-peak stroke of a model with
    harmonics (None without) and the midpoint of its turning points about the motion's mean
    (0 without: a sine's turning points are symmetric about its mean)."""
    if not harmonics:
        return None, np.zeros(samples.shape[0])
    names = list(names)
    c = samples[:, [names.index(f"c{k}") for k in harmonics]]
    s = samples[:, [names.index(f"s{k}") for k in harmonics]]
    return model.stroke_and_midpoint(samples[:, 0], harmonics, c, s)


def _report_stroke(summary, stroke):
    """With harmonics (``stroke`` not None), ``A12`` reports the stroke and the fundamental's
    moves to ``A12_fundamental``."""
    if stroke is not None:
        summary["A12_fundamental"] = summary["A12"]
        summary["A12"] = _quantiles(stroke)


def pool_fits(fits) -> FitResult:
    """One posterior of ``A12, E_b, f_hz, phase, sigma`` from the fits of several models, with
    equal weights.

    Model averaging for models the readings cannot tell apart: each fit contributes the same
    number of samples (evenly spaced over its pooled samples), so the reported intervals cover
    what every model allows instead of following the one picked by a margin inside the noise.
    Equal weights are the prior-odds answer when the held-out scores do not separate the
    models; weights from the scores' difference would go on favouring the pick on evidence
    the comparison itself called inconclusive.

    Parameters
    ----------
    fits : sequence of FitResult
        Fits of one log (same step, centre count and time origin); the first one's
        identification (``reason``) is kept.

    Returns
    -------
    FitResult
        ``samples`` with the five common columns, ``chains`` None, ``offset_a``/``bias_b``
        from the pooled ``a_eq - b`` when every fit identifies them, diagnostics the worst over
        the fits (largest ``tau`` and R-hat, smallest ESS), ``converged`` when all are,
        ``settings`` the first fit's sampler settings and ``"pooled"``, the model labels
        (``"+"``-joined terms, ``"sinusoid"``).

    Raises
    ------
    ValueError
        When fewer than two fits are given or they describe different logs.
    """
    fits = list(fits)
    if len(fits) < 2:
        raise ValueError(f"pool_fits needs at least two fits, got {len(fits)}")
    first = fits[0]
    for f in fits[1:]:
        if (f.step, f.centre_count, f.t_ref) != (first.step, first.centre_count, first.t_ref):
            raise ValueError("pool_fits: the fits describe different logs (step, centre count "
                             "or time origin differ)")
    n = min(f.samples.shape[0] for f in fits)
    picks = [np.round(np.linspace(0, f.samples.shape[0] - 1, n)).astype(np.int64) for f in fits]
    names = PARAM_NAMES
    samples = np.concatenate([f.samples[i, :len(names)] for f, i in zip(fits, picks)])
    a_eq = np.concatenate([f.a_eq_samples[i] for f, i in zip(fits, picks)])
    summary = {name: _quantiles(samples[:, j]) for j, name in enumerate(names)}
    summary["a_eq"] = _quantiles(a_eq)
    midpoint = np.concatenate([np.zeros(i.size) if f.midpoint_samples is None
                               else f.midpoint_samples[i] for f, i in zip(fits, picks)])
    summary["E_b"] = _quantiles(samples[:, 1] + midpoint)
    stroke = None
    if any(f.stroke_samples is not None for f in fits):
        stroke = np.concatenate([f.stroke[i] for f, i in zip(fits, picks)])
    _report_stroke(summary, stroke)
    b = None
    offset_a = bias_b = None
    if all(f.b_samples is not None for f in fits):
        b = np.concatenate([f.b_samples[i] for f, i in zip(fits, picks)])
        bias_b, offset_a = _quantiles(b), _quantiles(a_eq - b)
        summary["offset_a"], summary["bias_b"] = offset_a, bias_b
    labels = [f.label for f in fits]
    return FitResult(
        param_names=names, samples=samples, chains=None, a_eq_samples=a_eq, summary=summary,
        offset_a=offset_a, bias_b=bias_b, reason=first.reason if b is not None else _UNIDENTIFIED,
        tau=_worst(fits, "tau", max), rhat=_worst(fits, "rhat", max),
        ess=_worst(fits, "ess", min),
        converged=all(f.converged for f in fits), step=first.step,
        centre_count=first.centre_count, steps_pp=first.steps_pp, t_ref=first.t_ref,
        init=first.init, acceptance=float(np.mean([f.acceptance for f in fits])),
        wall_time_s=float(sum(f.wall_time_s for f in fits)),
        settings={k: v for k, v in first.settings.items()
                  if k not in ("harmonics", "effects", "extra_scale", "bounds_internal")}
        | {"pooled": labels}, b_samples=b, stroke_samples=stroke,
        midpoint_samples=None if stroke is None else midpoint)


def _worst(fits, name, pick) -> dict:
    """Per parameter, the worst of the fits' diagnostic ``name``: over the paper's parameters
    when every fit samples them (the periodic models), else over every parameter any fit
    samples, among the fits that sample it (the loop structures' internal parameters)."""
    keys = [k for k in PARAM_NAMES if all(k in getattr(f, name) for f in fits)]
    keys = keys or list(dict.fromkeys(k for f in fits for k in getattr(f, name)))
    return {k: pick(getattr(f, name)[k] for f in fits if k in getattr(f, name)) for k in keys}


def map_fit(t, counts, step, f_hz=None, harmonics=(), effects=(), start=None,
            sigma_range=None, sigma_prior="uniform", max_evals=800, init=None,
            prev_counts=None) -> dict:
    """Maximum of the log-posterior of a model (Nelder-Mead, restarted once from its optimum).

    A cheap stand-in for :func:`fit_sinusoid` where only a point estimate is needed (the
    held-out comparison of models): a few hundred likelihood evaluations instead of tens of
    thousands.

    Parameters
    ----------
    t, counts, step, f_hz, harmonics, effects, sigma_range, sigma_prior :
        As :func:`fit_sinusoid`.
    start : array_like, optional
        Internal row of the paper's sinusoid (first five columns; e.g. another model's
        optimum) to start from; the extra columns start at their defaults.
    max_evals : int
        Likelihood evaluations per Nelder-Mead run.
    init : dict, optional
        Another point fit's ``init`` (:func:`initial_guess` of the whole log): its centre
        count, time origin and prior bounds are reused, so that fits to subsets of the log
        (e.g. every other cycle) share one frame.
    prev_counts : numpy.ndarray, optional
        The reading before each sample in the whole log, when ``counts`` joins separate
        pieces of it (:func:`log_likelihood`).

    Returns
    -------
    dict
        ``x`` (internal row), ``log_post``, ``log_lik``, ``names``, ``centre``, ``t_ref``,
        ``step``, ``harmonics``, ``effects``, ``extra_scale``, ``bounds``, ``steps_pp``.
    """
    from scipy.optimize import minimize

    t = np.asarray(t, dtype=float)
    counts = _check_int_counts(counts, t.size)
    step = model._check_step(step)
    setup = _setup(t, counts, step, f_hz, sigma_range, sigma_prior, harmonics, effects, init)
    bounds, kwargs = setup["bounds"], setup["kwargs"] | {"prev_counts": prev_counts}
    margin = 1e-6 * np.ptp(bounds, axis=1)
    starts = [setup["x0"].copy()]
    if start is not None:
        starts[0][:5] = np.asarray(start, dtype=float)[:5]
    if lrde_effects.offsets_counts(setup["effects"]):
        # A jump wrecks the sinusoid's optimum over the whole log: also start from the
        # sinusoid of the first and of the last third, one of which is free of the jump.
        third = t.size // 3
        for part in (slice(0, third), slice(t.size - third, t.size)):
            seg = map_fit(t[part], counts[part], step, sigma_range=sigma_range,
                          sigma_prior=sigma_prior, max_evals=max_evals, init=setup["init"])
            starts.append(np.concatenate((seg["x"][:5], setup["x0"][5:])))
    duration = t[-1] - t[0]

    def objective(x):
        value = log_probability(x[None, :], **kwargs)[0]
        return -value if np.isfinite(value) else 1e300

    simplex_step = np.array([0.02, 0.02, 0.01 / duration, 0.02, 0.2]
                            + [0.02] * (2 * len(setup["harmonics"]))
                            + [e.simplex_step(duration)
                               for e in lrde_effects.active(setup["effects"]) if e.sampled])
    # A first run with the jitter held at 0.05 step or more: a smoothed likelihood whose
    # optimum is not hidden behind the cliffs of the nearly hard-edged one.
    smooth = max(np.log10(0.05), bounds[4, 0] + margin[4])
    free = np.arange(len(setup["names"])) != 4

    def smoothed(y):
        x = np.insert(y, 4, smooth)
        return objective(x)

    def descend(x):
        x = np.clip(x, bounds[:, 0] + margin, bounds[:, 1] - margin)
        y = x[free]
        sub = np.vstack([y] + [np.clip(y + np.eye(y.size)[i] * simplex_step[free][i],
                                       bounds[free, 0] + margin[free],
                                       bounds[free, 1] - margin[free])
                               for i in range(y.size)])
        res = minimize(smoothed, y, method="Nelder-Mead",
                       options={"initial_simplex": sub, "maxfev": int(max_evals),
                                "xatol": 1e-7, "fatol": 1e-2})
        x = np.insert(res.x, 4, x[4])
        for _ in range(2):
            simplex = np.vstack([x] + [np.clip(x + np.eye(x.size)[i] * simplex_step[i],
                                               bounds[:, 0] + margin, bounds[:, 1] - margin)
                                       for i in range(x.size)])
            res = minimize(objective, x, method="Nelder-Mead",
                           options={"initial_simplex": simplex, "maxfev": int(max_evals),
                                    "xatol": 1e-7, "fatol": 1e-2})
            x = res.x
        return res

    def gradient_descend(x):
        """L-BFGS-B on the smoothed likelihood (jitter held), then on the full one."""
        lo, hi = bounds[:, 0] + margin, bounds[:, 1] - margin
        x = np.clip(x, lo, hi)
        res = minimize(smoothed, x[free], method="L-BFGS-B",
                       bounds=list(zip(lo[free], hi[free])),
                       options={"maxfun": int(4 * max_evals)})
        x = np.insert(res.x, 4, x[4])
        return minimize(objective, x, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                        options={"maxfun": int(4 * max_evals)})

    if lrde_motion.from_harmonics(setup["harmonics"]).gradient_point_fit:
        # Many shape columns (a Fourier series): a simplex in that many dimensions stops far
        # from the optimum within its budget, a gradient method does not (the likelihood is
        # smooth in the coefficients at a jitter of a few hundredths of a step).
        descend = gradient_descend

    best = None
    for x in starts:
        res = descend(x)
        if best is None or res.fun < best.fun:
            best = res
    if best.x[4] > bounds[4, 1] - 0.1:
        # The jitter at its upper bound: a misfit the start could not resolve (over a long
        # log a drift or jump the start lacks sends the other terms far off). The terms found
        # are a better start: descend once more from them.
        res = descend(np.insert(best.x[free], 4, smooth))
        if res.fun < best.fun:
            best = res
    res, x = best, best.x
    log_lik = float(log_likelihood(x[None, :], t, counts, step, setup["centre"], setup["t_ref"],
                                   None, setup["harmonics"], setup["effects"], prev_counts)[0])
    return {"x": x, "log_post": -float(res.fun), "log_lik": log_lik, "names": setup["names"],
            "centre": setup["centre"], "t_ref": setup["t_ref"], "step": step,
            "harmonics": setup["harmonics"], "effects": setup["effects"],
            "extra_scale": setup["extra_scale"], "bounds": bounds,
            "steps_pp": setup["init"]["steps_pp"], "dt": float(np.median(np.diff(t))),
            "init": {k: v for k, v in setup["init"].items() if k != "cycles"}}


def log_interval_probability(lower, upper) -> np.ndarray:
    """``log(Phi(upper) - Phi(lower))`` elementwise, as the fit's likelihood computes it.

    Parameters
    ----------
    lower, upper : numpy.ndarray
        Interval bounds in standard deviations, ``lower < upper`` (broadcast together); the
        intervals must be a few standard deviations wide (see :func:`_log_interval_prob`).

    Returns
    -------
    numpy.ndarray
        The log-probability of each interval under a standard normal.
    """
    return _log_interval_prob(lower, upper)
