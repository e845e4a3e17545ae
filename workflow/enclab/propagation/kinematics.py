"""Devices: forward kinematics, Jacobians and Hessians, vectorized over samples.

Every device maps joint coordinates ``theta`` (rad for revolute, m for prismatic joints) to
operational-space outputs (m) and provides the first and second derivatives needed to
propagate joint-space quantization error (Colonnese & Okamura, Table II) and to bound the
error of the affine approximation over a trajectory. All second derivatives are analytic.

Shapes: ``theta`` is ``(N, n)`` (N samples of n joints) or ``(n,)`` (one sample, in which
case the sample axis is dropped from every result). ``forward`` returns ``(N, m)``,
``jacobian`` ``(N, m, n)`` with ``J[k, i, j] = d out_i / d theta_j`` and ``hessian``
``(N, m, n, n)`` with ``H[k, i, j, l] = d^2 out_i / (d theta_j d theta_l)``. Non-finite
joint values are not rejected: they propagate to NaN in the affected samples only, so a log
with gaps can be processed in one call.

References
----------
.. [1] N. Colonnese and A. M. Okamura, "Propagation of joint space quantization error to
   operational space coordinates and their derivatives".
.. [2] M. C. Cavusoglu, D. Feygin, and F. Tendick, "A critical study of the mechanical and
   electrical properties of the PHANToM haptic interface and improvements for high
   performance control," Presence, 11(5):555-568, 2002.
.. [3] Franka Emika, "Robot and interface specifications: Denavit-Hartenberg parameters",
   https://frankaemika.github.io/docs/control_parameters.html
.. [4] J. J. Craig, Introduction to Robotics: Mechanics and Control, 3rd ed., 2005
   (modified DH convention).
"""
from __future__ import annotations

import inspect
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = [
    "DEVICE_KINDS",
    "DHChain",
    "Device",
    "Planar2R",
    "PhantomPremium15",
    "SingleJoint",
    "franka_panda",
    "make_device",
]

JOINT_UNITS = ("rad", "m")


def _positive_length(name: str, value: Any) -> float:
    try:
        length = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive length in m, got {value!r}") from None
    if not (math.isfinite(length) and length > 0.0):
        raise ValueError(f"{name} must be a positive finite length in m, got {value!r}")
    return length


