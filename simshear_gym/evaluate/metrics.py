"""Metrics shared by the benchmarks and the export steps: GDNN errors against labels (periodic angles wrapped),
chance, calibration and NLL; image MAPE and SSIM of translated against real images.
"""

from __future__ import annotations

import numpy as np
import torch
from skimage.metrics import structural_similarity

from simshear_gym.data.labels import POSE_COLUMNS, SHEAR_COLUMNS, wrap_deg
from simshear_gym.data.tactile_set import TactileSet
from simshear_gym.models.gdnn import gaussian_nll
from simshear_gym.models.gdnn_input import label_matrix


def errors(predicted: np.ndarray, truth: np.ndarray, variables) -> np.ndarray:
    """(N, V) signed errors predicted - truth in the variables' units, periodic ones wrapped."""
    error = np.asarray(predicted, np.float64) - np.asarray(truth, np.float64)
    for index, spec in enumerate(variables.variables):
        if spec.periodic:
            error[:, index] = wrap_deg(error[:, index])
    return error


def chance_mae(truth: np.ndarray, variables) -> np.ndarray:
    """(V,) MAE of always predicting the range centre (0 for a periodic angle)."""
    guess = np.array([0.0 if spec.periodic else spec.centre for spec in variables.variables])
    return np.abs(errors(np.broadcast_to(guess, truth.shape), truth, variables)).mean(axis=0)


def metrics(mean_encoded, std_encoded, truth: np.ndarray, variables) -> dict:
    """Figures of the module docstring from network outputs (N, D) and labels (N, V) in the variables' units."""
    mean_encoded, std_encoded = torch.as_tensor(mean_encoded), torch.as_tensor(std_encoded)
    mean, std = (t.numpy() for t in variables.decode(mean_encoded, std_encoded))
    nll = gaussian_nll(mean_encoded, std_encoded, variables.encode(truth), reduction="none")
    absolute = np.abs(errors(mean, truth, variables))
    chance = chance_mae(truth, variables)
    per_variable = {
        spec.name: {"unit": spec.unit, "mae": float(absolute[:, i].mean()), "chance_mae": float(chance[i]),
                    "within_1_std": float((absolute[:, i] <= std[:, i]).mean()),
                    "within_2_std": float((absolute[:, i] <= 2 * std[:, i]).mean())}
        for i, spec in enumerate(variables.variables)
    }
    return {"rows": int(len(truth)), "mean_nll": float(nll.mean()), "variables": per_variable,
            "mae_by_depth": mae_by_depth(absolute, truth, variables)}


DEPTH_VARIABLE = "z_mm"
DEPTH_BINS = 3


def mae_by_depth(absolute: np.ndarray, truth: np.ndarray, variables) -> list[dict]:
    """MAE per variable within each third of the rows by true contact depth (shallow to deep): where the
    generators' errors concentrate (they lose the markers of deep, sheared contacts)."""
    depth = truth[:, variables.names.index(DEPTH_VARIABLE)]
    edges = np.quantile(depth, np.linspace(0.0, 1.0, DEPTH_BINS + 1))
    bins = np.clip(np.searchsorted(edges, depth, side="right") - 1, 0, DEPTH_BINS - 1)
    return [{"depth_mm": [float(edges[b]), float(edges[b + 1])], "rows": int((bins == b).sum()),
             "mae": {name: float(absolute[bins == b, i].mean()) for i, name in enumerate(variables.names)}}
            for b in range(DEPTH_BINS)]


def truth_labels(val: TactileSet, variables) -> np.ndarray:
    """(N, V) labels of a real set: ``pose_*`` from its poses, ``shear_sensor_*`` from its moves and Rz."""
    return pose_shear_labels(val.poses(), val.shear_sensor(), variables)


def pose_shear_labels(poses: np.ndarray, shear: np.ndarray, variables) -> np.ndarray:
    """(N, V) labels for a variable set from poses (N, 6) and sensor-frame shear (N, 6), as the real sets' columns
    ``pose_*`` and ``shear_sensor_*`` (e.g. of a simulated sequence)."""
    table = dict(zip(POSE_COLUMNS, poses.T))
    table.update(zip(SHEAR_COLUMNS, shear.T))
    return label_matrix(table, variables)


def mape(generated: np.ndarray, real: np.ndarray) -> np.ndarray:
    """Per-image mean absolute error of uint8 (N, H, W) stacks, on the [0, 1] scale."""
    return np.abs(generated.astype(np.float32) - real.astype(np.float32)).mean(axis=(1, 2)) / 255.0


def ssim(generated: np.ndarray, real: np.ndarray) -> np.ndarray:
    """Per-image SSIM (scikit-image, data_range 1) of uint8 (N, H, W) stacks."""
    return np.array([structural_similarity(g.astype(np.float32) / 255.0, r.astype(np.float32) / 255.0,
                                           data_range=1.0) for g, r in zip(generated, real)])
