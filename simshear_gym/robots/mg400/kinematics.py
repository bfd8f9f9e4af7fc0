"""Dobot MG400 kinematics and joint limits (pure numpy, no simulator).

Frames and units: poses are ``(x_mm, y_mm, z_mm, r_deg)`` of the tool flange in the robot base frame, as the
controller reports them (``GetPose``); joints are ``(J1, J2, J3, J4)`` in degrees as ``GetAngle`` reports them.
J3 is the *absolute* forearm angle (the parallelogram keeps it independent of J2), which is why the arm has a
coupled limit on ``J3 - J2``.

The model, from public MG400 drivers::

    radius in the arm plane  r = base_x + tool_x + L1 sin J2 + L2 cos J3
    height                   z = L1 cos J2 - L2 sin J3 + tool_z
    x = r cos J1,  y = r sin J1,  R = J1 + J4

With the defaults, all joints zero put the flange at (284, 0, 118) mm.

The same module serves the simulated arm and the real-robot safety layer, so it carries no robot-connection or
simulator code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from simshear_gym.data.labels import wrap_deg

JOINT_NAMES: tuple[str, str, str, str] = ("J1", "J2", "J3", "J4")

# Round-off allowance on limits, deg, so that a pose computed from joints exactly on a limit passes.
_LIMIT_TOLERANCE_DEG = 1e-9


class KinematicsError(ValueError):
    """Base class of kinematics errors (a ``ValueError``: the input is the problem)."""


class LimitError(KinematicsError):
    """A joint (or the J2/J3 coupling) is outside its allowed range.

    Attributes:
        joint: which limit failed, e.g. ``"J2"`` or ``"J3-J2"``.
        value_deg: the offending value, deg.
        lower_deg, upper_deg: the allowed closed range, deg.
    """

    def __init__(self, joint: str, value_deg: float, lower_deg: float, upper_deg: float, note: str = "") -> None:
        self.joint = joint
        self.value_deg = float(value_deg)
        self.lower_deg = float(lower_deg)
        self.upper_deg = float(upper_deg)
        extra = f" {note}" if note else ""
        super().__init__(
            f"{joint} = {self.value_deg:.3f} deg is outside the allowed range "
            f"[{self.lower_deg:g}, {self.upper_deg:g}] deg{extra}"
        )


class UnreachableError(KinematicsError):
    """No inverse-kinematics solution: the pose is outside the arm's reach."""


@dataclass(frozen=True)
class MG400Geometry:
    """MG400 link lengths and offsets, mm.

    Attributes:
        base_x_mm: horizontal offset of the J2 axis from the J1 axis.
        upper_arm_mm: J2 -> elbow link length (L1).
        forearm_mm: elbow -> wrist link length (L2).
        tool_x_mm: horizontal offset wrist -> flange.
        tool_z_mm: vertical offset wrist -> flange (negative: the flange hangs below the wrist).
    """

    base_x_mm: float = 43.0
    upper_arm_mm: float = 175.0
    forearm_mm: float = 175.0
    tool_x_mm: float = 66.0
    tool_z_mm: float = -57.0

    def __post_init__(self) -> None:
        for name in ("base_x_mm", "upper_arm_mm", "forearm_mm", "tool_x_mm", "tool_z_mm"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"MG400Geometry.{name} must be finite, got {value!r}")
        for name in ("upper_arm_mm", "forearm_mm"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"MG400Geometry.{name} must be > 0 mm, got {getattr(self, name)!r}")

    @property
    def radial_offset_mm(self) -> float:
        """Total horizontal offset (base + tool) added to the two-link radius, mm."""
        return self.base_x_mm + self.tool_x_mm