def _finite_vector(name: str, value: Any, length: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a 1-D sequence of numbers, got {value!r}") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence, got shape {arr.shape}")
    if length is not None and arr.size != length:
        raise ValueError(f"{name} must have {length} entries, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


class Device(ABC):
    """Base class of a device: joint coordinates in, operational-space coordinates out.

    Subclasses set ``name``, ``joint_names``, ``joint_units``, ``output_names`` and
    ``output_units`` and implement ``_forward``, ``_jacobian`` and ``_hessian`` on a
    validated ``(N, n)`` float64 array; the public methods handle shapes.

    Attributes
    ----------
    name : str
        Device kind as used by :func:`make_device` (e.g. ``"phantom_premium_1_5"``).
    joint_names : tuple of str
        One name per joint, in the column order of ``theta``.
    joint_units : tuple of str
        ``"rad"`` (revolute) or ``"m"`` (prismatic) per joint.
    output_names : tuple of str
        One name per output, in the column order of ``forward``.
    output_units : tuple of str
        SI unit per output.
    """

    name: str
    joint_names: tuple[str, ...]
    joint_units: tuple[str, ...]
    output_names: tuple[str, ...]
    output_units: tuple[str, ...]

    @property
    def n_joints(self) -> int:
        """Number of joints n."""
        return len(self.joint_names)

    @property
    def n_outputs(self) -> int:
        """Number of outputs m."""
        return len(self.output_names)

    @property
    @abstractmethod
    def spec(self) -> dict:
        """The :func:`make_device` specification that rebuilds this device (JSON-friendly)."""

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.spec.items() if k != "kind")
        return f"{type(self).__name__}({params})"

    def _samples(self, theta: Any) -> tuple[np.ndarray, bool]:
        """Return ``theta`` as an ``(N, n)`` float64 array and whether it was one sample."""
        n = self.n_joints
        try:
            arr = np.asarray(theta, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"theta must be a real array of shape ({n},) or (N, {n}) for device "
                f"{self.name!r}; could not convert {type(theta).__name__} to float"
            ) from None
        if arr.ndim == 1 and arr.shape[0] == n:
            return arr[np.newaxis, :], True
        if arr.ndim == 2 and arr.shape[1] == n:
            return arr, False
        hint = " (use theta.reshape(-1, 1) for N samples of one joint)" if n == 1 else ""
        raise ValueError(
            f"theta must have shape ({n},) or (N, {n}) for device {self.name!r} with "
            f"joints {self.joint_names}; got shape {arr.shape}{hint}"
        )

    def forward(self, theta: Any) -> np.ndarray:
        """Operational-space outputs, shape ``(N, m)`` (or ``(m,)`` for one sample)."""
        arr, single = self._samples(theta)
        out = self._forward(arr)
        return out[0] if single else out

    def jacobian(self, theta: Any) -> np.ndarray:
        """Jacobian ``d out / d theta``, shape ``(N, m, n)`` (or ``(m, n)``)."""
        arr, single = self._samples(theta)
        out = self._jacobian(arr)
        return out[0] if single else out

    def hessian(self, theta: Any) -> np.ndarray:
        """Second derivatives, shape ``(N, m, n, n)`` (or ``(m, n, n)``), symmetric in the
        last two axes."""
        arr, single = self._samples(theta)
        out = self._hessian(arr)
        return out[0] if single else out

    @abstractmethod
    def _forward(self, theta: np.ndarray) -> np.ndarray:
        """Outputs for validated ``theta`` of shape ``(N, n)``; returns ``(N, m)``."""

    @abstractmethod
    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        """Jacobian for validated ``theta`` of shape ``(N, n)``; returns ``(N, m, n)``."""

    @abstractmethod
    def _hessian(self, theta: np.ndarray) -> np.ndarray:
        """Hessian for validated ``theta`` of shape ``(N, n)``; returns ``(N, m, n, n)``."""


class PhantomPremium15(Device):
    """SensAble Phantom Premium 1.5 in the standard coordinates of Cavusoglu et al. [2]_.

    .. math::

        x &= \\sin\\theta_1 (l_1\\cos\\theta_2 + l_2\\sin\\theta_3) \\\\
        y &= l_2 - l_2\\cos\\theta_3 + l_1\\sin\\theta_2 \\\\
        z &= -l_1 + \\cos\\theta_1 (l_1\\cos\\theta_2 + l_2\\sin\\theta_3)

    The origin is the end point in the zero configuration, where
    ``J = [[l1, 0, 0], [0, l1, 0], [0, 0, l2]]``.

    Parameters
    ----------
    l1, l2 : float
        Link lengths in m. Published values differ: 0.215 m / 0.170 m are used by several
        codes derived from Cavusoglu et al. (the default here), 0.20955 m (8.25 in) for l1 by
        others. They are configuration (``make_device``) because the sensitivities, and hence
        every Cartesian prediction, scale with them.

    References
    ----------
    .. [1] Colonnese & Okamura, Section IV and Fig. 4.
    .. [2] Cavusoglu, Feygin and Tendick, Presence 11(5), 2002.
    """

    name = "phantom_premium_1_5"
    joint_names = ("theta1", "theta2", "theta3")
    joint_units = ("rad", "rad", "rad")
    output_names = ("x", "y", "z")
    output_units = ("m", "m", "m")

    def __init__(self, l1: float = 0.215, l2: float = 0.170) -> None:
        self.l1 = _positive_length("l1", l1)
        self.l2 = _positive_length("l2", l2)

    @property
    def spec(self) -> dict:
        return {"kind": self.name, "l1": self.l1, "l2": self.l2}

    def _trig(self, theta: np.ndarray):
        t1, t2, t3 = theta.T
        return np.sin(t1), np.cos(t1), np.sin(t2), np.cos(t2), np.sin(t3), np.cos(t3)

    def _forward(self, theta: np.ndarray) -> np.ndarray:
        s1, c1, s2, c2, s3, c3 = self._trig(theta)
        reach = self.l1 * c2 + self.l2 * s3
        return np.stack(
            [s1 * reach, self.l2 - self.l2 * c3 + self.l1 * s2, -self.l1 + c1 * reach], axis=-1
        )

    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        s1, c1, s2, c2, s3, c3 = self._trig(theta)
        l1, l2 = self.l1, self.l2
        reach = l1 * c2 + l2 * s3
        zero = np.zeros_like(s1)
        rows = [
            [c1 * reach, -l1 * s1 * s2, l2 * s1 * c3],
            [zero, l1 * c2, l2 * s3],
            [-s1 * reach, -l1 * c1 * s2, l2 * c1 * c3],
        ]
        return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)

    def _hessian(self, theta: np.ndarray) -> np.ndarray:
        s1, c1, s2, c2, s3, c3 = self._trig(theta)
        l1, l2 = self.l1, self.l2
        reach = l1 * c2 + l2 * s3
        zero = np.zeros_like(s1)
        hx = [
            [-s1 * reach, -l1 * c1 * s2, l2 * c1 * c3],
            [-l1 * c1 * s2, -l1 * s1 * c2, zero],
            [l2 * c1 * c3, zero, -l2 * s1 * s3],
        ]
        hy = [
            [zero, zero, zero],
            [zero, -l1 * s2, zero],
            [zero, zero, l2 * c3],
        ]
        hz = [
            [-c1 * reach, l1 * s1 * s2, -l2 * s1 * c3],
            [l1 * s1 * s2, -l1 * c1 * c2, zero],
            [-l2 * s1 * c3, zero, -l2 * c1 * s3],
        ]
        return np.stack([_stack_matrix(h) for h in (hx, hy, hz)], axis=1)


