"""What every training run in ``train/`` shares: the learning-rate schedule, the holdout split, the resume settings
check, the help of the flags the translator and posenet commands share, and their ``run``'s body. Torch-free, so
that the command modules can build their parsers without it; the checkpoint itself is written by
:mod:`simshear_gym.train.loop`."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import MISSING, asdict, fields
from pathlib import Path

import numpy as np

from simshear_gym.models.device import DEVICES, check_device_name

LR_SCHEDULES = ("constant", "cosine")
LR_SCALINGS = ("none", "linear", "sqrt")
"""How a run's learning rate follows its batch size (:func:`batch_scaled_lr`)."""
DATA_PLACEMENTS = ("auto", "on", "off")
"""Where a run's training rows live (``data_on_device``): ``on`` the training device (batches gathered and augmented
there), ``off`` on the CPU (each batch built there and copied over), ``auto``: on the device when it is a GPU."""

RUN_CHOICES = {"lr_schedule": LR_SCHEDULES, "device": DEVICES, "lr_scaling": LR_SCALINGS,
               "data_on_device": DATA_PLACEMENTS}
"""The values the flags of the run settings that ``simshear train translator`` and ``posenet`` share accept."""
BUDGET_FLAG_HELP = {
    "max_minutes": "stop after this much training time (counted across --resume); the run is checkpointed there",
    "cap_minutes": "wall-clock safety cap: stop after this much training time of this run, back at its last "
                   "finished epoch (--resume continues it), without changing the schedule (which runs over the "
                   "epochs unless --max-minutes is given)",
}
"""Help of the time-budget flags of ``simshear train translator`` and ``posenet``."""

CAP_STOP = "wall-clock cap"
"""``stopped_by`` of a training stopped by its ``cap_minutes`` safety cap: not the recipe's model (it stopped at
its last finished epoch; a resumed run continues it)."""


def check_choice(name: str, value, choices: tuple) -> None:
    """A ValueError naming the valid values unless setting ``name``'s ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")


def device_flag_help(network: str, reference_batch: int) -> dict[str, str]:
    """Help of the device and GPU flags of ``simshear train translator`` and ``posenet``, in their order, for a run
    that trains the ``network`` ("generator", "GDNN") with an ``lr`` tuned at ``reference_batch``."""
    return {
        "device": "where to train: auto (CUDA where torch finds it, else the CPU), cpu or cuda (an error without "
                  "CUDA); under torchrun each process takes GPU LOCAL_RANK",
        "amp": "on CUDA, no mixed precision (bf16 autocast, or fp16 with loss scaling where the GPU lacks bf16); the "
               "CPU always trains in float32",
        "lr_scaling": f"scale --lr from the batch it was tuned at ({reference_batch}) to --batch-size: none, linear (x "
                      "the ratio) or sqrt (x its square root, the rule for Adam)",
        "warmup_epochs": "ramp the rate up linearly from 0 over this many epochs",
        "data_on_device": "keep the training rows on the training device, batches gathered there: on, off, or auto (on "
                          "a GPU); the same batches either way",
        "compile": f"run the {network} through torch.compile (the eager {network}, after one warning, where it cannot "
                   "compile)",
        "tf32": "on CUDA, float32 matrix products and convolutions in full float32, not TF32",
    }


def scheduled_lr(lr: float, schedule: str, progress: float) -> float:
    """Learning rate after ``progress`` (0..1) of a run: ``constant``, or ``cosine`` (decays to 0 at the end)."""
    check_choice("lr_schedule", schedule, LR_SCHEDULES)
    if schedule == "constant":
        return lr
    return lr * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


def batch_scaled_lr(lr: float, batch_size: int, reference_batch: int, scaling: str) -> float:
    """The peak learning rate of a run of ``batch_size`` rows per step whose ``lr`` was tuned at
    ``reference_batch``: ``none`` keeps ``lr``; ``linear`` multiplies it by ``batch_size / reference_batch`` (the
    same step per row seen, for SGD-like updates); ``sqrt`` by the square root of that ratio (the rule for Adam,
    whose step size does not grow with the gradient's scale: the gradient's noise falls as the square root of the
    batch)."""
    check_choice("lr_scaling", scaling, LR_SCALINGS)
    ratio = batch_size / reference_batch
    return lr * {"none": 1.0, "linear": ratio, "sqrt": math.sqrt(ratio)}[scaling]


def warmup_factor(progress: float, warmup_share: float) -> float:
    """The share of its learning rate a run takes after ``progress`` (0..1) with a linear warm-up over the first
    ``warmup_share`` of it (1 throughout when ``warmup_share`` is 0): a large batch's scaled rate would throw
    the freshly initialised weights about in the first steps."""
    if warmup_share <= 0 or progress >= warmup_share:
        return 1.0
    return max(progress, 0.0) / warmup_share


def run_lr(config, progress: float) -> float:
    """The learning rate of a training run (a trainer config: ``lr``, ``lr_schedule``, ``batch_size``,
    ``lr_scaling``, ``reference_batch``, ``warmup_epochs``, ``epochs``) after ``progress`` (0..1) of it: the
    schedule of the batch-scaled peak rate, times the warm-up."""
    peak = batch_scaled_lr(config.lr, config.batch_size, config.reference_batch, config.lr_scaling)
    share = config.warmup_epochs / config.epochs
    return scheduled_lr(peak, config.lr_schedule, progress) * warmup_factor(progress, share)


def data_on_device(setting: str, device_type: str) -> bool:
    """Whether a run with ``data_on_device`` = ``setting`` keeps its training rows on its device (of
    ``device_type``: "cpu" or "cuda")."""
    return setting == "on" or (setting == "auto" and device_type == "cuda")


def check_run_knobs(config) -> None:
    """Raise a ValueError naming the valid values unless a trainer config's ``lr_schedule``, ``device``,
    ``lr_scaling``, ``warmup_epochs``, ``data_on_device``, ``compile`` and ``tf32`` are valid."""
    check_choice("lr_schedule", config.lr_schedule, LR_SCHEDULES)
    check_device_name(config.device)
    batch_scaled_lr(config.lr, config.batch_size, config.reference_batch, config.lr_scaling)
    if not 0.0 <= config.warmup_epochs <= config.epochs:
        raise ValueError(f"warmup_epochs must be in [0, epochs = {config.epochs}], got {config.warmup_epochs!r}")
    check_choice("data_on_device", config.data_on_device, DATA_PLACEMENTS)
    for name in ("compile", "tf32"):
        if not isinstance(getattr(config, name), bool):
            raise ValueError(f"{name} must be true or false, got {getattr(config, name)!r}")


def run_progress(elapsed_s: float, budget_s: float, step: int, total_steps: int) -> float:
    """Share of a run done: of its time budget when it has one (``budget_s`` finite), else of its steps."""
    return elapsed_s / budget_s if math.isfinite(budget_s) else step / max(total_steps, 1)


def split_holdout(n_rows: int, share: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, holdout rows): a seeded permutation, ``share`` of the rows (at least one) held out."""
    order = np.random.default_rng(seed).permutation(n_rows)
    n_holdout = max(1, int(round(share * n_rows)))
    if n_rows - n_holdout < 2:
        raise ValueError(f"{n_rows} rows are too few to hold out {n_holdout} and train")
    return order[n_holdout:], order[:n_holdout]


