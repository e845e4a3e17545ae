"""A motion driven by the logged loop signals: the shaft angle as the output of a low-order
linear filter of the logged tracking error (paper 002's servo loop, Fig. 5).

Inside a loop the controller acts on ``e_j = r_j - step * c_j`` (reference and reading, both
logged), so for a linear controller ``C`` and plant ``P`` the angle is
``theta = P C e`` plus the response to a constant disturbance and to the state at the start of
the log. For a PI or PID controller driving a DC motor ``tau theta'' + theta' = g (u + d)``
held by a zero-order hold, ``P C`` has poles ``z = 1`` (twice: the plant's and the
controller's integrators), ``z = p = exp(-dt / tau)`` and, with derivative action, ``z = 0``;
it is strictly proper (the sample ``j`` depends on errors before ``j`` only). In partial
fractions

``theta_j / step = w_2 I2_j + w_1 I1_j + w_p L_j + sum_{k < taps} v_k e_{j-1-k}
+ w_r j / n + w_t p^j + const``,

with ``I1 = sum_{i<j} e_i``, ``I2`` its running sum, ``L_j = sum_{i<j} p^{j-1-i} e_i`` and
``e`` in steps; ``const``, the ramp ``j / n`` and ``p^j`` are the homogeneous responses (the
state at the start of the log and the disturbance). For a given ``p`` the angle is linear in
the coefficients. ``loop-pi`` has no tap, ``loop-pid`` one (``e_{j-1}``: the derivative's pole
at 0); the held-out comparison picks between them and against the periodic models.

The readings factorise causally (``theta_j`` depends on readings before ``j`` only), so the
reading likelihood of :mod:`enclab.lrde.fit` applies to this ``theta`` unchanged:
``count_j = floor(theta_j / step + a / step + noise)``, with the constant absorbed into the
offset. What a free periodic shape cannot see, the motion inside the extreme count, follows
here from the logged error.

Reported quantities per posterior sample, with the definitions for a motion that is not a
sinusoid (docs/low-resolution-encoder.md), over the cycles of the reference (upward
crossings of its mean): ``A12`` the mean over cycles of ``max theta - min theta``, ``a_eq``
the mean over cycles of ``a + (max theta + min theta) / 2``, ``E_b = a_eq - (m + 1/2) step``.
"""
from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from typing import NamedTuple

import emcee
import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp
from scipy.signal import lfilter

from enclab.core import parallel
from enclab.lrde import effects as lrde_effects
from enclab.lrde import fit as lrde_fit

__all__ = ["STRUCTURES", "LOOP_EFFECTS", "JITTER_FLOOR_STEPS", "LoopFilter", "JumpPlacement",
           "jump_placement", "jump_window", "simulate_readings", "loop_structure", "error_steps",
           "reference_cycles", "point_fit", "fit_loop", "LoopFitResult",
           "compare_loop_models", "predictive_check", "posterior_predictive_dwell"]

#: Taps of each structure (derivative action adds a pole at 0: one tap).
STRUCTURES = {"loop-pi": 0, "loop-pid": 1}
#: Encoder terms a loop structure's readings can carry (:mod:`enclab.lrde.effects`): the
#: reading's dead band (a sampled width, steps) and one missed or extra count (marginalised
#: over where and which way). Either one acts inside the loop too, since the controller acts on
#: the reading, but the logged error already holds what it did to the motion.
LOOP_EFFECTS = ("hysteresis", "count_jump")
_P_BOUNDS = (0.02, 0.995)  # the plant's discrete pole exp(-dt / tau)
_P_GRID = np.exp(-1.0 / np.array([0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0]))  # tau / dt
# The jitter's lower bounds. A log read without noise has a likelihood of hard edges: the
# posterior is a thin polytope in the coefficients, and the ensembles mix poorly on it. A
# floor softens the edges, but Gaussian edges softened by more than the readings allow
# penalise the true angle wherever it passes close to an edge, so the posterior moves off it:
# on the closed-loop benchmark's 23 clean 20-cycle logs read without noise a floor of 0.01
# step held the true A12 in 17 and E_b in 19 of the 90 % intervals, 10^-2.5 step in 21 and 23
# with every fit converged (loop-pi alone, started as the stage starts it; started at a point
# fit with the same floor, 22 of 23 converged, and at 10^-3 step 20). The posterior samples
# down to 10^-2.5 step.
# The point fits of the held-out comparison keep 0.01 step: from a soft start they stop far
# from the sharp optimum below it, and their held-out scores need a smooth likelihood.
# A noisy log's jitter (a few hundredths of a step) lies far above both.
# docs/low-resolution-encoder.md.
_LOG_S_BOUNDS = (-2.5, lrde_fit._LOG_SIGMA_BOUNDS[1])
_POINT_LOG_S_FLOOR = -2.0
#: The posterior jitter's floor in steps (above).
JITTER_FLOOR_STEPS = 10.0 ** _LOG_S_BOUNDS[0]
_SMOOTH_LOG_S = np.log10(0.05)
# The loop posterior's chains may end after half their burn-in when the log is noisy: a
# median jitter of at least 0.01 step. On the 46 closed-loop benchmark logs (read with a
# jitter of 0.02 step) whose chains ended there, doubling the burn-in moved the medians of
# A12 and E_b by at most 0.06 half-widths and the intervals' widths by at most 7 %, and the
# fit took 0.74 of the time (median); logs read without noise sit near the jitter's floor,
# where the ensembles spread more slowly (benchmarks/lrde_loop_burn_in.py).
_EARLY_LOG_S = _POINT_LOG_S_FLOOR
_W_BOUND = 1e3  # the coefficients' prior box (steps per unit column): wide, only a box
# Many rows' lag columns come from a series about the poles of a grid (_Columns.motion):
# cells 0.05 wide in log(1 - p), 10 terms; fewer rows than _SERIES_ROWS (the point fits'
# single rows) are filtered one by one. The cells' terms are kept, the least recently used
# dropped first, up to _LAG_CACHE_BYTES (at least _LAG_CACHE cells): a walker ensemble whose
# pole is loosely held spans tens of the grid's ~106 cells, and with only the last 8 cells
# kept nearly every evaluation filtered its cells afresh (about half of the stage's time on
# a 40-cycle soft-gain dead-band log of the closed-loop benchmark, profiled).
_LAG_CELL, _LAG_TERMS, _LAG_CACHE, _SERIES_ROWS = 0.05, 10, 8, 4
_LAG_CACHE_BYTES = 64 * 2**20


class LoopFilter:
    """A loop structure: the filter from the logged error to the angle (see the module) and
    the encoder terms of its readings (:data:`LOOP_EFFECTS`)."""

    def __init__(self, taps: int = 0, effects=()) -> None:
        if isinstance(taps, bool) or not isinstance(taps, (int, np.integer)) or taps < 0:
            raise ValueError(f"taps must be a non-negative integer, got {taps!r}")
        self.taps = int(taps)
        unknown = [e for e in effects if e not in LOOP_EFFECTS]
        if unknown:
            raise ValueError(f"loop structures take the encoder terms {list(LOOP_EFFECTS)}, "
                             f"got {unknown}")
        self.effects = tuple(e for e in LOOP_EFFECTS if e in effects)

    @property
    def base(self) -> str:
        names = {v: k for k, v in STRUCTURES.items()}
        return names.get(self.taps, f"loop-taps{self.taps}")

    @property
    def label(self) -> str:
        return "+".join((self.base,) + self.effects)

    @property
    def dead_band(self) -> bool:
        return "hysteresis" in self.effects

    @property
    def count_jump(self) -> bool:
        return "count_jump" in self.effects

    @property
    def n_coefficients(self) -> int:
        """Linear coefficients: ramp, transient, I2, I1, lag and the taps."""
        return 5 + self.taps

    def with_effect(self, name) -> "LoopFilter":
        return LoopFilter(self.taps, self.effects + (name,))

    def __eq__(self, other) -> bool:
        return (isinstance(other, LoopFilter) and other.taps == self.taps
                and other.effects == self.effects)

    def __hash__(self) -> int:
        return hash(("LoopFilter", self.taps, self.effects))

    def __repr__(self) -> str:
        return f"LoopFilter({self.label!r})"


