"""Safe by default: the limits a client gets without asking, loosening only by name, joint feedback checked
against the reported pose, and the emulator's speed limits (issue 24, bullets 1 and 2)."""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from simshear_gym.real.mg400_client import (
    MG400Client,
    MG400ClientConfig,
    MG400TimeoutError,
    ServoStreamConfig,
    ServoStreamer,
)
from simshear_gym.real.mg400_emulator import (
    READY_POSE_MM_DEG,
    EmulatorConfig,
    FaultConfig,
    FeedbackFault,
    MG400Emulator,
)
from simshear_gym.real.safety import (
    FeedbackMismatchError,
    MotionKind,
    SafetyConfig,
    SafetyError,
    SafetyLayer,
    UnsafeSafetyConfig,
)
from simshear_gym.robots.mg400.kinematics import forward
from simshear_gym.robots.mg400.protocol import RobotMode
from tests.clocks import wait_for

INCONSISTENT = FaultConfig(corrupt_feedback_every=1, feedback_faults=(FeedbackFault.INCONSISTENT,))



@pytest.fixture
def make_emulator() -> Iterator[Callable[..., MG400Emulator]]:
    started: list[MG400Emulator] = []

    def make(faults: FaultConfig | None = None, **overrides) -> MG400Emulator:
        settings = dict(dashboard_port=0, motion_port=0, feedback_port=0, joint_speed_deg_s=400.0)
        emulator = MG400Emulator(EmulatorConfig(**{**settings, **overrides}, faults=faults or FaultConfig())).start()
        started.append(emulator)
        return emulator

    yield make
    for emulator in started:
        emulator.stop()


def config_for(emulator: MG400Emulator, **overrides) -> MG400ClientConfig:
    settings = dict(host="127.0.0.1", dashboard_port=emulator.dashboard_port, motion_port=emulator.motion_port,
                    feedback_port=emulator.feedback_port, connect_timeout_s=1.0, reply_timeout_s=1.0)
    return MG400ClientConfig(**{**settings, **overrides})


def raw_request(port: int, command: str) -> str:
    with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
        sock.sendall(command.encode())
        data = b""
        while not data.endswith(b";"):
            data += sock.recv(1024)
    return data.decode()


# -- acceptance ------------------------------------------------------------------------------------------------


def test_a_client_without_a_safety_argument_refuses_a_fast_servo_p_and_a_long_mov_l(make_emulator):
    emulator = make_emulator()
    with MG400Client(config_for(emulator)) as robot:  # no safety argument
        assert robot.safety.config == SafetyConfig() and not robot.safety.config.unsafe
        robot.enable_robot()
        assert wait_for(lambda: robot.feedback_received > 0)
        x, y, z, r = emulator.pose
        with pytest.raises(SafetyError, match=r"step of 100.000 mm .* exceeds max_step_mm = 5 mm"):
            robot.servo_p(x + 100.0, y, z, r, t_s=0.1)  # 1 m/s
        with pytest.raises(SafetyError, match=r"step of 100.000 mm .* exceeds max_move_mm = 50 mm"):
            robot.mov_l(x + 100.0, y, z, r)
        with pytest.raises(SafetyError, match=r"exceeds max_move_mm = 50 mm"):
            robot.mov_j(x, y + 100.0, z, r)
    assert emulator.received_commands("motion") == []
    assert emulator.pose == pytest.approx(READY_POSE_MM_DEG, abs=1e-9)


def test_the_speed_limit_holds_where_the_step_limit_was_loosened(make_emulator):
    emulator = make_emulator()
    bench = SafetyLayer(UnsafeSafetyConfig(max_step_mm=200.0, max_step_deg=90.0))  # the steps, not the speeds
    with MG400Client(config_for(emulator), bench) as robot:
        robot.enable_robot()
        assert robot.wait_until_still(0.1)
        x, y, z, r = emulator.pose
        with pytest.raises(SafetyError, match=r"speed of 1000.0 mm/s \(100.000 mm in t = 0.1 s\) exceeds "
                                              r"max_speed_mm_s = 50 mm/s"):
            robot.servo_p(x + 100.0, y, z, r, t_s=0.1)
        j1, j2, j3, j4 = emulator.joints_deg
        with pytest.raises(SafetyError, match=r"R speed of 60.0 deg/s \(6.000 deg in t = 0.1 s\) exceeds "
                                              r"max_speed_deg_s = 50 deg/s"):
            robot.servo_j(j1, j2, j3, j4 + 6.0, t_s=0.1)  # the wrist alone: the flange stays, R turns
        robot.servo_p(x + 4.0, y, z, r, t_s=0.1)  # 40 mm/s: fine
    assert len(emulator.received_commands("motion")) == 1


