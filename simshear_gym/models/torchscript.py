"""One way to make a frozen CPU-inference copy of a model, shared by the GDNN and the U-Net generator."""

from __future__ import annotations

import warnings

import torch
from torch import nn


class Unchecked(nn.Module):
    """A model's computation without its input checks (its ``_run``): what :func:`frozen_copy` traces."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, *inputs: torch.Tensor):
        return self.model._run(*inputs)


def frozen_copy(core: nn.Module, example: tuple[torch.Tensor, ...]) -> nn.Module:
    """``core`` (an eval-mode module without input checks) traced on ``example`` and frozen by TorchScript:
    batch norm folded into the convolutions, weights pre-packed. TorchScript is deprecated in favour of
    ``torch.compile``, whose compile time (tens of seconds) would dwarf an episode; with the pinned torch it works,
    and where it does not ``core`` itself is returned (slower, same outputs)."""
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            return torch.jit.freeze(torch.jit.trace(core.eval(), example, check_trace=False))
    except (AttributeError, RuntimeError):
        return core