def loop_structure(spec) -> LoopFilter:
    """A structure from its label (``loop-pi``, ``loop-pid``, either with ``+hysteresis``
    and/or ``+count_jump``) or itself."""
    if isinstance(spec, LoopFilter):
        return spec
    base, *effects = str(spec).split("+")
    if base in STRUCTURES and all(e in LOOP_EFFECTS for e in effects):
        return LoopFilter(STRUCTURES[base], effects)
    raise ValueError(f"unknown loop structure {spec!r}: one of {sorted(STRUCTURES)}, "
                     f"optionally with +{' or +'.join(LOOP_EFFECTS)}")


def error_steps(counts, reference, step) -> np.ndarray:
    """The loop's error ``reference / step - counts`` in steps; a ValueError naming the
    first sample that is not finite, or when the reference holds fewer than two whole cycles
    (:func:`reference_cycles`: a loop structure's quantities are means over them)."""
    r = np.asarray(reference, dtype=float)
    c = np.asarray(counts, dtype=float)
    if r.shape != c.shape or r.ndim != 1:
        raise ValueError(f"reference must be one-dimensional with the shape of counts "
                         f"{c.shape}, got {r.shape}")
    bad = np.flatnonzero(~np.isfinite(r))
    if bad.size:
        raise ValueError(f"reference is not finite at sample {bad[0]} ({r[bad[0]]}) and "
                         f"{bad.size - 1} more")
    reference_cycles(r)
    return r / step - c


def reference_cycles(reference) -> np.ndarray:
    """Sample indices starting the reference's cycles: its upward crossings of its mean
    (at least two, else a ValueError)."""
    r = np.asarray(reference, dtype=float)
    if r.size < 3:
        raise ValueError(f"the reference has {r.size} samples: fewer than two whole cycles")
    r = r - 0.5 * (r.max() + r.min())
    up = np.flatnonzero((r[:-1] < 0) & (r[1:] >= 0)) + 1
    if up.size < 3:
        raise ValueError("the reference crosses its mean upward fewer than three times: "
                         "fewer than two whole cycles")
    return up