def test_joint_feedback_that_disagrees_with_the_pose_stops_even_a_2_mm_step(make_emulator):
    emulator = make_emulator(faults=INCONSISTENT)  # every packet: J1 turned 5 deg from the pose's joints
    with MG400Client(config_for(emulator)) as robot:
        robot.enable_robot()
        assert wait_for(lambda: robot.feedback_received > 2)
        assert "max_pose_mismatch_mm" in robot.feedback_mismatch
        x, y, z, r = emulator.pose
        with pytest.raises(FeedbackMismatchError, match=r"joint feedback .* disagree|apart"):
            robot.servo_p(x, y, z - 2.0, r)
        robot.reset_reference()  # a fresh measurement disagrees too
        with pytest.raises(FeedbackMismatchError, match=r"MG400 at 127.0.0.1, feedback: the joint feedback"):
            robot.servo_p(x, y, z - 2.0, r)
        with pytest.raises(FeedbackMismatchError):
            ServoStreamer(robot).start()  # checked before streaming
    assert emulator.received_commands("motion") == []


def test_disagreeing_feedback_mid_stream_stops_the_streamer_and_a_fresh_start_recovers(make_emulator):
    emulator = make_emulator()
    with MG400Client(config_for(emulator)) as robot:
        robot.enable_robot()
        assert wait_for(lambda: robot.feedback_received > 0)
        x, y, z, r = emulator.pose
        streamer = ServoStreamer(robot, ServoStreamConfig(period_s=0.02, margin_s=0.03, max_step_mm=0.5)).start()
        streamer.set_goal((x, y, z - 20.0, r))
        assert wait_for(lambda: streamer.commands_sent >= 3)
        emulator.set_faults(INCONSISTENT)
        assert wait_for(lambda: not streamer.running)
        assert isinstance(streamer.error, FeedbackMismatchError)
        sent = len(emulator.received_commands("motion"))
        time.sleep(0.1)
        assert len(emulator.received_commands("motion")) == sent  # nothing more
        streamer.stop()
        emulator.set_faults(FaultConfig())
        time.sleep(0.05)  # packets that agree again
        robot.reset_reference()
        pose, _ = robot.measured_state()
        robot.servo_p(pose[0], pose[1], pose[2] - 1.0, pose[3])
    assert len(emulator.received_commands("motion")) == sent + 1


def test_the_step_is_measured_from_the_reported_pose_and_from_a_target_whose_reply_was_lost(make_emulator):
    emulator = make_emulator(faults=FaultConfig(reply_delay_s=0.3, slow_commands=("ServoP",)))
    with MG400Client(config_for(emulator, reply_timeout_s=0.1)) as robot:
        robot.enable_robot()
        assert wait_for(lambda: robot.feedback_received > 0)
        x, y, z, r = emulator.pose
        with pytest.raises(MG400TimeoutError):
            robot.servo_p(x, y, z + 4.0, r, t_s=1.0)  # executed (slowly) by the robot, the reply lost
        # 4 mm below the robot but 8 mm from the target that may be in force: refused
        with pytest.raises(SafetyError, match="exceeds max_step_mm = 5 mm"):
            robot.servo_p(x, y, z - 4.0, r, t_s=1.0)
        emulator.set_faults(FaultConfig())
        time.sleep(0.3)  # the late reply arrives meanwhile
        robot.servo_p(x, y, z + 1.0, r, t_s=1.0)  # within the limits of both
    assert [c.split("(")[0] for c in emulator.received_commands("motion")] == ["ServoP", "ServoP"]


def test_measurements_without_the_feedback_stream_are_checked_too(make_emulator):
    emulator = make_emulator()
    with MG400Client(config_for(emulator, use_feedback=False)) as robot:
        robot.enable_robot()
        pose, joints = robot.measured_state()  # GetAngle() and GetPose(), checked to agree
        assert pose == pytest.approx(forward(joints), abs=1e-6)
        # without the stream the client cannot tell how long the arm has been still: from rest, a servo command
        # may ask for max_accel_mm_s2 * controller_cycle_s (16 mm/s)
        with pytest.raises(SafetyError, match="stream acceleration"):
            robot.servo_p(pose[0], pose[1], pose[2] - 2.0, pose[3], t_s=0.1)
        robot.servo_p(pose[0], pose[1], pose[2] - 2.0, pose[3], t_s=0.2)
    assert len(emulator.received_commands("motion")) == 1


