"""``--vec batched``: SB3's VecEnv API over the batched vector env (SAME_STEP autoreset, the episode's last image
translated in the step's batch), and a tiny image-only PPO run on it."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode

import simshear_gym.envs  # noqa: F401
from simshear_gym.train.rl import RLTrainConfig, train
from simshear_gym.train.rl_vec import SB3VectorEnv, unbatch_infos

torch.set_num_threads(1)
LIFT = np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32)  # loses contact on the third step
HOLD = np.zeros(4, dtype=np.float32)


def test_same_step_autoreset_returns_the_reset_observation_and_the_translated_last_one():
    kwargs = dict(num_envs=2, obs_mode="real", image_size_px=64, workers=0, max_episode_steps=4)
    same = gym.make_vec("SimShearTracking-v0", autoreset_mode="same_step", **kwargs)
    nxt = gym.make_vec("SimShearTracking-v0", **kwargs)
    try:
        assert same.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        same.reset(seed=3)
        nxt.reset(seed=3)
        actions = np.stack([LIFT, HOLD])
        for _ in range(3):
            obs, reward, terminated, truncated, info = same.step(actions)
            last, reward_next, terminated_next, *_ = nxt.step(actions)
        assert terminated.tolist() == [True, False] and terminated_next.tolist() == [True, False]
        assert reward.tolist() == reward_next.tolist()
        assert info["_final_obs"].tolist() == [True, False]
        assert info["final_info"]["termination"][0] == "contact_lost"
        # the episode's last image: what NEXT_STEP returned at that step, translated in the same batch
        np.testing.assert_array_equal(info["final_obs"][0]["tactile"], last["tactile"][0])
        np.testing.assert_array_equal(obs["tactile"][1], last["tactile"][1])
        # sub-env 0 has already been reset: it is back at the start depth
        np.testing.assert_allclose(info["contact_error_mm"][0], 0.0, atol=1e-9)
        reset_obs, *_ = nxt.step(actions)  # NEXT_STEP resets now; the reset images agree
        np.testing.assert_array_equal(obs["tcp_pose"][0], reset_obs["tcp_pose"][0])
    finally:
        same.close()
        nxt.close()


def test_sb3_adapter_gives_terminal_observations_and_the_time_limit_flag():
    vector_env = gym.make_vec("SimShearTracking-v0", num_envs=2, obs_mode="sim", image_size_px=64, workers=0,
                              max_episode_steps=4, autoreset_mode=AutoresetMode.SAME_STEP)
    venv = SB3VectorEnv(vector_env)
    try:
        venv.seed(7)
        obs = venv.reset()
        assert obs["tactile"].shape == (2, 1, 64, 64) and len(venv.reset_infos) == 2
        for step in range(4):
            venv.step_async(np.stack([LIFT, HOLD]) if step < 3 else np.stack([HOLD, HOLD]))
            obs, rewards, dones, infos = venv.step_wait()
            if step == 2:  # sub-env 0 lost contact: an end that is not a time limit
                assert dones.tolist() == [True, False]
                assert infos[0]["termination"] == "contact_lost" and not infos[0]["TimeLimit.truncated"]
                assert infos[0]["terminal_observation"]["tactile"].shape == (1, 64, 64)
                assert "terminal_observation" not in infos[1]
        # sub-env 1 reached the 4-step limit: truncated, SB3 bootstraps its value
        assert dones.tolist() == [False, True] and infos[1]["TimeLimit.truncated"]
        assert rewards.dtype == np.float32 and venv.get_attr("num_envs") == [2, 2]
    finally:
        venv.close()


def test_the_adapter_needs_same_step_autoreset():
    vector_env = gym.make_vec("SimShearTracking-v0", num_envs=1, obs_mode="sim", workers=0)
    with pytest.raises(ValueError, match="autoreset_mode SAME_STEP"):
        SB3VectorEnv(vector_env)
    vector_env.close()
    with pytest.raises(ValueError, match="autoreset_mode must be one of"):
        gym.make_vec("SimShearTracking-v0", num_envs=1, workers=0, autoreset_mode="later")


def test_unbatch_infos_keeps_each_sub_envs_own_keys():
    infos = {"a": np.array([1.0, 2.0]), "_a": np.array([True, False]),
             "inner": {"b": np.array([3, 4]), "_b": np.array([False, True])}, "_inner": np.array([False, True])}
    assert unbatch_infos(infos, 2) == [{"a": 1.0}, {"inner": {"b": 4}}]


def test_batched_vec_trains_an_image_policy_and_is_refused_where_it_cannot_serve(tmp_path):
    config = RLTrainConfig(algo="ppo", timesteps=32, observation="tactile", obs_mode="real", image_size_px=64,
                           n_envs=2, vec="batched", n_steps=16, batch_size=16, n_epochs=1, checkpoint_steps=16)
    summary = train(config, tmp_path / "batched", progress=False)
    assert summary["timesteps"] >= 32 and (tmp_path / "batched" / "model.zip").is_file()
    with pytest.raises(ValueError, match="--vec batched .* needs --task tracking --observation tactile"):
        RLTrainConfig(vec="batched", observation="estimate")
    with pytest.raises(ValueError, match="--vec batched"):
        RLTrainConfig(vec="batched", task="colift")


def test_same_step_final_images_agree_whether_workers_or_this_process_translate():
    kwargs = dict(num_envs=2, obs_mode="real", image_size_px=64, max_episode_steps=4, autoreset_mode="same_step")
    in_process = gym.make_vec("SimShearTracking-v0", workers=0, **kwargs)
    in_main = gym.make_vec("SimShearTracking-v0", workers=2, translate_in="main", **kwargs)
    try:
        results = []
        for envs in (in_process, in_main):
            envs.reset(seed=5)
            for _ in range(3):
                obs, _, terminated, _, info = envs.step(np.stack([LIFT, HOLD]))
            assert terminated.tolist() == [True, False]
            results.append((obs["tactile"], info["final_obs"][0]["tactile"]))
        np.testing.assert_array_equal(results[0][0], results[1][0])
        np.testing.assert_array_equal(results[0][1], results[1][1])
    finally:
        in_process.close()
        in_main.close()
