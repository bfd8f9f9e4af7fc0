"""SimShearCoLift-v0: registry, env checkers, determinism, pickling, the horizontal mount and its action, the oracle
holding every object, drops, arm limits, trajectories."""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs
from simshear_gym.control.oracle import OracleController
from simshear_gym.envs.colift import (
    COLIFT_TRAJECTORIES,
    OBJECT_NAMES,
    ROTATION_LIMIT_DEG,
    HorizontalTacTipMount,
)
from simshear_gym.envs.trajectories import TRAJECTORIES, Trajectory, TrajectoryConfig
from simshear_gym.robots.mg400.kinematics import MG400Limits
from simshear_gym.sim.mg400_arm import MG400ArmConfig
from simshear_gym.sim.replay import SURFACE_DEPTH_MM

ENV_ID = "SimShearCoLift-v0"


def make(obs_mode="sim", **kwargs):
    return gym.make(ENV_ID, obs_mode=obs_mode, **kwargs)


def test_registered_with_a_time_limit_and_the_batched_vector_env():
    assert ENV_ID in simshear_gym.envs.ENV_IDS
    spec = gym.spec(ENV_ID)
    assert spec.entry_point == "simshear_gym.envs.colift:SimShearCoLiftEnv" and spec.max_episode_steps == 500
    assert spec.vector_entry_point == "simshear_gym.envs.colift:make_colift_vector_env"
    assert COLIFT_TRAJECTORIES == ("circular_wave", "star")
    assert OBJECT_NAMES == ("prism", "egg", "brain", "ducky")
    assert not set(COLIFT_TRAJECTORIES) & set(TRAJECTORIES)  # tracking's choices are unchanged


def test_gymnasium_and_sb3_env_checkers_pass():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make("sim", render_mode="rgb_array", randomise=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


def test_real_mode_resets_and_steps_with_translated_images():
    sim, _ = make("sim").reset(seed=0)
    env = make("real", image_size_px=64)
    obs, _ = env.reset(seed=0)
    assert obs["tactile"].shape == (1, 64, 64) and obs["tactile"].dtype == np.uint8
    assert obs["tactile"].mean() > 3 * sim["tactile"].mean()  # markers on a grey membrane, not depth
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0)
    assert env.observation_space.contains(obs) and not terminated and np.isfinite(reward)


def rollout(env, seed, steps=25):
    obs, _ = env.reset(seed=seed)
    actions = np.random.default_rng(123).uniform(-0.3, 0.3, (steps, 4)).astype(np.float32)
    trace = [obs["true_pose_shear"].copy(), obs["tactile"].copy()]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        trace += [obs["true_pose_shear"].copy(), obs["tcp_pose"].copy(), reward, info["contact_error_mm"],
                  info["sensor_world_mm"].copy(), info["object_slip_mm"]]
        if terminated or truncated:
            break
    trace.append(obs["tactile"].copy())
    return trace


def traces_equal(a, b):
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_same_seed_same_rollout_seeds_matter_and_the_env_pickles():
    env = make("oracle", trajectory="random", object_name="egg", randomise=True)
    first, again, other = rollout(env, 7), rollout(env, 7), rollout(env, 8)
    assert traces_equal(first, again)
    assert not traces_equal(first, other)
    copy = pickle.loads(pickle.dumps(env))
    assert copy.unwrapped.object_name == "egg" and copy.spec.max_episode_steps == 500
    assert traces_equal(first, rollout(copy, 7))


def test_reset_grips_the_object_at_the_reference_depth_with_a_horizontal_sensor():
    env = make("oracle", object_name="brain")
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs["true_pose_shear"], [SURFACE_DEPTH_MM + 3.0, 0.0, 0.0, 0.0], atol=1e-5)
    assert info["contact_error_mm"] == pytest.approx(0.0, abs=1e-9)
    assert info["penetration_mm"] == pytest.approx(3.0)
    assert info["in_contact"] and not info["dropped"] and obs["tactile"].max() > 0
    assert 1.5 < info["contact_depth_mm"] < 3.05  # the soft brain gives part of the squeeze to the plate side
    np.testing.assert_allclose(info["sensor_world_mm"], info["target_world_mm"], atol=1e-9)
    T_world_sensor = env.unwrapped.follower.T_world_tool()
    np.testing.assert_allclose(T_world_sensor[:3, 2], [-1.0, 0.0, 0.0], atol=1e-9)  # facing the leader's plate
    np.testing.assert_allclose(T_world_sensor[:3, 1], [0.0, 0.0, -1.0], atol=1e-9)  # image rows run down
    assert env.unwrapped.follower.T_world_flange()[2, 3] - T_world_sensor[2, 3] == pytest.approx(60.0)


