"""Wrappers that fit the default (``observation="tactile"``) observation to an off-the-shelf learner.

The default observation's ``tcp_pose`` is the TCP's absolute pose in the robot base frame (mm, deg) in a
+-1000 box, as the robot reports it and as :class:`~simshear_gym.real.env.RealTactileEnv` gives it: an unscaled
input that SB3's ``MultiInputPolicy`` takes as it is unless ``VecNormalize`` scales it (``simshear train rl`` does).
:class:`RelativeTcpPose` gives a policy the TCP's move since the episode's start instead, scaled into [-1, 1].
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: what one unit of the wrapped ``tcp_pose`` is: x, y, z mm and R deg from the episode's start pose (every default
#: path stays within 100 mm of its start; the depth within a few mm; the flange turns within 90 deg)
RELATIVE_TCP_SCALE = np.array([100.0, 100.0, 10.0, 90.0])


class RelativeTcpPose(gym.ObservationWrapper):
    """``tcp_pose`` float32 (4,) in [-1, 1]: ``(pose - pose at reset) / RELATIVE_TCP_SCALE``, clipped; the other
    keys as they are. Works on the sim envs and ``RealTactileEnv`` alike (both give ``tcp_pose`` with
    ``observation="tactile"``)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        if not isinstance(env.observation_space, spaces.Dict) or "tcp_pose" not in env.observation_space.spaces:
            raise ValueError("RelativeTcpPose needs an observation with tcp_pose (observation='tactile'), got "
                             f"{env.observation_space}")
        self.observation_space = spaces.Dict({**env.observation_space.spaces,
                                              "tcp_pose": spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)})
        self._start: np.ndarray | None = None

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        self._start = np.asarray(observation["tcp_pose"], dtype=np.float64)
        return self.observation(observation), info

    def observation(self, observation: dict) -> dict:
        relative = (np.asarray(observation["tcp_pose"], dtype=np.float64) - self._start) / RELATIVE_TCP_SCALE
        return {**observation, "tcp_pose": np.clip(relative, -1.0, 1.0).astype(np.float32)}
