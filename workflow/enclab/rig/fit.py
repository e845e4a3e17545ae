"""Rig fit: several runs of one rig analysed together, shared effects proven on held-out runs.

A rig is a set of runs (logs) of one machine under different conditions (frequency, load, ...),
each with a truth channel ``theta`` (e.g. a fine motor encoder through a gear) and a measured
channel (e.g. an output encoder). The measured reading of run ``k`` is modelled as

.. math::

    y = P_{w_k}(\\theta) + c_k - \\tau_k \\dot P + s\\,(a - a_{mid}) + m(a) + \\sum_j \\kappa_j f_j(T)

with **per-run** effects (they may change from run to run and are refitted on every run,
held-out runs included): the offset ``c_k`` (a counter's zero), the play width ``w_k`` of a
gear's backlash (:func:`enclab.residuals.effects.play_operator` ``P``) and the latency
``tau_k`` (a delay of the measured side: ``y(t - tau) ~ y - tau * dy/dt``; or one latency for
the rig, ``RigSpec(latency="shared")``); and **shared**
effects (one value for the rig, fitted on training runs only and applied unchanged to held-out
runs): the scale ``s``, the calibration map ``m`` of the measured-side angle ``a`` (the reading
itself; :class:`enclab.residuals.calibration.MapBasis`) and the compliance coefficients
``kappa`` against one or more logged torques (:func:`enclab.residuals.calibration.compliance_columns`),
optionally with a torque map (``RigSpec(torque_map=...)``: a spline of a torque, the take-up
curve of the transmission, on the torque range every group of training runs covers,
:func:`torque_range`).

Fit: given the play widths, the model is linear; the per-run offset and latency are projected
out run by run (Frisch-Waugh), so the shared coefficients solve one small normal-equation system
summed over training runs, with each run's play-width step (the play's derivative in its
width, linear) projected out too: Gauss-Newton on the widths, started from each run's own
bounded search. Intervals of the shared terms (and the map's
band) come from the delete-one-run jackknife over the training runs: the residual of a slow motion
is strongly autocorrelated within a run, runs are the independent units.

Scoring a held-out run refits only its per-run effects (3 parameters on thousands of samples)
with every shared term fixed at its training value. Two residual std are reported:
``steady`` (strokes where the play is taken up: more than ``travel`` rad of truth motion since the
last reversal) and ``all`` (every sample after ``t_skip``). The residual is the *error*
``reading - prediction`` (its floor is the quantization of both channels,
``sqrt((step**2 + truth_step**2) / 12)``).

Splits (:func:`make_folds`): by a condition (train on some values, test on others; or leave one
value out) and leave-one-run-out.

Choices made on held-out data (:func:`choose_model`), on each fold's training runs alone with
groups of them held out in turn (:func:`inner_groups`: by the fold's condition): the knot
spacing, and the model form (:func:`takeup_variants`: the declared compliance or the play
take-up ``tanh(T / T0)`` in place of ``T|T|``, with or without the reversal transient) and
the number of intervals of a torque map (on every sample, as the knot spacing). An
input-side calibration map (harmonics of ``gear_ratio * truth``) is available when a gear ratio
is declared (``RigSpec(gear_ratio=..., input_harmonics=...)``).

Where the fit holds (:func:`extrapolation`): a condition split whose held-out error is well above
the other splits' or its training runs' own held-out error does not extrapolate to its test
conditions; each group of shared terms refitted on the test runs alone says which one carries the
excess (:func:`refit_shared`), and :func:`coverage` lists the conditions the runs covered.
"""
from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from enclab.residuals.calibration import MapBasis, compliance_columns, compliance_names
from enclab.residuals.effects import motion_sign, play_operator

__all__ = ["Run", "RigSpec", "RigFit", "steady_mask", "fit_rig", "predict_run", "score_run",
           "choose_spacing", "choose_variant", "heldout_per_run", "n_shared", "input_columns",
           "choose_model", "takeup_variants", "heldout_rms",
           "inner_groups", "make_folds", "declared_compliance", "torque_map_basis", "torque_range", "resolve_torque_map",
           "evaluate", "pooled", "fold_spread", "loose_parameters", "floor_std", "map_range",
           "term_groups", "refit_shared", "coverage", "extrapolation"]


@dataclass
class Run:
    """One run of a rig: time (s), truth and measured angles (rad), their steps, the logged
    torques ``{channel: N m}`` and the run's conditions ``{name: value}``."""

    run_id: str
    t: np.ndarray
    truth: np.ndarray
    measured: np.ndarray
    step: float
    truth_step: float | None = None
    torques: dict = field(default_factory=dict)
    conditions: dict = field(default_factory=dict)

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=np.float64)
        self.truth = np.asarray(self.truth, dtype=np.float64)
        self.measured = np.asarray(self.measured, dtype=np.float64)
        n = self.t.size
        for name, arr in [("truth", self.truth), ("measured", self.measured)] + \
                [(f"torque {k}", np.asarray(v)) for k, v in self.torques.items()]:
            if arr.shape != (n,):
                raise ValueError(f"run {self.run_id!r}: {name} has shape {arr.shape}, time has {n} samples")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"run {self.run_id!r}: {name} is not finite at row "
                                 f"{int(np.flatnonzero(~np.isfinite(arr))[0])}")
        if n < 3 or np.any(np.diff(self.t) <= 0):
            raise ValueError(f"run {self.run_id!r}: time must hold >= 3 strictly increasing stamps")
        self.torques = {k: np.asarray(v, dtype=np.float64) for k, v in self.torques.items()}


@dataclass(frozen=True)
class RigSpec:
    """What the rig model contains.

    Parameters
    ----------
    play, latency, scale : bool
        Per-run play width and latency (``latency="shared"``: one latency for the rig, a
        column ``-d theta / dt`` of the truth); the shared scale.
    spacing : float or None
        Knot spacing (rad) of the calibration map; ``None`` = no map.
    compliance : dict
        ``{torque channel: [term, ...]}`` (terms ``linear``, ``signed_square``, ``saturating``);
        empty = none.
    torque_scales : dict
        ``{torque channel: T0}`` (N m) of the ``saturating`` terms (play take-up ``tanh(T / T0)``).
    torque_map : dict
        ``{torque channel: n}`` or ``{torque channel: (lo, hi, n)}``: the take-up curve of the
        transmission, a shared cubic spline of the torque with ``n`` equal intervals over
        ``[lo, hi]`` (N m), its constant and linear parts removed (the linear part is the
        ``linear`` compliance term), continued along its end slopes outside the range. Without a range
        it is resolved on the training runs (:func:`resolve_torque_map`).
    max_play : float
        Upper bound of the play width (rad).
    transient : float or None
        Knot spacing (rad of truth travel) of a shared reversal transient: a spline in the
        truth's travel since the last reversal, odd in the direction of motion, vanishing from
        ``travel`` on (the mean motion of the measured side inside the play that a play
        operator cannot follow); ``None`` = none.
    gear_ratio : float or None
        Input angle per truth angle (e.g. 35 for a 35:1 gear whose input encoder, read on the
        output side, is the truth): the input-side map's angle is ``gear_ratio * truth``.
    input_harmonics : int
        Harmonics per input-side revolution of the input-side calibration map (0 = none): a
        repeatable error of the input encoder or the gear mesh, periodic in the input angle
        (a spline of the output angle cannot hold it once a stroke spans many input turns).
    torque_map_forms : tuple of str
        Forms of a torque map offered by :func:`takeup_variants` (``"linear"``: continued along
        its end slopes; ``"flat"``: a bounded take-up beside the linear stiffness,
        :func:`torque_map_basis`); a map's own form is the fourth entry of its
        ``(lo, hi, n, form)`` (default ``"linear"``).
    travel, t_skip : float
        Steady strokes: more than ``travel`` rad since the last reversal; every score leaves
        out the first ``t_skip`` s (and the fit does too).
    n_iter : int
        Largest number of Gauss-Newton passes over the play widths (they stop when no width
        moves by more than 1e-7 rad).
    """

    play: bool = True
    latency: bool | str = True
    scale: bool = True
    spacing: float | None = 0.05
    compliance: Mapping = field(default_factory=dict)
    torque_scales: Mapping = field(default_factory=dict)
    torque_map: Mapping = field(default_factory=dict)
    max_play: float = 0.08
    transient: float | None = None
    gear_ratio: float | None = None
    input_harmonics: int = 0
    torque_map_forms: tuple = ("linear",)
    travel: float = 0.06
    t_skip: float = 1.5
    n_iter: int = 20

    def with_(self, **kw) -> RigSpec:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d.update(kw)
        return RigSpec(**d)