def test_the_action_moves_in_the_sensor_frame_and_turns_about_the_vertical():
    env = make("oracle", speed_mm_s=1e-6).unwrapped  # the leader all but still
    env.reset(seed=0)
    start = env.follower.T_world_tool()
    obs, _, _, _, info = env.step(np.array([1.0, 0.0, 0.5, 0.0], dtype=np.float32))
    moved = env.follower.T_world_tool()
    np.testing.assert_allclose(moved[:3, 3] - start[:3, 3], start[:3, :3] @ [1.0, 0.0, 0.5], atol=1e-9)
    assert obs["true_pose_shear"][0] == pytest.approx(SURFACE_DEPTH_MM + 3.5, abs=1e-4)
    assert obs["true_pose_shear"][1] == pytest.approx(1.0, abs=1e-4)
    assert info["contact_error_mm"] == pytest.approx(np.hypot(1.0, 0.5), abs=1e-4)
    obs, _, _, _, info = env.step(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))  # +2 deg about the vertical
    turned = env.follower.T_world_tool()
    np.testing.assert_allclose(turned[:3, 3], moved[:3, 3], atol=1e-9)  # about the apex
    assert np.degrees(np.arctan2(turned[1, 2], turned[0, 2]) - np.arctan2(moved[1, 2], moved[0, 2])) == \
        pytest.approx(2.0, abs=1e-6)
    assert obs["true_pose_shear"][3] == pytest.approx(2.0, abs=1e-4) and info["yaw_error_deg"] == pytest.approx(2.0)
    assert turned[2, 2] == pytest.approx(0.0, abs=1e-12)  # the sensor stays horizontal


def run_oracle(trajectory, object_name, steps=500, **kwargs):
    env = make("oracle", trajectory=trajectory, object_name=object_name, **kwargs)
    controller = OracleController.for_env(env)
    obs, info = env.reset(seed=0)
    controller.reset()
    errors = []
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(controller(obs))
        errors.append(info["contact_error_mm"])
        if terminated or truncated:
            break
    return np.array(errors), info


@pytest.mark.parametrize("trajectory", COLIFT_TRAJECTORIES)
@pytest.mark.parametrize("object_name", ["prism", "ducky"])
def test_the_oracle_holds_the_object_over_the_first_part_of_the_path(object_name, trajectory):
    errors, info = run_oracle(trajectory, object_name, steps=60)
    assert len(errors) == 60 and info["termination"] == "" and not info["dropped"]
    assert errors.mean() <= 1.0 and info["object_slip_mm"] < 2.0


@pytest.mark.slow
@pytest.mark.parametrize("trajectory", COLIFT_TRAJECTORIES)
@pytest.mark.parametrize("object_name", OBJECT_NAMES)
def test_the_oracle_carries_every_object_along_every_trajectory(object_name, trajectory):
    errors, info = run_oracle(trajectory, object_name, steps=500, max_episode_steps=500)
    assert len(errors) == 500 and info["termination"] == "" and not info["dropped"]
    assert errors.mean() <= 1.0 and info["steps_out_of_contact"] == 0


def run_until_done(env, action, steps=200):
    env.reset(seed=0)
    for step in range(steps):
        _, reward, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
        if terminated or truncated:
            return step, info
    return steps, info


@pytest.mark.parametrize("object_name", ["egg", "brain"])
def test_holding_still_while_the_leader_moves_drops_the_object(object_name):
    step, info = run_until_done(make(trajectory="circular_wave", object_name=object_name), [0, 0, 0, 0])
    assert info["termination"] == "dropped" and info["dropped"] and step < 60


