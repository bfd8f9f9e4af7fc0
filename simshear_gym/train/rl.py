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

ALGORITHMS = ("ppo", "sac")


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
        if self.obs_mode not in ("real", "sim"):
            raise ValueError(f"obs_mode must be 'real' or 'sim' (a policy never sees ground truth), got {self.obs_mode!r}")
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
        before = json.loads(saved_config.read_text())
        changed = {k: (before.get(k), v) for k, v in asdict(config).items()
                   if k not in ("timesteps", "threads") and before.get(k) != v}
        if changed:
            raise ValueError(f"{saved_config}: --resume with different settings {changed}; use a new --out")
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = RLTrainConfig()
    parser.add_argument("--algo", choices=ALGORITHMS, default=defaults.algo)
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    for name in ("timesteps", "obs_mode", "image_size_px", "n_envs", "n_steps", "batch_size", "learning_rate",
                 "checkpoint_steps", "seed", "threads"):
        value = getattr(defaults, name)
        flag = "--" + name.replace("_px", "").replace("_", "-")
        parser.add_argument(flag, dest=name, type=type(value), default=value, help=f"default {value}")
    parser.add_argument("--resume", action="store_true", help="continue from the run's newest checkpoint")
    parser.add_argument("--quiet", action="store_true", help="no SB3 training log on stdout")


def run(args: argparse.Namespace) -> int:
    config = RLTrainConfig(**{name: getattr(args, name) for name in RLTrainConfig.__dataclass_fields__})
    summary = train(config, args.out, resume=args.resume, progress=not args.quiet)
    print(json.dumps(summary))
    return 0
