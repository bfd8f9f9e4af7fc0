"""Weights files of every model here: ``{"config": <config fields>, "state_dict": ..., "card": {...}}``.

Written atomically; fp16 on request (loaded back as fp32). A model's ``config`` is the frozen dataclass it was
built from, so a file alone rebuilds the model.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import torch
from torch import nn

from simshear_gym.io import atomic_write


def save_model(path: str | os.PathLike, model: nn.Module, card: dict | None = None, half: bool = False) -> Path:
    """Write ``model.config``, its weights (fp16 if ``half``) and a free-form ``card``, atomically."""
    state = {k: (v.half() if half and v.is_floating_point() else v) for k, v in model.state_dict().items()}
    payload = {"config": asdict(model.config), "state_dict": state, "card": card or {}}
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


def load_model(path: str | os.PathLike, build: Callable[[dict], nn.Module], what: str,
               checkpoint_entry: str | None = None) -> tuple[nn.Module, dict]:
    """Rebuild a model written by :func:`save_model` (or a training checkpoint's ``checkpoint_entry``) in eval
    mode; returns it with its card. ``build`` makes the model from the saved config fields (lists as tuples)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} weights {path} not found")
    payload = torch.load(path, map_location="cpu", weights_only=True)
    if checkpoint_entry and checkpoint_entry in payload:
        payload = payload[checkpoint_entry]
    try:
        settings = {k: tuple(v) if isinstance(v, list) else v for k, v in payload["config"].items()}
        model = build(settings)
        model.load_state_dict({k: v.float() if v.is_floating_point() else v
                               for k, v in payload["state_dict"].items()})
    except (KeyError, TypeError, RuntimeError) as error:
        raise ValueError(f"{path}: not a simshear {what} file ({error})") from None
    return model.eval(), payload.get("card", {})
