"""SB3's ``VecEnv`` API over a gymnasium vector env with SAME_STEP autoreset: how ``simshear train rl --vec batched``
trains on :class:`simshear_gym.envs.vector.SimShearVectorEnv` (sub-envs in worker processes, their images
translated in one batch per worker and step) instead of one translation per sub-env and step.

SB3 wants, at the step that ends an episode, the reset observation, ``done`` and the episode's last observation in
``infos[i]["terminal_observation"]``; ``infos[i]["TimeLimit.truncated"]`` marks a step-limit end (SB3 bootstraps
its value). Gymnasium's SAME_STEP autoreset gives exactly that, in ``info["final_obs"]`` / ``info["final_info"]``.
Per-env infos are unbatched from gymnasium's ``{key: array, "_key": mask}`` form into SB3's list of dicts.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnv


def unbatch_infos(infos: dict, num_envs: int) -> list[dict]:
    """Gymnasium's vector info (``{key: batched value, "_key": mask}``, nested for dict values) -> one dict per
    sub-env holding the keys its mask sets."""
    per_env: list[dict] = [{} for _ in range(num_envs)]
    for key, value in infos.items():
        if key.startswith("_"):
            continue
        mask = infos.get(f"_{key}", np.ones(num_envs, dtype=bool))
        parts = unbatch_infos(value, num_envs) if isinstance(value, dict) else value
        for index in np.flatnonzero(mask):
            item = parts[index]
            per_env[index][key] = item.item() if isinstance(item, np.generic) else item
    return per_env


class SB3VectorEnv(VecEnv):
    """A gymnasium :class:`VectorEnv` with ``metadata["autoreset_mode"] == AutoresetMode.SAME_STEP`` as an SB3
    ``VecEnv`` (module docstring). ``get_attr`` / ``set_attr`` / ``env_method`` reach the vector env itself (its
    sub-envs may live in other processes): every sub-env gets the vector env's value."""

    def __init__(self, vector_env: VectorEnv) -> None:
        mode = vector_env.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise ValueError(f"SB3VectorEnv needs a vector env with autoreset_mode SAME_STEP (SB3 resets a sub-env in "
                             f"the step that ends its episode), got {mode!r}")
        self.vector_env = vector_env
        super().__init__(vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self):
        seeds = None if all(seed is None for seed in self._seeds) else list(self._seeds)
        options = self._options[0] if any(self._options) else None
        observations, infos = self.vector_env.reset(seed=seeds, options=options)
        self.reset_infos = unbatch_infos(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        observations, rewards, terminated, truncated, infos = self.vector_env.step(self._actions)
        self._actions = None
        per_env = unbatch_infos({key: value for key, value in infos.items()
                                 if key not in ("final_obs", "_final_obs", "final_info", "_final_info")},
                                self.num_envs)
        final_infos = unbatch_infos(infos["final_info"], self.num_envs) if "final_info" in infos else None
        dones = np.logical_or(terminated, truncated)
        for index in np.flatnonzero(dones):
            info = {**final_infos[index]} if final_infos is not None else {}
            info["terminal_observation"] = infos["final_obs"][index]
            info["TimeLimit.truncated"] = bool(truncated[index] and not terminated[index])
            self.reset_infos[index] = per_env[index]
            per_env[index] = info
        return observations, np.asarray(rewards, dtype=np.float32), dones, per_env

    def close(self) -> None:
        self.vector_env.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = getattr(self.vector_env, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.vector_env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = getattr(self.vector_env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)
