"""GDNN weights files (the common format of :mod:`simshear_gym.models.weights_io`)."""

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


POSENET_WEIGHTS_DIR = Path(__file__).resolve().parent / "weights" / "posenet"
"""Shipped GDNNs: ``weights/posenet/<contact>.pt`` (trained on shPix2pix-generated images), each with a ``.md`` card."""


def shipped_posenet_path(contact: str) -> Path:
    """Path of the shipped GDNN of a contact type (``surface`` | ``edge``)."""
    path = POSENET_WEIGHTS_DIR / f"{contact}.pt"
    if not path.is_file():
        shipped = sorted(p.stem for p in POSENET_WEIGHTS_DIR.glob("*.pt"))
        raise FileNotFoundError(f"no shipped posenet for {contact!r} contacts in {POSENET_WEIGHTS_DIR}; "
                                f"shipped: {shipped}")
    return path


def load_shipped_posenet(contact: str = "surface") -> tuple[GDNN, dict]:
    """The shipped GDNN of a contact type, in eval mode, with its card."""
    return load_posenet(shipped_posenet_path(contact))