@pytest.mark.slow
@pytest.mark.parametrize("trajectory, object_name", [("circular_wave", "prism"), ("circular_wave", "ducky"),
                                                     ("star", "egg"), ("star", "brain"), ("star", "ducky")])
def test_holding_still_drops_the_object_on_more_paths(trajectory, object_name):
    step, info = run_until_done(make(trajectory=trajectory, object_name=object_name), [0, 0, 0, 0])
    assert info["termination"] == "dropped"


@pytest.mark.parametrize("object_name", OBJECT_NAMES)
def test_withdrawing_the_tip_drops_the_object(object_name):
    step, info = run_until_done(make(object_name=object_name, speed_mm_s=1e-6), [0, 0, -1.0, 0])
    assert info["termination"] == "dropped" and step <= 5  # 3 mm squeeze, 1 mm back per step
    assert not info["in_contact"] and info["contact_depth_mm"] == 0.0


def test_pressing_in_ends_the_episode_too_deep():
    step, info = run_until_done(make(speed_mm_s=1e-6), [0, 0, 1.0, 0])
    assert info["termination"] == "too_deep" and info["contact_depth_mm"] > 10.0 and not info["dropped"]


def test_a_refused_arm_target_terminates_the_episode_without_crashing():
    narrow = MG400ArmConfig(limits=MG400Limits(j1_deg=(-1.0, 1.0)))  # 1 deg of J1 is ~5 mm at 290 mm
    step, info = run_until_done(make(arm_config=narrow, speed_mm_s=1e-6), [1.0, 0, 0, 0], steps=20)
    assert info["termination"] == "arm_limit" and "follower refused the target" in info["arm_error"]


def test_the_leaders_path_and_the_targets_are_in_the_info():
    env = make("oracle", trajectory="star", speed_mm_s=5.0, rotation_deg=10.0)
    env.reset(seed=0)
    trajectory = Trajectory(TrajectoryConfig("star", speed_mm_s=5.0, rotation_deg=10.0))
    start = env.unwrapped._T_world_plate_start[:3, 3].copy()
    for _ in range(10):
        _, _, terminated, _, info = env.step(np.zeros(4, dtype=np.float32))
    plate = env.unwrapped.leader.T_world_tool()[:3, 3]
    np.testing.assert_allclose(plate - start, trajectory.offset_at(info["time_s"])[:3], atol=1e-9)
    assert info["sensor_world_mm"].shape == (3,) and info["target_world_mm"].shape == (3,)
    assert info["contact_error_mm"] == pytest.approx(np.linalg.norm(info["sensor_world_mm"] - info["target_world_mm"]))


