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

A policy of ``simshear train rl`` is its run folder: the policy's pickle-free files ``model.pt`` (its network's
state dict) and ``model.json`` (what rebuilds it, with the ``.pt``'s sha256; :mod:`~simshear_gym.control.policy_files`)
beside ``config.json`` (the env settings it was trained with: :class:`PolicySettings`) and ``vecnormalize.json``
(SB3's ``VecNormalize`` statistics as JSON; a checkpoint's own ``rl_model_vecnormalize_<steps>_steps.json``).
:meth:`SB3Controller.load` loads them together, so the benchmark and the robot normalise the observation as training
did, and a residual policy adds its correction to the same servo law (:class:`ResidualServo`). A policy may be named
by any of its files, or by the SB3 ``.zip`` they were written beside: ``model.zip``, ``model.pt`` and ``model.json``
load the same policy, and nothing in them is unpickled. An SB3 ``.zip`` or ``vecnormalize.pkl`` without those files
(a run of an older version) is refused unless ``trust_pickle`` (a pickle runs whatever code it carries: only for
files you made yourself); ``simshear train export-policy --trust-pickle`` converts such a run once. A policy without
``config.json`` is the ``tactile`` observation, not normalised, not residual.

Stable-Baselines3 (and so torch) is imported only when a model is loaded, so importing this module stays cheap.
"""

from __future__ import annotations

import json
import re
import warnings
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simshear_gym.contract import (
    ESTIMATE_OBSERVATIONS,
    OBS_MODES,
    ActionScale,
    check_image_size,
    check_observation,
    filter_mean_from_estimate,
    servo_hints,
)
from simshear_gym.control.pi_law import PIGains, PILaw
from simshear_gym.control.policy_files import (
    PolicyFileError,
    has_policy_files,
    load_policy,
    policy_files,
    policy_path,
    read_description,
)
from simshear_gym.control.policy_files import load_normalizer as load_json_normalizer


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


class EstimateThenLaw:
    """What the image-driven controllers (servo, 6-DoF servo, edge, push) share: their ``estimator`` reads each
    ``tactile`` image, predicted forward by the move commanded since the last (the action times ``_scale``), and
    their ``law`` turns the estimate into the action; both restart at :meth:`reset`."""

    who = "the controller"
    """Names the controller in its errors."""
    _last_move: np.ndarray | None = None
    last_estimate: tuple[np.ndarray, np.ndarray] | None = None
    """(mean, std) of the last step's state estimate, for logging (None before the first): (4,) each for the servo
    controller, (6,) for the 6-DoF one, the edge and push controllers' ``state_names`` (3,)."""

    def reset(self) -> None:
        self.estimator.reset()
        self.law.reset()
        self._last_move = None
        self.last_estimate = None

    def _check_tactile(self, observation: dict) -> None:
        if "tactile" not in observation:
            raise ValueError(f"{self.who} needs the observation's 'tactile' image; got {sorted(observation)}")

    def _estimate(self, observation: dict) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std) of the estimator on the observation's image (checked), fed the move commanded last."""
        self._check_tactile(observation)
        return self.estimator(observation["tactile"], self._last_move)

    def _command(self, action: np.ndarray) -> np.ndarray:
        """``action``, remembered as the move commanded (for the next estimate's prediction)."""
        self._last_move = action.astype(np.float64) * self._scale
        return action


def estimator_for_env(env, estimator: Any, shipped: bool = True, process: bool = True) -> Any:
    """``estimator`` (an :class:`~simshear_gym.control.estimator.EstimatorConfig`) with what it leaves open (None)
    from the env's :class:`~simshear_gym.contract.ServoHints` (wrappers looked through): the GDNN, a sensor's own
    ``.pt`` (with ``shipped``, also a shipped one by its name) and, with ``process``, the process noise."""
    if not (process or estimator.posenet is None):
        return estimator
    hints = servo_hints(env)
    if estimator.posenet is None and (shipped or hints.posenet.endswith(".pt")):
        from simshear_gym.models.zoo import posenet_weights

        name = hints.posenet  # a shipped GDNN's name, or a sensor's weights
        estimator = replace(estimator, posenet=name if name.endswith(".pt") else str(posenet_weights(name)))
    if process and estimator.process_std_mm is None and hints.process_std_mm is not None:
        estimator = replace(estimator, process_std_mm=hints.process_std_mm)
    return estimator


