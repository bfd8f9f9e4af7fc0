"""SimShearTracking6D-v0, the simulated Panda and the 6-DoF servo: registry, env checkers, determinism, pickling,
spaces, tilt moves, IK within limits and clear refusals, and the controller holding contact."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs  # noqa: F401  (registers the envs)
from simshear_gym.contract import ActionScale, action_to_move_6d
from simshear_gym.envs.tracking6d import PANDA_T_WORLD_BASE, tilt_matrix
from simshear_gym.robots.mg400.kinematics import KinematicsError, LimitError, UnreachableError
from simshear_gym.sim.arm import Arm
from simshear_gym.sim.mg400_arm import SimMG400
from simshear_gym.sim.panda_arm import SimPanda
from simshear_gym.sim.world import World
from simshear_gym.transforms import pose_to_matrix

ENV_ID = "SimShearTracking6D-v0"
START_T_WORLD_SENSOR = pose_to_matrix(np.array([380.0, 0.0, -61.8, 180.0, 0.0, 180.0]))  # the env's start contact
T_FLANGE_SENSOR = pose_to_matrix(np.array([0.0, 0.0, 95.0, 0.0, 0.0, -45.0]))


def make(obs_mode="sim", **kwargs):
    return gym.make(ENV_ID, obs_mode=obs_mode, **kwargs)


@pytest.fixture(scope="module")
def panda():
    world = World()
    arm = SimPanda(world, PANDA_T_WORLD_BASE, START_T_WORLD_SENSOR, T_FLANGE_SENSOR, bodies=True)
    yield arm
    arm.close()
    world.close()


# ---------------------------------------------------------------------------------------------------- the arm
def test_both_arms_implement_the_arm_interface(panda):
    world = World()
    mg400 = SimMG400(world, np.eye(4), np.array([310.0, 0.0, -40.0, 0.0]), bodies=False)
    assert isinstance(panda, Arm) and isinstance(mg400, Arm)
    assert (panda.tool_dof, mg400.tool_dof) == (6, 4)
    target = mg400.T_world_tool() @ pose_to_matrix(np.array([5.0, -3.0, 2.0, 0.0, 0.0, 10.0]))
    mg400.reset_tool(target)
    np.testing.assert_allclose(mg400.T_world_tool(), target, atol=1e-9)
    world.close()


@pytest.mark.parametrize("seed", range(3))
def test_panda_ik_reaches_tilted_poses_within_its_joint_limits(panda, seed):
    rng = np.random.default_rng(seed)
    for _ in range(5):
        move = np.concatenate([rng.uniform(-80.0, 80.0, 3), rng.uniform(-30.0, 30.0, 3)])
        target = START_T_WORLD_SENSOR @ pose_to_matrix(move)
        panda.reset_tool(target)
        reached = panda.T_world_tool()
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 0.02  # mm
        assert np.abs(reached[:3, :3] - target[:3, :3]).max() < 1e-3
        joints = panda.joints_deg
        assert np.all(joints >= panda.lower_deg) and np.all(joints <= panda.upper_deg)


def test_panda_servo_moves_along_and_on_to_the_target(panda):
    panda.reset_tool(START_T_WORLD_SENSOR)
    target = START_T_WORLD_SENSOR @ pose_to_matrix(np.array([2.0, 1.0, -1.0, 3.0, -2.0, 5.0]))
    assert panda.servo_tool(target, 0.1) == pytest.approx(0.1)
    panda.advance(0.05)
    halfway = panda.T_world_tool()[:3, 3]
    np.testing.assert_allclose(halfway, (START_T_WORLD_SENSOR[:3, 3] + target[:3, 3]) / 2.0, atol=0.02)
    panda.advance(0.05)
    assert not panda.moving
    np.testing.assert_allclose(panda.T_world_tool(), target, atol=0.02)
    far = panda.T_world_tool() @ pose_to_matrix(np.array([50.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert panda.servo_tool(far, 0.1) == pytest.approx(0.5)  # 50 mm at 100 mm/s


def test_panda_refuses_out_of_reach_and_out_of_limit_targets_clearly(panda):
    panda.reset_tool(START_T_WORLD_SENSOR)
    before = panda.joints_deg
    with pytest.raises(UnreachableError, match=r"cannot reach the tool target at \[0.0, 0.0, 1500.0\] mm"):
        panda.servo_tool(pose_to_matrix(np.array([0.0, 0.0, 1500.0, 180.0, 0.0, 0.0])), 0.1)
    # the same place with the sensor turned 150 deg about its axis: joint 7 (45 deg now) would leave its range
    with pytest.raises(LimitError, match="panda_joint7 = 19.* deg is outside the allowed range"):
        panda.servo_tool(START_T_WORLD_SENSOR @ pose_to_matrix(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 150.0])), 0.1)
    assert issubclass(UnreachableError, KinematicsError) and issubclass(LimitError, ValueError)
    np.testing.assert_array_equal(panda.joints_deg, before)
    assert not panda.moving
    with pytest.raises(ValueError, match="duration_s"):
        panda.servo_tool(START_T_WORLD_SENSOR, 0.0)


def test_action_to_move_6d_scales_and_validates():
    move = action_to_move_6d([1.0, -1.0, 0.5, 1.0, 0.5, -1.0], ActionScale(), tilt_step_deg=1.0)
    np.testing.assert_allclose(move, [1.0, -1.0, 0.5, 2.0, 0.5, -1.0])
    for bad in ([0.0] * 4, [0.0] * 5 + [1.5], [0.0] * 5 + [np.nan]):
        with pytest.raises(ValueError, match="action"):
            action_to_move_6d(bad, ActionScale())


# ---------------------------------------------------------------------------------------------------- the env
def test_registered_with_a_time_limit():
    spec = gym.spec(ENV_ID)
    assert spec.entry_point == "simshear_gym.envs.tracking6d:SimShearTracking6DEnv" and spec.max_episode_steps == 500


@pytest.mark.parametrize("obs_mode, follower", [("sim", "panda"), ("oracle", "panda"), ("sim", "mg400")])
def test_gymnasium_and_sb3_env_checkers_pass(obs_mode, follower):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make(obs_mode, follower=follower, render_mode="rgb_array", randomise=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


def rollout(env, seed, steps=30):
    obs, _ = env.reset(seed=seed)
    actions = np.random.default_rng(5).uniform(-0.3, 0.3, (steps, 6)).astype(np.float32)
    trace = [obs["true_pose_shear"].copy(), obs["tactile"].copy()]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        trace += [obs["true_pose_shear"].copy(), obs["tcp_pose"].copy(), reward, info["normal_error_deg"]]
        if terminated or truncated:
            break
    trace.append(obs["tactile"].copy())
    return trace


def traces_equal(a, b):
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_same_seed_same_rollout_seeds_matter_and_pickled_copies_agree():
    env = make("oracle", trajectory="random", randomise=True)
    first, again, other = rollout(env, 7), rollout(env, 7), rollout(env, 8)
    assert traces_equal(first, again) and not traces_equal(first, other)
    copy = pickle.loads(pickle.dumps(env))
    assert copy.unwrapped.follower_name == "panda" and copy.spec.max_episode_steps == 500
    assert traces_equal(first, rollout(copy, 7))


@pytest.mark.parametrize("follower, action_shape", [("panda", (6,)), ("mg400", (4,))])
def test_spaces_are_the_tracking_envs_and_the_action_adds_the_tilts(follower, action_shape):
    env = make("oracle", follower=follower, image_size_px=64)
    tracking = gym.make("SimShearTracking-v0", obs_mode="oracle", image_size_px=64)
    assert env.observation_space == tracking.observation_space
    assert env.action_space.shape == action_shape and env.action_space.dtype == np.float32
    assert env.action_space.low.min() == -1 and env.action_space.high.max() == 1


def test_reset_is_the_reference_contact_normal_to_the_plate():
    obs, info = make("oracle").reset(seed=0)
    np.testing.assert_allclose(obs["true_pose_shear"], [4.0, 0.0, 0.0, 0.0], atol=1e-3)
    assert info["contact_error_mm"] < 1e-3 and info["normal_error_deg"] < 0.05 and info["in_contact"]
    assert obs["tactile"].max() > 0


def test_tilt_action_turns_the_sensor_about_its_axes():
    env = make("oracle", tilt_deg=0.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0, 0, 0, 0, 1.0, 0], np.float32))
    np.testing.assert_allclose(info["sensor_tilt_deg"], [1.0, 0.0], atol=0.02)
    assert info["normal_error_deg"] == pytest.approx(1.0, abs=0.02)
    _, _, _, _, info = env.step(np.array([0, 0, 0, 0, -1.0, 0.5], np.float32))
    np.testing.assert_allclose(info["sensor_tilt_deg"], [0.0, 0.5], atol=0.02)


def test_still_follower_normal_error_is_the_plates_tilt():
    env = make("oracle", trajectory="circle")
    env.reset(seed=0)
    largest = 0.0
    for _ in range(15):
        _, _, terminated, _, info = env.step(np.zeros(6, np.float32))
        assert not terminated
        rx, ry = info["plate_tilt_deg"]
        tilt = np.degrees(np.arccos(tilt_matrix(rx, ry)[2, 2]))
        assert info["normal_error_deg"] == pytest.approx(tilt, abs=0.05)
        largest = max(largest, tilt)
    assert largest > 5.0  # the plate does tilt: about 0.6 deg per step about y


def test_bad_kwargs_and_actions_raise_clear_errors():
    with pytest.raises(ValueError, match="follower"):
        make(follower="ur5")
    with pytest.raises(ValueError, match="tilt_deg"):
        make(tilt_deg=30.0)
    with pytest.raises(ValueError, match="trajectory"):
        make(trajectory="figure8")
    env = make().unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(4, np.float32))


# ---------------------------------------------------------------------------------------------- the controller
@pytest.mark.slow
def test_servo6d_keeps_contact_and_the_sensor_normal_on_a_short_episode():
    from simshear_gym.control.servo6d import Servo6DController

    env = make("real", trajectory="tilted_square")
    controller = Servo6DController.for_env(env)
    obs, _ = env.reset(seed=0)
    controller.reset()
    normal = []
    for _ in range(60):
        obs, _, terminated, _, info = env.step(controller(obs))
        assert not terminated and info["in_contact"], info["termination"]
        assert info["contact_error_mm"] < 1.5
        normal.append(info["normal_error_deg"])
    assert np.mean(normal) < 3.0 and max(abs(np.asarray(info["plate_tilt_deg"]))) > 5.0
    assert controller.last_estimate[0].shape == (6,)


def test_servo6d_refuses_a_4dof_env():
    from simshear_gym.control.servo6d import Servo6DController

    with pytest.raises(ValueError, match="6-D action space"):
        Servo6DController.for_env(make(follower="mg400"))
