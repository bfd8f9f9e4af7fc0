"""Mixed precision of a training step on CUDA, and its memory layout (``channels_last``) on every device.

:class:`MixedPrecision` wraps a step's forward passes in ``torch.autocast`` (bf16 where the GPU has it, else fp16
with a ``GradScaler`` against underflowing gradients) and its backward and optimiser steps in the scaler's calls;
disabled (the CPU, or ``amp`` off) every call is the plain one. Losses are computed in float32 from the autocast
outputs (``.float()``), so the holdout metrics and the checkpoints stay float32.
"""

from __future__ import annotations

import contextlib

import torch


def autocast_dtype(device: torch.device, amp: bool) -> torch.dtype | None:
    """The autocast dtype of a run on ``device`` with ``amp`` asked for: None (full precision) off CUDA or without
    ``amp``; bf16 where the GPU supports it, else fp16."""
    if not amp or device.type != "cuda":
        return None
    return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16


def memory_format(device: torch.device) -> torch.memory_format:
    """``channels_last`` on every device: CUDA's convolutions (tensor cores above all) run faster in it, and so do
    the CPU's, max pooling above all (one thread, two processes side by side as the pipeline runs them: a GDNN
    step 1.6x, a translator step 1.06-1.26x faster than in the default layout; ``simshear evaluate train-speed``,
    ``results/ablations/train_speed.json``).
    Saved weights are layout-free: they load into a model in either layout."""
    del device  # the layout is the same everywhere; the argument keeps the call sites device-aware
    return torch.channels_last


class MixedPrecision:
    """Autocast and gradient scaling for one run; ``dtype`` None: full precision (every call the plain one)."""

    def __init__(self, device: torch.device, dtype: torch.dtype | None) -> None:
        self.device_type = device.type
        self.dtype = dtype
        self.scaler = torch.amp.GradScaler(device.type, enabled=dtype == torch.float16)

    @property
    def enabled(self) -> bool:
        return self.dtype is not None

    def autocast(self) -> contextlib.AbstractContextManager:
        """The context of a step's forward passes."""
        if self.dtype is None:
            return contextlib.nullcontext()
        return torch.autocast(self.device_type, dtype=self.dtype)

    def backward(self, loss: torch.Tensor) -> None:
        self.scaler.scale(loss).backward()

    def step(self, optimiser: torch.optim.Optimizer) -> None:
        """``optimiser.step()`` (skipped by the fp16 scaler where a gradient overflowed)."""
        self.scaler.step(optimiser)

    def update(self) -> None:
        """After the step's last optimiser step: adapt the fp16 loss scale."""
        self.scaler.update()
