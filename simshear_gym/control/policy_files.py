"""Pickle-free policy files: a policy is its network's state dict plus JSON, so loading one runs no code from it.

A Stable-Baselines3 ``.zip`` holds cloudpickled objects (the spaces, the policy class, schedules) and its
``VecNormalize`` statistics are a pickle: loading either can run whatever code a crafted file carries. Here a
policy ``<stem>`` is two files:

- ``<stem>.pt``: the policy network's ``state_dict`` (tensors only: read with ``torch.load(weights_only=True)``;
  ``<stem>.safetensors`` instead in a zoo folder, ``simshear ship zoo``);
- ``<stem>.json``: :data:`POLICY_FORMAT`, the algorithm (``ppo``, ``sac``, ``tqc``), the policy class (one of
  :data:`POLICY_CLASSES`, by name), its constructor arguments (spaces as plain tables, classes by allowlisted name,
  :data:`ALLOWED_CLASSES`) and the sha256 of the ``.pt``, checked at load.

Its observation statistics are ``vecnormalize.json`` (:data:`NORMALIZER_FORMAT`: per normalised key the running mean,
variance and count, the clip and epsilon), read into an :class:`ObservationNormalizer` that normalises exactly as
SB3's ``VecNormalize.normalize_obs`` does. JSON keeps every float64 exactly (shortest round-trip repr), so a
converted policy acts as the pickled one did, bit for bit.

:func:`save_policy` / :func:`save_normalizer` write them from a live SB3 model / ``VecNormalize``;
:func:`load_policy` / :func:`load_normalizer` read them. A bad file is a :class:`PolicyFileError` (a ValueError)
naming the file and what was expected. torch and Stable-Baselines3 are imported only when a policy is loaded or
saved.
"""

from __future__ import annotations

import importlib
import json
import os
from copy import deepcopy
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.io import atomic_write, file_sha256, write_json

POLICY_FORMAT = "simshear-policy/1"
NORMALIZER_FORMAT = "simshear-vecnormalize/1"
ALGORITHMS = ("ppo", "sac", "tqc")
POLICY_CLASSES: frozenset[str] = frozenset({
    "stable_baselines3.common.policies.ActorCriticPolicy",
    "stable_baselines3.common.policies.ActorCriticCnnPolicy",
    "stable_baselines3.common.policies.MultiInputActorCriticPolicy",
    "stable_baselines3.sac.policies.SACPolicy",
    "stable_baselines3.sac.policies.CnnPolicy",
    "stable_baselines3.sac.policies.MultiInputPolicy",
    "sb3_contrib.tqc.policies.TQCPolicy",
    "sb3_contrib.tqc.policies.CnnPolicy",
    "sb3_contrib.tqc.policies.MultiInputPolicy",
    "simshear_gym.control.asymmetric.AsymmetricActorCriticPolicy",
})
"""The policy classes a policy file may name (module and class name)."""
ALLOWED_CLASSES: frozenset[str] = frozenset({
    *(f"torch.nn.modules.activation.{name}" for name in ("Tanh", "ReLU", "ELU", "LeakyReLU", "GELU", "SiLU",
                                                         "Sigmoid", "Softplus", "Mish")),
    *(f"torch.optim.{module}.{name}" for module, name in (("adam", "Adam"), ("adamw", "AdamW"),
                                                          ("rmsprop", "RMSprop"), ("sgd", "SGD"))),
    "stable_baselines3.common.torch_layers.CombinedExtractor",
    "stable_baselines3.common.torch_layers.FlattenExtractor",
    "stable_baselines3.common.torch_layers.NatureCNN",
    "stable_baselines3.common.sb2_compat.rmsprop_tf_like.RMSpropTFLike",
    "simshear_gym.control.asymmetric.MaskedCombinedExtractor",
})
"""The classes a policy's constructor arguments may name (activations, optimisers, feature extractors)."""