def test_render_shows_the_scene_beside_the_tactile_image():
    env = make(render_mode="rgb_array", object_name="ducky")
    env.reset(seed=0)
    env.step(np.zeros(4, dtype=np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape == (180, 420, 3)
    assert frame[:, :240].std() > 10 and frame[:, 240:].max() > 0


def test_bad_kwargs_and_options_raise_clear_errors():
    with pytest.raises(ValueError, match="object_name"):
        make(object_name="teapot")
    with pytest.raises(ValueError, match="trajectory"):
        make(trajectory="circle")
    with pytest.raises(ValueError, match="mass_kg"):
        make(mass_kg=-1.0)
    with pytest.raises(ValueError, match=r"rotation_deg must be within \+-10.0 deg, got 15.0"):
        make(rotation_deg=15.0)
    with pytest.raises(ValueError, match="HorizontalTacTipMount"):
        from simshear_gym.contract import TacTipMount

        make(mount=TacTipMount())
    with pytest.raises(ValueError, match="start_offset_mm"):
        make().reset(seed=0, options={"start_offset_mm": (0.0, 50.0, 0.0)})
    assert HorizontalTacTipMount(drop_mm=40.0).T_flange_sensor()[2, 3] == -40.0


@pytest.mark.parametrize("name", COLIFT_TRAJECTORIES)
def test_colift_trajectories_start_at_zero_run_at_constant_speed_and_close(name):
    trajectory = Trajectory(TrajectoryConfig(name, speed_mm_s=5.0))
    np.testing.assert_allclose(trajectory.offset_at(0.0), 0.0, atol=1e-12)
    times = np.arange(0.0, trajectory.duration_s, 0.5)
    points = np.array([trajectory.offset_at(t)[:3] for t in times])
    chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert chords.max() <= 2.5 + 1e-6 and np.median(chords) > 2.4  # 2.5 mm per 0.5 s (chords cut corners)
    assert trajectory.duration_s < 40.0  # ends within the 500-step episode at 10 Hz
    np.testing.assert_allclose(trajectory.path_mm()[-1], 0.0, atol=1e-9)  # a closed path
    path = trajectory.path_mm()
    if name == "star":
        assert np.allclose(path[:, 0], 0.0) and path[:, 2].max() == pytest.approx(25.0 * (1 + np.sin(np.radians(54))))
    else:
        assert path[:, 2].max() == pytest.approx(8.0, abs=1e-3) and path[:, 0].min() == pytest.approx(-50.0)


@pytest.mark.parametrize("name", COLIFT_TRAJECTORIES)
def test_the_largest_randomised_trajectories_stay_within_both_arms_limits(name):
    """Scale 1.3, +-10 deg and the leader's start +-10 mm (the randomisation's extremes), the follower on target."""
    from simshear_gym.robots.mg400.kinematics import check_pose_reachable

    env = make("oracle", trajectory=name).unwrapped
    for offset in ((10.0, 10.0, 10.0), (-10.0, -10.0, -10.0), (10.0, -10.0, -10.0), (-10.0, 10.0, 10.0)):
        env.reset(seed=0, options={"start_offset_mm": offset})
        T_plate_sensor = np.linalg.inv(env._T_world_plate_start) @ env.follower.T_world_tool()
        for rotation in (ROTATION_LIMIT_DEG, -ROTATION_LIMIT_DEG):
            env.trajectory = Trajectory(TrajectoryConfig(name, scale=1.3, rotation_deg=rotation))
            for time_s in np.linspace(0.0, env.trajectory.duration_s, 60):
                T_world_plate = env._T_world_plate_at(time_s)
                check_pose_reachable(env.leader.flange_pose_for_tool(T_world_plate))
                check_pose_reachable(env.follower.flange_pose_for_tool(T_world_plate @ T_plate_sensor))


def test_make_vec_batches_colift_envs():
    envs = gym.make_vec(ENV_ID, num_envs=2, obs_mode="sim", image_size_px=64, workers=0, object_name="egg")
    obs, infos = envs.reset(seed=0)
    assert obs["tactile"].shape == (2, 1, 64, 64) and infos["object_name"].tolist() == ["egg", "egg"]
    obs, rewards, terminated, truncated, infos = envs.step(np.zeros((2, 4), dtype=np.float32))
    assert rewards.shape == (2,) and infos["sensor_world_mm"].shape == (2, 3)
    envs.close()


def test_the_heavy_payload_grips_firmly_deeper_and_asks_the_servo_to_hold_the_load():
    """payload="heavy": the heavy objects on the firm TacTip, squeezed 4 mm; the weight shows as downward shear in the
    env's info from the first step; the servo holds the load (servo_hints.hold_load) and reads with the heavy GDNN."""
    env = gym.make("SimShearCoLift-v0", obs_mode="oracle", payload="heavy", object_name="egg")
    base = env.unwrapped
    assert base.scene_config.object.mass_kg == 1.5 and base.scene_config.tip_contact_stiffness_npm == 4000.0
    assert base.reference_depth_mm == pytest.approx(SURFACE_DEPTH_MM + 4.0)
    assert base.servo_hints.hold_load and base.servo_hints.posenet == "colift_heavy"
    _, info = env.reset(seed=0)
    assert info["shear_sensor_mm_deg"][1] < -1.0  # sensor +y is down: the load's sag
    light = gym.make("SimShearCoLift-v0", obs_mode="oracle").unwrapped
    assert not light.servo_hints.hold_load and light.servo_hints.posenet == "colift"
    assert light.scene_config.object.mass_kg == 0.03
    with pytest.raises(ValueError, match="payload"):
        gym.make("SimShearCoLift-v0", obs_mode="oracle", payload="medium")
    env.close()
    light.close()
