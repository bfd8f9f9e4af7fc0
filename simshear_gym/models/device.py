"""Where a model runs: the device names the commands take (``--device auto|cpu|cuda``) and the torch device each
names on this machine.

``auto`` is CUDA where ``torch.cuda.is_available()``, else the CPU; ``cuda`` on a machine without CUDA is an error
(never a silent fall back to the CPU). Checkpoints and weights are loaded with ``map_location="cpu"`` and then
moved, so a file written on any device loads on any other. Torch is imported inside the functions, so that the
torch-free training configs can validate a device name with :func:`check_device_name`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch
    from torch import nn

DEVICES = ("auto", "cpu", "cuda")


def check_device_name(name: str) -> str:
    """``name`` if it is one of :data:`DEVICES`, else a ValueError naming them (torch-free)."""
    if name not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {name!r}")
    return name


def resolve_device(name: str, index: int | None = None) -> torch.device:
    """The torch device ``name`` picks on this machine; ``index``: which GPU (a process's local rank), for CUDA.

    Raises ValueError for an unknown name, or for ``cuda`` where torch sees no CUDA device."""
    import torch

    check_device_name(name)
    cuda = torch.cuda.is_available()
    if name == "cuda" and not cuda:
        built = torch.version.cuda or "no CUDA (a CPU-only build)"
        raise ValueError(f"device 'cuda': torch {torch.__version__} (built with {built}) finds no CUDA device on "
                         "this machine; use --device cpu, or auto (CUDA where there is one, else the CPU)")
    if name == "cpu" or not cuda:
        return torch.device("cpu")
    return torch.device("cuda", index) if index is not None else torch.device("cuda")


def cpu_state(module: nn.Module) -> dict:
    """``module``'s state dict with every tensor on the CPU (the same tensors where it already runs there), so
    that a checkpoint holds no device tensors."""
    return {name: value.cpu() for name, value in module.state_dict().items()}


class OnDevice:
    """A model run on ``device`` behind a CPU interface: CPU tensors in, CPU tensors (or a tuple of them) out,
    the model's other attributes (``config``, ``variables``) read through, so that code written for a CPU model
    (:func:`~simshear_gym.models.gdnn_input.predict`, :class:`~simshear_gym.models.translator.Translator` with
    ``fast=False``) runs it on a GPU unchanged."""

    def __init__(self, model: nn.Module, device: torch.device) -> None:
        self.model = model.to(device).eval()
        self.device = device

    def __getattr__(self, name: str):
        return getattr(self.__dict__["model"], name)

    def eval(self) -> OnDevice:
        self.model.eval()
        return self

    def __call__(self, *inputs):
        out = self.model(*(x.to(self.device) if x is not None else None for x in inputs))
        return tuple(part.cpu() for part in out) if isinstance(out, tuple) else out.cpu()
