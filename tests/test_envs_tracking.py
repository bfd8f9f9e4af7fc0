"""SimShearTracking-v0: registry, env checkers, determinism, pickling, spaces, contact error, termination."""

from __future__ import annotations

import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs
from simshear_gym.envs.trajectories import COLIFT_TRAJECTORIES, TRAJECTORIES, Trajectory, TrajectoryConfig
from simshear_gym.robots.mg400.kinematics import MG400Limits
from simshear_gym.sim.mg400_arm import MG400ArmConfig
from simshear_gym.sim.replay import SURFACE_DEPTH_MM

ENV_IDS = simshear_gym.envs.ENV_IDS


def make(obs_mode="sim", **kwargs):
    return gym.make("SimShearTracking-v0", obs_mode=obs_mode, **kwargs)


def test_every_env_id_is_registered_with_a_time_limit():
    steps = {"SimShearEdgeFollow-v0": 1000, "SimShearPush-v0": 800}  # a lap at 5 mm/s: 37-75 s at 10 Hz; a push 60 s
    for env_id in ENV_IDS:
        spec = gym.spec(env_id)
        assert isinstance(spec.entry_point, str) and spec.max_episode_steps == steps.get(env_id, 500)
        assert spec.vector_entry_point is not None


def test_importing_the_package_and_registering_stays_cheap():
    code = ("import sys, simshear_gym, simshear_gym.envs, gymnasium; "
            "assert 'SimShearTracking-v0' in gymnasium.registry; "
            "print(sorted(m for m in ('torch', 'pybullet') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("obs_mode", ["sim", "oracle"])
def test_gymnasium_and_sb3_env_checkers_pass(env_id, obs_mode):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id, obs_mode=obs_mode, render_mode="rgb_array", randomise=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


def rollout(env, seed, steps=40):
    obs, _ = env.reset(seed=seed)
    actions = np.random.default_rng(123).uniform(-0.3, 0.3, (steps, 4)).astype(np.float32)
    trace = [obs["true_pose_shear"].copy(), obs["tactile"].copy()]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        trace += [obs["true_pose_shear"].copy(), obs["tcp_pose"].copy(), reward, info["contact_error_mm"]]
        if terminated or truncated:
            break
    trace.append(obs["tactile"].copy())
    return trace


def traces_equal(a, b):
    return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_same_seed_same_rollout_and_seeds_matter():
    env = make("oracle", trajectory="random", randomise=True)
    first, again, other = rollout(env, 7), rollout(env, 7), rollout(env, 8)
    assert traces_equal(first, again)
    assert not traces_equal(first, other)
    assert traces_equal(first, rollout(make("oracle", trajectory="random", randomise=True), 7))  # fresh env


def test_env_pickles_and_the_copy_behaves_the_same():
    env = make("oracle", trajectory="spiral", randomise=True)
    copy = pickle.loads(pickle.dumps(env))
    assert copy.unwrapped.trajectory_name == "spiral" and copy.spec.max_episode_steps == 500
    assert traces_equal(rollout(env, 3), rollout(copy, 3))


@pytest.mark.parametrize("obs_mode, keys", [("sim", {"tactile", "tcp_pose"}), ("real", {"tactile", "tcp_pose"}),
                                            ("oracle", {"tactile", "tcp_pose", "true_pose_shear"}),
                                            ("oracle_real", {"tactile", "tcp_pose", "true_pose_shear"})])
@pytest.mark.parametrize("size", [128, 64])
def test_observation_spaces(obs_mode, keys, size):
    env = make(obs_mode, image_size_px=size)
    space = env.observation_space
    assert set(space.spaces) == keys
    assert space["tactile"].shape == (1, size, size) and space["tactile"].dtype == np.uint8
    assert space["tcp_pose"].shape == (4,) and space["tcp_pose"].dtype == np.float32
    assert env.action_space.shape == (4,) and env.action_space.low.min() == -1 and env.action_space.high.max() == 1


def test_oracle_observation_at_reset_is_the_reference_contact():
    env = make("oracle")
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(obs["true_pose_shear"], [4.0, 0.0, 0.0, 0.0], atol=1e-5)
    assert info["contact_error_mm"] == pytest.approx(0.0, abs=1e-9)
    assert info["penetration_mm"] == pytest.approx(4.0 - SURFACE_DEPTH_MM)
    assert info["in_contact"] and obs["tactile"].max() > 0  # the plate shows in the image
    # the TCP is reported in the follower's base frame: 310 mm out
    assert obs["tcp_pose"][0] == pytest.approx(310.0, abs=1e-3)


def test_real_images_are_translated_and_64_px_is_the_128_px_image_halved():
    obs_sim, _ = make("sim").reset(seed=0)
    obs_128, _ = make("real").reset(seed=0)
    obs_64, _ = make("real", image_size_px=64).reset(seed=0)
    assert not np.array_equal(obs_128["tactile"], obs_sim["tactile"])
    assert obs_128["tactile"].mean() > 3 * obs_sim["tactile"].mean()  # markers on a grey membrane, not depth
    halved = obs_128["tactile"][0].reshape(64, 2, 64, 2).mean(axis=(1, 3))
    assert np.abs(obs_64["tactile"][0].astype(float) - halved).max() <= 0.5 + 1e-9


@pytest.mark.parametrize("action", [[np.nan, 0, 0, 0], [0, 0, 1.5, 0], [0, 0, 0], [[0, 0, 0, 0]]])
def test_bad_actions_raise_clear_errors(action):
    env = make().unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.array(action, dtype=np.float64))


