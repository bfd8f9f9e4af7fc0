"""Train a Stable-Baselines3 agent (PPO, SAC, or sb3-contrib's TQC) on ``SimShearTracking-v0`` or ``SimShearCoLift-v0``.

``simshear train rl --algo ppo --out runs/rl/ppo --timesteps N`` trains on randomised episodes (``trajectory=
"random"``, ``randomise=True``: the trajectory's scale, speed, turn and the start place drawn per reset; co-lift:
sub-env i carries object i mod 4) in what a robot can give a policy:

- ``--observation tactile`` (default): the env's image (``--obs-mode real``: translated by the shipped
  shPix2pix, as on the robot; ``sim``: raw renders) and the TCP pose; SB3's ``MultiInputPolicy`` puts a CNN on the
  image (at least 36 px: 64 px by default, half the policy's cost at the same translation cost);
- ``--observation estimate``: the servo controller's estimator (the env's shipped GDNN + Bayesian filter) on that
  image, its reading and filter state normalised (16 numbers a frame): an MLP;
- ``--observation tactile+estimate``: both; ``--history k`` stacks the last k frames and estimates;
- ``--observation estimate+action``: the estimate and the last action taken (over the full scale): with two frames a
  policy can carry a PI law's integral in its action (the ``--bc-steps`` teacher is the law in velocity form).

Set-up: ``--n-envs`` sub-envs, stepped in worker processes (``--vec subproc``, one torch thread each), in this
one (``--vec dummy``), or in SimShearTracking-v0's batched vector env (``--vec batched``, image-only tracking
policies: one worker per core translates its sub-envs' images in one batch, :mod:`simshear_gym.train.rl_vec`);
``VecNormalize`` (observations but the image; rewards for PPO) unless
``--no-normalize``. Options: ``--residual-bound B``: residual RL, the policy's action a correction of at most B
full-scale actions added to the servo law on the filter's estimate
(:class:`~simshear_gym.control.policy.ResidualServo`; needs an estimate observation); ``--asymmetric-critic``
(PPO): the critic also sees the true contact state (the env's ``true_pose_shear``,
:mod:`simshear_gym.control.asymmetric`), the actor only the observation above; the deployed policy needs no true
state (the controller fills those inputs with zeros, which the actor never reads); ``--bc-steps N`` (PPO, estimate
observations): the policy starts as a clone of the servo controller's law, fitted on N steps of it acting (and
``--bc-rounds`` - 1 rounds of DAgger), the critic on their returns (:mod:`simshear_gym.train.rl_imitation`;
``imitation.json`` in the run folder).

Training stops at ``--timesteps`` env steps or after ``--minutes`` of wall-clock time in this invocation, whichever
comes first. Every ``--eval-steps`` env steps (and at the end) the deterministic policy runs the nominal episodes
(tracking: circle, tilted square, spiral, loop; co-lift: the four objects on the circular wave), capped at
``--eval-max-steps`` steps; the mean contact error per episode and over them, the steps run and the early ends go
to tensorboard (``eval/*`` against env steps: the learning curve) and ``evaluations.json``.

Run directory: ``config.json`` (these settings and the residual law's gains: what
:meth:`~simshear_gym.control.policy.SB3Controller.load` reads to rebuild the env's observation), tensorboard logs
``tb/``, ``checkpoints/rl_model_<steps>_steps.zip`` with ``rl_model_vecnormalize_<steps>_steps.json`` every
``--checkpoint-steps``, ``evaluations.json`` and ``learning_curve.png``, ``best_model.zip`` with
``best_model_vecnormalize.json`` (the evaluation with the lowest mean contact error among those without an early
end, else the lowest), and the final ``model.zip`` with ``vecnormalize.json``, ``summary.json``; beside every
``<stem>.zip`` the policy's pickle-free ``<stem>.pt`` and ``<stem>.json``, what controllers load
(:mod:`~simshear_gym.control.policy_files`; no pickle is written). ``--resume`` continues from the newest
checkpoint (or ``model.zip``, read without unpickling) and its normalisation statistics, the step count carried
on (SAC's replay buffer starts empty). Evaluate: ``simshear evaluate servo --variants ppo --policy-ppo
OUT/model.pt``; on the robot: ``simshear rollout --policy OUT/model.pt``.

This module is the command, its flags and its settings; it imports no torch (``--help`` stays fast). The trainer
is :mod:`simshear_gym.train.rl_trainer`, the settings :mod:`simshear_gym.train.rl_config`.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from simshear_gym.contract import OBSERVATIONS
from simshear_gym.models.device import DEVICES
from simshear_gym.train.flags import config_flags
from simshear_gym.train.rl_config import (
    ALGORITHMS,
    OBS_MODES,
    PRESETS,
    TASKS,
    VEC_ENVS,
    RLTrainConfig,
    latest_checkpoint,
)
from simshear_gym.train.wandb_sync import FLAG_HELP as WANDB_HELP

__all__ = ["RLTrainConfig", "add_arguments", "config_of", "latest_checkpoint", "run", "train"]

def train(config: RLTrainConfig, run_dir: Path, resume: bool = False, progress: bool = True) -> dict:
    """Train (or continue) a run; returns its summary (:func:`simshear_gym.train.rl_trainer.train`)."""
    from simshear_gym.train.rl_trainer import train as run_training

    return run_training(config, Path(run_dir), resume=resume, progress=progress)


FLAG_HELP = {
    "algo": "SB3 algorithm (tqc: sb3-contrib's TQC, SAC with a distributional critic; needs sb3-contrib)",
    "task": "env: tracking (SimShearTracking-v0), colift (SimShearCoLift-v0; sub-env i carries object i mod 4), "
            "edge (SimShearEdgeFollow-v0, random outlines) or push (SimShearPush-v0, random shapes)",
    "timesteps": "env steps to train in all (a resumed run trains until its step count reaches this; 0 with "
                 "--bc-steps: the servo law's clone, no RL)",
    "minutes": "wall-clock budget of this invocation: stop (and save) after this many minutes",
    "observation": "what the policy sees: tactile (image + TCP pose), estimate (the servo controller's GDNN + filter "
                   "estimate of the image, normalised), tactile+estimate, estimate+action (the estimate and the last "
                   "action)",
    "history": "the observation stacks the last HISTORY images / estimates",
    "obs_mode": "tactile images the policy (or its estimator) sees: real (sim renders through the shipped "
                "translator, as on the robot) or sim (the raw sim renders)",
    "image_size_px": "tactile image size in px: 64 or 128 (the policy's CNN needs at least 36)",
    "randomise": "domain randomisation per reset: trajectory scale, speed, turn and start place (--no-randomise: "
                 "nominal episodes of random trajectories)",
    "n_envs": "sub-envs stepped side by side",
    "vec": "subproc: sub-envs in worker processes (one torch thread each; use the cores), dummy: in this process, "
           "batched: SimShearTracking-v0's batched vector env (sub-envs in one worker per core, each worker "
           "translating its sub-envs' images in one batch; --task tracking --observation tactile only)",
    "n_steps": "PPO: env steps per sub-env between updates",
    "batch_size": "minibatch size of the updates",
    "n_epochs": "PPO: passes over each rollout",
    "gamma": "discount factor",
    "learning_rate": "Adam learning rate",
    "net_arch": "hidden layer widths of the policy and value networks (default: the algorithm's, PPO 64 64, "
                "SAC 256 256)",
    "normalize": "VecNormalize: running mean/std normalisation of the observations but the image (and of PPO's "
                 "rewards), saved with the model (--no-normalize: off)",
    "residual_bound": "residual RL: the policy adds at most this many full-scale actions to the servo law's action "
                      "(needs an estimate observation; 0: the policy acts alone)",
    "asymmetric_critic": "PPO: the critic also sees the true contact state (depth, shear), the actor only the "
                         "observation (asymmetric actor-critic; the deployed policy needs no true state)",
    "bc_steps": "PPO: first clone the servo controller's law (on the filter estimate) into the policy from this many "
                "env steps of it acting (0: start from a random policy; simshear_gym.train.rl_imitation)",
    "bc_rounds": "DAgger: after the first fit, this many - 1 more rounds of BC_STEPS steps in which the clone acts and "
                 "the law labels each step, the fit redone on all rounds' steps",
    "bc_epochs": "passes of the clone's fit over the steps",
    "bc_noise": "std (full-scale actions) of the noise added to the law's actions while cloning, and the cloned "
                "policy's action std",
    "eval_steps": "evaluate the deterministic policy on the nominal episodes every this many env steps (0: never)",
    "eval_max_steps": "cap on each evaluation episode's steps",
    "checkpoint_steps": "write checkpoints/rl_model_<steps>_steps.zip (+ its VecNormalize statistics) every this "
                        "many env steps",
    "seed": "seed of the envs and the agent",
    "threads": "torch CPU threads of this process",
    "device": "where the policy trains: cpu (the default: the envs step on the CPU and the policies are small), "
              "auto (CUDA where torch finds it, else the CPU) or cuda (an error without CUDA); the trained policy "
              "loads on any device",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--preset", choices=sorted(PRESETS), default=None,
                        help="start from named settings (every flag given beside it wins): tracking-first, a "
                             "tracking policy on a 2-core CPU (the servo law's DAgger clone on estimate+action, then "
                             "a short PPO phase; its budget and error: docs/first_policy.md); edge-first and "
                             "push-first, the same on the edge following and pushing envs")
    config_flags(parser, RLTrainConfig, FLAG_HELP,
                 choices={"algo": ALGORITHMS, "task": TASKS, "observation": OBSERVATIONS, "obs_mode": OBS_MODES,
                          "vec": VEC_ENVS, "device": DEVICES})
    # a setting's flag left out reads None here, so that a preset can fill it (config_of); the help texts still
    # show the dataclass defaults, which fill what neither gives
    parser.set_defaults(**{name: None for name in FLAG_HELP})
    parser.add_argument("--resume", action="store_true", help="continue from the run's newest checkpoint")
    parser.add_argument("--quiet", action="store_true", help="no SB3 training log on stdout")
    parser.add_argument("--wandb", default=None, metavar="PROJECT", help=WANDB_HELP)


def config_of(args: argparse.Namespace) -> RLTrainConfig:
    """The run's settings: the flags given, then ``--preset``'s values (:data:`PRESETS`), then the defaults."""
    given = {name: getattr(args, name) for name in FLAG_HELP if getattr(args, name, None) is not None}
    given = {name: tuple(value) if isinstance(value, list) else value for name, value in given.items()}
    preset = PRESETS[args.preset] if getattr(args, "preset", None) else {}
    return RLTrainConfig(**{**preset, **given})


def run(args: argparse.Namespace) -> int:
    from simshear_gym.train.wandb_sync import wandb_run

    config = config_of(args)
    with wandb_run(args.wandb, args.out, asdict(config)):
        summary = train(config, args.out, resume=args.resume, progress=not args.quiet)
    print(json.dumps(summary))
    return 0
