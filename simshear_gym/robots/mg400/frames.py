"""MG400 flange frames: the ``(x_mm, y_mm, z_mm, r_deg)`` pose of a level flange as a 4x4 transform in the
robot base frame and back, and the joint positions the kinematic model places (for drawing the arm).

The MG400 flange is always level: its frame is the base frame turned by R about z and moved to the flange, so a
transform with any tilt has no pose. Transforms are named ``T_a_b`` (maps frame b coordinates into frame a).
"""

from __future__ import annotations

import math

import numpy as np

from simshear_gym.robots.mg400.kinematics import DEFAULT_GEOMETRY, MG400Geometry


def pose_to_T_base_flange(pose_mm_deg: np.ndarray) -> np.ndarray:
    """``(x_mm, y_mm, z_mm, r_deg)`` -> 4x4 flange frame in the base frame (a level flange turned by R)."""
    x, y, z, r_deg = (float(v) for v in pose_mm_deg)
    c, s = math.cos(math.radians(r_deg)), math.sin(math.radians(r_deg))
    return np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]])


def T_base_flange_to_pose(T_base_flange: np.ndarray, level_tolerance_deg: float = 1e-3) -> np.ndarray:
    """Inverse of :func:`pose_to_T_base_flange`; raises ``ValueError`` if the frame is not level."""
    rotation = np.asarray(T_base_flange, dtype=np.float64)[:3, :3]
    tilt_deg = math.degrees(math.acos(min(1.0, max(-1.0, rotation[2, 2]))))
    if tilt_deg > level_tolerance_deg:
        raise ValueError(
            f"the MG400 flange is always level, but this target tilts it by {tilt_deg:.4f} deg "
            f"(allowed {level_tolerance_deg} deg): command rotations about the vertical only"
        )
    r_deg = math.degrees(math.atan2(rotation[1, 0], rotation[0, 0]))
    return np.array([T_base_flange[0, 3], T_base_flange[1, 3], T_base_flange[2, 3], r_deg], dtype=np.float64)


def joint_points_base_mm(joints_deg: np.ndarray, geometry: MG400Geometry = DEFAULT_GEOMETRY) -> dict[str, np.ndarray]:
    """Positions (base frame, mm) of the arm's joints from the FK model: J2 axis, elbow, wrist, flange.

    The J2 axis lies ``base_x_mm`` out from the J1 axis at the base frame's z = 0; the upper arm makes angle J2
    with the vertical, the forearm angle J3 below the horizontal; the flange hangs ``tool_z_mm`` below and
    ``tool_x_mm`` beyond the wrist. The flange point equals :func:`forward`'s position.
    """
    j1, j2, j3 = (math.radians(float(v)) for v in np.asarray(joints_deg)[:3])
    g = geometry
    plane = {  # (radius, height) in the arm's vertical plane
        "shoulder": (g.base_x_mm, 0.0),
        "elbow": (g.base_x_mm + g.upper_arm_mm * math.sin(j2), g.upper_arm_mm * math.cos(j2)),
    }
    plane["wrist"] = (plane["elbow"][0] + g.forearm_mm * math.cos(j3), plane["elbow"][1] - g.forearm_mm * math.sin(j3))
    plane["wrist_out"] = (plane["wrist"][0] + g.tool_x_mm, plane["wrist"][1])
    plane["flange"] = (plane["wrist_out"][0], plane["wrist"][1] + g.tool_z_mm)
    c, s = math.cos(j1), math.sin(j1)
    return {name: np.array([r * c, r * s, h]) for name, (r, h) in plane.items()}
