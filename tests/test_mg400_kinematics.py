"""MG400 kinematics: the doc's forward model, closed-form inverse, and joint limits with the coupling."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from simshear_gym.robots.mg400.kinematics import (
    LimitError,
    MG400Geometry,
    MG400Limits,
    UnreachableError,
    check_joint_limits,
    check_pose_reachable,
    forward,
    inverse,
)


def doc_forward(j1: float, j2: float, j3: float, j4: float) -> tuple[float, float, float, float]:
    """The protocol doc's formula, written out independently of the module."""
    s, c = (lambda a: math.sin(math.radians(a))), (lambda a: math.cos(math.radians(a)))
    r = 109.0 + 175.0 * s(j2) + 175.0 * c(j3)
    z = 175.0 * c(j2) - 175.0 * s(j3) - 57.0
    return r * c(j1), r * s(j1), z, j1 + j4


def random_valid_joints(rng: np.random.Generator, count: int) -> np.ndarray:
    limits = MG400Limits()
    lows = [limits.j1_deg[0], limits.j2_deg[0], limits.j3_deg[0], limits.j4_deg[0]]
    highs = [limits.j1_deg[1], limits.j2_deg[1], limits.j3_deg[1], limits.j4_deg[1]]
    out = []
    while len(out) < count:
        q = rng.uniform(lows, highs)
        try:
            check_joint_limits(q)
        except LimitError:
            continue
        out.append(q)
    return np.array(out)


def test_zero_joints_put_the_flange_at_284_0_118():
    assert doc_forward(0, 0, 0, 0) == pytest.approx((284.0, 0.0, 118.0, 0.0))
    assert forward([0, 0, 0, 0]) == pytest.approx((284.0, 0.0, 118.0, 0.0))


def test_geometry_defaults_sum_to_the_doc_radius_offset():
    geometry = MG400Geometry()
    assert geometry.radial_offset_mm == pytest.approx(109.0)
    assert geometry.tool_z_mm == -57.0


@pytest.mark.parametrize("joints", [(30, 10, 20, 5), (-90, 40, -10, 100), (150, 80, 100, -170), (0, -19, -5, 0)])
def test_forward_matches_the_doc_formula(joints):
    assert forward(joints) == pytest.approx(doc_forward(*joints), abs=1e-9)


def test_fk_ik_round_trip_over_random_valid_joints():
    rng = np.random.default_rng(1)
    for q in random_valid_joints(rng, 500):
        pose = forward(q)
        assert np.allclose(inverse(*pose), q, atol=1e-7), (q, pose)


def test_ik_fk_round_trip_over_random_reachable_poses():
    rng = np.random.default_rng(2)
    checked = 0
    for _ in range(2000):
        pose = rng.uniform([-450, -450, -220, -180], [450, 450, 200, 180])
        try:
            joints = check_pose_reachable(pose)
        except (LimitError, UnreachableError):
            continue
        fk = np.array(forward(joints))
        assert np.allclose(fk[:3], pose[:3], atol=1e-7)
        assert math.isclose(((fk[3] - pose[3] + 180) % 360) - 180, 0.0, abs_tol=1e-7)
        checked += 1
    assert checked > 200


def test_reach_matches_the_doc():
    rng = np.random.default_rng(3)
    poses = np.array([forward(q) for q in random_valid_joints(rng, 3000)])
    radius = np.hypot(poses[:, 0], poses[:, 1])
    assert 170 < radius.min() < 190 and 440 < radius.max() <= 447.1
    assert -220 < poses[:, 2].min() < -200 and 180 < poses[:, 2].max() < 193


def test_j4_is_wrapped():
    joints = inverse(*forward([-20, 10, 10, 0])[:3], 170.0)
    assert joints[3] == pytest.approx(-170.0)
    check_joint_limits(joints)


@pytest.mark.parametrize("joints, name, value, lower, upper", [
    ((170, 0, 0, 0), "J1", 170, -160, 160),
    ((-161, 0, 0, 0), "J1", -161, -160, 160),
    ((0, -26, 10, 0), "J2", -26, -25, 85),
    ((0, 86, 60, 0), "J2", 86, -25, 85),
    ((0, 0, -26, 0), "J3", -26, -25, 105),
    ((0, 60, 106, 0), "J3", 106, -25, 105),
    ((0, 0, 0, 181), "J4", 181, -180, 180),
    ((0, 0, 0, -190), "J4", -190, -180, 180),
])
def test_each_joint_limit_is_refused_with_a_clear_message(joints, name, value, lower, upper):
    with pytest.raises(LimitError) as info:
        check_joint_limits(joints)
    error = info.value
    assert (error.joint, error.value_deg, error.lower_deg, error.upper_deg) == (name, value, lower, upper)
    message = str(error)
    assert message.startswith(f"{name} = {value:.3f} deg") and f"[{lower}, {upper}] deg" in message
    assert isinstance(error, ValueError)


@pytest.mark.parametrize("j2, j3, diff", [(0, 61, 61), (80, 10, -70)])
def test_parallelogram_coupling_is_refused(j2, j3, diff):
    with pytest.raises(LimitError, match=r"J3-J2 = .* outside the allowed range \[-60, 60\] deg") as info:
        check_joint_limits((0, j2, j3, 0))
    assert info.value.joint == "J3-J2" and info.value.value_deg == diff


def test_j2_coupled_lower_limit_when_j3_is_not_positive():
    check_joint_limits((0, -20, 1, 0))  # J3 > 0: the plain J2 range applies
    check_joint_limits((0, -19, 0, 0))
    with pytest.raises(LimitError, match=r"J2 = -20.000 deg .*\[-19, 85\] deg.*J3 = 0.000 deg <= 0") as info:
        check_joint_limits((0, -20, 0, 0))
    assert info.value.lower_deg == -19


@pytest.mark.parametrize("joints", [(160, 0, 0, 0), (-160, 0, 0, 180), (0, 85, 105, -180), (0, -25, 5, 0),
                                    (0, 45, 105, 0), (0, 0, 60, 0)])
def test_limit_boundaries_are_allowed(joints):
    check_joint_limits(joints)


def test_check_pose_reachable_returns_joints_and_refuses_limits_and_reach():
    assert check_pose_reachable((284, 0, 118, 0)) == pytest.approx([0, 0, 0, 0], abs=1e-9)
    with pytest.raises(LimitError, match="J1 = 170"):
        check_pose_reachable(forward((170, 10, 10, 0)))
    with pytest.raises(UnreachableError, match="out of reach"):
        check_pose_reachable((600, 0, 0, 0))
    with pytest.raises(UnreachableError, match="J1 axis"):
        check_pose_reachable((0, 0, 100, 0))


def test_bad_inputs_and_configs_are_refused():
    with pytest.raises(ValueError, match="4 values"):
        forward([0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        check_joint_limits([0, math.nan, 0, 0])
    with pytest.raises(ValueError, match="j1_deg"):
        MG400Limits(j1_deg=(10.0, -10.0))
    with pytest.raises(ValueError, match="upper_arm_mm"):
        MG400Geometry(upper_arm_mm=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        MG400Geometry().base_x_mm = 1.0  # type: ignore[misc]


def test_custom_limits_are_used():
    tight = MG400Limits(j1_deg=(-10.0, 10.0))
    with pytest.raises(LimitError, match=r"\[-10, 10\]"):
        check_joint_limits((20, 0, 0, 0), tight)