_CURVES = ("map", "transient", "input", "tmap")


@dataclass
class RigFit:
    """Shared coefficients and the training runs' per-run effects of a rig fit."""

    spec: RigSpec
    names: list            # names of the shared coefficients
    coef: np.ndarray       # shared coefficients
    cov: np.ndarray | None  # delete-one-run jackknife covariance (None with < 3 runs)
    basis: MapBasis | None
    a_mid: float
    per_run: dict          # run_id -> {"offset", "play_width", "latency"}
    train_ids: list
    jack_coef: np.ndarray | None = None  # (n_runs, n_coef) delete-one-run estimates

    def shared(self) -> dict:
        """``{name: value}`` of the scalar shared coefficients (scale, latency, compliance); the
        map and the reversal transient are curves (:meth:`map_curve`)."""
        out = {n: float(c) for n, c in zip(self.names, self.coef) if not n.startswith(_CURVES)}
        for n in list(out):
            channel, _, term = n.partition(":")
            if term == "saturating":
                out[f"{channel}:T0"] = float(self.spec.torque_scales[channel])
        return out

    def ci(self, z: float = 1.6449) -> dict:
        """``{name: (lo, hi)}`` 90 % intervals (jackknife) of the scalar shared coefficients."""
        if self.cov is None:
            return {}
        sd = np.sqrt(np.diag(self.cov))
        return {n: (float(c - z * s), float(c + z * s)) for n, c, s in zip(self.names, self.coef, sd)
                if not n.startswith(_CURVES)}

    def input_curve(self, phi, z: float = 1.6449):
        """The input-side calibration map at input angles ``phi`` (rad): ``(curve, lo, hi)``,
        what it adds to the reading (rad, measured side), with a 90 % jackknife band; zeros
        without one."""
        phi = np.asarray(phi, dtype=np.float64)
        idx = [i for i, n in enumerate(self.names) if n.startswith("input")]
        if not idx:
            zero = np.zeros_like(phi)
            return zero, zero, zero
        D = input_columns(phi, self.spec.input_harmonics)
        curve = D @ self.coef[idx]
        if self.cov is None:
            return curve, curve, curve
        sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", D, self.cov[np.ix_(idx, idx)], D), 0.0))
        return curve, curve - z * sd, curve + z * sd

    def torque_map_curve(self, channel: str, torque) -> np.ndarray:
        """The torque map of ``channel`` at ``torque`` (N m): the twist (rad) it adds to the
        linear compliance; zeros without one."""
        torque = np.asarray(torque, dtype=np.float64)
        rng = self.spec.torque_map.get(channel)
        if rng is None:
            return np.zeros_like(torque)
        idx = [i for i, n in enumerate(self.names) if n.startswith(f"tmap_{channel}")]
        return torque_map_basis(*rng).design(torque) @ self.coef[idx]

    def map_curve(self, a, z: float = 1.6449):
        """The calibration map at ``a``: ``(curve, lo, hi)`` with a 90 % jackknife band (the
        band is the curve itself when there is no interval)."""
        a = np.asarray(a, dtype=np.float64)
        if self.basis is None:
            zero = np.zeros_like(a)
            return zero, zero, zero
        idx = [i for i, n in enumerate(self.names) if n.startswith("map")]
        D = self.basis.design(a)
        curve = D @ self.coef[idx]
        if self.cov is None:
            return curve, curve, curve
        var = np.einsum("ij,jk,ik->i", D, self.cov[np.ix_(idx, idx)], D)
        sd = np.sqrt(np.maximum(var, 0.0))
        return curve, curve - z * sd, curve + z * sd


def floor_std(step: float, truth_step: float | None) -> float:
    """Std of the error ``reading - truth`` from quantization of both channels alone."""
    return float(np.sqrt((step**2 + (truth_step or 0.0) ** 2) / 12.0))


def steady_mask(t, truth, travel: float = 0.06, t_skip: float = 1.5) -> np.ndarray:
    """Samples after ``t_skip`` with more than ``travel`` rad of truth motion since the last
    reversal (a play narrower than ``travel`` is then taken up).

    The distance from the last turning point reaches ``travel`` exactly when a play operator of
    width ``travel`` is engaged again (its output rests ``travel / 2`` from the input on one side
    and must cross to the other), which also ignores dithering of the truth near a reversal.
    """
    t = np.asarray(t, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    follow = play_operator(truth, travel)
    return (t >= t[0] + t_skip) & (np.abs(truth - follow) >= 0.5 * travel * (1 - 1e-9))


# ----------------------------------------------------------------------------- model pieces


def reversal_travel(truth, hysteresis: float = 2e-4) -> tuple[np.ndarray, np.ndarray]:
    """Truth travel since the last reversal (rad, >= 0) and the direction of motion (+1/-1).

    A reversal is a change of direction of a play operator of width ``hysteresis`` (so that
    the dithering of a truth reading at rest is not a reversal); the travel is measured from
    the extreme of the truth before it.
    """
    x = np.asarray(truth, dtype=np.float64)
    p = play_operator(x, hysteresis)
    d = motion_sign(np.diff(p, prepend=p[0]))
    d[d == 0] = 1.0
    change = np.flatnonzero(np.diff(d) != 0) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [x.size]))
    travel = np.zeros_like(x)
    prev = None
    for s0, e0 in zip(starts, ends):
        seg = x[s0:e0]
        if prev is None:
            turn = seg[0]
        else:
            turn = np.max(x[prev[0]:prev[1]]) if d[s0] < 0 else np.min(x[prev[0]:prev[1]])
        travel[s0:e0] = np.maximum(d[s0] * (seg - turn), 0.0)
        prev = (s0, e0)
    return travel, d


def input_columns(phi, harmonics: int) -> np.ndarray:
    """``cos(k phi), sin(k phi)`` for ``k = 1..harmonics`` of the input angle ``phi`` (rad):
    the columns of the input-side calibration map (no constant: that is the offset)."""
    phi = np.asarray(phi, dtype=np.float64)
    k = np.arange(1, int(harmonics) + 1)
    return np.hstack([np.cos(np.outer(phi, k)), np.sin(np.outer(phi, k))])


def transient_columns(truth, spacing: float, travel: float) -> np.ndarray:
    """Columns of the reversal transient: cubic B-splines in the travel since the last
    reversal on ``[0, travel]`` (knots every ``spacing``), times the direction; the two that do
    not vanish with their slope at ``travel`` are dropped, so the transient ends smoothly."""
    from scipy.interpolate import BSpline

    dist, direction = reversal_travel(truth)
    n_int = max(int(np.ceil(travel / spacing - 1e-9)), 1)
    knots = np.concatenate(([0.0] * 3, np.linspace(0.0, travel, n_int + 1), [travel] * 3))
    inside = dist < travel
    B = np.zeros((dist.size, len(knots) - 4))
    if inside.any():
        B[inside] = BSpline.design_matrix(dist[inside], knots, 3).toarray()
    return B[:, :-2] * direction[:, None]


