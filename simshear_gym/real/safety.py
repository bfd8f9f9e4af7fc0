"""The real-robot safety layer, in one place: target checks, feedback agreement, stop conditions and dry-run.

Every motion command the MG400 client sends passes :meth:`SafetyLayer.check_target` (Cartesian targets) or
:meth:`SafetyLayer.check_joint_target` (joint targets) first, and then :meth:`SafetyLayer.submit`, which only logs
in dry-run mode. A refused target raises :class:`SafetyError` and nothing is sent.

Checks, in order: the arm's joint limits and the J2/J3 coupling (via :mod:`simshear_gym.robots.mg400.kinematics`),
the workspace box and radius, the step from the current pose (Cartesian from the pose, per joint from the joints),
for servo commands the speed (step / ``t``, Cartesian and per joint), and for queued moves the path in between
(sampled every ``path_check_step_mm``; MovL is straight in Cartesian space, MovJ/JointMovJ straight in joint space).

**A stream of commands** (:class:`MotionStream`, one per arm: each client holds its own). A servo command replaces
the target the arm is heading to and asks it to get there from *wherever it is* in ``t``, so a burst of commands,
each a small step from the one before, can ask the arm for far more than one step's speed. The stream check bounds
what the arm is asked to do: the distance from the new target to every place the arm may be (the fed-back pose, the
target in force when that packet was sampled and every target sent since, within ``stream_latency_s``: the arm
moves on straight lines between these, so it stays in their convex hull), over ``t``, must stay within
``max_speed_mm_s`` / ``max_speed_deg_s`` (R and every joint); and the velocity it asks for may differ from the
velocity of the command in force (zero once that one has arrived) by at most ``max_accel_*`` times the time since
that command (at most ``t``). Queued moves (MovL, MovJ, JointMovJ, RelMovL, RelMovJ) are planned by the controller:
each is sent with the ``SpeedL``/``SpeedJ`` and ``AccL``/``AccJ`` ratios that keep the arm within the same
speed and acceleration bounds at the controller's speeds at 100 % (``arm_*``, upper bounds of the real arm's), and
:func:`queued_ratios` refuses a move that even the slowest ratio would make too fast. A servo command over the
stream limits is refused (:class:`SafetyError`), or, with ``servo_over_limit="clamp"`` (the user's explicit choice
for a servo stream), moved back toward where the arm is until it is within them.
:meth:`SafetyLayer.check_feedback_agreement` checks that joint feedback and the reported pose agree (forward
kinematics within ``max_pose_mismatch_mm`` / ``_deg``); the client runs it before it trusts a measurement and on
every feedback packet.

**Safe by default.** :class:`SafetyConfig`'s defaults are limits for tactile work near a surface (5 mm and
50 mm/s per servo command, 50 mm per queued move). A :class:`SafetyConfig` cannot loosen them: a looser value
raises ``ValueError``. Loosening takes :class:`UnsafeSafetyConfig`, whose name says so and whose loosened limits
:class:`SafetyLayer` logs as a warning when it is built.

Poses are ``(x_mm, y_mm, z_mm, r_deg)`` in the robot base frame; joints ``(J1, J2, J3, J4)`` in deg.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import ClassVar, TypeVar

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

DEFAULT_SERVO_TIME_S = 0.1
"""The controller's default ``t`` of ServoP / ServoJ, s: the speed check's duration when none is given."""


class SafetyError(RuntimeError):
    """A command was refused by the safety layer; nothing was sent to the robot."""


class FeedbackMismatchError(SafetyError):
    """The joint feedback and the reported pose disagree (forward kinematics beyond the tolerance): the robot's
    state is not known, so nothing is sent."""


class MotionRefusedError(SafetyError):
    """Motion refused because of the robot's state, not the target: stale or missing feedback, or error mode.

    Attributes:
        reason: the stop condition (:attr:`StopReason.STALE_FEEDBACK` or :attr:`StopReason.ROBOT_ERROR_MODE`).
    """

    def __init__(self, reason: StopReason, message: str) -> None:
        self.reason = reason
        super().__init__(message)


class MotionKind(enum.Enum):
    """How the robot moves to a target, which decides the step limit and the path check."""

    SERVO = "servo"  # ServoP / ServoJ: small step per command (max_step_*), speed step / t (max_speed_*)
    LINEAR = "linear"  # MovL: queued, straight line in Cartesian space (max_move_*)
    JOINT = "joint"  # MovJ / JointMovJ: queued, straight line in joint space (max_move_*)


def _range(pair: tuple[float, float], name: str) -> None:
    if len(pair) != 2 or any(math.isnan(v) for v in pair) or pair[0] >= pair[1]:
        raise ValueError(f"SafetyConfig.{name} must be (lower, upper) with lower < upper, got {pair!r}")


# Limits where a larger value is looser, and (lower, upper) ranges where a wider one is.
_UPPER_LIMITS: tuple[str, ...] = ("max_step_mm", "max_step_deg", "max_speed_mm_s", "max_speed_deg_s", "max_move_mm",
                                  "max_move_deg", "max_pose_mismatch_mm", "max_pose_mismatch_deg",
                                  "path_check_step_mm", "max_accel_mm_s2", "max_accel_deg_s2")
# Settings where a smaller value is looser: the assumed delays and the controller's assumed speeds at 100 %.
_LOWER_LIMITS: tuple[str, ...] = ("stream_latency_s", "controller_cycle_s", "arm_linear_speed_mm_s",
                                  "arm_rotation_speed_deg_s", "arm_joint_speed_deg_s", "arm_linear_accel_mm_s2",
                                  "arm_joint_accel_deg_s2")
SERVO_OVER_LIMIT: tuple[str, ...] = ("refuse", "clamp")
"""What the client does with a servo command over the stream limits: refuse it (default) or clamp it."""
_RANGES: tuple[str, ...] = ("x_range_mm", "y_range_mm", "z_range_mm", "radius_range_mm", "r_range_deg")
_JOINT_RANGES: tuple[str, ...] = ("j1_deg", "j2_deg", "j3_deg", "j4_deg")


@dataclass(frozen=True)
class SafetyConfig:
    """Limits enforced before any motion command is sent; the defaults are safe for tactile work near a surface
    and a ``SafetyConfig`` may only tighten them (loosening takes :class:`UnsafeSafetyConfig`).

    Attributes:
        max_step_mm: largest translation of one servo command from the previous target (or the measured pose), mm.
        max_step_deg: largest R change and per-joint change of one servo command, deg.
        max_speed_mm_s: largest Cartesian speed of one servo command: its translation over its ``t``, mm/s.
        max_speed_deg_s: largest R and per-joint speed of one servo command: change over ``t``, deg/s.
        max_move_mm: largest translation (jump) of one queued move (MovJ/MovL/JointMovJ), mm.
        max_move_deg: largest R change and per-joint change of one queued move, deg.
        x_range_mm, y_range_mm, z_range_mm: workspace box of the flange in the base frame, mm.
        radius_range_mm: allowed horizontal distance of the flange from the J1 axis, mm.
        r_range_deg: allowed flange rotation R, deg.
        path_check_step_mm: spacing of the points checked along a queued move, mm.
        max_pose_mismatch_mm: largest distance between the reported flange position and the forward kinematics
            of the reported joints, mm (more: the feedback disagrees and the client stops).
        max_pose_mismatch_deg: the same for R, deg.
        max_accel_mm_s2: largest change of the Cartesian velocity a servo command asks for, per second, mm/s^2;
            also the acceleration of queued moves (``AccL``).
        max_accel_deg_s2: the same for R and every joint, deg/s^2 (``AccJ`` for queued joint moves).
        stream_latency_s: the assumed bound on the delays between the controller and the client (a feedback packet
            on its way plus a command on its way), s: every target sent this long before the newest feedback packet
            arrived, or later, may still be ahead of the arm. Larger is stricter.
        controller_cycle_s: the controller's servo cycle, s: a new target takes effect on its cycle, so the time
            between two velocity changes is known to within one cycle (two after an arrival); the acceleration check
            counts that time short by as much. Larger is stricter.
        refuse_stale_feedback: refuse every motion command while the feedback stream (when the client uses one)
            has no packet newer than ``max_feedback_age_s`` or the robot reports error mode.
        servo_over_limit: ``"refuse"`` a servo command over the stream limits (default), or ``"clamp"`` it: move it
            back toward the arm until it is within them (a servo stream that should slow down, not stop).
        arm_linear_speed_mm_s, arm_rotation_speed_deg_s, arm_joint_speed_deg_s: the controller's speed of MovL
            (flange, R) and of joint moves at ``SpeedL`` / ``SpeedJ`` = ``SpeedFactor`` = 100 %: upper bounds of
            the real arm's, from which the client computes the ratios it sends (smaller is looser).
        arm_linear_accel_mm_s2, arm_joint_accel_deg_s2: the same for the acceleration at ``AccL`` / ``AccJ`` 100 %.
        max_feedback_age_s: feedback older than this counts as a lost connection, s.
        max_camera_frame_age_s: a camera frame older than this counts as a stalled camera, s.
        stop_on_lost_contact: stop when the snapshot says contact was lost.
        dry_run: log motion commands instead of sending them.
        geometry, limits: the arm model (mm) and joint limits (deg).
    """

    unsafe: ClassVar[bool] = False
    """True only for :class:`UnsafeSafetyConfig`: may loosen the limits."""

    max_step_mm: float = 5.0
    max_step_deg: float = 5.0
    max_speed_mm_s: float = 50.0
    max_speed_deg_s: float = 50.0
    max_move_mm: float = 50.0
    max_move_deg: float = 45.0
    x_range_mm: tuple[float, float] = (150.0, 440.0)
    y_range_mm: tuple[float, float] = (-250.0, 250.0)
    z_range_mm: tuple[float, float] = (-150.0, 150.0)
    radius_range_mm: tuple[float, float] = (180.0, 440.0)
    r_range_deg: tuple[float, float] = (-180.0, 180.0)
    path_check_step_mm: float = 5.0
    max_pose_mismatch_mm: float = 1.0
    max_pose_mismatch_deg: float = 1.0
    max_accel_mm_s2: float = 2000.0
    max_accel_deg_s2: float = 2000.0
    stream_latency_s: float = 0.01
    controller_cycle_s: float = 0.008
    refuse_stale_feedback: bool = True
    servo_over_limit: str = "refuse"
    arm_linear_speed_mm_s: float = 1000.0
    arm_rotation_speed_deg_s: float = 360.0
    arm_joint_speed_deg_s: float = 400.0
    arm_linear_accel_mm_s2: float = 10000.0
    arm_joint_accel_deg_s2: float = 4000.0
    max_feedback_age_s: float = 0.1
    max_camera_frame_age_s: float = 0.5
    stop_on_lost_contact: bool = True
    dry_run: bool = False
    geometry: MG400Geometry = field(default_factory=MG400Geometry)
    limits: MG400Limits = field(default_factory=MG400Limits)

    def __post_init__(self) -> None:
        for name in _UPPER_LIMITS + _LOWER_LIMITS + ("max_feedback_age_s", "max_camera_frame_age_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) or value <= 0.0:
                raise ValueError(f"SafetyConfig.{name} must be > 0, got {value!r}")
        for name in _LOWER_LIMITS:
            if math.isinf(getattr(self, name)):
                raise ValueError(f"SafetyConfig.{name} must be finite, got {getattr(self, name)!r}")
        if self.servo_over_limit not in SERVO_OVER_LIMIT:
            raise ValueError(f"SafetyConfig.servo_over_limit must be one of {SERVO_OVER_LIMIT}, got "
                             f"{self.servo_over_limit!r}")
        if not isinstance(self.refuse_stale_feedback, bool):
            raise ValueError(f"SafetyConfig.refuse_stale_feedback must be True or False, got "
                             f"{self.refuse_stale_feedback!r}")
        if math.isinf(self.path_check_step_mm):
            raise ValueError("SafetyConfig.path_check_step_mm must be finite")
        for name in _RANGES:
            _range(getattr(self, name), name)
        loosened = self.loosened()
        if loosened and not self.unsafe:
            raise ValueError(f"{type(self).__name__}: {'; '.join(loosened)}: looser than the safe defaults; "
                             "loosening the robot's limits takes an explicit UnsafeSafetyConfig(...)")

    def loosened(self) -> tuple[str, ...]:
        """The limits looser than the safe defaults, each as ``"name = value (safe default: ...)"``."""
        safe = {f.name: f.default for f in fields(SafetyConfig)
                if f.name in _UPPER_LIMITS + _LOWER_LIMITS + _RANGES + ("refuse_stale_feedback",)}
        out = [f"{name} = {getattr(self, name)!r} (safe default {safe[name]!r})" for name in _UPPER_LIMITS
               if getattr(self, name) > safe[name]]
        out += [f"{name} = {getattr(self, name)!r} (safe default {safe[name]!r})" for name in _LOWER_LIMITS
                if getattr(self, name) < safe[name]]
        if not self.refuse_stale_feedback:
            out.append("refuse_stale_feedback = False (safe default True)")
        for name in _RANGES:
            (lower, upper), (safe_lower, safe_upper) = getattr(self, name), safe[name]
            if lower < safe_lower or upper > safe_upper:
                out.append(f"{name} = {(lower, upper)!r} (safe default {(safe_lower, safe_upper)!r})")
        arm = MG400Limits()
        for name in _JOINT_RANGES:
            (lower, upper), (safe_lower, safe_upper) = getattr(self.limits, name), getattr(arm, name)
            if lower < safe_lower or upper > safe_upper:
                out.append(f"limits.{name} = {(lower, upper)!r} (the arm's {(safe_lower, safe_upper)!r})")
        for name in ("j3_minus_j2_max_deg",):
            if getattr(self.limits, name) > getattr(arm, name):
                out.append(f"limits.{name} = {getattr(self.limits, name)!r} (the arm's {getattr(arm, name)!r})")
        if self.limits.j2_min_when_j3_nonpositive_deg < arm.j2_min_when_j3_nonpositive_deg:
            out.append(f"limits.j2_min_when_j3_nonpositive_deg = {self.limits.j2_min_when_j3_nonpositive_deg!r} "
                       f"(the arm's {arm.j2_min_when_j3_nonpositive_deg!r})")
        return tuple(out)


@dataclass(frozen=True)
class UnsafeSafetyConfig(SafetyConfig):
    """A :class:`SafetyConfig` that may loosen the safe defaults: the explicit, named choice to do so.

    :class:`SafetyLayer` logs every loosened limit as a warning when it is built. Use it for bench tests away from
    any surface, never as a default.
    """

    unsafe: ClassVar[bool] = True

    @classmethod
    def arm_limits_only(cls, dry_run: bool = False) -> UnsafeSafetyConfig:
        """Only the arm's joint limits: unbounded workspace, steps, speeds and jumps."""
        inf = math.inf
        return cls(max_step_mm=inf, max_step_deg=inf, max_speed_mm_s=inf, max_speed_deg_s=inf, max_move_mm=inf,
                   max_move_deg=inf, max_accel_mm_s2=inf, max_accel_deg_s2=inf, x_range_mm=(-inf, inf),
                   y_range_mm=(-inf, inf), z_range_mm=(-inf, inf),
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
    """Checks targets against the arm, the workspace, the step, speed and jump limits and the feedback against
    itself; decides stop/continue; dry-run. Built with an :class:`UnsafeSafetyConfig`, it logs the loosened
    limits as a warning."""

    def __init__(self, config: SafetyConfig | None = None) -> None:
        self.config = config if config is not None else SafetyConfig()
        if self.config.unsafe:
            loosened = self.config.loosened()
            logger.warning("UNSAFE safety limits in use (%s): %s", type(self.config).__name__,
                           "; ".join(loosened) if loosened else "none loosened")

    @property
    def dry_run(self) -> bool:
        """Whether motion commands are logged instead of sent."""
        return self.config.dry_run

    # -- targets -------------------------------------------------------------------------------------------------

    def check_target(self, current_pose: Sequence[float], target_pose: Sequence[float],
                     kind: MotionKind = MotionKind.SERVO, duration_s: float | None = None,
                     current_joints: Sequence[float] | None = None) -> np.ndarray:
        """Validate a Cartesian target.

        Args:
            current_pose: where the robot is (its reported pose) or was last sent, ``(x_mm, y_mm, z_mm, r_deg)``;
                the Cartesian step is measured from it.
            target_pose: the commanded pose, same units.
            kind: the motion type, which picks the step limit, the speed check and the path check.
            duration_s: a servo command's ``t``, s (default :data:`DEFAULT_SERVO_TIME_S`); the speed is step / t.
            current_joints: the joints at ``current_pose`` (the reported joints, or the last target's); default:
                its inverse kinematics. The per-joint steps are measured from them.

        Returns:
            The target's joint angles, deg.

        Raises:
            SafetyError: naming the failed check, the value and the limit.
        """
        current = self._pose(current_pose, "current_pose")
        target = self._pose(target_pose, "target_pose")
        target_joints = self._reachable(target, "target")
        self._check_workspace(target, "target")
        joints = self._joints_or_none(current) if current_joints is None else self._pose(current_joints,
                                                                                         "current_joints")
        self._check_step(current, target, joints, target_joints, kind, duration_s)
        if kind is MotionKind.LINEAR:
            self._check_linear_path(current, target)
        elif kind is MotionKind.JOINT and joints is not None:
            self._check_joint_path(joints, target_joints)
        return target_joints

    def check_joint_target(self, current_joints_deg: Sequence[float], target_joints_deg: Sequence[float],
                           kind: MotionKind = MotionKind.SERVO, duration_s: float | None = None,
                           current_pose: Sequence[float] | None = None) -> tuple[float, float, float, float]:
        """Validate a joint target (ServoJ, JointMovJ); ``MotionKind.LINEAR`` is treated as ``JOINT``.

        Args:
            current_pose: the reported pose at ``current_joints_deg`` (default their forward kinematics); the
                Cartesian step is measured from it.

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
        current = (np.array(forward(current_joints, self.config.geometry)) if current_pose is None
                   else self._pose(current_pose, "current_pose"))
        self._check_step(current, target, current_joints, target_joints, kind, duration_s)
        if kind is not MotionKind.SERVO:
            self._check_joint_path(current_joints, target_joints)
        return tuple(float(v) for v in target)  # type: ignore[return-value]

    def feedback_mismatch(self, joints_deg: Sequence[float], pose: Sequence[float]) -> str | None:
        """Why the reported joints and pose disagree (forward kinematics beyond ``max_pose_mismatch_*``), or None
        when they agree."""
        joints = np.asarray(joints_deg, dtype=float).reshape(-1)
        reported = np.asarray(pose, dtype=float).reshape(-1)
        if joints.shape != (4,) or reported.shape != (4,) or not (np.all(np.isfinite(joints))
                                                                   and np.all(np.isfinite(reported))):
            return (f"feedback is not 4 finite joints and a 4-number pose: joints {joints.tolist()}, "
                    f"pose {reported.tolist()}")
        expected = np.array(forward(joints, self.config.geometry))
        distance_mm = float(np.linalg.norm(expected[:3] - reported[:3]))
        r_deg = abs(wrap_deg(expected[3] - reported[3]))
        cfg = self.config
        if distance_mm > cfg.max_pose_mismatch_mm or r_deg > cfg.max_pose_mismatch_deg:
            return (f"the joint feedback {self._fmt(joints)} deg puts the flange at {self._fmt(expected)} (mm, deg) "
                    f"but the reported pose is {self._fmt(reported)}: {distance_mm:.3f} mm and {r_deg:.3f} deg "
                    f"apart (max_pose_mismatch_mm = {cfg.max_pose_mismatch_mm:g}, max_pose_mismatch_deg = "
                    f"{cfg.max_pose_mismatch_deg:g})")
        return None

    def check_feedback_agreement(self, joints_deg: Sequence[float], pose: Sequence[float],
                                 source: str = "feedback") -> None:
        """Raise :class:`FeedbackMismatchError` when the reported joints and pose disagree."""
        reason = self.feedback_mismatch(joints_deg, pose)
        if reason is not None:
            raise FeedbackMismatchError(f"{source}: {reason}; not sending anything until they agree")

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
                    target_joints: np.ndarray, kind: MotionKind, duration_s: float | None) -> None:
        cfg = self.config
        servo = kind is MotionKind.SERVO
        if servo:
            max_mm, max_deg, names = cfg.max_step_mm, cfg.max_step_deg, ("max_step_mm", "max_step_deg")
            t_s = DEFAULT_SERVO_TIME_S if duration_s is None else float(duration_s)
            if not (math.isfinite(t_s) and t_s > 0.0):
                raise SafetyError(f"servo time t = {duration_s!r} s must be finite and > 0")
        else:
            max_mm, max_deg, names = cfg.max_move_mm, cfg.max_move_deg, ("max_move_mm", "max_move_deg")
        step_mm = float(np.linalg.norm(target[:3] - current[:3]))
        if step_mm > max_mm:
            raise SafetyError(f"step of {step_mm:.3f} mm from {self._fmt(current[:3])} to {self._fmt(target[:3])} "
                              f"exceeds {names[0]} = {max_mm:g} mm")
        step_r_deg = abs(wrap_deg(target[3] - current[3]))
        if step_r_deg > max_deg:
            raise SafetyError(f"R step of {step_r_deg:.3f} deg exceeds {names[1]} = {max_deg:g} deg")
        joint_steps: list[tuple[str, float]] = []
        if current_joints is not None:
            for index, name in enumerate(JOINT_NAMES):
                delta = target_joints[index] - current_joints[index]
                if index == 3:
                    delta = wrap_deg(delta)
                joint_steps.append((name, abs(float(delta))))
                if abs(delta) > max_deg:
                    raise SafetyError(f"{name} step of {abs(delta):.3f} deg exceeds {names[1]} = {max_deg:g} deg")
        if not servo:
            return
        if step_mm / t_s > cfg.max_speed_mm_s:
            raise SafetyError(f"speed of {step_mm / t_s:.1f} mm/s ({step_mm:.3f} mm in t = {t_s:g} s) exceeds "
                              f"max_speed_mm_s = {cfg.max_speed_mm_s:g} mm/s")
        for name, step_deg in [("R", step_r_deg)] + joint_steps:
            if step_deg / t_s > cfg.max_speed_deg_s:
                raise SafetyError(f"{name} speed of {step_deg / t_s:.1f} deg/s ({step_deg:.3f} deg in t = {t_s:g} s) "
                                  f"exceeds max_speed_deg_s = {cfg.max_speed_deg_s:g} deg/s")

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


# ----------------------------------------------------------------------------------------------------------------
# A stream of commands


@dataclass(frozen=True)
class ArmSample:
    """Where the arm was, as measured: a feedback packet (or ``GetPose`` / ``GetAngle``).

    Attributes:
        pose: flange pose ``(x_mm, y_mm, z_mm, r_deg)``.
        joints: joints (J1..J4), deg.
        time_s: when the client received it, on the client's clock, s.
        target_pose, target_joints: the target in force when it was sampled (the packet's ``tool_vector_target`` and
            ``q_target``), None when unknown.
        moved_s: when a packet last showed the arm moving (or the first packet, if it never moved since), the
            client's clock, s; None when unknown (then the arm counts as having just stopped).
    """

    pose: tuple[float, ...]
    joints: tuple[float, ...]
    time_s: float
    target_pose: tuple[float, ...] | None = None
    target_joints: tuple[float, ...] | None = None
    moved_s: float | None = None


@dataclass(frozen=True)
class SentTarget:
    """A motion command the client sent: when (client clock, s), its target and, for a servo command, its ``t``."""

    time_s: float
    pose: np.ndarray
    joints: np.ndarray
    duration_s: float | None


def _rates(target_pose: np.ndarray, target_joints: np.ndarray, from_pose: np.ndarray, from_joints: np.ndarray,
           duration_s: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(xyz velocity mm/s, R rate deg/s, joint rates deg/s) of going from ``from_*`` to ``target_*`` in
    ``duration_s`` (R and J4 the short way round)."""
    joints = target_joints - from_joints
    joints[3] = wrap_deg(joints[3])
    return ((target_pose[:3] - from_pose[:3]) / duration_s, wrap_deg(target_pose[3] - from_pose[3]) / duration_s,
            joints / duration_s)


_ServoState = tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]

