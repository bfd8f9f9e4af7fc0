"""ServoHints: what a controller made for an env takes from it, one typed object per env (sim and real)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs  # noqa: F401
from simshear_gym.contract import ServoHints, servo_hints

# Each env's hints, as its class attributes gave them before they were gathered in ServoHints.
ENV_HINTS = [
    ("SimShearTracking-v0", {}, ServoHints()),
    ("SimShearTracking6D-v0", {}, ServoHints()),
    ("SimShearCoLift-v0", {}, ServoHints(posenet="colift", process_std_mm=1.5)),
    ("SimShearCoLift-v0", {"payload": "heavy"},
     ServoHints(posenet="colift_heavy", process_std_mm=1.5, hold_load=True, load_margin_mm=(0.0, -0.4),
                shear_gains=(1.0, 0.5))),
    ("SimShearEdgeFollow-v0", {}, ServoHints(law="edge", posenet="edge", process_std_mm=0.3)),
    ("SimShearPush-v0", {}, ServoHints(law="push", process_std_mm=0.5)),
]


@pytest.fixture(scope="module")
def envs():
    made = {}
    yield lambda env_id, kwargs: made.setdefault(
        (env_id, tuple(sorted(kwargs.items()))), gym.make(env_id, obs_mode="sim", **kwargs))
    for env in made.values():
        env.close()


@pytest.mark.parametrize("env_id, kwargs, expected", ENV_HINTS, ids=lambda value: str(value)[:24])
def test_each_env_gives_the_hints_it_gave_before(envs, env_id, kwargs, expected):
    env = envs(env_id, kwargs)
    assert servo_hints(env) == expected  # through gymnasium's wrappers
    assert env.unwrapped.servo_hints == expected


def test_the_real_env_names_its_configured_gdnn():
    from simshear_gym.real.env import RealEnvConfig, RealTactileEnv

    assert RealTactileEnv(RealEnvConfig(preprocess=None)).servo_hints == ServoHints()
    mine = RealTactileEnv(RealEnvConfig(preprocess=None, posenet="/tmp/sensor/best.pt"))
    assert mine.servo_hints == ServoHints(posenet="/tmp/sensor/best.pt")


def test_controllers_made_for_each_env_take_the_settings_they_took_before(envs):
    from simshear_gym.control.edge_servo import EdgeServoController
    from simshear_gym.control.push_servo import PushServoController
    from simshear_gym.control.servo import SERVO_GAINS, ServoController
    from simshear_gym.control.servo6d import Servo6DController
    from simshear_gym.models.zoo import posenet_weights
    from simshear_gym.train.rl_imitation import EdgeTeacher, PushTeacher, ServoTeacher, teacher_for

    for env_id, kwargs, posenet, process_mm in (("SimShearTracking-v0", {}, "surface", None),
                                                ("SimShearCoLift-v0", {}, "colift", 1.5),
                                                ("SimShearCoLift-v0", {"payload": "heavy"}, "colift_heavy", 1.5),
                                                ("SimShearEdgeFollow-v0", {}, "edge", 0.3),
                                                ("SimShearPush-v0", {}, "surface", 0.5)):
        env = envs(env_id, kwargs)
        servo = ServoController.for_env(env)
        assert servo.estimator.config.posenet == str(posenet_weights(posenet)), env_id
        assert servo.estimator.config.process_std_mm == process_mm, env_id
        heavy = kwargs.get("payload") == "heavy"
        assert servo.hold_load == heavy
        np.testing.assert_allclose(servo.load_margin_mm, [0.0, -0.4] if heavy else [0.0, 0.0])
        assert servo.law.gains.kp[:2] == ((1.0, 1.0) if heavy else SERVO_GAINS.kp[:2])
        assert servo.law.gains.ki[:2] == ((0.5, 0.5) if heavy else SERVO_GAINS.ki[:2])
    edge_env = envs("SimShearEdgeFollow-v0", {})
    edge = EdgeServoController.for_env(edge_env)
    assert edge.estimator.config.posenet == str(posenet_weights("edge"))
    assert edge.estimator.config.process_std_mm == 0.3
    push = PushServoController.for_env(envs("SimShearPush-v0", {}))
    assert push.estimator.config.process_std_mm == 0.5
    servo6d = Servo6DController.for_env(envs("SimShearTracking6D-v0", {}))
    assert servo6d.estimator.config.posenet == str(posenet_weights("surface"))
    assert isinstance(teacher_for(envs("SimShearTracking-v0", {})), ServoTeacher)
    assert isinstance(teacher_for(edge_env), EdgeTeacher)
    assert isinstance(teacher_for(envs("SimShearPush-v0", {})), PushTeacher)


def test_the_edge_envs_estimate_observation_keeps_the_estimators_default_noise():
    """The edge env's own process noise is for its controllers; the estimate observation's estimator, built in the
    base constructor, keeps the estimator's default (what the shipped edge policy was trained on)."""
    from simshear_gym.control.edge_servo import EdgeReadingEstimator
    from simshear_gym.control.env_estimator import env_estimator

    env = gym.make("SimShearEdgeFollow-v0", obs_mode="sim", observation="estimate", estimator=env_estimator)
    try:
        estimator = env.unwrapped._policy_observation.estimator
        assert isinstance(estimator, EdgeReadingEstimator)
        assert estimator.config.process_std_mm is None
        assert env.unwrapped.servo_hints.process_std_mm == 0.3
    finally:
        env.close()


def test_an_env_without_hints_is_refused_by_name():
    from simshear_gym.control.servo import ServoController

    env = gym.make("CartPole-v1")
    try:
        with pytest.raises(TypeError, match="CartPoleEnv has no servo_hints"):
            servo_hints(env)
        with pytest.raises(TypeError, match="servo_hints"):
            ServoController.for_env(env)
    finally:
        env.close()


@pytest.mark.parametrize("kwargs, match", [
    ({"law": "oracle"}, "law must be one of"),
    ({"posenet": ""}, "posenet"),
    ({"process_std_mm": 0.0}, "process_std_mm"),
    ({"load_margin_mm": (0.0,)}, "load_margin_mm"),
    ({"shear_gains": (1.0, float("nan"))}, "shear_gains"),
])
def test_bad_hints_raise_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ServoHints(**kwargs)
