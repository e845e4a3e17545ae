"""The per-log quantization-error analysis (Colonnese & Okamura), one function per pipeline stage.

Every function is pure: a canonical log (``DataFrame`` + metadata dict, see
``docs/architecture.md``) and settings in, tables and dicts out. The Snakemake scripts in
``scripts/`` only read inputs, call one of these and write the result.

Stages
------
:func:`requantize`
    Re-quantize each joint's truth channel at several levels (integer counts).
:func:`kinematics_table`
    Operational-space position of the truth and of every level, and the Jacobian at the truth.
:func:`export_derivatives`
    Time series of a few derivative estimators (truth and measured), for inspection.
:func:`empirical_rows`
    Error moments (measured - true) for every signal, level, filter and architecture.
:func:`theory_rows`
    Table II (PQN and worst case), the exact non-white model and the trajectory bound.
:func:`build_summary`
    ``summary.json`` (docs/output-contract.md) from the two row sets.

A *row key* is ``(level, signal, order, filter label or "", architecture or "")``: positions
have order 0 and no filter; derivative rows have order ``d`` of their filter. Joint signals
(the truth channel names, e.g. ``theta1``) are filtered directly (architecture ``"joint"``);
operational signals (e.g. ``x``) are filtered in operational space (``"operational"``, paper
Fig. 2A) or computed as ``J(theta^) G theta^ - J(theta) G theta`` with the filter in joint
space (``"joint"``, Fig. 2B, velocities only: for ``d = 2`` the product ``J G theta`` is not
an acceleration estimate).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from enclab.core import quantize as qz
from enclab.core.canonical import Channel
from enclab.core.errors import EnclabInputError
from enclab.propagation import filters as flt
from enclab.propagation import moments as mom
from enclab.propagation import theory as th
from enclab.propagation.kinematics import Device, make_device

__all__ = [
    "truth_channels",
    "plan_levels",
    "requantize",
    "level_counts",
    "device_of",
    "kinematics_table",
    "filter_bank",
    "check_cutoffs",
    "export_derivatives",
    "empirical_rows",
    "theory_rows",
    "build_summary",
    "log_header",
    "centre_of",
    "centre_label",
    "summary_table",
    "third_derivative_bound",
    "error_traces",
]

# Impulse responses are truncated where the tail energy is below this fraction: far below
# the 1e-4 relative precision any statistic here is quoted with.
_IMPULSE_TOL = 1e-12
_ORDER_SUFFIX = {0: "", 1: "/s", 2: "/s^2", 3: "/s^3"}


# ----------------------------------------------------------------------------- channels, levels


def truth_channels(meta: Mapping) -> list[dict]:
    """The truth channel of every joint, sorted by joint index.

    Raises
    ------
    ValueError
        When the log has no truth channel (nothing to re-quantize).
    """
    chans = [dict(c) for c in meta["channels"] if c.get("role") == "truth"]
    if not chans:
        names = [c["name"] for c in meta["channels"]]
        raise ValueError(
            f"log {meta.get('log_id')!r} has no channel with role 'truth' (channels {names}); "
            "the quantization stages re-quantize the finest record of each joint, so mark it "
            "role: truth in the manifest"
        )
    chans.sort(key=lambda c: c["joint"])
    return chans


def _truth_values(df: pd.DataFrame, chan: Mapping) -> np.ndarray:
    return Channel.of(chan, df).values


def _truth_step(chan: Mapping) -> float | None:
    """The grid of a truth channel (counts step or detected/declared native step)."""
    return Channel.of(chan).grid


def plan_levels(meta: Mapping, settings: Mapping) -> list[dict]:
    """Re-quantization levels of a log.

    Parameters
    ----------
    meta : dict
        Canonical-log metadata.
    settings : dict
        ``config["requantize"]`` updated with the log's ``analysis.requantize``:
        ``steps`` (SI steps, the same for every joint; wins over ``multiples``), ``multiples``
        (integer multiples of each truth channel's native step) and ``offset_frac``.

    Returns
    -------
    list of dict
        ``{"label", "offset_frac", "joints": [{"name", "joint", "unit", "step",
        "truth_step", "ratio"}]}``; ``truth_step``/``ratio`` are ``None`` for a truth without
        a grid (continuous-truth model).
    """
    offset_frac = float(settings.get("offset_frac", 0.5))
    if not 0.0 <= offset_frac < 1.0:
        raise ValueError(f"requantize.offset_frac must be in [0, 1), got {offset_frac!r}")
    chans = truth_channels(meta)
    steps = settings.get("steps")
    multiples = settings.get("multiples") or []
    levels = []
    if steps:
        for step in steps:
            step = float(step)
            if not (math.isfinite(step) and step > 0):
                raise ValueError(f"requantize.steps must be positive numbers, got {step!r}")
            joints = []
            for c in chans:
                fine = _truth_step(c)
                ratio = None if fine is None else qz.ratio_of(step, fine)
                joints.append(_level_joint(c, step, fine, ratio))
            levels.append({"label": qz.level_label(step, chans[0]["unit"]),
                           "offset_frac": offset_frac, "joints": joints})
        return levels
    for multiple in multiples:
        multiple = int(multiple)
        if multiple < 2:
            raise ValueError(f"requantize.multiples must be integers >= 2, got {multiple!r}")
        joints = []
        for c in chans:
            fine = _truth_step(c)
            if fine is None:
                raise ValueError(
                    f"log {meta.get('log_id')!r}: truth channel {c['name']!r} has no known grid, "
                    "so requantize.multiples cannot be applied; give requantize.steps (SI) in the "
                    "log's analysis block or declare the channel's native_step"
                )
            joints.append(_level_joint(c, multiple * fine, fine, multiple))
        levels.append({"label": qz.multiple_label(multiple), "offset_frac": offset_frac,
                       "joints": joints})
    if not levels:
        raise ValueError("requantize needs a non-empty 'steps' or 'multiples' list")
    return levels


def _level_joint(chan, step, fine, ratio) -> dict:
    return {"name": chan["name"], "joint": int(chan["joint"]), "unit": chan["unit"],
            "step": float(step), "truth_step": fine, "ratio": ratio}


def _column(name: str, label: str) -> str:
    return f"{name}@{label}"


def requantize(df: pd.DataFrame, meta: Mapping, levels: Sequence[Mapping]) -> pd.DataFrame:
    """Truth channels plus one int64 counts column ``<name>@<level>`` per joint and level.

    A truth stored as counts is re-quantized exactly in integer arithmetic
    (:func:`enclab.core.quantize.requantize_counts`); a float truth on its native grid is first
    snapped to that grid; a truth without grid is quantized directly.
    """
    out = {"t": df["t"].to_numpy()}
    by_name = {c["name"]: c for c in truth_channels(meta)}
    for c in by_name.values():
        out[c["name"]] = df[c["name"]].to_numpy()
    for level in levels:
        for j in level["joints"]:
            out[_column(j["name"], level["label"])] = level_counts(
                df[j["name"]].to_numpy(), by_name[j["name"]], j, level["offset_frac"])
    return pd.DataFrame(out)


def level_counts(column: np.ndarray, chan: Mapping, joint: Mapping,
                 offset_frac: float) -> np.ndarray:
    """One joint's counts at one level (an entry of ``plan_levels(...)[k]["joints"]``) from
    the truth channel's stored column (counts or SI floats, as ``chan["storage"]`` says)."""
    if joint["ratio"] is None:
        return qz.quantize(Channel.of(chan, column=column).values, joint["step"], offset_frac)
    fine = column
    if chan["storage"] != "counts":
        fine = np.rint(fine / joint["truth_step"]).astype(np.int64)
    return qz.requantize_counts(fine, joint["ratio"], offset_frac)


def _angles(req: pd.DataFrame, meta: Mapping, level: Mapping | None) -> np.ndarray:
    """(N, n) angles in SI: the truth (``level=None``) or a level's measured reading."""
    if level is None:
        return np.column_stack([_truth_values(req, c) for c in truth_channels(meta)])
    return np.column_stack([
        req[_column(j["name"], level["label"])].to_numpy().astype(np.float64) * j["step"]
        for j in level["joints"]
    ])


def _models(level: Mapping) -> list[th.QuantizerErrorModel]:
    return [th.QuantizerErrorModel(j["step"], level["offset_frac"], j["truth_step"])
            for j in level["joints"]]


# ----------------------------------------------------------------------------- kinematics


def device_of(meta: Mapping) -> Device | None:
    """The log's device, or ``None`` when the kinematics do not apply.

    Operational-space analysis needs a truth channel for every joint of the device, joints
    numbered ``1..n``. A single joint without a radius maps the angle onto itself, so it adds
    nothing to the joint-space rows and is skipped too.
    """
    spec = meta.get("device")
    if not spec:
        return None
    device = make_device(dict(spec))
    joints = [c["joint"] for c in truth_channels(meta)]
    if joints != list(range(1, device.n_joints + 1)):
        raise ValueError(
            f"log {meta.get('log_id')!r}: device {device.name!r} has {device.n_joints} joints but "
            f"the truth channels cover joints {joints}; give a truth channel for joints "
            f"1..{device.n_joints} or set device: null"
        )
    if device.name == "single_joint" and device.spec.get("radius") is None:
        return None
    return device


def kinematics_table(req: pd.DataFrame, meta: Mapping, levels: Sequence[Mapping]) -> pd.DataFrame:
    """Operational outputs of the truth (``x``), of each level (``x@1mrad``) and the Jacobian
    at the truth (``J_x_theta1``); only ``t`` when the log has no device."""
    out = {"t": req["t"].to_numpy()}
    device = device_of(meta)
    if device is None:
        return pd.DataFrame(out)
    theta = _angles(req, meta, None)
    x = device.forward(theta)
    for j, name in enumerate(device.output_names):
        out[name] = x[:, j]
    for level in levels:
        xq = device.forward(_angles(req, meta, level))
        for j, name in enumerate(device.output_names):
            out[_column(name, level["label"])] = xq[:, j]
    J = device.jacobian(theta)
    chans = truth_channels(meta)
    for j, name in enumerate(device.output_names):
        for i, c in enumerate(chans):
            out[f"J_{name}_{c['name']}"] = J[:, j, i]
    return pd.DataFrame(out)


def third_derivative_bound(device: Device) -> float:
    """A bound on every third partial derivative of the forward kinematics.

    Every output of these devices is a sum of terms ``length * (product of sines and cosines
    of joint angles)`` (or linear in the joints), and every partial derivative of such a term
    is bounded by its length, so the sum of the lengths bounds all derivatives.
    """
    spec = device.spec
    kind = spec["kind"]
    if kind in ("phantom_premium_1_5", "planar_2r"):
        return float(abs(spec["l1"]) + abs(spec["l2"]))
    if kind == "single_joint":
        return 0.0
    lengths = 0.0
    for key in ("a", "d"):
        lengths += float(np.sum(np.abs(np.asarray(spec.get(key, []), dtype=float))))
    flange = spec.get("flange")
    if flange is not None:
        lengths += float(np.linalg.norm(np.asarray(flange, dtype=float)))
    return lengths


# ----------------------------------------------------------------------------- filters


def filter_bank(derivatives: Mapping) -> list[flt.DerivativeFilter]:
    """The cross product of ``derivatives.bank`` (config) as filters."""
    bank = derivatives["bank"]
    return [
        flt.DerivativeFilter(int(d), int(n), float(fc), disc)
        for d in bank["d"] for n in bank["n"] for fc in bank["fc_hz"]
        for disc in bank["discretization"]
    ]


def check_cutoffs(derivatives: Mapping, meta: Mapping) -> None:
    """Every configured cutoff (bank and export) below this log's Nyquist frequency.

    Raises
    ------
    EnclabInputError
        Naming the configuration key, the cutoff and the log's sample rate.
    """
    fs = _fs(meta)
    places = [("derivatives.bank.fc_hz", fc) for fc in derivatives["bank"]["fc_hz"]]
    places += [(f"derivatives.export[{i}].fc_hz", spec["fc_hz"])
               for i, spec in enumerate(derivatives.get("export") or [])]
    for key, fc in places:
        if float(fc) >= fs / 2:
            raise EnclabInputError(
                "configuration", f"cutoff {float(fc):g} Hz is at or above the Nyquist frequency "
                f"{fs / 2:.6g} Hz of log '{meta.get('log_id')}' (sampled at {fs:.6g} Hz)", key=key,
                expected="fc_hz < fs/2 for every log", hint="Lower the cutoff or leave the log out.")


def _fs(meta: Mapping) -> float:
    fs = meta.get("fs_hz")
    if fs is None or not fs > 0:
        raise ValueError(f"log {meta.get('log_id')!r} has no sample rate (fs_hz={fs!r})")
    return float(fs)


def export_derivatives(req: pd.DataFrame, meta: Mapping, levels: Sequence[Mapping],
                       export: Sequence[Mapping]) -> pd.DataFrame:
    """Derivative estimates of the truth and every level for the ``export`` filters.

    Columns ``<signal>~<filter label>`` (truth) and ``<signal>~<filter label>@<level>``, for
    the joint signals and, with a device, the operational outputs (filter in operational
    space).
    """
    fs = _fs(meta)
    device = device_of(meta)
    out = {"t": req["t"].to_numpy()}
    joint_names = [c["name"] for c in truth_channels(meta)]
    sources = [(None, _angles(req, meta, None))] + [(lv, _angles(req, meta, lv)) for lv in levels]
    for spec in export:
        filt = flt.DerivativeFilter.from_dict(dict(spec))
        for level, theta in sources:
            suffix = "" if level is None else f"@{level['label']}"
            y = flt.apply(filt, theta, fs)
            for i, name in enumerate(joint_names):
                out[f"{name}~{filt.label()}{suffix}"] = y[:, i]
            if device is not None:
                yx = flt.apply(filt, device.forward(theta), fs)
                for j, name in enumerate(device.output_names):
                    out[f"{name}~{filt.label()}{suffix}"] = yx[:, j]
    return pd.DataFrame(out)


# ----------------------------------------------------------------------------- row keys


def _key(level: str, signal: str, order: int, filt: flt.DerivativeFilter | None,
         architecture: str | None) -> tuple:
    return (level, signal, int(order), "" if filt is None else filt.label(), architecture or "")


def _signal_units(meta: Mapping, device: Device | None) -> dict:
    units = {c["name"]: c["unit"] for c in truth_channels(meta)}
    if device is not None:
        units.update(dict(zip(device.output_names, device.output_units)))
    return units


def _row_head(level: str, signal: str, order: int, filt, architecture, unit: str) -> dict:
    return {
        "level": level,
        "signal": signal,
        "order": int(order),
        "filter": None if filt is None else filt.to_dict(),
        "architecture": architecture,
        "unit": unit + _ORDER_SUFFIX[int(order)],
    }


# ----------------------------------------------------------------------------- empirical


def empirical_rows(req: pd.DataFrame, kin: pd.DataFrame, meta: Mapping,
                   levels: Sequence[Mapping], bank: Sequence[flt.DerivativeFilter],
                   architectures: Sequence[str], *, settle_tol: float = 1e-9,
                   ci_level: float = 0.95, n_batches: int = 20) -> list[dict]:
    """Moments of the error (measured - true) for every row key.

    Filtered errors are computed as ``filter(measured) - filter(truth)`` (the filters are
    linear, so this is ``filter(measured - truth)``) and the first
    :func:`enclab.propagation.filters.settle_samples` samples of each are discarded: the start-up
    transient from rest is not part of the stationary error the theory describes.
    """
    fs = _fs(meta)
    device = device_of(meta)
    units = _signal_units(meta, device)
    joint_names = [c["name"] for c in truth_channels(meta)]
    theta = _angles(req, meta, None)
    x = None if device is None else kin[list(device.output_names)].to_numpy()
    J = None if device is None else _jacobian_columns(kin, device, joint_names)
    rows = []

    def add(level, names, order, filt, arch, err):
        stats = [mom.error_moments(err[:, i], ci_level=ci_level, n_batches=n_batches)
                 for i in range(err.shape[1])]
        for name, s in zip(names, stats):
            row = _row_head(level, name, order, filt, arch, units[name])
            row["empirical"] = {
                "mean": float(s["mean"]), "std": float(s["std"]),
                "std_ci": [float(s["std_ci"][0]), float(s["std_ci"][1])],
                "max_abs": float(s["max_abs"]), "n": int(s["n"]),
            }
            rows.append(row)

    for level in levels:
        label = level["label"]
        theta_q = _angles(req, meta, level)
        add(label, joint_names, 0, None, None, theta_q - theta)
        if device is not None:
            xq = kin[[_column(o, label) for o in device.output_names]].to_numpy()
            add(label, device.output_names, 0, None, None, xq - x)
            Jq = device.jacobian(theta_q) if "joint" in architectures else None
        for filt in bank:
            skip = flt.settle_samples(filt, fs, settle_tol)
            err_joint = flt.apply(filt, theta_q - theta, fs)
            add(label, joint_names, filt.d, filt, "joint", err_joint[skip:])
            if device is None:
                continue
            if "operational" in architectures:
                err_x = flt.apply(filt, xq - x, fs)[skip:]
                add(label, device.output_names, filt.d, filt, "operational", err_x)
            if "joint" in architectures and filt.d == 1:
                phi = flt.apply(filt, theta, fs)
                y_err = joint_architecture_error(Jq, J, phi, err_joint)
                add(label, device.output_names, filt.d, filt, "joint", y_err[skip:])
    return rows


def joint_architecture_error(jac_q: np.ndarray, jac: np.ndarray, phi: np.ndarray,
                             phi_err: np.ndarray) -> np.ndarray:
    """Error of an operational derivative filtered in joint space (Fig. 2 B), ``(N, m)``.

    ``J(theta_q) phi_q - J(theta) phi`` with ``phi_q = phi + phi_err``, evaluated as
    ``(J(theta_q) - J(theta)) phi + J(theta_q) phi_err``: the two products of the first form
    are the size of the velocity and cancel to the size of the error, so their round-off
    (and that of filtering the whole angle, ~1e-16 of ``fs * theta``) would be a part in 1e9
    of the error instead of a part in 1e16. The filter is linear, so ``phi_err``, the
    filtered joint error, is the filtered reading minus the filtered truth.

    Parameters
    ----------
    jac_q, jac : ndarray, shape (N, m, n)
        Jacobian at the readings and at the truth.
    phi, phi_err : ndarray, shape (N, n)
        Filtered truth and filtered joint error.
    """
    return (np.einsum("kji,ki->kj", jac_q - jac, phi)
            + np.einsum("kji,ki->kj", jac_q, phi_err))


def _jacobian_columns(kin: pd.DataFrame, device: Device, joint_names: Sequence[str]) -> np.ndarray:
    cols = [[kin[f"J_{o}_{c}"].to_numpy() for c in joint_names] for o in device.output_names]
    return np.moveaxis(np.asarray(cols), -1, 0)


# ----------------------------------------------------------------------------- theory


def _centre(theta: np.ndarray) -> np.ndarray:
    """The configuration Table II is evaluated at: the mean of the trajectory."""
    return theta.mean(axis=0)


def _lag_sums(theta: np.ndarray, J: np.ndarray | None, models, max_lag: int,
              joint_arch: Mapping[str, tuple[np.ndarray, np.ndarray]]):
    """One pass over the lags for a whole filter bank.

    Returns ``c_joint`` (n, L+1) with ``mean_k C_i(theta_i(k+m) - theta_i(k))``, ``c_x``
    (m, L+1) with ``mean_k sum_i J_ji(k) J_ji(k+m) C_i(...)`` (the trajectory-averaged
    autocovariance of :func:`enclab.propagation.theory.exact_std_operational`) and, for every joint-
    architecture filter ``label -> (h, c)``, the cross term of
    :func:`enclab.propagation.theory.exact_std_joint_architecture`. Sharing the lag loop across the bank
    costs one pass instead of one per filter; the test suite checks the results equal the
    per-filter functions of :mod:`enclab.propagation.theory`.
    """
    n_samples, n = theta.shape
    c_joint = np.empty((n, max_lag + 1))
    c_x = None if J is None else np.empty((J.shape[1], max_lag + 1))
    cross = {label: np.zeros(J.shape[1]) for label in joint_arch} if J is not None else {}
    for m, G in th._lagged_autocovariances(theta, models, max_lag):
        c_joint[:, m] = G.mean(axis=0)
        if J is None:
            continue
        JJ = J[m:] * J[: n_samples - m]
        c_x[:, m] = np.einsum("kji,ki->j", JJ, G) / (n_samples - m)
        for label, (h, c) in joint_arch.items():
            if m < h.size and h[m] != 0.0:
                cross[label] += h[m] * np.einsum("kji,kji,ki->j", J[m:], c[m:], G) / (n_samples - m)
    return c_joint, c_x, cross


def theory_rows(req: pd.DataFrame, kin: pd.DataFrame, meta: Mapping,
                levels: Sequence[Mapping], bank: Sequence[flt.DerivativeFilter],
                architectures: Sequence[str], *, settle_tol: float = 1e-9) -> list[dict]:
    """Table II (PQN, worst case at the centre), exact model and trajectory bound per row key.

    ``worst_case_trajectory`` is the largest per-sample bound over the samples the empirical
    statistics use (after the filter's start-up transient), so ``max|error|`` of a log can
    be compared with it directly.
    """
    fs = _fs(meta)
    device = device_of(meta)
    units = _signal_units(meta, device)
    chans = truth_channels(meta)
    joint_names = [c["name"] for c in chans]
    theta = _angles(req, meta, None)
    n_samples = theta.shape[0]
    if device is not None:
        J = _jacobian_columns(kin, device, joint_names)
        H = device.hessian(theta)
        J0 = device.jacobian(_centre(theta))
        t3 = third_derivative_bound(device)
    else:
        J = H = J0 = None
    impulses = {f.label(): flt.impulse_response(f, fs, tol=_IMPULSE_TOL) for f in bank}
    max_lag = max([h.size for h in impulses.values()] + [1]) - 1
    if max_lag >= n_samples:
        raise ValueError(
            f"log {meta.get('log_id')!r}: {n_samples} samples are fewer than the longest filter "
            f"memory ({max_lag + 1} samples); use higher cutoffs or a longer log"
        )
    joint_arch_filters = [f for f in bank if f.d == 1] if (
        device is not None and "joint" in architectures) else []
    phis = {f.label(): flt.apply(f, theta, fs) for f in joint_arch_filters}
    rows = []

    def add(level, names, order, filt, arch, values):
        for i, name in enumerate(names):
            row = _row_head(level, name, order, filt, arch, units[name])
            row["theory"] = {k: float(np.asarray(v)[i]) for k, v in values.items()}
            rows.append(row)

    for level in levels:
        label = level["label"]
        models = _models(level)
        steps = np.array([mdl.step for mdl in models])
        eps = np.array([mdl.max_abs for mdl in models])
        mu = np.array([mdl.mean for mdl in models])
        var = np.array([mdl.variance for mdl in models])
        joint_arch = {}
        for f in joint_arch_filters:
            c = np.einsum("kjil,kl->kji", H, phis[f.label()])
            joint_arch[f.label()] = (impulses[f.label()], c)
        c_joint, c_x, cross = _lag_sums(theta, J, models, max_lag, joint_arch)

        add(label, joint_names, 0, None, None, {
            "pqn_std": steps / math.sqrt(12.0), "pqn_mean": np.zeros_like(steps),
            "exact_std": np.sqrt(var), "exact_mean": mu,
            "worst_case": eps, "worst_case_trajectory": eps,
        })
        if device is not None:
            mean_signal = J @ mu
            bound_x = th.worst_case_trajectory_position(J, H, eps, t3)
            add(label, device.output_names, 0, None, None, {
                "pqn_std": th.pqn_position_std(J0, steps),
                "pqn_mean": np.zeros(device.n_outputs),
                "exact_std": th.exact_std_operational(theta, J, models),
                "exact_mean": mean_signal.mean(axis=0),
                "worst_case": th.worst_case_position(J0, eps),
                "worst_case_trajectory": bound_x.max(axis=0),
            })
        for filt in bank:
            h = impulses[filt.label()]
            r_h = th.impulse_autocorrelation(h)
            L = r_h.size
            skip = flt.settle_samples(filt, fs, settle_tol)
            wc_joint = th.worst_case_derivative(h, eps)
            add(label, joint_names, filt.d, filt, "joint", {
                "pqn_std": th.pqn_derivative_std_joint(h, steps),
                "pqn_mean": np.zeros_like(steps),
                "exact_std": np.sqrt(np.maximum(th._two_sided_sum(r_h, c_joint[:, :L]), 0.0)),
                "exact_mean": mu * float(np.sum(h)),
                "worst_case": wc_joint, "worst_case_trajectory": wc_joint,
            })
            if device is None:
                continue
            if "operational" in architectures:
                wc_x = th.worst_case_position(J0, eps)
                mean_filtered = np.stack(
                    [np.convolve(mean_signal[:, j], h, mode="valid")
                     for j in range(device.n_outputs)], axis=1)
                var_x = th._two_sided_sum(r_h, c_x[:, :L]) + np.var(mean_filtered, axis=0)
                add(label, device.output_names, filt.d, filt, "operational", {
                    "pqn_std": np.sqrt(np.diag(th.pqn_derivative_cov_operational(
                        h, J0, steps, "operational"))),
                    "pqn_mean": np.zeros(device.n_outputs),
                    "exact_std": np.sqrt(np.maximum(var_x, 0.0)),
                    "exact_mean": mean_filtered.mean(axis=0),
                    "worst_case": th.worst_case_derivative(h, wc_x),
                    "worst_case_trajectory": th.worst_case_trajectory_derivative(
                        bound_x, h)[skip:].max(axis=0),
                })
            if filt.label() in joint_arch:
                _, c = joint_arch[filt.label()]
                c0 = np.einsum("kji,i->j", c**2, var) / n_samples
                var_y = (th._two_sided_sum(r_h, c_x[:, :L]) + 2.0 * cross[filt.label()] + c0)
                mean_y = J @ (mu * float(np.sum(h))) + np.einsum("kji,i->kj", c, mu)
                var_y = var_y + np.var(mean_y, axis=0)
                bound_y = th.worst_case_trajectory_derivative_joint(
                    J, H, phis[filt.label()], h, eps, t3)
                add(label, device.output_names, filt.d, filt, "joint", {
                    "pqn_std": np.sqrt(np.diag(th.pqn_derivative_cov_operational(
                        h, J0, steps, "joint"))),
                    "pqn_mean": np.zeros(device.n_outputs),
                    "exact_std": np.sqrt(np.maximum(var_y, 0.0)),
                    "exact_mean": mean_y.mean(axis=0),
                    "worst_case": th.worst_case_derivative_joint(h, J0, eps),
                    "worst_case_trajectory": bound_y[skip:].max(axis=0),
                })
    return rows


# ----------------------------------------------------------------------------- summary


def _row_key(row: Mapping) -> tuple:
    filt = row["filter"]
    return _key(row["level"], row["signal"], row["order"],
                None if filt is None else flt.DerivativeFilter.from_dict(dict(filt)),
                row["architecture"])


def log_header(meta: Mapping) -> dict:
    """The summary.json keys every log has: id, size, rate, grouping, device, provenance."""
    return {
        "log_id": meta["log_id"],
        "n_samples": int(meta["n_samples"]),
        "fs_hz": float(meta["fs_hz"]),
        "group": meta.get("group"),
        "tags": list(meta.get("tags") or []),
        "device": meta.get("device"),
        "source": meta.get("source"),
        "time_report": meta.get("time_report"),
    }


def build_summary(meta: Mapping, levels: Sequence[Mapping], empirical: Sequence[Mapping],
                  theory: Sequence[Mapping], centre_rad: Sequence[float] = ()) -> dict:
    """``summary.json`` for one log: the keys of docs/output-contract.md plus provenance.

    Raises
    ------
    ValueError
        If the empirical and theory stages did not produce the same row keys (they were run
        with different settings).
    """
    by_key = {_row_key(r): r for r in theory}
    emp_keys = [_row_key(r) for r in empirical]
    if set(emp_keys) != set(by_key):
        missing = sorted(set(emp_keys) ^ set(by_key))[:3]
        raise ValueError(f"empirical and theory rows differ (e.g. {missing}); rerun both stages "
                         "with the same configuration")
    rows = []
    for key, emp in zip(emp_keys, empirical):
        row = dict(emp)
        row["theory"] = by_key[key]["theory"]
        rows.append(row)
    return {
        **log_header(meta),
        "quantization": {
            "convention": "error = measured - true; SI units (rad, m, s)",
            "centre_deg": centre_label(centre_rad),
            "levels": [dict(lv) for lv in levels],
            "rows": rows,
        },
    }


def centre_of(req: pd.DataFrame, meta: Mapping) -> list[float]:
    """Mean truth configuration of a log (SI), the centre Table II is evaluated at."""
    return _centre(_angles(req, meta, None)).tolist()


def centre_label(centre_rad: Sequence[float]) -> str:
    """``"0,30,0"``: the centre configuration in degrees, to 0.1 deg, as the figures label it."""
    out = []
    for v in np.rad2deg(np.asarray(centre_rad, dtype=float)):
        v = round(float(v), 1) + 0.0  # + 0.0 turns -0.0 into 0.0
        out.append(f"{v:.0f}" if v == round(v) else f"{v:.1f}")
    return ",".join(out)


def summary_table(summary: Mapping, centre_deg: str = "") -> pd.DataFrame:
    """One row per quantity of a summary (the batch-table columns of ``enclab.propagation.batch``)."""
    device = summary.get("device") or {}
    step_of = {}
    for lv in summary["quantization"]["levels"]:
        for j in lv["joints"]:
            step_of[(lv["label"], j["name"])] = j["step"]
    records = []
    for r in summary["quantization"]["rows"]:
        filt = r["filter"] or {}
        emp, theo = r["empirical"], r["theory"]
        records.append({
            "log_id": summary["log_id"],
            "group": summary.get("group") or summary["log_id"],
            "tags": ",".join(summary.get("tags") or []),
            "device": device.get("kind", "") if isinstance(device, Mapping) else str(device),
            "level": r["level"],
            "step": step_of.get((r["level"], r["signal"]), np.nan),
            "centre_deg": summary["quantization"].get("centre_deg", centre_deg),
            "signal": r["signal"],
            "order": r["order"],
            "d": filt.get("d", np.nan),
            "n": filt.get("n", np.nan),
            "fc_hz": filt.get("fc_hz", np.nan),
            "discretization": filt.get("discretization", ""),
            "architecture": r["architecture"] or "none",
            "emp_mean": emp["mean"],
            "emp_std": emp["std"],
            "emp_std_lo": emp["std_ci"][0],
            "emp_std_hi": emp["std_ci"][1],
            "emp_max_abs": emp["max_abs"],
            "n_samples": emp["n"],
            "pqn_std": theo["pqn_std"],
            "exact_std": theo["exact_std"],
            "exact_mean": theo["exact_mean"],
            "worst_case": theo["worst_case"],
            "worst_case_trajectory": theo["worst_case_trajectory"],
            "unit": r["unit"],
        })
    return pd.DataFrame.from_records(records)


def error_traces(req: pd.DataFrame, kin: pd.DataFrame, deriv: pd.DataFrame, meta: Mapping,
                 level_label: str, export: Sequence[Mapping], settle_tol: float = 1e-9) -> dict:
    """Position, velocity and acceleration error of one signal, for the per-log figure.

    The signal is the first operational output (or the first joint without a device); the
    derivative errors come from the first exported filter of each order, with their start-up
    transient set to NaN.

    Returns
    -------
    dict
        ``{"t", "errors": {"position", "velocity", "acceleration"}, "signal", "unit",
        "step", "filters"}``.
    """
    levels = {lv["label"]: lv for lv in meta["levels"]}
    if level_label not in levels:
        raise ValueError(f"level {level_label!r} is not one of {sorted(levels)}")
    level = levels[level_label]
    device = device_of(meta)
    if device is not None:
        signal, unit = device.output_names[0], device.output_units[0]
        position = (kin[_column(signal, level_label)] - kin[signal]).to_numpy()
        step = None
    else:
        first = level["joints"][0]
        signal, unit, step = first["name"], first["unit"], first["step"]
        position = (req[_column(signal, level_label)].to_numpy() * step
                    - _truth_values(req, truth_channels(meta)[0]))
    errors = {"position": position}
    used = []
    fs = _fs(meta)
    for order, key in ((1, "velocity"), (2, "acceleration")):
        specs = [flt.DerivativeFilter.from_dict(dict(s)) for s in export if int(s["d"]) == order]
        if not specs:
            continue
        filt = specs[0]
        col = f"{signal}~{filt.label()}"
        err = (deriv[f"{col}@{level_label}"] - deriv[col]).to_numpy().copy()
        err[: flt.settle_samples(filt, fs, settle_tol)] = np.nan
        errors[key] = err
        used.append(filt.to_dict())
    return {"t": req["t"].to_numpy(), "errors": errors, "signal": signal, "unit": unit,
            "step": step, "filters": used}
