"""Vector envs: make_vec with the batched entry point (in-process and worker processes), sync and async."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import simshear_gym.envs  # noqa: F401
from simshear_gym.envs.vector import SimShearVectorEnv

LIFT = np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32)  # loses contact on the third step


def rollout(envs, steps, seed=0):
    obs, _ = envs.reset(seed=seed)
    trace = [obs["tactile"].copy(), obs["true_pose_shear"].copy()]
    actions = np.random.default_rng(5).uniform(-0.5, 0.5, (steps, envs.num_envs, 4)).astype(np.float32)
    for action in actions:
        obs, reward, terminated, truncated, info = envs.step(action)
        trace += [obs["tactile"].copy(), obs["true_pose_shear"].copy(), reward, terminated, truncated,
                  info["contact_error_mm"]]
    return trace


def test_make_vec_uses_the_batched_entry_point_and_matches_single_envs():
    envs = gym.make_vec("SimShearTracking-v0", num_envs=3, obs_mode="oracle", workers=0, randomise=True)
    assert isinstance(envs, SimShearVectorEnv) and envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.observation_space["tactile"].shape == (3, 1, 128, 128)
    assert envs.single_observation_space["true_pose_shear"].shape == (4,)
    obs, info = envs.reset(seed=10)
    for index in range(3):  # sub-env i is seeded with seed + i
        single_obs, _ = gym.make("SimShearTracking-v0", obs_mode="oracle", randomise=True).reset(seed=10 + index)
        np.testing.assert_array_equal(obs["tactile"][index], single_obs["tactile"])
        np.testing.assert_array_equal(obs["tcp_pose"][index], single_obs["tcp_pose"])
    assert info["contact_error_mm"].shape == (3,) and info["_contact_error_mm"].all()
    envs.close()


def test_worker_processes_give_the_same_rollout_as_in_process():
    kwargs = dict(num_envs=3, obs_mode="oracle", randomise=True, trajectory="random")
    in_process = gym.make_vec("SimShearTracking-v0", workers=0, **kwargs)
    in_workers = gym.make_vec("SimShearTracking-v0", workers=2, **kwargs)
    try:
        a, b = rollout(in_process, 12), rollout(in_workers, 12)
        assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    finally:
        in_process.close()
        in_workers.close()


def test_autoreset_next_step_and_truncation():
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, obs_mode="oracle", workers=0, max_episode_steps=4)
    envs.reset(seed=0)
    hold = np.zeros((2, 4), dtype=np.float32)
    lift_first = np.stack([LIFT, np.zeros(4, dtype=np.float32)])
    for _ in range(3):
        _, _, terminated, truncated, info = envs.step(lift_first)
    assert terminated.tolist() == [True, False] and info["termination"][0] == "contact_lost"
    obs, reward, terminated, truncated, info = envs.step(hold)  # env 0 resets; env 1 reaches 4 steps
    assert reward[0] == 0.0 and not terminated[0] and info["contact_error_mm"][0] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(obs["true_pose_shear"][0], [4.0, 0, 0, 0], atol=1e-5)
    assert truncated.tolist() == [False, True]
    envs.close()


def test_the_raw_sub_envs_carry_the_shear_in_their_observation_and_the_vector_env_takes_it_out():
    """The sub-envs' raw observation holds the shear the image was rendered at (no data through info); the vector
    env's observations, an ended episode's last one included, are the single env's."""
    from simshear_gym.contract import RAW_SHEAR_KEY

    raw = gym.make("SimShearTracking-v0", obs_mode="sim", raw_tactile=True)
    try:
        obs, info = raw.reset(seed=0)
        assert raw.observation_space.contains(obs)
        np.testing.assert_array_equal(obs[RAW_SHEAR_KEY], info["shear_sensor_mm_deg"].astype(np.float32))
    finally:
        raw.close()
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, obs_mode="real", image_size_px=64, workers=0,
                        max_episode_steps=2, autoreset_mode=AutoresetMode.SAME_STEP)
    try:
        obs, _ = envs.reset(seed=0)
        assert set(obs) == set(envs.single_observation_space.spaces)
        for _ in range(2):
            obs, _, _, truncated, info = envs.step(np.zeros((2, 4), dtype=np.float32))
        assert truncated.all() and set(obs) == set(envs.single_observation_space.spaces)
        assert all(envs.single_observation_space.contains(final) for final in info["final_obs"])
    finally:
        envs.close()


@pytest.mark.parametrize("translate_in, workers", [("workers", 0), ("main", 2)])
def test_batched_translation_matches_the_single_env(translate_in, workers):
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, obs_mode="real", image_size_px=64, workers=workers,
                        translate_in=translate_in, randomise=True)
    try:
        obs, _ = envs.reset(seed=4)
        obs, *_ = envs.step(np.full((2, 4), 0.3, dtype=np.float32))
        assert obs["tactile"].shape == (2, 1, 64, 64)
        for index in range(2):
            single = gym.make("SimShearTracking-v0", obs_mode="real", image_size_px=64, randomise=True)
            single.reset(seed=4 + index)
            single_obs, *_ = single.step(np.full(4, 0.3, dtype=np.float32))
            difference = np.abs(obs["tactile"][index].astype(int) - single_obs["tactile"].astype(int))
            assert difference.max() <= 1  # batch vs single inference: float round-off only
    finally:
        envs.close()


def test_gymnasiums_sync_vectorisation_works_too():
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, vectorization_mode="sync", obs_mode="sim")
    obs, _ = envs.reset(seed=0)
    obs, reward, *_ = envs.step(np.zeros((2, 4), dtype=np.float32))
    assert obs["tactile"].shape == (2, 1, 128, 128) and reward.shape == (2,)
    envs.close()


