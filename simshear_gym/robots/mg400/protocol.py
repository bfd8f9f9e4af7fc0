"""Dobot MG400 TCP/IP protocol (controller V1.6): messages, replies, error ids and the 30004 feedback packet.

No sockets here: this module turns values into bytes and bytes into values, for both the client and the
loopback emulator.

Messages are ASCII ``Name(p1,...,pn)``; replies are ``ErrorID,{v1,...},Name(p1,...,pn);``. Numbers are written
with :data:`NUMBER_DECIMALS` decimals, trailing zeros stripped, and negative zero normalised to ``0``.
"""

from __future__ import annotations

import enum
import math
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

DASHBOARD_PORT = 29999
MOTION_PORT = 30003
FEEDBACK_PORT = 30004
FEEDBACK_PERIOD_S = 0.008
SERVO_TIME_RANGE_S = (0.004, 3600.0)  # the controller's accepted range of ServoP's / ServoJ's t, s
NUMBER_DECIMALS = 6

FEEDBACK_PACKET_BYTES = 1440
FEEDBACK_TEST_VALUE = 0x0123456789ABCDEF


class ProtocolError(ValueError):
    """A message or reply does not follow the protocol."""


class FeedbackError(ProtocolError):
    """A 30004 feedback packet failed validation (size, length field or test value)."""


# ----------------------------------------------------------------------------------------------------------------
# Numbers and commands


def format_number(value: float | int, decimals: int = NUMBER_DECIMALS) -> str:
    """Format a number for a command: ints as ints, floats with ``decimals`` decimals, trailing zeros stripped.

    ``-0.0`` and values that round to zero become ``"0"``; never ``"-0.000000"``.

    Raises:
        ProtocolError: for bools, non-numbers and non-finite floats.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"a command parameter must be an int or float, got {value!r} ({type(value).__name__})")
    if isinstance(value, int):
        return str(value)
    if not math.isfinite(value):
        raise ProtocolError(f"a command parameter must be finite, got {value!r}")
    text = f"{value:.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    if text in ("-0", ""):
        text = "0"
    return text


def format_command(name: str, *params: float | int, decimals: int = NUMBER_DECIMALS, **keywords: float | int) -> str:
    """Format a command, e.g. ``format_command("ServoP", 300.0, 0.0, 50.0, 0.0, t=0.05)``
    -> ``"ServoP(300,0,50,0,t=0.05)"``.

    Args:
        name: command name (letters and digits).
        params: positional numeric parameters, in protocol units (mm, deg, s).
        decimals: decimals before trailing zeros are stripped.
        keywords: ``key=value`` numeric parameters, written after the positional ones.
    """
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9]*", name):
        raise ProtocolError(f"command name must be letters and digits, got {name!r}")
    parts = [format_number(p, decimals) for p in params]
    for key, value in keywords.items():
        parts.append(f"{key}={format_number(value, decimals)}")
    return f"{name}({','.join(parts)})"


@dataclass(frozen=True)
class ParsedCommand:
    """A received command, split but not interpreted (the emulator checks types per command).

    Attributes:
        name: the command name as sent.
        args: positional parameter texts.
        keywords: ``(key, value text)`` pairs for ``key=value`` parameters, in order.
        text: the whole command text, stripped.
    """

    name: str
    args: tuple[str, ...]
    keywords: tuple[tuple[str, str], ...]
    text: str


def parse_command(text: str) -> ParsedCommand:
    """Parse ``Name(p1,...,k=v)``.

    Raises:
        ProtocolError: when the text is not of that form.
    """
    stripped = text.strip()
    match = re.fullmatch(r"([A-Za-z][A-Za-z0-9]*)\s*\((.*)\)", stripped, flags=re.DOTALL)
    if match is None:
        raise ProtocolError(f"expected a command like Name(p1,...), got {stripped!r}")
    body = match.group(2).strip()
    args: list[str] = []
    keywords: list[tuple[str, str]] = []
    if body:
        for part in (p.strip() for p in body.split(",")):
            if "=" in part:
                key, _, value = part.partition("=")
                keywords.append((key.strip(), value.strip()))
            elif keywords:
                raise ProtocolError(f"positional parameter {part!r} after a keyword parameter in {stripped!r}")
            else:
                args.append(part)
    return ParsedCommand(name=match.group(1), args=tuple(args), keywords=tuple(keywords), text=stripped)


class _DelimitedBuffer:
    """Splits a received byte stream into texts ending at ``delimiter`` (texts may share or straddle segments)."""

    delimiter: bytes = b";"
    keep_delimiter: bool = False
    skip_between: bytes = b""  # bytes dropped between texts
    what: str = "text"

    def __init__(self, max_pending_bytes: int = 65536) -> None:
        self._pending = b""
        self._max_pending_bytes = max_pending_bytes

    def feed(self, data: bytes) -> list[str]:
        """Add received bytes; return the complete texts (stripped), oldest first."""
        self._pending += data
        texts: list[str] = []
        while True:
            end = self._pending.find(self.delimiter)
            if end < 0:
                break
            cut = end + len(self.delimiter)
            chunk = self._pending[:cut] if self.keep_delimiter else self._pending[:end]
            self._pending = self._pending[cut:]
            text = chunk.decode("ascii", errors="replace").strip()
            if text:
                texts.append(text)
        self._pending = self._pending.lstrip(self.skip_between)
        if len(self._pending) > self._max_pending_bytes:
            raise ProtocolError(
                f"more than {self._max_pending_bytes} bytes received without a {self.delimiter.decode()!r}"
            )
        return texts

    @property
    def pending_bytes(self) -> int:
        """Bytes received that do not yet form a complete text."""
        return len(self._pending)


class CommandBuffer(_DelimitedBuffer):
    """Splits a received byte stream into command texts at ``)``, keeping the ``)``."""

    delimiter = b")"
    keep_delimiter = True
    skip_between = b" \r\n\t;"


# ----------------------------------------------------------------------------------------------------------------
# Replies

Value = int | float | str | tuple["Value", ...]


@dataclass(frozen=True)
class Reply:
    """One reply ``ErrorID,{values},Command;``.

    Attributes:
        error_id: 0 ok, negative for a protocol error (see :func:`describe_error_id`).
        values: the returned values; nested lists (``GetErrorID``) become nested tuples, non-numbers stay text.
        command: the echoed command text (may be empty on firmware that omits it).
    """

    error_id: int
    values: tuple[Value, ...]
    command: str

    @property
    def ok(self) -> bool:
        """True when ``error_id == 0``."""
        return self.error_id == 0

    @property
    def command_name(self) -> str:
        """The echoed command's name, or ``""``."""
        match = re.match(r"\s*([A-Za-z][A-Za-z0-9]*)", self.command)
        return match.group(1) if match else ""

    def numbers(self) -> tuple[float, ...]:
        """The leading flat numeric values as floats (stops at the first non-number)."""
        out: list[float] = []
        for value in self.values:
            if isinstance(value, (int, float)):
                out.append(float(value))
            else:
                break
        return tuple(out)


