"""The estimator an env's estimate observation runs: the servo controller's, built for that env.

Envs (and ``RealTactileEnv``) take it as their ``estimator`` argument; envs cannot import the controllers (same
floor), so it is passed in::

    from simshear_gym.control.env_estimator import env_estimator
    env = gymnasium.make("SimShearTracking-v0", observation="estimate", estimator=env_estimator)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simshear_gym.contract import ESTIMATE_OBSERVATIONS, servo_hints
from simshear_gym.control.estimator import TactileEstimator
from simshear_gym.control.policy import PolicySettings
from simshear_gym.control.servo import ServoController


class ReadingEstimator(TactileEstimator):
    """A :class:`~simshear_gym.control.estimator.TactileEstimator` that keeps the GDNN's raw reading of the last
    image (``last_reading``: (mean (4,), std (4,))) besides returning the filter's state, so the estimate
    observation holds both at one GDNN pass per image."""

    last_reading: tuple[np.ndarray, np.ndarray] | None = None

    def read(self, tactile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.last_reading = super().read(tactile)
        return self.last_reading


def env_estimator(env) -> ReadingEstimator:
    """The estimator the env's controller builds (:meth:`ServoController.for_env
    <simshear_gym.control.servo.ServoController.for_env>`, or the edge or push controller's ``for_env`` by the env's
    :class:`~simshear_gym.contract.ServoHints` law: the GDNN the env names, its process noise), keeping its
    readings (:func:`reading_estimator`)."""
    law = servo_hints(env).law
    return reading_estimator(law, _controller_class(law).for_env(env))


def _controller_class(law: str) -> type:
    """The controller of ``law`` (``servo``, ``edge`` or ``push``)."""
    if law == "push":
        from simshear_gym.control.push_servo import PushServoController

        return PushServoController
    if law == "edge":
        from simshear_gym.control.edge_servo import EdgeServoController

        return EdgeServoController
    return ServoController


def reading_estimator(law: str, controller) -> ReadingEstimator:
    """An estimate observation's estimator, of the same GDNN and filter settings as ``controller`` (a controller of
    ``law``: ``servo``, ``edge`` or ``push``): for the servo law a :class:`ReadingEstimator`; for the edge and push
    laws theirs, their estimates in the observation's four slots
    (:class:`~simshear_gym.control.edge_servo.EdgeReadingEstimator`,
    :func:`~simshear_gym.control.push_servo.push_reading_estimator`). Sim envs (:func:`env_estimator`) and
    ``simshear rollout`` (a policy on the real path) build theirs with it."""
    if law == "push":
        from simshear_gym.control.push_servo import push_reading_estimator

        return push_reading_estimator(controller.estimator.config)
    if law == "edge":
        from simshear_gym.control.edge_servo import EdgeReadingEstimator

        return EdgeReadingEstimator(controller.estimator.config, controller.law.gains.angle_process_std_deg)
    if law != "servo":
        raise ValueError(f"unknown law {law!r}; expected servo, edge or push")
    return ReadingEstimator(controller.estimator.config)


def env_kwargs(settings: PolicySettings) -> dict[str, Any]:
    """``gym.make`` keyword arguments of a sim env that gives a policy the observation it was trained on."""
    kwargs = settings.env_kwargs()
    if settings.observation in ESTIMATE_OBSERVATIONS:
        kwargs["estimator"] = env_estimator
    return kwargs


def policy_env_kwargs(model: str) -> dict[str, Any]:
    """``gym.make`` keyword arguments of a sim env that gives the SB3 model at ``model`` the observation it was
    trained on (:func:`env_kwargs` of its run's settings; a bare ``.zip`` without them: translated images)."""
    settings = PolicySettings.of_model(model)
    return env_kwargs(settings) if settings is not None else {"obs_mode": "real"}


__all__ = ["ReadingEstimator", "env_estimator", "env_kwargs", "policy_env_kwargs", "reading_estimator"]