def _stack_matrix(entries: Sequence[Sequence[np.ndarray]]) -> np.ndarray:
    """Stack a nested list of ``(N,)`` arrays into ``(N, rows, cols)``."""
    return np.stack([np.stack(row, axis=-1) for row in entries], axis=-2)


class SingleJoint(Device):
    """One joint, revolute (``unit="rad"``) or prismatic (``unit="m"``).

    With ``radius=None`` the output is the joint coordinate itself (output ``"q"``, in the
    joint's unit). With a radius r (revolute only) the outputs are the coordinates of a point
    at distance r from the axis: ``x = r cos q``, ``y = r sin q`` (m).

    Parameters
    ----------
    unit : {"rad", "m"}
        Unit of the joint coordinate.
    radius : float or None
        Lever arm in m, or None for the joint coordinate itself.
    """

    name = "single_joint"
    joint_names = ("q1",)

    def __init__(self, unit: str = "rad", radius: float | None = None) -> None:
        if unit not in JOINT_UNITS:
            raise ValueError(f"unit must be one of {JOINT_UNITS}, got {unit!r}")
        if radius is not None and unit != "rad":
            raise ValueError(
                f"radius applies to a revolute joint (unit='rad'); got radius={radius!r} "
                f"with unit={unit!r}"
            )
        self.unit = unit
        self.radius = None if radius is None else _positive_length("radius", radius)
        self.joint_units = (unit,)
        if self.radius is None:
            self.output_names = ("q",)
            self.output_units = (unit,)
        else:
            self.output_names = ("x", "y")
            self.output_units = ("m", "m")

    @property
    def spec(self) -> dict:
        return {"kind": self.name, "unit": self.unit, "radius": self.radius}

    def _forward(self, theta: np.ndarray) -> np.ndarray:
        if self.radius is None:
            return theta.copy()
        q = theta[:, 0]
        return self.radius * np.stack([np.cos(q), np.sin(q)], axis=-1)

    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        if self.radius is None:
            return np.ones((theta.shape[0], 1, 1))
        q = theta[:, 0]
        return (self.radius * np.stack([-np.sin(q), np.cos(q)], axis=-1))[:, :, np.newaxis]

    def _hessian(self, theta: np.ndarray) -> np.ndarray:
        if self.radius is None:
            return np.zeros((theta.shape[0], 1, 1, 1))
        return -self._forward(theta)[:, :, np.newaxis, np.newaxis]


