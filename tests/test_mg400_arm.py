"""Simulated MG400 in servo mode: timing, rate limits, refused targets, tool frames and link bodies."""

from __future__ import annotations

import numpy as np
import pytest

from simshear_gym.robots.mg400.frames import (
    T_base_flange_to_pose,
    joint_points_base_mm,
    pose_to_T_base_flange,
)
from simshear_gym.robots.mg400.kinematics import (
    LimitError,
    MG400Geometry,
    UnreachableError,
    forward,
    inverse,
)
from simshear_gym.sim.mg400_arm import MG400ArmConfig, SimMG400
from simshear_gym.sim.world import World
from simshear_gym.transforms import pose_to_matrix

START = np.array([260.0, 0.0, 0.0, 0.0])


@pytest.fixture()
def world():
    with World() as world:
        yield world


def make_arm(world, config=MG400ArmConfig(), **kwargs):
    return SimMG400(world, np.eye(4), START, config=config, **kwargs)


def test_servo_reaches_the_target_in_the_commanded_time(world):
    arm = make_arm(world, bodies=False)
    target = START + [5.0, -3.0, 2.0, 4.0]
    assert arm.servo_p(target, 0.1) == pytest.approx(0.1)
    arm.advance(0.05)
    np.testing.assert_allclose(arm.pose_mm_deg, (START + target) / 2, atol=1e-12)
    assert arm.moving
    arm.advance(0.05)
    np.testing.assert_allclose(arm.pose_mm_deg, target, atol=1e-12)
    assert not arm.moving
    np.testing.assert_allclose(forward(arm.joints_deg), target, atol=1e-9)  # joints follow the pose


def test_speed_limits_stretch_a_large_step(world):
    arm = make_arm(world, MG400ArmConfig(max_linear_speed_mm_s=50.0, max_angular_speed_deg_s=30.0), bodies=False)
    assert arm.servo_p(START + [20.0, 0, 0, 0], 0.1) == pytest.approx(0.4)  # 20 mm at 50 mm/s
    arm.advance(0.1)
    assert arm.pose_mm_deg[0] == pytest.approx(START[0] + 5.0)  # 50 mm/s, not 200
    assert arm.servo_p(arm.pose_mm_deg + [0, 0, 0, 15.0], 0.1) == pytest.approx(0.5)  # 15 deg at 30 deg/s


def test_a_new_servo_target_replaces_the_old_one(world):
    arm = make_arm(world, bodies=False)
    arm.servo_p(START + [10.0, 0, 0, 0], 1.0)
    arm.advance(0.5)
    arm.servo_p(START + [0, 4.0, 0, 0], 0.1)  # from where it is now
    arm.advance(0.1)
    np.testing.assert_allclose(arm.pose_mm_deg, START + [0, 4.0, 0, 0], atol=1e-12)


def test_r_takes_the_short_way_round(world):
    arm = SimMG400(world, np.eye(4), [260.0, 0.0, 0.0, 170.0], bodies=False)
    arm.servo_p([260.0, 0.0, 0.0, -170.0], 0.2)
    arm.advance(0.1)
    assert arm.pose_mm_deg[3] == pytest.approx(180.0)  # 170 -> 190 (= -170), through 180


@pytest.mark.parametrize("target, error", [((500.0, 0.0, 0.0, 0.0), UnreachableError),
                                           ((-250.0, 10.0, 0.0, 0.0), LimitError),  # J1 ~ 178 deg > 160
                                           ((420.0, 0.0, 100.0, 0.0), LimitError),  # |J3 - J2| > 60
                                           ((180.0, 0.0, 150.0, 0.0), LimitError)])  # J2 < -25
def test_targets_outside_the_limits_are_refused_and_change_nothing(world, target, error):
    arm = make_arm(world, bodies=False)
    arm.servo_p(START + [2.0, 0, 0, 0], 0.1)
    with pytest.raises(error):
        arm.servo_p(target, 0.1)
    np.testing.assert_allclose(arm.target_mm_deg, START + [2.0, 0, 0, 0])  # the old motion goes on
    with pytest.raises(error):
        arm.reset(target)
    np.testing.assert_allclose(arm.pose_mm_deg, START)


