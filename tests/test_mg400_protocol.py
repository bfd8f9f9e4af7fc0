"""MG400 protocol: command formatting, reply parsing and splitting, error ids, the feedback packet."""

from __future__ import annotations

import struct

import pytest

from simshear_gym.robots.mg400.protocol import (
    ALARMS,
    FEEDBACK_PACKET_BYTES,
    CommandBuffer,
    FeedbackBuffer,
    FeedbackError,
    MG400Feedback,
    ProtocolError,
    Reply,
    ReplyBuffer,
    RobotMode,
    describe_alarm,
    describe_error_id,
    format_command,
    format_number,
    format_reply,
    pack_feedback,
    parse_command,
    parse_feedback,
    parse_reply,
)

# ---------------------------------------------------------------------------------------------------------------
# Formatting


def test_format_command_servo_p():
    assert format_command("ServoP", 300.0, 0.0, 50.0, 0.0, t=0.05) == "ServoP(300,0,50,0,t=0.05)"


@pytest.mark.parametrize("value, text", [
    (0.0, "0"), (-0.0, "0"), (-1e-9, "0"), (-4e-7, "0"), (1.5, "1.5"), (-2.25, "-2.25"), (300, "300"),
    (-12, "-12"), (1.0 / 3.0, "0.333333"), (123.4567891, "123.456789"), (-0.0000006, "-0.000001"), (1e6, "1000000"),
])
def test_format_number(value, text):
    assert format_number(value) == text


def test_format_never_writes_negative_zero():
    text = format_command("MovL", -0.0, -1e-12, -0.0000004, 0.0)
    assert text == "MovL(0,0,0,0)" and "-0" not in text


def test_format_command_without_parameters_and_with_ints():
    assert format_command("EnableRobot") == "EnableRobot()"
    assert format_command("SpeedFactor", 50) == "SpeedFactor(50)"


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), True, "1", None])
def test_format_refuses_bad_parameters(bad):
    with pytest.raises(ProtocolError, match="parameter"):
        format_command("MovJ", bad, 0, 0, 0)


def test_format_refuses_bad_names():
    with pytest.raises(ProtocolError, match="letters and digits"):
        format_command("Mov J")


def test_parse_command_with_keywords():
    cmd = parse_command(" ServoP(300, 0,50,0,t=0.05)\r\n")
    assert cmd.name == "ServoP" and cmd.args == ("300", "0", "50", "0") and cmd.keywords == (("t", "0.05"),)
    assert parse_command("RobotMode()").args == ()
    with pytest.raises(ProtocolError, match="Name"):
        parse_command("nonsense")


def test_command_buffer_splits_merged_and_straddling_commands():
    buffer = CommandBuffer()
    assert buffer.feed(b"EnableRobot()\r\nRobotMode()\nMovJ(1,") == ["EnableRobot()", "RobotMode()"]
    assert buffer.feed(b"2,3,4)") == ["MovJ(1,2,3,4)"]
    assert buffer.feed(b"") == []


# ---------------------------------------------------------------------------------------------------------------
# Replies


def test_parse_simple_replies():
    assert parse_reply("0,{},EnableRobot();") == Reply(0, (), "EnableRobot()")
    reply = parse_reply("0,{5},RobotMode();")
    assert reply.values == (5,) and reply.ok and reply.command_name == "RobotMode"
    failed = parse_reply("-40001,{},SpeedFactor(150);")
    assert failed.error_id == -40001 and not failed.ok


def test_parse_get_pose_with_six_numbers_and_a_word():
    reply = parse_reply("0,{300.000000,-0.000000,50.5,0.000000,0.000000,0.000000},GetPose();")
    assert reply.values == (300.0, 0.0, 50.5, 0.0, 0.0, 0.0)
    assert reply.numbers()[:4] == (300.0, 0.0, 50.5, 0.0)
    assert parse_reply("0,{1,2,3,4,user},GetPose();").numbers() == (1.0, 2.0, 3.0, 4.0)


def test_parse_nested_get_error_id():
    reply = parse_reply("0,{[[18, 23],[],[1],[],[],[],[]]},GetErrorID();")
    assert reply.values == (((18, 23), (), (1,), (), (), (), ()),)
    assert parse_reply("0,{[[],[],[],[],[],[],[]]},GetErrorID()").values == (((),) * 7,)


def test_parse_reply_echoing_a_command_with_commas():
    reply = parse_reply("0,{},MovJ(300,0,50,0);")
    assert reply.command == "MovJ(300,0,50,0)" and reply.command_name == "MovJ"


@pytest.mark.parametrize("bad, match", [
    ("ok,{},EnableRobot();", "integer ErrorID"),
    ("0,EnableRobot();", "ErrorID,{values},Command"),
    ("0,{1,2,EnableRobot();", "closing"),
    ("0,{1,,2},A();", "unexpected ','"),
    ("0,{[1,2},A();", "unclosed"),
    ("0,{1]},A();", "expected ','"),
    ("0,{1}A();", "',Command'"),
])
def test_parse_reply_refuses_malformed_text(bad, match):
    with pytest.raises(ProtocolError, match=match):
        parse_reply(bad)


def test_format_reply_round_trip():
    values = (((18,), (), (), (), (), (), ()),)
    text = format_reply(0, values, "GetErrorID()")
    assert text == "0,{[[18],[],[],[],[],[],[]]},GetErrorID();"
    assert parse_reply(text).values == values
    assert format_reply(0, (-0.0, 1.5), "GetPose()") == "0,{0,1.5},GetPose();"