# -- loosening takes a name ------------------------------------------------------------------------------------


def test_a_safety_config_cannot_loosen_the_safe_defaults(caplog):
    for loosened in (dict(max_step_mm=10.0), dict(max_speed_mm_s=100.0), dict(max_move_mm=100.0),
                     dict(z_range_mm=(-200.0, 150.0)), dict(max_pose_mismatch_mm=5.0)):
        with pytest.raises(ValueError, match=rf"{next(iter(loosened))} = .* looser than the safe defaults; .*"
                                             "UnsafeSafetyConfig"):
            SafetyConfig(**loosened)
    tight = SafetyConfig(max_step_mm=2.0, max_speed_mm_s=20.0, z_range_mm=(-10.0, 10.0))  # tightening is fine
    assert tight.loosened() == ()
    with caplog.at_level(logging.WARNING, logger="simshear_gym.real.safety"):
        SafetyLayer(tight)
        assert caplog.text == ""
        SafetyLayer(UnsafeSafetyConfig(max_move_mm=200.0))
    assert "UNSAFE safety limits in use (UnsafeSafetyConfig): max_move_mm = 200.0 (safe default 50.0)" in caplog.text
    everything = UnsafeSafetyConfig.arm_limits_only()
    assert everything.unsafe and len(everything.loosened()) == 13


def test_servo_checks_use_the_command_time():
    safety = SafetyLayer()
    pose = np.array(READY_POSE_MM_DEG)
    safety.check_target(pose, pose + [2.0, 0, 0, 0], MotionKind.SERVO, duration_s=0.05)  # 40 mm/s
    with pytest.raises(SafetyError, match="speed of 100.0 mm/s"):
        safety.check_target(pose, pose + [2.0, 0, 0, 0], MotionKind.SERVO, duration_s=0.02)
    with pytest.raises(SafetyError, match="R speed of 100.0 deg/s"):
        safety.check_target(pose, pose + [0, 0, 0, 2.0], MotionKind.SERVO, duration_s=0.02)
    safety.check_target(pose, pose + [20.0, 0, 0, 0], MotionKind.LINEAR)  # queued moves: the jump only


# -- the emulator's speed limits --------------------------------------------------------------------------------


def test_the_emulator_raises_overspeed_for_a_servo_command_faster_than_the_arm(make_emulator):
    emulator = make_emulator()
    raw_request(emulator.dashboard_port, "EnableRobot()")
    x, y, z, r = emulator.pose
    assert raw_request(emulator.motion_port, f"ServoP({x + 140:g},{y:g},{z:g},{r:g},t=0.1)").startswith("-1,{},")
    assert emulator.robot_mode is RobotMode.ERROR and emulator.alarms[0] in (48, 49, 50, 51)
    assert emulator.pose == pytest.approx((x, y, z, r), abs=1e-9)  # stopped where it was, not moved at all
    record = emulator.motion_records()[-1]
    assert record.servo and record.error_id == -1 and record.in_force_pose == pytest.approx((x, y, z, r))
    raw_request(emulator.dashboard_port, "ClearError()")
    # J1 alone at 400 deg/s (limit 300): the J1 alarm, 48
    j1, j2, j3, j4 = emulator.joints_deg
    assert raw_request(emulator.motion_port, f"ServoJ({j1 + 40:g},{j2:g},{j3:g},{j4:g},t=0.1)").startswith("-1,")
    assert emulator.alarms == (48,)
    raw_request(emulator.dashboard_port, "ClearError()")
    # the same moves given the time the arm needs are fine
    assert raw_request(emulator.motion_port, f"ServoP({x + 140:g},{y:g},{z:g},{r:g},t=0.2)").startswith("0,")
    assert wait_for(lambda: np.allclose(emulator.pose, (x + 140, y, z, r), atol=1e-6), timeout_s=1.0)
    assert emulator.alarms == ()


def test_queued_moves_are_planned_and_never_overspeed(make_emulator):
    emulator = make_emulator(joint_speed_deg_s=400.0)
    raw_request(emulator.dashboard_port, "EnableRobot()")
    assert raw_request(emulator.motion_port, "JointMovJ(40,20,40,0)").startswith("0,")
    assert wait_for(lambda: emulator.queue_length == 0, timeout_s=2.0)
    assert emulator.alarms == () and emulator.joints_deg == pytest.approx((40, 20, 40, 0))
