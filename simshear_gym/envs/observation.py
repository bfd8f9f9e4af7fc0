"""The policy's observation, built the same way in the sim envs and on the robot (``RealTactileEnv``).

:class:`PolicyObservation` turns each step's tactile image and TCP pose into the observation of
:func:`simshear_gym.contract.observation_space` for an ``observation`` (``tactile``, ``estimate``,
``tactile+estimate``, ``estimate+action``) and a ``history`` of k frames: it keeps the last k images (or
estimates), oldest first, and, for the estimate, runs an :class:`Estimator` (the servo controller's: GDNN + Bayesian
filter) on every image, fed with the move actually commanded since the last one (``last_action``: that move over the
action's full scale). At reset the history is filled with the first frame.

The estimator is passed in (envs do not import :mod:`simshear_gym.control`, which sits on their floor):
:func:`simshear_gym.control.env_estimator.env_estimator` builds the one ``ServoController.for_env`` would.
"""

from __future__ import annotations

from collections import deque
from typing import Protocol, runtime_checkable

import numpy as np

from simshear_gym.contract import (
    ACTION_OBSERVATIONS,
    ESTIMATE_OBSERVATIONS,
    TACTILE_OBSERVATIONS,
    TCP_POSE_LOW,
    check_observation,
    estimate_features,
)


@runtime_checkable
class Estimator(Protocol):
    """What the estimate observation needs (:class:`simshear_gym.control.env_estimator.ReadingEstimator` is one):
    ``reset()`` per episode; ``__call__(tactile, commanded_move) -> (mean (4,), std (4,))``, the filter's state
    after fusing an image (``commanded_move``: dx, dy, dz mm, dRz deg sent since the last image, or None); and
    ``last_reading``: the GDNN's own (mean, std) of that image."""

    last_reading: tuple[np.ndarray, np.ndarray] | None

    def reset(self) -> None: ...

    def __call__(self, tactile: np.ndarray, commanded_move: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]: ...


class PolicyObservation:
    """Image (S, S) uint8 and ``tcp_pose`` (4,) per step -> the observation dict (see the module docstring).

    Args:
        observation: one of :data:`~simshear_gym.contract.OBSERVATIONS`.
        history: k, frames or estimates stacked (1: none).
        reference_depth_mm: the depth the task holds (labels' convention): the estimate's depth is relative to it.
        estimator: needed when the observation holds the estimate; else unused.
        action_scale: the action's full scale (x, y, z mm, Rz deg): needed when the observation holds the last
            action (the commanded move over it); else unused.
    """

    def __init__(self, observation: str, history: int, reference_depth_mm: float,
                 estimator: Estimator | None = None, action_scale: np.ndarray | None = None) -> None:
        check_observation(observation, history)
        self.observation = observation
        self.history = history
        self.with_tactile = observation in TACTILE_OBSERVATIONS
        self.with_estimate = observation in ESTIMATE_OBSERVATIONS
        if self.with_estimate and not isinstance(estimator, Estimator):
            raise ValueError(f"observation={observation!r} needs an estimator (reset, __call__ and last_reading), "
                             f"got {estimator!r}")
        self.estimator = estimator
        self.with_action = observation in ACTION_OBSERVATIONS
        if self.with_action:
            scale = np.asarray(action_scale if action_scale is not None else [], dtype=np.float64).reshape(-1)
            if scale.shape != (4,) or not np.all(scale > 0):
                raise ValueError(f"observation={observation!r} needs action_scale=, 4 positive full-scale moves "
                                 f"(x, y, z mm, Rz deg), got {action_scale!r}")
            self._action_scale = scale
        self.reference_depth_mm = float(reference_depth_mm)
        self._images: deque[np.ndarray] = deque(maxlen=history)
        self._estimates: deque[np.ndarray] = deque(maxlen=history)
        self.last_estimate: tuple[np.ndarray, np.ndarray] | None = None
        """The filter's (mean (4,), std (4,)) after the last image (estimate observations only)."""

    def reset(self, image: np.ndarray, tcp_pose: np.ndarray) -> dict[str, np.ndarray]:
        """The first observation of an episode: the history filled with this frame."""
        if self.estimator is not None and self.with_estimate:
            self.estimator.reset()
        self._images.clear()
        self._estimates.clear()
        return self._push(image, tcp_pose, None, fill=True)

    def step(self, image: np.ndarray, tcp_pose: np.ndarray, commanded_move: np.ndarray | None
             ) -> dict[str, np.ndarray]:
        """The observation after a step that commanded ``commanded_move`` (dx, dy, dz mm, dRz deg)."""
        return self._push(image, tcp_pose, commanded_move, fill=False)

    def _push(self, image: np.ndarray, tcp_pose: np.ndarray, move: np.ndarray | None,
              fill: bool) -> dict[str, np.ndarray]:
        image = np.asarray(image, dtype=np.uint8)
        if image.ndim == 3 and image.shape[0] == 1:
            image = image[0]
        count = self.history if fill else 1
        obs: dict[str, np.ndarray] = {}
        if self.with_tactile:
            for _ in range(count):
                self._images.append(image)
            obs["tactile"] = np.stack(self._images)
        if self.observation == "tactile":
            obs["tcp_pose"] = np.clip(np.asarray(tcp_pose, dtype=np.float64), TCP_POSE_LOW,
                                      -TCP_POSE_LOW).astype(np.float32)
        if self.with_estimate:
            filtered = self.estimator(image, move)
            self.last_estimate = (np.asarray(filtered[0]).copy(), np.asarray(filtered[1]).copy())
            features = estimate_features(self.estimator.last_reading, filtered, self.reference_depth_mm)
            for _ in range(count):
                self._estimates.append(features)
            obs["estimate"] = np.concatenate(self._estimates).astype(np.float32)
        if self.with_action:
            last = np.zeros(4) if move is None else np.asarray(move, dtype=np.float64) / self._action_scale
            obs["last_action"] = np.clip(np.nan_to_num(last), -1.0, 1.0).astype(np.float32)
        return obs


__all__ = ["Estimator", "PolicyObservation"]
