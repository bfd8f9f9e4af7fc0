"""What the closed-loop benchmarks (``servo``, ``servo6d``, ``edge-follow``, ``push``) share: the SB3 policy
variants, the checks of ``--policy``, and one timed episode loop."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

POLICY_VARIANTS = ("policy", "ppo", "sac", "tqc")
"""The variants that run an SB3 agent of ``simshear train rl``."""


def check_policy(variants: list[str], policy: str | None, task: str | None = None) -> None:
    """At most one policy variant (``--policy`` names one agent), and then ``--policy`` an existing model file;
    ``task``: the ``--task`` the agent was trained on, named in the message."""
    policy_variants = [v for v in variants if v in POLICY_VARIANTS]
    if len(policy_variants) > 1:
        raise ValueError(f"one policy variant a run (--policy names one agent), got {policy_variants}")
    if policy_variants and not policy:
        raise ValueError(f"--variants {policy_variants[0]} needs --policy MODEL.zip (from simshear train rl"
                         f"{f' --task {task}' if task else ''})")
    if policy and not Path(policy).is_file():
        raise FileNotFoundError(f"--policy {policy!r}: no such model file")


def env_kwargs(variant: str, policy: str | None, obs_mode: str) -> dict:
    """``gym.make`` arguments of a variant's env: an agent's in the settings it was trained on (its run's
    ``config.json``; a bare zip: translated images at 128 px and the TCP pose), else ``obs_mode``."""
    if variant in POLICY_VARIANTS:
        from simshear_gym.control.env_estimator import policy_env_kwargs

        return policy_env_kwargs(policy)
    return {"obs_mode": obs_mode}


class TimedEpisode:
    """One episode of ``controller`` in ``env`` from ``env.reset(seed=seed)`` (the controller reset too): iterating
    steps it and gives each step's ``info``, until the env ends the episode or ``max_steps`` steps. Kept: the
    latest ``info`` (the reset's before the first step), the step count, whether the env ``terminated`` or
    ``truncated``, and the time of each controller call (``control_s``) and each ``env.step`` (``step_s``)."""

    def __init__(self, env, controller, seed: int | None, max_steps: int | None = None) -> None:
        self.observation, self.info = env.reset(seed=seed)
        controller.reset()
        self.env, self.controller, self.max_steps = env, controller, max_steps
        self.steps, self.terminated, self.truncated = 0, False, False
        self.control_s: list[float] = []
        self.step_s: list[float] = []

    def __iter__(self) -> Iterator[dict]:
        while True:
            started = time.perf_counter()
            action = self.controller(self.observation)
            self.control_s.append(time.perf_counter() - started)
            started = time.perf_counter()
            self.observation, _, self.terminated, self.truncated, self.info = self.env.step(action)
            self.step_s.append(time.perf_counter() - started)
            self.steps += 1
            yield self.info
            if self.terminated or self.truncated or (self.max_steps is not None and self.steps >= self.max_steps):
                return
