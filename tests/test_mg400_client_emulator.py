"""MG400 client against the loopback emulator (ephemeral ports on 127.0.0.1), fault injection and safety.

The emulator starts here at the arm's zero pose, the flange at (284, 0, 118). Tests of the protocol and the
emulator that make long queued moves use ``BENCH``, the safe limits with the jump of queued moves loosened by
name (:class:`UnsafeSafetyConfig`); the safe defaults themselves are tested in ``test_safety_defaults.py``.
"""

from __future__ import annotations

import argparse
import logging
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from simshear_gym.real import mg400_emulator
from simshear_gym.real.mg400_client import (
    FeedbackStaleError,
    MG400Client,
    MG400ClientConfig,
    MG400ConnectionError,
    MG400Error,
    MG400TimeoutError,
    ServoStreamConfig,
    ServoStreamer,
)
from simshear_gym.real.mg400_emulator import (
    EmulatorConfig,
    FaultConfig,
    FeedbackFault,
    MG400Emulator,
)
from simshear_gym.real.safety import (
    MotionKind,
    SafetyConfig,
    SafetyError,
    SafetyLayer,
    StatusSnapshot,
    UnsafeSafetyConfig,
)
from simshear_gym.robots.mg400.kinematics import forward
from simshear_gym.robots.mg400.protocol import RobotMode, parse_reply

FAST = dict(dashboard_port=0, motion_port=0, feedback_port=0, joint_speed_deg_s=400.0, linear_speed_mm_s=1000.0,
            initial_joints_deg=(0.0, 0.0, 0.0, 0.0))
# protocol tests with long, fast queued moves (at the emulator's full speed)
BENCH = UnsafeSafetyConfig(max_move_mm=250.0, max_move_deg=90.0, max_speed_mm_s=1000.0, max_speed_deg_s=400.0,
                           max_accel_mm_s2=10000.0, max_accel_deg_s2=4000.0)


