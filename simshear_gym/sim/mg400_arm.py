"""A simulated Dobot MG400 in servo mode: kinematic, rate-limited, refusing targets outside its limits.

The arm is kinematic (no dynamics): its state is the flange pose ``(x_mm, y_mm, z_mm, r_deg)`` in its own base
frame, as ``GetPose`` reports it, and the joints from :mod:`simshear_gym.robots.mg400.kinematics`. Commands behave
like the real ``ServoP(X, Y, Z, R, t=T)``: a new target replaces the previous one and is reached along a straight
line (R along the shorter way round) over ``T`` seconds, or slower when that would exceed the configured linear
or angular speed. :meth:`SimMG400.advance` moves the arm on in time.

Limits: every command path goes through :func:`~simshear_gym.robots.mg400.kinematics.check_pose_reachable` (IK plus
joint limits and the J2/J3 coupling): :meth:`SimMG400.reset` and :meth:`SimMG400.servo_p` refuse a bad target
with :class:`~simshear_gym.robots.mg400.kinematics.LimitError` or
:class:`~simshear_gym.robots.mg400.kinematics.UnreachableError` (both ``ValueError``) and leave the arm where it was;
:meth:`SimMG400.advance` checks every pose it passes through and stops the arm (an alarm on the real one) at the
last good pose before raising.

Frames: ``T_world_base`` places the base (its z axis is vertical; only a rotation about z is allowed, so that the
level flange stays level in the world). The flange frame is the base frame turned by R about z and moved to the
flange; it faces down on the real arm, but the transform carries no tilt because the MG400 flange is always
level. A tool (the TacTip, a plate) is mounted by an explicit ``T_flange_tool``.

Bodies: with ``bodies=True`` the arm adds a few static boxes (base column, upper arm, forearm, wrist) to the world
for scene views and collision queries, placed from the joint positions. They are placed on demand
(:meth:`SimMG400.update_bodies`), because nothing in the kinematic envs collides with them and the TacTip, whose
far plane ends just beyond its dome, never sees them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet

from simshear_gym.data.labels import wrap_deg
from simshear_gym.robots.mg400.frames import (
    T_base_flange_to_pose,
    joint_points_base_mm,
    pose_to_T_base_flange,
)
from simshear_gym.robots.mg400.kinematics import (
    DEFAULT_GEOMETRY,
    DEFAULT_LIMITS,
    MG400Geometry,
    MG400Limits,
    check_pose_reachable,
)
from simshear_gym.robots.mg400.protocol import SERVO_TIME_RANGE_S
from simshear_gym.sim.arm import ServoMotion
from simshear_gym.sim.world import World
from simshear_gym.transforms import invert, matrix_to_pybullet


@dataclass(frozen=True)
class MG400ArmConfig:
    """Servo-mode limits and the arm model.

    Attributes:
        max_linear_speed_mm_s: fastest flange translation; a servo target that would need more takes longer.
        max_angular_speed_deg_s: fastest R rotation, likewise.
        link_width_mm: side of the square boxes drawn for the links.
        base_height_mm: height of the base column drawn below the J2 axis (the base frame's z = 0).
        geometry: link lengths and offsets, mm.
        limits: joint limits, deg.
    """

    max_linear_speed_mm_s: float = 100.0
    max_angular_speed_deg_s: float = 180.0
    link_width_mm: float = 40.0
    base_height_mm: float = 150.0
    geometry: MG400Geometry = DEFAULT_GEOMETRY
    limits: MG400Limits = DEFAULT_LIMITS

    def __post_init__(self) -> None:
        for name in ("max_linear_speed_mm_s", "max_angular_speed_deg_s", "link_width_mm", "base_height_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MG400ArmConfig.{name} must be finite and > 0, got {value!r}")


class SimMG400(ServoMotion):
    """One simulated MG400 in a :class:`World` (see the module docstring for the motion model and frames).

    Args:
        world: the world to add the arm's bodies to.
        T_world_base: 4x4 (mm) base frame in the world; a rotation about the vertical only.
        pose_mm_deg: initial flange pose ``(x, y, z, R)`` in the base frame (checked against the limits).
        T_flange_tool: 4x4 (mm) the mounted tool (TacTip TCP, plate, ...) in the flange frame.
        config: speeds, arm model, drawing sizes.
        bodies: add the link boxes to the world.
    """

    tool_dof = 4
    """The tool's degrees of freedom (:class:`~simshear_gym.sim.arm.Arm`): x, y, z and R; it stays level."""

    def __init__(self, world: World, T_world_base: np.ndarray, pose_mm_deg: np.ndarray,
                 T_flange_tool: np.ndarray = np.eye(4), config: MG400ArmConfig = MG400ArmConfig(),
                 bodies: bool = True) -> None:
        self.world = world
        self.config = config
        self.T_world_base = np.array(T_world_base, dtype=np.float64)
        if self.T_world_base.shape != (4, 4) or abs(self.T_world_base[2, 2] - 1.0) > 1e-9:
            raise ValueError("T_world_base must be a 4x4 transform whose z axis is vertical (rotation about z only)")
        self.T_flange_tool = np.array(T_flange_tool, dtype=np.float64)
        if self.T_flange_tool.shape != (4, 4):
            raise ValueError(f"T_flange_tool must be 4x4, got shape {self.T_flange_tool.shape}")
        self._T_base_world = invert(self.T_world_base)
        self._T_tool_flange = invert(self.T_flange_tool)
        self._pose = np.zeros(4)
        self._joints = np.zeros(4)
        self._body_ids: dict[str, int] = self._create_bodies() if bodies else {}
        self.reset(pose_mm_deg)

    # ----------------------------------------------------------------- state
    @property
    def pose_mm_deg(self) -> np.ndarray:
        """Current flange pose ``(x_mm, y_mm, z_mm, r_deg)`` in the base frame (a copy)."""
        return self._pose.copy()

    @property
    def joints_deg(self) -> np.ndarray:
        """Current joints ``(J1, J2, J3, J4)``, deg (a copy)."""
        return self._joints.copy()

    @property
    def target_mm_deg(self) -> np.ndarray:
        """The pose the arm is moving to (the current pose when idle)."""
        return self._pose.copy() if self._motion is None else self._motion[1].copy()

    def T_world_flange(self) -> np.ndarray:
        return self.T_world_base @ pose_to_T_base_flange(self._pose)

    def T_world_tool(self) -> np.ndarray:
        return self.T_world_base @ pose_to_T_base_flange(self._pose) @ self.T_flange_tool

    def tool_pose_mm_deg(self) -> np.ndarray:
        """The tool point and the flange's R in the base frame, ``(x, y, z, R)`` (what ``GetPose`` reports
        once the tool is configured with ``Tool(i)``)."""
        T_base_tool = pose_to_T_base_flange(self._pose) @ self.T_flange_tool
        return np.array([T_base_tool[0, 3], T_base_tool[1, 3], T_base_tool[2, 3], self._pose[3]])

    # -------------------------------------------------------------- commands
    def reset(self, pose_mm_deg: np.ndarray) -> None:
        """Put the arm at a pose at once (no motion), after checking it; cancels any servo motion."""
        pose = np.asarray(pose_mm_deg, dtype=np.float64).reshape(-1)
        self._joints = check_pose_reachable(pose, self.config.geometry, self.config.limits)
        self._pose = pose.copy()
        self._motion = None

    def reset_tool(self, T_world_tool: np.ndarray) -> None:
        """:meth:`reset` to the flange pose that puts the tool at ``T_world_tool`` (the
        :class:`~simshear_gym.sim.arm.Arm` interface)."""
        self.reset(self.flange_pose_for_tool(T_world_tool))

    def flange_pose_for_tool(self, T_world_tool: np.ndarray) -> np.ndarray:
        """The flange pose (base frame) that puts the tool at ``T_world_tool``; R is unwrapped next to the
        current R. Raises ``ValueError`` if that needs a tilted flange."""
        T_base_flange = self._T_base_world @ np.asarray(T_world_tool, dtype=np.float64) @ self._T_tool_flange
        pose = T_base_flange_to_pose(T_base_flange)
        pose[3] = self._pose[3] + wrap_deg(pose[3] - self._pose[3])
        return pose

    def servo_p(self, pose_mm_deg: np.ndarray, duration_s: float) -> float:
        """``ServoP``: move to a flange pose (base frame) over ``duration_s``, replacing any previous target.

        Returns the motion's actual duration, s (longer than ``duration_s`` when the speed limits apply).

        Raises:
            ValueError: ``duration_s`` outside the controller's range.
            LimitError, UnreachableError: the target is outside the arm's limits; the arm keeps its motion.
        """
        if not SERVO_TIME_RANGE_S[0] <= duration_s <= SERVO_TIME_RANGE_S[1]:
            raise ValueError(f"servo duration_s must be in {SERVO_TIME_RANGE_S} s, got {duration_s!r}")
        target = np.asarray(pose_mm_deg, dtype=np.float64).reshape(-1).copy()
        target_joints = check_pose_reachable(target, self.config.geometry, self.config.limits)
        target[3] = self._pose[3] + wrap_deg(target[3] - self._pose[3])
        distance_mm = float(np.linalg.norm(target[:3] - self._pose[:3]))
        turn_deg = abs(float(target[3] - self._pose[3]))
        duration = max(duration_s, distance_mm / self.config.max_linear_speed_mm_s,
                       turn_deg / self.config.max_angular_speed_deg_s)
        return self._start_motion(self._pose.copy(), target, duration, target_joints)

    def servo_tool(self, T_world_tool: np.ndarray, duration_s: float) -> float:
        """``ServoP`` to the flange pose that puts the tool at ``T_world_tool``; see :meth:`servo_p`."""
        return self.servo_p(self.flange_pose_for_tool(T_world_tool), duration_s)

    def _arrive(self, end: np.ndarray, end_joints: np.ndarray) -> None:  # the target was checked by servo_p
        self._pose, self._joints = end.copy(), end_joints.copy()

    def _pass_through(self, start: np.ndarray, end: np.ndarray, fraction: float) -> None:
        pose = start + fraction * (end - start)
        self._joints = check_pose_reachable(pose, self.config.geometry, self.config.limits)
        self._pose = pose

    # ---------------------------------------------------------------- bodies
    def joint_points_world_mm(self) -> dict[str, np.ndarray]:
        """Base foot, J2 axis, elbow, wrist and flange positions in the world, mm."""
        points = joint_points_base_mm(self._joints, self.config.geometry)
        points["foot"] = np.array([0.0, 0.0, -self.config.base_height_mm])
        points["column_top"] = np.zeros(3)
        return {name: (self.T_world_base @ np.append(p, 1.0))[:3] for name, p in points.items()}

    _LINKS = (("column", "foot", "column_top", 2.0), ("upper_arm", "shoulder", "elbow", 1.0),
              ("forearm", "elbow", "wrist", 1.0), ("wrist", "wrist", "wrist_out", 0.8),
              ("flange", "wrist_out", "flange", 0.8))

    def _create_bodies(self) -> dict[str, int]:
        client, ids = self.world.client, {}
        geometry = self.config.geometry
        lengths = {"column": self.config.base_height_mm, "upper_arm": geometry.upper_arm_mm,
                   "forearm": geometry.forearm_mm, "wrist": max(geometry.tool_x_mm, 1.0),
                   "flange": max(abs(geometry.tool_z_mm), 1.0)}
        for name, _, _, width_scale in self._LINKS:
            half_m = [self.config.link_width_mm * width_scale / 2000.0] * 2 + [lengths[name] / 2000.0]
            visual = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_m, rgbaColor=[0.85, 0.85, 0.9, 1.0])
            collision = client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_m)
            ids[name] = client.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=collision,
                                               baseVisualShapeIndex=visual)
        return ids

    def update_bodies(self) -> None:
        """Place the link boxes at the current joints (no-op without bodies)."""
        if not self._body_ids:
            return
        points = self.joint_points_world_mm()
        for name, start, end, _ in self._LINKS:
            position_m, quaternion = matrix_to_pybullet(_segment_frame(points[start], points[end]))
            self.world.client.resetBasePositionAndOrientation(self._body_ids[name], position_m, quaternion)

    @property
    def body_ids(self) -> dict[str, int]:
        return dict(self._body_ids)


def _segment_frame(start_mm: np.ndarray, end_mm: np.ndarray) -> np.ndarray:
    """4x4 frame at the segment's midpoint with z along it (x horizontal where possible)."""
    axis = end_mm - start_mm
    length = float(np.linalg.norm(axis))
    z = axis / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    x = np.cross([0.0, 0.0, 1.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    frame = np.eye(4)
    frame[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    frame[:3, 3] = (start_mm + end_mm) / 2.0
    return frame
