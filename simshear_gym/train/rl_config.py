"""The settings of ``simshear train rl`` (:mod:`simshear_gym.train.rl`: what each means) and the run folder's
checkpoints; torch-free, so the command's ``--help`` stays fast."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from simshear_gym.contract import ACTION_OBSERVATIONS, ESTIMATE_OBSERVATIONS, IMAGE_SIZES_PX, check_observation
from simshear_gym.models.device import check_device_name
from simshear_gym.train.runs import check_choice

ALGORITHMS = ("ppo", "sac", "tqc")  # tqc: sb3-contrib's TQC (an optional dependency)
TASKS = ("tracking", "colift", "edge", "push")
ENV_IDS = {"tracking": "SimShearTracking-v0", "colift": "SimShearCoLift-v0", "edge": "SimShearEdgeFollow-v0",
           "push": "SimShearPush-v0"}
OBS_MODES = ("real", "sim")  # what a policy may see: never the ground truth
VEC_ENVS = ("dummy", "subproc", "batched")
# settings a resumed run may change (they change neither the agent nor its envs)
RESUME_FREE = ("timesteps", "minutes", "threads", "vec", "eval_steps", "eval_max_steps", "checkpoint_steps",
               "device")

FIRST_RECIPE: dict = {
    "algo": "ppo", "history": 2, "obs_mode": "real", "image_size_px": 64, "n_envs": 4, "vec": "subproc",
    "n_steps": 512, "batch_size": 256, "n_epochs": 10, "gamma": 0.98, "learning_rate": 1e-4, "net_arch": (128, 128),
    "bc_steps": 6000, "bc_rounds": 6, "bc_epochs": 30, "timesteps": 100_000, "eval_steps": 25_000,
    "checkpoint_steps": 25_000, "seed": 0, "threads": 1,
}
"""The first-policy recipe on a 2-core CPU: the task's law cloned by DAgger (6 x 6000 steps), then 100,000 PPO
steps from the clone; each ``*-first`` preset is it plus its task's settings."""

#: ``simshear train rl --preset NAME``: named settings a run starts from (any flag given beside it wins). The
#: recipe, its budget and what it gives are in docs/first_policy.md and results/first_policy.json.
PRESETS: dict[str, dict] = {
    # a first tracking policy: the servo law's clone on the estimate and the last action (the law in velocity form:
    # a function of what the policy sees)
    "tracking-first": {**FIRST_RECIPE, "task": "tracking", "observation": "estimate+action"},
    # a first edge-following policy: the edge law's clone on the edge estimate (two frames)
    "edge-first": {**FIRST_RECIPE, "task": "edge", "observation": "estimate", "eval_max_steps": 1000},
    # a first pushing policy: the push law's clone (without its path-side integral) on the estimate and the goal
    "push-first": {**FIRST_RECIPE, "task": "push", "observation": "estimate", "eval_max_steps": 800},
}