class PolicyFileError(ValueError):
    """A policy or statistics file that cannot be loaded; the message names the file and what was expected."""


SAFETENSORS_SUFFIX = ".safetensors"
FOLDER_MODEL = "model.json"
"""The description of the policy in a policy folder (a shipped one, its zoo folder, a run's final model)."""


def policy_path(path: str | os.PathLike) -> Path:
    """A policy named by its folder: the folder's ``model.json``; any other name as it is."""
    path = Path(path)
    return path / FOLDER_MODEL if path.is_dir() else path


def policy_files(path: str | os.PathLike) -> tuple[Path, Path]:
    """The pickle-free files of a policy given by any of its names (``<stem>.json``, ``<stem>.pt`` or the SB3
    ``<stem>.zip`` they were written beside, or a policy folder, :func:`policy_path`): (``<stem>.json``,
    ``<stem>.pt``); named other than by its ``.pt``, ``<stem>.safetensors`` for the weights where that lies there
    instead (a zoo folder)."""
    path = policy_path(path)
    weights = path.with_suffix(".pt")
    if path.suffix != ".pt" and not weights.is_file() and path.with_suffix(SAFETENSORS_SUFFIX).is_file():
        weights = path.with_suffix(SAFETENSORS_SUFFIX)
    return path.with_suffix(".json"), weights


def has_policy_files(path: str | os.PathLike) -> bool:
    """Whether the pickle-free files of a policy (:func:`policy_files`) are there."""
    description, weights = policy_files(path)
    return description.is_file() and weights.is_file()


# ----------------------------------------------------------------------------------------------------------------
# JSON encoding of constructor arguments


def class_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def resolve_class(name: Any, allowed: frozenset[str], source: Path) -> type:
    """The class an allowlisted ``module.Class`` name names (nothing else is imported)."""
    if not isinstance(name, str) or name not in allowed:
        raise PolicyFileError(f"{source}: class {name!r} is not one a policy file may name; expected one of "
                              f"{sorted(allowed)}")
    module, _, attribute = name.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as error:
        raise PolicyFileError(f"{source}: class {name!r} cannot be imported here ({error})") from None