def wait_for(predicate: Callable[[], bool], timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if predicate():
                return True
        except FeedbackStaleError:
            pass  # no packet yet
        time.sleep(0.005)
    return predicate()


@pytest.fixture
def make_emulator() -> Iterator[Callable[..., MG400Emulator]]:
    started: list[MG400Emulator] = []

    def make(faults: FaultConfig | None = None, **overrides) -> MG400Emulator:
        config = EmulatorConfig(**{**FAST, **overrides}, faults=faults or FaultConfig())
        emulator = MG400Emulator(config).start()
        started.append(emulator)
        return emulator

    yield make
    for emulator in started:
        emulator.stop()


def client_for(emulator: MG400Emulator, safety: SafetyLayer | None = None, **overrides) -> MG400Client:
    settings = dict(host="127.0.0.1", dashboard_port=emulator.dashboard_port, motion_port=emulator.motion_port,
                    feedback_port=emulator.feedback_port, connect_timeout_s=1.0, reply_timeout_s=1.0,
                    sync_timeout_s=5.0)
    config = MG400ClientConfig(**{**settings, **overrides})
    client = MG400Client(config, safety).connect()
    # the arm known still for 0.1 s: a first servo command may then ask for up to max_accel * 0.1 s of speed
    client.wait_until_still(0.1)
    return client


def raw_request(port: int, command: str) -> str:
    with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
        sock.sendall(command.encode())
        data = b""
        while not data.endswith(b";"):
            chunk = sock.recv(1024)
            if not chunk:
                break
            data += chunk
    return data.decode()


# ---------------------------------------------------------------------------------------------------------------
# Normal operation


def test_enable_disable_and_robot_modes(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        assert robot.robot_mode() is RobotMode.DISABLED
        robot.enable_robot()
        assert robot.robot_mode() is RobotMode.ENABLED
        assert wait_for(lambda: robot.latest_feedback().enable_status)
        robot.disable_robot()
        assert robot.robot_mode() is RobotMode.DISABLED
    assert not robot.connected


def test_moves_sync_and_get_pose(make_emulator):
    emulator = make_emulator()
    with client_for(emulator, SafetyLayer(BENCH)) as robot:
        robot.enable_robot()
        robot.speed_factor(100)
        robot.mov_l(300.0, 20.0, 60.0, 10.0)
        robot.mov_j(280.0, -30.0, 80.0, 0.0)
        robot.sync()
        assert robot.get_pose() == pytest.approx((280.0, -30.0, 80.0, 0.0), abs=1e-3)
        robot.joint_mov_j(10.0, 20.0, 30.0, 5.0)
        assert emulator.queue_length >= 1 or emulator.robot_mode is RobotMode.ENABLED
        robot.sync()
        assert robot.get_angle() == pytest.approx((10.0, 20.0, 30.0, 5.0), abs=1e-3)
        assert robot.robot_mode() is RobotMode.ENABLED
        feedback = robot.latest_feedback()
        assert wait_for(lambda: np.allclose(robot.latest_feedback().q_actual_deg, (10, 20, 30, 5)))
        assert feedback.robot_type == 1
    # queued moves carry the speed and acceleration ratios that keep them within the limits (here BENCH's)
    assert [c.split(",S")[0] for c in emulator.received_commands("motion")[:2]] == ["MovL(300,20,60,10",
                                                                                   "MovJ(280,-30,80,0"]
    assert all("SpeedL=" in c and "AccL=" in c for c in emulator.received_commands("motion")[:1])


@pytest.mark.parametrize("count", [4, 6])
def test_get_pose_accepts_four_to_six_numbers(make_emulator, count):
    emulator = make_emulator(pose_value_count=count)
    reply = parse_reply(raw_request(emulator.dashboard_port, "GetPose()"))
    assert len(reply.values) == count
    with client_for(emulator, use_feedback=False) as robot:
        assert robot.get_pose() == pytest.approx((284.0, 0.0, 118.0, 0.0))


def test_motion_is_refused_while_disabled(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        with pytest.raises(MG400Error, match=r"MovL\(.*\) failed with ErrorID -1") as info:
            robot.mov_l(290.0, 0.0, 110.0, 0.0)
        assert info.value.error_id == -1


def test_protocol_error_ids_from_the_emulator(make_emulator):
    emulator = make_emulator()
    assert raw_request(emulator.dashboard_port, "SpeedFactor(150)") == "-40001,{},SpeedFactor(150);"
    assert raw_request(emulator.dashboard_port, "Foo()") == "-10000,{},Foo();"
    assert raw_request(emulator.dashboard_port, "MovJ(300,0,50,0)") == "-10000,{},MovJ(300,0,50,0);"
    assert raw_request(emulator.motion_port, "MovJ(1,2,3)") == "-20000,{},MovJ(1,2,3);"
    assert raw_request(emulator.motion_port, "MovJ(a,0,0,0)") == "-30001,{},MovJ(a,0,0,0);"
    assert raw_request(emulator.motion_port, "ServoP(300,0,50,0,t=0.001)") == "-40005,{},ServoP(300,0,50,0,t=0.001);"
    with socket.create_connection(("127.0.0.1", emulator.dashboard_port), timeout=1.0) as sock:
        sock.sendall(b"EnableRobot()\r\nRobotMode()\n")  # two commands in one segment
        data = b""
        while data.count(b";") < 2:
            data += sock.recv(1024)
    assert data == b"0,{},EnableRobot();0,{5},RobotMode();"


@pytest.mark.parametrize("command, alarm", [("JointMovJ(170,0,0,0)", 18), ("JointMovJ(0,0,70,0)", 18),
                                            ("MovJ(600,0,0,0)", 23), ("ServoP(600,0,0,0,t=0.1)", 23)])
def test_emulator_refuses_targets_beyond_limits_with_an_alarm(make_emulator, command, alarm):
    emulator = make_emulator()
    raw_request(emulator.dashboard_port, "EnableRobot()")
    assert raw_request(emulator.motion_port, command).startswith("-1,{},")
    assert emulator.robot_mode is RobotMode.ERROR and emulator.alarms == (alarm,)
    with client_for(emulator) as robot:
        assert robot.get_error_id().controller == (alarm,)
        robot.clear_error()
        robot.continue_()
        assert robot.robot_mode() is RobotMode.ENABLED


def test_servo_p_streaming_reaches_the_target(make_emulator):
    emulator = make_emulator()
    safety = SafetyLayer(SafetyConfig(max_step_mm=3.0, max_step_deg=3.0))
    with client_for(emulator, safety) as robot:
        robot.enable_robot()
        assert wait_for(lambda: robot.latest_feedback() is not None)
        goal = (300.0, 10.0, 100.0, 5.0)
        # 0.6 mm per 20 ms period: a stream at 30 mm/s (the speed of a stream is step / period, not step / t); a
        # margin of 0.1 s keeps each target in force past a late cycle of a busy machine (else the arm may arrive,
        # stop, and the next target, a restart from rest, is refused by the stream's acceleration bound)
        config = ServoStreamConfig(period_s=0.02, margin_s=0.1, max_step_mm=0.6, max_step_deg=0.6)
        with ServoStreamer(robot, config) as streamer:
            streamer.set_goal(goal)
            assert wait_for(lambda: streamer.at_goal, timeout_s=60.0), streamer.error
            assert wait_for(lambda: np.allclose(emulator.pose, goal, atol=1e-3), timeout_s=10.0)
        assert streamer.error is None and not streamer.running
        servo = [c for c in emulator.received_commands("motion") if c.startswith("ServoP")]
        assert len(servo) == streamer.commands_sent >= 10
        assert all(c.endswith(",t=0.12)") for c in servo)
        assert wait_for(lambda: np.allclose(robot.latest_feedback().tool_vector_actual, goal, atol=1e-3))


def test_servo_streamer_never_queues_when_replies_are_slow(make_emulator):
    emulator = make_emulator(faults=FaultConfig(reply_delay_s=0.1, slow_commands=("ServoP",)))
    with client_for(emulator) as robot:
        robot.enable_robot()
        streamer = ServoStreamer(robot, ServoStreamConfig(period_s=0.01, margin_s=0.02, max_step_mm=0.3))
        start = time.monotonic()
        with streamer:
            streamer.set_goal((284.0, 0.0, 90.0, 0.0))
            assert wait_for(lambda: streamer.commands_sent >= 2, timeout_s=30.0), streamer.error
        elapsed_s = time.monotonic() - start
        # One command per slow reply (0.1 s) at most, not one per 10 ms period, however slow the machine.
        assert streamer.error is None
        assert streamer.commands_sent <= elapsed_s / 0.1 + 1


def test_servo_j(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        robot.enable_robot()
        robot.servo_j(0.5, 0.5, 0.5, 1.0, t_s=0.1)  # about 3 mm at the flange
        assert wait_for(lambda: np.allclose(emulator.joints_deg, (0.5, 0.5, 0.5, 1.0)), timeout_s=1.0)
        with pytest.raises(ValueError, match="t_s"):
            robot.servo_j(1.0, 0.5, 0.5, 1.0, t_s=0.001)


# ---------------------------------------------------------------------------------------------------------------
# Faults


def test_alarm_during_motion_raises_and_shows_error_mode(make_emulator):
    emulator = make_emulator(faults=FaultConfig(alarm_during_motion=112, alarm_after_s=0.03))
    with client_for(emulator, SafetyLayer(BENCH)) as robot:
        robot.enable_robot()
        robot.mov_l(284.0, 0.0, -50.0, 0.0)  # 168 mm: ~0.17 s at 1000 mm/s
        with pytest.raises(MG400Error, match=r"Sync\(\) failed.*112 \(collision detected\)") as info:
            robot.sync()
        assert info.value.alarms == (112,)
        assert robot.robot_mode() is RobotMode.ERROR
        assert wait_for(lambda: robot.latest_feedback().error_status)
        assert emulator.pose[2] > -50.0  # stopped part way
        robot.clear_error()
        robot.continue_()
        assert robot.robot_mode() is RobotMode.ENABLED
        robot.mov_l(284.0, 0.0, 100.0, 0.0)  # the fault fires once
        robot.sync()


def test_dropped_connection_gives_a_clear_error_and_a_safe_stop(make_emulator):
    emulator = make_emulator(faults=FaultConfig(drop_after_commands=3))
    safety = SafetyLayer(SafetyConfig())
    with client_for(emulator, safety) as robot:
        assert wait_for(lambda: robot.latest_feedback() is not None)  # so the safety check needs no GetAngle
        robot.enable_robot()  # command 1
        robot.mov_l(284.0, 0.0, 80.0, 0.0)  # command 2
        assert safety.check_status(robot.status_snapshot()).stop is False
        with pytest.raises(MG400ConnectionError, match="closed"):
            robot.get_pose()  # command 3: the emulator drops every connection
        assert emulator.queue_length == 0
        stopped_at = emulator.pose
        time.sleep(0.05)
        assert emulator.pose == stopped_at  # the emulated robot stopped
        assert wait_for(lambda: not robot.connected)
        decision = safety.check_status(robot.status_snapshot())
        assert decision.stop and "lost connection to the robot" in decision.reasons
        with pytest.raises(MG400ConnectionError, match="closed"):
            robot.mov_l(284.0, 0.0, 100.0, 0.0)
        with pytest.raises(FeedbackStaleError, match="connection lost"):
            wait_for(lambda: False, timeout_s=0.05)
            robot.latest_feedback(max_age_s=0.02)


def test_servo_streamer_stops_on_a_dropped_connection(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        robot.enable_robot()
        streamer = ServoStreamer(robot, ServoStreamConfig(period_s=0.01, margin_s=0.04, max_step_mm=0.3)).start()
        streamer.set_goal((284.0, 0.0, 60.0, 0.0))
        assert wait_for(lambda: streamer.commands_sent > 2)
        emulator.drop_connections()
        assert wait_for(lambda: not streamer.running)
        assert isinstance(streamer.error, MG400ConnectionError)
        with pytest.raises(MG400ConnectionError):
            streamer.set_goal((284.0, 0.0, 70.0, 0.0))
        streamer.stop()


def test_split_replies_are_reassembled(make_emulator):
    emulator = make_emulator(faults=FaultConfig(split_replies_bytes=3, split_delay_s=0.001))
    with client_for(emulator) as robot:
        robot.enable_robot()
        assert robot.get_pose() == pytest.approx((284.0, 0.0, 118.0, 0.0))
        assert robot.get_error_id().controller == ()
        robot.mov_l(284.0, 0.0, 110.0, 0.0)
        robot.sync()
        assert robot.robot_mode() is RobotMode.ENABLED


def test_corrupt_and_partial_feedback_packets_are_rejected_and_reading_goes_on(make_emulator, caplog):
    emulator = make_emulator(faults=FaultConfig(corrupt_feedback_every=3))
    with caplog.at_level(logging.WARNING), client_for(emulator) as robot:
        assert wait_for(lambda: robot.feedback_rejected >= 3 and robot.feedback_received >= 10, timeout_s=3.0)
        robot.enable_robot()
        robot.mov_l(284.0, 0.0, 100.0, 0.0)
        robot.sync()
        assert wait_for(lambda: robot.latest_feedback().tool_vector_actual[2] == pytest.approx(100.0, abs=1e-6))
        assert robot.latest_feedback(max_age_s=0.1).robot_type == 1
    reasons = " ".join(r.getMessage() for r in caplog.records)
    assert "length field" in reasons and "test value" in reasons and "truncated" in reasons


@pytest.mark.parametrize("fault", [FeedbackFault.BAD_LENGTH, FeedbackFault.BAD_TEST_VALUE, FeedbackFault.PARTIAL])
def test_each_feedback_fault_alone(make_emulator, fault):  # the malformed ones (INCONSISTENT: test_safety_defaults)
    emulator = make_emulator(faults=FaultConfig(corrupt_feedback_every=2, feedback_faults=(fault,)))
    with client_for(emulator) as robot:
        assert wait_for(lambda: robot.feedback_rejected >= 2 and robot.feedback_received >= 3)
        robot.latest_feedback()


def test_slow_reply_times_out_and_the_late_reply_is_discarded(make_emulator):
    emulator = make_emulator(faults=FaultConfig(reply_delay_s=0.3, slow_commands=("GetPose",)))
    with client_for(emulator, reply_timeout_s=0.1) as robot:
        # the timeout fired before the reply (0.3 s late) arrived, however busy the machine: a reply waiting in
        # the socket after the deadline is not read, so get_pose() raises rather than returns
        with pytest.raises(MG400TimeoutError, match=r"no reply to GetPose\(\) .* within 0.1 s"):
            robot.get_pose()
        time.sleep(0.3)  # the late GetPose reply arrives meanwhile (or later: it comes first on the socket anyway)
        assert robot.robot_mode() is RobotMode.DISABLED  # not mistaken for the late GetPose reply


def test_stale_feedback_raises(make_emulator):
    emulator = make_emulator()
    robot = client_for(emulator)
    try:
        assert wait_for(lambda: robot.feedback_received > 0)
        emulator.stop()
        time.sleep(0.06)
        with pytest.raises(FeedbackStaleError):
            robot.latest_feedback(max_age_s=0.05)
    finally:
        robot.close()


# ---------------------------------------------------------------------------------------------------------------
# Safety


def test_safety_refusals_send_nothing(make_emulator):
    emulator = make_emulator()
    safety = SafetyLayer(SafetyConfig(max_step_mm=5.0, max_step_deg=5.0, z_range_mm=(-100.0, 120.0)))
    with client_for(emulator, safety) as robot:
        robot.enable_robot()
        with pytest.raises(SafetyError, match=r"beyond the arm's limits: J1 = 170.000 deg .*\[-160, 160\]"):
            robot.joint_mov_j(170.0, 0.0, 0.0, 0.0)
        with pytest.raises(SafetyError, match=r"beyond the arm's limits: J3-J2"):
            robot.servo_j(0.0, 0.0, 61.0, 0.0)
        with pytest.raises(SafetyError, match=r"beyond the arm's limits: .*out of reach"):
            robot.mov_l(600.0, 0.0, 0.0, 0.0)
        with pytest.raises(SafetyError, match=r"target z_mm = 150.000 mm is outside the workspace \[-100, 120\]"):
            robot.mov_l(284.0, 0.0, 150.0, 0.0)
        with pytest.raises(SafetyError, match=r"step of 10.000 mm .* exceeds max_step_mm = 5 mm"):
            robot.servo_p(284.0, 0.0, 108.0, 0.0)
        with pytest.raises(SafetyError, match=r"R step of 10.000 deg exceeds max_step_deg = 5 deg"):
            robot.servo_p(284.0, 0.0, 118.0, 10.0)
        with pytest.raises(SafetyError, match=r"step of 39.622 mm .* exceeds max_step_mm"):
            robot.servo_j(8.0, 0.0, 0.0, 0.0)
        with pytest.raises(SafetyError, match=r"speed of 80.0 mm/s \(4.000 mm in t = 0.05 s\) exceeds max_speed_mm_s"):
            robot.servo_p(284.0, 0.0, 114.0, 0.0, t_s=0.05)
        assert emulator.received_commands("motion") == []
        robot.servo_p(284.0, 0.0, 114.0, 0.0, t_s=0.1)  # a small, slow step passes
        assert emulator.received_commands("motion") == ["ServoP(284,0,114,0,t=0.1)"]


def test_default_client_still_enforces_joint_limits(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        robot.enable_robot()
        with pytest.raises(SafetyError, match="J1 = 170"):
            robot.joint_mov_j(170.0, 0.0, 0.0, 0.0)
        with pytest.raises(SafetyError, match="J3-J2 = -70.000 deg"):
            robot.mov_j(*forward((0.0, 80.0, 10.0, 0.0)))
        with pytest.raises(SafetyError, match=r"J2 = -20.000 deg .*\[-19, 85\] deg \(coupled limit"):
            robot.mov_l(*forward((0.0, -20.0, -5.0, 0.0)))
        assert emulator.received_commands("motion") == []


def test_dry_run_logs_instead_of_sending(make_emulator, caplog):
    emulator = make_emulator()
    with caplog.at_level(logging.INFO), client_for(emulator, SafetyLayer(SafetyConfig(dry_run=True))) as robot:
        robot.enable_robot()
        robot.mov_l(290.0, 0.0, 110.0, 0.0)
        robot.servo_p(292.0, 0.0, 110.0, 0.0)
        robot.sync()
        with pytest.raises(SafetyError):
            robot.mov_l(600.0, 0.0, 0.0, 0.0)  # checks still apply
    assert emulator.received_commands("motion") == []
    assert "dry run: not sending MovL(290,0,110,0,SpeedL=" in caplog.text


def test_joint_steps_are_limited_too():
    safety = SafetyLayer(UnsafeSafetyConfig(max_step_mm=100.0, max_step_deg=5.0, max_speed_mm_s=1000.0))
    with pytest.raises(SafetyError, match=r"J1 step of 8.000 deg exceeds max_step_deg = 5 deg"):
        safety.check_joint_target((0, 0, 0, 0), (8, 0, 0, -8))
    with pytest.raises(SafetyError, match=r"J1 step of 100.000 deg exceeds max_move_deg = 45 deg"):
        SafetyLayer(UnsafeSafetyConfig(max_move_mm=1000.0)).check_joint_target((-50, 0, 0, 50), (50, 0, 0, -50),
                                                                                 MotionKind.JOINT)
    assert safety.check_joint_target((0, 0, 0, 0), (4, 0, 0, 0)) == pytest.approx(forward((4, 0, 0, 0)))


def test_queued_move_paths_are_checked():
    wide = SafetyLayer(UnsafeSafetyConfig(max_move_mm=500.0, max_move_deg=180.0, x_range_mm=(100.0, 440.0),
                                          y_range_mm=(-300.0, 300.0)))
    # A straight line from y=-200 to y=+200 at x=250 passes radius 250 mm: fine.
    wide.check_target((250.0, -200.0, 0.0, 0.0), (250.0, 200.0, 0.0, 0.0), MotionKind.LINEAR)
    # At x=150 it passes close to the base, beyond the arm's limits, though both ends are reachable.
    with pytest.raises(SafetyError, match="MovL path point at .* beyond the arm's limits"):
        wide.check_target((150.0, -200.0, 0.0, 0.0), (150.0, 200.0, 0.0, 0.0), MotionKind.LINEAR)
    # Joint-space interpolation keeps the radius, so the same move as MovJ is fine...
    wide.check_target((150.0, -200.0, 0.0, 0.0), (150.0, 200.0, 0.0, 0.0), MotionKind.JOINT)
    # ...but it sweeps an arc that leaves an x box the straight line would respect.
    boxed = SafetyLayer(UnsafeSafetyConfig(max_move_mm=500.0, max_move_deg=180.0, x_range_mm=(140.0, 240.0),
                                           y_range_mm=(-300.0, 300.0)))
    with pytest.raises(SafetyError, match="joint-space path point .* x_mm = .* outside the workspace"):
        boxed.check_target((150.0, -200.0, 0.0, 0.0), (150.0, 200.0, 0.0, 0.0), MotionKind.JOINT)


def test_stop_conditions():
    safety = SafetyLayer(SafetyConfig(max_feedback_age_s=0.1, max_camera_frame_age_s=0.2))
    ok = StatusSnapshot(connected=True, robot_mode=int(RobotMode.RUNNING), feedback_age_s=0.01,
                        camera_frame_age_s=0.05, in_contact=True)
    assert safety.check_status(ok).stop is False
    cases = {
        "lost connection": StatusSnapshot(connected=False),
        "feedback is 0.500 s old": StatusSnapshot(connected=True, feedback_age_s=0.5),
        "error mode": StatusSnapshot(connected=True, robot_mode=int(RobotMode.ERROR)),
        "camera stalled": StatusSnapshot(connected=True, camera_frame_age_s=1.0),
        "lost contact": StatusSnapshot(connected=True, in_contact=False),
    }
    for reason, snapshot in cases.items():
        decision = safety.check_status(snapshot)
        assert decision.stop and any(reason in r for r in decision.reasons), (reason, decision)
    relaxed = SafetyLayer(SafetyConfig(stop_on_lost_contact=False))
    assert relaxed.check_status(StatusSnapshot(connected=True, in_contact=False)).stop is False


def test_configs_are_validated():
    with pytest.raises(ValueError, match="max_step_mm"):
        SafetyConfig(max_step_mm=0.0)
    with pytest.raises(ValueError, match="x_range_mm"):
        SafetyConfig(x_range_mm=(400.0, 100.0))
    with pytest.raises(ValueError, match="loopback"):
        EmulatorConfig(host="192.168.1.6")
    with pytest.raises(ValueError, match="loopback"):
        EmulatorConfig(host="0.0.0.0")
    with pytest.raises(ValueError, match="drop_after_commands"):
        FaultConfig(drop_after_commands=0)
    with pytest.raises(ValueError, match="dashboard_port"):
        MG400ClientConfig(dashboard_port=0)
    with pytest.raises(ValueError, match="period_s"):
        ServoStreamConfig(period_s=0.0)


def test_cli_hooks(monkeypatch):
    parser = argparse.ArgumentParser()
    mg400_emulator.add_arguments(parser)
    args = parser.parse_args(["--dashboard-port", "0", "--motion-port", "0", "--feedback-port", "0",
                              "--split-replies-bytes", "4", "--slow-commands", "GetPose"])
    assert args.host == "127.0.0.1" and args.split_replies_bytes == 4

    def interrupt(_seconds: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(mg400_emulator.time, "sleep", interrupt)
    assert mg400_emulator.run(args) == 0
    with pytest.raises(ValueError, match="loopback"):
        mg400_emulator.run(parser.parse_args(["--host", "10.0.0.1"]))