def as_action_scale(action_scale: Any, owner: str) -> ActionScale:
    """The :class:`~simshear_gym.contract.ActionScale` a controller takes, checked (``owner`` names the caller)."""
    if not isinstance(action_scale, ActionScale):
        raise TypeError(f"{owner}: action_scale must be an ActionScale (e.g. the env's action_scale), got "
                        f"{action_scale!r}")
    return action_scale


# ----------------------------------------------------------------------------------------------------------------
# Stable-Baselines3 models


def sb3_algorithm(path: str | Path) -> str:
    """``"ppo"``, ``"sac"`` or ``"tqc"`` (sb3-contrib): which algorithm made a policy (its ``<stem>.json``, else the
    SB3 ``.zip``'s ``data`` entry, read as JSON: nothing unpickled).

    Raises:
        ValueError: not a policy of simshear train rl, or none of PPO, SAC, TQC.
    """
    if has_policy_files(path):
        return read_description(path)["algorithm"]
    if Path(path).suffix in (".pt", ".json"):
        description, weights = policy_files(path)
        missing = weights if description.is_file() else description
        raise FileNotFoundError(f"{missing}: missing; a policy is <stem>.pt with its <stem>.json")
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as error:
        raise ValueError(f"{path} is not a Stable-Baselines3 model .zip (no readable 'data' entry): {error}") from None
    # The zip names the policy class, not the algorithm; the saved hyper-parameters tell PPO and SAC apart.
    if "clip_range" in data:
        return "ppo"
    if "top_quantiles_to_drop_per_net" in data:
        return "tqc"
    if "target_entropy" in data:
        return "sac"
    raise ValueError(f"{path}: not a PPO, SAC or TQC model of stable_baselines3 / sb3-contrib (saved keys: "
                     f"{sorted(data)[:12]}...)")


RUN_CONFIG = "config.json"
VECNORMALIZE = "vecnormalize.json"
VECNORMALIZE_PICKLE = "vecnormalize.pkl"  # SB3's own format (older runs): loaded only when trusted


@dataclass(frozen=True)
class ResidualSettings:
    """A residual policy: ``action = clip(servo law(filter mean) + bound * policy action, -1, 1)``.

    Attributes:
        bound: the largest correction, in full-scale actions (0 < bound <= 1).
        kp, ki, integral_limit: the servo law's gains (:class:`~simshear_gym.control.pi_law.PIGains`; training
            writes the servo controller's ``SERVO_GAINS``).
    """

    bound: float
    kp: tuple[float, float, float, float]
    ki: tuple[float, float, float, float]
    integral_limit: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.bound <= 1.0:
            raise ValueError(f"ResidualSettings.bound must be in (0, 1] full-scale actions, got {self.bound!r}")
        object.__setattr__(self, "kp", tuple(float(v) for v in self.kp))
        object.__setattr__(self, "ki", tuple(float(v) for v in self.ki))
        self.gains()  # validates

    def gains(self) -> PIGains:
        return PIGains(kp=self.kp, ki=self.ki, integral_limit=self.integral_limit)


