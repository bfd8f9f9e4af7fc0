"""The GDNN's input and output contract: images enter as uint8 / 255 at the network's size (area interpolation),
labels as an (N, V) matrix in the variables' units (:class:`~simshear_gym.models.gdnn.VariableSet`).

Training (:mod:`simshear_gym.train.posenet`), the benchmarks and the tactile estimator all go through here, so the
network sees the same input wherever it runs.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np
import torch

from simshear_gym.models.gdnn import VariableSet


def label_matrix(table: Mapping[str, np.ndarray], variables: VariableSet) -> np.ndarray:
    """(N, V) float32 label values in the variables' units, from ``table[spec.column]`` (a DataFrame or dict)."""
    missing = [spec.column for spec in variables.variables if spec.column not in table]
    if missing:
        raise ValueError(f"labels for {variables.name} need the columns {list(variables.columns)}; missing {missing}")
    return np.stack([np.asarray(table[spec.column], dtype=np.float32) for spec in variables.variables], axis=1)


def resize_images(images: np.ndarray, size_px: int) -> np.ndarray:
    """uint8 (..., H, W) -> uint8 (..., size, size) (area interpolation); unchanged if already that size."""
    if images.shape[-2:] == (size_px, size_px):
        return images
    flat = images.reshape(-1, *images.shape[-2:])
    resized = np.stack([cv2.resize(image, (size_px, size_px), interpolation=cv2.INTER_AREA) for image in flat])
    return resized.reshape(*images.shape[:-2], size_px, size_px)


def to_input(images_uint8: torch.Tensor) -> torch.Tensor:
    """uint8 (B, H, W) -> float32 (B, 1, H, W) in [0, 1]: the GDNN input contract."""
    return images_uint8.unsqueeze(1).to(torch.float32) / 255.0


def predict(model, images_uint8: np.ndarray, batch: int = 64):
    """GDNN outputs (mean, std), each float (N, D), of uint8 (N, H, W) images (resized to the model's size)."""
    images = resize_images(images_uint8, model.config.image_size_px)
    means, stds = [], []
    model.eval()
    with torch.inference_mode():
        for start in range(0, len(images), batch):
            mean, std = model(to_input(torch.from_numpy(images[start:start + batch])))
            means.append(mean)
            stds.append(std)
    return torch.cat(means), torch.cat(stds)