@functools.lru_cache(maxsize=256)
def torque_map_basis(lo: float, hi: float, n: int, form: str = "linear") -> MapBasis:
    """Basis of a torque map: cubic B-splines with ``n`` equal intervals over ``[lo, hi]``
    (N m) (:class:`MapBasis` on the torque). ``form="linear"``: constant and linear parts
    removed, continued along its end slopes beyond the range; ``"flat"``: a bounded take-up,
    zero slope at both ends, constant removed, held at its end values beyond the range (the
    ``linear`` compliance term is then the stiffness at both ends and beyond)."""
    n = int(n)
    if n < 1:
        raise ValueError(f"a torque map needs at least 1 interval, got {n}")
    if form not in ("linear", "flat"):
        raise ValueError(f"torque map form {form!r}: expected 'linear' or 'flat'")
    return MapBasis(float(lo), float(hi), (float(hi) - float(lo)) / n, extrapolate=form)


def torque_range(runs: Sequence[Run], channel: str, groups: Mapping | None = None,
                 t_skip: float = 0.0, q: float = 0.005) -> tuple[float, float]:
    """Range of a torque (N m) that every group of ``runs`` covers: the largest of the groups'
    ``q`` quantiles to the smallest of their ``1 - q`` quantiles (samples after ``t_skip``).

    A torque map is a spline: beyond the torques a fit sees it is unconstrained, and a map on
    the range of all runs together would be fitted where one group alone has data and
    extrapolate wildly when that group is held out. On the range every group covers, a held-out
    group is predicted inside the range by what the others saw, and beyond it by the end values
    and the linear compliance, as a new condition is.
    """
    groups = groups or {r.run_id: r.run_id for r in runs}
    by: dict = {}
    for r in runs:
        if channel not in r.torques:
            raise ValueError(f"run {r.run_id!r}: no torque channel {channel!r}; have {sorted(r.torques)}")
        by.setdefault(groups[r.run_id], []).append(r.torques[channel][r.t >= r.t[0] + t_skip])
    lo = max(float(np.quantile(np.concatenate(v), q)) for v in by.values())
    hi = min(float(np.quantile(np.concatenate(v), 1 - q)) for v in by.values())
    if not hi > lo:
        raise ValueError(f"torque {channel!r}: the groups of runs share no range "
                         f"(largest low quantile {lo:.4g} N m >= smallest high one {hi:.4g} N m)")
    return lo, hi


def resolve_torque_map(runs: Sequence[Run], spec: RigSpec, groups: Mapping | None = None,
                       n: int | None = None) -> RigSpec:
    """``spec`` with each torque map's range set to the range every group of ``runs`` covers
    (:func:`torque_range`) and (``n``) its number of intervals replaced."""
    if not spec.torque_map:
        return spec
    tm = {}
    for channel, v in spec.torque_map.items():
        lo, hi = torque_range(runs, channel, groups, spec.t_skip)
        tm[channel] = (lo, hi, int(n if n is not None else (v if np.ndim(v) == 0 else v[2])),
                       *(() if np.ndim(v) == 0 else tuple(v[3:])))
    return spec.with_(torque_map=tm)


def declared_compliance(declared: Mapping, n_intervals: int = 8) -> dict:
    """``{"compliance": ..., "torque_map": ...}`` (:meth:`RigSpec.with_` keywords) of a declared
    compliance ``{torque channel: [term, ...]}`` whose terms may include ``map``: that channel's
    torque map, with ``n_intervals`` intervals until they are chosen on held-out runs and the
    ``linear`` term beside it (the map has its slope removed: the linear term carries it)."""
    compliance, torque_map = {}, {}
    for channel, terms in declared.items():
        terms = list(terms)
        if "map" in terms:
            torque_map[channel] = int(n_intervals)
            terms = ["linear"] + [t for t in terms if t not in ("map", "linear")]
        compliance[channel] = terms
    return {"compliance": compliance, "torque_map": torque_map}


def _shared_columns(run: Run, spec: RigSpec, basis: MapBasis | None, a_mid: float):
    names, cols = [], []
    a = run.measured
    if spec.scale:
        names.append("scale")
        cols.append((a - a_mid)[:, None])
    if spec.latency == "shared":
        names.append("latency")
        cols.append(-np.gradient(run.truth, run.t)[:, None])
    if basis is not None:
        D = basis.design(a)
        names += [f"map{j}" for j in range(D.shape[1])]
        cols.append(D)
    if spec.compliance:
        names += compliance_names(spec.compliance)
        cols.append(compliance_columns(spec.compliance, run.torques, spec.torque_scales))
    for channel, rng in spec.torque_map.items():
        if np.ndim(rng) == 0:
            raise ValueError(f"run {run.run_id!r}: the torque map of {channel!r} has no range; "
                             "resolve it on the training runs (resolve_torque_map)")
        if channel not in run.torques:
            raise ValueError(f"run {run.run_id!r}: the torque map needs torque channel {channel!r}; "
                             f"have {sorted(run.torques)}")
        D = torque_map_basis(*rng).design(run.torques[channel])
        names += [f"tmap_{channel}{j}" for j in range(D.shape[1])]
        cols.append(D)
    if spec.input_harmonics:
        if not spec.gear_ratio:
            raise ValueError(f"run {run.run_id!r}: an input-side map needs a gear ratio")
        k = range(1, spec.input_harmonics + 1)
        names += [f"input_cos{j}" for j in k] + [f"input_sin{j}" for j in k]
        cols.append(input_columns(spec.gear_ratio * run.truth, spec.input_harmonics))
    if spec.transient:
        T = transient_columns(run.truth, spec.transient, spec.travel)
        names += [f"transient{j}" for j in range(T.shape[1])]
        cols.append(T)
    X = np.hstack(cols) if cols else np.zeros((a.size, 0))
    return names, X


