"""Tests of enclab.propagation.kinematics: analytic values, finite-difference checks, shapes, factory."""
from __future__ import annotations

import math

import numpy as np
import pytest
from enclab.propagation.kinematics import (
    DEVICE_KINDS,
    DHChain,
    PhantomPremium15,
    Planar2R,
    SingleJoint,
    franka_panda,
    make_device,
)

EPS = np.finfo(np.float64).eps
FD_STEP = 1e-3  # rad; truncation ~h^2 dominates rounding ~eps/h by four orders at this h

# A random 5-joint DH table exercises both conventions with non-trivial twists and offsets.
_TABLE_RNG = np.random.default_rng(20240501)
RANDOM_TABLE = dict(
    a=_TABLE_RNG.uniform(-0.3, 0.3, 5),
    d=_TABLE_RNG.uniform(-0.3, 0.3, 5),
    alpha=_TABLE_RNG.uniform(-np.pi, np.pi, 5),
    theta_offset=_TABLE_RNG.uniform(-np.pi, np.pi, 5),
    flange=[0.05, -0.02, 0.1],
)


def _reach(table: dict) -> float:
    """Upper bound on the distance from any joint axis to the end point (triangle inequality)."""
    return float(
        np.sum(np.abs(table["a"])) + np.sum(np.abs(table["d"])) + np.linalg.norm(table["flange"])
    )


# (device, R): R bounds the distance from every joint axis to the end point. For a revolute
# joint every output, and every Jacobian entry, is A cos q + B sin q + C in that joint's angle
# with sqrt(A^2 + B^2) <= R, so all its derivatives are bounded by R.
DEVICES = [
    pytest.param(PhantomPremium15(), 0.215 + 0.170, id="phantom"),
    pytest.param(PhantomPremium15(l1=0.20955, l2=0.20955), 2 * 0.20955, id="phantom_20955"),
    pytest.param(SingleJoint(), 1.0, id="single_rad"),
    pytest.param(SingleJoint(unit="m"), 1.0, id="single_m"),
    pytest.param(SingleJoint(radius=0.05), 0.05, id="single_radius"),
    pytest.param(Planar2R(0.3, 0.2), 0.5, id="planar_2r"),
    pytest.param(DHChain(**RANDOM_TABLE, convention="modified"), _reach(RANDOM_TABLE), id="dh_mod"),
    pytest.param(DHChain(**RANDOM_TABLE, convention="standard"), _reach(RANDOM_TABLE), id="dh_std"),
    pytest.param(
        franka_panda(), 0.333 + 0.316 + 0.0825 + 0.0825 + 0.384 + 0.088 + 0.107, id="panda"
    ),
]


def _fd_tolerance(reach: float, h: float = FD_STEP) -> float:
    # Central difference: |(f(q+h) - f(q-h))/2h - f'(q)| <= h^2/6 max|f'''| <= h^2 R / 6.
    # Rounding: each evaluation carries at most ~64 eps R (a few dozen flops on values <= R),
    # divided by 2h. The bound is ~1e-7 R, far below the O(R) derivatives being checked.
    return reach * (h**2 / 6 + 64 * EPS / h)


def _random_configs(device, n_samples: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, size=(n_samples, device.n_joints))


