"""The one controller interface: what the rollout loops drive, whether the actions come from a law or a network.

A :class:`Controller` is anything with ``reset()`` (call it at each episode start) and ``__call__(observation)``
that maps one observation dict of the envs (``tactile``, ``tcp_pose`` and, in the oracle modes,
``true_pose_shear``) to an action, float32 (4,) in [-1, 1]. The servo controller
(:class:`~simshear_gym.control.servo.ServoController`), the oracle
(:class:`~simshear_gym.control.oracle.OracleController`) and a trained Stable-Baselines3 agent
(:class:`SB3Controller`) all are one, so the simulated benchmark (``simshear_gym.evaluate.servo.run_episode``)
and the real rollout (``simshear_gym.real.rollout.run_rollout``) take any of them.

A controller that keeps a state estimate exposes it as ``last_estimate`` (:class:`EstimatingController`); the real
rollout logs it. A controller may carry a ``name`` for logs (``"servo"``, ``"ppo:<path>"``).

Stable-Baselines3 (and so torch) is imported only when a model is loaded, so importing this module stays cheap.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simshear_gym.contract import ActionScale


@runtime_checkable
class Controller(Protocol):
    """Observation -> action in [-1, 1]^4; :meth:`reset` at each episode start (forget filters, integrals)."""

    def reset(self) -> None:
        """Start a new episode."""

    def __call__(self, observation: dict) -> np.ndarray:
        """One observation dict -> float32 (4,) action in [-1, 1]."""


@runtime_checkable
class EstimatingController(Controller, Protocol):
    """A controller that keeps a state estimate: ``last_estimate`` is (mean (4,), std (4,)) of (depth, shear x,
    shear y mm, shear Rz deg) after the last call, or None before the first."""

    last_estimate: tuple[np.ndarray, np.ndarray] | None


def as_action_scale(action_scale: Any, owner: str) -> ActionScale:
    """The :class:`~simshear_gym.contract.ActionScale` a controller takes, checked (``owner`` names the caller)."""
    if not isinstance(action_scale, ActionScale):
        raise TypeError(f"{owner}: action_scale must be an ActionScale (e.g. the env's action_scale), got "
                        f"{action_scale!r}")
    return action_scale


# ----------------------------------------------------------------------------------------------------------------
# Stable-Baselines3 models


def sb3_algorithm(path: str | Path) -> str:
    """``"ppo"`` or ``"sac"``: which SB3 algorithm saved a ``.zip`` (read from its ``data`` entry).

    Raises:
        ValueError: not a Stable-Baselines3 model, or neither PPO nor SAC.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as error:
        raise ValueError(f"{path} is not a Stable-Baselines3 model .zip (no readable 'data' entry): {error}") from None
    # The zip names the policy class, not the algorithm; the saved hyper-parameters tell PPO and SAC apart.
    if "clip_range" in data:
        return "ppo"
    if "target_entropy" in data:
        return "sac"
    raise ValueError(f"{path}: neither a PPO nor a SAC model of stable_baselines3 (saved keys: {sorted(data)[:12]}...)")


class SB3Controller:
    """A Stable-Baselines3 model as a :class:`Controller`: deterministic ``predict``, no state between episodes
    (a recurrent policy is not supported).

    Args:
        model: anything with SB3's ``predict(observation, deterministic=True) -> (action, state)``.
        name: for logs; :meth:`load` gives ``"<algorithm>:<path>"``.
    """

    def __init__(self, model, name: str = "sb3") -> None:
        self.model = model
        self.name = name

    @classmethod
    def load(cls, path: str | Path, observation_space, action_space) -> SB3Controller:
        """Load a PPO/SAC ``.zip`` on the CPU and check that it was trained on these spaces (the env's).

        Raises:
            FileNotFoundError: no such file.
            ValueError: not an SB3 PPO/SAC model, or trained for other observation/action spaces.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no Stable-Baselines3 model file at {str(path)!r}")
        if sb3_algorithm(path) == "ppo":
            from stable_baselines3 import PPO as Algorithm
        else:
            from stable_baselines3 import SAC as Algorithm
        model = Algorithm.load(path, device="cpu")
        if model.observation_space != observation_space:
            raise ValueError(f"{path} was trained on observations {model.observation_space}, but the env gives "
                             f"{observation_space} (another tactile image size?)")
        if model.action_space != action_space:
            raise ValueError(f"{path} was trained with actions {model.action_space}, the env takes {action_space}")
        return cls(model, f"{type(model).__name__.lower()}:{path}")

    def reset(self) -> None:
        """Nothing to forget: the policy is feed-forward."""

    def __call__(self, observation: dict) -> np.ndarray:
        action, _ = self.model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32).reshape(4)


__all__ = ["Controller", "EstimatingController", "SB3Controller", "as_action_scale", "sb3_algorithm"]