def _parse_scalar(token: str) -> int | float | str:
    token = token.strip()
    try:
        return int(token)
    except ValueError:
        pass
    try:
        number = float(token)
    except ValueError:
        return token
    return 0.0 if number == 0.0 else number  # normalise -0.0


def _parse_values(text: str) -> tuple[Value, ...]:
    """Parse the inside of ``{...}``: comma-separated scalars and ``[...]`` lists, nested."""
    tokens = [t.strip() for t in re.findall(r"\[|\]|,|[^\[\],]+", text)]
    tokens = [t for t in tokens if t]
    position = 0

    def fail(what: str) -> ProtocolError:
        return ProtocolError(f"{what} in reply values {{{text}}}")

    def parse_sequence(closing: str | None) -> tuple[Value, ...]:
        nonlocal position
        items: list[Value] = []
        if (position < len(tokens) and tokens[position] == closing) or (closing is None and position == len(tokens)):
            position += closing is not None
            return ()
        while True:
            if position >= len(tokens):
                raise fail("missing value")
            token = tokens[position]
            position += 1
            if token == "[":
                items.append(parse_sequence("]"))
            elif token in (",", "]"):
                raise fail(f"unexpected {token!r}")
            else:
                items.append(_parse_scalar(token))
            if position >= len(tokens):
                if closing is None:
                    return tuple(items)
                raise fail("unclosed '['")
            separator = tokens[position]
            position += 1
            if separator == closing:
                return tuple(items)
            if separator != ",":
                raise fail(f"expected ',' or {closing or 'the end'!r}, got {separator!r}")

    values = parse_sequence(None)
    if position != len(tokens):
        raise fail("unbalanced ']'")
    return values