def _played(run: Run, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Played truth and its time derivative."""
    p = play_operator(run.truth, width) if width > 0 else run.truth
    return p, np.gradient(p, run.t)


def _nuisance(spec: RigSpec, dp: np.ndarray) -> np.ndarray:
    cols = [np.ones_like(dp)]
    if spec.latency is True:
        cols.append(-dp)
    return np.column_stack(cols)


def _fit_mask(run: Run, spec: RigSpec) -> np.ndarray:
    return run.t >= run.t[0] + spec.t_skip


def _per_run(run: Run, spec: RigSpec, shared_pred: np.ndarray, around: float | None = None) -> dict:
    """Per-run effects given the shared part of the prediction: the play width by a bounded
    search (coarse grid, then Brent; ``around``: Brent within 2 mrad of a known width), the
    offset and latency by least squares."""
    mask = _fit_mask(run, spec)
    z = run.measured - shared_pred

    def solve(width):
        p, dp = _played(run, width)
        N = _nuisance(spec, dp)[mask]
        y = (z - p)[mask]
        # Least squares on 1 or 2 columns: the normal equations (an SVD per width costs more
        # than the play operator); lstsq when they are singular (a run at rest).
        try:
            beta = np.linalg.solve(N.T @ N, N.T @ y)
        except np.linalg.LinAlgError:
            beta = np.linalg.lstsq(N, y, rcond=None)[0]
        res = y - N @ beta
        return float(res @ res), beta

    width = 0.0
    if spec.play:
        grid = np.linspace(0.0, spec.max_play, 17) if around is None else \
            np.clip(np.array([around - 2e-3, around, around + 2e-3]), 0.0, spec.max_play)
        rss = [solve(w)[0] for w in grid]
        i = int(np.argmin(rss))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        res = optimize.minimize_scalar(lambda w: solve(w)[0], bounds=(lo, hi), method="bounded",
                                       options={"xatol": 1e-6})
        width = float(res.x) if res.fun <= rss[i] else float(grid[i])
    _, beta = solve(width)
    return {"offset": float(beta[0]), "play_width": width,
            "latency": float(beta[1]) if spec.latency is True else 0.0}


def _prediction(run: Run, spec: RigSpec, shared_pred: np.ndarray, per: Mapping) -> np.ndarray:
    p, dp = _played(run, per["play_width"])
    return p + per["offset"] - per["latency"] * dp + shared_pred


def _play_derivative(p: np.ndarray) -> np.ndarray:
    """``d P_w(theta) / d w``: ``-1/2`` times the side the play rests on (the direction of the
    output's last motion), both while it follows the input and while it dwells."""
    return -0.5 * motion_sign(np.diff(p, prepend=p[0]))


def _columns(runs, spec, basis, a_mid) -> tuple[list, dict]:
    """Names and, per run id, ``(X, X'X)`` of the shared columns on the fit samples: they do
    not depend on the play widths, so a fit computes them once, not once per width update."""
    names, cols = [], {}
    for run in runs:
        names, X = _shared_columns(run, spec, basis, a_mid)
        X = np.ascontiguousarray(X[_fit_mask(run, spec)])
        cols[run.run_id] = (X, X.T @ X)
    return names, cols


def _normal_equations(runs, spec, basis, a_mid, widths, play_step: bool = False, columns=None):
    """Per-run ``(G, h, q, z, N, X)`` of the shared columns after projecting out the run's
    offset, latency and (``play_step``) the linearised play width (fit samples only):
    ``G = Xp'Xp`` and ``h = Xp'zp`` of the projected columns ``Xp = X - q q'X`` and reading
    ``zp = z - q q'z`` (``q``: an orthonormal basis of the nuisance columns ``N``), formed as
    ``X'X - (q'X)'(q'X)`` so that the projected columns are never built. ``columns``: the
    :func:`_columns` of ``runs`` (computed here when absent)."""
    names, cols = _columns(runs, spec, basis, a_mid) if columns is None else columns
    out = []
    for run in runs:
        X, G0 = cols[run.run_id]
        p, dp = _played(run, widths[run.run_id])
        m = _fit_mask(run, spec)
        N = _nuisance(spec, dp)
        if play_step and spec.play:
            N = np.column_stack([N, _play_derivative(p)])
        N = N[m]
        z = (run.measured - p)[m]
        q, _ = np.linalg.qr(N)
        A = q.T @ X
        b = q.T @ z
        out.append((G0 - A.T @ A, X.T @ z - A.T @ b, q, z, N, X))
    return names, out


def _solve(G, h):
    if G.shape[0] == 0:
        return np.zeros(0)
    return np.linalg.lstsq(G, h, rcond=None)[0]


def _jackknife(eqs):
    G = sum(e[0] for e in eqs)
    h = sum(e[1] for e in eqs)
    n = len(eqs)
    if n < 3 or G.shape[0] == 0:
        return None, None
    jack = np.array([_solve(G - g, h - hh) for g, hh, *_ in eqs])
    d = jack - jack.mean(axis=0)
    return (n - 1) / n * d.T @ d, jack


def map_range(runs: Sequence[Run], t_skip: float = 0.0) -> tuple[float, float]:
    """Range of the measured-side angle over ``runs`` (rad), samples after ``t_skip`` only
    (those the fit sees: a map beyond them would be unconstrained)."""
    keep = [r.measured[r.t >= r.t[0] + t_skip] for r in runs]
    return (float(min(np.min(k) for k in keep)), float(max(np.max(k) for k in keep)))


def make_basis(runs: Sequence[Run], spacing: float, t_skip: float = 0.0) -> MapBasis:
    """The map's basis over the runs' range; its scale is the slope over the middle 90 % of
    the range (the ends are where the motion reverses)."""
    lo, hi = map_range(runs, t_skip)
    return MapBasis(lo, hi, float(spacing), ref=(lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo)))


def fit_rig(runs: Sequence[Run], spec: RigSpec, widths: Mapping | None = None) -> RigFit:
    """Fit the rig model on ``runs`` (the training runs).

    Parameters
    ----------
    runs : sequence of Run
    spec : RigSpec
    widths : dict, optional
        Starting play widths per run id (default: each run's own fit without shared terms).

    Returns
    -------
    RigFit
    """
    if not runs:
        raise ValueError("a rig fit needs at least one run")
    if any(np.ndim(v) == 0 for v in spec.torque_map.values()):
        spec = resolve_torque_map(runs, spec)
    lo, hi = map_range(runs, spec.t_skip)
    basis = make_basis(runs, spec.spacing, spec.t_skip) if spec.spacing else None
    a_mid = 0.5 * (lo + hi)
    zero = {r.run_id: np.zeros_like(r.t) for r in runs}
    per = {r.run_id: _per_run(r, spec, zero[r.run_id]) for r in runs} if widths is None else \
        {r.run_id: {"play_width": float(widths[r.run_id])} for r in runs}
    coef = np.zeros(0)
    names: list = []
    eqs: list = []
    # Gauss-Newton on the play widths: each pass solves the shared terms with every run's
    # offset, latency and play-width step projected out, then moves the widths by their steps
    # (an alternation of the two would converge slowly: widths and shared terms are coupled).
    columns = _columns(runs, spec, basis, a_mid)
    for _ in range(max(spec.n_iter, 1)):
        w = {k: v["play_width"] for k, v in per.items()}
        names, eqs = _normal_equations(runs, spec, basis, a_mid, w, play_step=True, columns=columns)
        coef = _solve(sum(e[0] for e in eqs), sum(e[1] for e in eqs))
        if not spec.play:
            break
        moved = 0.0
        for run, e in zip(runs, eqs):
            N, z, X = e[4], e[3], e[5]
            beta, *_ = np.linalg.lstsq(N, z - X @ coef, rcond=None)
            new = float(np.clip(w[run.run_id] + beta[-1], 0.0, spec.max_play))
            moved = max(moved, abs(new - w[run.run_id]))
            per[run.run_id] = {"play_width": new}
        if moved < 1e-7:
            break
    shared = {r.run_id: _shared_columns(r, spec, basis, a_mid)[1] @ coef for r in runs}
    per = {r.run_id: _per_run(r, spec, shared[r.run_id], around=per[r.run_id]["play_width"]) for r in runs}
    cov, jack = _jackknife(eqs)
    return RigFit(spec=spec, names=list(names), coef=coef, cov=cov, basis=basis, a_mid=a_mid,
                  per_run=per, train_ids=[r.run_id for r in runs], jack_coef=jack)


def predict_run(fit: RigFit, run: Run, around: float | None = None) -> tuple[np.ndarray, dict]:
    """Prediction of a run with the shared terms of ``fit`` fixed and the run's own effects
    (offset, play width, latency) fitted on it (``around``: its play width searched within 2
    mrad of this one). Returns ``(prediction, per-run effects)``."""
    _, X = _shared_columns(run, fit.spec, fit.basis, fit.a_mid)
    shared = X @ fit.coef
    per = _per_run(run, fit.spec, shared, around=around)
    return _prediction(run, fit.spec, shared, per), per


def score_run(run: Run, prediction: np.ndarray, spec: RigSpec) -> dict:
    """``steady`` and ``all`` residual std (rad) of ``reading - prediction`` and sample counts."""
    e = run.measured - prediction
    steady = steady_mask(run.t, run.truth, spec.travel, spec.t_skip)
    every = _fit_mask(run, spec)
    return {"steady_std": float(np.std(e[steady])) if steady.any() else float("nan"),
            "all_std": float(np.std(e[every])), "n_steady": int(steady.sum()), "n_all": int(every.sum()),
            "steady_ss": float(np.sum((e[steady] - e[steady].mean()) ** 2)) if steady.any() else 0.0,
            "all_ss": float(np.sum((e[every] - e[every].mean()) ** 2))}


def heldout_rms(runs: Sequence[Run], spec: RigSpec, widths: Mapping,
                groups: Mapping | None = None, on: str = "all") -> float:
    """Rms residual of each group of ``runs`` under the shared terms fitted without it
    (:func:`heldout_per_run` pooled)."""
    ss, n = heldout_per_run(runs, spec, widths, groups, on)
    return float(np.sqrt(ss.sum() / n.sum()))


def heldout_per_run(runs: Sequence[Run], spec: RigSpec, widths: Mapping,
                    groups: Mapping | None = None, on: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """Sum of squared residuals and number of samples of each run (in the order of ``runs``),
    each group of ``runs`` scored under the shared terms fitted without it.

    The play widths start at ``widths``; the shared terms of ``spec`` are refitted without
    each group in turn (from the summed normal equations, minus the group's), and the left-out
    runs' residual is taken after refitting their own offset, latency and play width (one
    linearised step). ``groups``:
    ``{run id: group}`` (default: every run its own group, leave-one-run-out). ``on``: the
    samples scored, ``"all"`` (after ``t_skip``) or ``"steady"`` (:func:`steady_mask`).
    """
    if on not in ("all", "steady"):
        raise ValueError(f"held-out score on {on!r}: expected 'all' or 'steady'")
    groups = groups or {r.run_id: r.run_id for r in runs}
    if len({groups[r.run_id] for r in runs}) < 2:
        raise ValueError("a held-out choice needs at least 2 groups of runs")
    lo, hi = map_range(runs, spec.t_skip)
    basis = make_basis(runs, spec.spacing, spec.t_skip) if spec.spacing else None
    # The left-out runs' play widths are refitted too (their linearised step, like a held-out
    # run's own width): widths fitted under one form would otherwise favour that form.
    _, eqs = _normal_equations(runs, spec, basis, 0.5 * (lo + hi), widths, play_step=True)
    G = sum(e[0] for e in eqs)
    h = sum(e[1] for e in eqs)
    ss, n = np.zeros(len(runs)), np.zeros(len(runs))
    keep = {r.run_id: (steady_mask(r.t, r.truth, spec.travel, spec.t_skip)[_fit_mask(r, spec)]
                       if on == "steady" else slice(None)) for r in runs}
    for key in dict.fromkeys(groups[r.run_id] for r in runs):
        inside = [(k, r.run_id, e) for k, (r, e) in enumerate(zip(runs, eqs)) if groups[r.run_id] == key]
        beta = _solve(G - sum(e[0] for *_, e in inside), h - sum(e[1] for *_, e in inside))
        for k, run_id, (_, _, q, z, _, X) in inside:
            v = z - X @ beta
            r = (v - q @ (q.T @ v))[keep[run_id]]
            ss[k] = float(r @ r)
            n[k] = r.size
    return ss, n


def choose_spacing(runs: Sequence[Run], spec: RigSpec, candidates: Sequence[float],
                   widths: Mapping | None = None, groups: Mapping | None = None) -> tuple[float, dict]:
    """Knot spacing of the map with the least held-out error over ``runs``
    (:func:`heldout_rms`; the play widths of a fit with ``spec``, its own spacing, unless
    given). Returns ``(best spacing, {spacing: held-out rms})``."""
    if len(runs) < 2:
        raise ValueError("choosing the knot spacing on held-out runs needs at least 2 runs")
    if widths is None:
        base = fit_rig(runs, spec)
        widths = {k: v["play_width"] for k, v in base.per_run.items()}
    scores = {float(s): heldout_rms(runs, spec.with_(spacing=float(s)), widths, groups) for s in candidates}
    best = min(scores, key=scores.get)
    return best, scores


def takeup_variants(runs: Sequence[Run], spec: RigSpec, relative: Sequence[float] = (0.1, 0.2, 0.4, 0.8),
                    transient: bool = True, drop_channels: bool = True) -> list[dict]:
    """Candidate compliance forms and reversal transients to choose from on held-out runs.

    For every torque channel declared with ``signed_square``, a candidate replaces it with the
    play take-up ``saturating`` ``tanh(T / T0)``, ``T0`` = each of ``relative`` times the
    channel's std over ``runs`` (no constant of a particular rig). With ``drop_channels`` and
    more than one torque channel declared, the declared form also comes without each channel
    in turn: torques of one drive are correlated, and a channel whose term is only fitted to
    what another channel's curve leaves at the training conditions changes sign with the
    conditions it is fitted on (a coefficient no rig has) and predicts new conditions worse.
    With ``transient`` (and a
    transient in ``spec``) each candidate also comes without the reversal transient: the
    transient is a function of travel, the take-up one of torque, and at the training runs'
    loads the two can coincide. Every form with a torque map also comes with the map in each
    further form of ``spec.torque_map_forms`` (``"flat"``: a bounded take-up beside the linear
    stiffness, :func:`torque_map_basis`). Returns a list of :meth:`RigSpec.with_` keyword dicts,
    the declared form first.
    """
    channels = [c for c, terms in spec.compliance.items() if "signed_square" in terms]
    forms = [{}]
    for q in relative:
        if not channels:
            break
        comp = {c: [("saturating" if t == "signed_square" else t) for t in terms]
                for c, terms in spec.compliance.items()}
        scales = {c: float(q * np.std(np.concatenate([r.torques[c] for r in runs]))) for c in channels}
        forms.append({"compliance": comp, "torque_scales": scales})
    if drop_channels and len(spec.compliance) > 1:
        for channel in spec.compliance:
            forms.append({"compliance": {c: t for c, t in spec.compliance.items() if c != channel},
                          "torque_scales": {c: v for c, v in spec.torque_scales.items() if c != channel},
                          "torque_map": {c: v for c, v in spec.torque_map.items() if c != channel}})
    # Other forms of the torque maps (a bounded take-up beside the stiffness: it extrapolates
    # as a gear does, where a spline continued along its end slopes only interpolates).
    for form in [f for f in spec.torque_map_forms if f != "linear"]:
        for f in list(forms):
            tm = f.get("torque_map", spec.torque_map)
            if tm and all(np.ndim(v) > 0 for v in tm.values()):
                forms.append({**f, "torque_map": {c: (*v[:3], form) for c, v in tm.items()}})
    if transient and spec.transient:
        forms = forms + [{**f, "transient": None} for f in forms]
    return forms


def n_shared(run: Run, spec: RigSpec) -> int:
    """Number of shared coefficients of ``spec`` (its torque maps resolved)."""
    basis = make_basis([run], spec.spacing, spec.t_skip) if spec.spacing else None
    return len(_shared_columns(run, spec, basis, 0.0)[0])


def choose_variant(runs: Sequence[Run], spec: RigSpec, variants: Sequence[Mapping],
                   widths: Mapping | None = None, groups: Mapping | None = None,
                   on: str = "steady") -> tuple[RigSpec, list]:
    """The variant of ``spec`` (:meth:`RigSpec.with_` keyword dicts) chosen on held-out error
    (:func:`heldout_per_run`) on steady strokes (``on``): a compliance is a twist of the
    transmission under load, what the steady strokes show; the reversal windows are dominated by
    the motion inside the play, which a more flexible transient always fits better in-sample
    and which varies from one reversal to the next.

    One-standard-error rule: of the variants whose held-out mean square lies within one
    standard error of the best one's (the error of their difference, runs as units), the one
    with the fewest shared coefficients (then the least error). A term that buys less than the
    run-to-run scatter of the held-out gain is not supported by the runs: kept, its coefficient
    follows whichever conditions it was fitted on. Returns ``(chosen spec, [held-out rms per
    variant])``."""
    if widths is None:
        base = fit_rig(runs, spec)
        widths = {k: v["play_width"] for k, v in base.per_run.items()}
    terms = [heldout_per_run(runs, spec.with_(**v), widths, groups, on) for v in variants]
    n = terms[0][1]
    w = n / n.sum()
    ms = [ss / np.maximum(n, 1) for ss, _ in terms]
    mean_sq = np.array([float(w @ m) for m in ms])
    best = int(np.argmin(mean_sq))
    size = [n_shared(runs[0], spec.with_(**v)) for v in variants]
    within = []
    for k, m in enumerate(ms):
        d = m - ms[best]
        se = float(np.sqrt(len(d) / max(len(d) - 1, 1) * np.sum(w ** 2 * (d - w @ d) ** 2)))
        if mean_sq[k] <= mean_sq[best] + se:
            within.append(k)
    pick = min(within, key=lambda k: (size[k], mean_sq[k]))
    return spec.with_(**variants[pick]), [float(np.sqrt(v)) for v in mean_sq]


# ----------------------------------------------------------------------------- splits


def _same(a, b) -> bool:
    try:
        return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=0.0))
    except (TypeError, ValueError):
        return str(a) == str(b)