CLAMP_SPEED_SHARE = 0.8
"""The share of the speed limits a clamped servo target aims at (it passes the full limits)."""


class MotionStream:
    """One arm's recent motion commands and the checks that span commands (module docstring, "A stream of
    commands"). Each :class:`~simshear_gym.real.mg400_client.MG400Client` holds its own, so two arms (a leader and
    a follower) each get the same rules. Times are on the client's clock, s."""

    def __init__(self, layer: SafetyLayer) -> None:
        self.layer = layer
        self._sent: list[SentTarget] = []
        # What may be in force, newest first: a servo command as (time_s, the pose and joints the client expected the
        # arm to start from, target pose, target joints, t), or None (no servo command: at rest or a queued move).
        # More than one while the reply of a command was lost (it may or may not be in force).
        self._options: list[_ServoState | None] = [None]
        self._before_last: list[_ServoState | None] = [None]

    @property
    def _servo(self) -> _ServoState | None:
        return self._options[0]

    def forget(self) -> None:
        """Forget the commands sent (after a stop, a reset or a cleared error: the arm is at rest where it is)."""
        self._sent.clear()
        self._options = [None]
        self._before_last = [None]

    def outcome(self, answered: bool, accepted: bool) -> None:
        """How the last recorded command ended: accepted (in force), refused by the controller (never in force), or
        no answer (``answered`` False: it may or may not be in force, both are checked from now on)."""
        if answered and not accepted:
            self._options = list(self._before_last)
        elif not answered:
            self._options = self._options[:1] + [option for option in self._before_last
                                                 if option is not self._options[0]]

    def record(self, now_s: float, pose: np.ndarray, joints: np.ndarray, duration_s: float | None,
               sample: ArmSample | None) -> None:
        """Note a command about to be sent (before sending: once sent, it may be in force even without a reply)."""
        pose, joints = np.asarray(pose, dtype=float), np.asarray(joints, dtype=float)
        self._sent.append(SentTarget(now_s, pose, joints, duration_s))
        horizon_s = 10.0 * max(self.layer.config.stream_latency_s, self.layer.config.max_feedback_age_s)
        while self._sent and self._sent[0].time_s < now_s - horizon_s:
            self._sent.pop(0)
        self._before_last = list(self._options)
        if duration_s is None:
            self._options = [None]  # a queued move: the controller plans it (queued_ratios)
            return
        start_pose, start_joints = self._expected_position(now_s, sample)
        self._options = [(now_s, start_pose, start_joints, pose, joints, float(duration_s))]

    def _expected_position(self, now_s: float, sample: ArmSample | None, servo: _ServoState | None = None,
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Where the client expects the arm to be now: on the way of the servo command ``servo`` (default the
        newest), or the measurement."""
        servo = self._servo if servo is None else servo
        if servo is not None:
            sent_s, start_pose, start_joints, pose, joints, t_s = servo
            fraction = min(1.0, max(0.0, (now_s - sent_s) / t_s))
            if fraction < 1.0 or sample is None:
                joint_delta = joints - start_joints
                joint_delta[3] = wrap_deg(joint_delta[3])
                pose_delta = pose - start_pose
                pose_delta[3] = wrap_deg(pose_delta[3])
                return start_pose + fraction * pose_delta, start_joints + fraction * joint_delta
        if sample is None:
            raise SafetyError("no measurement of the arm to check a servo command against")
        return np.array(sample.pose, dtype=float), np.array(sample.joints, dtype=float)

    def hull(self, sample: ArmSample | None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every place the arm may be or be heading to: the measurement, the target in force when it was taken and
        every target sent since (``stream_latency_s`` earlier, for the delays)."""
        points: list[tuple[np.ndarray, np.ndarray]] = []
        cutoff_s = -math.inf
        if sample is not None:
            points.append((np.array(sample.pose, dtype=float), np.array(sample.joints, dtype=float)))
            if sample.target_pose is not None and sample.target_joints is not None:
                points.append((np.array(sample.target_pose, dtype=float), np.array(sample.target_joints, dtype=float)))
            cutoff_s = sample.time_s - self.layer.config.stream_latency_s
        points += [(sent.pose, sent.joints) for sent in self._sent if sent.time_s >= cutoff_s]
        return points

    def check_servo(self, now_s: float, pose: np.ndarray, joints: np.ndarray, duration_s: float,
                    sample: ArmSample | None, speed_share: float = 1.0) -> None:
        """Refuse (:class:`SafetyError`) a servo command that asks the arm for more than the speed or acceleration
        limits, from anywhere it may be; ``sample`` is the newest measurement (None: only the commands sent);
        ``speed_share``: the share of the speed limits to hold it to (the clamp aims below them)."""
        cfg = self.layer.config
        max_mm_s, max_deg_s = cfg.max_speed_mm_s * speed_share, cfg.max_speed_deg_s * speed_share
        fmt = self.layer._fmt
        pose, joints = np.asarray(pose, dtype=float), np.asarray(joints, dtype=float)
        points = self.hull(sample)
        if not points:
            raise SafetyError("no measurement of the arm to check a servo command against")
        for where_pose, where_joints in points:
            velocity, r_rate, joint_rates = _rates(pose, joints, where_pose, where_joints, duration_s)
            speed = float(np.linalg.norm(velocity))
            if speed > max_mm_s * (1.0 + 1e-9):
                raise SafetyError(f"stream speed: reaching {fmt(pose[:3])} from {fmt(where_pose[:3])}, where the arm "
                                  f"may be, in t = {duration_s:g} s needs {speed:.1f} mm/s > {max_mm_s:g} mm/s "
                                  f"(max_speed_mm_s = {cfg.max_speed_mm_s:g})")
            for name, rate in [("R", r_rate)] + list(zip(JOINT_NAMES, joint_rates)):
                if abs(rate) > max_deg_s * (1.0 + 1e-9):
                    raise SafetyError(f"stream speed: {name} at {abs(rate):.1f} deg/s to reach the target from where "
                                      f"the arm may be in t = {duration_s:g} s > {max_deg_s:g} deg/s "
                                      f"(max_speed_deg_s = {cfg.max_speed_deg_s:g})")
        self._check_acceleration(now_s, pose, joints, duration_s, sample)

    def _check_acceleration(self, now_s: float, pose: np.ndarray, joints: np.ndarray, duration_s: float,
                            sample: ArmSample | None) -> None:
        for option in self._options:  # against everything that may be in force
            self._check_acceleration_from(option, now_s, pose, joints, duration_s, sample)

    def _check_acceleration_from(self, servo: _ServoState | None, now_s: float, pose: np.ndarray, joints: np.ndarray,
                                 duration_s: float, sample: ArmSample | None) -> None:
        """Check the change of velocity against one state that may be in force: ``servo`` still on its way, or the
        arm at rest (``servo`` None or arrived); near its arrival, both."""
        cfg = self.layer.config
        # The controller applies a change on its cycle, and a command's delay may differ from the previous one's by
        # up to stream_latency_s: the time since the last change is counted short by both.
        cycle_s, slack_s = cfg.controller_cycle_s, cfg.controller_cycle_s + cfg.stream_latency_s
        rest_since_s: float | None = None
        may_rest = servo is None
        if servo is not None:
            sent_s, old_start_pose, old_start_joints, old_pose, old_joints, old_t_s = servo
            arrival_s = sent_s + old_t_s
            if now_s < arrival_s + slack_s:  # may still be on its way: the change from its velocity
                start_pose, start_joints = self._expected_position(now_s, sample, servo)
                velocity, r_rate, joint_rates = _rates(pose, joints, start_pose, start_joints, duration_s)
                before = _rates(old_pose, old_joints, old_start_pose, old_start_joints, old_t_s)
                # how far along the arm is, is known to within a cycle of its progress: the velocity asked for, to
                # within that distance over t
                spread = cycle_s / duration_s
                self._check_change((velocity, r_rate, joint_rates), before, max(now_s - sent_s - slack_s, cycle_s),
                                   (float(np.linalg.norm(before[0])) * spread, abs(before[1]) * spread,
                                    np.abs(before[2]) * spread))
            if now_s > arrival_s - slack_s:  # may have arrived (and stopped), as late as its delay and a cycle
                may_rest, rest_since_s = True, arrival_s + slack_s
        if not may_rest:
            return
        # From rest: the velocity asked for from anywhere the arm may be; since when at rest (the packet after the
        # last one that showed it moving; unknown, or still moving in the newest packet: just now)?
        if sample is not None and sample.moved_s is not None:
            moved_s = now_s if sample.moved_s >= sample.time_s else sample.moved_s + cycle_s
            rest_since_s = max(rest_since_s if rest_since_s is not None else -math.inf, moved_s)
        interval_s = (cycle_s if rest_since_s is None
                      else min(duration_s, max(now_s - rest_since_s - cycle_s, cycle_s)))
        fastest = (np.zeros(3), 0.0, np.zeros(4))
        for where_pose, where_joints in self.hull(sample):
            velocity, r_rate, joint_rates = _rates(pose, joints, where_pose, where_joints, duration_s)
            fastest = (velocity if np.linalg.norm(velocity) > np.linalg.norm(fastest[0]) else fastest[0],
                       r_rate if abs(r_rate) > abs(fastest[1]) else fastest[1],
                       np.where(np.abs(joint_rates) > np.abs(fastest[2]), joint_rates, fastest[2]))
        self._check_change(fastest, (np.zeros(3), 0.0, np.zeros(4)), interval_s)

    def _check_change(self, new: tuple[np.ndarray, float, np.ndarray], old: tuple[np.ndarray, float, np.ndarray],
                      interval_s: float, uncertainty: tuple[float, float, np.ndarray] = (0.0, 0.0, np.zeros(4)),
                      ) -> None:
        """Refuse a change of velocity (xyz mm/s, R deg/s, joints deg/s) faster than ``max_accel_*`` over
        ``interval_s``; ``uncertainty``: how far off the new velocity may be (the same units), added."""
        cfg = self.layer.config
        delta_mm_s = float(np.linalg.norm(new[0] - old[0])) + uncertainty[0]
        if delta_mm_s / interval_s > cfg.max_accel_mm_s2 * (1.0 + 1e-9):
            raise SafetyError(f"stream acceleration: the velocity asked for changes by {delta_mm_s:.1f} mm/s within "
                              f"{interval_s:.3f} s ({delta_mm_s / interval_s:.0f} mm/s^2 > max_accel_mm_s2 = "
                              f"{cfg.max_accel_mm_s2:g})")
        for name, new_rate, old_rate, spread in ([("R", new[1], old[1], uncertainty[1])]
                                                 + list(zip(JOINT_NAMES, new[2], old[2], uncertainty[2]))):
            delta = abs(float(new_rate - old_rate)) + float(spread)
            if delta / interval_s > cfg.max_accel_deg_s2 * (1.0 + 1e-9):
                raise SafetyError(f"stream acceleration: {name} rate changes by {delta:.1f} deg/s within "
                                  f"{interval_s:.3f} s ({delta / interval_s:.0f} deg/s^2 > max_accel_deg_s2 = "
                                  f"{cfg.max_accel_deg_s2:g})")

    def clamp_servo_pose(self, now_s: float, target_pose: np.ndarray, duration_s: float, sample: ArmSample | None,
                         check: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """The point nearest ``target_pose`` on the way from where the arm is expected (or its newest target, or
        the measurement) that passes ``check`` (the per-command checks; returns the joints) and
        :meth:`check_servo`; raises :class:`SafetyError` when not even the start of the way passes."""

        def passes(pose: np.ndarray, speed_share: float = 1.0) -> bool:
            try:
                self.check_servo(now_s, pose, check(pose), duration_s, sample, speed_share)
            except SafetyError:
                return False
            return True

        target_pose = np.asarray(target_pose, dtype=float)
        expected, _ = self._expected_position(now_s, sample)
        anchors = []
        if self._servo is not None:  # carrying on at the velocity in force (no change), or part of it
            sent_s, start_pose, _, pose, _, t_s = self._servo
            cfg = self.layer.config
            if now_s < sent_s + t_s + cfg.controller_cycle_s + cfg.stream_latency_s:  # may still be on its way
                velocity = pose - start_pose
                velocity[3] = wrap_deg(velocity[3])
                velocity /= t_s
                anchors += [expected + share * velocity * duration_s for share in (1.0, 0.75, 0.5, 0.25)]
        anchors.append(expected)
        if self._servo is not None:
            anchors.append(self._servo[3])
        # from rest, the arm may be anywhere among the places it may be: the middle of them asks the least
        points = [point for point, _ in self.hull(sample)]
        if points:
            anchors.append(0.5 * (np.min(points, axis=0) + np.max(points, axis=0)))
        if sample is not None:
            anchors.append(np.array(sample.pose, dtype=float))
        for anchor in anchors:
            anchor = anchor.copy()
            anchor[3] = target_pose[3] - wrap_deg(target_pose[3] - anchor[3])  # turn the short way
            if not passes(anchor):
                continue
            if passes(target_pose, CLAMP_SPEED_SHARE):
                return target_pose
            # Toward the target, aiming at CLAMP_SPEED_SHARE of the speed limits: the room left lets the next
            # command carry on even when the feedback it is checked against is a little older.
            low, high = 0.0, 1.0
            for _ in range(30):
                middle = 0.5 * (low + high)
                if passes(anchor + middle * (target_pose - anchor), CLAMP_SPEED_SHARE):
                    low = middle
                else:
                    high = middle
            clamped = anchor + low * (target_pose - anchor)
            clamped[3] = wrap_deg(clamped[3])
            return clamped
        raise SafetyError("servo target cannot be clamped within the stream limits: not even holding where the arm "
                          "is expected passes (the arm is moving faster than a stop within max_accel allows)")


def _profile_s(distance: float, speed: float, accel: float) -> float:
    """How long a trapezoidal profile takes over ``distance`` at ``speed`` and ``accel``, s."""
    if distance * accel >= speed * speed:
        return distance / speed + speed / accel
    return 2.0 * math.sqrt(distance / accel)


def _refuse_j4_wrap(points: list[tuple[np.ndarray, np.ndarray]], start_pose: np.ndarray, target_pose: np.ndarray,
                    cfg: SafetyConfig) -> None:
    """Refuse a straight move whose R crosses J4's end stop (R = J1 + J4): J4 cannot turn through its limit, so
    the arm would have to turn it the long way round mid-move."""
    j4 = [float(joints[3]) for _, joints in points]
    for a, b in zip(j4, j4[1:]):
        if abs(b - a) > 180.0:
            lower, upper = cfg.limits.j4_deg
            raise SafetyError(f"queued straight move from R = {start_pose[3]:.2f} to {target_pose[3]:.2f} deg takes "
                              f"J4 across its end stop ({lower:g}, {upper:g}) deg (J4 {j4[0]:.1f} -> {j4[-1]:.1f} "
                              "deg): it would have to turn the long way round; turn R the other way (a MovJ, or "
                              "a target R that keeps J4 inside its range)")


def queued_ratios(layer: SafetyLayer, start_pose: np.ndarray, start_joints: np.ndarray, target_pose: np.ndarray,
                  target_joints: np.ndarray, linear: bool, speed_factor_percent: int = 100) -> tuple[int, int]:
    """The ``(speed, acceleration)`` ratios (percent, 1..100) that keep a queued move within ``max_speed_*`` and
    ``max_accel_*`` at the controller's speeds at 100 % (``arm_*``) and the global ``SpeedFactor``.

    Args:
        linear: MovL / RelMovL (straight in Cartesian space; ratios for ``SpeedL`` / ``AccL``), else a joint move
            (``SpeedJ`` / ``AccJ``).

    Raises:
        SafetyError: even 1 % would be too fast.
    """
    cfg = layer.config
    geometry = cfg.geometry
    start_pose, target_pose = np.asarray(start_pose, float), np.asarray(target_pose, float)
    start_joints, target_joints = np.asarray(start_joints, float), np.asarray(target_joints, float)
    r_delta = abs(wrap_deg(target_pose[3] - start_pose[3]))
    joint_delta = target_joints - start_joints
    # Path derivatives per unit of path fraction, sampled: mm and deg per unit fraction.
    fractions = np.linspace(0.0, 1.0, 41)
    points = []
    path_target = target_pose.copy()  # a straight move turns R the short way (as the emulator's, and ServoP)
    path_target[3] = start_pose[3] + wrap_deg(target_pose[3] - start_pose[3])
    for fraction in fractions:
        if linear:
            pose = start_pose + fraction * (path_target - start_pose)
            try:
                joints = check_pose_reachable(pose, geometry, cfg.limits)
            except KinematicsError:
                joints = start_joints + fraction * joint_delta
            points.append((pose, np.asarray(joints, float)))
        else:
            joints = start_joints + fraction * joint_delta
            points.append((np.array(forward(joints, geometry)), joints))
    if linear:
        _refuse_j4_wrap(points, start_pose, target_pose, cfg)
    step = fractions[1]
    cart_per_fraction = max(float(np.linalg.norm(b[0][:3] - a[0][:3])) / step for a, b in zip(points, points[1:]))
    joint_per_fraction = max(float(np.max(np.abs(b[1] - a[1]))) / step for a, b in zip(points, points[1:]))
    rot_per_fraction = r_delta
    # Path fraction per second at 100 % (the controller's plan: the dominant axis at its speed).
    if linear:
        distance_mm = float(np.linalg.norm(target_pose[:3] - start_pose[:3]))
        duration_s = max(distance_mm / cfg.arm_linear_speed_mm_s, r_delta / cfg.arm_rotation_speed_deg_s)
        # the controller syncs both axes to the one whose profile lasts longer: its fraction acceleration
        axes = [(distance_mm, cfg.arm_linear_speed_mm_s, cfg.arm_linear_accel_mm_s2),
                (r_delta, cfg.arm_rotation_speed_deg_s, cfg.arm_joint_accel_deg_s2)]
        length, _, top_accel = max((axis for axis in axes if axis[0] > 0.0), key=lambda axis: _profile_s(*axis),
                                   default=(1.0, 1.0, 0.0))
        accel_fraction = top_accel / length
    else:
        spread_deg = float(np.max(np.abs(joint_delta)))
        duration_s = spread_deg / cfg.arm_joint_speed_deg_s
        accel_fraction = cfg.arm_joint_accel_deg_s2 / max(spread_deg, 1e-9)
    if duration_s <= 1e-9 or max(cart_per_fraction, joint_per_fraction, rot_per_fraction) < 1e-6:
        return 100, 100  # no move (to within the numbers' precision)
    rate = 1.0 / duration_s  # fraction per second at 100 %
    speed_scale = min(1.0, cfg.max_speed_mm_s / max(cart_per_fraction * rate, 1e-12),
                      cfg.max_speed_deg_s / max(joint_per_fraction * rate, 1e-12),
                      cfg.max_speed_deg_s / max(rot_per_fraction * rate, 1e-12))
    accel_scale = min(1.0, cfg.max_accel_mm_s2 / max(cart_per_fraction * accel_fraction, 1e-12),
                      cfg.max_accel_deg_s2 / max(joint_per_fraction * accel_fraction, 1e-12),
                      cfg.max_accel_deg_s2 / max(rot_per_fraction * accel_fraction, 1e-12))
    factor = max(1, min(100, int(speed_factor_percent))) / 100.0
    speed_ratio = math.floor(100.0 * speed_scale / factor + 1e-9)
    accel_ratio = math.floor(100.0 * accel_scale + 1e-9)
    if linear and speed_ratio >= 1:
        # Which axis the controller syncs to depends on the ratios themselves: take the largest acceleration ratio
        # whose synced profile keeps every axis within the limits.
        speed = factor * min(100, speed_ratio) / 100.0
        for candidate in range(min(100, accel_ratio if accel_ratio >= 1 else 100), 0, -1):
            share = candidate / 100.0
            axes = [(length, top_speed * speed, top_accel * share) for length, top_speed, top_accel in (
                (distance_mm, cfg.arm_linear_speed_mm_s, cfg.arm_linear_accel_mm_s2),
                (r_delta, cfg.arm_rotation_speed_deg_s, cfg.arm_joint_accel_deg_s2)) if length > 0.0]
            length, _, synced_accel = max(axes, key=lambda axis: _profile_s(*axis))
            fraction_accel = synced_accel / length
            if (cart_per_fraction * fraction_accel <= cfg.max_accel_mm_s2 * (1.0 + 1e-9)
                    and joint_per_fraction * fraction_accel <= cfg.max_accel_deg_s2 * (1.0 + 1e-9)
                    and rot_per_fraction * fraction_accel <= cfg.max_accel_deg_s2 * (1.0 + 1e-9)):
                accel_ratio = candidate
                break
        else:
            accel_ratio = 0
    if speed_ratio < 1 or accel_ratio < 1:
        raise SafetyError(f"queued move too fast even at 1 %: needs a speed ratio of "
                          f"{100 * speed_scale / factor:.2f} % "
                          f"and an acceleration ratio of {100 * accel_scale:.2f} % (max_speed_mm_s = "
                          f"{cfg.max_speed_mm_s:g}, arm_*_speed at 100 %)")
    return min(100, speed_ratio), min(100, accel_ratio)
