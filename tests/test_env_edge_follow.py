"""SimShearEdgeFollow-v0: the outlines, the edge labels' conventions, the edge servo law and laps round the edge."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs  # noqa: F401
from simshear_gym.control.edge_servo import EdgeGains, EdgeLaw, EdgeOracleController, EdgeServoController
from simshear_gym.sim.contours import OUTLINES, Contour, ContourObject

ENV_ID = "SimShearEdgeFollow-v0"


def make(obs_mode="oracle", **kwargs):
    return gym.make(ENV_ID, obs_mode=obs_mode, **kwargs)


def test_outlines_are_sampled_within_their_sag_and_measure_their_perimeter():
    disk = Contour(ContourObject("disk", 40.0))
    assert disk.perimeter_mm == pytest.approx(2 * math.pi * 40.0, rel=1e-4)
    for outline in OUTLINES:
        contour = Contour(ContourObject(outline, 40.0, max_sag_mm=0.01))
        assert np.hypot(*contour.points_mm.T).min() > 0.8 * 40.0 - 1e-9
        dense = Contour(ContourObject(outline, 40.0, max_sag_mm=1e-4))  # points of the true curve
        for point in dense.points_mm[::7]:
            assert abs(contour.nearest(point)[1]) <= 0.01 + 1e-6


@pytest.mark.parametrize("outline", OUTLINES)
def test_nearest_gives_the_signed_distance_and_point_at_inverts_it(outline):
    contour = Contour(ContourObject(outline, 40.0))
    for arc in np.linspace(0.0, contour.perimeter_mm, 13)[:-1]:
        point, tangent = contour.point_at(arc)
        inward = np.array([-tangent[1], tangent[0]])  # left of the ccw tangent: the material
        for offset in (-3.0, 0.0, 2.0):
            found_arc, signed, foot, _ = contour.nearest(point + offset * inward)
            assert signed == pytest.approx(offset, abs=0.05)
            assert np.hypot(*(foot - point)) < 0.3
            assert min(abs(found_arc - arc), contour.perimeter_mm - abs(found_arc - arc)) < 0.3


def test_bad_outlines_and_arguments_are_refused_by_name():
    with pytest.raises(ValueError, match="outline"):
        ContourObject("star")
    with pytest.raises(ValueError, match="size_mm"):
        ContourObject("disk", 5.0)
    with pytest.raises(ValueError, match="outline"):
        make(outline="hexagon")
    with pytest.raises(ValueError, match="speed_mm_s"):
        make(speed_mm_s=0.0)
    env = make()
    with pytest.raises(ValueError, match="start_offset_mm"):
        env.reset(seed=0, options={"start_offset_mm": 5.0})
    with pytest.raises(ValueError, match="start_arc_mm"):
        env.reset(seed=0, options={"start_arc_mm": float("nan")})


def test_reset_puts_the_sensor_on_the_edge_at_the_asked_offset_depth_and_angle():
    env = make()
    obs, info = env.reset(seed=0, options={"start_offset_mm": 1.5, "start_angle_deg": 40.0, "start_arc_mm": 30.0})
    offset, depth, along, angle = obs["true_pose_shear"]
    assert offset == pytest.approx(1.5, abs=1e-3) and info["edge_offset_mm"] == pytest.approx(1.5, abs=1e-3)
    assert depth == pytest.approx(4.0, abs=1e-6) and along == 0.0
    assert angle == pytest.approx(40.0, abs=0.05)
    assert info["in_contact"] and info["contact_error_mm"] == pytest.approx(1.5, abs=1e-3)
    assert info["perimeter_mm"] == pytest.approx(2 * math.pi * 40.0, rel=1e-4)
    # out over the air, the dome still touches the material while it is within its footprint
    _, info = env.reset(seed=0, options={"start_offset_mm": -3.0})
    assert info["in_contact"] and info["edge_offset_mm"] == pytest.approx(-3.0, abs=1e-3)


def test_the_env_renders_what_the_edge_labels_render_at_the_same_label_pose():
    """The images the shipped edge models read come from the same conventions as the data's: the sim image at a
    state equals the replay of the straight-edge stimulus at the state's label pose, but for the bend."""
    from simshear_gym.sim.replay import ReplayScene

    env = make("sim", outline="disk")
    with ReplayScene("edge") as scene:
        for offset, angle in ((0.0, 0.0), (1.5, 60.0), (-2.0, -120.0)):
            obs, _ = env.reset(seed=0, options={"start_offset_mm": offset, "start_angle_deg": angle})
            label = env.unwrapped._state.pose_work
            replayed = scene.render(label) > 0
            ours = obs["tactile"][0] > 0
            assert (ours & replayed).sum() / (ours | replayed).sum() > 0.9