def test_bad_kwargs_raise_clear_errors():
    with pytest.raises(ValueError, match="obs_mode"):
        make("depth")
    with pytest.raises(ValueError, match="image_size_px"):
        make(image_size_px=96)
    with pytest.raises(ValueError, match="trajectory"):
        make(trajectory="figure8")
    with pytest.raises(ValueError, match="control_rate_hz"):
        make(control_rate_hz=0)


def test_still_follower_error_is_the_plates_travel():
    """The target is the plate centre here (start offset 0), which the plate's rotation does not move: holding
    the sensor still, the contact error is exactly the trajectory's translation so far."""
    env = make("oracle", trajectory="tilted_square")
    env.reset(seed=0)
    trajectory = Trajectory(TrajectoryConfig("tilted_square"))
    for _ in range(20):
        _, _, terminated, _, info = env.step(np.zeros(4, dtype=np.float32))
        assert not terminated
        offset = trajectory.offset_at(info["time_s"])
        assert info["contact_error_mm"] == pytest.approx(np.linalg.norm(offset[:3]), abs=1e-6)


def test_follower_held_at_its_target_has_no_error_and_a_known_offset_gives_that_error():
    env = make("oracle", trajectory="loop").unwrapped
    env.reset(seed=0, options={"start_offset_mm": (8.0, -5.0)})  # off the plate's centre: rotation moves it
    for _ in range(15):
        env.step(np.zeros(4, dtype=np.float32))
        face = env._T_world_face()
        target_world = face[:3, :3] @ env._target_face_mm + face[:3, 3]
        T_world_sensor = env.follower.T_world_tool()
        T_world_sensor[:3, 3] = target_world
        env.follower.reset(env.follower.flange_pose_for_tool(T_world_sensor))
        assert env._measure().contact_error_mm == pytest.approx(0.0, abs=1e-9)
    env.follower.reset(env.follower.pose_mm_deg + np.array([3.0, 4.0, 0.0, 0.0]))  # 5 mm off, in the plane
    assert env._measure().contact_error_mm == pytest.approx(5.0, abs=1e-9)


def test_shear_reports_the_sensor_motion_over_the_plate_in_the_sensor_frame():
    env = make("oracle", speed_mm_s=1e-6).unwrapped  # the plate all but still
    env.reset(seed=0)
    obs = None
    for _ in range(3):
        obs, _, _, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32))  # +1 mm along sensor x
    np.testing.assert_allclose(obs["true_pose_shear"][1:3], [3.0, 0.0], atol=1e-3)
    assert info["contact_error_mm"] == pytest.approx(3.0, abs=1e-3)
    obs, *_ = env.step(np.array([0.0, 0.0, 0.5, 0.0], dtype=np.float32))  # 0.5 mm deeper
    assert obs["true_pose_shear"][0] == pytest.approx(4.5, abs=1e-4)


@pytest.mark.parametrize("dz, reason", [(-1.0, "contact_lost"), (1.0, "too_deep")])
def test_losing_contact_or_pressing_too_deep_terminates(dz, reason):
    env = make()
    env.reset(seed=0)
    for step in range(10):
        _, reward, terminated, truncated, info = env.step(np.array([0, 0, dz, 0], dtype=np.float32))
        if terminated:
            break
    assert terminated and not truncated and info["termination"] == reason
    if reason == "contact_lost":
        assert step == 2  # 1.8 mm deep, lifted 1 mm per step: 1.2 mm above after the third step
        assert not info["in_contact"] and info["steps_out_of_contact"] == 2 and reward < 0


