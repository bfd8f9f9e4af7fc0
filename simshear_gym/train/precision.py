"""Mixed precision of a training step on CUDA, and its memory layout (``channels_last``) on every device; TF32 and
``torch.compile`` for the GPU path.

:class:`MixedPrecision` wraps a step's forward passes in ``torch.autocast`` (bf16 where the GPU has it, else fp16
with a ``GradScaler`` against underflowing gradients) and its backward and optimiser steps in the scaler's calls;
disabled (the CPU, or ``amp`` off) every call is the plain one. Losses are computed in float32 from the autocast
outputs (``.float()``), so the holdout metrics and the checkpoints stay float32. Where autocast does not pay (the
U-Net's forward runs slower in bf16 than in float32 on an H100), a run turns ``amp`` off and keeps ``tf32``
(:func:`use_tf32`): float32 tensors, the matrix products and convolutions on the tensor cores in TF32.
:class:`Compiled` runs a network through ``torch.compile`` where it compiles, the eager network otherwise.
"""

from __future__ import annotations

import contextlib
import warnings

import torch
from torch import nn


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


def use_tf32(device: torch.device, tf32: bool) -> None:
    """On CUDA with ``tf32``, let float32 matrix products and convolutions run in TF32 (10-bit mantissa, float32
    range; torch's default for convolutions, not for matrix products). The setting is the process's: a trainer
    runs in a process of its own (the pipeline's workers), and nothing changes off CUDA or without ``tf32``."""
    if device.type == "cuda" and tf32:
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True


COMPILE_FALLBACK = "torch.compile is unavailable here ({reason}); {name} trains uncompiled (eager), as with compile off"
"""The one warning of a :class:`Compiled` network that could not compile."""


class Compiled:
    """``module`` called through ``torch.compile(module)`` when ``enabled``, else the module itself. Compilation
    happens at the first call; where it fails (no ``torch.compile``, no compiler or Triton for the backend, an
    operator the backend cannot take) the module runs eagerly from then on, after one :class:`RuntimeWarning`
    (:data:`COMPILE_FALLBACK`). The weights are the module's either way: save and load ``module``."""

    def __init__(self, module: nn.Module, enabled: bool, name: str = "the network") -> None:
        self.module = module
        self.name = name
        self.compiled = None
        self.fallback_reason: str | None = None
        if enabled:
            try:
                self.compiled = torch.compile(module)
            except Exception as error:  # noqa: BLE001 - an unsupported platform raises RuntimeError and others
                self._fall_back(error)
        self._checked = self.compiled is None

    def _fall_back(self, error: BaseException) -> None:
        self.compiled = None
        self.fallback_reason = f"{type(error).__name__}: {' '.join(str(error).split())[:200]}"
        warnings.warn(COMPILE_FALLBACK.format(reason=self.fallback_reason, name=self.name), RuntimeWarning,
                      stacklevel=3)

    def __call__(self, *args, **kwargs):
        if self.compiled is None:
            return self.module(*args, **kwargs)
        if self._checked:
            return self.compiled(*args, **kwargs)
        try:  # the first call compiles
            out = self.compiled(*args, **kwargs)
        except Exception as error:  # noqa: BLE001 - inductor/dynamo raise many kinds; the eager call re-raises real faults
            self._fall_back(error)
            return self.module(*args, **kwargs)
        self._checked = True
        return out