def test_edge_law_moves_along_the_edge_in_the_sensor_frame_and_back_onto_it():
    law = EdgeLaw(4.0, np.array([1.0, 1.0, 1.0, 2.0]), 0.5, EdgeGains(ki_offset=0.0, ki_depth=0.0))
    np.testing.assert_allclose(law(np.array([0.0, 4.0, 0.0])), [0.5, 0.0, 0.0, 0.0], atol=1e-6)
    # turned 90 deg against the edge: the edge runs along the sensor's -y
    np.testing.assert_allclose(law(np.array([0.0, 4.0, 90.0])), [0.0, -0.5, 0.0, 0.0], atol=1e-6)
    # 1 mm over the material: move back across the edge (edge frame -y = sensor -y when unturned); too deep: lift
    np.testing.assert_allclose(law(np.array([1.0, 4.4, 0.0])), [0.5, -0.5, -0.2, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="full"):
        EdgeLaw(4.0, np.array([1.0, 1.0, 1.0, 2.0]), 1.5)


@pytest.mark.parametrize("outline", OUTLINES)
def test_the_oracle_goes_once_round_every_outline(outline):
    env = make("oracle", outline=outline)
    controller = EdgeOracleController.for_env(env)
    obs, info = env.reset(seed=0)
    controller.reset()
    offsets, rewards = [], []
    for _ in range(900):
        obs, reward, terminated, truncated, info = env.step(controller(obs))
        offsets.append(abs(info["edge_offset_mm"]))
        rewards.append(reward)
        if terminated or truncated:
            break
    assert info["termination"] == "lap" and terminated
    assert info["progress_mm"] >= info["perimeter_mm"]
    assert max(offsets) < 0.1
    assert min(rewards) > 1.5  # progress at speed, centred, at depth; the lap is no early end


def test_the_edge_servo_goes_round_the_disk_on_translated_images():
    env = make("real", outline="disk")
    controller = EdgeServoController.for_env(env)
    obs, info = env.reset(seed=0)
    controller.reset()
    offsets, depth_errors = [], []
    while True:
        obs, _, terminated, truncated, info = env.step(controller(obs))
        offsets.append(abs(info["edge_offset_mm"]))
        depth_errors.append(abs(info["depth_mm"] - 4.0))
        if terminated or truncated:
            break
    assert info["termination"] == "lap"
    assert np.mean(offsets) < 0.5 and np.mean(depth_errors) < 0.3
    assert controller.last_estimate[0].shape == (3,)


def test_leaving_the_edge_ends_the_episode_with_a_penalty():
    env = make("oracle")
    env.reset(seed=0)
    for _ in range(20):
        _, reward, terminated, _, info = env.step(np.array([0.0, 1.0, 0.0, 0.0], dtype=np.float32))
        if terminated:
            break
    assert terminated and info["termination"] in ("edge_lost", "contact_lost") and reward < -5


def test_randomised_resets_draw_size_start_and_turn_from_the_seed_and_the_env_pickles():
    env = make("oracle", outline="random", randomise=True)
    first = [env.reset(seed=seed)[1] for seed in (1, 2, 1)]
    assert first[0]["perimeter_mm"] == first[2]["perimeter_mm"]
    assert first[0]["edge_offset_mm"] == first[2]["edge_offset_mm"]
    assert (first[0]["outline"], first[0]["edge_offset_mm"]) != (first[1]["outline"], first[1]["edge_offset_mm"])
    copy = pickle.loads(pickle.dumps(env))
    assert copy.reset(seed=1)[1]["edge_offset_mm"] == first[0]["edge_offset_mm"]


def test_make_vec_translates_the_sub_envs_images_in_a_batch():
    envs = gym.make_vec(ENV_ID, num_envs=2, obs_mode="real", workers=1)
    try:
        obs, info = envs.reset(seed=0)
        assert obs["tactile"].shape == (2, 1, 128, 128) and obs["tactile"].mean() > 20  # markers, not depth
        obs, _, _, _, info = envs.step(np.zeros((2, 4), dtype=np.float32))
        assert np.all(info["in_contact"]) and set(info["outline"]) == {"disk"}
    finally:
        envs.close()


def test_the_edge_estimate_fills_the_policies_four_slots_and_comes_back():
    from simshear_gym.contract import estimate_features, filter_mean_from_estimate
    from simshear_gym.control.edge_servo import edge_estimate_slots, edge_state_from_slots

    mean, std = edge_estimate_slots(np.array([1.25, 4.3, 150.0]), np.array([0.4, 0.1, 6.0]))
    np.testing.assert_allclose(mean[:2], [4.3, 1.5])  # depth, then the offset from the edge line (y + 0.25)
    features = estimate_features((mean, std), (mean, std), 4.0)
    np.testing.assert_allclose(features[2:4], [np.cos(np.radians(150)), np.sin(np.radians(150))], atol=1e-6)
    state = edge_state_from_slots(filter_mean_from_estimate(features, 4.0))
    np.testing.assert_allclose(state, [1.5, 4.3, 150.0], atol=1e-4)


def test_an_edge_policy_run_clones_the_edge_law_from_its_estimate_observation(tmp_path):
    """``simshear train rl --task edge``: the edge env's estimate observation (the edge estimator's), the teacher
    the edge law on its filter mean, evaluation on the four outlines."""
    from simshear_gym.contract import filter_mean_from_estimate
    from simshear_gym.control.edge_servo import EdgeGains, EdgeLaw, edge_state_from_slots
    from simshear_gym.train.rl import RLTrainConfig, train
    from simshear_gym.train.rl_imitation import EdgeTeacher, teacher_for
    from simshear_gym.train.rl_trainer import evaluation_settings, make_env

    config = RLTrainConfig(task="edge", observation="estimate", history=2, image_size_px=64, timesteps=32,
                           n_steps=16, batch_size=16, n_epochs=1, checkpoint_steps=32, bc_steps=32, bc_epochs=2)
    assert set(evaluation_settings(config)) == set(OUTLINES)
    env = make_env(config)
    teacher = teacher_for(env)
    assert isinstance(teacher, EdgeTeacher)
    law = EdgeLaw(4.0, env.unwrapped.action_scale.as_array(), 0.5, EdgeGains(ki_offset=0.0, ki_depth=0.0))
    observation, _ = env.reset(seed=2)
    for _ in range(3):
        action = teacher(observation)
        expected = law(edge_state_from_slots(filter_mean_from_estimate(observation["estimate"], 4.0)))
        np.testing.assert_allclose(action, expected, atol=1e-6)
        observation, *_ = env.step(action)
    env.close()
    summary = train(config, tmp_path / "edge", progress=False)
    assert summary["task"] == "edge" and summary["imitation"]["steps"] == 32
    assert (tmp_path / "edge" / "model.pt").is_file()