class _Columns:
    """The design of one log: the columns that do not depend on ``p`` are built once, with
    the structure's encoder terms and the reading before each sample (the dead band's
    state)."""

    def __init__(self, e, structure, counts=None):
        s = loop_structure(structure)
        taps = s.taps
        self.structure = s
        e = np.asarray(e, dtype=float)
        n = e.size
        self.n = n
        self.prev = None
        if counts is not None:
            readings = np.asarray(counts, dtype=float)
            self.prev = np.concatenate((readings[:1], readings[:-1]))
        self.band_col = 3 + 5 + taps if s.dead_band else None
        self.jump_window = None  # set by fit_loop: _JumpWindow
        self.ed = np.concatenate(([0.0], e[:-1]))  # e_{j-1}: strictly causal
        i1 = lfilter([1.0], [1.0, -1.0], self.ed)
        i2 = lfilter([1.0], [1.0, -1.0], i1)
        ramp = np.arange(n) / n - 0.5  # centred: nearly uncorrelated with the offset
        base = np.column_stack((np.ones(n), ramp))
        fixed = [ramp]
        # I2 and I1 grow over a long log; their parts along 1 and the ramp belong to the
        # homogeneous terms, so they are projected out and the rest scaled to unit RMS
        # (a linear reparametrisation of the same span, well conditioned).
        for col in (i2, i1):
            coef, *_ = np.linalg.lstsq(base, col, rcond=None)
            col = col - base @ coef
            fixed.append(col / max(np.sqrt(np.mean(col ** 2)), 1e-12))
        for k in range(taps):  # e_{j-1-k}: a pole at 0 (derivative action) and delays
            fixed.append(np.concatenate((np.zeros(k), self.ed[:self.n - k])))
        self.fixed = np.column_stack(fixed)  # ramp, I2, I1, taps
        self.j = np.arange(n, dtype=float)
        self._lag_cache = {}  # grid cell -> (p0, basis): _series_basis; shared by copies
        cell_bytes = 8 * n * (self.fixed.shape[1] + _LAG_TERMS)
        self._lag_cache_cells = max(_LAG_CACHE, _LAG_CACHE_BYTES // max(cell_bytes, 1))

    def for_counts(self, counts) -> "_Columns":
        """The same design for other readings (their own predecessors)."""
        out = copy.copy(self)
        k = np.asarray(counts, dtype=float)
        out.prev = np.concatenate((k[:1], k[:-1]))
        return out

    def lag(self, p):
        """``(L, p^j)`` for a pole ``p``."""
        trans = np.zeros(self.n)
        if p > 0:
            k = _transient_length(p, self.n)
            trans[:k] = _powers(np.array([p]), self.j[:k])[0]
        else:
            trans[0] = 1.0
        return lfilter([1.0], [1.0, -p], self.ed), trans

    def _series_basis(self, cell):
        """The pole ``p0`` of a grid cell and the rows ``fixed.T`` then the series terms
        ``G_k = z^-k (1 - p0 z^-1)^-(k+1) e``, ``k < _LAG_TERMS``, kept for the cells last
        used."""
        cache = self._lag_cache
        if cell in cache:
            cache[cell] = cache.pop(cell)  # the most recently used last
            return cache[cell]
        p0 = -np.expm1(cell * _LAG_CELL)
        g = lfilter([1.0], [1.0, -p0], self.ed)
        terms = [g]
        for _ in range(_LAG_TERMS - 1):
            g = lfilter([0.0, 1.0], [1.0, -p0], g)
            terms.append(g)
        if len(cache) >= self._lag_cache_cells:
            del cache[next(iter(cache))]
        cache[cell] = (p0, np.vstack((self.fixed.T, np.stack(terms))))
        return cache[cell]

    def motion(self, x):
        """``z - a`` in steps for internal rows ``x`` (a0, log s, p, w_ramp, w_I2, w_I1,
        taps..., w_L, w_t): shape (rows, n).

        Many rows at once take their lag column ``L(p)`` from a series about the pole ``p0``
        of their cell of a grid in ``log(1 - p)``: ``L(p) = sum_k (p - p0)^k G_k``
        (:meth:`_series_basis`), exact as a power series. Within a cell ``|p - p0| / (1 -
        p0)`` stays below ``_LAG_CELL / 2`` and the filter ``(1 - p0 z^-1)^-1`` gains at most
        ``1 / (1 - p0)``, so the ``_LAG_TERMS`` terms leave an error of order ``1e-16`` of
        ``max |e| / (1 - p0)``, the bound of ``L`` itself; the filter runs once per cell, not
        once per row, and the columns and the series are one product.
        """
        x = np.atleast_2d(x)
        nf = self.fixed.shape[1]
        p = x[:, 2]
        if x.shape[0] < _SERIES_ROWS:
            out = x[:, 3:3 + nf] @ self.fixed.T
            for i, row in enumerate(x):
                lag, trans = self.lag(row[2])
                out[i] += row[3 + nf] * lag + row[4 + nf] * trans
            return out
        def product(rows, cell):
            p0, basis = self._series_basis(float(cell))
            weights = np.hstack((rows[:, 3:3 + nf], rows[:, 3 + nf, None]
                                 * (rows[:, 2:3] - p0) ** np.arange(_LAG_TERMS)))
            return weights @ basis

        cells = np.rint(np.log1p(-p) / _LAG_CELL)
        unique = np.unique(cells)
        if unique.size == 1:  # the usual case: no copy of the rows or of the product
            out = product(x, unique[0])
        else:
            out = np.empty((x.shape[0], self.n))
            for cell in unique:
                sel = cells == cell
                out[sel] = product(x[sel], cell)
        k = _transient_length(p.max(), self.n)
        trans = _powers(p, self.j[:k])
        trans *= x[:, 4 + nf, None]
        out[:, :k] += trans
        return out


def _transient_length(p, n) -> int:
    """Samples over which ``p^j`` exceeds 1e-18 (the rest is 0 in double precision's sums):
    a power of every sample costs most of a likelihood evaluation."""
    return min(n, int(np.ceil(np.log(1e-18) / np.log(p))) + 1)


def _powers(p, j) -> np.ndarray:
    """``p[:, None] ** j`` as ``exp(j log p)``, in place: a third of the power's time, and
    within 1e-14 of it relatively where ``p^j`` exceeds 1e-18 (there ``j |log p| < 42``)."""
    out = np.multiply.outer(np.log(p), j)
    return np.exp(out, out=out)


def _bounds(structure, log_s_floor=None):
    """The prior box of a structure's internal rows; the jitter's floor (log10 steps) is the
    posterior's unless given."""
    s = loop_structure(structure)
    n_w = 5 + s.taps
    floor = _LOG_S_BOUNDS[0] if log_s_floor is None else log_s_floor
    return np.array([[-50.0, 50.0], [floor, _LOG_S_BOUNDS[1]], list(_P_BOUNDS)]
                    + [[-_W_BOUND, _W_BOUND]] * n_w
                    + ([lrde_effects.effect("hysteresis").bounds(1.0, 1.0)] if s.dead_band
                       else []))


def _interval_bounds(x, cols, counts, mask=None, time_blur=0.0, offsets=None):
    """Standardised bounds ``(lower, upper)`` of the readings' intervals, rows of ``x``
    (over ``mask``); ``offsets`` (per sample) are taken off the counts first."""
    z = cols.motion(x) + x[:, 0:1]
    k = np.asarray(counts, dtype=float)
    prev = cols.prev
    if offsets is not None:
        k = k - offsets
        prev = None if prev is None else prev - offsets
    s = 10.0 ** x[:, 1:2]
    if time_blur > 0:
        # As the periodic models' held-out score: timing blurred by a fraction of a sample,
        # i.e. the jitter widened by the motion's speed times that fraction.
        speed = np.gradient(z, axis=1)
        s = np.sqrt(s * s + (speed * time_blur) ** 2)
    if mask is not None:
        z, k = z[:, mask], k[mask]
        prev = None if prev is None else prev[mask]
        s = s[:, mask] if s.shape[1] > 1 else s
    if cols.band_col is not None:
        lower, upper = lrde_effects.dead_band_bounds(
            z - k, k, prev, 0.5 * x[:, cols.band_col:cols.band_col + 1])
        return lower / s, upper / s
    return (k - z) / s, (k + 1.0 - z) / s


def _log_lik_rows(x, cols, counts, mask=None, time_blur=0.0, pointwise=False, offsets=None):
    """Reading log-likelihood of internal rows (sums over ``mask``, or per sample).

    With a count jump and no ``offsets`` the sum is marginalised over the jump's gap and sign
    (uniform prior, as :func:`enclab.lrde.effects.log_likelihood`); per sample it needs the
    jump placed (``offsets``).
    """
    x = np.atleast_2d(x)
    if (cols.structure.count_jump and offsets is None and cols.jump_window is not None
            and mask is None and time_blur == 0 and not pointwise):
        return _windowed_jump_log_lik(x, cols, counts, cols.jump_window)
    if cols.structure.count_jump and offsets is None:
        if pointwise:
            raise ValueError("per-sample values of a count-jump structure need the jump "
                             "placed (offsets)")
        terms = []
        for delta in (0,) + lrde_effects.JUMP_SIGNS:
            lower, upper = _interval_bounds(x, cols, counts, None, time_blur,
                                            None if delta == 0 else np.full(cols.n, delta))
            lp = lrde_effects._log_interval_full(lower, upper)
            if mask is not None:
                lp[:, ~mask] = 0.0
            terms.append(lp)
        flat = lrde_effects.jump_log_terms(terms[0], terms[1:]).reshape(x.shape[0], -1)
        return logsumexp(flat, axis=1) - np.log(flat.shape[1])
    lower, upper = _interval_bounds(x, cols, counts, mask, time_blur, offsets)
    if pointwise:
        return lrde_effects._log_interval_full(lower, upper)
    return lrde_effects._log_interval_rows(lower, upper)


class _JumpWindow(NamedTuple):
    """The gaps ``lo..hi`` (sample after the jump) that hold a count jump's posterior, the
    offsets with the jump before ``lo`` (``ref``) and those the samples ``[lo, hi)`` take when
    the jump lies after them (``alt``)."""

    lo: int
    hi: int
    ref: np.ndarray
    alt: np.ndarray


def _jump_posterior(x, cols, counts) -> np.ndarray:
    """Posterior of the count jump's sign and gap at the row ``x``: (signs, n - 1)."""
    x = np.atleast_2d(x)[:1]
    terms = []
    for delta in (0,) + lrde_effects.JUMP_SIGNS:
        lower, upper = _interval_bounds(x, cols, counts, None, 0.0,
                                        None if delta == 0 else np.full(cols.n, delta))
        terms.append(lrde_effects._log_interval_full(lower, upper))
    flat = lrde_effects.jump_log_terms(terms[0], terms[1:])[0]
    return np.exp(flat - logsumexp(flat))


def jump_window(x, cols, counts, margin) -> _JumpWindow | None:
    """The window of a count jump's posterior at the row ``x``: the gaps of the most
    probable sign whose probability exceeds 1e-12 of the largest, widened by ``margin``
    samples each side (not across the log's middle, where the shorter segment changes side);
    None when the other sign holds more than 1e-12 of the mass or those gaps lie on both
    sides of the middle."""
    post = _jump_posterior(x, cols, counts)
    sign_i = int(np.argmax(post.max(axis=1)))
    if post[1 - sign_i].sum() > 1e-12:
        return None
    held = np.flatnonzero(post[sign_i] > 1e-12 * post[sign_i].max()) + 1  # sample after
    lo = max(int(held[0]) - int(margin), 1)
    hi = min(int(held[-1]) + int(margin), cols.n - 1)  # gaps lo..hi, samples [lo, hi)
    # The margin stops at the log's middle, where the shorter segment changes side (the
    # gaps beyond it hold no mass); held gaps on both sides of it take the full marginal.
    middle = (cols.n + 1) // 2  # the first gap g with g >= n - g
    if held[0] >= middle:
        lo = max(lo, middle)
    elif held[-1] < middle:
        hi = min(hi, middle - 1)
    else:
        return None
    delta = int(lrde_effects.JUMP_SIGNS[sign_i])
    ref = lrde_effects.jump_offsets(cols.n, lo, delta)
    shorter_before = lo < cols.n - lo
    alt = np.full(hi - lo, delta if shorter_before else 0)
    return _JumpWindow(lo, hi, ref, alt)


def _windowed_jump_log_lik(x, cols, counts, window):
    """The count jump's marginal over the gaps of its window (prior uniform over every gap
    and sign, as the full marginal): the readings with the jump before the window, plus per
    gap the change on the window's samples before it."""
    lower, upper = _interval_bounds(x, cols, counts, None, 0.0, window.ref)
    total = lrde_effects._log_interval_rows(lower, upper)
    w = slice(window.lo, window.hi)
    z = cols.motion(x)[:, w] + x[:, 0:1]
    k = np.asarray(counts, dtype=float)[w]
    s = 10.0 ** x[:, 1:2]
    diffs = []
    for off in (window.ref[w], window.alt):
        kk = k - off
        if cols.band_col is not None:
            prev = cols.prev[w] - off
            lo_b, up_b = lrde_effects.dead_band_bounds(
                z - kk, kk, prev, 0.5 * x[:, cols.band_col:cols.band_col + 1])
        else:
            lo_b, up_b = kk - z, kk + 1.0 - z
        diffs.append(lrde_effects._log_interval_full(lo_b / s, up_b / s))
    change = np.concatenate((np.zeros((x.shape[0], 1)), np.cumsum(diffs[1] - diffs[0], axis=1)),
                            axis=1)
    return total + logsumexp(change, axis=1) - np.log(2.0 * (cols.n - 1))


class JumpPlacement(NamedTuple):
    """A count jump placed: ``gaps`` (the sample after the jump) of equal highest
    probability, ``delta`` the offset of the segment on the side ``before`` (the samples
    before the jump when True) in the frame of the other one, and ``offsets`` per sample with
    the jump at ``gaps[0]``."""

    gaps: np.ndarray
    delta: int
    before: bool
    offsets: np.ndarray

    def offsets_at(self, gap) -> np.ndarray:
        out = np.zeros(self.offsets.size, dtype=np.int64)
        if self.before:
            out[:int(gap)] = self.delta
        else:
            out[int(gap):] = self.delta
        return out


def jump_placement(x, cols, counts, mask=None) -> JumpPlacement:
    """The most probable count jump of a count-jump structure at the internal row ``x``.

    With ``mask`` (a fold's training samples) every gap between the two training samples
    around it is as probable: ``gaps`` holds them all, in the frame of the most probable one
    (its offset side kept across the log's middle, where the shorter segment changes side).
    """
    x = np.atleast_2d(x)[:1]
    terms = []
    for delta in (0,) + lrde_effects.JUMP_SIGNS:
        lower, upper = _interval_bounds(x, cols, counts, None, 0.0,
                                        None if delta == 0 else np.full(cols.n, delta))
        lp = lrde_effects._log_interval_full(lower, upper)[0]
        if mask is not None:
            lp[~mask] = 0.0
        terms.append(lp)
    flat = lrde_effects.jump_log_terms(terms[0][None, :], [t[None, :] for t in terms[1:]])[0]
    sign_i, gap = np.unravel_index(int(np.argmax(flat)), flat.shape)
    delta = int(lrde_effects.JUMP_SIGNS[sign_i])
    index = int(gap) + 1
    before = index < cols.n - index
    # every gap in the frame of the most probable one: offset on the same side
    c0 = np.cumsum(terms[0])
    cd = np.cumsum(terms[1 + sign_i])
    idx = np.arange(1, cols.n)
    row = (cd[idx - 1] + c0[-1] - c0[idx - 1]) if before else (c0[idx - 1] + cd[-1] - cd[idx - 1])
    # the run of equal values around the maximum: the gaps between two training samples
    flat_run = row >= row[gap] - 1e-9
    lo = hi = int(gap)
    while lo > 0 and flat_run[lo - 1]:
        lo -= 1
    while hi + 1 < row.size and flat_run[hi + 1]:
        hi += 1
    gaps = np.arange(lo, hi + 1) + 1
    placed = JumpPlacement(gaps, delta, bool(before), np.zeros(cols.n, dtype=np.int64))
    return placed._replace(offsets=placed.offsets_at(gaps[0]))


def _log_post(x, cols, counts, bounds, mask=None):
    x = np.atleast_2d(x)
    inside = np.all((x > bounds[:, 0]) & (x < bounds[:, 1]), axis=1)
    out = np.full(x.shape[0], -np.inf)
    if np.any(inside):
        # Uniform prior in sigma (the sampled column is log10 sigma): Jacobian ln10 * log s.
        out[inside] = (_log_lik_rows(x[inside], cols, counts, mask)
                       + np.log(10.0) * x[inside, 1])
    return out


def _effect_start(structure):
    """Start values of a structure's sampled encoder terms (internal units)."""
    return [lrde_effects.effect("hysteresis").start] if structure.dead_band else []


def _change_point(resid) -> int:
    """The index after which the mean of ``resid`` shifts most (CUSUM)."""
    cusum = np.cumsum(resid - resid.mean())
    return int(np.argmax(np.abs(cusum[:-1]))) + 1


def _start(cols, counts, mask):
    """Least squares of the readings' centres on the columns at each ``p`` of a grid; the
    ``p`` whose smoothed likelihood is best.

    With a count jump the readings are first fitted without it; where the mean of that fit's
    residual shifts most, a step column joins the columns (the jump's start), and the
    offset refers to the longer segment.
    """
    best = None
    y = np.asarray(counts, dtype=float) + 0.5
    m = np.ones(cols.n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    extra = _effect_start(cols.structure)
    for p in _P_GRID:
        lag, trans = cols.lag(p)
        design = np.column_stack((np.ones(cols.n), cols.fixed, lag, trans))
        coef, *_ = np.linalg.lstsq(design[m], y[m], rcond=None)
        if cols.structure.count_jump:
            at = np.flatnonzero(m)[_change_point(y[m] - design[m] @ coef)]
            after = (np.arange(cols.n) >= at).astype(float)
            coef, *_ = np.linalg.lstsq(np.column_stack((design, after))[m], y[m], rcond=None)
            if np.count_nonzero(m[at:]) > np.count_nonzero(m[:at]):
                coef[0] += coef[-1]  # the frame of the longer segment, after the jump
            coef = coef[:-1]
        x = np.concatenate(([coef[0], _SMOOTH_LOG_S, p], coef[1:], extra))
        value = _log_lik_rows(x, cols, counts, mask)[0]
        if best is None or value > best[0]:
            best = (value, x)
    return best[1]


def point_fit(t, counts, reference, step, structure="loop-pi", mask=None, max_evals=3000,
              cols=None, start=None) -> dict:
    """Maximum of the log-posterior of a loop structure (L-BFGS-B, first with the jitter
    held at 0.05 step, a smoothed likelihood, then free).

    ``mask`` restricts the likelihood to some samples (a held-out fold's training cycles);
    the columns always run over the whole log (the logged error is known everywhere).
    ``start``: an internal row to start from (that of the same filter without encoder terms
    is extended by their start values), else least squares over a grid of poles.
    Returns ``x`` (internal row), ``log_post``, ``structure``, ``taps``, ``step``.
    """
    s = loop_structure(structure)
    counts = np.asarray(counts)
    cols = cols or _Columns(error_steps(counts, reference, step), s, counts)
    bounds = _bounds(s, _POINT_LOG_S_FLOOR)
    margin = 1e-6 * np.ptp(bounds, axis=1)
    lo, hi = bounds[:, 0] + margin, bounds[:, 1] - margin
    if start is None:
        x = _start(cols, counts, mask)
    else:
        x = np.asarray(start, dtype=float)[:3 + s.n_coefficients]
        x = np.concatenate((x, _effect_start(s)))
    x = np.clip(x, lo, hi)
    free = np.arange(x.size) != 1

    def smoothed(y):
        value = _log_lik_rows(np.insert(y, 1, _SMOOTH_LOG_S), cols, counts, mask)[0]
        return -value if np.isfinite(value) else 1e300

    def objective(y):
        value = _log_post(y, cols, counts, bounds, mask)[0]
        return -value if np.isfinite(value) else 1e300

    res = minimize(smoothed, x[free], method="L-BFGS-B", bounds=list(zip(lo[free], hi[free])),
                   options={"maxfun": int(max_evals)})
    x = np.insert(res.x, 1, _SMOOTH_LOG_S)
    res = minimize(objective, x, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                   options={"maxfun": int(max_evals)})
    return {"x": res.x, "log_post": -float(res.fun), "structure": s.label, "taps": s.taps,
            "effects": s.effects, "step": float(step), "hess_inv": res.hess_inv.todense()}


def _cycle_extremes(z, starts):
    """Per row, the max and min of ``z`` over each whole cycle ``[starts[i], starts[i+1])``."""
    seg = z[:, starts[0]:starts[-1]]
    idx = starts[:-1] - starts[0]
    return np.maximum.reduceat(seg, idx, axis=1), np.minimum.reduceat(seg, idx, axis=1)


@dataclass
class LoopFitResult(lrde_fit.FitResult):
    """A :class:`enclab.lrde.fit.FitResult` of a loop structure: ``samples`` holds the
    reported columns (``A12`` per-cycle stroke, ``E_b``, the reference's ``f_hz``, ``phase``
    0, ``sigma``) per posterior sample, ``loop_samples`` the internal rows of the filter."""

    structure: str = "loop-pi"
    loop_samples: np.ndarray | None = None
    loop_names: tuple = ()
    #: per-sample count offsets of the most probable count jump (count-jump structures)
    jump_offsets: np.ndarray | None = None
    #: the encoder terms' reported values: ``hysteresis`` (rad) quantiles, ``jump`` (index,
    #: delta, probability within one sample)
    loop_params: dict | None = None

    @property
    def label(self) -> str:
        return self.structure

    def take(self, rows) -> "LoopFitResult":
        out = super().take(rows)
        out.loop_samples = None if self.loop_samples is None else self.loop_samples[rows]
        return out


def _names(structure):
    s = loop_structure(structure)
    return (("a0", "log_sigma", "p", "w_ramp", "w_I2", "w_I1")
            + tuple(f"w_tap{k}" for k in range(1, s.taps + 1)) + ("w_lag", "w_transient")
            + (("hysteresis",) if s.dead_band else ()))


class _EnsembleRun(NamedTuple):
    """A stretch of one ensemble's chain and what continues it."""

    chain: np.ndarray  # (steps, walkers, ndim)
    coords: np.ndarray
    log_prob: np.ndarray
    random: np.random.RandomState
    sampler_state: tuple
    accepted: np.ndarray  # accepted moves per walker


def _sample_ensemble(coords, random, n_steps, cols, counts, bounds, log_prob=None,
                     sampler_state=None) -> _EnsembleRun:
    """``n_steps`` of one ensemble (differential evolution) from ``coords`` (walkers x ndim).

    An ensemble draws only from its own random states, so it runs the same alone or beside
    others, in this process or a forked one.
    """
    sampler = emcee.EnsembleSampler(
        coords.shape[0], coords.shape[1], _log_post, args=(cols, counts, bounds),
        vectorize=True,
        moves=[(lrde_fit._EnsemblesMove(m, [random]), w) for m, w in lrde_fit._MOVES["de"]()])
    state = emcee.State(coords, log_prob=log_prob, random_state=sampler_state)
    last = sampler.run_mcmc(state, int(n_steps), progress=False)
    return _EnsembleRun(sampler.get_chain(), last.coords, last.log_prob, random,
                        last.random_state, sampler.backend.accepted.copy())


def fit_loop(t, counts, reference, step, seed, structure="loop-pi", start=None, n_ensembles=4,
             n_walkers=64, n_steps=250, n_burn=400, max_steps=1000, truth=None,
             truth_step=None, centre_count=None, threads=1) -> LoopFitResult:
    """Posterior of a loop structure (independent emcee ensembles, split R-hat across them,
    as :func:`enclab.lrde.fit.fit_sinusoid`) and the paper's quantities per sample.

    64 walkers per ensemble: with 32 the differential-evolution moves needed 500-1000 steps
    for R-hat <= 1.01 on 20-cycle closed-loop logs read without noise (integrated
    autocorrelation times of 40-80 steps), with 64 they converged within the first 250 (times
    of 20-25 steps) at the same cost per sample. The chains are first checked after half
    of ``n_burn``, where those of a noisy log (median jitter 0.01 step or more) end when they
    have converged; else after the whole burn-in (:meth:`LoopFitPlan.finish`). The ensembles
    run ``threads`` at a time; the result does not depend on ``threads``.

    ``truth`` (rad, a fine channel) gives the bias ``b``: the mean over the reference's
    cycles of its turning points' midpoint, widened by half its rounding step; ``a = a_eq - b``.
    """
    plan = plan_loop_fit(t, counts, reference, step, seed, structure, start, n_ensembles,
                         n_walkers, n_steps, n_burn, max_steps, truth, truth_step, centre_count)
    return plan.finish(parallel.call_forked(plan.calls, threads), threads)


def plan_loop_fit(t, counts, reference, step, seed, structure="loop-pi", start=None,
                  n_ensembles=4, n_walkers=64, n_steps=250, n_burn=400, max_steps=1000,
                  truth=None, truth_step=None, centre_count=None) -> "LoopFitPlan":
    """:func:`fit_loop` up to its first round of ensembles: ``calls`` (``(fn, args)`` each,
    for :func:`enclab.core.parallel.call_forked`, beside other jobs) and ``finish`` (their
    results, processes) -> :class:`LoopFitResult`, the same as :func:`fit_loop`'s."""
    started = time.perf_counter()
    t = np.asarray(t, dtype=float)
    counts = lrde_fit._check_int_counts(counts, t.size)
    s = loop_structure(structure)
    cols = _Columns(error_steps(counts, reference, step), s, counts)
    if start is None:
        start = point_fit(t, counts, reference, step, s, cols=cols)
    x0, cov = np.asarray(start["x"], dtype=float), np.asarray(start["hess_inv"])
    bounds = _bounds(s)
    names = _names(s)
    cycles = reference_cycles(reference)
    if s.count_jump:
        # The jump's posterior is a few samples wide: the sampler's likelihood marginalises
        # over the gaps around the point fit's jump (half a cycle each side) and costs one
        # evaluation of the readings plus the window's; the full marginal when the point fit
        # leaves the jump's place or sign open.
        half_cycle = int(np.median(np.diff(cycles))) // 2
        cols.jump_window = jump_window(x0, cols, counts, margin=half_cycle)
    ndim = len(names)
    n_walkers = max(int(n_walkers), 2 * ndim + (2 * ndim) % 2)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    # Start dispersion: a thousandth of the point fit's inverse-Hessian widths (L-BFGS's own
    # estimate, which overstates the widths of this hard-edged likelihood by orders of
    # magnitude: started at a tenth of them, walkers stray where the jitter is large and do
    # not return within the chain); the differential-evolution moves widen the ensembles
    # during the burn-in.
    scale = 1e-3 * np.sqrt(np.clip(np.diag(cov), 1e-12, None))
    margin = 1e-9 * np.ptp(bounds, axis=1)
    jobs = []
    for child in root.spawn(n_ensembles):
        rng = np.random.default_rng(child)
        p0 = np.clip(x0 + scale * rng.standard_normal((n_walkers, ndim)),
                     bounds[:, 0] + margin, bounds[:, 1] - margin)
        random = np.random.RandomState(int(rng.integers(2**32)))
        sampler_state = np.random.RandomState(int(rng.integers(2**32))).get_state()
        jobs.append((p0, random, _early_burn(n_burn) + n_steps, cols, counts, bounds, None,
                     sampler_state))
    return LoopFitPlan(calls=[(_sample_ensemble, job) for job in jobs], started=started,
                       t=t, counts=counts, reference=reference, step=step, root=root, s=s,
                       cols=cols, x0=x0, bounds=bounds, names=names, cycles=cycles,
                       n_ensembles=n_ensembles, n_walkers=n_walkers, n_steps=n_steps,
                       n_burn=n_burn, max_steps=max_steps, truth=truth, truth_step=truth_step,
                       centre_count=centre_count)


@dataclass
class LoopFitPlan:
    """A loop fit between its set-up and its first round of ensembles (:func:`plan_loop_fit`)."""
    calls: list
    started: float
    t: np.ndarray
    counts: np.ndarray
    reference: np.ndarray
    step: float
    root: np.random.SeedSequence
    s: LoopFilter
    cols: "_Columns"
    x0: np.ndarray
    bounds: np.ndarray
    names: list
    cycles: np.ndarray
    n_ensembles: int
    n_walkers: int
    n_steps: int
    n_burn: int
    max_steps: int
    truth: object
    truth_step: object
    centre_count: object

    def finish(self, runs, threads=1) -> LoopFitResult:
        """The fit from the first round's ``runs`` (results of ``calls``, in order): more
        rounds until converged or ``max_steps``, ``threads`` ensembles at a time."""
        t, counts, reference, step, root = (self.t, self.counts, self.reference, self.step,
                                            self.root)
        s, cols, x0, bounds, names, cycles = (self.s, self.cols, self.x0, self.bounds,
                                              self.names, self.cycles)
        n_ensembles, n_walkers, n_steps, n_burn, max_steps = (
            self.n_ensembles, self.n_walkers, self.n_steps, self.n_burn, self.max_steps)
        truth, truth_step, centre_count, started = (self.truth, self.truth_step,
                                                    self.centre_count, self.started)
        ndim = len(names)
        chains = [run.chain for run in runs]
        accepted = sum(run.accepted for run in runs)
        total = _early_burn(n_burn) + n_steps  # steps run, burn-in included
        while True:
            # The first check comes after half the burn-in, and only a noisy log's chains
            # end there: its soft edges let the ensembles fill the posterior within it. Else
            # the chains go on to the full burn-in and are checked on the block after it,
            # then extended by blocks; chains extended past that block keep their second
            # half only: the first is further warm-up (the walkers start in a tiny ball about
            # the point fit, and a log read with little noise takes them longer to fill its
            # posterior).
            kept = max(total - n_burn, n_steps)
            window = max(n_steps, kept // 2)
            internal = np.stack([c[-window:] for c in chains])  # (ensembles, steps, ...)
            tau, rhat, ess = lrde_fit._chain_diagnostics(internal, names)
            converged = bool(max(rhat.values()) <= 1.01 and min(ess.values()) >= 1000)
            burnt = total >= n_burn + n_steps
            if not burnt:
                converged &= bool(np.median(internal[..., 1]) >= _EARLY_LOG_S)
            if converged or (burnt and kept >= max_steps):
                break
            more = min(n_steps, max_steps - kept) if burnt else n_burn + n_steps - total
            runs = parallel.map_forked(_sample_ensemble, [
                (run.coords, run.random, more, cols, counts, bounds, run.log_prob,
                 run.sampler_state) for run in runs], threads)
            chains = [np.concatenate((c, run.chain)) for c, run in zip(chains, runs)]
            accepted = accepted + sum(run.accepted for run in runs)
            total += more
        rows = internal.reshape(-1, ndim)
        f_hz = float((cycles.size - 1) / (t[cycles[-1]] - t[cycles[0]]))
        init = lrde_fit.initial_guess(t, counts, step)
        centre = float(init["centre_count"] if centre_count is None else centre_count)
        loop_params, offsets, cycle_offset = {}, None, 0.0
        if s.count_jump:
            # The jump is placed where the point fit puts it (its posterior is a few samples
            # wide); the readings' offset of each cycle is its mean over the cycle's samples, so
            # that a_eq is in the frame of the readings on either side of the jump.
            gaps, delta, _, offsets = jump_placement(x0, cols, counts)
            mass = _jump_mass(x0, cols, counts, int(gaps[0]), delta)
            loop_params["jump"] = {"index": int(gaps[0]), "time_s": float(t[gaps[0]]),
                                   "delta": delta, "probability_within_1_sample": mass,
                                   "frame": "a_eq refers to the longer segment; the shorter one "
                                            f"reads {delta:+d} count"}
            seg = offsets[cycles[0]:cycles[-1]].astype(float)
            cycle_offset = np.add.reduceat(seg, cycles[:-1] - cycles[0]) / np.diff(cycles)
        # The motion of every posterior row, in parts of whole 256-row chunks (the same
        # arithmetic as in one part), ``threads`` parts at a time.
        part = 256 * -(-rows.shape[0] // (256 * max(int(threads), 1)))
        done = parallel.map_forked(_cycle_quantities, [
            (rows[i:i + part], cols, cycles, cycle_offset)
            for i in range(0, rows.shape[0], part)], threads)
        stroke = step * np.concatenate([d[0] for d in done])
        a_eq = step * np.concatenate([d[1] for d in done])
        if s.dead_band:
            loop_params["hysteresis"] = lrde_fit._quantiles(step * rows[:, cols.band_col])
        e_b = a_eq - (centre + 0.5) * step
        sigma = step * 10.0 ** rows[:, 1]
        samples = np.column_stack((stroke, e_b, np.full(rows.shape[0], f_hz),
                                   np.zeros(rows.shape[0]), sigma))
        q = lrde_fit._quantiles
        summary = {"A12": q(stroke), "E_b": q(e_b), "a_eq": q(a_eq), "f_hz": q(samples[:, 2]),
                   "phase": q(samples[:, 3]), "sigma": q(sigma)}
        offset_a = bias_b = b_draws = None
        reason = lrde_fit._UNIDENTIFIED
        if truth is not None:
            truth = np.asarray(truth, dtype=float)
            top, bottom = _cycle_extremes(truth[None, :], cycles)
            b_hat = float((0.5 * (top + bottom)).mean())
            half = 0.5 * float(truth_step) if truth_step else 0.0
            rng = np.random.default_rng(root.spawn(2)[1])
            b_draws = b_hat + half * rng.uniform(-1.0, 1.0, rows.shape[0])
            bias_b, offset_a = q(b_draws), q(a_eq - b_draws)
            summary["bias_b"], summary["offset_a"] = bias_b, offset_a
            reason = ("bias b from the truth channel (mean over the reference's cycles of the "
                      "midpoint of its turning points, widened by half its step), offset "
                      "a = a_eq - b")
        return LoopFitResult(
            param_names=lrde_fit.PARAM_NAMES, samples=samples, chains=None, a_eq_samples=a_eq,
            summary=summary, offset_a=offset_a, bias_b=bias_b, reason=reason, tau=tau, rhat=rhat,
            ess=ess, converged=converged, step=float(step), centre_count=centre,
            steps_pp=int(init["steps_pp"]), t_ref=float(0.5 * (t[0] + t[-1])),
            init={k: v for k, v in init.items() if k != "cycles"},
            acceptance=float(np.mean(accepted) / (n_ensembles * total)),
            wall_time_s=time.perf_counter() - started,
            settings={"n_ensembles": n_ensembles, "n_walkers": n_walkers, "n_steps": window,
                      "n_burn": total - window, "structure": s.label, "harmonics": [],
                      "effects": list(s.effects)},
            b_samples=b_draws, stroke_samples=stroke, midpoint_samples=np.zeros(rows.shape[0]),
            structure=s.label, loop_samples=rows, loop_names=names, jump_offsets=offsets,
            loop_params=loop_params)


def _early_burn(n_burn) -> int:
    """Burn-in steps before the first convergence check (:meth:`LoopFitPlan.finish`)."""
    return int(n_burn) // 2


def _cycle_quantities(rows, cols, cycles, cycle_offset):
    """Per internal row: the mean over cycles of the stroke and of the turning points'
    midpoint plus ``cycle_offset`` (steps), in chunks of 256 rows."""
    stroke, mid = np.empty(rows.shape[0]), np.empty(rows.shape[0])
    for i in range(0, rows.shape[0], 256):
        z = cols.motion(rows[i:i + 256]) + rows[i:i + 256, 0:1]
        top, bottom = _cycle_extremes(z, cycles)
        stroke[i:i + 256] = (top - bottom).mean(axis=1)
        mid[i:i + 256] = (0.5 * (top + bottom) + cycle_offset).mean(axis=1)
    return stroke, mid


def _jump_mass(x, cols, counts, index, delta) -> float:
    """Posterior probability (at the row ``x``) of the jump lying within one sample of
    ``index`` with the sign ``delta``."""
    post = _jump_posterior(x, cols, counts)
    gap = index - 1
    return float(post[lrde_effects.JUMP_SIGNS.index(delta), max(gap - 1, 0):gap + 2].sum())


def predictive_check(m, counts, reference, rng, n_sim=20) -> dict:
    """The point fit's log-likelihood of the readings against that of ``n_sim`` readings
    simulated from it, given the logged error (the readings' causal factorisation: each
    reading is drawn from the angle the logged errors before it set). Returns ``observed``,
    ``sim_mean``, ``sim_sd`` and ``z``."""
    counts = np.asarray(counts)
    cols = _Columns(error_steps(counts, reference, m["step"]), m["structure"], counts)
    x = np.asarray(m["x"], dtype=float)[None, :]
    observed = float(_log_lik_rows(x, cols, counts)[0])
    scores = np.array([_log_lik_rows(x, cols.for_counts(sim), sim)[0]
                       for sim in simulate_readings(x[0], cols, counts, rng, n_sim)])
    sd = float(scores.std(ddof=1))
    return {"observed": observed, "sim_mean": float(scores.mean()), "sim_sd": sd,
            "z": float((observed - scores.mean()) / sd) if sd > 0 else 0.0}


def simulate_readings(x, cols, counts, rng, n_rep) -> np.ndarray:
    """``n_rep`` readings (rows) of the internal row ``x`` given the logged error: the
    angle plus its jitter through the structure's dead band, the most probable count jump of
    the observed ``counts`` added."""
    z = cols.motion(x[None, :])[0] + x[0]
    noisy = z + 10.0 ** x[1] * rng.standard_normal((int(n_rep), z.size))
    half_w = 0.5 * x[cols.band_col] if cols.band_col is not None else 0.0
    sims = lrde_effects.relay(noisy, half_w)
    if cols.structure.count_jump:
        sims = sims + jump_placement(x, cols, counts).offsets
    return sims


def compare_loop_models(t, counts, reference, step, comparison, structures=tuple(STRUCTURES),
                        effects=LOOP_EFFECTS, min_z=2.0, fold_se=2.0, trust_z=-4.0, seed=0,
                        threads=1) -> dict:
    """The loop structures in the held-out comparison of the periodic models.

    Same folds (every other cycle of ``comparison``), same unit (the held-out cycle), same
    score (plug-in predictive density of a point fit with an eighth of a sample's time blur)
    as :func:`enclab.lrde.compare.compare_effect_models`, whose chosen model is the one to
    beat (the log's first cycle left out of every model's score: the loop's starting
    transient is seen only by a fold that trains on it). A structure replaces it when its
    held-out gain over it exceeds ``min_z`` standard errors, over every held-out cycle or
    over all but its most favourable one (:func:`_z_without_best`), no fold is predicted
    worse by more than ``fold_se`` of that fold's standard errors and its full-log BIC
    (log-likelihood under the same time blur, a parameter costing ``ln N``; a count jump one
    parameter) is lower; a structure later in the list replaces a passing one only by the
    same rule against it. The structures are ``structures``, then the one of them this rule
    chooses (else the one with the best held-out score) with each encoder term of
    ``effects`` (:data:`LOOP_EFFECTS`), fitted from its fits.
    A count jump is scored as in the periodic comparison: placed where the training fit puts
    it, anywhere between the two training samples around it with equal probability.
    Returns ``models`` (per structure: ``label, delta_elpd, delta_se, z, delta_bic,
    delta_elpd_halves``), ``chosen`` (label or None), ``alternatives`` (the dead-band
    structures the chosen one is pooled with: each predicts every fold better than the
    periodic pick and scores no more than ``min_z`` standard errors below the chosen),
    ``min_z``, ``fits`` (label -> whole-log point fit) and, for a chosen structure, ``check``
    (:func:`predictive_check`, ``trusted`` when ``z >= trust_z``).
    """
    from enclab.lrde import compare as lrde_compare

    t = np.asarray(t, dtype=float)
    counts = np.asarray(counts)
    cycle = np.asarray(comparison["cycle"])
    odd = (cycle % 2).astype(bool)
    folds = [(~odd, odd), (odd, ~odd)]
    error = error_steps(counts, reference, step)
    structures = [loop_structure(s) for s in structures]
    unknown = [e for e in effects if e not in LOOP_EFFECTS]
    if unknown:
        raise ValueError(f"loop structures take the encoder terms {list(LOOP_EFFECTS)}, "
                         f"got {unknown}")
    fold_fits, full = _fit_structures(t, counts, reference, step, structures, folds, threads)
    pick = comparison["chosen"]
    # The log's first cycle is left out of every model's held-out score: there the loop's
    # state at the start of the log (the transient p^j) is known only to a fold that trains
    # on it, and the other fold would be scored on a term it could not see.
    first = next(f for f, (_, test) in enumerate(folds) if test[0])
    units = {pick: list(comparison["heldout"][pick]["units"])}
    units[pick][first] = units[pick][first][1:]

    def score_units(label):
        cols = _Columns(error, label, counts)
        units[label] = [_heldout_units(m["x"], cols, counts, train, test, cycle)
                        for (train, test), m in zip(folds, fold_fits[label])]
        units[label][first] = units[label][first][1:]

    # Full-log log-likelihood under the same time blur, and parameter counts, for the BIC.
    blurred = {pick: float(comparison["full_fits"][pick]["log_lik_blurred"])}
    n_params = {pick: int(np.size(comparison["full_fits"][pick]["x"]))}

    def add(label):
        score_units(label)
        cols = _Columns(error, label, counts)
        offsets = (jump_placement(full[label]["x"], cols, counts).offsets
                   if cols.structure.count_jump else None)
        blurred[label] = float(_log_lik_rows(full[label]["x"], cols, counts, time_blur=0.125,
                                             offsets=offsets)[0])
        n_params[label] = int(np.size(full[label]["x"])) + int(cols.structure.count_jump)

    for s in structures:
        add(s.label)
    totals = lambda label: [float(u.sum()) for u in units[label]]  # noqa: E731

    def delta_bic(a, b):
        return (2.0 * (blurred[a] - blurred[b])
                - (n_params[a] - n_params[b]) * np.log(counts.size))

    def score(a, b):
        diffs = [x[:min(x.size, y.size)] - y[:min(x.size, y.size)]
                 for x, y in zip(units[a], units[b])]
        gains = [float(x - y) for x, y in zip(totals(a), totals(b))]
        ses = [lrde_compare._sum_se(d) for d in diffs]
        delta = float(sum(gains))
        se = lrde_compare._sum_se(np.concatenate(diffs))
        passed = bool(se > 0 and max(delta / se, _z_without_best(np.concatenate(diffs))) > min_z
                      and lrde_compare._no_fold_worse(gains, ses, fold_se)
                      and delta_bic(a, b) > 0)
        return delta, se, gains, passed

    plain = (loop_structure(_plain_for_terms([s.label for s in structures], pick,
                                             lambda a, b: score(a, b)[3],
                                             lambda label: sum(totals(label))))
             if structures else None)
    variants = ([plain.with_effect(e) for e in effects if e not in plain.effects]
                if plain is not None else [])
    if variants:
        # A dead band starts from the filter's own fits; a count jump from least squares
        # with a step column (a fit without the jump bends the filter around it).
        starts = {v.label: (fold_fits[plain.label], full[plain.label]) for v in variants
                  if not v.count_jump}
        more_folds, more_full = _fit_structures(t, counts, reference, step, variants, folds,
                                                threads, starts)
        fold_fits.update(more_folds)
        full.update(more_full)
        for v in variants:
            add(v.label)
    labels = [s.label for s in structures + variants]

    variant_labels = [v.label for v in variants]
    passed, chosen = _loop_choice(labels, pick, plain and plain.label, variant_labels,
                                  lambda a, b: score(a, b)[3])
    models = []
    for label in labels:
        delta, se, gains, _ = score(label, pick)
        n_units = sum(u.size for u in units[label])
        row = {"label": label, "over": pick,
               "elpd_per_cycle": float(sum(totals(label)) / max(n_units, 1)),
               "delta_elpd": delta, "delta_se": se,
               "z": delta / se if se > 0 else None, "delta_elpd_halves": gains,
               "delta_bic": float(delta_bic(label, pick)), "passed": passed[label]}
        if label in variant_labels:
            d_plain, se_plain, _, passed_plain = score(label, plain.label)
            row["over_plain"] = {"label": plain.label, "delta_elpd": d_plain,
                                 "delta_se": se_plain, "passed": passed_plain}
        models.append(row)
    alternatives = _loop_alternatives(variant_labels, chosen, pick, score, min_z)
    out = {"models": models, "chosen": chosen, "fits": full, "alternatives": alternatives,
           "min_z": min_z,
           "rule": (f"a loop structure replaces the periodic pick when its held-out gain over "
                    f"it exceeds {min_z:g} standard errors (over every held-out cycle, or over "
                    f"all but its most favourable one), it predicts no fold worse by "
                    f"more than {fold_se:g} of that fold's standard errors and its full-log "
                    "delta BIC over it is positive (the periodic comparison's folds, units "
                    "and time blur); more taps or an encoder term only by the same rule "
                    "against the structure without; the reported estimates pool the chosen "
                    "structure's posterior with those of the dead-band structures whose "
                    f"held-out score is no more than {min_z:g} standard errors below its own "
                    "and that predict each fold better than the periodic pick")}
    if chosen is not None:
        check = predictive_check(full[chosen], counts, reference,
                                 np.random.default_rng(seed))
        out["check"] = check | {"trusted": bool(check["z"] >= trust_z), "threshold_z": trust_z,
                                "localized": False, "local_z": None, "trace": {}}
    return out


def _z_without_best(diff) -> float:
    """z of the summed held-out gain over all units but the most favourable one.

    A gain held by one unit caps the z of the whole sum: with ``d`` on one of ``n`` units
    and ``g`` on each of the others, the standard error is ``d - g`` and ``z = 1 + n g /
    (d - g)``, which falls towards 1 the larger ``d`` is. A count jump is so: the cycle
    that holds it gains hundreds of nats, every other cycle a few to twenty (closed-loop
    benchmark, soft gains: 19 of 19 held-out cycles positive, z 1.5). Without that unit
    the gain stands on the others alone, so this z never counts it.
    """
    from enclab.lrde import compare as lrde_compare

    rest = np.delete(diff, np.argmax(diff)) if diff.size else diff
    se = lrde_compare._sum_se(rest)
    return float(rest.sum() / se) if se > 0 else -np.inf


def _loop_choice(labels, pick, plain, variants, passes) -> tuple[dict, str | None]:
    """``(passed, chosen)`` of the loop comparison's rule, ``passes(a, b)`` telling whether
    ``a`` beats ``b``: a label passes when it beats the periodic ``pick`` and, for one of
    the ``variants`` (``plain`` with an encoder term), ``plain`` too, whether or not
    ``plain`` beat the pick (else a term of no size could ride past the pick on a fold that
    ``plain`` predicts worse); in the order of ``labels``, a passing label replaces the one
    chosen before only when it beats it."""
    passed, chosen = {}, None
    for label in labels:
        passed[label] = bool(passes(label, pick)
                             and (label not in variants or passes(label, plain)))
        if passed[label] and (chosen is None or passes(label, chosen)):
            chosen = label
    return passed, chosen


def _plain_for_terms(labels, pick, passes, total) -> str:
    """The plain structure (of ``labels``) the encoder terms join: the one the rule of
    :func:`_loop_choice` chooses over the periodic ``pick``, else the one with the largest
    held-out ``total``. Not simply the best-scoring one: a tap that scores a little better by
    chance, short of passing against the structure without it, would otherwise carry the dead
    band, and the chosen structure would be pooled with a band structure of a tap more (whose
    ensembles mix slowly) instead of its own."""
    chosen = _loop_choice(labels, pick, None, [], passes)[1]
    return chosen if chosen is not None else max(labels, key=total)


def _loop_alternatives(variants, chosen, pick, score, min_z) -> list:
    """The dead-band structures among ``variants`` pooled with the ``chosen`` one: each
    predicts every fold better than the periodic ``pick`` and scores on the held-out cycles
    no more than ``min_z`` standard errors below ``chosen``, or above it; ``score(a, b)``
    gives ``(delta, se, fold gains, passed)`` of ``a`` over ``b``.

    Unlike the periodic comparison's alternatives, one holding the chosen's terms and more
    counts: the plain filter takes a narrow dead band in by moving its pole, so the two
    score alike while their strokes differ by more than their widths
    (docs/low-resolution-encoder.md). A count jump is no such term: where there is none, a
    jump placed anyway loses hundreds of nats on its one cycle, which the standard error of
    the sum, swollen by that cycle, does not rule out.
    """
    out = []
    for label in variants if chosen is not None else ():
        if label == chosen or not loop_structure(label).dead_band:
            continue
        delta, se = score(label, chosen)[:2]
        if min(score(label, pick)[2]) > 0 and delta > -min_z * se:
            out.append(label)
    return out


def _fit_structures(t, counts, reference, step, structures, folds, threads, starts=None):
    """Point fits of each structure on the whole log and on each fold's training cycles:
    ``({label: [fold fits]}, {label: whole-log fit})``. ``starts`` (label -> (fold fits,
    whole-log fit) of the structure without encoder terms) start them; else a fold's fit
    starts at the structure's whole-log fit (as the periodic comparison's folds start at the
    whole log's sinusoid), and a whole-log fit of a structure with taps is the better of
    least squares and the fit of the one with a tap fewer. The pole ``p`` of the lag and a
    tap (a pole at 0) trade places: from least squares alone a fit on half the cycles, or a
    structure with a tap on the whole log, can end at ``p`` near 0, far from the whole log's
    pole, and lose to the periodic pick for it."""
    starts = starts or {}
    full = dict(zip([s.label for s in structures], parallel.map_forked(_whole_log_job, [
        (t, counts, reference, step, s.label,
         None if starts.get(s.label) is None else starts[s.label][1]["x"])
        for s in structures], threads)))
    jobs = []
    for s in structures:
        own = starts.get(s.label)
        jobs += [(t, counts, reference, step, s.label, train,
                  full[s.label]["x"] if own is None else own[0][f]["x"])
                 for f, (train, _) in enumerate(folds)]
    fits = parallel.map_forked(_point_job, jobs, threads)
    n = len(folds)
    fold_fits = {s.label: fits[n * i:n * (i + 1)] for i, s in enumerate(structures)}
    return fold_fits, full


def _heldout_units(x, cols, counts, train, test, cycle):
    """Per held-out cycle, the plug-in log predictive density of its readings (time blur of
    an eighth of a sample)."""
    if not cols.structure.count_jump:
        lp = _log_lik_rows(x, cols, counts, time_blur=0.125, pointwise=True)[0][test]
    else:
        placed = jump_placement(x, cols, counts, mask=train)
        lp0 = _log_lik_rows(x, cols, counts, time_blur=0.125, pointwise=True,
                            offsets=np.zeros(cols.n))[0]
        lpd = _log_lik_rows(x, cols, counts, time_blur=0.125, pointwise=True,
                            offsets=np.full(cols.n, placed.delta))[0]
        configs = [placed.offsets_at(g) != 0 for g in placed.gaps]
        totals = np.array([np.where(c, lpd, lp0)[test].sum() for c in configs])
        total = float(logsumexp(totals) - np.log(totals.size))
        lp = np.where(configs[int(np.argmax(totals))], lpd, lp0)[test]
        lp = lp + (total - lp.sum()) / lp.size
    _, unit = np.unique(cycle[test], return_inverse=True)
    return np.bincount(unit, weights=lp)


def _point_job(t, counts, reference, step, structure, train, start=None, also=()):
    """The best (highest log-posterior) of the point fits from ``start`` (least squares when
    None) and from each row of ``also``."""
    fits = [point_fit(t, counts, reference, step, structure, mask=train, start=x)
            for x in (start, *also)]
    return max(fits, key=lambda m: m["log_post"])


def _whole_log_job(t, counts, reference, step, structure, start=None):
    """The whole-log point fit from ``start``; with none, the better of least squares and,
    for a structure with taps and no encoder term, the fit of the one with a tap fewer
    extended by a tap at 0 (it holds that structure, so its fit from there is never worse).
    A count jump keeps its own start (least squares with a step column): its fits cost
    several times a plain one's."""
    s = loop_structure(structure)
    if start is not None or s.taps == 0 or s.effects:
        return _point_job(t, counts, reference, step, s, None, start)
    fewer = LoopFilter(s.taps - 1)
    # That structure's own job fits it too; fitting it again here (a fraction of a second)
    # keeps every whole-log fit in one round of the pool instead of two.
    base = _whole_log_job(t, counts, reference, step, fewer)["x"]
    nested = np.insert(base[:3 + fewer.n_coefficients], 3 + 3 + fewer.taps, 0.0)
    return _point_job(t, counts, reference, step, s, None, None, (nested,))


def posterior_predictive_dwell(result, t, counts, reference, seed, n_draws=40):
    """Per-cycle dwell half-widths of readings simulated from posterior draws of a loop fit,
    each reading drawn from the angle the logged errors set (as
    :func:`enclab.lrde.plots.posterior_predictive_dwell`)."""
    import pandas as pd

    from enclab.lrde import dwell

    rng = np.random.default_rng(seed)
    cols = _Columns(error_steps(counts, reference, result.step), result.structure, counts)
    idx = rng.choice(result.loop_samples.shape[0], size=int(n_draws), replace=False)
    frames = []
    for d, i in enumerate(idx):
        x = result.loop_samples[i]
        z = cols.motion(x)[0] + x[0] + 10.0 ** x[1] * rng.standard_normal(cols.n)
        readings = lrde_effects.relay(z, 0.5 * x[cols.band_col] if cols.band_col is not None
                                      else 0.0)[0]
        if result.jump_offsets is not None:
            readings = readings + result.jump_offsets
        table = dwell.cycle_table(readings, t, result.step, f_hz=float(result.samples[i, 2]))
        frames.append(pd.DataFrame({"draw": d, "cycle": table["cycle"], "w1": table["w1"],
                                    "w2": table["w2"], "steps_pp": table["steps_pp"]}))
    return pd.concat(frames, ignore_index=True)