def test_gymnasiums_async_vectorisation_works_too():
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, vectorization_mode="async", obs_mode="sim")
    obs, _ = envs.reset(seed=0)
    obs, reward, *_ = envs.step(np.zeros((2, 4), dtype=np.float32))
    assert obs["tactile"].shape == (2, 1, 128, 128) and reward.shape == (2,)
    envs.close()


def test_bad_vector_arguments_raise_clear_errors():
    with pytest.raises(ValueError, match="translate_in"):
        gym.make_vec("SimShearTracking-v0", num_envs=2, translate_in="gpu", workers=0)
    with pytest.raises(ValueError, match="render"):
        gym.make_vec("SimShearTracking-v0", num_envs=2, render_mode="rgb_array", workers=0)
    envs = gym.make_vec("SimShearTracking-v0", num_envs=2, obs_mode="sim", workers=0)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 4\)"):
        envs.step(np.zeros((3, 4), dtype=np.float32))
    with pytest.raises(ValueError, match="action"):
        envs.step(np.full((2, 4), 2.0, dtype=np.float32))
    envs.close()


@pytest.mark.slow
def test_evaluate_env_speed_writes_results_with_the_command(tmp_path):
    import json

    import torch

    from simshear_gym import cli

    threads = torch.get_num_threads()
    try:
        assert cli.main(["evaluate", "env-speed", "--steps", "5", "--vector-steps", "2", "--num-envs", "2",
                         "--workers", "2", "--threads", "1", "--onnx-threads", "1", "2", "--out", str(tmp_path)]) == 0
    finally:
        torch.set_num_threads(threads)
    result = json.loads((tmp_path / "env_speed.json").read_text())
    assert result["command"].startswith("simshear evaluate env-speed --steps 5")
    assert "--onnx-threads 1 2" in result["command"]
    onnx_rows = [row for row in result["single_process"]["real"] if row["translator_runtime"] == "onnx"]
    assert [row["onnx_threads"] for row in onnx_rows] == [1, 2]
    assert result["single_process"]["real"][0]["steps_per_s"] > 0 and result["single_process"]["sim"]["steps"] == 5
    assert [row["translate_in"] for row in result["vectorised"]] == ["workers", "main"]


@pytest.mark.slow
def test_evaluate_env_speed_measures_several_envs_into_one_record(tmp_path):
    import json

    import torch

    from simshear_gym import cli

    threads = torch.get_num_threads()
    try:
        assert cli.main(["evaluate", "env-speed", "--env", "SimShearEdgeFollow-v0", "SimShearPush-v0", "--steps",
                         "5", "--vector-steps", "2", "--num-envs", "2", "--threads", "1", "--runtimes", "onnx",
                         "--out", str(tmp_path), "--name", "tasks"]) == 0
    finally:
        torch.set_num_threads(threads)
    result = json.loads((tmp_path / "tasks.json").read_text())
    assert "--env SimShearEdgeFollow-v0 SimShearPush-v0" in result["command"] and "machine" in result
    assert list(result["envs"]) == ["SimShearEdgeFollow-v0", "SimShearPush-v0"]
    for section in result["envs"].values():
        assert section["goals"]["single_steps_per_s"] == 300.0
        assert section["single_process"]["sim"]["steps"] == 5 and section["vectorised"]


def test_evaluate_env_speed_measures_a_sensors_models_beside_the_shipped_ones(tmp_path):
    import json

    import torch

    from simshear_gym import cli
    from simshear_gym.models.translator import save_generator
    from simshear_gym.models.unet import UNetConfig, UNetGenerator
    from simshear_gym.models.zoo import write_sensor

    torch.manual_seed(0)  # a lab's translator as a pipeline run writes it (a small one), no ONNX export beside it
    generator = UNetGenerator(UNetConfig(image_size_px=128, base_channels=4, max_channels=16, shear_dim=6))
    save_generator(tmp_path / "run" / "shpix2pix_surface.pt", generator.eval())
    write_sensor(tmp_path / "run", "lab", "configs/lab.toml", "smoke", {"dome_radius_mm": 22.0},
                 translators={"surface": "shpix2pix_surface.pt"}, posenets={"surface": "posenet.pt"}, variables={})
    threads = torch.get_num_threads()
    try:
        assert cli.main(["evaluate", "env-speed", "--steps", "5", "--vector-steps", "2", "--num-envs", "2",
                         "--workers", "1", "--threads", "1", "--runtimes", "torch", "--sensor",
                         str(tmp_path / "run"), "--out", str(tmp_path)]) == 0
    finally:
        torch.set_num_threads(threads)
    result = json.loads((tmp_path / "env_speed.json").read_text())
    assert f"--sensor {tmp_path / 'run'}" in result["command"]
    assert result["sensor"]["name"] == "lab" and result["sensor"]["auto_runtime"] == {"SimShearTracking-v0": "torch"}
    assert result["sensor"]["translators"]["SimShearTracking-v0"] == str(tmp_path / "run" / "shpix2pix_surface.pt")
    rows = result["single_process"]["real"]
    assert [(row["models"], row["translator"]) for row in rows] == [("shipped", "full"), ("sensor", "sensor")]
    assert result["single_process"]["sensor_sim"]["steps"] == 5
    goal = result["goals"]["sensor"]
    assert goal["shipped_over_sensor_rate"] == pytest.approx(rows[0]["steps_per_s"] / rows[1]["steps_per_s"], rel=1e-2)
    assert goal["goal_shipped_over_sensor_rate"] == 1.2 and isinstance(goal["met"], bool)