def _central_difference(func, theta: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """Stack of d func / d theta_j along a new last axis, by central differences."""
    columns = []
    for j in range(theta.shape[1]):
        step = np.zeros(theta.shape[1])
        step[j] = h
        columns.append((func(theta + step) - func(theta - step)) / (2 * h))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize(("device", "reach"), DEVICES)
def test_jacobian_matches_central_differences(device, reach):
    theta = _random_configs(device, 64, seed=1)
    fd = _central_difference(device.forward, theta)
    np.testing.assert_allclose(device.jacobian(theta), fd, rtol=0, atol=_fd_tolerance(reach))


@pytest.mark.parametrize(("device", "reach"), DEVICES)
def test_hessian_matches_central_differences_of_jacobian(device, reach):
    theta = _random_configs(device, 64, seed=2)
    fd = _central_difference(device.jacobian, theta)
    hess = device.hessian(theta)
    np.testing.assert_allclose(hess, fd, rtol=0, atol=_fd_tolerance(reach))
    np.testing.assert_array_equal(hess, np.swapaxes(hess, -1, -2))


def test_phantom_zero_configuration():
    l1, l2 = 0.215, 0.170
    phantom = PhantomPremium15(l1, l2)
    np.testing.assert_allclose(phantom.forward(np.zeros(3)), [0.0, 0.0, 0.0], atol=1e-15)
    # dx/dt1 = l1, dy/dt2 = l1, dz/dt3 = l2, every other entry zero
    np.testing.assert_allclose(
        phantom.jacobian(np.zeros(3)), np.diag([l1, l1, l2]), rtol=0, atol=1e-15
    )


def test_phantom_quarter_turns_by_hand():
    l1, l2 = 0.2, 0.1
    phantom = PhantomPremium15(l1, l2)
    # t1 = 90 deg swings the reach l1 (t2 = t3 = 0) from z onto x
    np.testing.assert_allclose(phantom.forward([np.pi / 2, 0, 0]), [l1, 0, -l1], atol=1e-15)
    # t3 = 90 deg: reach l1 + l2, y = l2
    np.testing.assert_allclose(phantom.forward([0, 0, np.pi / 2]), [0, l2, l2], atol=1e-15)
    # t2 = 90 deg: first link vertical, reach 0
    np.testing.assert_allclose(phantom.forward([0, np.pi / 2, 0]), [0, l1, -l1], atol=1e-15)


def test_phantom_default_link_lengths():
    phantom = PhantomPremium15()
    assert (phantom.l1, phantom.l2) == (0.215, 0.170)
    assert phantom.joint_names == ("theta1", "theta2", "theta3")
    assert phantom.output_names == ("x", "y", "z")


def test_planar_2r_analytic():
    l1, l2 = 0.3, 0.2
    arm = Planar2R(l1, l2)
    t1, t2 = 0.4, -1.1
    expected_xy = [
        l1 * math.cos(t1) + l2 * math.cos(t1 + t2),
        l1 * math.sin(t1) + l2 * math.sin(t1 + t2),
    ]
    expected_j = [
        [-l1 * math.sin(t1) - l2 * math.sin(t1 + t2), -l2 * math.sin(t1 + t2)],
        [l1 * math.cos(t1) + l2 * math.cos(t1 + t2), l2 * math.cos(t1 + t2)],
    ]
    np.testing.assert_allclose(arm.forward([t1, t2]), expected_xy, rtol=1e-14)
    np.testing.assert_allclose(arm.jacobian([t1, t2]), expected_j, rtol=1e-14)
    # Stretched out along x the tip is at l1 + l2 and the determinant l1 l2 sin t2 vanishes.
    np.testing.assert_allclose(arm.forward([0, 0]), [l1 + l2, 0], atol=1e-15)
    assert abs(np.linalg.det(arm.jacobian([0.7, 0.0]))) < 1e-15
    assert np.linalg.det(arm.jacobian([t1, t2])) == pytest.approx(l1 * l2 * math.sin(t2))


def test_single_joint_identity_and_radius():
    theta = np.array([[0.0], [0.5], [-2.0]])
    ident = SingleJoint(unit="m")
    assert ident.output_names == ("q",) and ident.output_units == ("m",)
    np.testing.assert_array_equal(ident.forward(theta), theta)
    np.testing.assert_array_equal(ident.jacobian(theta), np.ones((3, 1, 1)))
    np.testing.assert_array_equal(ident.hessian(theta), np.zeros((3, 1, 1, 1)))
    wheel = SingleJoint(radius=0.1)
    assert wheel.output_names == ("x", "y")
    np.testing.assert_allclose(wheel.forward([np.pi / 2]), [0.0, 0.1], atol=1e-16)
    np.testing.assert_allclose(wheel.jacobian([0.0]), [[0.0], [0.1]], atol=1e-16)


def _rot_x(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x, y, z):
    t = np.eye(4)
    t[:3, 3] = [x, y, z]
    return t


# Franka's published table (frankaemika.github.io/docs/control_parameters.html), Craig convention.
PANDA_A = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]
PANDA_D = [0.333, 0, 0.316, 0, 0.384, 0, 0]
PANDA_ALPHA = [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2]