def make_folds(runs: Sequence[Run], splits: Sequence[Mapping]) -> list[dict]:
    """Train/test folds of a rig.

    Each split is ``{"name", "by": condition, "train": [values], "test": [values]}`` (one fold),
    ``{"name", "by": condition}`` (leave one value of the condition out: one fold per value) or
    ``{"name", "leave_one_run_out": true}``. Returns ``[{"split", "fold", "train", "test"}]``
    with run ids.
    """
    ids = [r.run_id for r in runs]
    folds = []
    for sp in splits:
        name = sp.get("name") or sp.get("by") or "leave_one_run_out"
        if sp.get("leave_one_run_out"):
            folds += [{"split": name, "fold": i, "train": [j for j in ids if j != i], "test": [i]}
                      for i in ids]
            continue
        by = sp.get("by")
        missing = [r.run_id for r in runs if by not in r.conditions]
        if by is None or missing:
            raise ValueError(f"split {name!r}: condition {by!r} missing in run(s) {missing or ids}")
        values = [r.conditions[by] for r in runs]
        if "train" in sp or "test" in sp:
            train = [r.run_id for r in runs if any(_same(r.conditions[by], v) for v in sp.get("train", []))]
            test = [r.run_id for r in runs if any(_same(r.conditions[by], v) for v in sp.get("test", []))]
            if not train or not test:
                raise ValueError(f"split {name!r}: no run with {by} in train {sp.get('train')} or test "
                                 f"{sp.get('test')}; values present {sorted(set(map(str, values)))}")
            folds.append({"split": name, "fold": f"{by} {sp.get('test')}", "by": by, "train": train, "test": test})
        else:
            levels = []
            for v in values:
                if not any(_same(v, u) for u in levels):
                    levels.append(v)
            for v in levels:
                test = [r.run_id for r in runs if _same(r.conditions[by], v)]
                folds.append({"split": name, "fold": f"{by}={v}", "by": by,
                              "train": [i for i in ids if i not in test], "test": test})
    return folds