@dataclass(frozen=True)
class PolicySettings:
    """The env settings a policy was trained with (from its run's ``config.json``); the env that runs it must
    give the same observation.

    Attributes:
        observation, history: the observation (:func:`~simshear_gym.contract.observation_space`).
        obs_mode: the image source it was trained on (``real``: translated, ``sim``).
        image_size_px: the tactile image size.
        task: ``tracking``, ``colift``, ``edge`` or ``push`` (the env it was trained in).
        residual: None, or the residual law it corrects.
    """

    observation: str = "tactile"
    history: int = 1
    obs_mode: str = "real"
    image_size_px: int = 128
    task: str = "tracking"
    residual: ResidualSettings | None = field(default=None)

    def __post_init__(self) -> None:
        check_observation(self.observation, self.history, "PolicySettings")
        check_image_size(self.image_size_px, "PolicySettings.image_size_px")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"PolicySettings.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")
        if self.residual is not None and self.observation not in ESTIMATE_OBSERVATIONS:
            raise ValueError("a residual policy corrects the servo law on the filter's estimate: it needs an "
                             f"observation with the estimate, got {self.observation!r}")

    @classmethod
    def from_run_config(cls, config: dict) -> PolicySettings:
        """From a ``simshear train rl`` run's ``config.json`` (older runs: their ``obs_mode`` and image size)."""
        bound = float(config.get("residual_bound", 0.0) or 0.0)
        residual = None
        if bound > 0:
            gains = config.get("residual_gains") or {}
            residual = ResidualSettings(bound=bound, **gains)
        return cls(observation=config.get("observation", "tactile"), history=int(config.get("history", 1)),
                   obs_mode=config.get("obs_mode", "real"), image_size_px=int(config.get("image_size_px", 128)),
                   task=config.get("task", "tracking"), residual=residual)

    @classmethod
    def of_model(cls, path: str | Path) -> PolicySettings | None:
        """The settings in the run folder of a model ``.zip`` (its ``config.json``), or None for a bare zip."""
        folder = Path(path).parent
        config = folder / RUN_CONFIG
        if not config.is_file() and folder.name == "checkpoints":  # a checkpoint: the run folder's settings
            config = folder.parent / RUN_CONFIG
        if not config.is_file():
            return None
        return cls.from_run_config(json.loads(config.read_text()))

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``gym.make`` for a sim env giving this observation; an estimate observation also
        needs ``estimator=`` (:func:`simshear_gym.control.env_estimator.env_kwargs` adds it)."""
        return {"obs_mode": self.obs_mode, "image_size_px": self.image_size_px, "observation": self.observation,
                "history": self.history}


class ResidualServo:
    """The servo law plus a policy's bounded correction: ``clip(law(filter mean) + bound * correction, -1, 1)``,
    the filter mean read from the newest frame of the observation's ``estimate``
    (:func:`~simshear_gym.contract.filter_mean_from_estimate`). One object per episode stream: :meth:`reset` at
    each episode start (the law's integral). Training's residual wrapper and :class:`SB3Controller` share it.
    """

    def __init__(self, settings: ResidualSettings, reference_depth_mm: float, action_scale: ActionScale) -> None:
        self.settings = settings
        self.reference_depth_mm = float(reference_depth_mm)
        self.law = PILaw(reference_depth_mm, as_action_scale(action_scale, "ResidualServo").as_array(),
                         settings.gains())

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict, correction: np.ndarray) -> np.ndarray:
        if "estimate" not in observation:
            raise ValueError(f"a residual policy needs the observation's 'estimate'; got {sorted(observation)}")
        base = self.law(filter_mean_from_estimate(observation["estimate"], self.reference_depth_mm))
        correction = np.clip(np.asarray(correction, dtype=np.float64).reshape(4), -1.0, 1.0)
        return np.clip(base + self.settings.bound * correction, -1.0, 1.0).astype(np.float32)


def vecnormalize_path(model_path: str | Path, suffix: str = ".json") -> Path | None:
    """The ``VecNormalize`` statistics saved with a model, or None: a checkpoint ``rl_model_<N>_steps``'s
    ``rl_model_vecnormalize_<N>_steps.json``; ``best_model``'s ``best_model_vecnormalize.json``; else (and for
    ``model``) the folder's ``vecnormalize.json``. ``suffix=".pkl"``: the pickles SB3 itself writes."""
    path = Path(model_path)
    name = f"vecnormalize{suffix}"
    match = re.fullmatch(r"(.*)_(\d+)_steps", path.stem)
    candidates = []
    if match:
        candidates.append(path.parent / f"{match.group(1)}_vecnormalize_{match.group(2)}_steps{suffix}")
    elif path.stem != "model":
        candidates.append(path.parent / f"{path.stem}_{name}")
    if not match:
        candidates.append(path.parent / name)
    return next((candidate for candidate in candidates if candidate.is_file()), None)


