"""SimShearPush-v0: the quasi-static pushing model, the env's contract, the push law and pushes to the target."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs  # noqa: F401
from simshear_gym.control.push_servo import PushGains, PushLaw, PushOracleController, PushServoController
from simshear_gym.sim.pushing import PUSH_SHAPES, PushedObject, PushPhysicsConfig, push_shape, torque_arm_mm

ENV_ID = "SimShearPush-v0"


def make(obs_mode="oracle", **kwargs):
    return gym.make(ENV_ID, obs_mode=obs_mode, **kwargs)


def _sensor(apex, axis=(-1.0, 0.0, 0.0)):
    z = np.asarray(axis, dtype=np.float64)
    T = np.eye(4)
    T[:3, 2] = z
    T[:3, 1] = [0.0, 0.0, -1.0]
    T[:3, 0] = np.cross(T[:3, 1], z)
    T[:3, 3] = apex
    return T


def _push(shape: str, offset_mm: float, config: PushPhysicsConfig = PushPhysicsConfig(), steps: int = 100):
    """Push ``steps`` x 0.5 mm along -x on face 0 (normal +x) at ``offset_mm`` along it."""
    obj = PushedObject(push_shape(shape), config, 20.0, 0.0, (0.0, 0.0, 0.0))
    apex = np.array([push_shape(shape).half_width_mm() - 0.3, offset_mm, 20.0])
    obj.place((0.0, 0.0, 0.0), _sensor(apex))
    for _ in range(steps):
        apex = apex + np.array([-0.5, 0.0, 0.0])
        obj.push(_sensor(apex))
    return obj


@pytest.mark.parametrize("shape", PUSH_SHAPES)
def test_a_push_through_the_centre_slides_the_object_straight_at_the_friction_indentation(shape):
    config = PushPhysicsConfig(mass_kg=0.2, table_friction=0.3)
    obj = _push(shape, 0.0, config)
    x, y, yaw = obj.pose
    contact = obj.contact()
    # 50 mm pushed, less the indentation the table's friction needs: f_max / k_n
    indentation = config.friction_limit_n / config.normal_stiffness_n_per_mm
    assert contact.penetration_mm == pytest.approx(indentation, rel=1e-3)
    assert x == pytest.approx(-(50.0 - indentation + 0.3), abs=0.01)
    assert abs(y) < 1e-6 and abs(yaw) < 1e-9
    assert contact.stretch_mm == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_an_off_centre_push_turns_the_object_away_and_stretches_the_skin():
    obj = _push("cube", 8.0)
    _, y, yaw = obj.pose
    assert yaw > math.radians(5.0)  # pushed along -x at +y: turned counter-clockwise
    assert y < -1.0  # and it slides away from the contact's side
    assert abs(obj.contact().stretch_mm[1]) > 0.05
    # a heavier object needs a deeper indentation to move
    light = _push("cube", 0.0, PushPhysicsConfig(mass_kg=0.1), steps=10).contact().penetration_mm
    heavy = _push("cube", 0.0, PushPhysicsConfig(mass_kg=0.3), steps=10).contact().penetration_mm
    assert heavy == pytest.approx(3 * light, rel=1e-3)


def test_the_skin_slips_at_its_friction_limit():
    config = PushPhysicsConfig(mass_kg=5.0, contact_friction=0.5)  # too heavy to move
    obj = PushedObject(push_shape("cube"), config, 20.0, 0.0, (0.0, 0.0, 0.0))
    apex = np.array([25.0 - 1.0, 0.0, 20.0])
    obj.place((0.0, 0.0, 0.0), _sensor(apex))
    for _ in range(20):  # slide 10 mm along the face
        apex = apex + np.array([0.0, 0.5, 0.0])
        obj.push(_sensor(apex))
    contact = obj.contact()
    limit = config.contact_friction * config.normal_stiffness_n_per_mm * contact.penetration_mm
    assert obj.pose == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert np.linalg.norm(contact.stretch_mm) * config.shear_stiffness_n_per_mm == pytest.approx(limit, rel=1e-6)
    assert obj.slipping


def test_the_limit_surface_arm_is_the_mean_distance_of_the_footprint():
    assert torque_arm_mm(push_shape("cylinder"), (0.0, 0.0), samples=200) == pytest.approx(2 * 25.0 / 3, rel=0.01)
    assert torque_arm_mm(push_shape("cube"), (0.0, 0.0), samples=200) == pytest.approx(0.3826 * 50.0, rel=0.01)
    with pytest.raises(ValueError, match="mass_kg"):
        PushPhysicsConfig(mass_kg=0.0)
    with pytest.raises(ValueError, match="shape"):
        push_shape("sphere")


def test_the_env_passes_gymnasiums_and_sb3s_checkers():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make("sim", shape="random", randomise=True)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False, skip_render_check=True)
    assert env.spec.max_episode_steps == 800


def test_bad_arguments_and_options_are_refused_by_name():
    with pytest.raises(ValueError, match="shape"):
        make(shape="sphere")
    with pytest.raises(ValueError, match="path_angle_deg"):
        make(path_angle_deg=45.0)
    with pytest.raises(ValueError, match="HorizontalTacTipMount"):
        from simshear_gym.contract import TacTipMount

        make(mount=TacTipMount())
    env = make()
    with pytest.raises(ValueError, match="contact_offset_mm"):
        env.reset(seed=0, options={"contact_offset_mm": float("nan")})
    with pytest.raises(ValueError, match="path_length_mm"):
        env.reset(seed=0, options={"path_length_mm": 500.0})


@pytest.mark.parametrize("shape", PUSH_SHAPES)
def test_reset_touches_the_face_at_the_reference_depth_and_observes_the_goal(shape):
    env = make(shape=shape)
    offset = 0.0 if shape == "cylinder" else 3.0  # off the middle of the cylinder, its face is turned
    obs, info = env.reset(seed=0, options={"contact_offset_mm": offset, "path_angle_deg": 20.0})
    depth, shear_x, face_yaw, bearing = obs["true_pose_shear"]
    assert depth == pytest.approx(2.6, abs=0.02) and shear_x == 0.0 and abs(face_yaw) < 0.5
    assert bearing == pytest.approx(20.0, abs=1e-3)  # the path, 20 deg towards the sensor's +x
    assert info["in_contact"] and info["target_distance_mm"] == pytest.approx(150.0, abs=1e-6)
    target_x, target_z, direction_x, direction_z = obs["goal"]
    assert direction_x == pytest.approx(math.sin(math.radians(20.0)), abs=1e-6)
    assert direction_z == pytest.approx(math.cos(math.radians(20.0)), abs=1e-6)
    assert env.observation_space.contains(obs)


def test_the_push_law_pushes_on_and_squares_up_to_the_face():
    law = PushLaw(np.array([1.0, 1.0, 1.0, 2.0]), 0.5, PushGains(ki_side=0.0))
    straight = np.array([0.0, 150.0, 0.0, 1.0])  # the target straight ahead
    np.testing.assert_allclose(law(np.array([2.6, 0.0, 0.0]), straight), [0.0, 0.0, 0.5, 0.0], atol=1e-6)
    # the face turned 1 deg: turn with it; the path to +x: move to -x (turns the push towards +x)
    action = law(np.array([2.6, 0.0, 1.0]), np.array([20.0, 150.0, 0.0, 1.0]))
    assert action[0] < 0.0 and action[3] == pytest.approx(0.5)
    # with shear, the centre of pressure lies to one side: the law aims from there
    with_shear = law(np.array([2.6, 0.1, 0.0]), straight)
    without = PushLaw(np.array([1.0, 1.0, 1.0, 2.0]), 0.5, PushGains(ki_side=0.0), use_shear=False)
    assert with_shear[0] != 0.0 and without(np.array([2.6, 0.1, 0.0]), straight)[0] == 0.0
    with pytest.raises(ValueError, match="goal"):
        law(np.array([2.6, 0.0, 0.0]), np.array([1.0, 2.0]))


def test_the_oracle_pushes_the_cube_to_the_target():
    env = make("oracle", shape="cube", path_angle_deg=15.0)
    controller = PushOracleController.for_env(env)
    obs, info = env.reset(seed=0)
    controller.reset()
    deviations = []
    while True:
        obs, reward, terminated, truncated, info = env.step(controller(obs))
        deviations.append(info["path_deviation_mm"])
        if terminated or truncated:
            break
    assert info["termination"] == "target" and info["target_distance_mm"] < 10.0
    assert np.mean(deviations) < 5.0 and reward > 0.0  # reaching the target is no early end


def test_the_push_servo_reads_translated_images_and_reaches_the_target():
    env = make("real", shape="cube", path_angle_deg=-10.0)
    controller = PushServoController.for_env(env)
    obs, info = env.reset(seed=0)
    controller.reset()
    while True:
        obs, _, terminated, truncated, info = env.step(controller(obs))
        if terminated or truncated:
            break
    assert info["termination"] == "target" and info["target_distance_mm"] < 10.0
    assert controller.last_estimate[0].shape == (3,)


def test_losing_the_object_ends_the_episode_with_a_penalty():
    env = make("oracle")
    env.reset(seed=0)
    for _ in range(20):
        _, reward, terminated, _, info = env.step(np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32))
        if terminated:
            break
    assert terminated and info["termination"] == "contact_lost" and reward < -5


def test_randomised_resets_draw_from_the_seed_and_the_env_pickles():
    env = make("oracle", shape="random", randomise=True)
    first = [env.reset(seed=seed)[1] for seed in (1, 2, 1)]
    assert first[0]["mass_kg"] == first[2]["mass_kg"] and first[0]["mass_kg"] != first[1]["mass_kg"]
    assert 0.05 <= first[1]["mass_kg"] <= 0.3
    copy = pickle.loads(pickle.dumps(env.unwrapped))
    a = env.unwrapped
    obs_a, _ = a.reset(seed=5)
    obs_b, _ = copy.reset(seed=5)
    np.testing.assert_allclose(obs_a["goal"], obs_b["goal"])
    for _ in range(3):
        action = np.array([0.1, 0.0, 0.5, 0.1], dtype=np.float32)
        obs_a, *_ = a.step(action)
        obs_b, *_ = copy.step(action)
    np.testing.assert_allclose(obs_a["true_pose_shear"], obs_b["true_pose_shear"])


def test_the_push_estimate_fills_the_policies_four_slots_and_comes_back():
    from simshear_gym.contract import estimate_features, filter_mean_from_estimate
    from simshear_gym.control.push_servo import push_estimate_slots, push_state_from_slots

    mean6 = np.array([3.1, 0.8, -0.4, 1.0, 2.0, -6.5])  # depth, shear x, y, Rz, Rx, Ry (the face's yaw)
    std6 = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    mean, std = push_estimate_slots(mean6, std6)
    np.testing.assert_allclose(mean, [3.1, 0.8, -0.4, -6.5])
    np.testing.assert_allclose(std, [0.1, 0.2, 0.3, 0.6])
    features = estimate_features((mean, std), (mean, std), 2.6)
    np.testing.assert_allclose(push_state_from_slots(filter_mean_from_estimate(features, 2.6)), [3.1, 0.8, -6.5],
                               atol=1e-5)
    with pytest.raises(ValueError, match="mean \\(6,\\), std \\(6,\\)"):
        push_estimate_slots(mean6[:4], std6[:4])


def test_a_push_policy_run_clones_the_push_law_from_its_estimate_and_goal(tmp_path):
    """``simshear train rl --task push``: the pushing env's estimate observation (the push estimator's) and goal,
    the teacher the push law without its integral, evaluation on the three shapes."""
    from simshear_gym.contract import filter_mean_from_estimate
    from simshear_gym.control.push_servo import push_state_from_slots
    from simshear_gym.train.rl import RLTrainConfig, train
    from simshear_gym.train.rl_imitation import PushTeacher, teacher_for
    from simshear_gym.train.rl_trainer import evaluation_settings, make_env

    config = RLTrainConfig(task="push", observation="estimate", history=2, image_size_px=64, timesteps=32,
                           n_steps=16, batch_size=16, n_epochs=1, checkpoint_steps=32, bc_steps=32, bc_epochs=2,
                           eval_steps=32, eval_max_steps=5)
    assert set(evaluation_settings(config)) == set(PUSH_SHAPES)
    env = make_env(config)
    teacher = teacher_for(env)
    assert isinstance(teacher, PushTeacher)
    base = env.unwrapped
    law = PushLaw(base.action_scale.as_array(), base.speed_mm_s * base.dt_s, PushGains(ki_side=0.0))
    observation, _ = env.reset(seed=2)
    assert set(observation) == {"estimate", "goal"} and observation["estimate"].shape == (32,)
    for _ in range(3):
        action = teacher(observation)
        state = push_state_from_slots(filter_mean_from_estimate(observation["estimate"], base.reference_depth_mm))
        np.testing.assert_allclose(action, law(state, observation["goal"]), atol=1e-6)
        assert action[2] > 0  # pushes on
        observation, *_ = env.step(action)
    env.close()
    summary = train(config, tmp_path / "push", progress=False)
    assert summary["task"] == "push" and summary["imitation"]["steps"] == 32
    assert set(summary["last_evaluation"]["episodes"]) == set(PUSH_SHAPES)
    assert (tmp_path / "push" / "model.pt").is_file()


def test_evaluate_push_runs_a_policy_in_the_settings_it_was_trained_on(tmp_path, capsys):
    from simshear_gym.cli import main
    from simshear_gym.train.rl import RLTrainConfig, train

    train(RLTrainConfig(task="push", observation="estimate", history=2, image_size_px=64, timesteps=16, n_steps=16,
                        batch_size=16, n_epochs=1, checkpoint_steps=16), tmp_path / "run", progress=False)
    assert main(["evaluate", "push", "--variants", "ppo", "--episodes", "1", "--out", str(tmp_path)]) == 2
    assert "--variants ppo needs --policy" in capsys.readouterr().err
    assert main(["evaluate", "push", "--variants", "ppo", "--policy", str(tmp_path / "run" / "model.zip"),
                 "--episodes", "1", "--figure-episodes", "1", "--out", str(tmp_path), "--name", "p"]) == 0
    import json

    record = json.loads((tmp_path / "p.json").read_text())
    assert record["results"]["ppo"]["episodes"] == 1 and "--policy" in record["command"]