def check_same_settings(path: Path, saved_config: dict, config, free: tuple[str, ...]) -> None:
    """Refuse to resume ``path`` when its run's settings differ from ``config`` outside the ``free`` ones; a
    setting the saved run predates counts as its default (a checkpoint written before a knob existed trained as the
    knob's default does)."""
    defaults = {item.name: item.default for item in fields(config) if item.default is not MISSING}
    saved = {k: tuple(v) if isinstance(v, list) else v for k, v in {**defaults, **saved_config}.items()
             if k not in free}
    mine = {k: v for k, v in asdict(config).items() if k not in free}
    if saved != mine:
        changed = sorted(k for k in mine if saved.get(k) != mine[k])
        raise ValueError(f"{path}: trained with other settings ({changed}); to train with different settings, use "
                         "a new --out")


def train_command(args, config, make_trainer: Callable) -> dict | None:
    """``simshear train translator|posenet``'s run: in a torchrun session (:mod:`simshear_gym.train.distributed`)
    the trainer ``make_trainer(distributed)`` resumed (``--resume``) and fitted (``--wandb``: mirrored to W&B);
    returns the summary, printed, on rank 0 (None on the others)."""
    from simshear_gym.train.distributed import distributed_session
    from simshear_gym.train.wandb_sync import wandb_run

    if (args.out / "checkpoint.pt").exists() and not args.resume:
        raise ValueError(f"{args.out / 'checkpoint.pt'} exists: pass --resume to continue it or use a new --out")
    with distributed_session(config.device) as distributed:
        trainer = make_trainer(distributed)
        resumed = args.resume and trainer.resume()
        if resumed and trainer.is_main:
            print(f"resumed from {args.out / 'checkpoint.pt'} at epoch {trainer.epoch}")
        with wandb_run(args.wandb if trainer.is_main else None, args.out, asdict(config)):
            summary = trainer.fit(progress=trainer.is_main)
    if not trainer.is_main:
        return None
    print(json.dumps(summary))
    return summary
