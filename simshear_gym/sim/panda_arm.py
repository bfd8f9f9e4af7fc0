"""A simulated Franka Panda in servo mode: a 6-DoF tool pose from 7 joints, kinematic, rate-limited, refusing
targets outside its reach or joint limits. It implements :class:`~simshear_gym.sim.arm.Arm`, the interface of the
simulated MG400 (:class:`~simshear_gym.sim.mg400_arm.SimMG400`), so an env takes either as its follower.

Model: PyBullet's ``franka_panda/panda.urdf`` (``pybullet_data``), fixed base, joints 1-7 with the URDF's hard
limits (the fingers stay closed); the flange is ``panda_link8`` (z out of the flange), the tool is mounted on it
by an explicit ``T_flange_tool``. The model lives in the arm's own headless PyBullet client, which holds nothing
but the robot: it answers forward and inverse kinematics only, so the scene's world (and the TacTip's renders of
it) never carries the arm's meshes. With ``bodies=True`` the arm draws a few boxes between its joints into the
scene's world for the scene view, placed on demand (:meth:`SimPanda.update_bodies`), as the MG400 does.

Motion, like the MG400's ``ServoP``: a new tool target replaces the previous one and is reached along a straight
line (orientation along the shortest rotation) over ``duration_s``, or slower where the configured linear or
angular speed would be exceeded; :meth:`SimPanda.advance` moves on in time, solving the inverse kinematics at
every pose it passes through (damped least squares on PyBullet's Jacobian from the current joints, the
redundant seventh joint drawn gently to a mid-range configuration, until the forward kinematics agree within
``position_tolerance_mm`` and ``orientation_tolerance_deg``).

Limits: a target whose solution leaves a joint range raises
:class:`~simshear_gym.robots.mg400.kinematics.LimitError` (naming the joint, its value and range); one the solver
cannot reach within the tolerances raises :class:`~simshear_gym.robots.mg400.kinematics.UnreachableError` (naming
the target and the residual). Both are ``ValueError`` (the envs' ``arm_limit`` end) and leave the arm where it was.

**The interface a real 6-DoF driver implements** (the sim and real arms then swap under the envs and the
controllers, as the MG400's ``real.mg400_client`` does for the 4-DoF arm):

- ``tool_dof = 6``;
- ``T_world_tool() -> (4, 4)``: the measured tool pose (mm) in the cell's world frame (the robot's reported flange
  pose, ``T_world_base @ T_base_flange @ T_flange_tool``; frames and the tool transform configured once);
- ``tool_pose_mm_deg() -> (4,)``: tool x, y, z (mm) in the base frame and its turn R about the base's vertical
  (deg): the observation's ``tcp_pose``;
- ``reset_tool(T_world_tool)``: a checked point-to-point move to a start pose, returning once there;
- ``servo_tool(T_world_tool, duration_s) -> float``: a streamed Cartesian servo target reached within the control
  period (a Panda's Cartesian-pose interface at 1 kHz interpolating it, a UR's ``servoL``), checked before it is
  sent (reach, joint limits, speed) and refused with a ``KinematicsError`` subclass: never clipped silently;
- ``advance(dt_s)``: on a real arm, wait out the period and read the pose back (raise ``KinematicsError`` on a
  protective stop);
- ``update_bodies()``: a no-op.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet
import pybullet_data

from simshear_gym.robots.mg400.kinematics import LimitError, UnreachableError
from simshear_gym.sim.arm import ServoMotion
from simshear_gym.sim.mg400_arm import _segment_frame
from simshear_gym.sim.world import World
from simshear_gym.transforms import invert, matrix_to_pybullet_fast

PANDA_URDF = "franka_panda/panda.urdf"
FLANGE_LINK = "panda_link8"
ARM_JOINTS: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
READY_JOINTS_DEG: tuple[float, ...] = (0.0, -17.0, 0.0, -137.0, 0.0, 120.0, 45.0)
"""A tool-down start configuration in the middle of the joint ranges (the IK starts from the current joints)."""
_DAMPING = 1e-3  # damped least squares, in m / rad: well below the workspace's scale, enough near singularities
_NULL_SPACE_GAIN = 0.02


@dataclass(frozen=True)
class PandaArmConfig:
    """Servo-mode limits and the inverse kinematics' settings.

    Attributes:
        max_linear_speed_mm_s: fastest tool translation; a servo target that would need more takes longer.
        max_angular_speed_deg_s: fastest tool rotation, likewise.
        position_tolerance_mm: the IK solution's tool position must agree with the target within this.
        orientation_tolerance_deg: and its orientation within this angle.
        ik_iterations: damped least-squares steps before a target counts as unreachable.
        link_width_mm: side of the boxes drawn for the links.
    """

    max_linear_speed_mm_s: float = 100.0
    max_angular_speed_deg_s: float = 90.0
    position_tolerance_mm: float = 0.01
    orientation_tolerance_deg: float = 0.01
    ik_iterations: int = 50
    link_width_mm: float = 60.0

    def __post_init__(self) -> None:
        for name in ("max_linear_speed_mm_s", "max_angular_speed_deg_s", "position_tolerance_mm",
                     "orientation_tolerance_deg", "link_width_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"PandaArmConfig.{name} must be finite and > 0, got {value!r}")
        if not (isinstance(self.ik_iterations, int) and self.ik_iterations >= 1):
            raise ValueError(f"PandaArmConfig.ik_iterations must be an int >= 1, got {self.ik_iterations!r}")


class SimPanda(ServoMotion):
    """One simulated Panda (see the module docstring for the motion model, limits and the real-driver interface).

    Args:
        world: the scene's world, for the drawn bodies only.
        T_world_base: 4x4 (mm) the robot's base (``panda_link0``) in the world.
        T_world_tool: the tool's initial pose in the world (checked against the limits).
        T_flange_tool: 4x4 (mm) the mounted tool in the flange frame (``panda_link8``).
        config: speeds, tolerances, drawing size.
        bodies: draw the links into ``world``.
    """

    tool_dof = 6

    def __init__(self, world: World, T_world_base: np.ndarray, T_world_tool: np.ndarray,
                 T_flange_tool: np.ndarray = np.eye(4), config: PandaArmConfig = PandaArmConfig(),
                 bodies: bool = True) -> None:
        self.world = world
        self.config = config
        self.T_world_base = np.array(T_world_base, dtype=np.float64)
        self.T_flange_tool = np.array(T_flange_tool, dtype=np.float64)
        for name, value in (("T_world_base", self.T_world_base), ("T_flange_tool", self.T_flange_tool)):
            if value.shape != (4, 4):
                raise ValueError(f"{name} must be a 4x4 transform, got shape {value.shape}")
        self._T_base_world = invert(self.T_world_base)
        self._T_tool_flange = invert(self.T_flange_tool)
        self._model = World()  # kinematics only: the robot alone, never rendered
        client = self._model.client
        self._robot = client.loadURDF(f"{pybullet_data.getDataPath()}/{PANDA_URDF}", useFixedBase=True)
        names = {client.getJointInfo(self._robot, j)[1].decode(): j for j in range(client.getNumJoints(self._robot))}
        links = {client.getJointInfo(self._robot, j)[12].decode(): j for j in range(client.getNumJoints(self._robot))}
        self._joints = [names[name] for name in ARM_JOINTS]
        self._flange = links[FLANGE_LINK]
        movable = [j for j in range(client.getNumJoints(self._robot))
                   if client.getJointInfo(self._robot, j)[2] != pybullet.JOINT_FIXED]
        self._ik_slots = [movable.index(j) for j in self._joints]  # the Jacobian has a column per movable joint
        self._movable = len(movable)
        info = [client.getJointInfo(self._robot, j) for j in self._joints]
        self.lower_deg = np.degrees([i[8] for i in info])
        self.upper_deg = np.degrees([i[9] for i in info])
        self._q = np.radians(READY_JOINTS_DEG)
        self._body_ids: list[int] = self._create_bodies() if bodies else []
        self.reset_tool(T_world_tool)

    # ----------------------------------------------------------------- state
    @property
    def joints_deg(self) -> np.ndarray:
        """Current joints 1-7, deg (a copy)."""
        return np.degrees(self._q)

    def T_world_flange(self) -> np.ndarray:
        return self.T_world_base @ self._forward(self._q)

    def T_world_tool(self) -> np.ndarray:
        return self.T_world_base @ self._forward(self._q) @ self.T_flange_tool

    def tool_pose_mm_deg(self) -> np.ndarray:
        """Tool x, y, z (mm) in the base frame and its turn R about the base's vertical (deg): the angle of the
        tool's x axis projected on the base's horizontal plane."""
        T_base_tool = self._forward(self._q) @ self.T_flange_tool
        x_axis = T_base_tool[:3, 0]
        return np.array([*T_base_tool[:3, 3], math.degrees(math.atan2(x_axis[1], x_axis[0]))])

    # -------------------------------------------------------------- commands
    def reset_tool(self, T_world_tool: np.ndarray) -> None:
        """Put the tool at ``T_world_tool`` at once (IK from the ready configuration); cancels any motion."""
        self._q = self.solve(T_world_tool, np.radians(READY_JOINTS_DEG))
        self._motion = None

    def servo_tool(self, T_world_tool: np.ndarray, duration_s: float) -> float:
        """Move the tool to ``T_world_tool`` over ``duration_s`` s, replacing any previous target; returns the
        motion's duration (longer where the speed limits apply).

        Raises:
            ValueError: ``duration_s`` not positive and finite.
            LimitError, UnreachableError: the target is outside the limits or reach; the arm keeps its motion.
        """
        if not (math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"servo duration_s must be finite and > 0, got {duration_s!r}")
        target = np.array(T_world_tool, dtype=np.float64)
        end_q = self.solve(target, self._q)
        start = self.T_world_tool()
        distance_mm = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
        duration = max(duration_s, distance_mm / self.config.max_linear_speed_mm_s,
                       _rotation_angle_deg(start[:3, :3].T @ target[:3, :3]) / self.config.max_angular_speed_deg_s)
        return self._start_motion(start, target, duration, end_q)

    def _arrive(self, end: np.ndarray, end_joints: np.ndarray) -> None:  # the target was solved by servo_tool
        self._q = end_joints.copy()

    def _pass_through(self, start: np.ndarray, end: np.ndarray, fraction: float) -> None:
        self._q = self.solve(_interpolate(start, end, fraction), self._q)

    # ------------------------------------------------------------- kinematics
    def solve(self, T_world_tool: np.ndarray, start_q: np.ndarray) -> np.ndarray:
        """Joints (rad) that put the tool at ``T_world_tool``, from ``start_q`` (rad); refuses (LimitError,
        UnreachableError) a target outside the joint ranges or the reach."""
        T_world_tool = np.asarray(T_world_tool, dtype=np.float64)
        if T_world_tool.shape != (4, 4) or not np.all(np.isfinite(T_world_tool)):
            raise ValueError(f"T_world_tool must be a finite 4x4 transform, got {T_world_tool!r}")
        T_base_flange = self._T_base_world @ T_world_tool @ self._T_tool_flange
        q = np.asarray(start_q, dtype=np.float64).copy()
        error_mm, error_deg = math.inf, math.inf
        for _ in range(self.config.ik_iterations):
            reached = self._forward(q)
            error = np.concatenate([(T_base_flange[:3, 3] - reached[:3, 3]) / 1000.0,
                                    _rotation_vector(T_base_flange[:3, :3] @ reached[:3, :3].T)])
            error_mm = 1000.0 * float(np.linalg.norm(error[:3]))
            error_deg = math.degrees(float(np.linalg.norm(error[3:])))
            if error_mm <= self.config.position_tolerance_mm and error_deg <= self.config.orientation_tolerance_deg:
                break
            jacobian = self._jacobian(q)
            inverse = jacobian.T @ np.linalg.inv(jacobian @ jacobian.T + _DAMPING ** 2 * np.eye(6))
            # the seventh joint's freedom pulls gently back to the ready configuration, away from the limits
            null_space = np.eye(len(q)) - inverse @ jacobian
            q = q + inverse @ error + null_space @ (_NULL_SPACE_GAIN * (np.radians(READY_JOINTS_DEG) - q))
        else:
            self._set_joints(self._q)
            where = np.round(T_world_tool[:3, 3], 1).tolist()
            raise UnreachableError(
                f"Panda cannot reach the tool target at {where} mm (world): the closest solution is {error_mm:.2f} mm "
                f"and {error_deg:.2f} deg off (tolerances {self.config.position_tolerance_mm} mm, "
                f"{self.config.orientation_tolerance_deg} deg)")
        q_deg = np.degrees(q)
        for index, (value, low, high) in enumerate(zip(q_deg, self.lower_deg, self.upper_deg)):
            if not low - 1e-9 <= value <= high + 1e-9:
                self._set_joints(self._q)
                raise LimitError(ARM_JOINTS[index], value, low, high,
                                 note=f"(Panda tool target at {np.round(T_world_tool[:3, 3], 1).tolist()} mm)")
        return q

    def _set_joints(self, q: np.ndarray) -> None:
        client = self._model.client
        for joint, value in zip(self._joints, q):
            client.resetJointState(self._robot, joint, float(value))

    def _jacobian(self, q: np.ndarray) -> np.ndarray:
        """(6, 7) the flange's linear (m/rad) and angular Jacobian at joints ``q`` (rad), base frame."""
        self._set_joints(q)
        positions = [0.0] * self._movable
        for slot, value in zip(self._ik_slots, q):
            positions[slot] = float(value)
        zeros = [0.0] * self._movable
        linear, angular = self._model.client.calculateJacobian(self._robot, self._flange, [0.0, 0.0, 0.0],
                                                               positions, zeros, zeros)
        return np.concatenate([np.asarray(linear), np.asarray(angular)])[:, self._ik_slots]

    def _forward(self, q: np.ndarray) -> np.ndarray:
        """4x4 (mm) the flange in the base frame at joints ``q`` (rad)."""
        self._set_joints(q)
        state = self._model.client.getLinkState(self._robot, self._flange, computeForwardKinematics=True)
        return _pybullet_to_matrix(state[4], state[5])

    # ---------------------------------------------------------------- bodies
    def _link_points_base_mm(self) -> list[np.ndarray]:
        """Joint 1-7 origins and the flange, base frame, mm, at the current joints."""
        self._set_joints(self._q)
        client = self._model.client
        return [np.asarray(client.getLinkState(self._robot, j, computeForwardKinematics=True)[4]) * 1000.0
                for j in self._joints] + [self._forward(self._q)[:3, 3]]

    def _create_bodies(self) -> list[int]:
        """One box per link, joint to joint (the distances are rigid: sized once)."""
        client, ids = self.world.client, []
        points = self._link_points_base_mm()
        for start, end in zip(points[:-1], points[1:]):
            length_mm = max(float(np.linalg.norm(end - start)), 1.0)
            half_m = [self.config.link_width_mm / 2000.0] * 2 + [length_mm / 2000.0]
            visual = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_m, rgbaColor=[0.9, 0.9, 0.92, 1.0])
            ids.append(client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=visual))
        return ids

    def update_bodies(self) -> None:
        """Place the link boxes at the current joints (no-op without bodies)."""
        if not self._body_ids:
            return
        points = [(self.T_world_base @ np.append(p, 1.0))[:3] for p in self._link_points_base_mm()]
        for body, start, end in zip(self._body_ids, points[:-1], points[1:]):
            position_m, quaternion = matrix_to_pybullet_fast(_segment_frame(start, end))
            self.world.client.resetBasePositionAndOrientation(body, position_m, quaternion)

    def close(self) -> None:
        self._model.close()