@dataclass(frozen=True)
class MG400Limits:
    """MG400 joint limits, deg (closed ranges), including the parallelogram coupling.

    Attributes:
        j1_deg .. j4_deg: ``(lower, upper)`` per joint; J3 is absolute.
        j3_minus_j2_max_deg: coupling ``|J3 - J2| <= j3_minus_j2_max_deg``.
        j2_min_when_j3_nonpositive_deg: ``J2 >= this`` whenever ``J3 <= 0``.
    """

    j1_deg: tuple[float, float] = (-160.0, 160.0)
    j2_deg: tuple[float, float] = (-25.0, 85.0)
    j3_deg: tuple[float, float] = (-25.0, 105.0)
    j4_deg: tuple[float, float] = (-180.0, 180.0)
    j3_minus_j2_max_deg: float = 60.0
    j2_min_when_j3_nonpositive_deg: float = -19.0

    def __post_init__(self) -> None:
        for name in ("j1_deg", "j2_deg", "j3_deg", "j4_deg"):
            pair = getattr(self, name)
            if len(pair) != 2 or not all(math.isfinite(v) for v in pair) or pair[0] >= pair[1]:
                raise ValueError(f"MG400Limits.{name} must be a finite (lower, upper) with lower < upper, got {pair!r}")
        if not (math.isfinite(self.j3_minus_j2_max_deg) and self.j3_minus_j2_max_deg > 0.0):
            raise ValueError("MG400Limits.j3_minus_j2_max_deg must be finite and > 0, "
                             f"got {self.j3_minus_j2_max_deg!r}")
        if not math.isfinite(self.j2_min_when_j3_nonpositive_deg):
            raise ValueError("MG400Limits.j2_min_when_j3_nonpositive_deg must be finite, "
                             f"got {self.j2_min_when_j3_nonpositive_deg!r}")

    def joint_range_deg(self, index: int) -> tuple[float, float]:
        """The independent ``(lower, upper)`` range of joint ``index`` (0-based), deg."""
        return (self.j1_deg, self.j2_deg, self.j3_deg, self.j4_deg)[index]


DEFAULT_GEOMETRY = MG400Geometry()
DEFAULT_LIMITS = MG400Limits()


def _as_four(values: Sequence[float] | np.ndarray, what: str) -> np.ndarray:
    array = np.asarray(values, dtype=float).reshape(-1)
    if array.shape != (4,):
        raise ValueError(f"{what} must have 4 values, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what} must be finite, got {array.tolist()}")
    return array


def forward(joints_deg: Sequence[float] | np.ndarray,
            geometry: MG400Geometry = DEFAULT_GEOMETRY) -> tuple[float, float, float, float]:
    """Flange pose from joint angles.

    Args:
        joints_deg: ``(J1, J2, J3, J4)``, deg (J3 absolute).
        geometry: arm constants, mm.

    Returns:
        ``(x_mm, y_mm, z_mm, r_deg)`` with ``r_deg = J1 + J4`` (not wrapped).
    """
    j1, j2, j3, j4 = _as_four(joints_deg, "joints_deg")
    j1r, j2r, j3r = np.radians([j1, j2, j3])
    radius_mm = geometry.radial_offset_mm + geometry.upper_arm_mm * math.sin(j2r) + geometry.forearm_mm * math.cos(j3r)
    z_mm = geometry.upper_arm_mm * math.cos(j2r) - geometry.forearm_mm * math.sin(j3r) + geometry.tool_z_mm
    return (radius_mm * math.cos(j1r), radius_mm * math.sin(j1r), float(z_mm), float(j1 + j4))


