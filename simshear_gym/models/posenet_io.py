"""GDNN weights files: ``{"config": GDNNConfig fields, "state_dict": ..., "card": {...}}`` written atomically."""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path

import torch

from simshear_gym.io import atomic_write
from simshear_gym.models.gdnn import GDNN, GDNNConfig


def save_posenet(path: str | os.PathLike, model: GDNN, card: dict | None = None) -> Path:
    """Write a GDNN's config and fp32 weights (plus a free-form ``card``), atomically."""
    payload = {"config": asdict(model.config), "state_dict": model.state_dict(), "card": card or {}}
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


def load_posenet(path: str | os.PathLike) -> tuple[GDNN, dict]:
    """Load a GDNN written by :func:`save_posenet` (``best.pt`` of a posenet run) in eval mode, with its card."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"posenet weights {path} not found")
    payload = torch.load(path, map_location="cpu", weights_only=True)
    try:
        settings = {k: tuple(v) if isinstance(v, list) else v for k, v in payload["config"].items()}
        model = GDNN(GDNNConfig(**settings))
        model.load_state_dict(payload["state_dict"])
    except (KeyError, TypeError, RuntimeError) as error:
        raise ValueError(f"{path}: not a simshear posenet file ({error})") from None
    return model.eval(), payload.get("card", {})
