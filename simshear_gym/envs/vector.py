"""Batched vector env for the SimShear envs: sub-envs step in worker processes, images are translated in batches.

``gymnasium.make_vec("SimShearTracking-v0", num_envs=N)`` (no ``vectorization_mode``, or
``"vector_entry_point"``) builds a :class:`SimShearVectorEnv`. Its sub-envs run with ``raw_tactile=True`` (raw
128 px sim image plus its shear in the observation, :data:`~simshear_gym.contract.RAW_SHEAR_KEY`, which the
finishing takes out) in ``workers`` processes, each holding a contiguous group of them;
the translator then runs once per group and step on the whole group's images (``translate_in="workers"``, the
default), or once per step on all N images in the main process (``translate_in="main"``). With ``workers=0``
everything runs in this process (one group, one batched translation per step).

On a GPU (``device="cuda"``: where the translator runs,
:func:`~simshear_gym.models.translator_runtime.choose_translator_device`) the workers only render and this process
translates all N images in one batch: ``translate_in="main"``.

Why translating in the workers is the default: each worker translates its group with one torch thread while the
other worker renders, so the cores stay busy without torch's multi-threading, which collapses when other
processes share the cores (two threads were ~5x slower than one under load in ``simshear evaluate env-speed``).
Per image, a one-thread translation at batch 8-16 costs about half of one at batch 1.

Autoreset (``autoreset_mode``): ``AutoresetMode.NEXT_STEP`` (gymnasium's default): the step after a sub-env's
episode ended resets it (its action is ignored; reward 0, not terminated or truncated) and returns the reset
observation and info. ``AutoresetMode.SAME_STEP`` (what SB3's ``VecEnv`` API needs,
:class:`simshear_gym.train.rl_vec.SB3VectorEnv`): the step that ends an episode resets the sub-env at once and
returns the reset observation; the episode's last observation and info are in ``info["final_obs"][i]`` and
``info["final_info"]`` (masked by ``info["_final_obs"]``), its last image translated in the same batch.
Truncation: ``max_episode_steps`` (from the registration) per sub-env, like gymnasium's ``TimeLimit``.
"""

from __future__ import annotations

import importlib
import multiprocessing
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from simshear_gym.contract import RAW_SHEAR_KEY, TRANSLATED_MODES, finish_tactile

TRANSLATE_IN: tuple[str, ...] = ("workers", "main")
AUTORESET_MODES: tuple[AutoresetMode, ...] = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


def make_tracking_vector_env(num_envs: int = 1, max_episode_steps: int | None = 500, workers: int | None = None,
                             translate_in: str = "workers", start_method: str | None = None,
                             autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                             **env_kwargs: Any) -> SimShearVectorEnv:
    """The ``vector_entry_point`` of ``SimShearTracking-v0`` (see :class:`SimShearVectorEnv`)."""
    return SimShearVectorEnv("simshear_gym.envs.tracking:SimShearTrackingEnv", num_envs, env_kwargs,
                             max_episode_steps, workers, translate_in, start_method, autoreset_mode)


