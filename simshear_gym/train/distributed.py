"""Data-parallel training under ``torchrun``: which process this is, its share of each batch, and what the
processes agree on.

``torchrun --nproc_per_node N`` starts N copies of a command and tells each its place in the environment
(``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``); :func:`distributed_session` reads it, joins the process group (gloo on
the CPU, nccl on CUDA, one GPU per process: ``cuda:LOCAL_RANK``) and yields a :class:`Distributed`; without
torchrun (or with one process) it yields None and a trainer runs exactly as it always has.

How the processes split the work (:class:`~simshear_gym.train.loop.EpochTrainer`): every process draws the same
batches from the same seeded generators (so the epochs, steps, learning-rate schedule and the generators' states
in the checkpoint are those of one process), and each trains on its share of every batch
(:meth:`Distributed.rows`, a ``DistributedSampler`` over the batch's rows); ``DistributedDataParallel`` averages
the gradients. Rank 0 alone measures the holdout, writes the run directory and prints; the others take its
holdout metric and its clock (:meth:`Distributed.share`), so that all of them stop at the same step.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DistributedSampler

from simshear_gym.models.device import resolve_device

ENVIRONMENT = ("RANK", "WORLD_SIZE", "LOCAL_RANK")


def torchrun_place(environ: Mapping[str, str] | None = None) -> tuple[int, int, int] | None:
    """(rank, world size, local rank) that torchrun set in ``environ`` (default ``os.environ``); None without
    torchrun or with one process."""
    environ = os.environ if environ is None else environ
    if int(environ.get("WORLD_SIZE", "1")) <= 1:
        return None
    missing = [name for name in ENVIRONMENT if name not in environ]
    if missing:
        raise ValueError(f"WORLD_SIZE={environ['WORLD_SIZE']} but {missing} unset: start several processes with "
                         "torchrun --nproc_per_node N, which sets all of RANK, WORLD_SIZE and LOCAL_RANK")
    rank, world_size, local_rank = (int(environ[name]) for name in ENVIRONMENT)
    return rank, world_size, local_rank


@dataclass(frozen=True)
class Distributed:
    """This process's place in a data-parallel run and the device it trains on."""

    rank: int
    world_size: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def rows(self, batch_rows: int) -> list[int]:
        """This process's positions in a batch of ``batch_rows`` rows: every ``world_size``-th, padded from the
        batch's start so that every process gets ``ceil(batch_rows / world_size)``."""
        return list(DistributedSampler(range(batch_rows), num_replicas=self.world_size, rank=self.rank,
                                       shuffle=False))

    def min_batch_rows(self) -> int:
        """The fewest rows a batch needs for every process to get two (batch norm needs two rows)."""
        return self.world_size + 1

    def wrap(self, module: nn.Module) -> DistributedDataParallel:
        """``module`` (already on :attr:`device`) in DistributedDataParallel; the module itself keeps its state
        dict keys (no ``module.`` prefix), so checkpoints are written from it."""
        ids = [self.device.index] if self.device.type == "cuda" else None
        return DistributedDataParallel(module, device_ids=ids)

    def share(self, value: float) -> float:
        """Rank 0's ``value`` on every process."""
        tensor = torch.tensor([value], dtype=torch.float64, device=self.device)
        dist.broadcast(tensor, src=0)
        return float(tensor.item())

    def mean(self, values: Mapping[str, float]) -> dict[str, float]:
        """Each value averaged over the processes (every process gives the same names)."""
        names = sorted(values)
        tensor = torch.tensor([values[name] for name in names], dtype=torch.float64, device=self.device)
        dist.all_reduce(tensor)
        return {name: float(total) / self.world_size for name, total in zip(names, tensor.tolist())}

    def barrier(self) -> None:
        if self.device.type == "cuda":
            dist.barrier(device_ids=[self.device.index])
        else:
            dist.barrier()


@contextmanager
def distributed_session(device_name: str) -> Iterator[Distributed | None]:
    """Join the torchrun process group for the run (see the module docstring); None without torchrun."""
    place = torchrun_place()
    if place is None:
        yield None
        return
    rank, world_size, local_rank = place
    device = resolve_device(device_name, index=local_rank)
    if device.type == "cuda":
        if local_rank >= torch.cuda.device_count():
            raise ValueError(f"LOCAL_RANK {local_rank}: this machine has {torch.cuda.device_count()} CUDA devices; "
                             "start at most that many processes per node (--nproc_per_node)")
        torch.cuda.set_device(device)
    dist.init_process_group("nccl" if device.type == "cuda" else "gloo", rank=rank, world_size=world_size)
    try:
        yield Distributed(rank, world_size, device)
        # every rank finished (rank 0's last writes too) before the group goes: a rank that tore its group down
        # while a peer still talked to it aborted at exit on a loaded CPU ("terminate called without an active
        # exception"); after an error no barrier, which a dead peer would never reach
        dist.barrier()
    finally:
        dist.destroy_process_group()