def parse_reply(text: str) -> Reply:
    """Parse ``ErrorID,{v1,...},Command(...)`` (with or without the final ``;``).

    Raises:
        ProtocolError: naming what was expected.
    """
    stripped = text.strip()
    if stripped.endswith(";"):
        stripped = stripped[:-1].rstrip()
    head, sep, rest = stripped.partition(",")
    try:
        error_id = int(head.strip())
    except ValueError:
        raise ProtocolError(f"reply must start with an integer ErrorID, got {text.strip()!r}") from None
    rest = rest.strip()
    if not sep or not rest.startswith("{"):
        raise ProtocolError(f"reply must be 'ErrorID,{{values}},Command;', got {text.strip()!r}")
    depth = 0
    close = -1
    for index, char in enumerate(rest):
        if char == "{":
            depth += 1
        elif char == "}":
            depth -= 1
            if depth == 0:
                close = index
                break
    if close < 0:
        raise ProtocolError(f"reply values are missing their closing '}}': {text.strip()!r}")
    values = _parse_values(rest[1:close])
    tail = rest[close + 1:].strip()
    if tail.startswith(","):
        tail = tail[1:].strip()
    elif tail:
        raise ProtocolError(f"expected ',Command' after the reply values, got {tail!r}")
    return Reply(error_id=error_id, values=values, command=tail)


def format_reply(error_id: int, values: Sequence[Value], command: str, decimals: int = NUMBER_DECIMALS) -> str:
    """Format a reply ``ErrorID,{values},Command;`` (used by the emulator); nested sequences become ``[...]``."""

    def one(value: Value) -> str:
        if isinstance(value, (tuple, list)):
            return "[" + ",".join(one(v) for v in value) + "]"
        if isinstance(value, str):
            return value
        return format_number(value, decimals)

    return f"{int(error_id)},{{{','.join(one(v) for v in values)}}},{command};"


class ReplyBuffer(_DelimitedBuffer):
    """Splits a received byte stream into replies at ``;`` (without the ``;``)."""

    delimiter = b";"


# ----------------------------------------------------------------------------------------------------------------
# Error ids, robot modes, alarms

ERROR_OK = 0
ERROR_FAILED = -1
ERROR_UNKNOWN_COMMAND = -10000
ERROR_PARAMETER_COUNT = -20000
ERROR_PARAMETER_TYPE_BASE = -30000
ERROR_PARAMETER_RANGE_BASE = -40000


def parameter_type_error(parameter: int) -> int:
    """ErrorID for 'parameter ``parameter`` (1-based) has the wrong type'."""
    return ERROR_PARAMETER_TYPE_BASE - int(parameter)


def parameter_range_error(parameter: int) -> int:
    """ErrorID for 'parameter ``parameter`` (1-based) is out of range'."""
    return ERROR_PARAMETER_RANGE_BASE - int(parameter)


def describe_error_id(error_id: int) -> str:
    """A readable message for a reply ErrorID."""
    if error_id == ERROR_OK:
        return "no error"
    if error_id == ERROR_FAILED:
        return "command failed (robot not enabled, in error mode, or the target was refused; see GetErrorID)"
    if error_id == ERROR_UNKNOWN_COMMAND:
        return "unknown command"
    if error_id == ERROR_PARAMETER_COUNT:
        return "wrong number of parameters"
    if ERROR_PARAMETER_RANGE_BASE > error_id > ERROR_PARAMETER_RANGE_BASE - 10000:
        return f"parameter {ERROR_PARAMETER_RANGE_BASE - error_id} is out of range"
    if ERROR_PARAMETER_TYPE_BASE > error_id > ERROR_PARAMETER_RANGE_BASE:
        return f"parameter {ERROR_PARAMETER_TYPE_BASE - error_id} has the wrong type"
    return f"unrecognised ErrorID {error_id}"


class RobotMode(enum.IntEnum):
    """``RobotMode()`` values and the feedback packet's robot-mode field."""

    INIT = 1
    BRAKE_OPEN = 2
    POWER_OFF = 3
    DISABLED = 4
    ENABLED = 5
    DRAG = 6
    RUNNING = 7
    RECORDING = 8
    ERROR = 9
    PAUSED = 10
    JOG = 11


ALARM_IK_SINGULAR = 16
ALARM_IK_NO_SOLUTION = 17
ALARM_JOINT_LIMIT = 18
ALARM_OUT_OF_WORKSPACE = 23
ALARM_OVERSPEED = 48  # J1 overspeed; 49..51 are J2..J4
ALARM_COLLISION = 112

