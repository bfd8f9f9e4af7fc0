"""Train a Stable-Baselines3 agent (PPO or SAC) on SimShearTracking-v0.

``simshear train rl --algo ppo --out runs/rl/ppo --timesteps N`` trains on the env's translated images
(``obs_mode="real"`` by default, so the policy sees what it would see on the real robot) with randomised
trajectories (``trajectory="random"``, ``randomise=True``: scale, speed, rotation and start place drawn per reset).
Policy: SB3's ``MultiInputPolicy`` (a CNN on ``tactile``, an MLP on ``tcp_pose``; the CNN needs images of at
least 36 px, and 64 px is the default here because it halves the policy's cost at the same translation cost).

Run directory: ``config.json``, tensorboard logs ``tb/`` (episode reward and length, losses), checkpoints
``checkpoints/rl_model_<steps>_steps.zip`` every ``--checkpoint-steps`` (SB3's ``CheckpointCallback``; each file
written whole) and the final ``model.zip``. ``--resume`` continues from the newest checkpoint (or ``model.zip``)
with the step count carried on. Evaluate the result with the servo benchmark's policy variant:
``simshear evaluate servo --variants policy --policy OUT/model.zip``.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from simshear_gym.train.flags import config_flags, config_from_args
from simshear_gym.train.runs import check_same_settings

ALGORITHMS = ("ppo", "sac")
OBS_MODES = ("real", "sim")  # what a policy may see: never the ground truth
_RESUME_FREE = ("timesteps", "threads")  # settings a resumed run may change


@dataclass(frozen=True)
class RLTrainConfig:
    """Everything an RL run depends on (saved as ``config.json``)."""

    algo: str = "ppo"
    timesteps: int = 20_000
    obs_mode: str = "real"
    image_size_px: int = 64
    n_envs: int = 1
    n_steps: int = 256
    batch_size: int = 64
    learning_rate: float = 3e-4
    checkpoint_steps: int = 2_000
    seed: int = 0
    threads: int = 1

    def __post_init__(self) -> None:
        if self.algo not in ALGORITHMS:
            raise ValueError(f"algo must be one of {ALGORITHMS}, got {self.algo!r}")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be 'real' or 'sim' (a policy never sees ground truth), "
                             f"got {self.obs_mode!r}")
        if self.image_size_px not in (64, 128):
            raise ValueError(f"image_size_px must be 64 or 128, got {self.image_size_px}")
        if min(self.timesteps, self.n_envs, self.n_steps, self.batch_size, self.checkpoint_steps) < 1:
            raise ValueError("timesteps, n_envs, n_steps, batch_size and checkpoint_steps must be >= 1")
        if self.learning_rate <= 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate}")


def make_env(config: RLTrainConfig):
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401  (registers the envs)

    return gym.make("SimShearTracking-v0", trajectory="random", randomise=True, obs_mode=config.obs_mode,
                    image_size_px=config.image_size_px)


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest ``checkpoints/rl_model_<steps>_steps.zip``, else ``model.zip``, else None."""
    found = []
    for path in (run_dir / "checkpoints").glob("rl_model_*_steps.zip"):
        match = re.fullmatch(r"rl_model_(\d+)_steps\.zip", path.name)
        if match:
            found.append((int(match.group(1)), path))
    if found:
        return max(found)[1]
    return run_dir / "model.zip" if (run_dir / "model.zip").is_file() else None


def train(config: RLTrainConfig, run_dir: Path, resume: bool = False, progress: bool = True) -> dict:
    """Train (or continue) a run; returns a summary. The final model is ``run_dir/model.zip``."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.env_util import make_vec_env

    from simshear_gym.io import write_json

    torch.set_num_threads(config.threads)
    run_dir = Path(run_dir)
    saved_config = run_dir / "config.json"
    if saved_config.is_file() and resume:
        check_same_settings(saved_config, json.loads(saved_config.read_text()), config, _RESUME_FREE)
    if not resume and latest_checkpoint(run_dir) is not None:
        raise ValueError(f"{run_dir} already holds a model: pass --resume to continue it or use a new --out")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(saved_config, asdict(config))
    env = make_vec_env(lambda: make_env(config), n_envs=config.n_envs, seed=config.seed)
    Algorithm = PPO if config.algo == "ppo" else SAC
    start_from = latest_checkpoint(run_dir) if resume else None
    if start_from is not None:
        model = Algorithm.load(start_from, env=env, tensorboard_log=str(run_dir / "tb"))
    elif config.algo == "ppo":
        model = PPO("MultiInputPolicy", env, n_steps=config.n_steps, batch_size=config.batch_size,
                    learning_rate=config.learning_rate, seed=config.seed, tensorboard_log=str(run_dir / "tb"),
                    verbose=int(progress))
    else:
        model = SAC("MultiInputPolicy", env, batch_size=config.batch_size, learning_rate=config.learning_rate,
                    buffer_size=min(50_000, config.timesteps), learning_starts=min(1_000, config.timesteps // 4),
                    seed=config.seed, tensorboard_log=str(run_dir / "tb"), verbose=int(progress))
    remaining = config.timesteps - model.num_timesteps
    started = time.perf_counter()
    if remaining > 0:
        checkpoints = CheckpointCallback(save_freq=max(1, config.checkpoint_steps // config.n_envs),
                                         save_path=str(run_dir / "checkpoints"), name_prefix="rl_model")
        model.learn(total_timesteps=remaining, callback=checkpoints, reset_num_timesteps=start_from is None,
                    tb_log_name=config.algo)
    model.save(run_dir / "model.tmp.zip")
    (run_dir / "model.tmp.zip").replace(run_dir / "model.zip")
    env.close()
    summary = {"algo": config.algo, "timesteps": int(model.num_timesteps),
               "resumed_from": str(start_from) if start_from else None,
               "seconds": round(time.perf_counter() - started, 1), "model": str(run_dir / "model.zip")}
    write_json(run_dir / "summary.json", summary)
    return summary


FLAG_HELP = {
    "algo": "SB3 algorithm",
    "timesteps": "env steps to train in all (a resumed run trains until its step count reaches this)",
    "obs_mode": "tactile images the policy sees: real (sim renders through the shipped translator, as on the "
                "robot) or sim (the raw sim renders)",
    "image_size_px": "tactile image size in px: 64 or 128 (the policy's CNN needs at least 36)",
    "n_envs": "envs stepped side by side (SB3 make_vec_env)",
    "n_steps": "PPO: env steps per env between updates",
    "batch_size": "minibatch size of the updates",
    "learning_rate": "Adam learning rate",
    "checkpoint_steps": "write checkpoints/rl_model_<steps>_steps.zip every this many env steps",
    "seed": "seed of the envs and the agent",
    "threads": "torch CPU threads",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    config_flags(parser, RLTrainConfig, FLAG_HELP, choices={"algo": ALGORITHMS, "obs_mode": OBS_MODES})
    parser.add_argument("--resume", action="store_true", help="continue from the run's newest checkpoint")
    parser.add_argument("--quiet", action="store_true", help="no SB3 training log on stdout")


def run(args: argparse.Namespace) -> int:
    config = config_from_args(RLTrainConfig, args)
    summary = train(config, args.out, resume=args.resume, progress=not args.quiet)
    print(json.dumps(summary))
    return 0