class Planar2R(Device):
    """Planar two-link revolute arm.

    ``x = l1 cos t1 + l2 cos(t1 + t2)``, ``y = l1 sin t1 + l2 sin(t1 + t2)``.

    Parameters
    ----------
    l1, l2 : float
        Link lengths in m.
    """

    name = "planar_2r"
    joint_names = ("theta1", "theta2")
    joint_units = ("rad", "rad")
    output_names = ("x", "y")
    output_units = ("m", "m")

    def __init__(self, l1: float, l2: float) -> None:
        self.l1 = _positive_length("l1", l1)
        self.l2 = _positive_length("l2", l2)

    @property
    def spec(self) -> dict:
        return {"kind": self.name, "l1": self.l1, "l2": self.l2}

    def _parts(self, theta: np.ndarray):
        t1 = theta[:, 0]
        t12 = t1 + theta[:, 1]
        # (N, 2) tip contributions of link 1 and of link 2, as (cos, sin) pairs
        link1 = self.l1 * np.stack([np.cos(t1), np.sin(t1)], axis=-1)
        link2 = self.l2 * np.stack([np.cos(t12), np.sin(t12)], axis=-1)
        return link1, link2

    def _forward(self, theta: np.ndarray) -> np.ndarray:
        link1, link2 = self._parts(theta)
        return link1 + link2

    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        link1, link2 = self._parts(theta)
        perp = np.array([-1.0, 1.0])  # d/dt (r cos t, r sin t) = (-r sin t, r cos t)
        col2 = link2[:, ::-1] * perp
        col1 = link1[:, ::-1] * perp + col2
        return np.stack([col1, col2], axis=-1)

    def _hessian(self, theta: np.ndarray) -> np.ndarray:
        link1, link2 = self._parts(theta)
        h = np.empty((theta.shape[0], 2, 2, 2))
        h[:, :, 0, 0] = -(link1 + link2)
        h[:, :, 0, 1] = h[:, :, 1, 0] = h[:, :, 1, 1] = -link2
        return h


