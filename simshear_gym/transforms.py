"""Rigid transforms between named frames, with poses as (x, y, z mm, Rx, Ry, Rz deg).

Rotations are extrinsic x-y-z Euler angles (scipy ``"xyz"``). A transform ``T_a_b`` is a 4x4 matrix that maps
coordinates in frame ``b`` to frame ``a`` (``p_a = T_a_b @ p_b``); translations are in mm unless the name says
otherwise.
"""

from __future__ import annotations

import math

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


def rotation_to_quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), PyBullet's order, of a 3x3 rotation matrix (Shepperd's method).

    Plain numpy: scipy's ``Rotation`` costs about 0.1 ms a call, too slow for the envs' per-step body updates.
    """
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        k = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / k, (m[0, 2] - m[2, 0]) / k, (m[1, 0] - m[0, 1]) / k, 0.25 * k]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        k = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * k, (m[0, 1] + m[1, 0]) / k, (m[0, 2] + m[2, 0]) / k, (m[2, 1] - m[1, 2]) / k]
    elif m[1, 1] > m[2, 2]:
        k = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / k, 0.25 * k, (m[1, 2] + m[2, 1]) / k, (m[0, 2] - m[2, 0]) / k]
    else:
        k = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / k, (m[1, 2] + m[2, 1]) / k, 0.25 * k, (m[1, 0] - m[0, 1]) / k]
    q = np.array(q)
    return q / np.linalg.norm(q)


def matrix_to_pybullet_fast(matrix_mm: np.ndarray) -> tuple[list[float], list[float]]:
    """:func:`matrix_to_pybullet` (position in m, quaternion xyzw) without scipy, for per-step body updates."""
    return (matrix_mm[:3, 3] / 1000.0).tolist(), rotation_to_quaternion_xyzw(matrix_mm[:3, :3]).tolist()


def rz_matrix(rz_deg: float) -> np.ndarray:
    """(4, 4) rotation by ``rz_deg`` about z."""
    c, s = math.cos(math.radians(rz_deg)), math.sin(math.radians(rz_deg))
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def pose_from_matrix_fast(matrix: np.ndarray) -> np.ndarray:
    """:func:`~simshear_gym.transforms.matrix_to_pose` without scipy's per-call overhead (same extrinsic
    x-y-z angles away from Ry = +-90 deg, which a level face and a vertical sensor never approach)."""
    rotation = matrix[:3, :3]
    rx = math.atan2(rotation[2, 1], rotation[2, 2])
    ry = -math.asin(max(-1.0, min(1.0, rotation[2, 0])))
    rz = math.atan2(rotation[1, 0], rotation[0, 0])
    return np.array([matrix[0, 3], matrix[1, 3], matrix[2, 3], math.degrees(rx), math.degrees(ry), math.degrees(rz)])
