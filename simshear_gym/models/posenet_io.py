"""GDNN weights files (the common format of :mod:`simshear_gym.models.weights_io`; the shipped ones:
:mod:`simshear_gym.models.zoo`)."""

from __future__ import annotations

import os
from pathlib import Path

from simshear_gym.models.gdnn import GDNN, GDNNConfig
from simshear_gym.models.weights_io import load_model, save_model


def save_posenet(path: str | os.PathLike, model: GDNN, card: dict | None = None) -> Path:
    """Write a GDNN's config and fp32 weights (plus a free-form ``card``), atomically."""
    return save_model(path, model, card)


def load_posenet(path: str | os.PathLike) -> tuple[GDNN, dict]:
    """Load a GDNN written by :func:`save_posenet` (``best.pt`` of a posenet run) in eval mode, with its card."""
    return load_model(path, lambda settings: GDNN(GDNNConfig(**settings)), "posenet")