def _autoreset_mode(value: AutoresetMode | str) -> AutoresetMode:
    """An :class:`AutoresetMode` or its value ("NextStep", "SameStep"; case and "_" free)."""
    if isinstance(value, AutoresetMode) and value in AUTORESET_MODES:
        return value
    names = {mode.value.lower(): mode for mode in AUTORESET_MODES}
    names.update({"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP})
    mode = names.get(str(value).lower()) if isinstance(value, str) else None
    if mode is None:
        raise ValueError(f"autoreset_mode must be one of {[m.value for m in AUTORESET_MODES]}, got {value!r}")
    return mode


def _finish_images(observations: dict[str, np.ndarray], infos: list[dict], obs_mode: str, image_size_px: int,
                   contact: str, translator_weights: str | None, device: str = "cpu") -> dict[str, np.ndarray]:
    """Finish (translate, resize) a batch's raw images and the raw last images of the episodes that ended in it
    (``info["final_obs"]``, SAME_STEP autoreset) in one call, each with the shear its observation carries (taken
    out: the finished observations are the single envs')."""
    ended = [index for index, info in enumerate(infos) if "final_obs" in info]
    observations = dict(observations)
    raw = observations["tactile"][:, 0]
    shear = observations.pop(RAW_SHEAR_KEY)
    if ended:  # no copies on the common step where no episode ended
        finals = [dict(infos[index]["final_obs"]) for index in ended]
        raw = np.concatenate([raw] + [final["tactile"] for final in finals])
        shear = np.concatenate([shear, np.stack([final.pop(RAW_SHEAR_KEY) for final in finals])])
    finished = finish_tactile(raw, shear, obs_mode, image_size_px, contact, translator_weights,
                              translator_device=device)[:, None]
    count = len(infos)
    for place, index in enumerate(ended):
        infos[index]["final_obs"] = {**finals[place], "tactile": finished[count + place]}
    return {**observations, "tactile": finished[:count]}


def _load(entry_point: str):
    module, _, name = entry_point.partition(":")
    return getattr(importlib.import_module(module), name)


class _EnvGroup:
    """Sub-envs stepped one after another, with NEXT_STEP autoreset and the step limit; optionally finishes
    (translates) the group's images in one batch."""

    def __init__(self, entry_point: str, env_kwargs: dict, count: int, max_episode_steps: int | None,
                 finish: bool, autoreset_mode: AutoresetMode = AutoresetMode.NEXT_STEP) -> None:
        env_class = _load(entry_point)
        self.envs = [env_class(**env_kwargs, raw_tactile=True) for _ in range(count)]
        self.max_episode_steps = max_episode_steps
        self.finish = finish
        self.same_step = autoreset_mode == AutoresetMode.SAME_STEP
        self.obs_mode = env_kwargs.get("obs_mode", "real")
        self.image_size_px = env_kwargs.get("image_size_px", 128)
        self._elapsed = [0] * count
        self._needs_reset = [False] * count

    def _stack(self, observations: list[dict], infos: list[dict]) -> dict[str, np.ndarray]:
        batch = {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}
        if self.finish:
            env = self.envs[0]
            batch = _finish_images(batch, infos, self.obs_mode, self.image_size_px, env.translator_contact,
                                   env.translator_weights, env.translator_device)
        return batch

    def reset(self, seeds: list, options: dict | None):
        observations, infos = [], []
        for index, (env, seed) in enumerate(zip(self.envs, seeds)):
            obs, info = env.reset(seed=seed, options=options)
            self._elapsed[index], self._needs_reset[index] = 0, False
            observations.append(obs)
            infos.append(info)
        return self._stack(observations, infos), infos

    def step(self, actions: np.ndarray):
        count = len(self.envs)
        observations, infos = [], []
        rewards = np.zeros(count)
        terminations, truncations = np.zeros(count, dtype=bool), np.zeros(count, dtype=bool)
        for index, env in enumerate(self.envs):
            if self._needs_reset[index]:
                obs, info = env.reset()
                self._elapsed[index], self._needs_reset[index] = 0, False
            else:
                obs, rewards[index], terminations[index], _, info = env.step(actions[index])
                self._elapsed[index] += 1
                truncations[index] = (self.max_episode_steps is not None
                                      and self._elapsed[index] >= self.max_episode_steps)
                self._needs_reset[index] = bool(terminations[index] or truncations[index])
                if self.same_step and self._needs_reset[index]:
                    final_obs, final_info = obs, info
                    obs, info = env.reset()
                    self._elapsed[index], self._needs_reset[index] = 0, False
                    info = {**info, "final_obs": final_obs, "final_info": final_info}
            observations.append(obs)
            infos.append(info)
        return self._stack(observations, infos), rewards, terminations, truncations, infos

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _worker(connection, entry_point: str, env_kwargs: dict, count: int, max_episode_steps: int | None,
            finish: bool, autoreset_mode: AutoresetMode) -> None:
    if finish and env_kwargs.get("obs_mode", "real") in TRANSLATED_MODES:
        import torch

        torch.set_num_threads(1)  # this worker's share of the cores; the others run their own groups
    group = _EnvGroup(entry_point, env_kwargs, count, max_episode_steps, finish, autoreset_mode)
    connection.send(("ready", None))
    try:
        while True:
            command, payload = connection.recv()
            if command == "close":
                break
            try:
                result = group.reset(*payload) if command == "reset" else group.step(payload)
                connection.send(("ok", result))
            except Exception as error:  # hand the error to the main process, which raises it
                connection.send(("error", f"{type(error).__name__}: {error}"))
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        group.close()
        connection.close()


class SimShearVectorEnv(VectorEnv):
    """N SimShear sub-envs with batched translation (module docstring).

    Args:
        entry_point: ``"module:Class"`` of the sub-env.
        num_envs: N.
        env_kwargs: constructor arguments of every sub-env (``obs_mode``, ``trajectory``, ...).
        max_episode_steps: truncation per sub-env (None: never).
        workers: processes to step the sub-envs in (default: the number of CPUs, at most N); 0 = in-process.
        translate_in: ``"workers"`` (each group's images in its worker) or ``"main"`` (all N in this process).
        start_method: multiprocessing start method (default ``"fork"`` where available: starts in milliseconds
            and works from unguarded scripts; else ``"spawn"``, which needs the ``if __name__ == "__main__"``
            idiom). Forked workers set torch to one thread before they translate.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default) or ``SAME_STEP`` (or their names: module docstring).
    """

    def __init__(self, entry_point: str, num_envs: int, env_kwargs: dict, max_episode_steps: int | None = None,
                 workers: int | None = None, translate_in: str = "workers", start_method: str | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP) -> None:
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        if translate_in not in TRANSLATE_IN:
            raise ValueError(f"translate_in must be one of {TRANSLATE_IN}, got {translate_in!r}")
        autoreset_mode = _autoreset_mode(autoreset_mode)
        if env_kwargs.get("render_mode") is not None:
            raise ValueError("SimShearVectorEnv does not render; use vectorization_mode='sync' to render sub-envs")
        if "raw_tactile" in env_kwargs:
            raise ValueError("raw_tactile is set by SimShearVectorEnv itself; do not pass it")
        import os

        workers = min(os.cpu_count() or 1, num_envs) if workers is None else workers
        if not isinstance(workers, int) or workers < 0:
            raise ValueError(f"workers must be an int >= 0, got {workers!r}")
        workers = min(workers, num_envs)
        self.num_envs = num_envs
        self.workers = workers
        self.translate_in = translate_in
        self.env_kwargs = dict(env_kwargs)
        self.max_episode_steps = max_episode_steps

        single = _load(entry_point)(**env_kwargs)  # the spaces, and a fast failure on bad kwargs
        self.single_observation_space = single.observation_space
        self.single_action_space = single.action_space
        self.obs_mode, self.image_size_px = single.obs_mode, single.image_size_px
        self._contact = single.translator_contact
        self._translator_weights = single.translator_weights
        self._translator_device = single.translator_device
        single.close()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.metadata = {"autoreset_mode": autoreset_mode, "render_modes": []}
        self.render_mode = None

        finish_in_groups = translate_in == "workers" or workers == 0
        if self._translator_device != "cpu" and workers > 0 and translate_in == "workers":
            raise ValueError(f"device {self._translator_device!r}: worker processes cannot share the GPU; translate "
                             "all sub-envs' images there in this process with translate_in='main'")
        self._finish_in_main = not finish_in_groups
        if self._finish_in_main:
            env_kwargs = {**env_kwargs, "device": "cpu"}  # the workers only render; this process translates
        counts = [len(part) for part in np.array_split(np.arange(num_envs), max(workers, 1))]
        self._slices = np.cumsum([0] + counts)
        self._group: _EnvGroup | None = None
        self._processes, self._connections = [], []
        if workers == 0:
            self._group = _EnvGroup(entry_point, env_kwargs, num_envs, max_episode_steps, True, autoreset_mode)
        else:
            if start_method is None:
                methods = multiprocessing.get_all_start_methods()
                start_method = "fork" if "fork" in methods else "spawn"
            context = multiprocessing.get_context(start_method)
            for count in counts:
                parent, child = context.Pipe()
                process = context.Process(target=_worker, daemon=True,
                                          args=(child, entry_point, env_kwargs, count, max_episode_steps,
                                                finish_in_groups, autoreset_mode))
                process.start()
                child.close()
                self._processes.append(process)
                self._connections.append(parent)
            for connection in self._connections:
                self._receive(connection)
        self._closed = False

    # ------------------------------------------------------------- plumbing
    @staticmethod
    def _receive(connection):
        status, payload = connection.recv()
        if status == "error":
            raise RuntimeError(f"a SimShearVectorEnv worker failed: {payload}")
        return payload

    def _run(self, command: str, payloads: list) -> list:
        if self._closed:
            raise RuntimeError("this SimShearVectorEnv is closed")
        if self._group is not None:
            return [self._group.reset(*payloads[0]) if command == "reset" else self._group.step(payloads[0])]
        for connection, payload in zip(self._connections, payloads):
            connection.send((command, payload))
        return [self._receive(connection) for connection in self._connections]

    @staticmethod
    def _merge(parts: list[dict]) -> dict[str, np.ndarray]:
        return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}

    def _finish(self, batch: dict[str, np.ndarray], infos: list[dict]) -> dict[str, np.ndarray]:
        if self._finish_in_main:
            batch = _finish_images(batch, infos, self.obs_mode, self.image_size_px, self._contact,
                                   self._translator_weights, self._translator_device)
        return batch

    def _vector_infos(self, infos: list[dict]) -> dict:
        vector_infos: dict = {}
        for index, info in enumerate(infos):
            vector_infos = self._add_info(vector_infos, info, index)
        return vector_infos

    # ----------------------------------------------------------- gym API
    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + index for index in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset(seed=...) needs {self.num_envs} seeds, got {len(seeds)}")
        groups = self._groups()
        results = self._run("reset", [(seeds[a:b], options) for a, b in groups])
        infos = [info for _, group_infos in results for info in group_infos]
        observations = self._finish(self._merge([obs for obs, _ in results]), infos)
        return observations, self._vector_infos(infos)

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (self.num_envs, 4):
            raise ValueError(f"actions must have shape ({self.num_envs}, 4), got {actions.shape}")
        results = self._run("step", [actions[a:b] for a, b in self._groups()])
        infos = [info for result in results for info in result[4]]
        observations = self._finish(self._merge([result[0] for result in results]), infos)
        rewards = np.concatenate([result[1] for result in results])
        terminations = np.concatenate([result[2] for result in results])
        truncations = np.concatenate([result[3] for result in results])
        return observations, rewards, terminations, truncations, self._vector_infos(infos)

    def _groups(self) -> list[tuple[int, int]]:
        if self._group is not None:
            return [(0, self.num_envs)]
        return [(int(a), int(b)) for a, b in zip(self._slices[:-1], self._slices[1:])]

    def close_extras(self, **kwargs: Any) -> None:
        if self._closed:
            return
        self._closed = True
        if self._group is not None:
            self._group.close()
        for connection in self._connections:
            try:
                connection.send(("close", None))
            except (BrokenPipeError, OSError):
                pass
        for process in self._processes:
            process.join(timeout=5)
            if process.is_alive():
                process.terminate()
        for connection in self._connections:
            connection.close()
