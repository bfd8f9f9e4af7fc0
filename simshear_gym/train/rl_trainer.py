"""The trainer of ``simshear train rl`` (:mod:`simshear_gym.train.rl`: the command and the run folder's layout;
:mod:`simshear_gym.train.rl_config`: its settings): the envs, VecNormalize, the agent, checkpoints, the wall-clock
budget and the periodic evaluation.

Every saved model (``model``, ``best_model``, the checkpoints ``rl_model_<N>_steps``) is SB3's ``.zip`` (what a
resumed run continues: optimiser state, counters) plus the policy's pickle-free ``<stem>.pt`` and ``<stem>.json``
(:mod:`~simshear_gym.control.policy_files`, what a controller loads) and its VecNormalize statistics as JSON; no
pickle is written. A resumed run reads the ``.zip`` without unpickling its cloudpickled entries (the spaces, the
policy class and the schedules are given from the run's settings instead: :func:`load_agent`) and the statistics
from their JSON."""

from __future__ import annotations

import inspect
import json
import os
import time
import zipfile
from dataclasses import asdict, fields
from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback

import simshear_gym.envs  # noqa: F401  (registers the envs: the evaluation envs live in this process)
from simshear_gym.contract import ESTIMATE_OBSERVATIONS
from simshear_gym.control.env_estimator import env_estimator
from simshear_gym.control.policy import (
    RUN_CONFIG,
    VECNORMALIZE,
    ResidualServo,
    ResidualSettings,
    SB3Controller,
    sb3_class,
    vecnormalize_path,
)
from simshear_gym.control.policy_files import restore_vec_normalize, save_normalizer, save_policy
from simshear_gym.control.servo import SERVO_GAINS
from simshear_gym.io import atomic_write, write_json
from simshear_gym.machine import machine_info
from simshear_gym.models.device import resolve_device
from simshear_gym.train.rl_config import RESUME_FREE, RLTrainConfig, ended_early, latest_checkpoint
from simshear_gym.train.runs import check_same_settings

TRACKING_EVAL = ("circle", "tilted_square", "spiral", "loop")
COLIFT_EVAL_TRAJECTORY = "circular_wave"
PUSH_EVAL_PATH_ANGLE_DEG = 15.0  # the nominal pushing episodes' path, off the first push's direction


def residual_settings(config: RLTrainConfig) -> ResidualSettings | None:
    """The residual law of a run (the servo controller's gains), or None."""
    if config.residual_bound <= 0:
        return None
    return ResidualSettings(bound=config.residual_bound, kp=SERVO_GAINS.kp, ki=SERVO_GAINS.ki,
                            integral_limit=SERVO_GAINS.integral_limit)


class ResidualAction(gym.Wrapper):
    """Residual RL: the agent's action in [-1, 1]^4 is a correction; the env receives
    :class:`~simshear_gym.control.policy.ResidualServo`'s ``clip(servo law + bound * correction)``, the same sum
    :class:`~simshear_gym.control.policy.SB3Controller` sends at deployment. ``info["applied_action"]``: what
    the env received."""

    def __init__(self, env: gym.Env, settings: ResidualSettings) -> None:
        super().__init__(env)
        base = env.unwrapped
        self.residual = ResidualServo(settings, base.reference_depth_mm, base.action_scale)
        self._observation: dict | None = None

    def reset(self, **kwargs):
        observation, info = self.env.reset(**kwargs)
        self.residual.reset()
        self._observation = observation
        return observation, info

    def step(self, action):
        applied = self.residual(self._observation, action)
        observation, reward, terminated, truncated, info = self.env.step(applied)
        self._observation = observation
        info["applied_action"] = applied
        return observation, reward, terminated, truncated, info


def env_settings(config: RLTrainConfig, rank: int, training: bool = True) -> dict:
    """``gym.make`` keyword arguments of training sub-env ``rank`` (``training``: with the critic's true state for
    an asymmetric critic; else as deployed)."""
    obs_mode = config.obs_mode
    if training and config.asymmetric_critic:
        obs_mode = {"real": "oracle_real", "sim": "oracle"}[config.obs_mode]
    task_kwargs = {"edge": {"outline": "random"}, "push": {"shape": "random"}}.get(config.task,
                                                                                 {"trajectory": "random"})
    kwargs = {**task_kwargs, "randomise": config.randomise, "obs_mode": obs_mode,
              "image_size_px": config.image_size_px, "observation": config.observation, "history": config.history}
    if config.observation in ESTIMATE_OBSERVATIONS:
        kwargs["estimator"] = env_estimator
    if config.task == "colift":
        from simshear_gym.envs.colift import OBJECT_NAMES

        kwargs["object_name"] = OBJECT_NAMES[rank % len(OBJECT_NAMES)]
    return kwargs