def load_normalizer(path: str | Path, trust_pickle: bool = False):
    """Observation statistics in evaluation mode (``normalize_obs`` is all a controller calls): a
    ``vecnormalize.json`` (:class:`~simshear_gym.control.policy_files.ObservationNormalizer`), or with
    ``trust_pickle`` SB3's pickled ``VecNormalize`` (a pickle runs code: only your own files).

    Raises:
        PolicyFileError: a pickle without ``trust_pickle``, or a malformed file.
    """
    path = Path(path)
    if path.suffix != ".pkl":
        return load_json_normalizer(path)
    if not trust_pickle:
        raise PolicyFileError(f"{path}: a pickle, which runs whatever code it carries when loaded; refused. Use "
                              f"the pickle-free {path.with_suffix('.json').name} (simshear train export-policy "
                              "--trust-pickle converts a run of your own once)")
    import pickle

    with open(path, "rb") as handle:
        normalizer = pickle.load(handle)  # noqa: S301 - trusted by the caller
    normalizer.training = False
    normalizer.norm_reward = False
    return normalizer


def stale_estimator_models(path: str | Path) -> list[str]:
    """The models that made a shipped policy's observations at export (its ``config.json`` provenance) and have
    been replaced since (another sha256 now, or gone): the policy sees other observations than it was trained on.
    [] for a run folder without that record."""
    from simshear_gym.io import file_sha256
    from simshear_gym.models.zoo import estimator_file

    config = Path(path).parent / RUN_CONFIG
    if not config.is_file():
        return []
    recorded = (json.loads(config.read_text()).get("provenance") or {}).get("estimator_models_sha256") or {}
    stale = []
    for name, digest in recorded.items():
        current = estimator_file(name)
        if not current.is_file() or file_sha256(current) != digest:
            stale.append(name)
    return stale


def sb3_class(algorithm: str):
    """The SB3 class of ``"ppo"``, ``"sac"`` or ``"tqc"`` (from sb3-contrib: an optional dependency)."""
    if algorithm == "tqc":
        try:
            from sb3_contrib import TQC
        except ImportError:
            raise ValueError("TQC is sb3-contrib's: pip install sb3-contrib") from None
        return TQC
    import stable_baselines3

    if algorithm not in ("ppo", "sac"):
        raise ValueError(f"algorithm must be one of ('ppo', 'sac', 'tqc'), got {algorithm!r}")
    return getattr(stable_baselines3, algorithm.upper())


