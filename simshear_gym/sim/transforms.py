"""Rigid transforms between named frames, with poses as (x, y, z mm, Rx, Ry, Rz deg).

Rotations are extrinsic x-y-z Euler angles (scipy ``"xyz"``). A transform ``T_a_b`` is a 4x4 matrix that maps
coordinates in frame ``b`` to frame ``a`` (``p_a = T_a_b @ p_b``); translations are in mm unless the name says
otherwise.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def pose_to_matrix(pose_mm_deg: np.ndarray) -> np.ndarray:
    """(6,) pose -> (4, 4) homogeneous transform (translation in mm)."""
    pose = np.asarray(pose_mm_deg, dtype=np.float64)
    if pose.shape != (6,):
        raise ValueError(f"pose must be (x, y, z mm, Rx, Ry, Rz deg), got shape {pose.shape}")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("xyz", pose[3:], degrees=True).as_matrix()
    matrix[:3, 3] = pose[:3]
    return matrix


def matrix_to_pose(matrix: np.ndarray) -> np.ndarray:
    """(4, 4) transform -> (6,) pose (x, y, z mm, Rx, Ry, Rz deg)."""
    matrix = np.asarray(matrix, dtype=np.float64)
    euler = Rotation.from_matrix(matrix[:3, :3]).as_euler("xyz", degrees=True)
    return np.concatenate([matrix[:3, 3], euler])


def invert(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    rotation, translation = matrix[:3, :3], matrix[:3, 3]
    inverse = np.eye(4)
    inverse[:3, :3] = rotation.T
    inverse[:3, 3] = -rotation.T @ translation
    return inverse


def matrix_to_pybullet(matrix_mm: np.ndarray) -> tuple[list[float], list[float]]:
    """(4, 4) transform in mm -> (position in m, quaternion xyzw) for PyBullet calls."""
    position_m = (np.asarray(matrix_mm[:3, 3]) / 1000.0).tolist()
    quaternion = Rotation.from_matrix(matrix_mm[:3, :3]).as_quat().tolist()
    return position_m, quaternion