def test_reply_buffer_reassembles_replies_split_byte_by_byte():
    stream = b"0,{},EnableRobot();0,{[[],[18]]},GetErrorID();"
    buffer = ReplyBuffer()
    replies: list[str] = []
    for i in range(len(stream)):
        replies += buffer.feed(stream[i:i + 1])
    assert replies == ["0,{},EnableRobot()", "0,{[[],[18]]},GetErrorID()"]
    assert buffer.pending_bytes == 0


def test_reply_buffer_splits_several_replies_in_one_segment():
    buffer = ReplyBuffer()
    assert buffer.feed(b"0,{},A();\r\n-1,{},B();0,{5},Rob") == ["0,{},A()", "-1,{},B()"]
    assert buffer.pending_bytes > 0
    assert buffer.feed(b"otMode();") == ["0,{5},RobotMode()"]


def test_reply_buffer_limits_garbage():
    buffer = ReplyBuffer(max_pending_bytes=16)
    with pytest.raises(ProtocolError, match="without a ';'"):
        buffer.feed(b"x" * 32)


# ---------------------------------------------------------------------------------------------------------------
# Error ids, modes, alarms


@pytest.mark.parametrize("error_id, text", [
    (0, "no error"), (-1, "command failed"), (-10000, "unknown command"), (-20000, "wrong number of parameters"),
    (-30001, "parameter 1 has the wrong type"), (-30004, "parameter 4 has the wrong type"),
    (-40001, "parameter 1 is out of range"), (-40005, "parameter 5 is out of range"), (-7, "unrecognised ErrorID -7"),
])
def test_describe_error_id(error_id, text):
    assert describe_error_id(error_id).startswith(text)


def test_robot_modes_and_alarms():
    assert RobotMode(5) is RobotMode.ENABLED and RobotMode.ERROR == 9 and RobotMode.JOG == 11
    assert describe_alarm(18) == "joint limit" and describe_alarm(23) == "out of working area"
    assert describe_alarm(12294).startswith("collision") and ALARMS[66] == "joint limit exceeded"
    assert "see the Dobot alarm table" in describe_alarm(999)


# ---------------------------------------------------------------------------------------------------------------
# Feedback packet


def sample_feedback(mode: int = 7, stamp_ms: int = 123456) -> MG400Feedback:
    return MG400Feedback(robot_mode=mode, time_stamp_ms=stamp_ms, q_target_deg=(1.0, 2.0, 3.0, 4.0),
                         q_actual_deg=(1.5, 2.5, 3.5, 4.5), tool_vector_actual=(300.0, -1.0, 50.0, 10.0),
                         tool_vector_target=(301.0, -2.0, 51.0, 11.0), speed_scaling=0.5, enable_status=True,
                         error_status=False, run_queued_command=True, digital_inputs=5, digital_outputs=3)


def test_feedback_pack_parse_round_trip():
    feedback = sample_feedback()
    packet = pack_feedback(feedback)
    assert len(packet) == FEEDBACK_PACKET_BYTES
    parsed = parse_feedback(packet)
    assert parsed == feedback
    assert parsed.mode is RobotMode.RUNNING and parsed.robot_type == 1
    assert parsed.quaternion_actual[0] == pytest.approx(0.9961947)  # cos(5 deg), about z


def test_feedback_offsets_follow_the_doc():
    packet = pack_feedback(sample_feedback())
    assert struct.unpack_from("<H", packet, 0)[0] == 1440
    assert struct.unpack_from("<q", packet, 24)[0] == 7
    assert struct.unpack_from("<q", packet, 32)[0] == 123456
    assert struct.unpack_from("<Q", packet, 48)[0] == 0x0123456789ABCDEF
    assert struct.unpack_from("<4d", packet, 432) == (1.5, 2.5, 3.5, 4.5)
    assert struct.unpack_from("<4d", packet, 624) == (300.0, -1.0, 50.0, 10.0)
    assert packet[1026] == 1 and packet[1029] == 0 and packet[1031] == 1 and packet[1014] == 1


def test_parse_feedback_refuses_wrong_size_length_field_and_test_value():
    packet = bytearray(pack_feedback(sample_feedback()))
    with pytest.raises(FeedbackError, match="must be 1440 bytes, got 1439"):
        parse_feedback(packet[:-1])
    bad_length = bytearray(packet)
    struct.pack_into("<H", bad_length, 0, 1439)
    with pytest.raises(FeedbackError, match="length field is 1439, expected 1440"):
        parse_feedback(bad_length)
    bad_test = bytearray(packet)
    struct.pack_into("<Q", bad_test, 48, 42)
    with pytest.raises(FeedbackError, match="test value .* expected 0x0123456789abcdef"):
        parse_feedback(bad_test)


def test_feedback_buffer_resynchronises_after_bad_and_partial_packets():
    good = [pack_feedback(sample_feedback(stamp_ms=i)) for i in range(4)]
    corrupt = bytearray(good[0])
    struct.pack_into("<Q", corrupt, 48, 0)
    bad_length = bytearray(good[0])
    struct.pack_into("<H", bad_length, 0, 1000)
    stream = good[0] + bytes(corrupt) + good[1] + good[2][:700] + good[2] + bytes(bad_length) + good[3]
    buffer = FeedbackBuffer()
    packets, reasons = [], []
    for start in range(0, len(stream), 333):  # arbitrary TCP segmentation
        p, r = buffer.feed(stream[start:start + 333])
        packets += p
        reasons += r
    assert [p.time_stamp_ms for p in packets] == [0, 1, 2, 3]
    assert buffer.rejected == len(reasons) >= 3
    assert any("truncated" in r for r in reasons)
