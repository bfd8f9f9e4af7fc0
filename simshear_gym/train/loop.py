"""The epoch loop of the translator and GDNN trainers: epochs, time budget, holdout, best model, checkpoint, early
stop, resume, progress bars, tensorboard.

A trainer subclasses :class:`EpochTrainer` and keeps what is its own: data, networks, losses, and what its
checkpoint holds besides the loop's counters (the hooks below). :meth:`EpochTrainer.fit` trains until
``config.epochs`` epochs are done, ``config.patience_epochs`` epochs in a row bring no better holdout metric, or
the time budget ``config.max_minutes`` (training time, counted across resumes) runs out. Each step sets the
learning rate of every optimiser to :func:`~simshear_gym.train.runs.run_lr` of the share of the run done (of its
time budget when it has one, else of its steps): the schedule of the rate, scaled to the batch size and warmed up
where the config asks. A config may also hold ``cap_minutes``: a wall-clock
safety cap on the training time of one ``fit`` call (``stopped_by`` "wall-clock cap",
:data:`~simshear_gym.train.runs.CAP_STOP`) that does not shape the schedule. It stops at once and drops the
unfinished epoch: the trainer goes back to its last finished epoch's checkpoint, so a resumed run (which gets its
own cap) continues as a straight run would and a recipe counted in epochs trains the same model on any machine,
however slow. After each epoch, and in the epoch where the time budget runs out (a partial epoch), it measures
the holdout metric, appends a record to the history, saves ``best.pt`` when the metric improves and writes
``checkpoint.pt`` and ``history.json`` atomically, so ``resume`` continues from the last finished epoch with the
same numbers a straight run would give (the random generators are in the checkpoint).

Run directory: ``config.json`` (written when ``fit`` starts), ``history.json`` (``{"config": ..., "epochs":
[record, ...]}``; a record: ``epoch``, ``partial_epoch``, ``step``, ``elapsed_s``, ``train_<metric>`` (mean training
loss of the epoch's steps), ``holdout_<metric>``), ``checkpoint.pt``, ``best.pt``, tensorboard logs under ``tb/``
(every 20 steps ``train/<loss>`` and ``train/lr``; every epoch ``holdout/<metric>``, against steps and against
whole minutes as ``holdout/<metric>_vs_minutes``, plus what the trainer's ``log_epoch`` adds).

Under torchrun (a :class:`~simshear_gym.train.distributed.Distributed` given) every process runs this loop on its
share of each batch (:meth:`EpochTrainer.local_rows`); rank 0 alone measures the holdout and writes the run
directory, the others take its holdout metric and its clock, so the run stops at the same step everywhere and its
files are those one process writes. A batch needs :meth:`EpochTrainer.min_batch_rows` rows (two per process:
batch norm needs two).
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from simshear_gym.io import atomic_write, write_json
from simshear_gym.train.distributed import Distributed
from simshear_gym.train.runs import CAP_STOP, check_same_settings, run_lr, run_progress

LOG_EVERY_STEPS = 20  # training scalars to tensorboard


class CheckpointError(ValueError):
    """A ``checkpoint.pt`` that cannot be resumed from (unreadable, or holding objects that would run code)."""


def numpy_globals() -> list:
    """What a checkpoint's numpy parts (generator states, arrays, scalars) unpickle through: array and scalar
    reconstruction and the dtypes, nothing that runs code; allowlisted for ``torch.load(weights_only=True)``."""
    try:
        from numpy._core import multiarray
    except ImportError:  # numpy < 2
        from numpy.core import multiarray
    dtypes = [type(np.dtype(code)) for code in "?bBhHiIlLqQefdgFDGUS"]
    return [np.ndarray, np.dtype, multiarray._reconstruct, multiarray.scalar, *dtypes]


def load_checkpoint(path: Path) -> dict:
    """A ``checkpoint.pt`` read with ``torch.load(weights_only=True)`` and numpy's arrays allowlisted
    (:func:`numpy_globals`): a crafted file whose pickle would call anything else is refused, nothing run.

    Raises:
        CheckpointError: naming the file (corrupt, truncated, or not a checkpoint of plain data and tensors).
    """
    try:
        with torch.serialization.safe_globals(numpy_globals()):
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises RuntimeError, UnpicklingError, EOFError...
        reason = " ".join(str(error).split())[:240]
        raise CheckpointError(f"{path}: cannot be resumed from: not a checkpoint of plain data and tensors that "
                              f"loads without running code ({type(error).__name__}: {reason}); delete it to train "
                              "the run afresh") from None
    if not isinstance(state, dict) or "config" not in state:
        raise CheckpointError(f"{path}: not a training checkpoint (expected a table with 'config'); delete it to "
                              "train the run afresh")
    return state


class EpochTrainer(ABC):
    """Base of a trainer run in epochs; see the module docstring.

    ``config`` is a frozen dataclass with at least ``epochs``, ``max_minutes`` (None: no budget),
    ``patience_epochs``, ``lr``, ``lr_schedule``, ``batch_size`` and ``threads`` (and may hold ``lr_scaling``,
    ``reference_batch`` and ``warmup_epochs``: :func:`~simshear_gym.train.runs.run_lr`); ``distributed``: this
    process's place under torchrun (None: the only process). The loop's counters are attributes: ``epoch``
    (finished epochs), ``step`` (optimiser steps), ``elapsed_s`` (training time), ``best_holdout``,
    ``epochs_since_best`` and ``history`` (one record per epoch).

    A subclass sets :attr:`metric` and implements the abstract hooks :meth:`epoch_batches`, :meth:`optimisers`,
    :meth:`train_mode`, :meth:`train_batch`, :meth:`holdout_metric`, :meth:`save_best`, :meth:`trainer_state` and
    :meth:`load_trainer_state` (and may override :meth:`log_epoch`).
    """

    metric: str = "loss"
    """Name of the holdout metric (lower is better): history keys ``train_<metric>`` / ``holdout_<metric>``, the
    checkpoint's and summary's ``best_holdout_<metric>``; ``train_batch`` reports the training loss under it."""
    resume_free: tuple[str, ...] = ("epochs", "max_minutes", "patience_epochs", "cap_minutes", "device", "amp",
                                    "data_on_device", "compile", "tf32")
    """Settings a resumed run may change (where the run trains and how fast, not what it learns)."""
    clock: Callable[[], float] = staticmethod(time.perf_counter)
    """The clock (seconds) that the time budget and the wall-clock cap read; tests give a trainer a clock that
    advances per step, so that budgets and caps are tested alike on a fast, slow or busy machine."""

    def __init__(self, config, run_dir: str | Path, distributed: Distributed | None = None) -> None:
        self.config = config
        self.run_dir = Path(run_dir)
        self.distributed = distributed
        self.epoch = 0
        self.step = 0
        self.best_holdout = math.inf
        self.epochs_since_best = 0
        self.elapsed_s = 0.0
        self.history: list[dict] = []

    # ----------------------------------------------------------------------------------------------- hooks
    @abstractmethod
    def epoch_batches(self) -> list[np.ndarray]:
        """The row indices of each of the next epoch's batches (drawn from the trainer's own generator); batches
        of fewer than two rows are skipped but count in the schedule's steps per epoch."""

    @abstractmethod
    def optimisers(self) -> list[torch.optim.Optimizer]:
        """The optimisers whose learning rate follows the schedule."""

    @abstractmethod
    def train_mode(self) -> None:
        """Put the trained networks in training mode (``fit`` calls it once, at the start)."""

    @abstractmethod
    def train_batch(self, index: np.ndarray) -> dict[str, float]:
        """One optimiser step on the training rows ``index``; returns the step's losses by name (the main one
        under :attr:`metric`)."""

    @abstractmethod
    def holdout_metric(self) -> float:
        """The metric on the held-out rows (lower is better); leaves the networks in training mode."""

    @abstractmethod
    def save_best(self, path: Path, card: dict[str, Any]) -> None:
        """Save the network(s) as the run's best to ``path``, with ``card`` (``holdout_<metric>``, ``epoch``,
        ``elapsed_s``) in the file."""

    @abstractmethod
    def trainer_state(self) -> dict:
        """What the checkpoint holds besides the loop's counters: weights, optimisers, random generators."""

    @abstractmethod
    def load_trainer_state(self, state: dict) -> None:
        """Restore :meth:`trainer_state` from a checkpoint's ``state``."""

    def log_epoch(self, writer: SummaryWriter) -> None:
        """Write more to tensorboard after each epoch's holdout (nothing by default)."""

    # ------------------------------------------------------------------------------------ data parallelism
    @property
    def is_main(self) -> bool:
        """Whether this process writes the run directory (the only process, or rank 0 under torchrun)."""
        return self.distributed is None or self.distributed.is_main

    def local_rows(self, batch_rows: int) -> slice | list[int]:
        """This process's positions in a batch of ``batch_rows`` rows: all of them (``slice(None)``) in one
        process, its share under torchrun (:meth:`~simshear_gym.train.distributed.Distributed.rows`)."""
        return slice(None) if self.distributed is None else self.distributed.rows(batch_rows)

    def min_batch_rows(self) -> int:
        """The fewest rows a batch needs to be trained on (two per process); smaller ones are skipped."""
        return 2 if self.distributed is None else self.distributed.min_batch_rows()

    def _shared(self, value: float) -> float:
        """Rank 0's ``value`` on every process (``value`` itself in one process)."""
        return value if self.distributed is None else self.distributed.share(value)

    # ----------------------------------------------------------------------------------------- persistence
    def state(self) -> dict:
        """Everything ``checkpoint.pt`` holds: the config, the loop's counters, then :meth:`trainer_state`."""
        return {
            "config": asdict(self.config), "epoch": self.epoch, "step": self.step,
            f"best_holdout_{self.metric}": self.best_holdout, "epochs_since_best": self.epochs_since_best,
            "elapsed_s": self.elapsed_s, "history": self.history,
            **self.trainer_state(),
        }

    def save_checkpoint(self) -> None:
        """Write ``checkpoint.pt`` (:meth:`state`) and ``history.json`` atomically, so that a crash mid-write leaves
        the previous files whole (rank 0 only under torchrun)."""
        if self.is_main:
            state = self.state()
            atomic_write(self.run_dir / "checkpoint.pt", lambda tmp: torch.save(state, tmp))
            write_json(self.run_dir / "history.json", {"config": asdict(self.config), "epochs": self.history})

    def resume(self) -> bool:
        """Continue from ``checkpoint.pt`` if there is one; returns whether it did. Refuses a checkpoint trained
        with other settings (outside :attr:`resume_free`) and one that would run code (:func:`load_checkpoint`)."""
        path = self.run_dir / "checkpoint.pt"
        if not path.is_file():
            return False
        state = load_checkpoint(path)
        check_same_settings(path, state["config"], self.config, self.resume_free)
        self.load_trainer_state(state)
        self.epoch, self.step = state["epoch"], state["step"]
        self.best_holdout, self.epochs_since_best = state[f"best_holdout_{self.metric}"], state["epochs_since_best"]
        self.elapsed_s, self.history = state["elapsed_s"], state["history"]
        return True

    # -------------------------------------------------------------------------------------------- training
    def fit(self, progress: bool = True) -> dict:
        """Train until the epochs, the patience or the time budget run out (``progress``: show a bar per epoch);
        returns a summary: ``epochs``, ``steps``, ``elapsed_s``, ``best_holdout_<metric>``, ``stopped_by``."""
        config = self.config
        torch.set_num_threads(config.threads)
        if self.is_main:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            write_json(self.run_dir / "config.json", asdict(config))
        writer = SummaryWriter(str(self.run_dir / "tb")) if self.is_main else _NoWriter()
        budget_s = config.max_minutes * 60.0 if config.max_minutes else math.inf
        cap_minutes = getattr(config, "cap_minutes", None)
        cap_s = self.elapsed_s + cap_minutes * 60.0 if cap_minutes else math.inf  # this call's training time
        stop_reason = "epochs"
        self.train_mode()
        try:
            while self.epoch < config.epochs:
                started = self.clock() - self.elapsed_s
                stopped, train_losses = self._train_epoch(writer, started, budget_s, cap_s, progress)
                if stopped == CAP_STOP:
                    stop_reason = stopped
                    self._back_to_last_epoch()
                    break
                out_of_time = stopped is not None
                self.epoch += 0 if out_of_time else 1
                self._end_epoch(writer, started, out_of_time, train_losses)
                if out_of_time:
                    stop_reason = stopped
                    break
                if self.epochs_since_best >= config.patience_epochs:
                    stop_reason = "early stopping"
                    break
        finally:
            writer.close()
        if self.distributed is not None:
            self.distributed.barrier()  # the others wait for rank 0's last files
        return {"epochs": self.epoch, "steps": self.step, "elapsed_s": round(self.elapsed_s, 1),
                f"best_holdout_{self.metric}": self.best_holdout, "stopped_by": stop_reason}

    def _train_epoch(self, writer: SummaryWriter, started: float, budget_s: float, cap_s: float,
                     progress: bool) -> tuple[str | None, list[float]]:
        """One epoch's steps, or those done before the training time reaches ``cap_s`` (the wall-clock cap) or
        ``budget_s`` (the time budget); returns (what stopped it: :data:`CAP_STOP`, "time budget" or None, the
        steps' training losses). The schedule follows the time budget only."""
        config = self.config
        batches = self.epoch_batches()
        losses_seen = []
        for index in tqdm(batches, desc=f"epoch {self.epoch + 1}/{config.epochs}",
                          disable=not progress or not self.is_main, leave=False):
            if len(index) < self.min_batch_rows():  # batch norm needs two rows (per process)
                continue
            done = run_progress(self.elapsed_s, budget_s, self.step, config.epochs * len(batches))
            lr = run_lr(config, done)
            for optimiser in self.optimisers():
                for group in optimiser.param_groups:
                    group["lr"] = lr
            losses = self.train_batch(index)
            if self.distributed is not None:
                losses = self.distributed.mean(losses)
            losses_seen.append(losses[self.metric])
            self.step += 1
            if self.step % LOG_EVERY_STEPS == 0:
                for name, value in losses.items():
                    writer.add_scalar(f"train/{name}", value, self.step)
                writer.add_scalar("train/lr", lr, self.step)
            self.elapsed_s = self._shared(self.clock() - started)  # every process stops at one step
            if self.elapsed_s > cap_s:
                return CAP_STOP, losses_seen
            if self.elapsed_s > budget_s:
                return "time budget", losses_seen
        return None, losses_seen

    def _back_to_last_epoch(self) -> None:
        """After the wall-clock cap: drop the unfinished epoch (weights, optimisers, generators and counters back
        to the last checkpoint), so that a resumed run trains on as a straight run would; with no checkpoint yet
        (a cap below one epoch's time, which no rerun could pass) a ValueError."""
        if self.distributed is not None:
            self.distributed.barrier()  # rank 0's checkpoint is whole before anyone reads it
        if not self.resume():
            raise ValueError(f"{self.run_dir}: the wall-clock cap (cap_minutes = {self.config.cap_minutes}) "
                             "stopped the run inside its first epoch; give it a cap above one epoch's time")

    def _end_epoch(self, writer: SummaryWriter, started: float, partial: bool, train_losses: list[float]) -> None:
        """Holdout, history record, best model and checkpoint after an epoch (or the partial one at the budget)."""
        metric = self.metric
        holdout = self._shared(self.holdout_metric() if self.is_main else 0.0)
        self.elapsed_s = self._shared(self.clock() - started)
        self.history.append({"epoch": self.epoch, "partial_epoch": partial, "step": self.step,
                             "elapsed_s": round(self.elapsed_s, 1),
                             f"train_{metric}": float(np.mean(train_losses)) if train_losses else None,
                             f"holdout_{metric}": holdout})
        writer.add_scalar(f"holdout/{metric}", holdout, self.step)
        writer.add_scalar(f"holdout/{metric}_vs_minutes", holdout, int(self.elapsed_s / 60))
        if self.is_main:
            self.log_epoch(writer)
        if holdout < self.best_holdout:
            self.best_holdout, self.epochs_since_best = holdout, 0
            if self.is_main:
                self.save_best(self.run_dir / "best.pt",
                               {f"holdout_{metric}": holdout, "epoch": self.epoch, "elapsed_s": self.elapsed_s})
        else:
            self.epochs_since_best += 1
        self.save_checkpoint()


class _NoWriter:
    """The tensorboard writer of a process that writes nothing (not rank 0)."""

    def add_scalar(self, *args, **kwargs) -> None:
        pass

    def close(self) -> None:
        pass