def encode(value: Any) -> Any:
    """A constructor argument as JSON: spaces as tables, allowlisted classes by name, tuples marked."""
    from gymnasium import spaces

    if isinstance(value, spaces.Dict):
        return {"__space__": "Dict", "spaces": {key: encode(space) for key, space in value.spaces.items()}}
    if isinstance(value, spaces.Box):
        low, high = np.asarray(value.low, np.float64), np.asarray(value.high, np.float64)
        same = low.size and np.all(low == low.flat[0]) and np.all(high == high.flat[0])
        return {"__space__": "Box", "shape": list(value.shape), "dtype": str(value.dtype),
                "low": float(low.flat[0]) if same else low.tolist(),
                "high": float(high.flat[0]) if same else high.tolist()}
    if isinstance(value, spaces.Discrete):
        return {"__space__": "Discrete", "n": int(value.n), "start": int(value.start)}
    if isinstance(value, type):
        name = class_name(value)
        if name not in ALLOWED_CLASSES | POLICY_CLASSES:
            raise ValueError(f"class {name} is not allowlisted for policy files (ALLOWED_CLASSES)")
        return {"__class__": name}
    if isinstance(value, tuple):
        return {"__tuple__": [encode(item) for item in value]}
    if isinstance(value, list):
        return [encode(item) for item in value]
    if isinstance(value, dict):
        if not all(isinstance(key, str) for key in value):
            raise ValueError(f"policy constructor argument with non-string keys: {value!r}")
        return {key: encode(item) for key, item in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise ValueError(f"policy constructor argument of type {type(value).__name__} cannot be stored as JSON: "
                     f"{value!r}")


def decode(value: Any, source: Path) -> Any:
    """The inverse of :func:`encode`."""
    if isinstance(value, list):
        return [decode(item, source) for item in value]
    if not isinstance(value, dict):
        return value
    if "__space__" in value:
        return _decode_space(value, source)
    if "__class__" in value:
        return resolve_class(value["__class__"], ALLOWED_CLASSES, source)
    if "__tuple__" in value:
        return tuple(decode(item, source) for item in value["__tuple__"])
    return {key: decode(item, source) for key, item in value.items()}


def _decode_space(table: dict, source: Path):
    from gymnasium import spaces

    try:
        kind = table["__space__"]
        if kind == "Dict":
            return spaces.Dict({key: _decode_space(item, source) for key, item in table["spaces"].items()})
        if kind == "Box":
            dtype = np.dtype(table["dtype"])
            shape = tuple(int(n) for n in table["shape"])
            low = np.asarray(table["low"], np.float64).astype(dtype)
            high = np.asarray(table["high"], np.float64).astype(dtype)
            return spaces.Box(low=low if low.ndim else low.item(), high=high if high.ndim else high.item(),
                              shape=shape, dtype=dtype)
        if kind == "Discrete":
            return spaces.Discrete(int(table["n"]), start=int(table.get("start", 0)))
    except (KeyError, TypeError, ValueError) as error:
        raise PolicyFileError(f"{source}: a space {table!r} is malformed ({error})") from None
    raise PolicyFileError(f"{source}: unknown space {kind!r}; expected Dict, Box or Discrete")


# ----------------------------------------------------------------------------------------------------------------
# the policy


def algorithm_of(model) -> str:
    name = type(model).__name__.lower()
    if name not in ALGORITHMS:
        raise ValueError(f"a policy file holds a PPO, SAC or TQC agent, got {type(model).__name__}")
    return name


def save_policy(model, path: str | os.PathLike) -> Path:
    """Write an SB3 agent's policy as ``<stem>.pt`` + ``<stem>.json`` (:func:`policy_files` of ``path``), each
    atomically, the state dict first; returns the ``.json``."""
    import torch

    description, weights = policy_files(policy_path(path).with_suffix(".pt"))
    policy = model.policy
    arguments = {key: value for key, value in policy._get_constructor_parameters().items() if key != "lr_schedule"}
    state = {key: value.detach().cpu().clone() for key, value in policy.state_dict().items()}
    atomic_write(weights, lambda tmp: torch.save(state, tmp))
    write_json(description, {"format": POLICY_FORMAT, "algorithm": algorithm_of(model),
                             "policy_class": class_name(type(policy)), "constructor": encode(arguments),
                             "weights": weights.name, "weights_sha256": file_sha256(weights)})
    return description


def read_description(path: str | os.PathLike) -> dict:
    """A policy's ``<stem>.json``, checked for its format and algorithm (no torch import)."""
    description, _ = policy_files(path)
    table = _read_json(description, POLICY_FORMAT, "policy description")
    if table.get("algorithm") not in ALGORITHMS:
        raise PolicyFileError(f"{description}: algorithm {table.get('algorithm')!r}; expected one of {ALGORITHMS}")
    return table


class LoadedPolicy:
    """A policy read from its pickle-free files: what :class:`~simshear_gym.control.policy.SB3Controller` needs
    of an SB3 agent (``predict``, ``policy``, ``observation_space``, ``action_space``) and ``algorithm``."""

    def __init__(self, policy, algorithm: str) -> None:
        self.policy = policy
        self.algorithm = algorithm
        self.observation_space = policy.observation_space
        self.action_space = policy.action_space

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        """SB3's ``predict``: the same call an agent's makes (``BaseAlgorithm.predict`` is its policy's)."""
        return self.policy.predict(observation, state, episode_start, deterministic)


def _no_schedule(_progress: float) -> float:
    return 0.0  # a loaded policy is not trained: its optimiser's learning rate is never used


def load_policy(path: str | os.PathLike) -> LoadedPolicy:
    """Read a policy from ``<stem>.json`` + ``<stem>.pt`` on the CPU without unpickling anything.

    Raises:
        FileNotFoundError: either file missing.
        PolicyFileError: a malformed description, a class outside the allowlists, a ``.pt`` whose sha256 differs
            from the recorded one (a corrupt or replaced file), or weights of another network.
    """
    import torch

    description_path, weights = policy_files(path)
    description = read_description(description_path)
    if not weights.is_file():
        raise FileNotFoundError(f"{weights}: missing; the policy {description_path} names it")
    digest = file_sha256(weights)
    recorded = str(description.get("weights_sha256"))
    if digest != recorded:
        raise PolicyFileError(f"{weights}: sha256 {digest[:12]}... differs from the {recorded[:12]}... recorded in "
                              f"{description_path.name}: a corrupt or replaced weights file")
    cls = resolve_class(description.get("policy_class"), POLICY_CLASSES, description_path)
    arguments = decode(description.get("constructor", {}), description_path)
    if not isinstance(arguments, dict):
        raise PolicyFileError(f"{description_path}: 'constructor' must be a table of arguments")
    state = load_weights(weights, "policy")
    try:
        policy = cls(lr_schedule=_no_schedule, **arguments)
        policy.load_state_dict(state)
    except (TypeError, ValueError, KeyError, RuntimeError, AssertionError) as error:
        reason = " ".join(str(error).split())[:300]
        raise PolicyFileError(f"{weights}: not the weights of the policy {description_path.name} describes "
                              f"({reason})") from None
    policy.set_training_mode(False)
    return LoadedPolicy(policy.to(torch.device("cpu")), description["algorithm"])


def load_weights(path: Path, what: str) -> dict:
    """A ``torch.save``d table of tensors read with ``weights_only=True``, or a ``.safetensors`` file (a file that
    would run code, or that is no such file at all, is a :class:`PolicyFileError` naming it)."""
    import torch

    try:
        if Path(path).suffix == SAFETENSORS_SUFFIX:
            from safetensors.torch import load_file

            state = load_file(path, device="cpu")
        else:
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises RuntimeError, UnpicklingError, EOFError...
        reason = " ".join(str(error).split())[:200]
        raise PolicyFileError(f"{path}: not a {what} weights file of tensors that loads without running code "
                              f"({type(error).__name__}: {reason})") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise PolicyFileError(f"{path}: expected a table of tensors (a state dict), got {type(state).__name__}")
    return state


# ----------------------------------------------------------------------------------------------------------------
# observation statistics


def save_normalizer(vec_normalize, path: str | os.PathLike) -> Path:
    """Write a ``VecNormalize``'s statistics and settings as JSON, atomically."""

    def stats(rms) -> dict:
        return {"mean": np.asarray(rms.mean, np.float64).tolist(), "var": np.asarray(rms.var, np.float64).tolist(),
                "count": float(rms.count), "shape": list(np.shape(rms.mean))}

    obs_rms = vec_normalize.obs_rms
    return write_json(path, {
        "format": NORMALIZER_FORMAT, "norm_obs": bool(vec_normalize.norm_obs),
        "norm_reward": bool(vec_normalize.norm_reward),
        "norm_obs_keys": list(vec_normalize.norm_obs_keys) if vec_normalize.norm_obs_keys is not None else None,
        "clip_obs": float(vec_normalize.clip_obs), "clip_reward": float(vec_normalize.clip_reward),
        "gamma": float(vec_normalize.gamma), "epsilon": float(vec_normalize.epsilon),
        "obs_rms": ({key: stats(rms) for key, rms in obs_rms.items()} if isinstance(obs_rms, dict)
                    else stats(obs_rms)),
        "ret_rms": stats(vec_normalize.ret_rms)})


class ObservationNormalizer:
    """``VecNormalize.normalize_obs`` from its statistics alone: ``clip((obs - mean) / sqrt(var + epsilon),
    -clip_obs, clip_obs)`` as float32 for each normalised key (or the whole observation), the rest untouched."""

    def __init__(self, table: dict, source: Path) -> None:
        try:
            self.norm_obs = bool(table["norm_obs"])
            self.norm_obs_keys = table.get("norm_obs_keys")
            self.clip_obs = float(table["clip_obs"])
            self.epsilon = float(table["epsilon"])
            rms = table["obs_rms"]
            if "mean" in rms:
                self.obs_rms = self._stats(rms)
            else:
                self.obs_rms = {key: self._stats(value) for key, value in rms.items()}
            self.table = table
        except (KeyError, TypeError, ValueError) as error:
            raise PolicyFileError(f"{source}: not the observation statistics of {NORMALIZER_FORMAT} ({error})") \
                from None
        if isinstance(self.obs_rms, dict) and self.norm_obs and set(self.norm_obs_keys or ()) - set(self.obs_rms):
            raise PolicyFileError(f"{source}: norm_obs_keys {self.norm_obs_keys} without statistics")
        finite = all(np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()
                     for mean, var in (self.obs_rms.values() if isinstance(self.obs_rms, dict) else [self.obs_rms]))
        if not finite or not np.isfinite(self.clip_obs) or not self.epsilon > 0:
            raise PolicyFileError(f"{source}: statistics must be finite (variances >= 0, epsilon > 0)")

    @staticmethod
    def _stats(rms: dict) -> tuple[np.ndarray, np.ndarray]:
        shape = tuple(rms.get("shape", np.shape(rms["mean"])))
        mean = np.asarray(rms["mean"], np.float64).reshape(shape)
        var = np.asarray(rms["var"], np.float64).reshape(shape)
        return mean, var

    def _normalize(self, obs: np.ndarray, stats: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        mean, var = stats
        return np.clip((obs - mean) / np.sqrt(var + self.epsilon), -self.clip_obs, self.clip_obs)

    def normalize_obs(self, obs):
        obs_ = deepcopy(obs)
        if self.norm_obs:
            if isinstance(obs, dict) and isinstance(self.obs_rms, dict):
                for key in self.norm_obs_keys or ():
                    obs_[key] = self._normalize(obs[key], self.obs_rms[key]).astype(np.float32)
            else:
                obs_ = self._normalize(obs, self.obs_rms).astype(np.float32)
        return obs_


def load_normalizer(path: str | os.PathLike) -> ObservationNormalizer:
    """An :class:`ObservationNormalizer` from a ``vecnormalize.json`` (no pickle)."""
    path = Path(path)
    return ObservationNormalizer(_read_json(path, NORMALIZER_FORMAT, "observation statistics"), path)


def restore_vec_normalize(vec_normalize, path: str | os.PathLike) -> None:
    """Set a live ``VecNormalize``'s running statistics from a ``vecnormalize.json`` (a resumed training)."""
    path = Path(path)
    table = _read_json(path, NORMALIZER_FORMAT, "observation statistics")
    try:
        rms = table["obs_rms"]
        targets = vec_normalize.obs_rms
        pairs = [(targets, rms)] if "mean" in rms else [(targets[key], rms[key]) for key in targets]
        for target, stats in pairs + [(vec_normalize.ret_rms, table["ret_rms"])]:
            target.mean = np.asarray(stats["mean"], np.float64).reshape(np.shape(target.mean))
            target.var = np.asarray(stats["var"], np.float64).reshape(np.shape(target.var))
            target.count = float(stats["count"])
    except (KeyError, TypeError, ValueError) as error:
        raise PolicyFileError(f"{path}: statistics do not match the env's observation ({error})") from None


def _read_json(path: Path, format_name: str, what: str) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing ({what})")
    try:
        table = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise PolicyFileError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(table, dict) or table.get("format") != format_name:
        found = table.get("format") if isinstance(table, dict) else type(table).__name__
        raise PolicyFileError(f"{path}: expected a {what} file of format {format_name!r}, got {found!r}")
    return table
