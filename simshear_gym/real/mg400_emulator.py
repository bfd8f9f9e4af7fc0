"""A loopback MG400 emulator: the dashboard, motion and feedback ports, with fault injection.

It listens on 127.0.0.1 only and speaks the protocol of :mod:`simshear_gym.robots.mg400.protocol`:

* Dashboard (29999): EnableRobot (``EnableRobot()``, ``EnableRobot(load)``, ``EnableRobot(load,x,y,z)``: payload
  in kg, 0..``max_payload_kg``, and its centre offset, -500..500 mm), DisableRobot, ClearError, Continue, Pause,
  ResetRobot, EmergencyStop, SpeedFactor (1..100), the queued-move settings SpeedJ, SpeedL, AccJ, AccL (1..100) and
  CP (0..100), SetPayLoad / PayLoad, User, Tool, RobotMode, GetPose, GetAngle, GetErrorID.
* Motion (30003): MovJ, MovL, JointMovJ and RelMovJ, RelMovL (offsets from the current target; queued, executed in
  order: the controller plans them, so they never trip a speed limit) with the optional keywords of Dobot's API
  (``User=``, ``Tool=``, ``SpeedJ=``/``SpeedL=``, ``AccJ=``/``AccL=``, ``CP=``): a move runs at
  ``joint_speed_deg_s`` / ``linear_speed_mm_s`` (and ``rotation_speed_deg_s`` for R) times SpeedFactor times its
  speed ratio (its keyword, else the SpeedJ / SpeedL setting), speeding up and slowing down at
  ``joint_accel_deg_s2`` / ``linear_accel_mm_s2`` times its acceleration ratio (a trapezoidal profile); Sync
  (answers when the queue is empty; -1 if the robot is then in error mode), ServoP / ServoJ (replace the servo
  target, reached linearly over ``t``; refused while queued moves run; a move queued during a servo motion starts
  when that motion ends).
* Feedback (30004): a 1440-byte packet every ``feedback_period_s``.

A target beyond the joint limits puts the robot in error mode with alarm 18 (joint limit), an unreachable one with
alarm 23 (out of working area); the command is answered with ErrorID -1. Motion commands are answered -1 while the
robot is disabled or in error mode. ClearError clears the alarms; EmergencyStop stops and disables. When the
connections are dropped (fault injection), the emulated robot stops where it is.

**Speed limits.** A servo command is not planned by the controller: it asks the arm to reach its target from where
it is in ``t``. One that would need more than the arm can do (any joint faster than ``max_joint_speed_deg_s``, or
the flange faster than ``max_linear_speed_mm_s``) raises an overspeed alarm (48 + the index of the joint that is
fastest against its limit, J1 = 48 .. J4 = 51, the controller's overspeed alarms), is answered -1 and stops the
arm where it is; it does not move at the limit speed instead, because a controller that quietly stretched the
motion would lag every later target of the stream. (Our model of the MG400's servo mode; the limits' defaults,
300 deg/s per joint and 1000 mm/s at the flange, are of the order of the arm's datasheet, not measured.)

The emulator starts at :data:`READY_POSE_MM_DEG`, the tactile start pose of
:class:`~simshear_gym.real.env.RealEnvConfig` (``initial_joints_deg`` to start elsewhere, e.g. all joints zero:
the flange at (284, 0, 118)).

Faults (:class:`FaultConfig`, also swapped at run time with :meth:`MG400Emulator.set_faults`): an alarm during
motion, dropped connections after N commands, replies split across TCP segments, corrupt, partial or inconsistent
(joints that disagree with the pose) feedback packets, slow replies; and at run time :meth:`~MG400Emulator.
inject_alarm`, :meth:`~MG400Emulator.pause_feedback` (stale feedback) and :meth:`~MG400Emulator.drop_connections`.
Every motion command is recorded with the state it found (:meth:`MG400Emulator.motion_records`), and every motion
the arm executed with its peak speeds and accelerations (:meth:`MG400Emulator.executed_motions`), for audits.

Command line (hooked up by the ``simshear`` CLI): ``simshear mg400-emulator --host 127.0.0.1 --dashboard-port ...``
via :func:`add_arguments` and :func:`run`.
"""

from __future__ import annotations

import argparse
import enum
import ipaddress
import logging
import math
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from simshear_gym.data.labels import wrap_deg
from simshear_gym.real.mg400_client import shut_socket
from simshear_gym.robots.mg400.kinematics import (
    JOINT_NAMES,
    KinematicsError,
    LimitError,
    MG400Geometry,
    MG400Limits,
    UnreachableError,
    check_joint_limits,
    check_pose_reachable,
    forward,
    inverse,
)
from simshear_gym.robots.mg400.protocol import (
    ALARM_JOINT_LIMIT,
    ALARM_OUT_OF_WORKSPACE,
    ALARM_OVERSPEED,
    DASHBOARD_PORT,
    ERROR_FAILED,
    ERROR_OK,
    ERROR_PARAMETER_COUNT,
    ERROR_UNKNOWN_COMMAND,
    FEEDBACK_PACKET_BYTES,
    FEEDBACK_PERIOD_S,
    FEEDBACK_PORT,
    MOTION_PORT,
    SERVO_TIME_RANGE_S,
    CommandBuffer,
    MG400Feedback,
    ParsedCommand,
    ProtocolError,
    RobotMode,
    format_reply,
    pack_feedback,
    parameter_range_error,
    parameter_type_error,
    parse_command,
)

logger = logging.getLogger(__name__)

_POLL_S = 0.05  # how often blocked threads look at the stop flag

READY_POSE_MM_DEG: tuple[float, float, float, float] = (300.0, 0.0, 0.0, 0.0)
"""Where the emulated flange starts: the default tactile start pose of the real env, mm and deg."""

READY_JOINTS_DEG: tuple[float, float, float, float] = tuple(  # type: ignore[assignment]
    float(v) for v in inverse(*READY_POSE_MM_DEG))
"""The joints of :data:`READY_POSE_MM_DEG`, deg."""

INCONSISTENT_FEEDBACK_OFFSET_DEG = 5.0
"""How far J1 of an inconsistent feedback packet is turned from the joints the pose was computed from, deg."""


class FeedbackFault(enum.Enum):
    """Kinds of bad feedback packet the emulator can send."""

    BAD_LENGTH = "bad-length"  # length field 1439
    BAD_TEST_VALUE = "bad-test-value"  # test value 0
    PARTIAL = "partial"  # only the first half of the packet
    INCONSISTENT = "inconsistent"  # a well-formed packet whose joints disagree with its pose (J1 turned 5 deg)


