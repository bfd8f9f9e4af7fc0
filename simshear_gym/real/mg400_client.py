"""TCP/IP client for a Dobot MG400 (dashboard 29999, motion 30003, feedback 30004) and a servo streamer.

Every request waits for its reply (with a timeout); a non-zero ErrorID raises :class:`MG400Error`. Every motion
command passes the full :class:`~simshear_gym.real.safety.SafetyLayer` first: the arm's joint limits, the
workspace, the step and speed of servo commands and the jump of queued moves, with the safe defaults of
:class:`~simshear_gym.real.safety.SafetyConfig` when no safety layer is given (loosening them takes an explicit
:class:`~simshear_gym.real.safety.UnsafeSafetyConfig`).

**A stream of commands.** Every motion command is also checked against the arm's *fed-back* state and the commands
sent before it (:class:`~simshear_gym.real.safety.MotionStream`, one per client, so each arm of a two-arm rig gets
the same rules): a servo command must not ask the arm for more than ``max_speed_*`` from anywhere it may be (the
fed-back pose and the targets that may be in force) nor change the velocity asked for faster than ``max_accel_*``;
queued moves (MovJ, MovL, JointMovJ, RelMovL, RelMovJ) carry the ``SpeedL``/``SpeedJ`` and ``AccL``/``AccJ``
ratios that keep them within the same bounds. No motion command is sent while the feedback stream is stale or
missing or the robot reports error mode (:class:`~simshear_gym.real.safety.MotionRefusedError`; without the stream
the client asks ``RobotMode()``, ``GetAngle()`` and ``GetPose()`` before each one). The client's clock is
injectable (``clock=``) for tests.

Where the robot is: the step of a command is measured from the last target sent, or, when there is none (first
command, after a stop or a reset), from the robot's *reported* pose (Cartesian step) and its reported joints
(per-joint steps). The client trusts a measurement only when the two agree (forward kinematics within
``SafetyConfig.max_pose_mismatch_mm`` / ``_deg``), and it checks every feedback packet the same way: one that
disagrees stops all motion commands (:class:`~simshear_gym.real.safety.FeedbackMismatchError`, naming both) until
:meth:`MG400Client.reset_reference` and a measurement that agrees. A command whose reply was lost (timeout, dropped
connection) may or may not be in force, so the next target must be within the limits of both it and the robot's
measured pose.

Poses are ``(x_mm, y_mm, z_mm, r_deg)`` in the robot base frame; joints ``(J1, J2, J3, J4)`` in deg.

Example::

    with MG400Client(MG400ClientConfig(host="192.168.1.6")) as robot:  # the safe default limits
        robot.enable_robot()
        robot.mov_l(300.0, 0.0, 50.0, 0.0)
        robot.sync()
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from simshear_gym.data.labels import wrap_deg
from simshear_gym.real.safety import (
    ArmSample,
    FeedbackMismatchError,
    MotionKind,
    MotionRefusedError,
    MotionStream,
    SafetyConfig,
    SafetyError,
    SafetyLayer,
    StatusSnapshot,
    StopReason,
    queued_ratios,
)
from simshear_gym.robots.mg400.protocol import (
    DASHBOARD_PORT,
    FEEDBACK_PERIOD_S,
    FEEDBACK_PORT,
    MOTION_PORT,
    SERVO_TIME_RANGE_S,
    FeedbackBuffer,
    MG400Feedback,
    ProtocolError,
    Reply,
    ReplyBuffer,
    RobotMode,
    describe_alarm,
    describe_error_id,
    format_command,
    parse_reply,
)

logger = logging.getLogger(__name__)

Pose = tuple[float, float, float, float]


class MG400Error(RuntimeError):
    """The controller answered a command with a non-zero ErrorID.

    Attributes:
        error_id: the reply's ErrorID.
        command: the command text sent.
        description: the decoded ErrorID.
        alarms: active alarm ids read with ``GetErrorID`` after a failed motion command (may be empty).
    """

    def __init__(self, error_id: int, command: str, alarms: Sequence[int] = ()) -> None:
        self.error_id = int(error_id)
        self.command = command
        self.description = describe_error_id(self.error_id)
        self.alarms = tuple(int(a) for a in alarms)
        message = f"{command} failed with ErrorID {self.error_id}: {self.description}"
        if self.alarms:
            message += "; active alarms: " + ", ".join(f"{a} ({describe_alarm(a)})" for a in self.alarms)
        super().__init__(message)


class MG400ConnectionError(ConnectionError):
    """A connection to the robot could not be opened or was lost."""


class MG400TimeoutError(TimeoutError):
    """No reply arrived within the timeout."""


LATE_FEEDBACK_PERIODS = 5
"""A servo command refused by the stream checks while the newest feedback is older than this many feedback periods
is reported as stale feedback (the stall, not the command, is the cause)."""


class FeedbackStaleError(RuntimeError):
    """No feedback packet newer than the allowed age (or the feedback connection is lost)."""


@dataclass(frozen=True)
class MG400ClientConfig:
    """Where the robot is and how long to wait.

    Attributes:
        host: controller IP address (default LAN1).
        dashboard_port, motion_port, feedback_port: TCP ports.
        connect_timeout_s: per-connection connect timeout, s.
        reply_timeout_s: default wait for a reply, s.
        sync_timeout_s: default wait for ``Sync()`` (the motion queue to empty), s.
        use_feedback: open the 30004 feedback stream and its reader thread.
        feedback_max_age_s: default maximum age for :meth:`MG400Client.latest_feedback`, s.
    """

    host: str = "192.168.1.6"
    dashboard_port: int = DASHBOARD_PORT
    motion_port: int = MOTION_PORT
    feedback_port: int = FEEDBACK_PORT
    connect_timeout_s: float = 2.0
    reply_timeout_s: float = 2.0
    sync_timeout_s: float = 60.0
    use_feedback: bool = True
    feedback_max_age_s: float = 0.1

    def __post_init__(self) -> None:
        if not self.host:
            raise ValueError("MG400ClientConfig.host must be a host name or IP address, got ''")
        for name in ("dashboard_port", "motion_port", "feedback_port"):
            port = getattr(self, name)
            if not isinstance(port, int) or not 1 <= port <= 65535:
                raise ValueError(f"MG400ClientConfig.{name} must be an int in 1..65535, got {port!r}")
        for name in ("connect_timeout_s", "reply_timeout_s", "sync_timeout_s", "feedback_max_age_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MG400ClientConfig.{name} must be finite and > 0 s, got {value!r}")


def _connect(label: str, host: str, port: int, timeout_s: float) -> socket.socket:
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as error:
        raise MG400ConnectionError(f"cannot connect to the MG400 {label} port at {host}:{port}: {error}") from error
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def shut_socket(sock: socket.socket) -> None:
    """Shut a connection down (if it still is up) and close it (the client's and the emulator's)."""
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    sock.close()


class _ReplyChannel:
    """One request/reply connection (dashboard or motion): send a command, wait for its reply."""

    def __init__(self, label: str, host: str, port: int, connect_timeout_s: float) -> None:
        self.label = label
        self._where = f"{label} port {host}:{port}"
        self._sock = _connect(label, host, port, connect_timeout_s)
        self._buffer = ReplyBuffer()
        self._ready: deque[str] = deque()
        self._lock = threading.Lock()
        self._stale = 0  # replies still owed to requests that timed out; discarded when they arrive
        self._lost: str | None = None

    @property
    def connected(self) -> bool:
        return self._lost is None

    def request(self, command: str, timeout_s: float) -> Reply:
        """Send ``command`` and return its reply."""
        with self._lock:
            if self._lost is not None:
                raise MG400ConnectionError(f"cannot send {command}: the {self._where} is closed ({self._lost})")
            logger.debug("%s <- %s", self.label, command)
            try:
                self._sock.sendall(command.encode("ascii"))
            except OSError as error:
                self._mark_lost(f"send failed: {error}")
                raise MG400ConnectionError(f"sending {command} on the {self._where} failed: {error}") from error
            deadline = time.monotonic() + timeout_s
            expected = command.split("(", 1)[0].strip().lower()
            while True:
                text = self._next_text(deadline, command, timeout_s)
                try:
                    reply = parse_reply(text)
                except ProtocolError as error:
                    raise MG400ConnectionError(f"malformed reply to {command} on the {self._where}: {error}") \
                        from error
                if self._stale > 0:
                    # Replies arrive in order, so the first ones after a timeout belong to the timed-out requests.
                    self._stale -= 1
                    logger.warning("discarding late reply %r on the %s", text, self._where)
                    continue
                if reply.command_name and reply.command_name.lower() != expected:
                    logger.warning("discarding reply %r on the %s while waiting for %s", text, self._where, command)
                    continue
                logger.debug("%s -> %s", self.label, text)
                return reply

    def _next_text(self, deadline: float, command: str, timeout_s: float) -> str:
        while not self._ready:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                self._stale += 1
                raise MG400TimeoutError(f"no reply to {command} on the {self._where} within {timeout_s:g} s")
            self._sock.settimeout(remaining)
            try:
                data = self._sock.recv(4096)
            except TimeoutError:
                continue
            except OSError as error:
                self._mark_lost(f"receive failed: {error}")
                raise MG400ConnectionError(f"waiting for the reply to {command}: the {self._where} failed: {error}") \
                    from error
            if not data:
                self._mark_lost("closed by the robot")
                raise MG400ConnectionError(f"the robot closed the {self._where} while {command} waited for its reply")
            try:
                self._ready.extend(self._buffer.feed(data))
            except ProtocolError as error:
                self._mark_lost(str(error))
                raise MG400ConnectionError(f"garbage on the {self._where}: {error}") from error
        return self._ready.popleft()

    def _mark_lost(self, reason: str) -> None:
        self._lost = reason
        logger.error("MG400 %s lost: %s", self._where, reason)
        shut_socket(self._sock)

    def close(self) -> None:
        if self._lost is None:
            self._lost = "closed by the client"
            shut_socket(self._sock)


class _FeedbackReader:
    """Reads the 30004 stream in a thread, validates packets and keeps only the newest; ``check`` runs on every
    valid packet and the first reason it gives (joints and pose disagree) is kept until :meth:`clear_mismatch`."""

    def __init__(self, host: str, port: int, connect_timeout_s: float,
                 check: Callable[[MG400Feedback], str | None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._where = f"feedback port {host}:{port}"
        self._clock = clock
        self._check = check
        self._mismatch: str | None = None
        self._sock = _connect("feedback", host, port, connect_timeout_s)
        self._sock.settimeout(0.1)
        self._buffer = FeedbackBuffer()
        self._lock = threading.Lock()
        self._latest: tuple[MG400Feedback, float] | None = None
        self._received = 0
        self._lost: str | None = None
        self._stop = threading.Event()
        self._first = threading.Event()
        self._last_joints: tuple[float, ...] | None = None
        self._moved_s: float | None = None
        self._thread = threading.Thread(target=self._run, name="mg400-feedback", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as error:
                self._set_lost(f"receive failed: {error}")
                return
            if not data:
                self._set_lost("closed by the robot")
                return
            packets, reasons = self._buffer.feed(data)
            for reason in reasons:
                logger.warning("rejected an MG400 feedback packet: %s", reason)
            for packet in packets if self._check is not None else ():
                mismatch = self._check(packet)
                if mismatch is not None:
                    with self._lock:
                        first = self._mismatch is None
                        if first:
                            self._mismatch = mismatch
                    if first:
                        logger.error("MG400 %s: %s", self._where, mismatch)
            if packets:
                now_s = self._clock()
                with self._lock:
                    for packet in packets:  # when a packet last showed the arm moving (or the first packet)
                        joints = packet.q_actual_deg
                        if self._last_joints is None or joints != self._last_joints:
                            self._moved_s = now_s
                        self._last_joints = joints
                    self._latest = (packets[-1], now_s)
                    self._received += len(packets)
                self._first.set()

    def _set_lost(self, reason: str) -> None:
        with self._lock:
            self._lost = reason
        self._first.set()  # nothing more will come
        if not self._stop.is_set():
            logger.error("MG400 %s lost: %s", self._where, reason)

    @property
    def connected(self) -> bool:
        with self._lock:
            return self._lost is None

    @property
    def rejected(self) -> int:
        return self._buffer.rejected

    @property
    def mismatch(self) -> str | None:
        """The first disagreement between joints and pose seen since :meth:`clear_mismatch`, or None."""
        with self._lock:
            return self._mismatch

    def clear_mismatch(self) -> None:
        with self._lock:
            self._mismatch = None

    @property
    def received(self) -> int:
        with self._lock:
            return self._received

    @property
    def moved_s(self) -> float | None:
        """When a packet last showed the arm moving (or the first packet arrived), the client's clock, s."""
        with self._lock:
            return self._moved_s

    def wait_first(self, timeout_s: float) -> bool:
        """Wait until the first valid packet arrived (or ``timeout_s`` passed, or the stream was lost)."""
        return self._first.wait(timeout_s)

    def age_s(self) -> float | None:
        with self._lock:
            return None if self._latest is None else self._clock() - self._latest[1]

    def latest(self, max_age_s: float) -> MG400Feedback:
        return self.latest_with_time(max_age_s)[0]

    def latest_with_time(self, max_age_s: float) -> tuple[MG400Feedback, float]:
        """The newest valid packet and when it arrived (the client's clock, s)."""
        with self._lock:
            latest, lost = self._latest, self._lost
        if latest is None:
            raise FeedbackStaleError(f"no valid feedback packet received yet on the {self._where}"
                                     + (f" (connection lost: {lost})" if lost else ""))
        age_s = self._clock() - latest[1]
        if age_s > max_age_s:
            raise FeedbackStaleError(f"newest feedback is {age_s:.3f} s old, max_age_s = {max_age_s:g}"
                                     + (f" (connection lost: {lost})" if lost else ""))
        return latest

    def close(self) -> None:
        self._stop.set()
        shut_socket(self._sock)
        self._thread.join(timeout=1.0)