def inner_groups(runs: Sequence[Run], by: str | None) -> dict:
    """``{run id: group}`` for a choice on held-out runs inside a training set: the values of
    the condition ``by`` when it takes at least 2 of them (the choice then extrapolates across
    the condition as the fold does), else one group per run."""
    if by and len({str(r.conditions.get(by)) for r in runs}) >= 2:
        return {r.run_id: str(r.conditions.get(by)) for r in runs}
    return {r.run_id: r.run_id for r in runs}


def evaluate(runs: Sequence[Run], spec: RigSpec, folds: Sequence[Mapping],
             spacings: Sequence[float] | None = None,
             keep_residuals: bool = False, variants=None,
             torque_knots: Sequence[int] | None = None) -> tuple[list[dict], list[dict]]:
    """Fit on each fold's training runs, score every run of the fold.

    ``spacings``: candidate knot spacings chosen per fold on the training runs alone
    (:func:`choose_spacing`); ``None`` keeps ``spec.spacing``. ``variants``: candidate model
    forms (:meth:`RigSpec.with_` keyword dicts, or ``"takeup"`` for :func:`takeup_variants` of
    the training runs) chosen per fold on the training runs alone, before the spacing.
    ``torque_knots``: candidate numbers of intervals of the torque map (``spec.torque_map``),
    its range the one every inner group covers. Every choice holds out groups of training runs
    (:func:`inner_groups`: by the fold's condition).

    Returns
    -------
    rows : list of dict
        One per fold and run: ``split``, ``fold``, ``run_id``, ``role`` (train/test), the
        conditions, the before (offset only) and after std (steady, all), the per-run effects.
    folds_out : list of dict
        One per fold: the spacing, the shared coefficients and their intervals, the fit, and
        (``keep_residuals``) ``residuals``: ``{run id: reading - prediction}`` of its test runs.
    """
    by_id = {r.run_id: r for r in runs}
    rows, out = [], []
    before = {}
    for r in runs:
        m = _fit_mask(r, spec)
        c = float(np.mean((r.measured - r.truth)[m]))
        before[r.run_id] = score_run(r, r.truth + c, spec)
    for fold in folds:
        train = [by_id[i] for i in fold["train"]]
        fspec, scores, vscores = choose_model(train, spec, spacings, variants,
                                              inner_groups(train, fold.get("by")), torque_knots)
        fit = fit_rig(train, fspec)
        kept = {}
        for role, ids in (("train", fold["train"]), ("test", fold["test"])):
            for i in ids:
                run = by_id[i]
                pred, per = predict_run(fit, run)
                if keep_residuals and role == "test":
                    kept[i] = run.measured - pred
                sc = score_run(run, pred, fspec)
                rows.append({"split": fold["split"], "fold": fold["fold"], "run_id": i, "role": role,
                             **run.conditions,
                             "before_steady_std": before[i]["steady_std"],
                             "before_all_std": before[i]["all_std"],
                             "steady_std": sc["steady_std"], "all_std": sc["all_std"],
                             "n_steady": sc["n_steady"], "n_all": sc["n_all"],
                             "steady_ss": sc["steady_ss"], "all_ss": sc["all_ss"],
                             "floor_std": floor_std(run.step, run.truth_step), **per})
        out.append({**fold, "spacing": fspec.spacing, "spacing_scores": scores, "variant_scores": vscores,
                    "fit": fit,
                    **({"residuals": kept} if keep_residuals else {})})
    return rows, out


def choose_model(runs: Sequence[Run], spec: RigSpec, spacings: Sequence[float] | None = None,
                 variants=None, groups: Mapping | None = None,
                 torque_knots: Sequence[int] | None = None) -> tuple[RigSpec, dict | None, list | None]:
    """The model form (``variants``), then the torque map's number of intervals
    (``torque_knots``), then the knot spacing (``spacings``) with the least held-out error over
    ``runs`` (groups of them held out in turn). When a form is to be chosen, the knot spacing is
    first chosen for the declared form: a form judged beside too coarse an angle map is chosen
    for the part of the map it absorbs, so the choice would depend on where ``spec.spacing``
    starts. A torque map's range is the one every group
    covers (:func:`resolve_torque_map`). Returns ``(spec, spacing scores, variant scores)``; the
    torque-map scores are in the spacing scores under ``"torque_knots"``."""
    spec = resolve_torque_map(runs, spec, groups, torque_knots[0] if torque_knots else None)
    if variants == "takeup":
        variants = takeup_variants(runs, spec)
    choose_knots = bool(spec.torque_map and torque_knots and len(torque_knots) > 1)
    if not (variants and len(variants) > 1) and not (spacings and spec.spacing) and not choose_knots:
        return spec, None, None
    base = fit_rig(runs, spec)
    widths = {k: v["play_width"] for k, v in base.per_run.items()}
    vscores = None
    if spacings and spec.spacing and ((variants and len(variants) > 1) or choose_knots):
        spec = spec.with_(spacing=choose_spacing(runs, spec, spacings, widths, groups)[0])
        base = fit_rig(runs, spec)
        widths = {k: v["play_width"] for k, v in base.per_run.items()}
    if variants and len(variants) > 1:
        spec, vscores = choose_variant(runs, spec, variants, widths, groups)
        spec = resolve_torque_map(runs, spec, groups)
    scores = None
    if choose_knots:
        # A spline's resolution, like the map's knot spacing, is judged on every sample: the
        # training runs' steady strokes never carry the torques near zero that the map is for.
        kscores = {int(n): heldout_rms(runs, resolve_torque_map(runs, spec, groups, n), widths, groups)
                   for n in torque_knots}
        spec = resolve_torque_map(runs, spec, groups, min(kscores, key=kscores.get))
        scores = {"torque_knots": kscores}
    if spacings and spec.spacing:
        best, sscores = choose_spacing(runs, spec, spacings, widths, groups)
        spec = spec.with_(spacing=best)
        scores = {**sscores, **(scores or {})}
    return spec, scores, vscores


