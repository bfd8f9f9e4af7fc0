"""GDNN weights files (the common format of :mod:`simshear_gym.models.weights_io`) and zoo folders
(:mod:`simshear_gym.models.zoo_format`); the shipped ones: :mod:`simshear_gym.models.zoo`."""

from __future__ import annotations

import os
from pathlib import Path

from simshear_gym.models.gdnn import GDNN, GDNNConfig
from simshear_gym.models.weights_io import save_model
from simshear_gym.models.zoo_format import load_any


def save_posenet(path: str | os.PathLike, model: GDNN, card: dict | None = None) -> Path:
    """Write a GDNN's config and fp32 weights (plus a free-form ``card``), atomically."""
    return save_model(path, model, card)


def load_posenet(path: str | os.PathLike) -> tuple[GDNN, dict]:
    """Load a GDNN written by :func:`save_posenet` (``best.pt`` of a posenet run), or a zoo folder of one, in eval
    mode, with its card."""
    return load_any(path, lambda settings: GDNN(GDNNConfig(**settings)), "posenet", GDNN.__name__)