@dataclass(frozen=True)
class ErrorIDs:
    """``GetErrorID()`` result: active alarm ids of the controller and of each servo."""

    controller: tuple[int, ...]
    servos: tuple[tuple[int, ...], ...]

    @property
    def all_ids(self) -> tuple[int, ...]:
        """Every active alarm id, controller first."""
        return self.controller + tuple(i for servo in self.servos for i in servo)


def _three(values: Sequence[float], name: str) -> tuple[float, float, float]:
    if len(values) != 3 or not all(math.isfinite(float(v)) for v in values):
        raise ValueError(f"{name} must be 3 finite numbers, got {values!r}")
    return tuple(float(v) for v in values)  # type: ignore[return-value]


def _four(values: Sequence[float], name: str) -> Pose:
    if len(values) != 4:
        raise ValueError(f"{name} must have 4 values, got {len(values)}")
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be finite, got {out}")
    return out  # type: ignore[return-value]


def wait_at_pose(client, pose: np.ndarray, tolerance: float, timeout_s: float, poll_s: float,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> np.ndarray | None:
    """Wait until ``client``'s newest feedback shows no queued move running and the flange at ``pose`` (within
    ``tolerance`` mm and deg): None then, or after ``timeout_s`` the fed-back pose it stopped at."""
    deadline = clock() + timeout_s
    while True:
        feedback = client.latest_feedback()
        reached = np.asarray(feedback.tool_vector_actual, dtype=np.float64)[:4]
        if (not feedback.run_queued_command and np.linalg.norm(reached[:3] - pose[:3]) <= tolerance
                and abs(wrap_deg(reached[3] - pose[3])) <= tolerance):
            return None
        if clock() > deadline:
            return reached
        sleep(poll_s)


class MG400Client:
    """Dashboard, motion and feedback connections to one MG400 (a context manager).

    Args:
        config: host, ports and timeouts.
        safety: the safety layer every motion command passes; default: ``SafetyLayer(SafetyConfig())``, the safe
            defaults for tactile work near a surface.
        clock: the client's clock, s (default ``time.monotonic``): feedback arrival times and command times.
    """

    def __init__(self, config: MG400ClientConfig | None = None, safety: SafetyLayer | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        self.config = config if config is not None else MG400ClientConfig()
        self.safety = safety if safety is not None else SafetyLayer(SafetyConfig())
        self.clock: Callable[[], float] = clock if clock is not None else time.monotonic
        self.stream = MotionStream(self.safety)
        self._speed_factor_percent = 100  # assumed until set: the fastest
        self._dashboard: _ReplyChannel | None = None
        self._motion: _ReplyChannel | None = None
        self._feedback: _FeedbackReader | None = None
        # (pose, joints) of the last target sent (where the robot is, or is heading); None -> measure the robot.
        self._reference: tuple[np.ndarray, np.ndarray] | None = None
        # (pose, joints) of a target whose reply was lost: it may be in force, so the next step is checked from it too.
        self._uncertain: tuple[np.ndarray, np.ndarray] | None = None
        self._motion_lock = threading.RLock()

    # -- connection ----------------------------------------------------------------------------------------------

    def connect(self) -> MG400Client:
        """Open the dashboard, motion and (if configured) feedback connections."""
        cfg = self.config
        try:
            self._dashboard = _ReplyChannel("dashboard", cfg.host, cfg.dashboard_port, cfg.connect_timeout_s)
            self._motion = _ReplyChannel("motion", cfg.host, cfg.motion_port, cfg.connect_timeout_s)
            if cfg.use_feedback:
                self._feedback = _FeedbackReader(cfg.host, cfg.feedback_port, cfg.connect_timeout_s,
                                                 check=self._packet_mismatch, clock=self.clock)
        except MG400ConnectionError:
            self.close()
            raise
        if self._feedback is not None:  # motion waits for feedback: give the first packet the connect timeout
            self._feedback.wait_first(cfg.connect_timeout_s)
        logger.info("connected to MG400 at %s", cfg.host)
        return self

    def close(self) -> None:
        """Close all connections (idempotent)."""
        for part in (self._feedback, self._motion, self._dashboard):
            if part is not None:
                part.close()
        self._feedback = self._motion = self._dashboard = None

    def __enter__(self) -> MG400Client:
        return self if self._dashboard is not None else self.connect()  # connected already: keep those

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        """True when every opened connection is still up."""
        parts = [self._dashboard, self._motion] + ([self._feedback] if self.config.use_feedback else [])
        return all(part is not None and part.connected for part in parts)

    def _channel(self, which: str) -> _ReplyChannel:
        channel = self._dashboard if which == "dashboard" else self._motion
        if channel is None:
            raise MG400ConnectionError(f"the MG400 client is not connected (no {which} connection); call connect()")
        return channel

    def _request(self, which: str, command: str, timeout_s: float | None = None) -> Reply:
        reply = self._channel(which).request(command, self.config.reply_timeout_s if timeout_s is None else timeout_s)
        if not reply.ok:
            raise MG400Error(reply.error_id, command, self._alarms_best_effort() if which == "motion" else ())
        return reply

    def _alarms_best_effort(self) -> tuple[int, ...]:
        try:
            return self.get_error_id().all_ids
        except (MG400Error, MG400ConnectionError, MG400TimeoutError, ProtocolError) as error:
            logger.debug("could not read alarms after a failed command: %s", error)
            return ()

    # -- dashboard -----------------------------------------------------------------------------------------------

    def enable_robot(self, load_kg: float | None = None,
                     center_mm: tuple[float, float, float] | None = None) -> None:
        """``EnableRobot()``, or ``EnableRobot(load)`` / ``EnableRobot(load,centerX,centerY,centerZ)`` with the
        payload in kg and its centre offset in mm (-500..500)."""
        params: list[float] = []
        if load_kg is not None:
            params.append(float(load_kg))
            if center_mm is not None:
                params += [float(v) for v in _three(center_mm, "center_mm")]
        elif center_mm is not None:
            raise ValueError("EnableRobot: center_mm needs load_kg")
        self._request("dashboard", format_command("EnableRobot", *params))

    def disable_robot(self) -> None:
        """``DisableRobot()``."""
        self._request("dashboard", format_command("DisableRobot"))
        self._forget_targets()

    def clear_error(self) -> None:
        """``ClearError()``; follow with :meth:`continue_`. With the feedback stream, waits (up to the reply
        timeout) for a packet that no longer shows error mode, so that the next motion command is not refused."""
        self._request("dashboard", format_command("ClearError"))
        self._forget_targets()
        if self._feedback is not None:
            deadline_s = time.monotonic() + self.config.reply_timeout_s
            seen = self._feedback.received
            while time.monotonic() < deadline_s:
                try:
                    packet = self._feedback.latest(self.config.reply_timeout_s)
                except FeedbackStaleError:
                    packet = None
                if (packet is not None and self._feedback.received > seen and not packet.error_status
                        and packet.robot_mode != int(RobotMode.ERROR)):
                    return
                time.sleep(0.002)

    def continue_(self) -> None:
        """``Continue()``."""
        self._request("dashboard", format_command("Continue"))

    def reset_robot(self) -> None:
        """``ResetRobot()``: stop and clear the motion queue."""
        self._request("dashboard", format_command("ResetRobot"))
        self._forget_targets()

    def emergency_stop(self) -> None:
        """``EmergencyStop()``."""
        self._forget_targets()
        self._request("dashboard", format_command("EmergencyStop"))

    def speed_factor(self, percent: int) -> None:
        """``SpeedFactor(percent)``, percent in 1..100."""
        if isinstance(percent, bool) or not isinstance(percent, int) or not 1 <= percent <= 100:
            raise ValueError(f"speed factor must be an int percent in 1..100, got {percent!r}")
        self._speed_factor_percent = 100  # while in doubt (no reply): the fastest
        self._request("dashboard", format_command("SpeedFactor", percent))
        self._speed_factor_percent = percent

    def robot_mode(self) -> RobotMode:
        """``RobotMode()``."""
        reply = self._request("dashboard", format_command("RobotMode"))
        numbers = reply.numbers()
        try:
            return RobotMode(int(numbers[0]))
        except (IndexError, ValueError):
            raise ProtocolError(f"RobotMode() returned {reply.values!r}, expected one mode in 1..11") from None

    def get_pose(self) -> Pose:
        """``GetPose()`` -> ``(x_mm, y_mm, z_mm, r_deg)`` (4-6 numbers are accepted; extras ignored)."""
        return self._four_numbers(self._request("dashboard", format_command("GetPose")), "GetPose()")

    def get_angle(self) -> Pose:
        """``GetAngle()`` -> ``(J1, J2, J3, J4)`` deg (extras ignored)."""
        return self._four_numbers(self._request("dashboard", format_command("GetAngle")), "GetAngle()")

    @staticmethod
    def _four_numbers(reply: Reply, what: str) -> Pose:
        numbers = reply.numbers()
        if len(numbers) < 4:
            raise ProtocolError(f"{what} returned {reply.values!r}, expected at least 4 numbers")
        return numbers[:4]  # type: ignore[return-value]

    def get_error_id(self) -> ErrorIDs:
        """``GetErrorID()`` -> controller and per-servo alarm ids."""
        reply = self._request("dashboard", format_command("GetErrorID"))
        lists = reply.values[0] if len(reply.values) == 1 and isinstance(reply.values[0], tuple) else reply.values
        if not all(isinstance(item, tuple) for item in lists):
            raise ProtocolError(f"GetErrorID() returned {reply.values!r}, expected [[ids],[ids],...]")
        ids = [tuple(int(v) for v in item) for item in lists]  # type: ignore[union-attr]
        return ErrorIDs(controller=ids[0] if ids else (), servos=tuple(ids[1:]))

    # -- feedback ------------------------------------------------------------------------------------------------

    def latest_feedback(self, max_age_s: float | None = None) -> MG400Feedback:
        """The newest valid feedback packet.

        Raises:
            FeedbackStaleError: none newer than ``max_age_s`` (default ``config.feedback_max_age_s``).
        """
        if self._feedback is None:
            raise FeedbackStaleError("feedback is not running (not connected, or use_feedback=False)")
        return self._feedback.latest(self.config.feedback_max_age_s if max_age_s is None else max_age_s)

    def wait_feedback(self, timeout_s: float) -> MG400Feedback:
        """The newest valid feedback packet (:meth:`latest_feedback`), waiting up to ``timeout_s`` for one.

        Raises:
            FeedbackStaleError: none came within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return self.latest_feedback()
            except FeedbackStaleError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.005)

    def _fresh_feedback(self) -> MG400Feedback | None:
        """The newest feedback packet when the stream runs and it is fresh (``config.feedback_max_age_s``), else
        None."""
        try:
            return self.latest_feedback()
        except FeedbackStaleError:
            return None

    def wait_until_still(self, duration_s: float, timeout_s: float = 2.0) -> bool:
        """Wait until the feedback shows the arm still for ``duration_s`` (a servo command from rest may then ask
        for up to ``max_accel`` times that much speed: the acceleration check); False after ``timeout_s`` or
        without the feedback stream."""
        if self._feedback is None:
            return False
        deadline_s = time.monotonic() + timeout_s
        while True:
            moved_s = self._feedback.moved_s
            if moved_s is not None and self.clock() - moved_s >= duration_s + self.safety.config.controller_cycle_s:
                return True
            if time.monotonic() >= deadline_s:
                return False
            time.sleep(0.002)

    @property
    def feedback_rejected(self) -> int:
        """Feedback packets rejected so far (bad length field, test value or truncated)."""
        return 0 if self._feedback is None else self._feedback.rejected

    @property
    def feedback_received(self) -> int:
        """Valid feedback packets received so far."""
        return 0 if self._feedback is None else self._feedback.received

    def status_snapshot(self, camera_frame_age_s: float | None = None, in_contact: bool | None = None
                        ) -> StatusSnapshot:
        """The robot side of a :class:`StatusSnapshot` (mode and age from feedback; no network request)."""
        mode: int | None = None
        age_s: float | None = None
        if self._feedback is not None:
            age_s = self._feedback.age_s()
            try:
                mode = self._feedback.latest(math.inf).robot_mode
            except FeedbackStaleError:
                mode = None
            if age_s is None:
                age_s = math.inf
        return StatusSnapshot(connected=self.connected, robot_mode=mode, feedback_age_s=age_s,
                              camera_frame_age_s=camera_frame_age_s, in_contact=in_contact)

    def measured_joints(self) -> np.ndarray:
        """Current joints, deg: from fresh feedback if available, else ``GetAngle()``."""
        feedback = self._fresh_feedback()
        return np.array(feedback.q_actual_deg if feedback is not None else self.get_angle())

    def measured_pose(self) -> Pose:
        """Current flange pose: from fresh feedback if available, else ``GetPose()``."""
        feedback = self._fresh_feedback()
        return feedback.tool_vector_actual if feedback is not None else self.get_pose()

    def measured_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The robot's reported pose ``(x_mm, y_mm, z_mm, r_deg)`` and joints (deg), from one fresh feedback packet
        if available, else ``GetAngle()`` and ``GetPose()``, checked to agree.

        Raises:
            FeedbackMismatchError: the joints' forward kinematics and the pose disagree beyond the tolerance.
        """
        feedback = self._fresh_feedback()
        if feedback is not None:
            pose, joints, source = feedback.tool_vector_actual, feedback.q_actual_deg, "feedback"
        else:
            joints, pose, source = self.get_angle(), self.get_pose(), "GetAngle() and GetPose()"
        self.safety.check_feedback_agreement(joints, pose, f"MG400 at {self.config.host}, {source}")
        return np.array(pose, dtype=float), np.array(joints, dtype=float)

    @property
    def feedback_mismatch(self) -> str | None:
        """Why a feedback packet since :meth:`reset_reference` had joints and pose that disagree, or None."""
        return None if self._feedback is None else self._feedback.mismatch

    def _packet_mismatch(self, feedback: MG400Feedback) -> str | None:
        return self.safety.feedback_mismatch(feedback.q_actual_deg, feedback.tool_vector_actual)

    # -- motion (all through the safety layer) -------------------------------------------------------------------

    def reset_reference(self) -> None:
        """Forget the last target sent and any disagreeing feedback seen, so that the next motion command measures
        the robot afresh (and checks that its joints and pose agree) first."""
        self._forget_targets()
        if self._feedback is not None:
            self._feedback.clear_mismatch()

    def _forget_targets(self) -> None:
        self._reference = None
        self._uncertain = None
        self.stream.forget()

    def arm_sample(self) -> ArmSample:
        """The newest measurement of the arm for the stream checks; refuses motion on stale or missing feedback or
        in error mode (:class:`~simshear_gym.real.safety.MotionRefusedError`), unless
        ``SafetyConfig.refuse_stale_feedback`` was turned off (then GetAngle / GetPose stand in).

        Raises:
            MotionRefusedError: the feedback is stale or missing, or the robot is in error mode.
            FeedbackMismatchError: the measured joints and pose disagree.
        """
        cfg = self.safety.config
        where = f"MG400 at {self.config.host}"
        if self._feedback is not None:
            try:
                packet, received_s = self._feedback.latest_with_time(cfg.max_feedback_age_s)
            except FeedbackStaleError as error:
                if cfg.refuse_stale_feedback:
                    raise MotionRefusedError(StopReason.STALE_FEEDBACK,
                                             f"{where}: not sending motion on stale or missing feedback: {error} "
                                             f"(max_feedback_age_s = {cfg.max_feedback_age_s:g})") from error
            else:
                if cfg.refuse_stale_feedback and (packet.robot_mode == int(RobotMode.ERROR) or packet.error_status):
                    raise MotionRefusedError(StopReason.ROBOT_ERROR_MODE,
                                             f"{where}: not sending motion: the robot reports error mode "
                                             "(ClearError() and Continue() first)")
                self.safety.check_feedback_agreement(packet.q_actual_deg, packet.tool_vector_actual,
                                                     f"{where}, feedback")
                return ArmSample(tuple(packet.tool_vector_actual), tuple(packet.q_actual_deg), received_s,
                                 tuple(packet.tool_vector_target), tuple(packet.q_target_deg),
                                 self._feedback.moved_s)
        elif cfg.refuse_stale_feedback and self.robot_mode() is RobotMode.ERROR:
            raise MotionRefusedError(StopReason.ROBOT_ERROR_MODE,
                                     f"{where}: not sending motion: the robot reports error mode "
                                     "(ClearError() and Continue() first)")
        asked_s = self.clock()
        joints, pose = self.get_angle(), self.get_pose()
        self.safety.check_feedback_agreement(joints, pose, f"{where}, GetAngle() and GetPose()")
        return ArmSample(tuple(pose), tuple(joints), asked_s)

    def _reference_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(pose, joints) the next step is measured from; refuses while the feedback disagrees."""
        mismatch = self.feedback_mismatch
        if mismatch is not None:
            raise FeedbackMismatchError(f"MG400 at {self.config.host}, feedback: {mismatch}; not sending anything "
                                        "until reset_reference() and a measurement that agrees")
        if self._reference is None:
            self._reference = self.measured_state()
        return self._reference

    def _send_motion(self, command: str, target_pose: np.ndarray, target_joints: np.ndarray) -> None:
        target = (np.asarray(target_pose, dtype=float), np.asarray(target_joints, dtype=float))
        try:
            self.safety.submit(command, lambda text: self._request("motion", text))
        except MG400Error:  # the controller answered: refused, not in force
            self._reference = None
            self.stream.outcome(answered=True, accepted=False)
            raise
        except BaseException:  # no answer: it may be in force
            self._reference = None
            self._uncertain = target
            self.stream.outcome(answered=False, accepted=False)
            raise
        self._reference = target
        self._uncertain = None
        self.stream.outcome(answered=True, accepted=True)

    def _stream_sample(self, measured: ArmSample) -> ArmSample:
        """What the stream checks measure from: the arm, or in dry run (nothing is sent, the arm stays) the last
        target, as if it had been sent and reached."""
        if not self.safety.dry_run or self._reference is None:
            return measured
        pose, joints = self._reference
        return ArmSample(tuple(pose), tuple(joints), self.clock(), moved_s=measured.moved_s)

    def _check_cartesian(self, target: np.ndarray, kind: MotionKind, duration_s: float | None,
                         reference: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The per-command checks of a Cartesian target (from the reference and a target whose reply was lost)."""
        joints = self.safety.check_target(reference[0], target, kind, duration_s, reference[1])
        if self._uncertain is not None:
            self.safety.check_target(self._uncertain[0], target, kind, duration_s, self._uncertain[1])
        return joints

    def _queued_keywords(self, kind: MotionKind, reference: tuple[np.ndarray, np.ndarray], pose: np.ndarray,
                         joints: np.ndarray, sample: ArmSample) -> dict[str, int]:
        """The speed and acceleration ratios of a queued move: the slowest needed from anywhere it may start (the
        controller starts it where the arm is when the queue reaches it: the reference, or the target of a servo
        command still in force, or wherever the arm may be)."""
        linear = kind is MotionKind.LINEAR
        speed, accel = 100, 100
        for start_pose, start_joints in [reference] + self.stream.hull(sample):
            needed = queued_ratios(self.safety, start_pose, start_joints, pose, joints, linear,
                                   self._speed_factor_percent)
            speed, accel = min(speed, needed[0]), min(accel, needed[1])
        return {"SpeedL": speed, "AccL": accel} if linear else {"SpeedJ": speed, "AccJ": accel}

    def _cartesian(self, name: str, pose: Sequence[float], kind: MotionKind, duration_s: float | None = None,
                   command_params: Sequence[float] | None = None, **keywords: float) -> Pose:
        target = np.array(_four(pose, f"{name} target (x_mm, y_mm, z_mm, r_deg)"))
        with self._motion_lock:
            sample = self._stream_sample(self.arm_sample())
            reference = self._reference_state()
            now_s = self.clock()
            if kind is MotionKind.SERVO:
                assert duration_s is not None
                if self.safety.config.servo_over_limit == "clamp":
                    self.safety.check_target(target, target, MotionKind.JOINT)  # reach and workspace: never clamped
                    target = self.stream.clamp_servo_pose(
                        now_s, target, duration_s, sample,
                        lambda candidate: self._check_cartesian(candidate, kind, duration_s, reference))
                joints = self._check_cartesian(target, kind, duration_s, reference)
                self._check_stream_servo(now_s, target, joints, duration_s, sample)
            else:
                joints = self._check_cartesian(target, kind, duration_s, reference)
                keywords = {**keywords, **self._queued_keywords(kind, reference, target, joints, sample)}
            params = target if command_params is None else command_params
            self.stream.record(now_s, target, joints, duration_s, sample)
            self._send_motion(format_command(name, *params, **keywords), target, joints)
        return tuple(float(v) for v in target)  # type: ignore[return-value]

    def _check_stream_servo(self, now_s: float, pose: np.ndarray, joints: np.ndarray, duration_s: float,
                            sample: ArmSample) -> None:
        """The stream checks of a servo command; a refusal while the newest feedback is more than
        :data:`LATE_FEEDBACK_PERIODS` feedback periods old is reported as stale feedback (the stream could not place
        the arm because the feedback stalled), not as the motion asking too much."""
        try:
            self.stream.check_servo(now_s, pose, joints, duration_s, sample)
        except SafetyError as error:
            age_s = now_s - sample.time_s
            if self._feedback is not None and age_s > LATE_FEEDBACK_PERIODS * FEEDBACK_PERIOD_S:
                raise MotionRefusedError(StopReason.STALE_FEEDBACK,
                                         f"MG400 at {self.config.host}: feedback {age_s:.3f} s old, the stream cannot "
                                         f"place the arm: {error}") from error
            raise

    def _joint(self, name: str, joints_deg: Sequence[float], kind: MotionKind, duration_s: float | None = None,
               **keywords: float) -> None:
        target = np.array(_four(joints_deg, f"{name} target (J1, J2, J3, J4) deg"))
        with self._motion_lock:
            sample = self._stream_sample(self.arm_sample())
            current_pose, current_joints = reference = self._reference_state()
            now_s = self.clock()
            pose = np.array(self.safety.check_joint_target(current_joints, target, kind, duration_s, current_pose))
            if self._uncertain is not None:
                self.safety.check_joint_target(self._uncertain[1], target, kind, duration_s, self._uncertain[0])
            if kind is MotionKind.SERVO:
                assert duration_s is not None
                self._check_stream_servo(now_s, pose, target, duration_s, sample)
            else:
                keywords = {**keywords, **self._queued_keywords(MotionKind.JOINT, reference, pose, target, sample)}
            self.stream.record(now_s, pose, target, duration_s, sample)
            self._send_motion(format_command(name, *target, **keywords), pose, target)

    def mov_j(self, x_mm: float, y_mm: float, z_mm: float, r_deg: float) -> None:
        """Queue ``MovJ`` (joint-space move to a Cartesian pose)."""
        self._cartesian("MovJ", (x_mm, y_mm, z_mm, r_deg), MotionKind.JOINT)

    def mov_l(self, x_mm: float, y_mm: float, z_mm: float, r_deg: float) -> None:
        """Queue ``MovL`` (straight-line move)."""
        self._cartesian("MovL", (x_mm, y_mm, z_mm, r_deg), MotionKind.LINEAR)

    def joint_mov_j(self, j1_deg: float, j2_deg: float, j3_deg: float, j4_deg: float) -> None:
        """Queue ``JointMovJ`` to joint angles, deg."""
        self._joint("JointMovJ", (j1_deg, j2_deg, j3_deg, j4_deg), MotionKind.JOINT)

    def rel_mov_l(self, dx_mm: float, dy_mm: float, dz_mm: float, dr_deg: float) -> None:
        """Queue ``RelMovL``: a straight-line move by offsets from the current target (the last target sent, or
        the measured pose)."""
        self._relative("RelMovL", (dx_mm, dy_mm, dz_mm, dr_deg), MotionKind.LINEAR)

    def rel_mov_j(self, dx_mm: float, dy_mm: float, dz_mm: float, dr_deg: float) -> None:
        """Queue ``RelMovJ``: a joint-space move by Cartesian offsets from the current target."""
        self._relative("RelMovJ", (dx_mm, dy_mm, dz_mm, dr_deg), MotionKind.JOINT)

    def _relative(self, name: str, offsets: Sequence[float], kind: MotionKind) -> None:
        delta = np.array(_four(offsets, f"{name} offsets (dx_mm, dy_mm, dz_mm, dr_deg)"))
        with self._motion_lock:
            self.arm_sample()  # refuse before measuring on stale feedback or in error mode
            current_pose, _ = self._reference_state()
            self._cartesian(name, current_pose + delta, kind, command_params=delta)

    def servo_p(self, x_mm: float, y_mm: float, z_mm: float, r_deg: float, t_s: float = 0.1) -> Pose:
        """``ServoP``: replace the servo target with a pose, reached in ``t_s`` (0.004..3600 s).

        Returns:
            The pose sent: the one asked for, or with ``SafetyConfig.servo_over_limit = "clamp"`` the point toward
            it that keeps the stream within its limits.
        """
        self._servo_time(t_s)
        return self._cartesian("ServoP", (x_mm, y_mm, z_mm, r_deg), MotionKind.SERVO, t_s, t=t_s)

    def servo_j(self, j1_deg: float, j2_deg: float, j3_deg: float, j4_deg: float, t_s: float = 0.1) -> None:
        """``ServoJ``: replace the servo target with joint angles, reached in ``t_s`` (0.004..3600 s)."""
        self._servo_time(t_s)
        self._joint("ServoJ", (j1_deg, j2_deg, j3_deg, j4_deg), MotionKind.SERVO, t_s, t=t_s)

    @staticmethod
    def _servo_time(t_s: float) -> None:
        if not (math.isfinite(t_s) and SERVO_TIME_RANGE_S[0] <= t_s <= SERVO_TIME_RANGE_S[1]):
            raise ValueError(f"servo time t_s must be in {list(SERVO_TIME_RANGE_S)} s, got {t_s!r}")

    def sync(self, timeout_s: float | None = None) -> None:
        """``Sync()``: wait until the motion queue is empty (default ``config.sync_timeout_s``)."""
        if self.safety.dry_run:
            logger.info("dry run: not sending Sync()")
            return
        self._request("motion", format_command("Sync"), self.config.sync_timeout_s if timeout_s is None else timeout_s)


@dataclass(frozen=True)
class ServoStreamConfig:
    """Servo streaming settings.

    Attributes:
        period_s: time between ServoP commands, s.
        margin_s: added to the period for each command's ``t`` so the robot never idles between targets, s.
        max_step_mm: translation per command toward the goal, mm (keep within the safety layer's max_step_mm).
        max_step_deg: R change per command toward the goal, deg.
    """

    period_s: float = 0.05
    margin_s: float = 0.02
    max_step_mm: float = 2.0
    max_step_deg: float = 1.0

    def __post_init__(self) -> None:
        for name in ("period_s", "max_step_mm", "max_step_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"ServoStreamConfig.{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.margin_s) and self.margin_s >= 0.0):
            raise ValueError(f"ServoStreamConfig.margin_s must be finite and >= 0 s, got {self.margin_s!r}")
        if not SERVO_TIME_RANGE_S[0] <= self.t_s <= SERVO_TIME_RANGE_S[1]:
            raise ValueError(f"ServoStreamConfig period_s + margin_s = {self.t_s:g} s must be in "
                             f"{list(SERVO_TIME_RANGE_S)} s")

    @property
    def t_s(self) -> float:
        """The ``t`` of each ServoP: period + margin, s."""
        return self.period_s + self.margin_s


class ServoStreamer:
    """Sends ``ServoP`` at a fixed period toward the newest goal, in bounded steps, never queueing.

    Only the newest goal is kept; each tick sends at most one command (waiting for its reply), and ticks missed
    because a reply was slow are skipped, not caught up. The first command starts from the measured pose. Any
    error (safety refusal, MG400 error, lost connection) stops streaming; it is re-raised by :meth:`set_goal` and
    available as :attr:`error`.
    """

    def __init__(self, client: MG400Client, config: ServoStreamConfig | None = None) -> None:
        self.client = client
        self.config = config if config is not None else ServoStreamConfig()
        self._lock = threading.Lock()
        self._goal: np.ndarray | None = None
        self._commanded: np.ndarray | None = None
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.commands_sent = 0

    def start(self) -> ServoStreamer:
        """Start streaming from the measured pose, once the robot's joints and pose agree.

        Raises:
            FeedbackMismatchError: they do not (nothing is sent).
        """
        if self._thread is not None:
            raise RuntimeError("ServoStreamer already started")
        self.client.reset_reference()
        self._commanded = self.client.measured_state()[0]
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="mg400-servo", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop sending (the robot finishes the last target within its ``t``)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def __enter__(self) -> ServoStreamer:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def error(self) -> BaseException | None:
        """The error that stopped streaming, if any."""
        with self._lock:
            return self._error

    @property
    def running(self) -> bool:
        """True while the streaming thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def commanded_pose(self) -> Pose | None:
        """The last pose sent (or the start pose)."""
        with self._lock:
            return None if self._commanded is None else tuple(self._commanded)  # type: ignore[return-value]

    @property
    def at_goal(self) -> bool:
        """True when the last pose sent is the goal."""
        with self._lock:
            return self._goal is not None and self._commanded is not None and bool(
                np.allclose(self._goal, self._commanded))

    def set_goal(self, pose: Sequence[float]) -> None:
        """Replace the goal ``(x_mm, y_mm, z_mm, r_deg)``; raises the error that stopped streaming, if any."""
        goal = np.array(_four(pose, "servo goal (x_mm, y_mm, z_mm, r_deg)"))
        with self._lock:
            if self._error is not None:
                raise self._error
            self._goal = goal

    def _next_pose(self, current: np.ndarray, goal: np.ndarray) -> np.ndarray:
        delta = goal - current
        delta[3] = wrap_deg(delta[3])
        distance_mm = float(np.linalg.norm(delta[:3]))
        if distance_mm > self.config.max_step_mm:
            delta[:3] *= self.config.max_step_mm / distance_mm
        delta[3] = float(np.clip(delta[3], -self.config.max_step_deg, self.config.max_step_deg))
        nxt = current + delta
        if np.allclose(nxt[:3], goal[:3], atol=1e-9) and abs(wrap_deg(goal[3] - nxt[3])) < 1e-9:
            return goal.copy()
        return nxt

    def _run(self) -> None:
        period_s = self.config.period_s
        next_tick = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                goal, current = self._goal, self._commanded
            if goal is not None and current is not None and not np.array_equal(goal, current):
                pose = self._next_pose(current, goal)
                try:
                    self.client.servo_p(*pose, t_s=self.config.t_s)
                except BaseException as error:  # noqa: BLE001 - any failure must stop the stream
                    logger.error("servo streaming stopped: %s", error)
                    with self._lock:
                        self._error = error
                    return
                with self._lock:
                    self._commanded = pose
                self.commands_sent += 1
            next_tick += period_s
            delay_s = next_tick - time.monotonic()
            if delay_s < 0.0:
                next_tick = time.monotonic()  # late: skip the missed ticks instead of bursting
                delay_s = 0.0
            self._stop.wait(delay_s)
