"""The documented wrapper that fits the default observation to SB3: the TCP's move since the episode's start,
scaled into [-1, 1], instead of its absolute pose in a +-1000 box."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simshear_gym.envs  # noqa: F401  (registers the envs)
from simshear_gym.envs.wrappers import RELATIVE_TCP_SCALE, RelativeTcpPose


@pytest.mark.slow
def test_relative_tcp_pose_starts_at_zero_follows_the_moves_and_passes_the_env_checker():
    raw = gym.make("SimShearTracking-v0", obs_mode="sim", image_size_px=64)
    env = RelativeTcpPose(gym.make("SimShearTracking-v0", obs_mode="sim", image_size_px=64))
    try:
        first_raw, _ = raw.reset(seed=3)
        first, _ = env.reset(seed=3)
        assert np.array_equal(first["tcp_pose"], np.zeros(4, dtype=np.float32))
        assert np.array_equal(first["tactile"], first_raw["tactile"])
        action = np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32)
        for _ in range(3):
            moved_raw, *_ = raw.step(action)
            moved, *_ = env.step(action)
        expected = (moved_raw["tcp_pose"].astype(np.float64) - first_raw["tcp_pose"]) / RELATIVE_TCP_SCALE
        assert np.allclose(moved["tcp_pose"], expected, atol=1e-6) and abs(moved["tcp_pose"][0]) > 0.0
        assert env.observation_space["tcp_pose"].contains(moved["tcp_pose"])
        check_env(env.unwrapped, skip_render_check=True)  # the env; the wrapper only rescales one key
        assert env.observation_space.contains(moved)
    finally:
        env.close()
        raw.close()


def test_the_wrapper_needs_a_tcp_pose():
    class NoPose(gym.Env):
        observation_space = gym.spaces.Dict({"estimate": gym.spaces.Box(-1.0, 1.0, (16,))})
        action_space = gym.spaces.Box(-1.0, 1.0, (4,))

    with pytest.raises(ValueError, match="observation='tactile'"):
        RelativeTcpPose(NoPose())