ALARMS: dict[int, str] = {
    16: "inverse kinematics singular",
    17: "inverse kinematics has no solution",
    18: "joint limit",
    23: "out of working area",
    **{i: "overspeed" for i in range(48, 52)},
    **{i: "joint limit exceeded" for i in range(64, 72)},
    72: "parallelogram limit",
    73: "parallelogram limit",
    112: "collision detected",
    12294: "collision detected",
}


def describe_alarm(alarm_id: int) -> str:
    """A readable name for a controller/servo alarm id from ``GetErrorID``."""
    return ALARMS.get(int(alarm_id), f"alarm {int(alarm_id)} (see the Dobot alarm table)")


# ----------------------------------------------------------------------------------------------------------------
# Feedback packet (port 30004)

_OFFSET_SIZE = 0
_OFFSET_TEST_VALUE = 48

# The packet's fields this project uses, as (MG400Feedback attribute, struct format, byte offset): the one layout
# pack_feedback writes and parse_feedback reads. A 4-vector is the first 4 of 6 doubles (the other two stay zero).
_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("digital_inputs", "<q", 8),
    ("digital_outputs", "<q", 16),
    ("robot_mode", "<q", 24),
    ("time_stamp_ms", "<q", 32),
    ("speed_scaling", "<d", 64),
    ("q_target_deg", "<4d", 192),
    ("q_actual_deg", "<4d", 432),
    ("tool_vector_actual", "<4d", 624),
    ("tool_vector_target", "<4d", 768),
    ("run_queued_command", "<b", 1014),
    ("enable_status", "<b", 1026),
    ("error_status", "<b", 1029),
    ("robot_type", "<b", 1031),
    ("quaternion_target", "<4d", 1352),
    ("quaternion_actual", "<4d", 1384),
)
_FLAGS: tuple[str, ...] = ("run_queued_command", "enable_status", "error_status")  # bools, a byte each on the wire

#: The test value's bytes, used to find packet boundaries again after a corrupt or partial packet.
FEEDBACK_TEST_BYTES = struct.pack("<Q", FEEDBACK_TEST_VALUE)
FEEDBACK_SIZE_BYTES = struct.pack("<H", FEEDBACK_PACKET_BYTES)
FEEDBACK_TEST_OFFSET = _OFFSET_TEST_VALUE

ROBOT_TYPE_MG400 = 1

Vec4 = tuple[float, float, float, float]


def _vec4(values: Sequence[float], name: str) -> Vec4:
    if len(values) != 4:
        raise ValueError(f"{name} must have 4 values, got {len(values)}")
    return tuple(float(v) for v in values)  # type: ignore[return-value]


def _quaternion_about_z(r_deg: float) -> Vec4:
    half = math.radians(r_deg) / 2.0
    return (math.cos(half), 0.0, 0.0, math.sin(half))


@dataclass(frozen=True)
class MG400Feedback:
    """The fields of one 30004 feedback packet used by this project (only J1..J4 and X, Y, Z, R are kept).

    Attributes:
        robot_mode: :class:`RobotMode` value (an int; see :attr:`mode`).
        time_stamp_ms: controller time stamp, ms.
        q_target_deg, q_actual_deg: ``(J1, J2, J3, J4)``, deg.
        tool_vector_actual, tool_vector_target: ``(x_mm, y_mm, z_mm, r_deg)``.
        speed_scaling: speed scaling factor.
        enable_status, error_status, run_queued_command: flags.
        robot_type: 1 for an MG400.
        digital_inputs, digital_outputs: bit fields.
        quaternion_target, quaternion_actual: ``(w, x, y, z)``; default: derived from R about z.
    """

    robot_mode: int
    time_stamp_ms: int
    q_target_deg: Vec4
    q_actual_deg: Vec4
    tool_vector_actual: Vec4
    tool_vector_target: Vec4
    speed_scaling: float = 1.0
    enable_status: bool = False
    error_status: bool = False
    run_queued_command: bool = False
    robot_type: int = ROBOT_TYPE_MG400
    digital_inputs: int = 0
    digital_outputs: int = 0
    quaternion_target: Vec4 | None = field(default=None)
    quaternion_actual: Vec4 | None = field(default=None)

    def __post_init__(self) -> None:
        for name in ("q_target_deg", "q_actual_deg", "tool_vector_actual", "tool_vector_target"):
            object.__setattr__(self, name, _vec4(getattr(self, name), name))
        if self.quaternion_target is None:
            object.__setattr__(self, "quaternion_target", _quaternion_about_z(self.tool_vector_target[3]))
        if self.quaternion_actual is None:
            object.__setattr__(self, "quaternion_actual", _quaternion_about_z(self.tool_vector_actual[3]))
        for name in ("quaternion_target", "quaternion_actual"):
            object.__setattr__(self, name, _vec4(getattr(self, name), name))

    @property
    def mode(self) -> RobotMode | None:
        """The robot mode as :class:`RobotMode`, or None for a value this project does not know."""
        try:
            return RobotMode(self.robot_mode)
        except ValueError:
            return None


