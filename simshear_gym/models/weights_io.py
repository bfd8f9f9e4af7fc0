"""Weights files of every model here: ``{"config": <config fields>, "state_dict": ..., "card": {...}}``.

Written atomically, with the file's sha256 beside it (``<file>.sha256``: :func:`~simshear_gym.io.write_checksum`)
and checked on load, so a flipped bit is an error rather than a model that computes garbage (torch itself loads
such a file silently); fp16 on request (loaded back as fp32). A model's ``config`` is the frozen dataclass it was
built from, so a file alone rebuilds the model. Read with ``torch.load(weights_only=True)``: a file that would run
code is refused. Every bad file (empty, truncated, random bytes, a checksum that differs, another model's weights)
is one :class:`WeightsFileError` (a ValueError) naming the file and what was expected. The same model as a folder
in the Hugging Face Hub layout (safetensors, no pickle): :mod:`simshear_gym.models.zoo_format`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import torch
from torch import nn

from simshear_gym.io import atomic_write, verify_checksum, write_checksum


class WeightsFileError(ValueError):
    """A weights file that cannot be loaded; the message names the file and what was expected."""


def save_model(path: str | os.PathLike, model: nn.Module, card: dict | None = None, half: bool = False) -> Path:
    """Write ``model.config``, its weights (fp16 if ``half``) and a free-form ``card``, atomically."""
    state = {k: (v.half() if half and v.is_floating_point() else v) for k, v in model.state_dict().items()}
    payload = {"config": asdict(model.config), "state_dict": state, "card": card or {}}
    atomic_write(path, lambda tmp: torch.save(payload, tmp))
    write_checksum(path)
    return Path(path)


def read_weights(path: str | os.PathLike, what: str) -> dict:
    """The payload of a weights file (a table), its sha256 checked where one is recorded beside it.

    Raises:
        FileNotFoundError: no such file.
        ChecksumError: the recorded sha256 differs (a ValueError naming the file).
        WeightsFileError: empty, truncated, not a torch file, or one whose pickle would run code.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} weights {path} not found")
    verify_checksum(path)
    expected = f"expected {what} weights written by simshear (torch.save of config, state_dict and card)"
    if path.stat().st_size == 0:
        raise WeightsFileError(f"{path}: empty (0 bytes); {expected}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises RuntimeError, UnpicklingError, EOFError, ...
        reason = " ".join(str(error).split())[:200]
        raise WeightsFileError(f"{path}: not a readable weights file (truncated, corrupt, not a torch file, or "
                               f"one that would run code: {type(error).__name__}: {reason}); {expected}") from None
    if not isinstance(payload, dict):
        raise WeightsFileError(f"{path}: holds a {type(payload).__name__}; {expected}")
    return payload


def load_model(path: str | os.PathLike, build: Callable[[dict], nn.Module], what: str,
               checkpoint_entry: str | None = None) -> tuple[nn.Module, dict]:
    """Rebuild a model written by :func:`save_model` (or a training checkpoint's ``checkpoint_entry``) in eval
    mode; returns it with its card. ``build`` makes the model from the saved config fields (lists as tuples).

    Raises:
        FileNotFoundError, ChecksumError, WeightsFileError: see :func:`read_weights`; WeightsFileError also for
            weights of another model or architecture.
    """
    path = Path(path)
    payload = read_weights(path, what)
    if checkpoint_entry and checkpoint_entry in payload:
        payload = payload[checkpoint_entry]
    model = rebuild(payload, build, f"{path}: not a simshear {what} file (another model's weights or architecture?")
    card = payload.get("card", {})
    return model, card if isinstance(card, dict) else {}


def rebuild(payload, build: Callable[[dict], nn.Module], failure: str) -> nn.Module:
    """The model ``build`` makes from ``payload["config"]`` (lists as tuples) with ``payload["state_dict"]`` loaded
    (fp16 tensors as fp32), in eval mode; a payload of another model or architecture is a WeightsFileError starting
    with ``failure``."""
    try:
        settings = {k: tuple(v) if isinstance(v, list) else v for k, v in payload["config"].items()}
        model = build(settings)
        model.load_state_dict({k: v.float() if v.is_floating_point() else v
                               for k, v in payload["state_dict"].items()})
    except (KeyError, TypeError, RuntimeError, ValueError, AttributeError) as error:
        reason = " ".join(str(error).split())[:300]
        raise WeightsFileError(f"{failure} {reason})") from None
    return model.eval()
