"""Pose-consistency loss for translator training: a generated image should show its row's contact to a GDNN
that reads real images.

A GDNN trained on the **real** training images (way 3 of :mod:`simshear_gym.train.posenet`) is frozen and reads
each generated image; the loss is the squared error between its predicted means and the row's labels, both on the
GDNN's normalised scale (:meth:`~simshear_gym.models.gdnn.VariableSet.encode`: each range maps to [-1, 1]), averaged
over rows and the encoded components of the chosen variables (all of the GDNN's by default). Pixel L1 treats
every marker pixel alike; this term weighs the image the way a pose reader does, so a generator that moves the
contact's markers to the wrong place pays for it even where the pixel error is small. Only the training rows'
real images and labels enter it (the real-image GDNN saw no validation image).

The generated image (B, 1, S, S) in [0, 1] is brought to the GDNN's input size by area averaging, as
:func:`simshear_gym.models.gdnn_input.resize_images` does for uint8 images (without its rounding to uint8).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from simshear_gym.models.gdnn import VariableSet
from simshear_gym.models.gdnn_input import label_matrix
from simshear_gym.models.posenet_io import load_posenet


class PoseConsistency:
    """Owns a frozen real-image GDNN and scores generated images against their rows' labels."""

    def __init__(self, posenet_path: str | os.PathLike, variables: tuple[str, ...] = ()) -> None:
        path = Path(posenet_path)
        if not path.is_file():
            raise FileNotFoundError(f"pose-consistency GDNN {path} not found (a best.pt of simshear train posenet "
                                    f"--source real)")
        self.gdnn, self.card = load_posenet(path)  # in eval mode
        for parameter in self.gdnn.parameters():
            parameter.requires_grad_(False)
        names = self.variables.names
        unknown = sorted(set(variables) - set(names))
        if unknown:
            raise ValueError(f"pose-consistency variables {unknown} are not outputs of {path} ({list(names)})")
        columns, start = [], 0
        for spec in self.variables.variables:
            if not variables or spec.name in variables:
                columns.extend(range(start, start + spec.encoded_dim))
            start += spec.encoded_dim
        self.columns = torch.tensor(columns)  # the encoded components the loss compares

    def to(self, device: torch.device) -> PoseConsistency:
        """Run the GDNN on ``device`` (the generated images' device); returns self."""
        self.gdnn.to(device)
        self.columns = self.columns.to(device)
        return self

    @property
    def variables(self) -> VariableSet:
        return self.gdnn.variables

    def encoded_labels(self, table: Mapping[str, np.ndarray]) -> torch.Tensor:
        """(N, D) float32 labels of a paired set's targets table on the GDNN's normalised scale."""
        return self.variables.encode(label_matrix(table, self.variables)).to(torch.float32)

    def loss(self, generated: torch.Tensor, encoded_labels: torch.Tensor) -> torch.Tensor:
        """Mean squared error of the GDNN's means on ``generated`` (B, 1, S, S) against ``encoded_labels`` (B, D)."""
        size = self.gdnn.config.image_size_px
        image = generated if generated.shape[-1] == size else F.interpolate(generated, size=(size, size),
                                                                            mode="area")
        mean, _ = self.gdnn(image)
        return ((mean - encoded_labels)[:, self.columns] ** 2).mean()