def pooled(rows: Sequence[Mapping], role: str = "test") -> dict:
    """Pooled steady / all residual std over rows of one role (sums of squares over samples)."""
    sel = [r for r in rows if r["role"] == role]
    ns = sum(r["n_steady"] for r in sel)
    na = sum(r["n_all"] for r in sel)
    return {"steady_std": float(np.sqrt(sum(r["steady_ss"] for r in sel) / ns)) if ns else float("nan"),
            "all_std": float(np.sqrt(sum(r["all_ss"] for r in sel) / na)) if na else float("nan")}


def fold_spread(folds_out: Sequence[Mapping]) -> dict:
    """Per scalar shared parameter: mean over the folds that have it, the largest relative
    deviation ``max |p_f - mean| / |mean|``, ``kept_in`` (folds whose chosen form has it) and
    ``folds``; a term that some folds' training runs leave out is not pinned down either
    (:func:`loose_parameters`)."""
    names = sorted({n for f in folds_out for n in f["fit"].shared()})
    out = {}
    for n in names:
        vals = np.array([f["fit"].shared()[n] for f in folds_out if n in f["fit"].shared()])
        mean = float(vals.mean())
        out[n] = {"mean": mean, "min": float(vals.min()), "max": float(vals.max()),
                  "rel_dev": float(np.max(np.abs(vals - mean)) / abs(mean)) if mean else float("inf"),
                  "kept_in": int(vals.size), "folds": len(folds_out)}
    return out


def loose_parameters(spread: Mapping, max_spread: float) -> list[str]:
    """Shared parameters of a :func:`fold_spread` that move by more than ``max_spread`` between
    folds or that some folds' chosen form leaves out."""
    return sorted(n for n, v in spread.items()
                  if (v.get("rel_dev") is not None and v["rel_dev"] > max_spread)
                  or v.get("kept_in", 0) < v.get("folds", 0))


def simulate_rig(rng: np.random.Generator, conditions: Sequence[Mapping], *, duration: float = 4.0,
                 fs: float = 1000.0, amplitude: float = 0.5, step: float = 2 * np.pi / 8192,
                 truth_step: float = 2 * np.pi / 146860, scale: float = 0.0, map_fn=None,
                 compliance: Mapping | None = None, play_width=0.02, latency=0.0,
                 torque_gain: float = 0.1, torque_scales: Mapping | None = None,
                 gear_ratio: float | None = None, input_map_fn=None) -> list[Run]:
    """Runs of a simulated rig with known shared and per-run effects.

    Each condition ``{"frequency_hz": f, "load": L, ...}`` gives one run: the truth is a sine of
    ``amplitude`` rad about ``amplitude`` (so the measured side spans about ``[0, 2 amplitude]``)
    at frequency ``f``; the back torque follows the velocity, a sine at ``1.7 f`` and ``L``
    (``torque_gain`` N m per unit), the front torque a scaled copy with its own noise. The
    measured side is ``y = P_w(theta(t - latency)) + sum kappa f(T)`` and its reading
    ``q(y + scale (y - amplitude) + map_fn(y))``; the truth is read on ``truth_step``.

    ``play_width`` and ``latency`` are numbers or sequences (one per run). ``compliance`` is
    ``{"torque_back:linear": k1, "torque_back:signed_square": k2, "torque_front:linear": k3}``
    (``"torque_back:saturating": k`` with ``torque_scales={"torque_back": T0}``: ``k tanh(T / T0)``).
    ``input_map_fn(phi)`` (rad, truth side) is an error of the truth reading periodic in the
    input angle ``phi = gear_ratio * theta``: the truth reads ``theta + input_map_fn(phi)``.
    """
    runs = []
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    for i, cond in enumerate(conditions):
        f = float(cond.get("frequency_hz", 0.5))
        load = float(cond.get("load", 0.0))
        phase = rng.uniform(0, 2 * np.pi)
        w = float(np.atleast_1d(play_width)[i % np.size(play_width)])
        tau = float(np.atleast_1d(latency)[i % np.size(latency)])

        def theta(tt, f=f, phase=phase):
            return amplitude + amplitude * np.sin(2 * np.pi * f * tt + phase)
        om = 2 * np.pi * f
        vel = amplitude * om * np.cos(om * t + phase)
        # A friction-like part (velocity) and a part at an incommensurate frequency: a torque
        # that is a function of the angle alone would be confounded with the calibration map.
        tb = torque_gain * (load - 0.3 * vel / (amplitude * om)
                            + 0.3 * np.sin(2 * np.pi * 1.7 * f * t + rng.uniform(0, 2 * np.pi))) \
            + 0.002 * rng.standard_normal(n)
        tf = -0.4 * tb + torque_gain * 0.5 * load + 0.002 * rng.standard_normal(n)
        torques = {"torque_back": tb, "torque_front": tf}
        y = play_operator(theta(t - tau), w)
        for name, k in (compliance or {}).items():
            channel, term = name.split(":")
            y = y + k * compliance_columns({channel: [term]}, torques, torque_scales)[:, 0]
        reading = y + scale * (y - amplitude) + (map_fn(y) if map_fn is not None else 0.0)
        measured = step * np.round(reading / step)
        th = theta(t)
        if input_map_fn is not None:
            th = th + input_map_fn(gear_ratio * th)
        truth = truth_step * np.round(th / truth_step) if truth_step else th
        runs.append(Run(run_id=f"run{i:02d}", t=t, truth=truth, measured=measured, step=step,
                        truth_step=truth_step, torques=torques, conditions=dict(cond)))
    return runs


# ----------------------------------------------------------------------------- extrapolation


def term_groups(names: Sequence[str]) -> dict:
    """``{term: [coefficient index, ...]}`` of a fit's shared coefficient names: ``scale``,
    ``latency``, ``map`` (the calibration map), ``<channel> compliance`` (every term of that
    torque: ``linear``, ``signed_square``, ``saturating`` and its torque map), ``transient``
    and ``input`` (the input-side map)."""
    out: dict = {}
    for i, n in enumerate(names):
        if n.startswith("tmap_"):
            key = f"{n[5:].rstrip('0123456789')} compliance"
        elif ":" in n:
            key = f"{n.split(':')[0]} compliance"
        else:
            key = n.rstrip("0123456789")
            key = {"input_cos": "input", "input_sin": "input"}.get(key, key)
        out.setdefault(key, []).append(i)
    return out


def refit_shared(fit: RigFit, runs: Sequence[Run], index: Sequence[int] | None = None,
                 widths: Mapping | None = None) -> RigFit:
    """``fit`` with the shared coefficients ``index`` (default: all) refitted on ``runs`` and the
    others held at their values; every run's own offset and latency are projected out as in
    :func:`fit_rig`, its play width held (``widths``, default those :func:`predict_run` gives
    under ``fit``).

    On held-out runs this is the question "how much of their error would this term remove,
    had it been fitted on them": the term that removes most of the held-out excess is the one
    whose training value does not carry over to the held-out conditions."""
    if widths is None:
        widths = {r.run_id: predict_run(fit, r)[1]["play_width"] for r in runs}
    # The play widths held (not linearised): the refits then minimise the very sum of squares
    # they are scored on, so refitting more terms never scores worse at those widths.
    _, eqs = _normal_equations(runs, fit.spec, fit.basis, fit.a_mid, widths)
    G = sum(e[0] for e in eqs)
    h = sum(e[1] for e in eqs)
    coef = fit.coef.copy()
    idx = np.arange(coef.size) if index is None else np.asarray(index, dtype=int)
    rest = np.setdiff1d(np.arange(coef.size), idx)
    coef[idx] = _solve(G[np.ix_(idx, idx)], h[idx] - G[np.ix_(idx, rest)] @ coef[rest])
    return RigFit(spec=fit.spec, names=list(fit.names), coef=coef, cov=None, basis=fit.basis,
                  a_mid=fit.a_mid, per_run=fit.per_run, train_ids=list(fit.train_ids))