def make_env(config: RLTrainConfig, rank: int = 0, worker: bool = False, **overrides) -> gym.Env:
    """Training sub-env ``rank`` (``overrides``: other ``gym.make`` arguments, for evaluation), residual-wrapped
    for a residual run. ``worker``: in a worker process, so torch takes one thread."""
    if worker:
        import torch

        torch.set_num_threads(1)
    env = gym.make(config.env_id, **{**env_settings(config, rank), **overrides})
    settings = residual_settings(config)
    return ResidualAction(env, settings) if settings is not None else env


def evaluation_settings(config: RLTrainConfig) -> dict[str, dict]:
    """Name -> ``gym.make`` overrides of the nominal evaluation episodes."""
    if config.task == "tracking":
        return {name: {"trajectory": name, "randomise": False} for name in TRACKING_EVAL}
    if config.task == "edge":
        from simshear_gym.sim.contours import OUTLINES

        return {name: {"outline": name, "randomise": False} for name in OUTLINES}
    if config.task == "push":
        from simshear_gym.sim.pushing import PUSH_SHAPES

        return {name: {"shape": name, "randomise": False, "path_angle_deg": PUSH_EVAL_PATH_ANGLE_DEG}
                for name in PUSH_SHAPES}
    from simshear_gym.envs.colift import OBJECT_NAMES

    return {name: {"trajectory": COLIFT_EVAL_TRAJECTORY, "object_name": name, "randomise": False}
            for name in OBJECT_NAMES}


def run_episode(env: gym.Env, controller, seed: int, max_steps: int) -> dict:
    """One episode of ``controller`` (a :class:`~simshear_gym.control.policy.Controller`): contact error mean (mm),
    steps, the termination."""
    observation, info = env.reset(seed=seed)
    controller.reset()
    errors, termination = [info["contact_error_mm"]], ""
    for _ in range(max_steps):
        observation, _, terminated, truncated, info = env.step(controller(observation))
        errors.append(info["contact_error_mm"])
        if terminated or truncated:
            termination = info.get("termination", "") if terminated else ""
            break
    return {"contact_error_mean_mm": float(np.mean(errors)), "steps": len(errors) - 1, "termination": termination}


class EvaluationCallback(BaseCallback):
    """Every ``config.eval_steps`` env steps (and at the end of training): the deterministic policy on the nominal
    episodes, with the training's VecNormalize statistics; tensorboard ``eval/*``, ``evaluations.json`` and
    ``best_model.zip``."""

    def __init__(self, config: RLTrainConfig, run_dir: Path, vec_normalize) -> None:
        super().__init__()
        self.config = config
        self.run_dir = run_dir
        self.vec_normalize = vec_normalize
        self.path = run_dir / "evaluations.json"
        self.history: list[dict] = json.loads(self.path.read_text())["evaluations"] if self.path.is_file() else []
        self._envs: dict[str, gym.Env] = {}
        self._last = 0
        self.started = time.perf_counter()

    def _init_callback(self) -> None:
        self._last = self.num_timesteps
        if not self.config.eval_steps:
            return
        for name, overrides in evaluation_settings(self.config).items():
            # the bare env: the controller applies the residual law itself, as at deployment
            kwargs = {**env_settings(self.config, 0, training=False), **overrides}
            self._envs[name] = gym.make(self.config.env_id, **kwargs)

    def _on_step(self) -> bool:
        if self.config.eval_steps and self.num_timesteps - self._last >= self.config.eval_steps:
            self.evaluate()
        return True

    def evaluate(self) -> dict:
        self._last = self.num_timesteps
        settings = residual_settings(self.config)
        results = {}
        for name, env in self._envs.items():
            base = env.unwrapped
            residual = ResidualServo(settings, base.reference_depth_mm, base.action_scale) if settings else None
            controller = SB3Controller(self.model, "eval", self.vec_normalize, residual)
            results[name] = run_episode(env, controller, 0, self.config.eval_max_steps)
        errors = [r["contact_error_mean_mm"] for r in results.values()]
        record = {"timesteps": int(self.num_timesteps), "wall_s": round(time.perf_counter() - self.started, 1),
                  "contact_error_mean_mm": float(np.mean(errors)),
                  "ended_early": ended_early(results), "episodes": results}
        for name, result in results.items():
            self.logger.record(f"eval/contact_error_mm/{name}", result["contact_error_mean_mm"])
            self.logger.record(f"eval/steps/{name}", result["steps"])
        self.logger.record("eval/contact_error_mm_mean", record["contact_error_mean_mm"])
        self.logger.record("eval/ended_early", record["ended_early"])
        self.logger.dump(self.num_timesteps)
        if _better(record, self.history):
            record["best"] = True
            save_model(self.model, self.vec_normalize, self.run_dir / "best_model.zip",
                       self.run_dir / f"best_model_{VECNORMALIZE}")
        self.history.append(record)
        write_json(self.path, {"metric": "contact error (mm), mean over each nominal episode's steps; episodes "
                                         f"capped at {self.config.eval_max_steps} steps", "evaluations": self.history})
        return record

    def _on_training_end(self) -> None:
        if self.config.eval_steps and self.num_timesteps > self._last:
            self.evaluate()
        for env in self._envs.values():
            env.close()