@dataclass(frozen=True)
class RLTrainConfig:
    """Everything an RL run depends on (saved as ``config.json``); what each setting means: ``FLAG_HELP`` of
    :mod:`simshear_gym.train.rl`."""

    algo: str = "ppo"
    task: str = "tracking"
    timesteps: int = 20_000
    minutes: float | None = None
    observation: str = "tactile"
    history: int = 1
    obs_mode: str = "real"
    image_size_px: int = 64
    randomise: bool = True
    n_envs: int = 1
    vec: str = "dummy"
    n_steps: int = 256
    batch_size: int = 64
    n_epochs: int = 10
    gamma: float = 0.99
    learning_rate: float = 3e-4
    net_arch: tuple[int, ...] = ()
    normalize: bool = True
    residual_bound: float = 0.0
    asymmetric_critic: bool = False
    bc_steps: int = 0
    bc_rounds: int = 1
    bc_epochs: int = 30
    bc_noise: float = 0.1
    eval_steps: int = 0
    eval_max_steps: int = 500
    checkpoint_steps: int = 2_000
    seed: int = 0
    threads: int = 1
    device: str = "cpu"

    def __post_init__(self) -> None:
        check_choice("algo", self.algo, ALGORITHMS)
        check_choice("task", self.task, TASKS)
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be 'real' or 'sim' (a policy never sees ground truth), "
                             f"got {self.obs_mode!r}")
        check_observation(self.observation, self.history)
        if self.image_size_px not in IMAGE_SIZES_PX:
            raise ValueError(f"image_size_px must be one of {IMAGE_SIZES_PX}, got {self.image_size_px}")
        check_device_name(self.device)
        check_choice("vec", self.vec, VEC_ENVS)
        if min(self.n_envs, self.n_steps, self.batch_size, self.n_epochs, self.checkpoint_steps,
               self.eval_max_steps) < 1 or self.timesteps < (0 if self.bc_steps else 1):
            raise ValueError("timesteps (0 allowed with --bc-steps: the clone alone), n_envs, n_steps, batch_size, "
                             f"n_epochs, checkpoint_steps and eval_max_steps must be >= 1, got {self}")
        if self.eval_steps < 0:
            raise ValueError(f"eval_steps must be >= 0 (0: no evaluation), got {self.eval_steps}")
        if self.minutes is not None and not self.minutes > 0:
            raise ValueError(f"minutes must be > 0 (or left out: no time budget), got {self.minutes}")
        if self.learning_rate <= 0 or not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"need learning_rate > 0 and gamma in (0, 1], got {self.learning_rate}, {self.gamma}")
        if any(width < 1 for width in self.net_arch):
            raise ValueError(f"net_arch widths must be >= 1, got {self.net_arch}")
        if not 0.0 <= self.residual_bound <= 1.0:
            raise ValueError(f"residual_bound must be in [0, 1] full-scale actions (0: not residual), "
                             f"got {self.residual_bound}")
        if self.asymmetric_critic and self.algo != "ppo":
            raise ValueError(f"--asymmetric-critic is PPO's (an actor-critic policy with two extractors), got "
                             f"--algo {self.algo}")
        if self.vec == "batched" and (self.task != "tracking" or self.observation != "tactile" or self.history != 1):
            raise ValueError("--vec batched steps SimShearTracking-v0's batched vector env, whose sub-envs give the "
                             "image alone: it needs --task tracking --observation tactile --history 1, got "
                             f"--task {self.task} --observation {self.observation} --history {self.history}")
        if self.bc_steps < 0 or min(self.bc_rounds, self.bc_epochs) < 1 or not 0.0 < self.bc_noise <= 1.0:
            raise ValueError(f"need bc_steps >= 0, bc_rounds and bc_epochs >= 1 and bc_noise in (0, 1], got "
                             f"{self.bc_steps}, {self.bc_rounds}, {self.bc_epochs}, {self.bc_noise}")
        if self.bc_steps and (self.algo != "ppo" or self.observation not in ESTIMATE_OBSERVATIONS
                              or self.residual_bound > 0):
            raise ValueError("--bc-steps clones the servo law from the filter estimate into PPO's actor: it needs "
                             f"--algo ppo, --observation one of {list(ESTIMATE_OBSERVATIONS)} and no "
                             f"--residual-bound, got --algo {self.algo} --observation {self.observation} "
                             f"--residual-bound {self.residual_bound}")
        if self.bc_steps and self.observation in ACTION_OBSERVATIONS and self.history < 2:
            raise ValueError(f"--bc-steps with --observation {self.observation} clones the servo law in velocity form "
                             f"(the last action plus the change between the newest two frames): it needs --history "
                             f">= 2, got {self.history}")
        if self.residual_bound > 0 and self.observation not in ESTIMATE_OBSERVATIONS:
            raise ValueError("a residual policy corrects the servo law on the filter's estimate: --residual-bound "
                             f"needs --observation one of {list(ESTIMATE_OBSERVATIONS)}, got {self.observation!r}")

    @property
    def env_id(self) -> str:
        return ENV_IDS[self.task]


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest ``checkpoints/rl_model_<steps>_steps.zip``, else ``model.zip``, else None."""
    found = []
    for path in (Path(run_dir) / "checkpoints").glob("rl_model_*_steps.zip"):
        match = re.fullmatch(r"rl_model_(\d+)_steps\.zip", path.name)
        if match:
            found.append((int(match.group(1)), path))
    if found:
        return max(found)[1]
    return Path(run_dir) / "model.zip" if (Path(run_dir) / "model.zip").is_file() else None
SUCCESS_TERMINATIONS: tuple[str, ...] = ("lap", "target")
"""Terminations that are a task done (an edge lap, a push at its target), not an early end."""


def ended_early(episodes: dict[str, dict]) -> int:
    """How many evaluation episodes ended early (a termination other than a task's success)."""
    return int(sum(bool(r["termination"]) and r["termination"] not in SUCCESS_TERMINATIONS
                   for r in episodes.values()))