def coverage(runs: Sequence[Run], t_skip: float = 0.0, q: float = 0.005) -> dict:
    """The conditions a set of runs covers: every condition's values, and the ranges (``q`` to
    ``1 - q`` quantiles, samples after ``t_skip``) of each logged torque (N m) and of the
    measured-side angle (rad). A model fitted on them interpolates inside these; beyond them it
    extrapolates."""
    conds: dict = {}
    for r in runs:
        for k, v in r.conditions.items():
            conds.setdefault(k, [])
            if not any(_same(v, u) for u in conds[k]):
                conds[k].append(v)
    out = {"conditions": {k: sorted(v, key=lambda x: (str(type(x)), x)) for k, v in conds.items()}}
    channels = sorted({c for r in runs for c in r.torques})
    keep = [r.t >= r.t[0] + t_skip for r in runs]
    out["torques"] = {c: [float(np.quantile(np.concatenate([r.torques[c][m] for r, m in zip(runs, keep)
                                                             if c in r.torques]), x)) for x in (q, 1 - q)]
                      for c in channels}
    a = np.concatenate([r.measured[m] for r, m in zip(runs, keep)])
    out["angle"] = [float(np.min(a)), float(np.max(a))]
    return out


def _sum_squares(fit: RigFit, runs: Sequence[Run], widths: Mapping | None = None) -> float:
    """Sum of squares of the residuals of ``runs`` under ``fit`` on every sample after
    ``t_skip`` (``widths``: play widths to search around)."""
    return float(sum(score_run(r, predict_run(fit, r, (widths or {}).get(r.run_id))[0], fit.spec)["all_ss"]
                     for r in runs))


def extrapolation(runs: Sequence[Run], rows: Sequence[Mapping], folds_out: Sequence[Mapping],
                  ratio: float) -> list[dict]:
    """Whether each condition split's fit extrapolates to its held-out conditions, and if not,
    which shared term is to blame.

    For each split with a condition (``by``): its held-out std (test runs pooled; steady and
    all, :func:`pooled`) is compared with (a) the smallest held-out std of the other condition
    splits and (b) its training runs' own held-out std (:func:`heldout_per_run` with one value
    of the condition held out at a time, :func:`inner_groups`: what the fit achieves inside
    the conditions it was trained on). The split *does not extrapolate* when, on steady strokes
    or on all samples, the held-out std exceeds ``ratio`` times (a) or (b).

    Blame, for every condition split: each group of shared terms (:func:`term_groups`) is
    refitted on the test runs with the others held at their training values
    (:func:`refit_shared`); ``excess_share`` is the fraction of the held-out excess (held-out
    sum of squares minus that with every shared term refitted on the test runs) that refitting
    the group alone removes, on every sample after ``t_skip`` (what the refit minimises). The
    term with the largest share is ``blame``.

    Returns one dict per split: ``split``, ``by``, ``heldout`` and ``inner`` (``{steady,
    all}`` std, rad), ``others`` (the smallest of the other splits'), ``ratio_to_others``,
    ``ratio_to_inner``, ``extrapolates`` (bool), ``reason``, ``excess_share``, ``blame``,
    ``refit_all`` (test runs' std, all samples, with every shared term refitted on them) and the training and
    test runs' ``coverage`` (:func:`coverage`).
    """
    if not ratio > 1:
        raise ValueError(f"extrapolation ratio must exceed 1, got {ratio!r}")
    by_id = {r.run_id: r for r in runs}
    splits = list(dict.fromkeys(f["split"] for f in folds_out if f.get("by")))
    held = {s: pooled([r for r in rows if r["split"] == s]) for s in splits}
    out = []
    for s in splits:
        folds = [f for f in folds_out if f["split"] == s]
        inner_ss = {"steady": 0.0, "all": 0.0}
        inner_n = {"steady": 0.0, "all": 0.0}
        base_ss = oracle_ss = 0.0
        refit_ss: dict = {}
        n_test = 0
        train_runs, test_runs = [], []
        for f in folds:
            fit = f["fit"]
            train = [by_id[i] for i in f["train"]]
            test = [by_id[i] for i in f["test"]]
            train_runs += train
            test_runs += test
            groups = inner_groups(train, f.get("by"))
            widths = {k: v["play_width"] for k, v in fit.per_run.items()}
            if len(set(groups.values())) >= 2:
                for on in ("steady", "all"):
                    ss, n = heldout_per_run(train, fit.spec, widths, groups, on)
                    inner_ss[on] += float(ss.sum())
                    inner_n[on] += float(n.sum())
            # Steady sums of squares of the test runs: as held out, every term refitted, each alone.
            # As held out: the fold's own rows (their play widths: a start for the refits). The
            # refits minimise the sum of squares on every sample: the shares are taken there.
            mine = [r for r in rows if r["split"] == s and r["fold"] == f["fold"] and r["role"] == "test"]
            base_ss += sum(r["all_ss"] for r in mine)
            n_test += sum(r["n_all"] for r in mine)
            w = {r["run_id"]: r["play_width"] for r in mine}
            oracle_ss += _sum_squares(refit_shared(fit, test, widths=w), test, w)
            for term, idx in term_groups(fit.names).items():
                refit_ss[term] = refit_ss.get(term, 0.0) + _sum_squares(refit_shared(fit, test, idx, w), test, w)
        inner = {k: float(np.sqrt(inner_ss[k] / inner_n[k])) if inner_n[k] else float("nan") for k in inner_ss}
        others = {k: min((held[o][f"{k}_std"] for o in splits if o != s), default=float("nan"))
                  for k in ("steady", "all")}
        h = {k: held[s][f"{k}_std"] for k in ("steady", "all")}
        to_others = {k: h[k] / others[k] if others[k] > 0 else float("nan") for k in h}
        to_inner = {k: h[k] / inner[k] if inner[k] > 0 else float("nan") for k in h}
        reasons = [f"held-out {k} std {h[k] * 1e3:.3g} mrad is {to_others[k]:.2f}x the other splits' smallest"
                   for k in h if to_others[k] > ratio] + \
                  [f"held-out {k} std {h[k] * 1e3:.3g} mrad is {to_inner[k]:.2f}x its training runs' own "
                   "held-out std" for k in h if to_inner[k] > ratio]
        excess = base_ss - oracle_ss
        shares = {t: float((base_ss - v) / excess) if excess > 0 else float("nan") for t, v in refit_ss.items()}
        blame = max(shares, key=lambda t: shares[t]) if shares and excess > 0 else None
        out.append({"split": s, "by": folds[0].get("by"), "heldout": h, "inner": inner, "others": others,
                    "ratio_to_others": to_others, "ratio_to_inner": to_inner, "ratio": ratio,
                    "extrapolates": not reasons, "reason": "; ".join(reasons),
                    "excess_share": shares, "blame": blame,
                    "refit_all": float(np.sqrt(oracle_ss / n_test)) if n_test else float("nan"),
                    "coverage": {"train": coverage(train_runs, folds[0]["fit"].spec.t_skip),
                                 "test": coverage(test_runs, folds[0]["fit"].spec.t_skip)}})
    return out