def _better(record: dict, history: list[dict]) -> bool:
    """Lower (early ends, mean contact error) than every earlier evaluation."""
    def key(entry: dict) -> tuple[int, float]:
        return (min(entry["ended_early"], 1), entry["contact_error_mean_mm"])

    return all(key(record) < key(entry) for entry in history)


class WallClockBudget(BaseCallback):
    """Stop training after ``minutes`` of wall-clock time from the training's start (None: never)."""

    clock = staticmethod(time.monotonic)
    """The clock (seconds) the budget reads; tests give it one that moves per reading, so that the budget stops
    at the same step on any machine."""

    def __init__(self, minutes: float | None) -> None:
        super().__init__()
        self.minutes = minutes
        self.deadline: float | None = None
        self.stopped = False

    def _on_training_start(self) -> None:
        self.deadline = None if self.minutes is None else self.clock() + 60.0 * self.minutes

    def _on_step(self) -> bool:
        if self.deadline is not None and self.clock() >= self.deadline:
            self.stopped = True
            return False
        return True


def save_model(model, vec_normalize, path: Path, stats_path: Path) -> None:
    """The model: SB3's ``.zip`` (to resume from), the policy's pickle-free ``.pt`` + ``.json`` beside it, and its
    VecNormalize statistics as JSON (``stats_path``), each written atomically."""
    atomic_write(path, lambda tmp: model.save(tmp), suffix=".zip")
    save_policy(model, path)
    if vec_normalize is not None:
        save_normalizer(vec_normalize, stats_path)


class Checkpoints(CheckpointCallback):
    """SB3's periodic checkpoints, each saved as :func:`save_model` saves (``rl_model_<N>_steps.zip`` with its
    pickle-free policy files and ``rl_model_vecnormalize_<N>_steps.json``; no pickle)."""

    def _on_step(self) -> bool:
        if self.n_calls % self.save_freq == 0:
            save_model(self.model, self.model.get_vec_normalize_env(), Path(self._checkpoint_path(extension="zip")),
                       Path(self._checkpoint_path("vecnormalize_", extension="json")))
        return True


# SB3 ``.zip`` entries that are cloudpickled and rebuilt on resume from the run itself: None is what a fresh
# ``learn`` fills in (the last observation, the episode buffers) or what ``_setup_model`` derives (the buffers'
# classes, the learning-rate schedule from ``learning_rate``)
RESET_ON_RESUME = ("_last_obs", "_last_episode_starts", "_last_original_obs", "ep_info_buffer", "ep_success_buffer",
                   "rollout_buffer_class", "replay_buffer_class", "lr_schedule", "action_noise")