class SB3Controller:
    """A Stable-Baselines3 model as a :class:`Controller`: deterministic ``predict`` on the observation normalised
    as in training, plus the servo law for a residual policy; no state between episodes but the residual law's
    integral (a recurrent policy is not supported).

    Args:
        model: anything with SB3's ``predict(observation, deterministic=True) -> (action, state)``.
        name: for logs; :meth:`load` gives ``"<algorithm>:<path>"``.
        normalizer: anything with ``normalize_obs(observation) -> observation`` (SB3's ``VecNormalize``), or None.
        residual: a :class:`ResidualServo` the policy's action corrects, or None (the action is the policy's).
        settings: the env settings it was trained with, for logs (None: unknown).
    """

    def __init__(self, model, name: str = "sb3", normalizer=None, residual: ResidualServo | None = None,
                 settings: PolicySettings | None = None) -> None:
        self.model = model
        self.name = name
        self.normalizer = normalizer
        self.residual = residual
        self.settings = settings
        # an asymmetric actor-critic's critic-only keys (control.asymmetric): zeros, which its actor reads anyway
        keys = getattr(getattr(model, "policy", None), "privileged_keys", ())
        self.privileged = {key: np.zeros(model.observation_space[key].shape, model.observation_space[key].dtype)
                           for key in keys}

    @classmethod
    def load(cls, path: str | Path, observation_space, action_space, reference_depth_mm: float = 4.0,
             action_scale: ActionScale = ActionScale(), trust_pickle: bool = False) -> SB3Controller:
        """Load a PPO/SAC/TQC policy on the CPU with its run's ``VecNormalize`` statistics and settings, and check
        that it was trained on these spaces (the env's). ``path``: any of the policy's pickle-free files (or the
        SB3 ``.zip`` they lie beside), or its folder (a shipped one, or its zoo folder with ``model.safetensors``);
        ``trust_pickle``: an SB3 ``.zip`` / ``.pkl`` without them is loaded by unpickling (only files you made: a
        pickle runs code). ``reference_depth_mm`` and ``action_scale`` (the env's) are the residual law's, for a
        residual policy.

        Raises:
            FileNotFoundError: no such policy.
            ValueError: not a policy of PPO/SAC/TQC, a pickle without ``trust_pickle``
                (:class:`~simshear_gym.control.policy_files.PolicyFileError`), a corrupt file, or trained for other
                observation/action spaces.
        """
        path = policy_path(path)  # a policy folder: its model.json
        if has_policy_files(path):
            model = load_policy(path)
        elif path.suffix == ".zip" and path.is_file():
            if not trust_pickle:
                description, weights = policy_files(path)
                raise PolicyFileError(
                    f"{path}: a Stable-Baselines3 .zip without its pickle-free {weights.name} and "
                    f"{description.name}; loading the .zip unpickles objects that can run code, so it is refused. "
                    "Convert a run of your own once with simshear train export-policy --trust-pickle")
            model = sb3_class(sb3_algorithm(path)).load(path, device="cpu")
        else:
            raise FileNotFoundError(f"no policy at {str(path)!r}: expected <stem>.pt with its <stem>.json (or the "
                                    "SB3 .zip they were written beside)")
        settings = PolicySettings.of_model(path)
        trained = (f" ({settings.observation} observation, history {settings.history}, {settings.image_size_px} px)"
                   if settings else "")
        privileged = getattr(model.policy, "privileged_keys", ())  # the critic's alone: not the env's to give
        seen = model.observation_space
        if privileged:
            from gymnasium import spaces

            seen = spaces.Dict({key: space for key, space in seen.spaces.items() if key not in privileged})
        if seen != observation_space:
            raise ValueError(f"{path} was trained on observations {seen}{trained}, but the env "
                             f"gives {observation_space} (another observation or tactile image size?)")
        if model.action_space != action_space:
            raise ValueError(f"{path} was trained with actions {model.action_space}, the env takes {action_space}")
        normalizer = None
        if settings is not None:
            stats = vecnormalize_path(path)
            pickled = vecnormalize_path(path, ".pkl")
            if stats is not None:
                normalizer = load_normalizer(stats)
            elif pickled is not None:
                normalizer = load_normalizer(pickled, trust_pickle)
        residual = None
        if settings is not None and settings.residual is not None:
            residual = ResidualServo(settings.residual, reference_depth_mm, action_scale)
        stale = stale_estimator_models(path)
        if stale:
            warnings.warn(f"{path} was trained on observations made by other weights than the shipped {stale} "
                          "(their sha256 at export, in its config.json, differs): it sees other images or "
                          "estimates than in training; train it again", UserWarning, stacklevel=2)
        algorithm = getattr(model, "algorithm", type(model).__name__.lower())
        return cls(model, f"{algorithm}:{path}", normalizer, residual, settings)

    @classmethod
    def for_env(cls, path: str | Path, env, trust_pickle: bool = False) -> SB3Controller:
        """:meth:`load` for an env (a sim env or ``RealTactileEnv``; wrappers are looked through): its spaces,
        reference depth and action scale."""
        base = getattr(env, "unwrapped", env)
        return cls.load(path, env.observation_space, env.action_space, base.reference_depth_mm, base.action_scale,
                        trust_pickle)

    def reset(self) -> None:
        """Start an episode: the residual law forgets its integral; the policy itself is feed-forward."""
        if self.residual is not None:
            self.residual.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        seen = {**observation, **self.privileged} if self.privileged else observation
        seen = self.normalizer.normalize_obs(seen) if self.normalizer is not None else seen
        action, _ = self.model.predict(seen, deterministic=True)
        action = np.asarray(action, dtype=np.float32).reshape(4)
        if self.residual is not None:
            action = self.residual(observation, action)
        return action


__all__ = ["Controller", "EstimateThenLaw", "EstimatingController", "PolicySettings", "ResidualServo",
           "ResidualSettings", "SB3Controller", "as_action_scale", "estimator_for_env", "load_normalizer",
           "sb3_algorithm", "sb3_class", "stale_estimator_models", "vecnormalize_path"]