def _panda_flange_by_hand(q):
    pose = np.eye(4)
    for a, d, alpha, qi in zip(PANDA_A, PANDA_D, PANDA_ALPHA, q):
        pose = pose @ _rot_x(alpha) @ _trans(a, 0, 0) @ _rot_z(qi) @ _trans(0, 0, d)
    return pose @ _trans(0, 0, 0.107)


def test_panda_home_position():
    home = _panda_flange_by_hand(np.zeros(7))
    # Known home pose: flange at x = a7 = 0.088, z = 0.333 + 0.316 + 0.384 - 0.107, pointing down.
    np.testing.assert_allclose(home[:3, 3], [0.088, 0.0, 0.926], atol=1e-12)
    np.testing.assert_allclose(home[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(franka_panda().forward(np.zeros(7)), home[:3, 3], atol=1e-12)


def test_panda_random_configurations_by_hand():
    q = np.random.default_rng(7).uniform(-2.5, 2.5, size=(5, 7))
    expected = np.array([_panda_flange_by_hand(row)[:3, 3] for row in q])
    np.testing.assert_allclose(franka_panda().forward(q), expected, rtol=0, atol=1e-12)


def test_panda_flange_offset_option():
    frame7 = franka_panda(flange_d=0.0).forward(np.zeros(7))
    np.testing.assert_allclose(frame7, [0.088, 0.0, 1.033], atol=1e-12)


def test_dh_planar_chain_matches_planar_2r():
    l1, l2 = 0.3, 0.2
    theta = _random_configs(Planar2R(l1, l2), 16, seed=3)
    standard = DHChain(a=[l1, l2], d=[0, 0], alpha=[0, 0], convention="standard")
    modified = DHChain(a=[0, l1], d=[0, 0], alpha=[0, 0], flange=[l2, 0, 0])
    planar = Planar2R(l1, l2).forward(theta)
    for chain in (standard, modified):
        xyz = chain.forward(theta)
        np.testing.assert_allclose(xyz[:, :2], planar, atol=1e-15)
        np.testing.assert_allclose(xyz[:, 2], 0.0, atol=1e-15)
        np.testing.assert_allclose(
            chain.jacobian(theta)[:, :2], Planar2R(l1, l2).jacobian(theta), atol=1e-15
        )


def test_dh_flange_as_homogeneous_transform():
    flange = _rot_z(0.3) @ _trans(0.01, 0.02, 0.03)
    as_matrix = DHChain(**{**RANDOM_TABLE, "flange": flange})
    as_vector = DHChain(**{**RANDOM_TABLE, "flange": flange[:3, 3]})
    theta = _random_configs(as_matrix, 4, seed=4)
    np.testing.assert_array_equal(as_matrix.forward(theta), as_vector.forward(theta))


@pytest.mark.parametrize(("device", "reach"), DEVICES)
def test_shapes(device, reach):
    n, m = device.n_joints, device.n_outputs
    batch = _random_configs(device, 5, seed=5)
    assert device.forward(batch).shape == (5, m)
    assert device.jacobian(batch).shape == (5, m, n)
    assert device.hessian(batch).shape == (5, m, n, n)
    single = batch[2]
    assert device.forward(single).shape == (m,)
    assert device.jacobian(single).shape == (m, n)
    assert device.hessian(single).shape == (m, n, n)
    np.testing.assert_array_equal(device.forward(single), device.forward(batch)[2])
    np.testing.assert_array_equal(device.jacobian(list(single)), device.jacobian(batch)[2])
    assert device.forward(np.empty((0, n))).shape == (0, m)
    assert len(device.joint_units) == n and set(device.joint_units) <= {"rad", "m"}
    assert len(device.output_units) == m


def test_nan_sample_does_not_contaminate_others():
    theta = np.zeros((3, 3))
    theta[1, 0] = np.nan
    out = PhantomPremium15().forward(theta)
    assert np.all(np.isnan(out[1, [0, 2]]))
    np.testing.assert_allclose(out[[0, 2]], 0.0, atol=1e-15)


@pytest.mark.parametrize(
    "bad", [np.zeros(2), np.zeros((4, 2)), np.zeros((2, 3, 1)), np.float64(0.1)]
)
def test_bad_theta_shape_is_reported(bad):
    with pytest.raises(ValueError, match=r"theta must have shape \(3,\) or \(N, 3\).*got shape"):
        PhantomPremium15().jacobian(bad)


def test_single_joint_flat_array_is_ambiguous():
    with pytest.raises(ValueError, match=r"reshape\(-1, 1\)"):
        SingleJoint().forward(np.zeros(10))
    assert SingleJoint().forward(np.zeros((10, 1))).shape == (10, 1)


def test_non_numeric_theta_is_rejected():
    with pytest.raises(ValueError, match="theta must be a real array"):
        Planar2R(1, 1).forward(["a", "b"])


@pytest.mark.parametrize(
    ("factory", "kwargs", "message"),
    [
        (PhantomPremium15, {"l1": -0.2}, "l1 must be a positive"),
        (Planar2R, {"l1": 0.2, "l2": float("nan")}, "l2 must be a positive"),
        (SingleJoint, {"unit": "deg"}, "unit must be one of"),
        (SingleJoint, {"unit": "m", "radius": 0.1}, "radius applies to a revolute joint"),
        (DHChain, {"a": [0, 0], "d": [0], "alpha": [0, 0]}, "d must have 2 entries"),
        (DHChain, {"a": [0], "d": [0], "alpha": [0], "convention": "craig"}, "convention must be"),
        (DHChain, {"a": [0], "d": [0], "alpha": [0], "flange": [1, 2]}, "flange must be"),
        (DHChain, {"a": [], "d": [], "alpha": []}, "a must be a non-empty"),
        (franka_panda, {"flange_d": "long"}, "flange_d must be"),
    ],
)
def test_invalid_parameters_are_reported(factory, kwargs, message):
    with pytest.raises(ValueError, match=message):
        factory(**kwargs)


def test_make_device_builds_every_kind():
    specs = {
        "phantom_premium_1_5": {"kind": "phantom_premium_1_5", "l1": 0.20955},
        "single_joint": {"kind": "single_joint", "unit": "m"},
        "planar_2r": {"kind": "planar_2r", "l1": 0.3, "l2": 0.2},
        "dh": {"kind": "dh", "a": [0, 0.3], "d": [0.1, 0], "alpha": [np.pi / 2, 0]},
        "franka_panda": {"kind": "franka_panda"},
    }
    assert set(specs) == set(DEVICE_KINDS)
    for kind, spec in specs.items():
        device = make_device(spec)
        rebuilt = make_device(device.spec)
        theta = _random_configs(device, 3, seed=6)
        np.testing.assert_array_equal(rebuilt.forward(theta), device.forward(theta))
    assert make_device(specs["phantom_premium_1_5"]).l1 == 0.20955


def test_make_device_unknown_kind_names_it_and_lists_kinds():
    with pytest.raises(ValueError) as info:
        make_device({"kind": "an unknown device"})
    message = str(info.value)
    assert "'an unknown device'" in message
    assert all(kind in message for kind in DEVICE_KINDS)


def test_make_device_unknown_and_missing_parameters():
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['length', 'wheels'\]"):
        make_device({"kind": "planar_2r", "l1": 1, "l2": 1, "length": 2, "wheels": 4})
    with pytest.raises(ValueError, match=r"missing parameter\(s\) \['l2'\]"):
        make_device({"kind": "planar_2r", "l1": 1})
    with pytest.raises(ValueError, match="has no 'kind'"):
        make_device({"l1": 1})
    with pytest.raises(ValueError, match="must be a mapping"):
        make_device("phantom_premium_1_5")
