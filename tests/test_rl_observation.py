"""The policy's observation modes (tactile, estimate, tactile+estimate, with a history): one definition for the sim
envs and the real env, the estimate read by the servo controller's own estimator, and the reward that teaches
tracking."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import simshear_gym.envs  # noqa: F401  (registers the envs)
from simshear_gym.contract import (
    ESTIMATE_SCALE,
    ESTIMATE_SIZE,
    OBSERVATIONS,
    TCP_POSE_LOW,
    estimate_features,
    filter_mean_from_estimate,
    observation_space,
    policy_spaces,
)
from simshear_gym.control.env_estimator import ReadingEstimator, env_estimator
from simshear_gym.control.servo import ServoController
from simshear_gym.envs.base import RewardConfig
from simshear_gym.real.env import RealEnvConfig, RealTactileEnv

torch.set_num_threads(1)


def make(observation: str = "estimate", history: int = 1, env_id: str = "SimShearTracking-v0", **kwargs):
    return gym.make(env_id, observation=observation, history=history, image_size_px=64, estimator=env_estimator,
                    **kwargs)


def test_the_default_observation_is_the_image_and_tcp_pose_as_before():
    space = observation_space(64)
    assert set(space.spaces) == {"tactile", "tcp_pose"}
    assert space["tactile"].shape == (1, 64, 64) and space["tactile"].dtype == np.uint8
    assert np.array_equal(space["tcp_pose"].low, TCP_POSE_LOW)
    env = gym.make("SimShearTracking-v0", image_size_px=64, obs_mode="sim")
    try:
        assert env.observation_space == space
        obs, _ = env.reset(seed=0)
        assert set(obs) == {"tactile", "tcp_pose"} and obs["tactile"].shape == (1, 64, 64)
    finally:
        env.close()


@pytest.mark.parametrize("observation", OBSERVATIONS)
@pytest.mark.parametrize("history", [1, 3])
def test_sim_and_real_envs_give_the_same_spaces(observation, history):
    env = make(observation, history, obs_mode="sim")
    real = RealTactileEnv(RealEnvConfig(image_size_px=64, preprocess=None, observation=observation,
                                        history=history))  # connects only on reset
    try:
        assert env.observation_space == real.observation_space == policy_spaces(64, observation, history)[0]
        assert env.action_space == real.action_space
        keys = set(env.observation_space.spaces)
        assert ("estimate" in keys) == ("estimate" in observation)
        assert ("tactile" in keys) == ("tactile" in observation)
        if "estimate" in keys:
            assert env.observation_space["estimate"].shape == (ESTIMATE_SIZE * history,)
        if "tactile" in keys:
            assert env.observation_space["tactile"].shape == (history, 64, 64)
    finally:
        env.close()
        real.close()


def test_history_holds_the_last_frames_oldest_first():
    env = make("tactile+estimate", history=3)
    try:
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        first = obs["estimate"][-ESTIMATE_SIZE:]
        assert all(np.array_equal(frame, obs["tactile"][0]) for frame in obs["tactile"])  # filled at reset
        np.testing.assert_array_equal(obs["estimate"].reshape(3, ESTIMATE_SIZE), np.tile(first, (3, 1)))
        previous = obs
        for _ in range(2):
            obs, *_ = env.step(np.array([0.5, 0.0, 0.0, 0.0], np.float32))
            assert env.observation_space.contains(obs)
            np.testing.assert_array_equal(obs["tactile"][:2], previous["tactile"][1:])
            np.testing.assert_array_equal(obs["estimate"][:2 * ESTIMATE_SIZE], previous["estimate"][ESTIMATE_SIZE:])
            previous = obs
        assert not np.array_equal(obs["estimate"][-ESTIMATE_SIZE:], first)
    finally:
        env.close()


def test_the_last_action_is_the_move_the_arm_took_over_the_full_scale():
    env = make("estimate+action", history=2)
    try:
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        np.testing.assert_array_equal(obs["last_action"], np.zeros(4, np.float32))  # nothing commanded yet
        for action in ([0.5, -0.25, 0.1, 0.0], [1.0, 0.0, -1.0, 0.3]):
            obs, *_ = env.step(np.array(action, np.float32))
            assert env.observation_space.contains(obs)
            np.testing.assert_allclose(obs["last_action"], action, atol=1e-6)
        obs, _ = env.reset(seed=1)
        np.testing.assert_array_equal(obs["last_action"], np.zeros(4, np.float32))
    finally:
        env.close()
    from simshear_gym.envs.observation import PolicyObservation

    class Still:
        last_reading = None

        def reset(self):
            pass

        def __call__(self, tactile, commanded_move=None):
            return np.zeros(4), np.ones(4)

    with pytest.raises(ValueError, match="needs action_scale="):
        PolicyObservation("estimate+action", 2, 4.0, estimator=Still())


def test_the_estimate_is_the_servo_controllers_own_estimate():
    """Driven by the servo controller reading the same images, the env's estimate decodes to the controller's state
    estimate every step: one estimator (the env is fed the moves the controller commanded)."""
    env = make("tactile+estimate", obs_mode="real", trajectory="circle")
    try:
        servo = ServoController.for_env(env)
        assert isinstance(env.unwrapped._policy_observation.estimator, ReadingEstimator)
        assert env.unwrapped._policy_observation.estimator.config == servo.estimator.config
        obs, _ = env.reset(seed=0)
        servo.reset()
        for _ in range(8):
            action = servo(obs)
            mean, _ = servo.last_estimate
            np.testing.assert_allclose(filter_mean_from_estimate(obs["estimate"], env.unwrapped.reference_depth_mm),
                                       mean, atol=1e-4)
            obs, *_ = env.step(action)
    finally:
        env.close()


def test_estimate_features_are_normalised_and_invertible():
    reading = (np.array([4.5, 1.0, -2.0, 0.0]), np.array([0.2, 0.5, 0.5, 100.0]))
    filtered = (np.array([4.2, 0.9, -1.5, 0.0]), np.array([0.1, 0.3, 0.3, 100.0]))
    features = estimate_features(reading, filtered, reference_depth_mm=4.0)
    assert features.shape == (ESTIMATE_SIZE,) and features.dtype == np.float32
    np.testing.assert_allclose(features[:4], (reading[0] - [4.0, 0, 0, 0]) / ESTIMATE_SCALE, rtol=1e-6)
    assert features[7] == 1.0 and features[15] == 1.0  # a variable the GDNN cannot read: its std at the top
    assert np.all(np.abs(features) <= 1.0)
    np.testing.assert_allclose(filter_mean_from_estimate(np.tile(features, 2), 4.0), filtered[0], atol=1e-6)
    far = estimate_features((np.array([30.0, 99.0, -99.0, 0.0]), reading[1]), filtered, 4.0)
    assert far[0] == 4.0 and far[1] == 4.0 and far[2] == -4.0  # clipped to the space's bounds


def test_bad_observation_settings_are_refused_with_what_to_pass():
    with pytest.raises(ValueError, match="observation must be one of"):
        gym.make("SimShearTracking-v0", observation="pixels")
    with pytest.raises(ValueError, match="history must be an int"):
        gym.make("SimShearTracking-v0", history=0)
    with pytest.raises(ValueError, match="needs estimator=.*env_estimator"):
        gym.make("SimShearTracking-v0", observation="estimate")
    with pytest.raises(ValueError, match="raw_tactile"):
        gym.make("SimShearTracking-v0", observation="estimate", estimator=env_estimator, raw_tactile=True)
    with pytest.raises(ValueError, match="RealEnvConfig: observation must be one of"):
        RealEnvConfig(observation="pixels")


def test_colift_gives_the_estimate_with_its_own_gdnn():
    env = make("estimate", env_id="SimShearCoLift-v0", object_name="egg", obs_mode="real")
    try:
        estimator = env.unwrapped._policy_observation.estimator
        assert estimator.config == ServoController.for_env(env).estimator.config
        assert estimator.config.posenet.endswith("colift.pt") and estimator.config.process_std_mm == 1.5
        obs, _ = env.reset(seed=0)
        obs, reward, *_ = env.step(np.zeros(4, np.float32))
        assert env.observation_space.contains(obs) and set(obs) == {"estimate"}
        assert abs(filter_mean_from_estimate(obs["estimate"], env.unwrapped.reference_depth_mm)[0] - 5.2) < 1.5
    finally:
        env.close()


def test_reward_is_non_negative_in_contact_and_an_early_end_costs():
    env = gym.make("SimShearTracking-v0", obs_mode="oracle", image_size_px=64, trajectory="circle")
    config = RewardConfig()
    try:
        env.reset(seed=0)
        for _ in range(20):
            _, reward, terminated, _, info = env.step(np.zeros(4, np.float32))
            error = info["contact_error_mm"]
            expected = 1.0 - min(error / 5.0, 1.0) + math.exp(-error ** 2)
            assert reward == pytest.approx(expected) and 0.0 <= reward <= 2.0 and not terminated
        env.reset(seed=0)
        for _ in range(5):  # lift off: the contact is lost and the episode ends
            _, reward, terminated, _, info = env.step(np.array([0, 0, -1.0, 0], np.float32))
            if terminated:
                break
        assert info["termination"] == "contact_lost"
        assert reward <= 2.0 - config.contact_loss_penalty - config.termination_penalty
    finally:
        env.close()
    with pytest.raises(ValueError, match="RewardConfig"):
        RewardConfig(termination_penalty=-1.0)
