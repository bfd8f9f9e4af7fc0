"""The real-robot safety layer, in one place: target checks, stop conditions and dry-run.

Every motion command the MG400 client sends passes :meth:`SafetyLayer.check_target` (Cartesian targets) or
:meth:`SafetyLayer.check_joint_target` (joint targets) first, and then :meth:`SafetyLayer.submit`, which only logs
in dry-run mode. A refused target raises :class:`SafetyError` and nothing is sent.

Checks, in order: the arm's joint limits and the J2/J3 coupling (via :mod:`simshear_gym.robots.mg400.kinematics`),
the workspace box and radius, the step from the current pose, and for queued moves the path in between (sampled
every ``path_check_step_mm``; MovL is straight in Cartesian space, MovJ/JointMovJ straight in joint space).

Poses are ``(x_mm, y_mm, z_mm, r_deg)`` in the robot base frame; joints ``(J1, J2, J3, J4)`` in deg.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from simshear_gym.data.labels import wrap_deg
from simshear_gym.robots.mg400.kinematics import (
    JOINT_NAMES,
    KinematicsError,
    MG400Geometry,
    MG400Limits,
    check_joint_limits,
    check_pose_reachable,
    forward,
)

logger = logging.getLogger(__name__)

T = TypeVar("T")


class SafetyError(RuntimeError):
    """A command was refused by the safety layer; nothing was sent to the robot."""


class MotionKind(enum.Enum):
    """How the robot moves to a target, which decides the step limit and the path check."""

    SERVO = "servo"  # ServoP / ServoJ: small step per command (max_step_*), no path check
    LINEAR = "linear"  # MovL: queued, straight line in Cartesian space (max_move_*)
    JOINT = "joint"  # MovJ / JointMovJ: queued, straight line in joint space (max_move_*)


def _range(pair: tuple[float, float], name: str) -> None:
    if len(pair) != 2 or any(math.isnan(v) for v in pair) or pair[0] >= pair[1]:
        raise ValueError(f"SafetyConfig.{name} must be (lower, upper) with lower < upper, got {pair!r}")


@dataclass(frozen=True)
class SafetyConfig:
    """Limits enforced before any motion command is sent.

    Attributes:
        max_step_mm: largest translation of one servo command from the current/previous target, mm.
        max_step_deg: largest R change and per-joint change of one servo command, deg.
        max_move_mm: largest translation of one queued move (MovJ/MovL/JointMovJ), mm.
        max_move_deg: largest R change and per-joint change of one queued move, deg.
        x_range_mm, y_range_mm, z_range_mm: workspace box of the flange in the base frame, mm.
        radius_range_mm: allowed horizontal distance of the flange from the J1 axis, mm.
        r_range_deg: allowed flange rotation R, deg.
        path_check_step_mm: spacing of the points checked along a queued move, mm.
        max_feedback_age_s: feedback older than this counts as a lost connection, s.
        max_camera_frame_age_s: a camera frame older than this counts as a stalled camera, s.
        stop_on_lost_contact: stop when the snapshot says contact was lost.
        dry_run: log motion commands instead of sending them.
        geometry, limits: the arm model (mm) and joint limits (deg).
    """

    max_step_mm: float = 5.0
    max_step_deg: float = 5.0
    max_move_mm: float = 200.0
    max_move_deg: float = 90.0
    x_range_mm: tuple[float, float] = (150.0, 440.0)
    y_range_mm: tuple[float, float] = (-250.0, 250.0)
    z_range_mm: tuple[float, float] = (-150.0, 150.0)
    radius_range_mm: tuple[float, float] = (180.0, 440.0)
    r_range_deg: tuple[float, float] = (-180.0, 180.0)
    path_check_step_mm: float = 5.0
    max_feedback_age_s: float = 0.1
    max_camera_frame_age_s: float = 0.5
    stop_on_lost_contact: bool = True
    dry_run: bool = False
    geometry: MG400Geometry = field(default_factory=MG400Geometry)
    limits: MG400Limits = field(default_factory=MG400Limits)

    def __post_init__(self) -> None:
        for name in ("max_step_mm", "max_step_deg", "max_move_mm", "max_move_deg", "path_check_step_mm",
                     "max_feedback_age_s", "max_camera_frame_age_s"):
            value = getattr(self, name)
            if math.isnan(value) or value <= 0.0:
                raise ValueError(f"SafetyConfig.{name} must be > 0, got {value!r}")
        if math.isinf(self.path_check_step_mm):
            raise ValueError("SafetyConfig.path_check_step_mm must be finite")
        for name in ("x_range_mm", "y_range_mm", "z_range_mm", "radius_range_mm", "r_range_deg"):
            _range(getattr(self, name), name)

    @classmethod
    def arm_limits_only(cls, dry_run: bool = False) -> SafetyConfig:
        """Only the arm's joint limits: unbounded workspace and steps (the client's default)."""
        inf = math.inf
        return cls(max_step_mm=inf, max_step_deg=inf, max_move_mm=inf, max_move_deg=inf,
                   x_range_mm=(-inf, inf), y_range_mm=(-inf, inf), z_range_mm=(-inf, inf),
                   radius_range_mm=(0.0, inf), r_range_deg=(-inf, inf), dry_run=dry_run)


@dataclass(frozen=True)
class StatusSnapshot:
    """What the stop conditions look at; ``None`` means "not tracked" and never stops.

    Attributes:
        connected: all robot connections are up.
        robot_mode: the controller's RobotMode value.
        feedback_age_s: age of the newest feedback packet, s.
        camera_frame_age_s: age of the newest tactile-camera frame, s.
        in_contact: whether the tactile sensor touches the surface.
    """

    connected: bool
    robot_mode: int | None = None
    feedback_age_s: float | None = None
    camera_frame_age_s: float | None = None
    in_contact: bool | None = None


class StopReason(enum.Enum):
    """Why :meth:`SafetyLayer.check_status` stops, one member per stop condition, in order of precedence (when
    several hold, the first decides how the episode ends)."""

    LOST_CONNECTION = "lost_connection"  # a robot connection is down
    STALE_FEEDBACK = "stale_feedback"  # the newest feedback packet is older than max_feedback_age_s
    ROBOT_ERROR_MODE = "robot_error_mode"  # the controller reports RobotMode ERROR
    CAMERA_STALLED = "camera_stalled"  # the newest camera frame is older than max_camera_frame_age_s
    LOST_CONTACT = "lost_contact"  # the snapshot says the sensor left the surface (stop_on_lost_contact)


@dataclass(frozen=True)
class StatusStop:
    """One stop condition that holds: ``reason`` to act on, ``message`` for people (values and limits)."""

    reason: StopReason
    message: str


@dataclass(frozen=True)
class StopDecision:
    """The stop conditions that hold (none: carry on), in the order of :class:`StopReason`."""

    stops: tuple[StatusStop, ...] = ()

    @property
    def stop(self) -> bool:
        """Whether any stop condition holds."""
        return bool(self.stops)

    @property
    def reason(self) -> StopReason | None:
        """The stop condition that takes precedence, None when there is none."""
        order = list(StopReason)
        return min((stop.reason for stop in self.stops), key=order.index, default=None)

    @property
    def reasons(self) -> tuple[str, ...]:
        """The messages of the stop conditions, for logs."""
        return tuple(stop.message for stop in self.stops)


_ROBOT_MODE_ERROR = 9  # RobotMode.ERROR; kept numeric so this module does not depend on the protocol module


class SafetyLayer:
    """Checks targets against the arm, the workspace and the step limits; decides stop/continue; dry-run."""

    def __init__(self, config: SafetyConfig | None = None) -> None:
        self.config = config if config is not None else SafetyConfig()

    @property
    def dry_run(self) -> bool:
        """Whether motion commands are logged instead of sent."""
        return self.config.dry_run

    # -- targets -------------------------------------------------------------------------------------------------

    def check_target(self, current_pose: Sequence[float], target_pose: Sequence[float],
                     kind: MotionKind = MotionKind.SERVO) -> np.ndarray:
        """Validate a Cartesian target.

        Args:
            current_pose: where the robot is (or was last sent), ``(x_mm, y_mm, z_mm, r_deg)``.
            target_pose: the commanded pose, same units.
            kind: the motion type, which picks the step limit and the path check.

        Returns:
            The target's joint angles, deg.

        Raises:
            SafetyError: naming the failed check, the value and the limit.
        """
        current = self._pose(current_pose, "current_pose")
        target = self._pose(target_pose, "target_pose")
        target_joints = self._reachable(target, "target")
        self._check_workspace(target, "target")
        current_joints = self._joints_or_none(current)
        self._check_step(current, target, current_joints, target_joints, kind)
        if kind is MotionKind.LINEAR:
            self._check_linear_path(current, target)
        elif kind is MotionKind.JOINT and current_joints is not None:
            self._check_joint_path(current_joints, target_joints)
        return target_joints

    def check_joint_target(self, current_joints_deg: Sequence[float], target_joints_deg: Sequence[float],
                           kind: MotionKind = MotionKind.SERVO) -> tuple[float, float, float, float]:
        """Validate a joint target (ServoJ, JointMovJ); ``MotionKind.LINEAR`` is treated as ``JOINT``.

        Returns:
            The target's flange pose ``(x_mm, y_mm, z_mm, r_deg)``.

        Raises:
            SafetyError: naming the failed check, the value and the limit.
        """
        current_joints = self._pose(current_joints_deg, "current_joints_deg")
        target_joints = self._pose(target_joints_deg, "target_joints_deg")
        try:
            check_joint_limits(target_joints, self.config.limits)
        except KinematicsError as error:
            raise SafetyError(f"target joints {self._fmt(target_joints)} deg are beyond the arm's limits: {error}") \
                from error
        target = np.array(forward(target_joints, self.config.geometry))
        self._check_workspace(target, "target")
        current = np.array(forward(current_joints, self.config.geometry))
        self._check_step(current, target, current_joints, target_joints, kind)
        if kind is not MotionKind.SERVO:
            self._check_joint_path(current_joints, target_joints)
        return tuple(float(v) for v in target)  # type: ignore[return-value]

    # -- stop conditions -----------------------------------------------------------------------------------------

    def check_status(self, snapshot: StatusSnapshot) -> StopDecision:
        """Decide stop/continue: lost connection or stale feedback, robot error mode, camera stall, lost contact
        (a :class:`StopReason` and a message for each condition that holds)."""
        cfg = self.config
        stops: list[StatusStop] = []
        if not snapshot.connected:
            stops.append(StatusStop(StopReason.LOST_CONNECTION, "lost connection to the robot"))
        elif snapshot.feedback_age_s is not None and snapshot.feedback_age_s > cfg.max_feedback_age_s:
            stops.append(StatusStop(StopReason.STALE_FEEDBACK,
                                    f"robot feedback is {snapshot.feedback_age_s:.3f} s old "
                                    f"(max_feedback_age_s = {cfg.max_feedback_age_s:g})"))
        if snapshot.robot_mode is not None and snapshot.robot_mode == _ROBOT_MODE_ERROR:
            stops.append(StatusStop(StopReason.ROBOT_ERROR_MODE, "robot is in error mode"))
        if snapshot.camera_frame_age_s is not None and snapshot.camera_frame_age_s > cfg.max_camera_frame_age_s:
            stops.append(StatusStop(StopReason.CAMERA_STALLED,
                                    f"camera stalled: newest frame is {snapshot.camera_frame_age_s:.3f} s old "
                                    f"(max_camera_frame_age_s = {cfg.max_camera_frame_age_s:g})"))
        if cfg.stop_on_lost_contact and snapshot.in_contact is False:
            stops.append(StatusStop(StopReason.LOST_CONTACT, "lost contact with the surface"))
        return StopDecision(tuple(stops))

    # -- sending -------------------------------------------------------------------------------------------------

    def submit(self, command: str, send: Callable[[str], T]) -> T | None:
        """Send ``command`` with ``send``; in dry-run mode log it instead and return None."""
        if self.config.dry_run:
            logger.info("dry run: not sending %s", command)
            return None
        return send(command)

    # -- helpers -------------------------------------------------------------------------------------------------

    @staticmethod
    def _fmt(values: np.ndarray) -> str:
        return "(" + ", ".join(f"{v:.3f}" for v in values) + ")"

    @staticmethod
    def _pose(values: Sequence[float], name: str) -> np.ndarray:
        array = np.asarray(values, dtype=float).reshape(-1)
        if array.shape != (4,) or not np.all(np.isfinite(array)):
            raise SafetyError(f"{name} must be 4 finite numbers, got {list(np.asarray(values).reshape(-1))}")
        return array

    def _reachable(self, pose: np.ndarray, what: str) -> np.ndarray:
        try:
            return check_pose_reachable(pose, self.config.geometry, self.config.limits)
        except KinematicsError as error:
            raise SafetyError(f"{what} pose {self._fmt(pose)} (mm, deg) is beyond the arm's limits: {error}") \
                from error

    def _joints_or_none(self, pose: np.ndarray) -> np.ndarray | None:
        try:
            return check_pose_reachable(pose, self.config.geometry, self.config.limits)
        except KinematicsError:
            return None  # the measured pose may sit a hair outside the model; the Cartesian step still applies

    def _check_workspace(self, pose: np.ndarray, what: str) -> None:
        cfg = self.config
        x_mm, y_mm, z_mm, r_deg = pose
        for name, value, (lower, upper), unit in (("x_mm", x_mm, cfg.x_range_mm, "mm"),
                                                  ("y_mm", y_mm, cfg.y_range_mm, "mm"),
                                                  ("z_mm", z_mm, cfg.z_range_mm, "mm"),
                                                  ("radius_mm", math.hypot(x_mm, y_mm), cfg.radius_range_mm, "mm"),
                                                  ("r_deg", r_deg, cfg.r_range_deg, "deg")):
            if not lower <= value <= upper:
                raise SafetyError(f"{what} {name} = {value:.3f} {unit} is outside the workspace "
                                  f"[{lower:g}, {upper:g}] {unit}")

    def _check_step(self, current: np.ndarray, target: np.ndarray, current_joints: np.ndarray | None,
                    target_joints: np.ndarray, kind: MotionKind) -> None:
        cfg = self.config
        if kind is MotionKind.SERVO:
            max_mm, max_deg, names = cfg.max_step_mm, cfg.max_step_deg, ("max_step_mm", "max_step_deg")
        else:
            max_mm, max_deg, names = cfg.max_move_mm, cfg.max_move_deg, ("max_move_mm", "max_move_deg")
        step_mm = float(np.linalg.norm(target[:3] - current[:3]))
        if step_mm > max_mm:
            raise SafetyError(f"step of {step_mm:.3f} mm from {self._fmt(current[:3])} to {self._fmt(target[:3])} "
                              f"exceeds {names[0]} = {max_mm:g} mm")
        step_r_deg = abs(wrap_deg(target[3] - current[3]))
        if step_r_deg > max_deg:
            raise SafetyError(f"R step of {step_r_deg:.3f} deg exceeds {names[1]} = {max_deg:g} deg")
        if current_joints is not None:
            for index, name in enumerate(JOINT_NAMES):
                delta = target_joints[index] - current_joints[index]
                if index == 3:
                    delta = wrap_deg(delta)
                if abs(delta) > max_deg:
                    raise SafetyError(f"{name} step of {abs(delta):.3f} deg exceeds {names[1]} = {max_deg:g} deg")

    def _check_linear_path(self, start: np.ndarray, end: np.ndarray) -> None:
        distance_mm = float(np.linalg.norm(end[:3] - start[:3]))
        count = max(1, math.ceil(distance_mm / self.config.path_check_step_mm))
        for fraction in np.linspace(0.0, 1.0, count + 1)[1:-1]:
            point = start + fraction * (end - start)
            self._reachable(point, f"MovL path point at {fraction:.0%}")
            self._check_workspace(point, f"MovL path point at {fraction:.0%}")

    def _check_joint_path(self, start: np.ndarray, end: np.ndarray) -> None:
        geometry = self.config.geometry
        distance_mm = float(np.linalg.norm(np.subtract(forward(end, geometry)[:3], forward(start, geometry)[:3])))
        spread_deg = float(np.max(np.abs(end - start)))
        # Sample finely enough in both Cartesian distance and joint angle (1 deg ~ 6 mm at full reach).
        count = max(1, math.ceil(max(distance_mm / self.config.path_check_step_mm, spread_deg)))
        for fraction in np.linspace(0.0, 1.0, count + 1)[1:-1]:
            joints = start + fraction * (end - start)
            where = f"joint-space path point at {fraction:.0%}"
            try:
                check_joint_limits(joints, self.config.limits)
            except KinematicsError as error:
                raise SafetyError(f"{where} {self._fmt(joints)} deg is beyond the arm's limits: {error}") from error
            self._check_workspace(np.array(forward(joints, geometry)), where)
