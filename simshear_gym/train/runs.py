"""What every training run in ``train/`` shares: the learning-rate schedule, the holdout split, the resume settings
check. Torch-free, so that the command modules can build their parsers without it; the checkpoint itself is
written by :mod:`simshear_gym.train.loop`."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

LR_SCHEDULES = ("constant", "cosine")

CAP_STOP = "wall-clock cap"
"""``stopped_by`` of a training stopped by its ``cap_minutes`` safety cap: not the recipe's model (it stopped at
its last finished epoch; a resumed run continues it)."""


def scheduled_lr(lr: float, schedule: str, progress: float) -> float:
    """Learning rate after ``progress`` (0..1) of a run: ``constant``, or ``cosine`` (decays to 0 at the end)."""
    if schedule not in LR_SCHEDULES:
        raise ValueError(f"lr_schedule must be one of {LR_SCHEDULES}, got {schedule!r}")
    if schedule == "constant":
        return lr
    return lr * 0.5 * (1.0 + math.cos(math.pi * min(max(progress, 0.0), 1.0)))


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
    """Refuse to resume ``path`` when its run's settings differ from ``config`` outside the ``free`` ones."""
    saved = {k: tuple(v) if isinstance(v, list) else v for k, v in saved_config.items() if k not in free}
    mine = {k: v for k, v in asdict(config).items() if k not in free}
    if saved != mine:
        changed = sorted(k for k in mine if saved.get(k) != mine[k])
        raise ValueError(f"{path}: trained with other settings ({changed}); to train with different settings, use "
                         "a new --out")