def test_a_path_through_a_limit_stops_the_arm(world):
    # both ends have |J1| = 150 deg (allowed); the straight line between them passes J1 = 180 deg
    a = 250.0 * np.array([np.cos(np.radians(150)), np.sin(np.radians(150))])
    arm = SimMG400(world, np.eye(4), [a[0], a[1], 0.0, 150.0], bodies=False)
    arm.servo_p([a[0], -a[1], 0.0, -150.0], 1.0)
    with pytest.raises(LimitError, match="J1"):
        for _ in range(10):
            arm.advance(0.1)
    assert not arm.moving
    assert abs(arm.joints_deg[0]) <= 160.0


def test_servo_duration_must_be_in_the_controller_range(world):
    arm = make_arm(world, bodies=False)
    with pytest.raises(ValueError, match="duration_s"):
        arm.servo_p(START, 0.001)


def test_tool_frame_and_the_level_flange(world):
    T_world_base = pose_to_matrix(np.array([600.0, 10.0, 5.0, 0.0, 0.0, 180.0]))
    T_flange_tool = pose_to_matrix(np.array([0.0, 0.0, -95.0, 180.0, 0.0, 0.0]))
    arm = SimMG400(world, T_world_base, START + [0, 0, 0, 30.0], T_flange_tool, bodies=False)
    expected = T_world_base @ pose_to_T_base_flange(START + [0, 0, 0, 30.0]) @ T_flange_tool
    np.testing.assert_allclose(arm.T_world_tool(), expected, atol=1e-9)
    np.testing.assert_allclose(arm.flange_pose_for_tool(expected), START + [0, 0, 0, 30.0], atol=1e-9)
    # the tool sits 95 mm below the flange (base frame z up), R unchanged
    np.testing.assert_allclose(arm.tool_pose_mm_deg(), START + [0, 0, -95.0, 30.0], atol=1e-9)
    tilted = expected @ pose_to_matrix(np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="level"):
        arm.servo_tool(tilted, 0.1)
    with pytest.raises(ValueError, match="vertical"):
        SimMG400(world, pose_to_matrix(np.array([0.0, 0.0, 0.0, 10.0, 0.0, 0.0])), START)


def test_pose_matrix_round_trip():
    pose = np.array([123.0, -45.0, 67.0, -135.0])
    np.testing.assert_allclose(T_base_flange_to_pose(pose_to_T_base_flange(pose)), pose, atol=1e-12)


@pytest.mark.parametrize("pose", [(260.0, 0.0, 0.0, 0.0), (200.0, 150.0, -80.0, 40.0), (300.0, -50.0, 90.0, -10.0)])
def test_joint_points_end_at_the_flange_with_constant_link_lengths(pose):
    geometry = MG400Geometry()
    points = joint_points_base_mm(inverse(*pose), geometry)
    np.testing.assert_allclose(points["flange"], pose[:3], atol=1e-9)
    assert np.linalg.norm(points["elbow"] - points["shoulder"]) == pytest.approx(geometry.upper_arm_mm)
    assert np.linalg.norm(points["wrist"] - points["elbow"]) == pytest.approx(geometry.forearm_mm)


def test_link_bodies_follow_the_joints(world):
    arm = make_arm(world)
    assert set(arm.body_ids) == {"column", "upper_arm", "forearm", "wrist", "flange"}
    arm.reset([220.0, 60.0, -40.0, 0.0])
    arm.update_bodies()
    points = arm.joint_points_world_mm()
    position_m, _ = world.client.getBasePositionAndOrientation(arm.body_ids["forearm"])
    np.testing.assert_allclose(np.array(position_m) * 1000.0, (points["elbow"] + points["wrist"]) / 2, atol=1e-3)
    assert make_arm(world, bodies=False).body_ids == {}
