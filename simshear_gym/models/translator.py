"""Translator: (sim depth image, shear vector) -> real-looking TacTip image (the shipped ones:
:mod:`simshear_gym.models.zoo`).

Conventions shared by training and inference live here: the sim input is ``uint8 / SIM_SCALE`` (the sim images
hold penetration at 17.6 grey levels per mm, so a 3.6 mm contact maps to 1), the shear vector is the
sensor-frame shear (x, y, z mm, Rx, Ry, Rz deg, :data:`simshear_gym.data.labels.SHEAR_COLUMNS`) divided by
:data:`SHEAR_SCALE`, and the output is the real image in [0, 1], returned as uint8.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from simshear_gym.models.unet import UNetConfig, UNetGenerator
from simshear_gym.models.weights_io import save_model
from simshear_gym.models.zoo_format import load_any

ARCHS = ("shpix2pix", "pix2pix")  # shear-conditioned U-Net | the plain pix2pix baseline
SIM_SCALE = 64.0
SHEAR_SCALE = np.array([5.0, 5.0, 5.0, 5.0, 5.0, 5.0], dtype=np.float32)  # mm, mm, mm, deg, deg, deg
# The shear input leaves out z: the paired training data never moved along z during a shear (indentation shows
# in the sim image itself), so a tracker's z component (a sensor pressed in while sheared) is not shown to it.
SHEAR_INPUT_MASK = np.array([1.0, 1.0, 0.0, 1.0, 1.0, 1.0], dtype=np.float32)


def normalise_sim(sim_uint8: np.ndarray | torch.Tensor) -> torch.Tensor:
    """uint8 (B, H, W) or (B, 1, H, W) -> float32 (B, 1, H, W)."""
    sim = torch.as_tensor(sim_uint8)
    if sim.dim() == 3:
        sim = sim.unsqueeze(1)
    return sim.to(torch.float32) / SIM_SCALE


def normalise_shear(shear_sensor: np.ndarray | torch.Tensor) -> torch.Tensor:
    """(B, 6) sensor-frame shear (mm, deg) -> float32 (B, 6), about [-1, 1] over the data's ranges, z masked
    (:data:`SHEAR_INPUT_MASK`): the translator's whole shear-input contract."""
    shear = torch.as_tensor(np.asarray(shear_sensor, dtype=np.float32))
    return shear / torch.from_numpy(SHEAR_SCALE) * torch.from_numpy(SHEAR_INPUT_MASK)


def save_generator(path: str | os.PathLike, generator: UNetGenerator, card: dict | None = None,
                   half: bool = True) -> Path:
    """Write a generator's weights (fp16 by default) with its config, atomically."""
    return save_model(path, generator, card, half=half)


def load_generator(path: str | os.PathLike) -> tuple[UNetGenerator, dict]:
    """Load a generator written by :func:`save_generator` (or a training checkpoint's ``generator`` entry), or a zoo
    folder of one (:mod:`~simshear_gym.models.zoo_format`)."""
    return load_any(path, lambda settings: UNetGenerator(UNetConfig(**settings)), "translator",
                    UNetGenerator.__name__, checkpoint_entry="generator")


class Translator:
    """Batched inference of a trained generator.

    ``translator(sim_uint8, shear_sensor)``: sim uint8 (B, H, W) or (B, 1, H, W), shear (B, 6) in the sensor
    frame (mm, deg; ignored by a pix2pix generator) -> uint8 (B, H, W). Runs a frozen copy of the generator
    (:meth:`UNetGenerator.frozen`, taken at construction) unless ``fast=False``.
    """

    def __init__(self, generator: UNetGenerator, card: dict | None = None, fast: bool = True) -> None:
        self.generator = generator.eval()
        self.card = card or {}
        self._run = generator.frozen() if fast else generator

    @classmethod
    def load(cls, path: str | os.PathLike) -> Translator:
        return cls(*load_generator(path))

    @property
    def image_size_px(self) -> int:
        return self.generator.config.image_size_px

    @torch.inference_mode()
    def __call__(self, sim_uint8: np.ndarray, shear_sensor: np.ndarray | None = None) -> np.ndarray:
        sim = normalise_sim(sim_uint8)
        size = self.image_size_px
        if sim.shape[1:] != (1, size, size):
            raise ValueError(f"sim images must be {size}x{size} px for this translator, got {tuple(sim.shape[-2:])}")
        shear = None
        if self.generator.config.shear_dim:
            if shear_sensor is None:
                raise ValueError("this translator is shear-conditioned (shPix2pix): pass shear_sensor (B, 6)")
            shear = normalise_shear(shear_sensor)
            if shear.shape != (len(sim), 6):
                raise ValueError(f"shear_sensor must be (B, 6) = ({len(sim)}, 6), got {tuple(shear.shape)}")
        out = self._run(sim, shear) if shear is not None else self._run(sim)
        return (out[:, 0] * 255.0 + 0.5).clamp(0, 255).to(torch.uint8).numpy()


def translate_rows(translator, sim_uint8: np.ndarray, shear_sensor: np.ndarray, batch: int = 64) -> np.ndarray:
    """uint8 (N, H, W): ``translator`` (a :class:`Translator`, or anything called like one) over sim images (N, H, W)
    and their shear (N, 6), ``batch`` rows at a time."""
    return np.concatenate([translator(sim_uint8[i:i + batch], shear_sensor[i:i + batch])
                           for i in range(0, len(sim_uint8), batch)])