def load_agent(Algorithm, path: Path, env, config: RLTrainConfig, **kwargs):
    """SB3's ``Algorithm.load`` of a run's ``.zip`` without unpickling any of its entries: the spaces are the env's,
    the policy class the run's, the schedules rebuilt from the run's settings (a hyper-parameter the trainer does
    not set takes the algorithm's default, as it had in training); the tensors load with ``weights_only``.

    Raises:
        ValueError: the ``.zip`` holds a pickled entry this trainer does not know how to rebuild.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a Stable-Baselines3 model .zip ({error})") from None
    pickled = [key for key, value in data.items() if isinstance(value, dict) and ":serialized:" in value]
    defaults = {name: parameter.default for name, parameter in inspect.signature(Algorithm.__init__).parameters.items()
                if parameter.default is not inspect.Parameter.empty}
    if config.asymmetric_critic:
        from simshear_gym.control.asymmetric import AsymmetricActorCriticPolicy as policy_class
    else:
        policy_class = Algorithm.policy_aliases["MultiInputPolicy"]
    given = {"policy_class": policy_class, "observation_space": env.observation_space,
             "action_space": env.action_space, **dict.fromkeys(RESET_ON_RESUME)}
    custom = {}
    for key in pickled:
        if key in given:
            custom[key] = given[key]
        elif defaults.get(key) is not None:
            custom[key] = defaults[key]
        else:
            raise ValueError(f"{path}: entry {key!r} is pickled and cannot be rebuilt from the run's settings; "
                             "refusing to unpickle it (start a new run with another --out)")
    return Algorithm.load(path, env=env, custom_objects=custom, **kwargs)


def plot_learning_curve(evaluations: list[dict], path: Path, title: str) -> None:
    """Mean contact error of the nominal episodes against env steps, one line per episode and their mean."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [entry["timesteps"] for entry in evaluations]
    figure, axis = plt.subplots(figsize=(6.0, 3.8))
    for name in evaluations[0]["episodes"]:
        axis.plot(steps, [entry["episodes"][name]["contact_error_mean_mm"] for entry in evaluations], lw=0.8,
                  label=name)
    axis.plot(steps, [entry["contact_error_mean_mm"] for entry in evaluations], "k", lw=1.6, label="mean")
    axis.set(xlabel="env steps", ylabel="contact error (mm)", yscale="log", title=title)
    axis.legend(fontsize=7)
    figure.tight_layout()
    atomic_write(path, lambda tmp: figure.savefig(tmp, dpi=100, format="png"), suffix=".png")
    plt.close(figure)


def clone_servo_law(config: RLTrainConfig, model, vec_normalize) -> dict:
    """``--bc-steps``: the servo law's rollouts in the training envs' settings cloned into ``model``'s policy, then
    ``--bc-rounds`` - 1 rounds of DAgger (:func:`simshear_gym.train.rl_imitation.clone_servo_law`); returns the
    fits' records."""
    from simshear_gym.train.rl_imitation import clone_servo_law as clone

    envs = [make_env(config, rank) for rank in range(config.n_envs)]
    try:
        return clone(model, vec_normalize, envs, config.bc_steps, config.bc_rounds, config.bc_epochs,
                     config.bc_noise, seed=config.seed, gamma=config.gamma, batch_size=max(config.batch_size, 64))
    finally:
        for env in envs:
            env.close()


def _vec_env(config: RLTrainConfig):
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if config.vec == "batched":
        from gymnasium.vector import AutoresetMode

        from simshear_gym.train.rl_vec import SB3VectorEnv

        vector_env = gym.make_vec(config.env_id, num_envs=config.n_envs, autoreset_mode=AutoresetMode.SAME_STEP,
                                  **env_settings(config, 0))
        venv = VecMonitor(SB3VectorEnv(vector_env))
    else:
        subproc = config.vec == "subproc"
        makers = [partial(_monitored, config, rank, subproc, Monitor) for rank in range(config.n_envs)]
        venv = SubprocVecEnv(makers) if subproc else DummyVecEnv(makers)
    venv.seed(config.seed)
    return venv


def _monitored(config: RLTrainConfig, rank: int, worker: bool, monitor):
    return monitor(make_env(config, rank, worker=worker))