def inverse(x_mm: float, y_mm: float, z_mm: float, r_deg: float,
            geometry: MG400Geometry = DEFAULT_GEOMETRY) -> np.ndarray:
    """Closed-form inverse kinematics; joint limits are *not* checked.

    Of the two elbow solutions this returns the one with J2 = (direction to the wrist) - (elbow angle), the only
    one inside the MG400's joint limits (checked by the FK/IK round-trip tests).

    Args:
        x_mm, y_mm, z_mm: flange position in the base frame, mm.
        r_deg: flange rotation about z, deg.
        geometry: arm constants, mm.

    Returns:
        ``np.array([J1, J2, J3, J4])`` in deg; J4 is wrapped to ``[-180, 180)``.

    Raises:
        UnreachableError: the position is outside the two-link reach (or on the J1 axis, where J1 is undefined).
    """
    pose = _as_four((x_mm, y_mm, z_mm, r_deg), "pose (x_mm, y_mm, z_mm, r_deg)")
    x_mm, y_mm, z_mm, r_deg = (float(v) for v in pose)
    horizontal_mm = math.hypot(x_mm, y_mm)
    if horizontal_mm < 1e-9:
        raise UnreachableError(f"pose ({x_mm:g}, {y_mm:g}, {z_mm:g}) mm lies on the J1 axis; J1 is undefined there")
    j1 = math.atan2(y_mm, x_mm)
    # Wrist position in the arm plane, relative to the J2 axis.
    plane_mm = horizontal_mm - geometry.radial_offset_mm
    height_mm = z_mm - geometry.tool_z_mm
    l1, l2 = geometry.upper_arm_mm, geometry.forearm_mm
    distance_mm = math.hypot(plane_mm, height_mm)
    reach_min_mm, reach_max_mm = abs(l1 - l2), l1 + l2
    if not (reach_min_mm - 1e-9 <= distance_mm <= reach_max_mm + 1e-9) or distance_mm < 1e-9:
        raise UnreachableError(
            f"pose ({x_mm:.3f}, {y_mm:.3f}, {z_mm:.3f}) mm is out of reach: wrist distance {distance_mm:.3f} mm "
            f"from the J2 axis, expected within [{reach_min_mm:g}, {reach_max_mm:g}] mm"
        )
    # J2 is measured from vertical; the elbow sits on the side that keeps J3 (forearm below horizontal) natural.
    direction = math.atan2(plane_mm, height_mm)
    cos_alpha = (l1 * l1 + distance_mm * distance_mm - l2 * l2) / (2.0 * l1 * distance_mm)
    alpha = math.acos(min(1.0, max(-1.0, cos_alpha)))
    j2 = direction - alpha
    forearm_x = plane_mm - l1 * math.sin(j2)
    forearm_z = height_mm - l1 * math.cos(j2)
    j3 = math.atan2(-forearm_z, forearm_x)
    j1_deg, j2_deg, j3_deg = math.degrees(j1), math.degrees(j2), math.degrees(j3)
    return np.array([j1_deg, j2_deg, j3_deg, wrap_deg(r_deg - j1_deg)])


def check_joint_limits(joints_deg: Sequence[float] | np.ndarray, limits: MG400Limits = DEFAULT_LIMITS) -> None:
    """Check every joint limit and the J2/J3 coupling; the single place these limits are enforced.

    Args:
        joints_deg: ``(J1, J2, J3, J4)``, deg.
        limits: the ranges to enforce.

    Raises:
        LimitError: naming the first failing joint (or ``"J3-J2"``), its value and the allowed range.
    """
    joints = _as_four(joints_deg, "joints_deg")
    for index, name in enumerate(JOINT_NAMES):
        lower, upper = limits.joint_range_deg(index)
        if not lower - _LIMIT_TOLERANCE_DEG <= joints[index] <= upper + _LIMIT_TOLERANCE_DEG:
            raise LimitError(name, joints[index], lower, upper)
    j2, j3 = joints[1], joints[2]
    coupling = limits.j3_minus_j2_max_deg
    if abs(j3 - j2) > coupling + _LIMIT_TOLERANCE_DEG:
        raise LimitError("J3-J2", j3 - j2, -coupling, coupling, note="(parallelogram coupling)")
    if j3 <= 0.0 and j2 < limits.j2_min_when_j3_nonpositive_deg - _LIMIT_TOLERANCE_DEG:
        raise LimitError("J2", j2, limits.j2_min_when_j3_nonpositive_deg, limits.j2_deg[1],
                         note=f"(coupled limit while J3 = {j3:.3f} deg <= 0)")


def check_pose_reachable(pose: Sequence[float] | np.ndarray, geometry: MG400Geometry = DEFAULT_GEOMETRY,
                         limits: MG400Limits = DEFAULT_LIMITS) -> np.ndarray:
    """Inverse kinematics plus joint limits.

    Args:
        pose: ``(x_mm, y_mm, z_mm, r_deg)``.

    Returns:
        The joint angles ``(J1, J2, J3, J4)``, deg.

    Raises:
        UnreachableError: no IK solution.
        LimitError: the solution violates a joint limit or the coupling.
    """
    x_mm, y_mm, z_mm, r_deg = _as_four(pose, "pose (x_mm, y_mm, z_mm, r_deg)")
    joints = inverse(x_mm, y_mm, z_mm, r_deg, geometry)
    check_joint_limits(joints, limits)
    return joints