class DHChain(Device):
    """Serial chain of revolute joints from a Denavit-Hartenberg table (position outputs).

    Row i of the table gives the transform from frame i-1 to frame i:

    - ``convention="modified"`` (Craig [4]_):
      ``RotX(alpha_i) TransX(a_i) RotZ(theta_i + offset_i) TransZ(d_i)``; joint i turns about
      the z axis of frame i.
    - ``convention="standard"``:
      ``RotZ(theta_i + offset_i) TransZ(d_i) TransX(a_i) RotX(alpha_i)``; joint i turns about
      the z axis of frame i-1.

    The outputs are x, y, z of the end point: the origin of the last frame, moved by
    ``flange`` (expressed in the last frame) when given. Jacobian and Hessian are analytic
    for a revolute chain with unit axes ``z_j`` through points ``p_j`` and end point ``p``:
    ``J_j = z_j x (p - p_j)`` and, for ``j <= l``, ``H_jl = H_lj = z_j x J_l``.

    Parameters
    ----------
    a, d, alpha : sequence of float
        DH link lengths (m), link offsets (m) and twists (rad), one entry per joint.
    theta_offset : sequence of float or None
        Constant added to each joint angle (rad); None means zeros.
    convention : {"modified", "standard"}
        DH convention of the table.
    flange : None, sequence of 3 floats, or 4x4 array
        Fixed end-point offset in the last frame (m), or a homogeneous transform whose
        translation is used (orientation is not an output).
    """

    name = "dh"
    CONVENTIONS = ("modified", "standard")

    def __init__(
        self,
        a: Sequence[float],
        d: Sequence[float],
        alpha: Sequence[float],
        theta_offset: Sequence[float] | None = None,
        convention: str = "modified",
        flange: Any = None,
    ) -> None:
        self.a = _finite_vector("a", a)
        n = self.a.size
        self.d = _finite_vector("d", d, n)
        self.alpha = _finite_vector("alpha", alpha, n)
        self.theta_offset = (
            np.zeros(n) if theta_offset is None else _finite_vector("theta_offset", theta_offset, n)
        )
        if convention not in self.CONVENTIONS:
            raise ValueError(f"convention must be one of {self.CONVENTIONS}, got {convention!r}")
        self.convention = convention
        self.flange = self._flange_offset(flange)
        self._twist_trig = [self._exact_trig(al) for al in self.alpha]
        self.joint_names = tuple(f"theta{i + 1}" for i in range(n))
        self.joint_units = ("rad",) * n
        self.output_names = ("x", "y", "z")
        self.output_units = ("m", "m", "m")

    @staticmethod
    def _exact_trig(angle: float) -> tuple[float, float]:
        """``(cos, sin)`` of a twist, exact for multiples of pi/2: ``cos(pi/2)`` is 6e-17 in
        floating point, a rounding of the pi/2 the table means, not a geometric twist."""
        c, s = math.cos(angle), math.sin(angle)
        if abs(c) < 1e-15:
            return 0.0, math.copysign(1.0, s)
        if abs(s) < 1e-15:
            return math.copysign(1.0, c), 0.0
        return c, s

    @staticmethod
    def _flange_offset(flange: Any) -> np.ndarray:
        if flange is None:
            return np.zeros(3)
        try:
            arr = np.asarray(flange, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"flange must be None, 3 numbers or a 4x4 transform, got {flange!r}"
            ) from None
        if arr.shape == (4, 4):
            if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0]):
                raise ValueError(
                    f"flange 4x4 transform must end with row [0, 0, 0, 1], got {arr[3]}"
                )
            arr = arr[:3, 3]
        if arr.shape != (3,) or not np.all(np.isfinite(arr)):
            raise ValueError(
                f"flange must be None, 3 finite numbers or a 4x4 transform, got shape {arr.shape}"
            )
        return arr.copy()

    @property
    def spec(self) -> dict:
        return {
            "kind": self.name,
            "a": self.a.tolist(),
            "d": self.d.tolist(),
            "alpha": self.alpha.tolist(),
            "theta_offset": self.theta_offset.tolist(),
            "convention": self.convention,
            "flange": self.flange.tolist(),
        }

    def frames_from_trig(self, cos_q: np.ndarray, sin_q: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint axes, points on them and end point from the cosines and sines of the joints.

        The joint-major layout (samples last) of :meth:`_axes`, for callers that keep whole
        signals as rows (:mod:`enclab.propagation.stream`) or get the trigonometry cheaper than
        ``numpy.cos`` (a table of quantized angles).

        Parameters
        ----------
        cos_q, sin_q : ndarray, shape (n, N)
            ``cos`` and ``sin`` of ``theta + theta_offset``, one row per joint.

        Returns
        -------
        z : ndarray, shape (n, 3, N)
            Unit axis of each joint (base frame).
        p : ndarray, shape (n, 3, N)
            A point on each axis (the origin of its frame).
        end : ndarray, shape (3, N)
            The end point.

        Notes
        -----
        Each frame is kept as its three rotation columns and its origin, each a ``(3, N)``
        array, and composed column by column: a link transform changes two columns with one
        plane rotation for ``RotZ(theta)`` and one for the constant ``RotX(alpha)``, about a
        third of the arithmetic of a 4x4 product and none of its per-sample dispatch (a
        batched ``matmul`` of 4x4 matrices costs about 6x more per sample).
        """
        n = self.a.size
        # Start from the base frame as broadcastable columns; the first link makes them (3, N).
        r0 = np.array([[1.0], [0.0], [0.0]])
        r1 = np.array([[0.0], [1.0], [0.0]])
        r2 = np.array([[0.0], [0.0], [1.0]])
        p = np.zeros((3, 1))
        n_samples = cos_q.shape[1]
        z_out = np.empty((n, 3, n_samples))
        p_out = np.empty((n, 3, n_samples))
        modified = self.convention == "modified"
        for i in range(n):
            ct, st = cos_q[i], sin_q[i]
            a, d = self.a[i], self.d[i]
            if modified:
                # F_i = F_{i-1} RotX(alpha) TransX(a) RotZ(q) TransZ(d); joint i turns about z_i.
                if a != 0.0:
                    p = p + a * r0
                u1, r2 = self._twist(i, r1, r2)
                r0, r1 = self._turn(ct, st, r0, u1)
                if d != 0.0:
                    p = p + d * r2
                z_out[i], p_out[i] = r2, p
            else:
                # F_i = F_{i-1} RotZ(q) TransZ(d) TransX(a) RotX(alpha); joint i turns about
                # z_{i-1} through the origin of frame i-1.
                z_out[i], p_out[i] = r2, p
                r0, c1 = self._turn(ct, st, r0, r1)
                if d != 0.0:
                    p = p + d * r2
                if a != 0.0:
                    p = p + a * r0
                r1, r2 = self._twist(i, c1, r2)
        end = np.array(np.broadcast_to(p, (3, n_samples)))
        for f, column in zip(self.flange, (r0, r1, r2)):
            if f != 0.0:
                end += f * column
        return z_out, p_out, end

    @staticmethod
    def _turn(ct: np.ndarray, st: np.ndarray, c0: np.ndarray, c1: np.ndarray):
        """Columns 0 and 1 of ``[c0 c1 .] RotZ(q)``."""
        new0 = ct * c0
        new0 += st * c1
        new1 = ct * c1
        new1 -= st * c0
        return new0, new1

    def _twist(self, i: int, c1: np.ndarray, c2: np.ndarray):
        """Columns 1 and 2 of ``[. c1 c2] RotX(alpha_i)``; a twist of 0 or +-pi/2 (every row
        of the usual tables) only permutes and negates columns."""
        ca, sa = self._twist_trig[i]
        if sa == 0.0:
            return (c1, c2) if ca == 1.0 else (-c1, -c2)
        if ca == 0.0:
            return (c2, -c1) if sa == 1.0 else (-c2, c1)
        return ca * c1 + sa * c2, ca * c2 - sa * c1

    def frames(self, theta_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`frames_from_trig` of joint angles given as rows, shape ``(n, N)``."""
        q = theta_rows + self.theta_offset[:, np.newaxis]
        return self.frames_from_trig(np.cos(q), np.sin(q))

    @staticmethod
    def jacobian_rows(z: np.ndarray, p: np.ndarray, end: np.ndarray,
                      out: np.ndarray | None = None) -> np.ndarray:
        """Jacobian ``J[j, i, k] = d out_j / d theta_i`` at sample ``k``, shape ``(3, n, N)``,
        from the output of :meth:`frames_from_trig`: column ``i`` is ``z_i x (end - p_i)``.
        ``out`` (that shape) receives it when given."""
        d = end[np.newaxis] - p
        jac = np.empty((3,) + z.shape[:1] + z.shape[2:]) if out is None else out
        for j, (k, l) in enumerate(((1, 2), (2, 0), (0, 1))):
            np.multiply(z[:, k], d[:, l], out=jac[j])
            jac[j] -= z[:, l] * d[:, k]
        return jac

    def _axes(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint axes ``z`` (N, n, 3), points on them ``p`` (N, n, 3) and end point (N, 3)."""
        z, p, end = self.frames(np.ascontiguousarray(theta.T))
        return z.transpose(2, 0, 1), p.transpose(2, 0, 1), end.T

    def _forward(self, theta: np.ndarray) -> np.ndarray:
        return self._axes(theta)[2]

    def _columns(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, p, end = self._axes(theta)
        return z, np.cross(z, end[:, np.newaxis, :] - p)

    def _jacobian(self, theta: np.ndarray) -> np.ndarray:
        return self.jacobian_rows(*self.frames(np.ascontiguousarray(theta.T))).transpose(2, 0, 1)

    def _hessian(self, theta: np.ndarray) -> np.ndarray:
        z, cols = self._columns(theta)
        n = theta.shape[1]
        # z_j x J_l for every pair; the Hessian uses the proximal axis with the distal column
        pairs = np.cross(z[:, :, np.newaxis, :], cols[:, np.newaxis, :, :])
        idx = np.arange(n)
        proximal, distal = np.minimum.outer(idx, idx), np.maximum.outer(idx, idx)
        return np.moveaxis(pairs[:, proximal, distal, :], -1, 1)


def franka_panda(flange_d: float = 0.107) -> DHChain:
    """Franka Emika Panda (7 revolute joints) from Franka's published modified DH table.

    ======  ========  =======  ========
    joint   a (m)     d (m)    alpha
    ======  ========  =======  ========
    1       0         0.333    0
    2       0         0        -pi/2
    3       0         0.316    pi/2
    4       0.0825    0        pi/2
    5       -0.0825   0.384    -pi/2
    6       0         0        pi/2
    7       0.088     0        pi/2
    flange  0         0.107    0
    ======  ========  =======  ========

    At q = 0 the flange is at (0.088, 0, 0.926) m with its z axis pointing down.

    Parameters
    ----------
    flange_d : float
        Distance (m) from frame 7 to the end point along z7. The default 0.107 is the flange;
        0 gives frame 7; 0.107 + 0.1034 is the Franka Hand's TCP (position only).

    References
    ----------
    .. [1] Franka Emika, "Robot and interface specifications", Denavit-Hartenberg
       parameters (Craig's convention),
       https://frankaemika.github.io/docs/control_parameters.html
    """
    try:
        offset = float(flange_d)
    except (TypeError, ValueError):
        raise ValueError(f"flange_d must be a finite length in m, got {flange_d!r}") from None
    if not math.isfinite(offset):
        raise ValueError(f"flange_d must be a finite length in m, got {flange_d!r}")
    half_pi = math.pi / 2
    return DHChain(
        a=[0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088],
        d=[0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0],
        alpha=[0.0, -half_pi, half_pi, half_pi, -half_pi, half_pi, half_pi],
        convention="modified",
        flange=[0.0, 0.0, offset],
    )


_FACTORIES = {
    "phantom_premium_1_5": PhantomPremium15,
    "single_joint": SingleJoint,
    "planar_2r": Planar2R,
    "dh": DHChain,
    "franka_panda": franka_panda,
}

DEVICE_KINDS: tuple[str, ...] = tuple(_FACTORIES)


def make_device(spec: Mapping[str, Any]) -> Device:
    """Build a device from a configuration mapping.

    Parameters
    ----------
    spec : mapping
        ``{"kind": <one of DEVICE_KINDS>, **params}`` where params are the keyword arguments
        of the device's constructor (e.g. ``{"kind": "phantom_premium_1_5", "l1": 0.20955}``).

    Returns
    -------
    Device

    Raises
    ------
    ValueError
        If ``kind`` is missing or unknown (the message lists the known kinds), if a
        parameter is unknown or a required one missing (the message names them), or if a
        parameter value is invalid.
    """
    if not isinstance(spec, Mapping):
        raise ValueError(f"device spec must be a mapping with a 'kind' key, got {spec!r}")
    if "kind" not in spec:
        raise ValueError(f"device spec has no 'kind'; known kinds: {', '.join(DEVICE_KINDS)}")
    kind = spec["kind"]
    if kind not in _FACTORIES:
        raise ValueError(f"unknown device kind {kind!r}; known kinds: {', '.join(DEVICE_KINDS)}")
    factory = _FACTORIES[kind]
    params = {k: v for k, v in spec.items() if k != "kind"}
    signature = inspect.signature(factory)
    allowed = [p for p in signature.parameters if p != "self"]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise ValueError(
            f"unknown parameter(s) {unknown} for device kind {kind!r}; allowed: {allowed}"
        )
    missing = [
        p.name
        for p in signature.parameters.values()
        if p.default is inspect.Parameter.empty and p.name not in params
    ]
    if missing:
        raise ValueError(f"missing parameter(s) {missing} for device kind {kind!r}")
    return factory(**params)