def _pybullet_to_matrix(position_m, quaternion_xyzw) -> np.ndarray:
    x, y, z, w = quaternion_xyzw
    matrix = np.eye(4)
    matrix[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    matrix[:3, 3] = np.asarray(position_m) * 1000.0
    return matrix


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of a 3x3 rotation."""
    angle = math.radians(_rotation_angle_deg(rotation))
    axis = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    if angle < 1e-9:
        return axis / 2.0
    if angle > math.pi - 1e-6:  # half turn: the axis from the symmetric part
        axis = np.sqrt(np.maximum((np.diag(rotation) + 1.0) / 2.0, 0.0))
        k = int(np.argmax(axis))
        signs = np.where(rotation[k] + rotation[:, k] < 0, -1.0, 1.0)
        signs[k] = 1.0
        return axis * signs / np.linalg.norm(axis) * angle
    return axis / (2.0 * math.sin(angle)) * angle


def _rotation_angle_deg(rotation: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(rotation)) - 1.0) / 2.0))))


def _interpolate(start: np.ndarray, end: np.ndarray, fraction: float) -> np.ndarray:
    """The pose ``fraction`` of the way from ``start`` to ``end``: straight line, shortest rotation (Rodrigues)."""
    relative = start[:3, :3].T @ end[:3, :3]
    angle = math.radians(_rotation_angle_deg(relative))
    pose = np.eye(4)
    pose[:3, 3] = start[:3, 3] + fraction * (end[:3, 3] - start[:3, 3])
    if angle < 1e-9:
        pose[:3, :3] = start[:3, :3]
        return pose
    axis = np.array([relative[2, 1] - relative[1, 2], relative[0, 2] - relative[2, 0],
                     relative[1, 0] - relative[0, 1]]) / (2.0 * math.sin(angle))
    pose[:3, :3] = start[:3, :3] @ axis_angle_matrix(axis * fraction * angle)
    return pose


def axis_angle_matrix(rotation_vector: np.ndarray) -> np.ndarray:
    """3x3 rotation of a rotation vector (axis times angle, rad), Rodrigues' formula."""
    vector = np.asarray(rotation_vector, dtype=np.float64)
    angle = float(np.linalg.norm(vector))
    if angle < 1e-12:
        return np.eye(3)
    kx, ky, kz = vector / angle
    K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)
