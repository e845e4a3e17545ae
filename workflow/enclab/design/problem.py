"""What a design must achieve: device, workspace, motion, sample rate, budget and candidates.

A :class:`DesignProblem` is built from the ``design:`` block of ``config.yaml`` (or any mapping
of the same form) by :func:`problem_from_config`; every value is checked here, with errors that
name the key. SI units inside (rad, m, s, Hz); the configuration may give angles in degrees
where the key says so (``box_deg``, ``amplitude_deg``).

The workspace is a box of joint angles that the motion visits. The design model places the
centre of the motion on a grid (``points`` per joint) over the box shrunk by the motion's
amplitude, so that every motion stays inside the box; the simulation check draws centres
uniformly over the same shrunk box. A workspace may instead be a logged trajectory (the truth
of a manifest entry): the design then holds for that trajectory at any sub-step position.
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from enclab.propagation import filters as flt
from enclab.propagation.kinematics import Device, make_device

__all__ = [
    "ARCHITECTURES",
    "BudgetItem",
    "SinusoidMotion",
    "DesignProblem",
    "problem_from_config",
]

ARCHITECTURES = ("operational", "joint")
_ORDERS = (0, 1, 2)
_STD_CRITERIA = ("worst_phase", "average")


def _number(key: str, value, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
            or (positive and value <= 0):
        kind = "a finite positive number" if positive else "a finite number"
        raise ValueError(f"design.{key} must be {kind}, got {value!r}")
    return float(value)


def _per_joint(key: str, value, n: int, positive: bool = True) -> np.ndarray:
    values = [value] * n if not isinstance(value, (Sequence, np.ndarray)) or isinstance(value, str) \
        else list(value)
    if len(values) != n:
        raise ValueError(f"design.{key} must be one value or {n} values (one per joint), got {value!r}")
    return np.array([_number(key, v, positive) for v in values])


@dataclass(frozen=True)
class BudgetItem:
    """One requirement: ``std`` and/or ``worst`` (max |error|) of the derivative of ``order``
    (0 position, 1 velocity, 2 acceleration) on each of ``axes`` (operational output names),
    in SI units (m, m/s, m/s^2; rad... for a joint-coordinate device)."""

    order: int
    axes: tuple[str, ...]
    std: float | None = None
    worst: float | None = None

    def label(self) -> str:
        parts = [f"std<={self.std:g}" if self.std is not None else "",
                 f"worst<={self.worst:g}" if self.worst is not None else ""]
        return f"order{self.order}[{','.join(self.axes)}] " + " ".join(p for p in parts if p)

    def to_dict(self) -> dict:
        return {"order": self.order, "axes": list(self.axes), "std": self.std, "worst": self.worst}


@dataclass(frozen=True)
class SinusoidMotion:
    """The Section IV protocol of Colonnese & Okamura about a centre: ``theta_i = c_i + A_i sin(2 pi f_i t + phi_i)``.

    ``A_i`` is fixed per joint, ``f_i`` anywhere in ``[f_lo, f_hi]``, ``phi_i`` anything; the
    joints move at distinct frequencies (independent errors). The design model takes the worst
    frequency of the band (evaluated at ``n_freqs`` points, ends included).

    Signature when it does not describe the real motion: a motion that dwells longer at its
    turning points (slower, or with a smaller amplitude) has a smaller derivative noise than
    the model, a faster one tends to the white-noise (PQN) level; a motion whose turning points
    wander over the grid (varying amplitude) scatters less from run to run than the
    worst-phase prediction assumes.
    """

    amplitude: np.ndarray
    freq_band: tuple[float, float]
    n_freqs: int = 3

    def freqs(self) -> np.ndarray:
        lo, hi = self.freq_band
        return np.array([lo]) if hi == lo else np.linspace(lo, hi, self.n_freqs)


@dataclass
class DesignProblem:
    """Everything the search needs (see :func:`problem_from_config`)."""

    device: Device
    fs_hz: float
    budget: list[BudgetItem]
    steps: np.ndarray                # (R,) candidate quantization steps, same for every joint
    costs: np.ndarray                # (R,) cost of one joint's encoder at each step
    labels: list[str]                # (R,) how the candidates were given (e.g. "8192 cpr")
    filters: list[flt.DerivativeFilter]
    architectures: tuple[str, ...]
    motion: SinusoidMotion | None
    box: np.ndarray | None           # (n, 2) joint ranges visited by the motion (rad or m)
    points: int = 7
    bound_points: int = 16           # cells per joint of the worst-case grid over the box
    trajectory: np.ndarray | None = None   # (N, n) logged truth, for a logged workspace
    trajectory_source: str | None = None
    offset_frac: float = 0.5
    std_criterion: str = "worst_phase"
    phases: int = 32                 # grid phases for the worst-phase model
    max_lag_s: float | None = None   # designs whose filters lag more are not feasible
    check: dict = field(default_factory=dict)
    name: str = "design"

    @property
    def n_joints(self) -> int:
        return self.device.n_joints

    @property
    def orders(self) -> list[int]:
        return sorted({b.order for b in self.budget})

    def centres(self) -> np.ndarray:
        """Grid of motion centres (G, n) over the box shrunk by the amplitude."""
        lo, hi = self.centre_box().T
        axes = [np.linspace(a, b, self.points) if b > a else np.array([a]) for a, b in zip(lo, hi)]
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def centre_box(self) -> np.ndarray:
        """(n, 2) range of the motion's centre: the box shrunk by the amplitude."""
        if self.box is None:
            raise ValueError("a logged-trajectory workspace has no centre box")
        return np.stack([self.box[:, 0] + self.motion.amplitude,
                         self.box[:, 1] - self.motion.amplitude], axis=1)

    def bound_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Points (B, n) of a grid over the whole box (``bound_points`` per joint) and the
        half-widths (n,) of their cells: the cells cover the box."""
        axes, rho = [], []
        for lo, hi in self.box:
            k = self.bound_points if hi > lo else 1
            width = (hi - lo) / k
            axes.append(lo + width * (np.arange(k) + 0.5))
            rho.append(width / 2)
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1), np.array(rho)

    def spacing(self) -> np.ndarray:
        """(n,) grid spacing of the centres (0 for a single point)."""
        lo, hi = self.centre_box().T
        return (hi - lo) / max(self.points - 1, 1)

    def describe(self) -> dict:
        """JSON-friendly description (SI), for the ``design`` block."""
        out = {
            "name": self.name,
            "device": self.device.spec,
            "fs_hz": self.fs_hz,
            "budget": [b.to_dict() for b in self.budget],
            "candidates": {"steps": self.steps.tolist(), "costs": self.costs.tolist(),
                           "labels": list(self.labels), "filters": len(self.filters),
                           "architectures": list(self.architectures)},
            "std_criterion": self.std_criterion,
            "max_lag_s": self.max_lag_s,
            "offset_frac": self.offset_frac,
        }
        if self.trajectory is None:
            out["workspace"] = {"box": self.box.tolist(), "points_per_joint": self.points,
                                "centre_box": self.centre_box().tolist(),
                                "bound_cells_per_joint": self.bound_points}
            out["motion"] = {"kind": "sinusoid", "amplitude": self.motion.amplitude.tolist(),
                             "freq_hz": list(self.motion.freq_band)}
        else:
            out["workspace"] = {"trajectory": self.trajectory_source,
                                "n_samples": int(self.trajectory.shape[0])}
        return out


def _filters(spec, bank_config) -> list[flt.DerivativeFilter]:
    if spec in (None, "bank"):
        if not bank_config:
            raise ValueError("design.filters is 'bank' but no derivatives.bank was given")
        bank = bank_config["bank"]
        return [flt.DerivativeFilter(int(d), int(n), float(fc), disc)
                for d in bank["d"] for n in bank["n"] for fc in bank["fc_hz"]
                for disc in bank["discretization"]]
    if not isinstance(spec, Sequence) or isinstance(spec, str) or not spec:
        raise ValueError(f"design.filters must be 'bank' or a non-empty list of filters, got {spec!r}")
    out = []
    for i, item in enumerate(spec):
        try:
            out.append(flt.DerivativeFilter.from_dict(dict(item)))
        except (TypeError, ValueError) as err:
            raise ValueError(f"design.filters[{i}]: {err}") from None
    return out


def _resolutions(spec, unit: str):
    if not isinstance(spec, Mapping):
        raise ValueError("design.resolutions must be a mapping with counts_per_rev (or step) and cost")
    costs = spec.get("cost")
    if "counts_per_rev" in spec:
        if unit != "rad":
            raise ValueError("design.resolutions.counts_per_rev needs revolute joints; give step (m)")
        counts = list(spec["counts_per_rev"])
        steps = [2 * math.pi / _number("resolutions.counts_per_rev", c) for c in counts]
        labels = [f"{int(c)} cpr" if float(c).is_integer() else f"{c:g} cpr" for c in counts]
    elif "step" in spec:
        steps = [_number("resolutions.step", s) for s in spec["step"]]
        labels = [f"{s:.4g} {unit}" for s in steps]
    else:
        raise ValueError("design.resolutions needs counts_per_rev (revolute) or step")
    if not steps:
        raise ValueError("design.resolutions must list at least one candidate")
    if costs is None or len(list(costs)) != len(steps):
        raise ValueError(f"design.resolutions.cost must give one cost per candidate ({len(steps)})")
    costs = [_number("resolutions.cost", c, positive=False) for c in costs]
    order = np.argsort(steps)[::-1]  # coarse first
    return (np.array(steps)[order], np.array(costs)[order], [labels[i] for i in order])


def _budget(spec, output_names) -> list[BudgetItem]:
    if not isinstance(spec, Sequence) or isinstance(spec, str) or not spec:
        raise ValueError("design.budget must be a non-empty list of {order, std and/or worst, axes}")
    items = []
    for i, item in enumerate(spec):
        if not isinstance(item, Mapping):
            raise ValueError(f"design.budget[{i}] must be a mapping, got {item!r}")
        unknown = sorted(set(item) - {"order", "std", "worst", "axes"})
        if unknown:
            raise ValueError(f"design.budget[{i}] has unknown keys {unknown}")
        order = item.get("order")
        if order not in _ORDERS:
            raise ValueError(f"design.budget[{i}].order must be 0, 1 or 2, got {order!r}")
        std = None if item.get("std") is None else _number(f"budget[{i}].std", item["std"])
        worst = None if item.get("worst") is None else _number(f"budget[{i}].worst", item["worst"])
        if std is None and worst is None:
            raise ValueError(f"design.budget[{i}] needs std and/or worst")
        axes = item.get("axes", "all")
        axes = tuple(output_names) if axes in ("all", None) else tuple([axes] if isinstance(axes, str) else axes)
        bad = [a for a in axes if a not in output_names]
        if bad or not axes:
            raise ValueError(f"design.budget[{i}].axes {bad or axes} not among the device's "
                             f"outputs {list(output_names)}")
        items.append(BudgetItem(int(order), axes, std, worst))
    return items


def problem_from_config(design: Mapping, devices: Mapping | None = None,
                        derivatives: Mapping | None = None,
                        trajectory: np.ndarray | None = None) -> DesignProblem:
    """Build and check a :class:`DesignProblem` from a ``design:`` configuration block.

    Parameters
    ----------
    design : mapping
        The block (keys: ``device``, ``fs_hz``, ``workspace`` {``box_deg`` or ``box``,
        ``points``} or {``log``}, ``motion`` {``amplitude_deg`` or ``amplitude``, ``freq_hz``},
        ``budget``, ``resolutions``, ``filters``, ``architectures``, ``std``, ``offset_frac``,
        ``phases``, ``check``, ``name``).
    devices : mapping, optional
        ``config["devices"]``, to resolve a device given by name.
    derivatives : mapping, optional
        ``config["derivatives"]``, for ``filters: bank``.
    trajectory : ndarray (N, n), optional
        The logged truth when ``workspace.log`` names a manifest entry (read by the caller).

    Returns
    -------
    DesignProblem
    """
    if not isinstance(design, Mapping):
        raise ValueError("design must be a mapping (the design: block of config.yaml)")
    spec = design.get("device")
    if isinstance(spec, str):
        if not devices or spec not in devices:
            raise ValueError(f"design.device {spec!r} is not a name under devices: "
                             f"{sorted(devices or {})}")
        spec = devices[spec]
    if not isinstance(spec, Mapping):
        raise ValueError("design.device must name a device or give {kind: ...}")
    device = make_device(dict(spec))
    n = device.n_joints
    unit = device.joint_units[0]
    fs_hz = _number("fs_hz", design.get("fs_hz"))
    steps, costs, labels = _resolutions(design.get("resolutions"), unit)
    budget = _budget(design.get("budget"), device.output_names)
    filters = _filters(design.get("filters", "bank"), derivatives)
    for f in filters:
        if f.fc_hz >= fs_hz / 2:
            raise ValueError(f"design.filters: cutoff {f.fc_hz:g} Hz of {f.label()} is at or above "
                             f"the Nyquist frequency {fs_hz / 2:g} Hz")
    needed = {b.order for b in budget if b.order > 0}
    missing = sorted(needed - {f.d for f in filters})
    if missing:
        raise ValueError(f"design.budget asks for derivative order(s) {missing} but no candidate "
                         "filter has that many back differences")
    archs = tuple(design.get("architectures", ["operational"]))
    if not archs or any(a not in ARCHITECTURES for a in archs):
        raise ValueError(f"design.architectures must be a subset of {list(ARCHITECTURES)}, got {list(archs)}")
    std = design.get("std", "worst_phase")
    if std not in _STD_CRITERIA:
        raise ValueError(f"design.std must be one of {list(_STD_CRITERIA)}, got {std!r}")
    offset = design.get("offset_frac", 0.5)
    if isinstance(offset, bool) or not isinstance(offset, numbers.Real) or not 0 <= offset < 1:
        raise ValueError(f"design.offset_frac must be in [0, 1), got {offset!r}")
    phases = design.get("phases", 32)
    if isinstance(phases, bool) or not isinstance(phases, numbers.Integral) or phases < 1:
        raise ValueError(f"design.phases must be a positive integer, got {phases!r}")
    max_lag = design.get("max_lag_s")
    max_lag = None if max_lag is None else _number("max_lag_s", max_lag)
    workspace = design.get("workspace") or {}
    common = dict(device=device, fs_hz=fs_hz, budget=budget, steps=steps, costs=costs,
                  labels=labels, filters=filters, architectures=archs,
                  offset_frac=float(offset), std_criterion=std, phases=int(phases), max_lag_s=max_lag,
                  check=dict(design.get("check") or {}), name=str(design.get("name", "design")))
    if "log" in workspace:
        if trajectory is None:
            raise ValueError(f"design.workspace.log {workspace['log']!r}: the caller must pass the "
                             "logged trajectory")
        trajectory = np.asarray(trajectory, dtype=np.float64)
        if trajectory.ndim != 2 or trajectory.shape[1] != n or not np.all(np.isfinite(trajectory)):
            raise ValueError(f"the logged trajectory must be finite with shape (N, {n}), got "
                             f"{trajectory.shape}")
        return DesignProblem(motion=None, box=None, trajectory=trajectory,
                             trajectory_source=str(workspace["log"]), **common)
    if "box_deg" in workspace:
        box = np.deg2rad(np.asarray(workspace["box_deg"], dtype=np.float64))
    elif "box" in workspace:
        box = np.asarray(workspace["box"], dtype=np.float64)
    else:
        raise ValueError("design.workspace needs box_deg (or box, in SI) or log")
    if box.shape != (n, 2) or not np.all(np.isfinite(box)) or np.any(box[:, 1] < box[:, 0]):
        raise ValueError(f"design.workspace box must be {n} pairs [low, high] with low <= high, "
                         f"got {workspace.get('box_deg', workspace.get('box'))!r}")
    points = workspace.get("points", 7)
    if isinstance(points, bool) or not isinstance(points, numbers.Integral) or points < 1:
        raise ValueError(f"design.workspace.points must be a positive integer, got {points!r}")
    # About 4096 worst-case cells in all (16 per joint for 3 joints, 3 for 7).
    bound_points = workspace.get("bound_points") or max(2, int(4096 ** (1.0 / n) + 1e-9))
    if isinstance(bound_points, bool) or not isinstance(bound_points, numbers.Integral) or bound_points < 1:
        raise ValueError(f"design.workspace.bound_points must be a positive integer, got {bound_points!r}")
    for key, count in (("points", points), ("bound_points", bound_points)):
        if count**n > 200_000:
            raise ValueError(f"design.workspace.{key}={count} gives {count**n} grid points for {n} "
                             "joints (more than 200000); use fewer points per joint")
    motion = design.get("motion") or {}
    if "amplitude_deg" in motion:
        amplitude = np.deg2rad(_per_joint("motion.amplitude_deg", motion["amplitude_deg"], n))
    else:
        amplitude = _per_joint("motion.amplitude", motion.get("amplitude"), n)
    band = motion.get("freq_hz")
    band = [band, band] if isinstance(band, numbers.Real) and not isinstance(band, bool) else band
    if not isinstance(band, Sequence) or len(band) != 2:
        raise ValueError(f"design.motion.freq_hz must be a frequency or a band [low, high], got {band!r}")
    lo, hi = (_number("motion.freq_hz", f) for f in band)
    if hi < lo or hi >= fs_hz / 2:
        raise ValueError(f"design.motion.freq_hz band [{lo:g}, {hi:g}] must be ordered and below "
                         f"the Nyquist frequency {fs_hz / 2:g} Hz")
    if np.any(box[:, 1] - box[:, 0] < 2 * amplitude):
        raise ValueError("design.workspace box is narrower than the motion (2 x amplitude) on "
                         "some joint")
    return DesignProblem(motion=SinusoidMotion(amplitude, (lo, hi)), box=box, points=int(points),
                         bound_points=int(bound_points), **common)