def pack_feedback(feedback: MG400Feedback) -> bytes:
    """Build a 1440-byte feedback packet (unused bytes zero); the inverse of :func:`parse_feedback`."""
    buf = bytearray(FEEDBACK_PACKET_BYTES)
    struct.pack_into("<H", buf, _OFFSET_SIZE, FEEDBACK_PACKET_BYTES)
    struct.pack_into("<Q", buf, _OFFSET_TEST_VALUE, FEEDBACK_TEST_VALUE)
    for name, layout, offset in _FIELDS:
        value = getattr(feedback, name)
        values = value if layout == "<4d" else (int(value) if name in _FLAGS else value,)
        struct.pack_into(layout, buf, offset, *values)
    return bytes(buf)


def parse_feedback(buf: bytes | bytearray | memoryview) -> MG400Feedback:
    """Parse one 1440-byte feedback packet.

    Raises:
        FeedbackError: when the buffer is not 1440 bytes, its length field is not 1440, or its test value is not
            ``0x0123456789ABCDEF``.
    """
    data = bytes(buf)
    if len(data) != FEEDBACK_PACKET_BYTES:
        raise FeedbackError(f"feedback packet must be {FEEDBACK_PACKET_BYTES} bytes, got {len(data)}")
    (size,) = struct.unpack_from("<H", data, _OFFSET_SIZE)
    if size != FEEDBACK_PACKET_BYTES:
        raise FeedbackError(f"feedback length field is {size}, expected {FEEDBACK_PACKET_BYTES}")
    (test_value,) = struct.unpack_from("<Q", data, _OFFSET_TEST_VALUE)
    if test_value != FEEDBACK_TEST_VALUE:
        raise FeedbackError(f"feedback test value is {test_value:#018x}, expected {FEEDBACK_TEST_VALUE:#018x}")

    values: dict[str, object] = {}
    for name, layout, offset in _FIELDS:
        unpacked = struct.unpack_from(layout, data, offset)
        values[name] = unpacked if layout == "<4d" else bool(unpacked[0]) if name in _FLAGS else unpacked[0]
    return MG400Feedback(**values)  # type: ignore[arg-type]


class FeedbackBuffer:
    """Cuts a 30004 byte stream into validated packets, re-synchronising after corrupt or partial ones.

    A packet is accepted when its length field and test value are right and no other packet header starts
    inside it (which would mean it was truncated). Rejected bytes are skipped up to the next header.
    """

    def __init__(self) -> None:
        self._pending = bytearray()
        self.rejected = 0

    def feed(self, data: bytes) -> tuple[list[MG400Feedback], list[str]]:
        """Add received bytes; return ``(packets, rejection reasons)``, oldest first."""
        self._pending += data
        packets: list[MG400Feedback] = []
        reasons: list[str] = []
        n = FEEDBACK_PACKET_BYTES
        while len(self._pending) >= n:
            candidate = bytes(self._pending[:n])
            try:
                early = self._find_header(candidate, 1)
                if early is not None:
                    raise FeedbackError(f"feedback packet truncated: the next packet starts at byte {early}")
                packets.append(parse_feedback(candidate))
                del self._pending[:n]
            except FeedbackError as error:
                self.rejected += 1
                reasons.append(str(error))
                header = self._find_header(self._pending, 1)
                # Without a header in sight, keep only a tail that could still be the start of one.
                keep_from = header if header is not None else max(
                    1, len(self._pending) - FEEDBACK_TEST_OFFSET - len(FEEDBACK_TEST_BYTES) + 1)
                del self._pending[:keep_from]
        return packets, reasons

    @staticmethod
    def _find_header(data: bytes | bytearray, start: int) -> int | None:
        """Index of the first complete packet header (length field and test value) at or after ``start``."""
        position = start
        while True:
            found = data.find(FEEDBACK_TEST_BYTES, position + FEEDBACK_TEST_OFFSET)
            if found < 0:
                return None
            header = found - FEEDBACK_TEST_OFFSET
            if data[header: header + 2] == FEEDBACK_SIZE_BYTES:
                return header
            position = header + 1