@dataclass(frozen=True)
class FaultConfig:
    """Faults to inject (all off by default).

    Attributes:
        alarm_during_motion: alarm id raised once, ``alarm_after_s`` into the first motion that lasts that long.
        alarm_after_s: when the alarm fires, s after the motion started.
        drop_after_commands: close every connection (without replying) when this many commands have been
            received in total; once.
        split_replies_bytes: send each reply in chunks of this many bytes, ``split_delay_s`` apart.
        split_delay_s: pause between reply chunks, s.
        corrupt_feedback_every: every N-th feedback packet is bad, cycling through ``feedback_faults``.
        feedback_faults: which bad packets to send (by default the malformed ones: not ``INCONSISTENT``).
        reply_delay_s: delay before each reply, s.
        slow_commands: command names (case-insensitive) that get ``reply_delay_s``; empty: all commands.
    """

    alarm_during_motion: int | None = None
    alarm_after_s: float = 0.05
    drop_after_commands: int | None = None
    split_replies_bytes: int | None = None
    split_delay_s: float = 0.002
    corrupt_feedback_every: int | None = None
    feedback_faults: tuple[FeedbackFault, ...] = (FeedbackFault.BAD_LENGTH, FeedbackFault.BAD_TEST_VALUE,
                                                  FeedbackFault.PARTIAL)
    reply_delay_s: float = 0.0
    slow_commands: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("drop_after_commands", "split_replies_bytes", "corrupt_feedback_every", "alarm_during_motion"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ValueError(f"FaultConfig.{name} must be None or an int >= 1, got {value!r}")
        for name in ("alarm_after_s", "split_delay_s", "reply_delay_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"FaultConfig.{name} must be finite and >= 0 s, got {value!r}")
        if not self.feedback_faults or not all(isinstance(f, FeedbackFault) for f in self.feedback_faults):
            raise ValueError(f"FaultConfig.feedback_faults must be a non-empty tuple of FeedbackFault, "
                             f"choices {[f.value for f in FeedbackFault]}, got {self.feedback_faults!r}")
        object.__setattr__(self, "slow_commands", tuple(str(name).lower() for name in self.slow_commands))


@dataclass(frozen=True)
class EmulatorConfig:
    """Emulator settings.

    Attributes:
        host: loopback IPv4 address to listen on (``127.0.0.1`` or ``localhost``; others are refused).
        dashboard_port, motion_port, feedback_port: ports; 0 picks a free ephemeral port.
        feedback_period_s: time between feedback packets (and simulation steps), s.
        joint_speed_deg_s: joint speed of MovJ/JointMovJ at SpeedFactor 100, deg/s.
        linear_speed_mm_s: Cartesian speed of MovL at SpeedFactor 100, mm/s.
        rotation_speed_deg_s: R speed of MovL at SpeedFactor 100, deg/s.
        joint_accel_deg_s2: joint (and MovL's R) acceleration of queued moves at AccJ / AccL 100, deg/s^2.
        linear_accel_mm_s2: Cartesian acceleration of MovL at AccL 100, mm/s^2.
        max_payload_kg: the largest load EnableRobot accepts, kg.
        max_joint_speed_deg_s: the arm's joint speed limit: a servo command needing more raises overspeed, deg/s.
        max_linear_speed_mm_s: the flange's speed limit: a servo command needing more raises overspeed, mm/s.
        initial_joints_deg: start joints (J1..J4), deg (default: those of :data:`READY_POSE_MM_DEG`).
        pose_value_count: numbers returned by GetPose/GetAngle (4 per the guide, 6 as field firmware does).
        max_queue: queued moves accepted before answering -1.
        faults: fault injection.
        geometry, limits: the arm model.
    """

    host: str = "127.0.0.1"
    dashboard_port: int = DASHBOARD_PORT
    motion_port: int = MOTION_PORT
    feedback_port: int = FEEDBACK_PORT
    feedback_period_s: float = FEEDBACK_PERIOD_S
    joint_speed_deg_s: float = 180.0
    linear_speed_mm_s: float = 500.0
    rotation_speed_deg_s: float = 360.0
    joint_accel_deg_s2: float = 4000.0
    linear_accel_mm_s2: float = 10000.0
    max_payload_kg: float = 0.75
    max_joint_speed_deg_s: float = 300.0
    max_linear_speed_mm_s: float = 1000.0
    initial_joints_deg: tuple[float, float, float, float] = READY_JOINTS_DEG
    pose_value_count: int = 6
    max_queue: int = 50
    faults: FaultConfig = field(default_factory=FaultConfig)
    geometry: MG400Geometry = field(default_factory=MG400Geometry)
    limits: MG400Limits = field(default_factory=MG400Limits)

    def __post_init__(self) -> None:
        host = "127.0.0.1" if self.host == "localhost" else self.host
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            address = None
        if address is None or address.version != 4 or not address.is_loopback:
            raise ValueError(f"EmulatorConfig.host must be a loopback IPv4 address such as 127.0.0.1, "
                             f"got {self.host!r}")
        object.__setattr__(self, "host", host)
        for name in ("dashboard_port", "motion_port", "feedback_port"):
            port = getattr(self, name)
            if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
                raise ValueError(f"EmulatorConfig.{name} must be an int in 0..65535 (0: ephemeral), got {port!r}")
        for name in ("feedback_period_s", "joint_speed_deg_s", "linear_speed_mm_s", "rotation_speed_deg_s",
                     "joint_accel_deg_s2", "linear_accel_mm_s2", "max_payload_kg", "max_joint_speed_deg_s",
                     "max_linear_speed_mm_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"EmulatorConfig.{name} must be finite and > 0, got {value!r}")
        if not 4 <= self.pose_value_count <= 6:
            raise ValueError(f"EmulatorConfig.pose_value_count must be 4..6, got {self.pose_value_count!r}")
        if self.max_queue < 1:
            raise ValueError(f"EmulatorConfig.max_queue must be >= 1, got {self.max_queue!r}")
        if len(self.initial_joints_deg) != 4:
            raise ValueError(f"EmulatorConfig.initial_joints_deg must have 4 values, got {self.initial_joints_deg!r}")
        try:
            check_joint_limits(self.initial_joints_deg, self.limits)
        except LimitError as error:
            raise ValueError(f"EmulatorConfig.initial_joints_deg is outside the limits: {error}") from error


@dataclass(frozen=True)
class MotionRecord:
    """One motion command as the emulator received it, with the state it found (for audits).

    Attributes:
        time_s: emulator time at receipt, s.
        command: the command text.
        servo: ServoP / ServoJ (True) or a queued move (False); Sync is not recorded.
        target_pose, target_joints: the target, ``(x, y, z mm, R deg)`` and deg (None where it has no solution).
        duration_s: a servo command's ``t``, s (None for queued moves).
        in_force_pose, in_force_joints: where the arm was heading when it arrived: the running servo target, the
            last queued target, or the actual pose when idle.
        actual_pose: the flange's actual pose at receipt.
        error_id: the ErrorID of the reply.
    """

    time_s: float
    command: str
    servo: bool
    target_pose: tuple[float, ...] | None
    target_joints: tuple[float, ...] | None
    duration_s: float | None
    in_force_pose: tuple[float, ...]
    in_force_joints: tuple[float, ...]
    actual_pose: tuple[float, ...]
    error_id: int


@dataclass(frozen=True)
class ExecutedMotion:
    """One motion the emulated arm executed (a servo command accepted, a queued move started), with what it asked
    of the arm, for audits.

    Attributes:
        time_s: emulator time when it started, s.
        command: the command text.
        servo: ServoP / ServoJ (True) or a queued move (False).
        start_pose, end_pose: flange poses ``(x, y, z mm, R deg)`` (R unwrapped next to the start).
        start_joints, end_joints: deg.
        duration_s: how long it takes, s.
        peak_speed_mm_s: the flange's largest speed on the way, mm/s.
        peak_rotation_deg_s: R's largest rate, deg/s.
        peak_joint_deg_s: the fastest joint's largest rate, deg/s.
        accel_mm_s2: the flange's largest acceleration, mm/s^2 (a servo command: the change of the flange velocity
            from the motion it replaced, over the time since the velocity last changed, at least one tick).
        accel_deg_s2: the same for R and the joints, deg/s^2.
    """

    time_s: float
    command: str
    servo: bool
    start_pose: tuple[float, ...]
    end_pose: tuple[float, ...]
    start_joints: tuple[float, ...]
    end_joints: tuple[float, ...]
    duration_s: float
    peak_speed_mm_s: float
    peak_rotation_deg_s: float
    peak_joint_deg_s: float
    accel_mm_s2: float
    accel_deg_s2: float


@dataclass(frozen=True)
class _Queued:
    """A move waiting in the queue: a Cartesian pose (MovJ/MovL) or joints (JointMovJ), with its speed and
    acceleration ratios (percent; None: the global setting)."""

    command: str
    target: tuple[float, ...]
    joint_target: bool
    linear: bool
    speed_ratio: float | None = None
    accel_ratio: float | None = None


@dataclass
class _Motion:
    """A move in progress: joint-space or Cartesian-linear interpolation along a path fraction that grows at
    ``cruise_rate`` (1/s) after speeding up at ``accel_rate`` (1/s^2; inf: at once), a trapezoidal profile."""

    start_joints: np.ndarray
    end_joints: np.ndarray
    start_pose: np.ndarray
    end_pose: np.ndarray
    linear: bool
    cruise_rate: float
    servo: bool
    accel_rate: float = math.inf
    elapsed_s: float = 0.0

    @property
    def ramp_s(self) -> float:
        """Time spent speeding up (and slowing down), s."""
        if math.isinf(self.accel_rate):
            return 0.0
        return min(self.cruise_rate / self.accel_rate, math.sqrt(1.0 / self.accel_rate))

    @property
    def peak_rate(self) -> float:
        """The largest path-fraction rate, 1/s."""
        return self.cruise_rate if math.isinf(self.accel_rate) else self.accel_rate * self.ramp_s

    @property
    def duration_s(self) -> float:
        ramp_s = self.ramp_s
        covered = self.accel_rate * ramp_s * ramp_s if ramp_s > 0.0 else 0.0  # both ramps
        return 2.0 * ramp_s + max(0.0, 1.0 - covered) / self.peak_rate

    def fraction(self, elapsed_s: float) -> float:
        total_s, ramp_s, peak = self.duration_s, self.ramp_s, self.peak_rate
        if elapsed_s >= total_s:
            return 1.0
        if elapsed_s <= ramp_s:
            return 0.5 * self.accel_rate * elapsed_s * elapsed_s
        if elapsed_s >= total_s - ramp_s:
            left_s = total_s - elapsed_s
            return 1.0 - 0.5 * self.accel_rate * left_s * left_s
        return 0.5 * peak * ramp_s + peak * (elapsed_s - ramp_s)

    def rate(self, elapsed_s: float) -> float:
        """The path-fraction rate at ``elapsed_s``, 1/s."""
        total_s, ramp_s = self.duration_s, self.ramp_s
        if elapsed_s >= total_s or elapsed_s < 0.0:
            return 0.0
        if elapsed_s < ramp_s:
            return self.accel_rate * elapsed_s
        if elapsed_s > total_s - ramp_s:
            return self.accel_rate * (total_s - elapsed_s)
        return self.peak_rate

    def joints_at(self, fraction: float, geometry: MG400Geometry, limits: MG400Limits) -> np.ndarray:
        if self.linear:
            pose = self.start_pose + fraction * (self.end_pose - self.start_pose)
            return check_pose_reachable(pose, geometry, limits)
        joints = self.start_joints + fraction * (self.end_joints - self.start_joints)
        check_joint_limits(joints, limits)
        return joints


Handler = Callable[[ParsedCommand], "tuple[int, Sequence[object]] | None"]


class MG400Emulator:
    """The emulated controller: servers, motion, feedback and faults, in threads (a context manager)."""

    def __init__(self, config: EmulatorConfig | None = None) -> None:
        self.config = config if config is not None else EmulatorConfig()
        cfg = self.config
        self._cond = threading.Condition()
        self._joints = np.array(cfg.initial_joints_deg, dtype=float)
        self._enabled = False
        self._alarms: list[int] = []
        self._speed_factor = 100
        self._ratios = {"speedj": 100.0, "speedl": 100.0, "accj": 100.0, "accl": 100.0, "cp": 0.0}
        self._payload: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._executed: list[ExecutedMotion] = []
        self._velocity_changed_s = 0.0  # emulator time of the last change of the arm's velocity
        self._queue: deque[_Queued] = deque()
        self._active: _Motion | None = None
        self._alarm_fired = False
        self._time_s = 0.0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._servers: dict[str, socket.socket] = {}
        self._clients_lock = threading.Lock()
        self._clients: set[socket.socket] = set()
        self._feedback_clients: list[socket.socket] = []
        self._log: list[tuple[str, str]] = []
        self._command_count = 0
        self._dropped = False
        self._drop_generation = 0
        self._packets_sent = 0
        self._feedback_paused_until = 0.0
        self._records: list[MotionRecord] = []
        self._handlers: dict[tuple[str, str], Handler] = {
            ("dashboard", "enablerobot"): self._enable,
            ("dashboard", "disablerobot"): self._disable,
            ("dashboard", "clearerror"): self._clear_error,
            ("dashboard", "continue"): lambda cmd: self._no_args(cmd, lambda: None),
            ("dashboard", "pause"): lambda cmd: self._no_args(cmd, lambda: None),
            ("dashboard", "speedj"): lambda cmd: self._set_ratio(cmd, "speedj", 1),
            ("dashboard", "speedl"): lambda cmd: self._set_ratio(cmd, "speedl", 1),
            ("dashboard", "accj"): lambda cmd: self._set_ratio(cmd, "accj", 1),
            ("dashboard", "accl"): lambda cmd: self._set_ratio(cmd, "accl", 1),
            ("dashboard", "cp"): lambda cmd: self._set_ratio(cmd, "cp", 0),
            ("dashboard", "setpayload"): self._set_payload,
            ("dashboard", "payload"): self._set_payload,
            ("dashboard", "resetrobot"): lambda cmd: self._no_args(cmd, self._halt),
            ("dashboard", "emergencystop"): self._disable,  # the emulated arm stops and is disabled either way
            ("dashboard", "speedfactor"): self._set_speed_factor,
            ("dashboard", "user"): self._index_setting,
            ("dashboard", "tool"): self._index_setting,
            ("dashboard", "robotmode"): lambda cmd: self._no_args(cmd, lambda: [int(self.robot_mode)]),
            ("dashboard", "getpose"): lambda cmd: self._no_args(cmd, lambda: self._padded(self.pose)),
            ("dashboard", "getangle"): lambda cmd: self._no_args(cmd, lambda: self._padded(self.joints_deg)),
            ("dashboard", "geterrorid"): lambda cmd: self._no_args(cmd, lambda: ((tuple(self._alarms),) + ((),) * 6,)),
            ("motion", "movj"): lambda cmd: self._queue_move(cmd, joint_target=False, linear=False),
            ("motion", "movl"): lambda cmd: self._queue_move(cmd, joint_target=False, linear=True),
            ("motion", "jointmovj"): lambda cmd: self._queue_move(cmd, joint_target=True, linear=False),
            ("motion", "relmovj"): lambda cmd: self._queue_move(cmd, joint_target=False, linear=False, relative=True),
            ("motion", "relmovl"): lambda cmd: self._queue_move(cmd, joint_target=False, linear=True, relative=True),
            ("motion", "servop"): lambda cmd: self._servo(cmd, joint_target=False),
            ("motion", "servoj"): lambda cmd: self._servo(cmd, joint_target=True),
            ("motion", "sync"): self._sync,
        }

    # -- lifecycle -----------------------------------------------------------------------------------------------

    def start(self) -> MG400Emulator:
        """Bind the three ports and start the server, motion and feedback threads."""
        if self._servers:
            raise RuntimeError("MG400Emulator already started")
        cfg = self.config
        self._stop.clear()
        try:
            for name, port in (("dashboard", cfg.dashboard_port), ("motion", cfg.motion_port),
                               ("feedback", cfg.feedback_port)):
                server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._servers[name] = server
                server.bind((cfg.host, port))
                server.listen(4)
                server.settimeout(_POLL_S)
        except OSError:
            self.stop()
            raise
        for name, server in self._servers.items():
            self._spawn(f"mg400-emu-accept-{name}", self._accept_loop, name, server)
        self._spawn("mg400-emu-tick", self._tick_loop)
        logger.info("MG400 emulator on %s: dashboard %d, motion %d, feedback %d", cfg.host, self.dashboard_port,
                    self.motion_port, self.feedback_port)
        return self

    def stop(self) -> None:
        """Stop all threads and close every socket (idempotent)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for server in self._servers.values():
            server.close()
        self._close_clients()
        current = threading.current_thread()
        for _ in range(3):  # accept threads may still have spawned a handler while stopping
            with self._clients_lock:
                threads = [t for t in self._threads if t.is_alive() and t is not current]
            if not threads:
                break
            for thread in threads:
                thread.join(timeout=2.0)
        with self._clients_lock:
            self._threads.clear()
        self._servers.clear()

    def __enter__(self) -> MG400Emulator:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _spawn(self, name: str, target: Callable[..., None], *args: object) -> None:
        thread = threading.Thread(target=target, args=args, name=name, daemon=True)
        with self._clients_lock:
            self._threads.append(thread)
        thread.start()

    def _port(self, name: str) -> int:
        if name not in self._servers:
            raise RuntimeError("MG400Emulator is not started; call start() first")
        return int(self._servers[name].getsockname()[1])

    @property
    def dashboard_port(self) -> int:
        """The bound dashboard port."""
        return self._port("dashboard")

    @property
    def motion_port(self) -> int:
        """The bound motion port."""
        return self._port("motion")

    @property
    def feedback_port(self) -> int:
        """The bound feedback port."""
        return self._port("feedback")

    # -- state, for tests and tools ------------------------------------------------------------------------------

    @property
    def joints_deg(self) -> tuple[float, float, float, float]:
        """Actual joints (J1..J4), deg."""
        with self._cond:
            return tuple(float(v) for v in self._joints)  # type: ignore[return-value]

    @property
    def pose(self) -> tuple[float, float, float, float]:
        """Actual flange pose ``(x_mm, y_mm, z_mm, r_deg)``."""
        return forward(self.joints_deg, self.config.geometry)

    @property
    def robot_mode(self) -> RobotMode:
        """The current robot mode."""
        with self._cond:
            return self._mode()

    @property
    def alarms(self) -> tuple[int, ...]:
        """Active controller alarm ids."""
        with self._cond:
            return tuple(self._alarms)

    @property
    def queue_length(self) -> int:
        """Queued moves not yet finished (including the one running)."""
        with self._cond:
            return len(self._queue) + int(self._active is not None and not self._active.servo)

    @property
    def feedback_packets_sent(self) -> int:
        """Feedback ticks so far (one packet, good or bad, to each connected feedback client per tick)."""
        with self._cond:
            return self._packets_sent

    def received_commands(self, port: str | None = None) -> list[str]:
        """Command texts received so far, oldest first; ``port`` "dashboard" or "motion" filters."""
        with self._clients_lock:
            return [text for name, text in self._log if port is None or name == port]

    def drop_connections(self) -> None:
        """Close every client connection now; the emulated robot stops where it is (servers keep listening)."""
        logger.warning("MG400 emulator: dropping all connections")
        with self._cond:
            self._halt()
            self._drop_generation += 1
            self._cond.notify_all()
        self._close_clients()

    def set_faults(self, faults: FaultConfig) -> None:
        """Swap the fault injection now (the once-only faults, alarm and drop, are armed again)."""
        with self._cond:
            self.config = replace(self.config, faults=faults)
            self._alarm_fired = False
        with self._clients_lock:
            self._dropped = False
            self._command_count = 0

    def inject_alarm(self, alarm_id: int) -> None:
        """Raise ``alarm_id`` now, as a controller would mid-motion: error mode, the arm stops where it is."""
        with self._cond:
            self._raise_alarm(int(alarm_id), "injected alarm")

    def pause_feedback(self, duration_s: float) -> None:
        """Send no feedback packet for ``duration_s`` seconds (stale feedback); the arm keeps moving."""
        with self._cond:
            self._feedback_paused_until = time.monotonic() + float(duration_s)

    @property
    def feedback_paused(self) -> bool:
        """True while :meth:`pause_feedback` holds the feedback back."""
        with self._cond:
            return time.monotonic() < self._feedback_paused_until

    def motion_records(self) -> list[MotionRecord]:
        """Every motion command received so far (Sync excepted), with the state it found, oldest first."""
        with self._cond:
            return list(self._records)

    def executed_motions(self) -> list[ExecutedMotion]:
        """Every motion the arm executed so far (what it was asked to do and did), oldest first."""
        with self._cond:
            return list(self._executed)

    @property
    def payload(self) -> tuple[float, float, float, float]:
        """The payload set by EnableRobot / SetPayLoad: (kg, centre x, y, z mm)."""
        with self._cond:
            return self._payload

    @property
    def ratios(self) -> dict[str, float]:
        """The queued-move settings: SpeedJ, SpeedL, AccJ, AccL (percent) and CP (percent)."""
        with self._cond:
            return dict(self._ratios)

    def _close_clients(self) -> None:
        with self._clients_lock:
            clients = list(self._clients)
            self._clients.clear()
            self._feedback_clients.clear()
        for conn in clients:
            shut_socket(conn)

    # -- robot model (call with self._cond held) -----------------------------------------------------------------

    def _mode(self) -> RobotMode:
        if self._alarms:
            return RobotMode.ERROR
        if not self._enabled:
            return RobotMode.DISABLED
        if self._active is not None or self._queue:
            return RobotMode.RUNNING
        return RobotMode.ENABLED

    def _halt(self) -> None:
        self._queue.clear()
        self._active = None

    def _raise_alarm(self, alarm_id: int, reason: str) -> None:
        logger.info("MG400 emulator alarm %d: %s", alarm_id, reason)
        if alarm_id not in self._alarms:
            self._alarms.append(alarm_id)
        self._halt()
        self._cond.notify_all()

    def _ends(self, target: Sequence[float], joint_target: bool
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(start joints, start pose, end joints, end pose) of a move from where the arm is to ``target``, joints
        or a pose (whose R is unwrapped next to the start's); lock held."""
        geometry, start_joints = self.config.geometry, self._joints.copy()
        start_pose = np.array(forward(start_joints, geometry))
        if joint_target:
            end_joints = np.array(target)
            end_pose = np.array(forward(end_joints, geometry))
        else:
            end_pose = np.array(target)
            end_joints = check_pose_reachable(end_pose, geometry, self.config.limits)
            end_pose[3] = start_pose[3] + wrap_deg(end_pose[3] - start_pose[3])
        return start_joints, start_pose, end_joints, end_pose

    def _kinematics_alarm(self, error: UnreachableError | LimitError, reason: str) -> None:
        """The controller's alarm for a target or path point out of the workspace or beyond a joint limit."""
        self._raise_alarm(ALARM_OUT_OF_WORKSPACE if isinstance(error, UnreachableError) else ALARM_JOINT_LIMIT, reason)

    def _start_motion(self, item: _Queued) -> _Motion:
        cfg = self.config
        start_joints, start_pose, end_joints, end_pose = self._ends(item.target, item.joint_target)
        kind = "l" if item.linear else "j"
        speed = self._speed_factor / 100.0 * (item.speed_ratio or self._ratios["speed" + kind]) / 100.0
        accel = (item.accel_ratio or self._ratios["acc" + kind]) / 100.0
        # Each axis's (distance, speed, acceleration); the move follows the slowest, the others keep pace.
        if item.linear:
            axes = [(float(np.linalg.norm(end_pose[:3] - start_pose[:3])), cfg.linear_speed_mm_s,
                     cfg.linear_accel_mm_s2), (abs(float(end_pose[3] - start_pose[3])), cfg.rotation_speed_deg_s,
                                               cfg.joint_accel_deg_s2)]
        else:
            axes = [(float(np.max(np.abs(end_joints - start_joints))), cfg.joint_speed_deg_s, cfg.joint_accel_deg_s2)]
        best: _Motion | None = None
        for distance, top_speed, top_accel in axes:
            if distance <= 0.0:
                continue
            motion = _Motion(start_joints, end_joints, start_pose, end_pose, item.linear,
                             cruise_rate=top_speed * speed / distance, servo=False,
                             accel_rate=top_accel * accel / distance)
            if best is None or motion.duration_s > best.duration_s:
                best = motion
        if best is None:
            best = _Motion(start_joints, end_joints, start_pose, end_pose, item.linear, cruise_rate=math.inf,
                           servo=False)
        self._note_executed(item.command, best, accel_mm_s2=None, accel_deg_s2=None)
        return best

    def _path_rates(self, motion: _Motion) -> tuple[float, float, float]:
        """The largest (flange mm, R deg, joint deg) per unit of path fraction along ``motion``'s path."""
        distance_mm = float(np.linalg.norm(motion.end_pose[:3] - motion.start_pose[:3]))
        r_deg = abs(float(motion.end_pose[3] - motion.start_pose[3]))
        joint_delta = motion.end_joints - motion.start_joints
        if not motion.linear:
            # joint interpolation: the flange's speed varies along the arc; sample it
            fractions = np.linspace(0.0, 1.0, 41)
            poses = [np.array(forward(motion.start_joints + f * joint_delta, self.config.geometry)) for f in fractions]
            distance_mm = max(float(np.linalg.norm(b[:3] - a[:3])) / fractions[1] for a, b in zip(poses, poses[1:]))
            return distance_mm, r_deg, float(np.max(np.abs(joint_delta)))
        if motion.servo:
            joint_delta = joint_delta.copy()
            joint_delta[3] = wrap_deg(joint_delta[3])
            return distance_mm, r_deg, float(np.max(np.abs(joint_delta)))
        fractions = np.linspace(0.0, 1.0, 41)
        joints = []
        for f in fractions:
            try:
                joints.append(check_pose_reachable(motion.start_pose + f * (motion.end_pose - motion.start_pose),
                                                   self.config.geometry, self.config.limits))
            except KinematicsError:
                joints.append(motion.start_joints + f * joint_delta)
        joint_rate = max(float(np.max(np.abs(b - a))) / fractions[1] for a, b in zip(joints, joints[1:]))
        return distance_mm, r_deg, joint_rate

    def _note_executed(self, command: str, motion: _Motion, accel_mm_s2: float | None,
                       accel_deg_s2: float | None) -> None:
        """Append an :class:`ExecutedMotion` (lock held)."""
        mm, r_deg, joint_deg = self._path_rates(motion)
        peak = 0.0 if math.isinf(motion.cruise_rate) else motion.peak_rate
        if accel_mm_s2 is None:
            accel_rate = 0.0 if math.isinf(motion.accel_rate) else motion.accel_rate
            accel_mm_s2, accel_deg_s2 = mm * accel_rate, max(r_deg, joint_deg) * accel_rate
        self._executed.append(ExecutedMotion(
            self._time_s, command, motion.servo, tuple(float(v) for v in motion.start_pose),
            tuple(float(v) for v in motion.end_pose), tuple(float(v) for v in motion.start_joints),
            tuple(float(v) for v in motion.end_joints), float(motion.duration_s), mm * peak, r_deg * peak,
            joint_deg * peak, float(accel_mm_s2), float(accel_deg_s2 or 0.0)))
        self._velocity_changed_s = self._time_s

    def _step(self, dt_s: float) -> None:
        with self._cond:
            self._time_s += dt_s
            if self._alarms or not self._enabled:
                self._halt()
            elif self._active is None and self._queue:
                item = self._queue.popleft()
                try:
                    self._active = self._start_motion(item)
                except (UnreachableError, LimitError) as error:
                    self._kinematics_alarm(error, f"{item.command}: {error}")
            motion = self._active
            if motion is not None:
                motion.elapsed_s += dt_s
                fraction = motion.fraction(motion.elapsed_s)
                try:
                    self._joints = motion.joints_at(fraction, self.config.geometry, self.config.limits)
                except (UnreachableError, LimitError) as error:
                    self._kinematics_alarm(error, str(error))
                else:
                    if fraction >= 1.0:
                        self._joints = motion.end_joints.copy()
                        self._active = None
                        self._velocity_changed_s = self._time_s
                    faults = self.config.faults
                    if (faults.alarm_during_motion is not None and not self._alarm_fired
                            and motion.elapsed_s >= faults.alarm_after_s):
                        self._alarm_fired = True
                        self._raise_alarm(faults.alarm_during_motion, "injected alarm during motion")
            self._cond.notify_all()

    def _feedback(self) -> MG400Feedback:
        with self._cond:
            target = self._joints if self._active is None else self._active.end_joints
            return MG400Feedback(
                robot_mode=int(self._mode()),
                time_stamp_ms=int(self._time_s * 1000.0),
                q_target_deg=tuple(target),
                q_actual_deg=tuple(self._joints),
                tool_vector_actual=forward(self._joints, self.config.geometry),
                tool_vector_target=forward(target, self.config.geometry),
                speed_scaling=self._speed_factor / 100.0,
                enable_status=self._enabled,
                error_status=bool(self._alarms),
                run_queued_command=bool(self._queue) or (self._active is not None and not self._active.servo),
            )

    # -- command handlers (return (ErrorID, values) or None for no reply) ----------------------------------------

    @staticmethod
    def _numbers(cmd: ParsedCommand, count: int, keywords: tuple[str, ...] = ()
                 ) -> tuple[int, list[float], dict[str, float]]:
        """Parse ``count`` numeric parameters and optional keywords: (ErrorID, numbers, keywords)."""
        if len(cmd.args) != count or any(key.lower() not in keywords for key, _ in cmd.keywords):
            return ERROR_PARAMETER_COUNT, [], {}
        numbers: list[float] = []
        for index, text in enumerate(cmd.args):
            try:
                numbers.append(float(text))
            except ValueError:
                return parameter_type_error(index + 1), [], {}
            if not math.isfinite(numbers[-1]):
                return parameter_range_error(index + 1), [], {}
        named: dict[str, float] = {}
        for offset, (key, text) in enumerate(cmd.keywords):
            try:
                named[key.lower()] = float(text)
            except ValueError:
                return parameter_type_error(count + offset + 1), [], {}
        return ERROR_OK, numbers, named

    def _no_args(self, cmd: ParsedCommand, action: Callable[[], object]) -> tuple[int, Sequence[object]]:
        if cmd.args or cmd.keywords:
            return ERROR_PARAMETER_COUNT, ()
        with self._cond:
            values = action()
            self._cond.notify_all()
        return ERROR_OK, (values if values is not None else ())  # type: ignore[return-value]

    def _padded(self, four: Sequence[float]) -> list[float]:
        return [float(v) for v in four] + [0.0] * (self.config.pose_value_count - 4)

    def _enable(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        """``EnableRobot()``, ``EnableRobot(load)`` or ``EnableRobot(load,centerX,centerY,centerZ)``."""
        if cmd.keywords or len(cmd.args) not in (0, 1, 4):
            return ERROR_PARAMETER_COUNT, ()
        error_id, numbers, _ = self._numbers(cmd, len(cmd.args))
        if error_id != ERROR_OK:
            return error_id, ()
        if numbers and not 0.0 <= numbers[0] <= self.config.max_payload_kg:
            return parameter_range_error(1), ()
        for index, value in enumerate(numbers[1:], start=2):
            if not -500.0 <= value <= 500.0:
                return parameter_range_error(index), ()
        with self._cond:
            self._enabled = True
            if numbers:
                self._payload = (numbers[0], *(numbers[1:] or [0.0, 0.0, 0.0]))  # type: ignore[assignment]
            self._cond.notify_all()
        return ERROR_OK, ()

    def _integer(self, cmd: ParsedCommand, lowest: int, highest: int) -> tuple[int, int]:
        """One whole-number parameter in ``lowest..highest``: (ErrorID, the number)."""
        error_id, numbers, _ = self._numbers(cmd, 1)
        if error_id != ERROR_OK:
            return error_id, 0
        if numbers[0] != int(numbers[0]) or not lowest <= numbers[0] <= highest:
            return parameter_range_error(1), 0
        return ERROR_OK, int(numbers[0])

    def _set_ratio(self, cmd: ParsedCommand, name: str, lowest: int) -> tuple[int, Sequence[object]]:
        """SpeedJ / SpeedL / AccJ / AccL (1..100) and CP (0..100): the queued moves' settings, percent."""
        error_id, percent = self._integer(cmd, lowest, 100)
        if error_id == ERROR_OK:
            with self._cond:
                self._ratios[name] = float(percent)
        return error_id, ()

    def _set_payload(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        """``SetPayLoad(weight[,inertia])`` / ``PayLoad(weight,inertia)``: the load in kg."""
        if cmd.keywords or len(cmd.args) not in (1, 2):
            return ERROR_PARAMETER_COUNT, ()
        error_id, numbers, _ = self._numbers(cmd, len(cmd.args))
        if error_id != ERROR_OK:
            return error_id, ()
        if not 0.0 <= numbers[0] <= self.config.max_payload_kg:
            return parameter_range_error(1), ()
        with self._cond:
            self._payload = (numbers[0],) + self._payload[1:]
        return ERROR_OK, ()

    def _disable(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        def action() -> None:
            self._halt()
            self._enabled = False
        return self._no_args(cmd, action)

    def _clear_error(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        def action() -> None:
            self._alarms.clear()
            self._halt()
        return self._no_args(cmd, action)

    def _set_speed_factor(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        error_id, percent = self._integer(cmd, 1, 100)
        if error_id == ERROR_OK:
            with self._cond:
                self._speed_factor = percent
        return error_id, ()

    def _index_setting(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]]:
        return self._integer(cmd, 0, 9)[0], ()

    def _check_target(self, cmd: ParsedCommand, target: Sequence[float], joint_target: bool) -> bool:
        """Validate a target (lock held); on failure raise the alarm and return False."""
        try:
            if joint_target:
                check_joint_limits(target, self.config.limits)
            else:
                check_pose_reachable(target, self.config.geometry, self.config.limits)
        except (UnreachableError, LimitError) as error:
            self._kinematics_alarm(error, f"{cmd.text}: {error}")
            return False
        return True

    def _in_force(self) -> tuple[np.ndarray, np.ndarray]:
        """(pose, joints) the arm is heading to (lock held): the last queued target, the running motion's end, or
        where it is."""
        geometry = self.config.geometry
        if self._queue:
            item = self._queue[-1]
            try:
                joints = (np.array(item.target) if item.joint_target
                          else inverse(*item.target, geometry=geometry))
                return np.array(forward(joints, geometry)), joints
            except KinematicsError:
                pass
        if self._active is not None:
            return self._active.end_pose.copy(), self._active.end_joints.copy()
        return np.array(forward(self._joints, geometry)), self._joints.copy()

    def _record_motion(self, cmd: ParsedCommand, servo: bool, target: Sequence[float], joint_target: bool,
                duration_s: float | None, error_id: int, in_force: tuple[np.ndarray, np.ndarray]) -> None:
        """Append a :class:`MotionRecord` (lock held)."""
        geometry = self.config.geometry
        try:
            joints = np.array(target) if joint_target else inverse(*target, geometry=geometry)
            pose = np.array(forward(joints, geometry)) if joint_target else np.array(target, dtype=float)
            target_pose, target_joints = tuple(float(v) for v in pose), tuple(float(v) for v in joints)
        except KinematicsError:
            target_pose, target_joints = (None if joint_target else tuple(float(v) for v in target)), None
        self._records.append(MotionRecord(
            self._time_s, cmd.text, servo, target_pose, target_joints, duration_s,
            tuple(float(v) for v in in_force[0]), tuple(float(v) for v in in_force[1]),
            tuple(float(v) for v in forward(self._joints, geometry)), int(error_id)))

    def _queue_move(self, cmd: ParsedCommand, joint_target: bool, linear: bool,
                    relative: bool = False) -> tuple[int, Sequence[object]]:
        speed_key, accel_key = ("speedl", "accl") if linear else ("speedj", "accj")
        error_id, target, named = self._numbers(cmd, 4, keywords=("user", "tool", speed_key, accel_key, "cp"))
        if error_id != ERROR_OK:
            return error_id, ()
        for offset, (key, _) in enumerate(cmd.keywords):
            value, lowest, highest = named[key.lower()], (0 if key.lower() in ("cp", "user", "tool") else 1), (
                9 if key.lower() in ("user", "tool") else 100)
            if value != int(value) or not lowest <= value <= highest:
                return parameter_range_error(5 + offset), ()
        with self._cond:
            in_force = self._in_force()
            if relative:  # offsets from the current target, in mm and deg
                target = [float(v) for v in in_force[0] + np.array(target)]
            error_id = self._accept_move(cmd, target, joint_target, linear, named.get(speed_key),
                                         named.get(accel_key))
            self._record_motion(cmd, False, target, joint_target, None, error_id, in_force)
        return error_id, ()

    def _accept_move(self, cmd: ParsedCommand, target: Sequence[float], joint_target: bool, linear: bool,
                     speed_ratio: float | None = None, accel_ratio: float | None = None) -> int:
        if self._alarms or not self._enabled or len(self._queue) >= self.config.max_queue:
            return ERROR_FAILED
        if not self._check_target(cmd, target, joint_target):
            return ERROR_FAILED
        self._queue.append(_Queued(cmd.text, tuple(target), joint_target, linear, speed_ratio, accel_ratio))
        self._cond.notify_all()
        return ERROR_OK

    def _servo(self, cmd: ParsedCommand, joint_target: bool) -> tuple[int, Sequence[object]]:
        error_id, target, named = self._numbers(cmd, 4, keywords=("t",))
        if error_id != ERROR_OK:
            return error_id, ()
        duration_s = named.get("t", 0.1)
        if not SERVO_TIME_RANGE_S[0] <= duration_s <= SERVO_TIME_RANGE_S[1]:
            return parameter_range_error(5), ()
        with self._cond:
            in_force = self._in_force()
            error_id = self._accept_servo(cmd, target, joint_target, duration_s)
            self._record_motion(cmd, True, target, joint_target, duration_s, error_id, in_force)
        return error_id, ()

    def _accept_servo(self, cmd: ParsedCommand, target: Sequence[float], joint_target: bool,
                      duration_s: float) -> int:
        busy = bool(self._queue) or (self._active is not None and not self._active.servo)
        if self._alarms or not self._enabled or busy:
            return ERROR_FAILED
        if not self._check_target(cmd, target, joint_target):
            return ERROR_FAILED
        start_joints, start_pose, end_joints, end_pose = self._ends(target, joint_target)
        joint_delta = end_joints - start_joints
        if not joint_target:
            joint_delta[3] = wrap_deg(joint_delta[3])  # ServoP: R unwrapped next to the start, J4 the short way
        overspeed = self._overspeed(joint_delta, start_pose, end_pose, duration_s)
        if overspeed is not None:
            self._raise_alarm(*overspeed)
            return ERROR_FAILED
        before = self._active
        motion = _Motion(start_joints, end_joints, start_pose, end_pose, linear=not joint_target,
                         cruise_rate=1.0 / duration_s, servo=True)
        # The velocity change it asks for, from the motion it replaces, over the time since the velocity last
        # changed (the controller changes it once per tick at most).
        old_pose_rate, old_joint_rate = np.zeros(4), np.zeros(4)
        if before is not None and before.elapsed_s < before.duration_s:
            rate = before.rate(before.elapsed_s)
            old_pose_rate = (before.end_pose - before.start_pose) * rate
            old_joint_rate = (before.end_joints - before.start_joints) * rate
        new_pose_rate = (end_pose - start_pose) / duration_s
        new_joint_rate = joint_delta / duration_s
        interval_s = max(self._time_s - self._velocity_changed_s, self.config.feedback_period_s)
        accel_mm_s2 = float(np.linalg.norm(new_pose_rate[:3] - old_pose_rate[:3])) / interval_s
        accel_deg_s2 = float(max(abs(new_pose_rate[3] - old_pose_rate[3]),
                                 float(np.max(np.abs(new_joint_rate - old_joint_rate))))) / interval_s
        self._active = motion
        self._note_executed(cmd.text, motion, accel_mm_s2, accel_deg_s2)
        self._cond.notify_all()
        return ERROR_OK

    def _overspeed(self, joint_delta: np.ndarray, start_pose: np.ndarray, end_pose: np.ndarray,
                   duration_s: float) -> tuple[int, str] | None:
        """(alarm, reason) when reaching the target in ``duration_s`` needs more than the arm's speed limits."""
        cfg = self.config
        joint_speeds = np.abs(joint_delta) / duration_s
        linear_speed = float(np.linalg.norm(end_pose[:3] - start_pose[:3])) / duration_s
        ratios = joint_speeds / cfg.max_joint_speed_deg_s
        fastest = int(np.argmax(ratios))
        if ratios[fastest] <= 1.0 + 1e-9 and linear_speed <= cfg.max_linear_speed_mm_s * (1.0 + 1e-9):
            return None
        return (ALARM_OVERSPEED + fastest,
                f"servo target needs {JOINT_NAMES[fastest]} at {joint_speeds[fastest]:.1f} deg/s (limit "
                f"{cfg.max_joint_speed_deg_s:g}) and the flange at {linear_speed:.1f} mm/s (limit "
                f"{cfg.max_linear_speed_mm_s:g}) to arrive in t = {duration_s:g} s")

    def _sync(self, cmd: ParsedCommand) -> tuple[int, Sequence[object]] | None:
        if cmd.args or cmd.keywords:
            return ERROR_PARAMETER_COUNT, ()
        with self._cond:
            generation = self._drop_generation
            while self._queue or (self._active is not None and not self._active.servo):
                if self._stop.is_set() or self._drop_generation != generation:
                    return None
                self._cond.wait(_POLL_S)
            return (ERROR_FAILED if self._alarms else ERROR_OK), ()

    # -- networking ----------------------------------------------------------------------------------------------

    def _accept_loop(self, name: str, server: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            except OSError:
                return  # server closed
            # Set up before registering: a drop or stop may close the socket as soon as it is registered.
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(1.0 if name == "feedback" else _POLL_S)
            with self._clients_lock:
                if self._stop.is_set():
                    conn.close()
                    return
                self._clients.add(conn)
                if name == "feedback":
                    self._feedback_clients.append(conn)
            if name != "feedback":
                self._spawn(f"mg400-emu-{name}-client", self._serve_commands, name, conn)

    def _record(self, port: str, text: str) -> bool:
        """Log a received command; True when the drop fault fires now."""
        limit = self.config.faults.drop_after_commands
        with self._clients_lock:
            self._log.append((port, text))
            self._command_count += 1
            if limit is not None and not self._dropped and self._command_count >= limit:
                self._dropped = True
                return True
        return False

    def _serve_commands(self, port: str, conn: socket.socket) -> None:
        buffer = CommandBuffer()
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                if not data:
                    return
                for text in buffer.feed(data):
                    if self._record(port, text):
                        self.drop_connections()
                        return
                    reply = self._reply(port, text)
                    if reply is None:
                        return
                    name = text.split("(", 1)[0].strip().lower()
                    faults = self.config.faults  # read per command: set_faults swaps it at run time
                    if faults.reply_delay_s > 0.0 and (not faults.slow_commands or name in faults.slow_commands):
                        if self._stop.wait(faults.reply_delay_s):
                            return
                    self._send_reply(conn, reply)
        except (OSError, ProtocolError) as error:
            logger.debug("MG400 emulator %s connection ended: %s", port, error)
        finally:
            with self._clients_lock:
                self._clients.discard(conn)
            conn.close()

    def _reply(self, port: str, text: str) -> str | None:
        try:
            cmd = parse_command(text)
        except ProtocolError:
            return format_reply(ERROR_UNKNOWN_COMMAND, (), text)
        handler = self._handlers.get((port, cmd.name.lower()))
        if handler is None:
            return format_reply(ERROR_UNKNOWN_COMMAND, (), cmd.text)
        result = handler(cmd)
        if result is None:
            return None
        error_id, values = result
        return format_reply(error_id, values, cmd.text)  # type: ignore[arg-type]

    def _send_reply(self, conn: socket.socket, reply: str) -> None:
        data = reply.encode("ascii")
        chunk = self.config.faults.split_replies_bytes
        if chunk is None:
            conn.sendall(data)
            return
        for start in range(0, len(data), chunk):
            conn.sendall(data[start:start + chunk])
            if start + chunk < len(data):
                self._stop.wait(self.config.faults.split_delay_s)

    def _bad_packet(self, packet: bytes, fault: FeedbackFault) -> bytes:
        if fault is FeedbackFault.PARTIAL:
            return packet[: FEEDBACK_PACKET_BYTES // 2]
        if fault is FeedbackFault.INCONSISTENT:
            feedback = self._feedback()
            joints = list(feedback.q_actual_deg)
            joints[0] += INCONSISTENT_FEEDBACK_OFFSET_DEG
            return pack_feedback(replace(feedback, q_actual_deg=tuple(joints)))
        corrupt = bytearray(packet)
        if fault is FeedbackFault.BAD_LENGTH:
            struct.pack_into("<H", corrupt, 0, FEEDBACK_PACKET_BYTES - 1)
        else:
            struct.pack_into("<Q", corrupt, 48, 0)
        return bytes(corrupt)

    def _tick_loop(self) -> None:
        period_s = self.config.feedback_period_s
        last = time.monotonic()
        next_tick = last
        tick = 0
        while not self._stop.is_set():
            now = time.monotonic()
            self._step(now - last)
            last = now
            tick += 1
            packet = pack_feedback(self._feedback())
            faults = self.config.faults  # read per tick: set_faults swaps it at run time
            every = faults.corrupt_feedback_every
            if every is not None and tick % every == 0:
                kinds = faults.feedback_faults
                packet = self._bad_packet(packet, kinds[(tick // every - 1) % len(kinds)])
            with self._clients_lock:
                clients = list(self._feedback_clients)
            with self._cond:
                if time.monotonic() < self._feedback_paused_until:
                    clients = []  # stale feedback: the arm moves on, nothing is sent
            for conn in clients:
                try:
                    conn.sendall(packet)
                except OSError:
                    with self._clients_lock:
                        if conn in self._feedback_clients:
                            self._feedback_clients.remove(conn)
                        self._clients.discard(conn)
                    conn.close()
            with self._cond:
                self._packets_sent += 1
            next_tick += period_s
            delay_s = next_tick - time.monotonic()
            if delay_s < 0.0:
                next_tick = time.monotonic()
                delay_s = 0.0
            self._stop.wait(delay_s)


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear mg400-emulator``."""
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to listen on (default 127.0.0.1)")
    parser.add_argument("--dashboard-port", type=int, default=DASHBOARD_PORT, help="dashboard port (0: any free)")
    parser.add_argument("--motion-port", type=int, default=MOTION_PORT, help="motion port (0: any free)")
    parser.add_argument("--feedback-port", type=int, default=FEEDBACK_PORT, help="feedback port (0: any free)")
    parser.add_argument("--pose-values", type=int, default=6, choices=(4, 5, 6),
                        help="numbers returned by GetPose/GetAngle (default 6, as field firmware)")
    faults = parser.add_argument_group("fault injection")
    faults.add_argument("--alarm-during-motion", type=int, default=None, metavar="ALARM_ID",
                        help="raise this alarm once, --alarm-after-s into a motion")
    faults.add_argument("--alarm-after-s", type=float, default=0.05, help="seconds into the motion (default 0.05)")
    faults.add_argument("--drop-after-commands", type=int, default=None, metavar="N",
                        help="drop every connection when N commands have been received")
    faults.add_argument("--split-replies-bytes", type=int, default=None, metavar="N",
                        help="send replies in N-byte TCP segments")
    faults.add_argument("--corrupt-feedback-every", type=int, default=None, metavar="N",
                        help="make every N-th feedback packet bad (length, test value, partial in turn)")
    faults.add_argument("--reply-delay-s", type=float, default=0.0, help="delay every reply by this many seconds")
    faults.add_argument("--slow-commands", nargs="*", default=(), metavar="NAME",
                        help="only these commands get --reply-delay-s (default: all)")


def run(args: argparse.Namespace) -> int:
    """Run the emulator until Ctrl-C; returns 0."""
    config = EmulatorConfig(
        host=args.host, dashboard_port=args.dashboard_port, motion_port=args.motion_port,
        feedback_port=args.feedback_port, pose_value_count=args.pose_values,
        faults=FaultConfig(alarm_during_motion=args.alarm_during_motion, alarm_after_s=args.alarm_after_s,
                           drop_after_commands=args.drop_after_commands,
                           split_replies_bytes=args.split_replies_bytes,
                           corrupt_feedback_every=args.corrupt_feedback_every, reply_delay_s=args.reply_delay_s,
                           slow_commands=tuple(args.slow_commands)),
    )
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    with MG400Emulator(config) as emulator:
        logger.info("MG400 emulator running on %s (dashboard %d, motion %d, feedback %d); Ctrl-C to stop",
                    config.host, emulator.dashboard_port, emulator.motion_port, emulator.feedback_port)
        try:
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt:
            logger.info("MG400 emulator stopping")
    return 0