def test_a_refused_arm_target_terminates_the_episode_without_crashing():
    narrow = MG400ArmConfig(limits=MG400Limits(j1_deg=(-1.0, 1.0)))  # 1 deg of J1 is ~5.4 mm at 310 mm
    env = make(arm_config=narrow)
    env.reset(seed=0)
    for _ in range(10):
        _, _, terminated, _, info = env.step(np.array([0, 1.0, 0, 0], dtype=np.float32))
        if terminated:
            break
    assert terminated and info["termination"] == "arm_limit"
    assert "follower refused the target" in info["arm_error"] and "J1" in info["arm_error"]


def test_the_episode_is_truncated_by_the_registered_step_limit():
    env = make("oracle", max_episode_steps=5, speed_mm_s=0.5)
    env.reset(seed=0)
    results = [env.step(np.zeros(4, dtype=np.float32))[2:4] for _ in range(5)]
    assert results[-1] == (False, True) and all(r == (False, False) for r in results[:-1])


def test_render_shows_the_scene_beside_the_tactile_image():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(4, dtype=np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape == (180, 420, 3)
    scene, tactile = frame[:, :240], frame[:, 240:]
    assert scene.std() > 10 and tactile.max() > 0
    # the dome drawn for the scene view is parked again: the tactile render is unchanged
    before = env.unwrapped.tactip.render(env.unwrapped.follower.T_world_tool())
    env.render()
    np.testing.assert_array_equal(env.unwrapped.tactip.render(env.unwrapped.follower.T_world_tool()), before)
    no_render = make()
    no_render.reset(seed=0)
    assert no_render.render() is None


@pytest.mark.parametrize("name", TRAJECTORIES)
def test_trajectories_start_at_zero_and_run_at_constant_speed(name):
    trajectory = Trajectory(TrajectoryConfig(name, speed_mm_s=4.0))
    np.testing.assert_allclose(trajectory.offset_at(0.0), 0.0, atol=1e-12)
    times = np.arange(0.0, trajectory.duration_s, 0.5)
    points = np.array([trajectory.offset_at(t)[:3] for t in times])
    chords = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert chords.max() <= 2.0 + 1e-6 and np.median(chords) > 1.9  # 2 mm per 0.5 s (chords cut corners)
    assert trajectory.duration_s < 50.0  # ends within the 500-step episode at 10 Hz
    np.testing.assert_allclose(trajectory.offset_at(1e6), trajectory.offset_at(trajectory.duration_s))


def test_the_tilted_square_tilts_and_the_spiral_rises():
    square = Trajectory(TrajectoryConfig("tilted_square")).path_mm()
    assert square[:, 2].max() == pytest.approx(40.0 * np.sin(np.radians(30.0)))
    spiral = Trajectory(TrajectoryConfig("spiral")).path_mm()
    assert np.all(np.diff(spiral[:, 2]) > 0)


@pytest.mark.parametrize("name", COLIFT_TRAJECTORIES)
def test_the_held_out_paths_run_and_random_never_draws_them(name):
    """circular_wave and star test a tracking policy on paths it never saw: they run in the env (the oracle tracks
    them to the end), and ``trajectory="random"`` draws only the four training paths."""
    from simshear_gym.control.oracle import OracleController

    env = make("oracle", trajectory=name)
    controller = OracleController.for_env(env)
    obs, info = env.reset(seed=0)
    errors, terminated, truncated = [], False, False
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = env.step(controller(obs))
        errors.append(info["contact_error_mm"])
    assert not terminated and info["trajectory"] == name and np.mean(errors) < 0.1
    drawn = make("oracle", trajectory="random", randomise=True)
    names = set()
    for seed in range(40):
        drawn.reset(seed=seed)
        names.add(drawn.unwrapped.trajectory.config.name)
    assert names == set(TRAJECTORIES)


@pytest.mark.parametrize("name", TRAJECTORIES + COLIFT_TRAJECTORIES)
def test_the_largest_randomised_trajectories_stay_within_both_arms_limits(name):
    """Scale 1.3 and +-15 deg (the randomisation's extremes), with the follower on its target +-10 mm off centre."""
    from simshear_gym.robots.mg400.kinematics import check_pose_reachable

    env = make("oracle", trajectory=name).unwrapped
    env.reset(seed=0)
    for rotation in (15.0, -15.0):
        env.trajectory = Trajectory(TrajectoryConfig(name, scale=1.3, rotation_deg=rotation))
        for time_s in np.linspace(0.0, env.trajectory.duration_s, 120):
            T_world_plate = env._T_world_plate_at(time_s)
            check_pose_reachable(env.leader.flange_pose_for_tool(T_world_plate))
            for x, y in ((10.0, 10.0), (-10.0, -10.0), (10.0, -10.0), (-10.0, 10.0)):
                sensor = env.T_world_sensor_on_face(T_world_plate, x, y, env.reference_depth_mm)
                check_pose_reachable(env.follower.flange_pose_for_tool(sensor))