def train(config: RLTrainConfig, run_dir: Path, resume: bool = False, progress: bool = True) -> dict:
    """Train (or continue) a run (see :mod:`simshear_gym.train.rl`); returns its summary."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(config.threads)
    device = resolve_device(config.device)  # SB3's device for the networks; the envs step on the CPU
    saved_config = run_dir / RUN_CONFIG
    if saved_config.is_file() and resume:
        names = {field.name for field in fields(RLTrainConfig)}
        saved = {k: v for k, v in json.loads(saved_config.read_text()).items() if k in names}
        check_same_settings(saved_config, saved, config, RESUME_FREE)
    if not resume and latest_checkpoint(run_dir) is not None:
        raise ValueError(f"{run_dir} already holds a model: pass --resume to continue it or use a new --out")
    run_dir.mkdir(parents=True, exist_ok=True)
    residual = residual_settings(config)
    write_json(saved_config, {**asdict(config), "env_id": config.env_id,
                              "residual_gains": None if residual is None else {
                                  "kp": list(residual.kp), "ki": list(residual.ki),
                                  "integral_limit": residual.integral_limit}})
    venv = _vec_env(config)
    start_from = latest_checkpoint(run_dir) if resume else None
    vec_normalize = None
    if config.normalize:
        keys = [key for key in venv.observation_space.spaces if key != "tactile"]
        vec_normalize = VecNormalize(venv, norm_obs=True, norm_reward=config.algo == "ppo",
                                     norm_obs_keys=keys, gamma=config.gamma)
        if start_from is not None:
            stats = vecnormalize_path(start_from)
            if stats is None:
                older = vecnormalize_path(start_from, ".pkl")
                raise ValueError(f"{start_from}: its VecNormalize statistics are "
                                 + (f"only the pickle {older.name} of an older version, which is not unpickled"
                                    if older else "missing") + "; start a new run with another --out")
            restore_vec_normalize(vec_normalize, stats)
    env = vec_normalize if vec_normalize is not None else venv
    Algorithm = sb3_class(config.algo)
    tensorboard = str(run_dir / "tb")
    policy_kwargs = {"net_arch": list(config.net_arch)} if config.net_arch else None
    common = {"batch_size": config.batch_size, "gamma": config.gamma, "learning_rate": config.learning_rate,
              "policy_kwargs": policy_kwargs, "seed": config.seed, "tensorboard_log": tensorboard,
              "verbose": int(progress), "device": device}
    if start_from is not None:
        model = load_agent(Algorithm, start_from, env, config, tensorboard_log=tensorboard, device=device)
    elif config.algo == "ppo":
        policy = "MultiInputPolicy"
        if config.asymmetric_critic:
            from simshear_gym.control.asymmetric import AsymmetricActorCriticPolicy as policy
        model = PPO(policy, env, n_steps=config.n_steps, n_epochs=config.n_epochs, **common)
    else:  # SAC, TQC
        model = Algorithm("MultiInputPolicy", env, buffer_size=min(100_000, config.timesteps),
                          learning_starts=min(1_000, config.timesteps // 4), **common)
    imitation = None
    if start_from is None and config.bc_steps:
        imitation = clone_servo_law(config, model, vec_normalize)
        write_json(run_dir / "imitation.json", imitation)
    remaining = config.timesteps - model.num_timesteps
    started, load_start = time.perf_counter(), os.getloadavg()[0]
    budget = WallClockBudget(config.minutes)
    evaluation = EvaluationCallback(config, run_dir, vec_normalize)
    try:
        if remaining > 0:
            checkpoints = Checkpoints(save_freq=max(1, config.checkpoint_steps // config.n_envs),
                                      save_path=str(run_dir / "checkpoints"), name_prefix="rl_model")
            model.learn(total_timesteps=remaining, callback=CallbackList([checkpoints, evaluation, budget]),
                        reset_num_timesteps=start_from is None, tb_log_name=config.algo)
        save_model(model, vec_normalize, run_dir / "model.zip", run_dir / VECNORMALIZE)
    finally:
        env.close()
    if evaluation.history:
        plot_learning_curve(evaluation.history, run_dir / "learning_curve.png",
                            f"{config.algo}, {config.observation} ({config.task})")
    summary = {"algo": config.algo, "task": config.task, "observation": config.observation,
               "timesteps": int(model.num_timesteps), "resumed_from": str(start_from) if start_from else None,
               "stopped_by": "minutes" if budget.stopped else "timesteps",
               "seconds": round(time.perf_counter() - started, 1), "model": str(run_dir / "model.zip"),
               "last_evaluation": evaluation.history[-1] if evaluation.history else None, "imitation": imitation,
               "machine": {**machine_info(), "load_1min_rl_start": round(load_start, 2),
                           "load_1min_end": round(os.getloadavg()[0], 2)}}
    write_json(run_dir / "summary.json", summary)
    return summary
