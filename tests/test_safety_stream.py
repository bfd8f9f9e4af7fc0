"""Safety that holds for a stream of motion commands (issue 41, items 1, 6 and 7): the stream checks on their own
(explicit times, no clock), bursts, stale feedback and error mode against the emulator's own records, two arms
with a client each, and the vendor's command strings against the emulator."""

from __future__ import annotations

import math
import socket
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from simshear_gym.data.labels import wrap_deg
from simshear_gym.evaluate.safety_bursts import BurstConfig, make_sequence, run_bursts
from simshear_gym.real.mg400_client import MG400Client, MG400ClientConfig
from simshear_gym.real.mg400_emulator import READY_POSE_MM_DEG, EmulatorConfig, MG400Emulator
from simshear_gym.real.safety import (
    ArmSample,
    MotionRefusedError,
    MotionStream,
    SafetyConfig,
    SafetyError,
    SafetyLayer,
    StopReason,
    UnsafeSafetyConfig,
    queued_ratios,
)
from simshear_gym.robots.mg400.kinematics import inverse
from simshear_gym.robots.mg400.protocol import RobotMode
from tests.clocks import wait_for

START = np.array(READY_POSE_MM_DEG)


def joints_of(pose) -> np.ndarray:
    return np.asarray(inverse(*pose), dtype=float)


def at_rest(pose, time_s: float = 0.0) -> ArmSample:
    """A measurement of the arm still at ``pose`` since long before ``time_s``."""
    pose = tuple(float(v) for v in pose)
    return ArmSample(pose, tuple(joints_of(pose)), time_s, pose, tuple(joints_of(pose)), moved_s=time_s - 10.0)



# -- the stream checks, with explicit times --------------------------------------------------------------------


def test_a_burst_of_commands_each_fine_on_its_own_is_refused_once_it_asks_the_arm_for_too_much():
    stream = MotionStream(SafetyLayer())
    sample = at_rest(START)
    target = START.copy()
    refused_at = None
    for index in range(10):  # 4 mm apart, t = 0.1 s (40 mm/s each), all sent within 10 ms: the burst
        target = target + [4.0, 0.0, 0.0, 0.0]
        now_s = 0.001 * index
        try:
            stream.check_servo(now_s, target, joints_of(target), 0.1, sample)
        except SafetyError as error:
            refused_at = index
            assert "stream" in str(error)
            break
        stream.record(now_s, target, joints_of(target), 0.1, sample)
        stream.outcome(answered=True, accepted=True)
    # the arm is still where it was: the second target is already 8 mm away, 80 mm/s in t
    assert refused_at == 1


def test_a_steady_stream_within_the_speed_limit_passes():
    stream = MotionStream(SafetyLayer())
    period_s, t_s, step_mm = 0.02, 0.06, 0.6  # 30 mm/s
    position, target, now_s = START.copy(), START.copy(), 0.0
    sample = at_rest(START)
    for _ in range(60):
        target = target + [step_mm, 0.0, 0.0, 0.0]
        stream.check_servo(now_s, target, joints_of(target), t_s, sample)
        stream.record(now_s, target, joints_of(target), t_s, sample)
        stream.outcome(answered=True, accepted=True)
        # the arm heads to the new target for one period; the next packet shows it 4 ms before the next command
        velocity = (target - position) / t_s
        position = position + velocity * period_s
        now_s += period_s
        seen = position - velocity * 0.004
        sample = ArmSample(tuple(seen), tuple(joints_of(seen)), now_s - 0.004, tuple(target),
                           tuple(joints_of(target)), moved_s=now_s - 0.004)
    assert target[0] - START[0] == pytest.approx(36.0)


def test_turning_a_stream_round_at_once_is_refused_for_its_acceleration():
    stream = MotionStream(SafetyLayer())
    sample = at_rest(START)
    first = START + [1.2, 0.0, 0.0, 0.0]  # 20 mm/s over t = 0.06 s, from long at rest: fine
    stream.check_servo(0.0, first, joints_of(first), 0.06, sample)
    stream.record(0.0, first, joints_of(first), 0.06, sample)
    stream.outcome(answered=True, accepted=True)
    back = START + [-0.8, 0.0, 0.0, 0.0]  # 20 ms later: from +20 mm/s to about -20 mm/s
    with pytest.raises(SafetyError, match="stream acceleration"):
        stream.check_servo(0.02, back, joints_of(back), 0.06, sample)


def test_a_command_the_controller_refused_is_not_in_force():
    stream = MotionStream(SafetyLayer())
    sample = at_rest(START)
    target = START + [1.2, 0.0, 0.0, 0.0]
    stream.record(0.0, target, joints_of(target), 0.06, sample)
    stream.outcome(answered=True, accepted=False)
    assert stream._servo is None  # the arm is still at rest: the next command is checked from rest
    stream.record(0.0, target, joints_of(target), 0.06, sample)
    stream.outcome(answered=False, accepted=False)  # no reply: in force or not, both are checked
    assert len(stream._options) == 2


def test_clamping_moves_a_too_fast_servo_target_back_toward_the_arm():
    layer = SafetyLayer(SafetyConfig(servo_over_limit="clamp"))
    stream = MotionStream(layer)
    sample = at_rest(START)
    wanted = START + [4.0, 0.0, 0.0, 0.0]  # 4 mm in t = 0.02 s: 200 mm/s

    def check(pose):
        return layer.check_target(START, pose, duration_s=0.02)

    with pytest.raises(SafetyError):
        stream.check_servo(0.0, wanted, joints_of(wanted), 0.02, sample)
    clamped = stream.clamp_servo_pose(0.0, wanted, 0.02, sample, check)
    stream.check_servo(0.0, clamped, joints_of(clamped), 0.02, sample)  # within the limits
    assert 0.0 < clamped[0] - START[0] < 4.0 and clamped[1:] == pytest.approx(START[1:])


def test_queued_moves_get_the_ratios_that_keep_them_within_the_limits():
    layer = SafetyLayer()
    cfg = layer.config
    end = START + [40.0, 0.0, 0.0, 0.0]
    speed, accel = queued_ratios(layer, START, joints_of(START), end, joints_of(end), linear=True)
    assert speed == int(100 * cfg.max_speed_mm_s / cfg.arm_linear_speed_mm_s)  # 5 %: 50 mm/s at 1000 mm/s
    assert accel == int(100 * cfg.max_accel_mm_s2 / cfg.arm_linear_accel_mm_s2)  # 20 %
    assert queued_ratios(layer, START, joints_of(START), end, joints_of(end), linear=True,
                         speed_factor_percent=10) == (50, accel)  # SpeedFactor 10 % leaves room
    free = SafetyLayer(UnsafeSafetyConfig(max_speed_mm_s=1000.0, max_speed_deg_s=400.0, max_accel_mm_s2=1e4,
                                          max_accel_deg_s2=4000.0))
    assert queued_ratios(free, START, joints_of(START), end, joints_of(end), linear=True) == (100, 100)


def test_loosening_the_stream_settings_takes_an_unsafe_config():
    for loosened in (dict(max_accel_mm_s2=5000.0), dict(stream_latency_s=0.001), dict(refuse_stale_feedback=False),
                     dict(arm_linear_speed_mm_s=500.0), dict(controller_cycle_s=0.001)):
        with pytest.raises(ValueError, match=f"{next(iter(loosened))} = .*UnsafeSafetyConfig"):
            SafetyConfig(**loosened)
    with pytest.raises(ValueError, match="servo_over_limit"):
        SafetyConfig(servo_over_limit="slow down")


# -- against the emulator --------------------------------------------------------------------------------------


@pytest.fixture
def make_emulator() -> Iterator[Callable[..., MG400Emulator]]:
    started: list[MG400Emulator] = []

    def make(**overrides) -> MG400Emulator:
        settings = dict(dashboard_port=0, motion_port=0, feedback_port=0, joint_speed_deg_s=400.0,
                        linear_speed_mm_s=1000.0)
        emulator = MG400Emulator(EmulatorConfig(**{**settings, **overrides})).start()
        started.append(emulator)
        return emulator

    yield make
    for emulator in started:
        emulator.stop()


def client_for(emulator: MG400Emulator, safety: SafetyConfig | None = None, **overrides) -> MG400Client:
    settings = dict(host="127.0.0.1", dashboard_port=emulator.dashboard_port, motion_port=emulator.motion_port,
                    feedback_port=emulator.feedback_port, connect_timeout_s=2.0, reply_timeout_s=2.0)
    client = MG400Client(MG400ClientConfig(**{**settings, **overrides}), SafetyLayer(safety)).connect()
    client.wait_until_still(0.1)
    return client


def raw(port: int, command: str) -> str:
    with socket.create_connection(("127.0.0.1", port), timeout=2.0) as sock:
        sock.sendall(command.encode())
        data = b""
        while not data.endswith(b";"):
            chunk = sock.recv(1024)
            if not chunk:
                break
            data += chunk
    return data.decode()


def test_bursts_on_two_arms_never_move_an_arm_faster_than_the_limit():
    result = run_bursts(BurstConfig(sequences=12, seed=3))
    assert result["unhandled"] == 0, [arm["unhandled_examples"] for arm in result["arms"]]
    assert result["motions_faster_than_the_limit"] == 0, [arm["motions_faster_examples"] for arm in result["arms"]]
    for arm in result["arms"]:
        assert arm["commands_sent"] > 0 and arm["motions_executed"] > 0
        assert arm["peak_speed_mm_s"] <= SafetyConfig().max_speed_mm_s * (1 + 1e-6)


def test_burst_sequences_are_each_within_the_per_command_limits_and_seeded():
    cfg = SafetyConfig()
    config = BurstConfig(sequences=5, seed=1)
    limits = (cfg.max_step_mm, cfg.max_speed_mm_s, cfg.max_step_deg, cfg.max_speed_deg_s)
    first = make_sequence(config, 2, 1, *limits)
    assert first == make_sequence(config, 2, 1, *limits) and first != make_sequence(config, 2, 0, *limits)
    for command in first:
        step_mm = float(np.linalg.norm(command.offset[:3]))
        if command.kind == "ServoP":
            assert step_mm <= cfg.max_step_mm and step_mm / command.t_s <= cfg.max_speed_mm_s
        else:
            assert step_mm <= config.mov_l_max_mm


def test_no_motion_is_sent_on_stale_or_missing_feedback(make_emulator):
    emulator = make_emulator()
    robot = client_for(emulator)
    try:
        robot.enable_robot()
        x, y, z, r = robot.measured_state()[0]
        emulator.pause_feedback(30.0)  # stale: the arm is there, its feedback is not
        assert wait_for(lambda: robot.status_snapshot().feedback_age_s > robot.safety.config.max_feedback_age_s)
        for send in (lambda: robot.servo_p(x, y, z - 1.0, r), lambda: robot.mov_l(x, y, z - 1.0, r),
                     lambda: robot.rel_mov_l(0.0, 0.0, -1.0, 0.0), lambda: robot.servo_j(*robot.get_angle())):
            with pytest.raises(MotionRefusedError, match="stale or missing feedback") as info:
                send()
            assert info.value.reason is StopReason.STALE_FEEDBACK
    finally:
        robot.close()
    assert emulator.motion_records() == [] and emulator.received_commands("motion") == []
    # missing: a client whose feedback never arrived
    silent = make_emulator()
    silent.pause_feedback(30.0)
    robot = MG400Client(MG400ClientConfig(host="127.0.0.1", dashboard_port=silent.dashboard_port,
                                          motion_port=silent.motion_port, feedback_port=silent.feedback_port,
                                          connect_timeout_s=0.2))
    with robot.connect():
        with pytest.raises(MotionRefusedError, match="no valid feedback packet"):
            robot.servo_p(*READY_POSE_MM_DEG)
    assert silent.received_commands("motion") == []


def test_no_motion_is_sent_in_error_mode(make_emulator):
    emulator = make_emulator()
    with client_for(emulator) as robot:
        robot.enable_robot()
        x, y, z, r = robot.measured_state()[0]
        emulator.inject_alarm(112)
        assert wait_for(lambda: robot.latest_feedback().error_status)
        for send in (lambda: robot.servo_p(x, y, z - 1.0, r), lambda: robot.mov_j(x, y, z - 1.0, r),
                     lambda: robot.rel_mov_j(0.0, 0.0, -1.0, 0.0)):
            with pytest.raises(MotionRefusedError, match="error mode") as info:
                send()
            assert info.value.reason is StopReason.ROBOT_ERROR_MODE
        assert emulator.motion_records() == []
        robot.clear_error()  # waits for feedback without the error
        robot.continue_()
        robot.servo_p(x, y, z - 1.0, r)  # 10 mm/s: fine again
    assert len(emulator.motion_records()) == 1
    # without the feedback stream the client asks RobotMode() first
    emulator.inject_alarm(112)
    with client_for(emulator, use_feedback=False) as robot:
        with pytest.raises(MotionRefusedError, match="error mode"):
            robot.servo_p(x, y, z - 2.0, r)
    assert len(emulator.motion_records()) == 1


def test_two_arms_each_get_their_own_stream_checks(make_emulator):
    leader, follower = make_emulator(), make_emulator()
    with client_for(leader) as a, client_for(follower) as b:
        a.enable_robot()
        b.enable_robot()
        x, y, z, r = READY_POSE_MM_DEG
        a.servo_p(x + 1.0, y, z, r, t_s=0.1)  # 10 mm/s each: fine for each arm on its own
        b.servo_p(x + 1.0, y, z, r, t_s=0.1)
        with pytest.raises(SafetyError, match="stream"):
            a.servo_p(x + 5.0, y, z, r, t_s=0.1)  # the leader's burst is the leader's
        b.servo_p(x + 1.5, y, z, r, t_s=0.1)
    assert len(leader.motion_records()) == 1 and len(follower.motion_records()) == 2


def test_queued_moves_from_the_client_stay_within_the_speed_and_acceleration_limits(make_emulator):
    emulator = make_emulator()
    cfg = SafetyConfig()
    with client_for(emulator) as robot:
        robot.enable_robot()
        x, y, z, r = READY_POSE_MM_DEG
        robot.mov_l(x + 40.0, y, z, r)
        robot.rel_mov_l(-40.0, 10.0, 0.0, 0.0)
        robot.mov_j(x, y - 30.0, z, r)
        robot.sync()
        assert wait_for(lambda: emulator.queue_length == 0)
    moves = [m for m in emulator.executed_motions() if not m.servo]
    assert [m.command.split("(")[0] for m in moves] == ["MovL", "RelMovL", "MovJ"]
    assert emulator.pose == pytest.approx((x, y - 30.0, z, r), abs=1e-6)
    for move in moves:
        assert move.peak_speed_mm_s <= cfg.max_speed_mm_s * (1 + 1e-6), move
        assert max(move.peak_rotation_deg_s, move.peak_joint_deg_s) <= cfg.max_speed_deg_s * (1 + 1e-6), move
        assert move.accel_mm_s2 <= cfg.max_accel_mm_s2 * (1 + 1e-6), move


def test_a_straight_move_across_r_180_turns_the_short_way_or_is_refused_at_j4s_end_stop(make_emulator):
    """R = J1 + J4 wraps at +-180 deg. With J1 = 30 deg, R 175 -> -175 is J4 145 -> 155: a 10 deg turn (it was
    refused as needing a 0.01 % ratio, the path taken through R = 0). With J1 = 0, R 179 -> -179 takes J4 across its
    end stop: refused, saying so, nothing sent."""
    layer = SafetyLayer()
    j1 = math.radians(30.0)
    start = np.array([300.0 * math.cos(j1), 300.0 * math.sin(j1), 0.0, 175.0])
    end = start + [0.0, 3.0, 0.0, -350.0]
    assert queued_ratios(layer, start, joints_of(start), end, joints_of(end), linear=True)[0] >= 1
    across = (np.array([300.0, 0.0, 0.0, 179.0]), np.array([300.0, 5.0, 0.0, -179.0]))
    with pytest.raises(SafetyError, match=r"takes J4 across its end stop \(-180, 180\) deg"):
        queued_ratios(layer, across[0], joints_of(across[0]), across[1], joints_of(across[1]), linear=True)
    cfg = SafetyConfig()
    emulator = make_emulator(initial_joints_deg=tuple(float(v) for v in joints_of(start)))
    with client_for(emulator) as robot:
        robot.enable_robot()
        robot.mov_l(*end)
        robot.sync()
        assert wait_for(lambda: emulator.queue_length == 0)
        assert emulator.pose[:3] == pytest.approx(end[:3], abs=1e-6)
        assert math.isclose(wrap_deg(emulator.pose[3] - end[3]), 0.0, abs_tol=1e-6)
    move = [m for m in emulator.executed_motions() if m.command.startswith("MovL")][0]
    assert move.peak_speed_mm_s <= cfg.max_speed_mm_s * (1 + 1e-6), move
    assert max(move.peak_rotation_deg_s, move.peak_joint_deg_s) <= cfg.max_speed_deg_s * (1 + 1e-6), move
    emulator = make_emulator(initial_joints_deg=tuple(float(v) for v in joints_of(across[0])))
    with client_for(emulator) as robot:
        robot.enable_robot()
        with pytest.raises(SafetyError, match="J4 across its end stop"):
            robot.mov_l(*across[1])
    assert emulator.motion_records() == []


# -- the vendor's commands -------------------------------------------------------------------------------------


def test_the_command_strings_of_dobots_python_api_answer_as_the_manual_says(make_emulator):
    # exactly what dobot_api.py sends: str() of the EnableRobot parameters, "{:d}" settings, "{:f}" poses
    emulator = make_emulator()
    dashboard, motion = emulator.dashboard_port, emulator.motion_port
    assert raw(dashboard, "EnableRobot()") == "0,{},EnableRobot();"
    assert raw(dashboard, "EnableRobot(0.5)") == "0,{},EnableRobot(0.5);"
    assert emulator.payload == (0.5, 0.0, 0.0, 0.0)
    assert raw(dashboard, "EnableRobot(0.5,0,0,5.5)") == "0,{},EnableRobot(0.5,0,0,5.5);"
    assert emulator.payload == (0.5, 0.0, 0.0, 5.5)
    assert raw(dashboard, "EnableRobot(0.5,0)").startswith("-20000,")  # 0, 1 or 4 parameters
    assert raw(dashboard, "EnableRobot(5)").startswith("-40001,")  # more than the arm carries
    assert raw(dashboard, "EnableRobot(0.5,0,0,600)").startswith("-40004,")  # centre offsets -500..500 mm
    for setting in ("SpeedFactor", "SpeedJ", "SpeedL", "AccJ", "AccL", "CP"):
        assert raw(dashboard, f"{setting}(50)") == f"0,{{}},{setting}(50);"
        assert raw(dashboard, f"{setting}(101)").startswith("-40001,")
    assert raw(dashboard, "SpeedL(0)").startswith("-40001,") and raw(dashboard, "CP(0)").startswith("0,")
    assert emulator.ratios == {"speedj": 50.0, "speedl": 50.0, "accj": 50.0, "accl": 50.0, "cp": 0.0}
    assert raw(dashboard, "PayLoad(0.500000,0.000000)").startswith("0,")
    x, y, z, r = READY_POSE_MM_DEG
    assert raw(motion, f"MovL({x:f},{y:f},{z + 10:f},{r:f})").startswith("0,{},MovL(")
    assert raw(motion, "RelMovL(0.000000,5.000000,0.000000,0.000000)").startswith("0,{},RelMovL(")
    assert raw(motion, f"MovJ({x:f},{y:f},{z:f},{r:f},SpeedJ=10,AccJ=20)").startswith("0,{},MovJ(")
    assert raw(motion, "RelMovJ(0.000000,0.000000,-5.000000,0.000000)").startswith("0,{},RelMovJ(")
    assert raw(motion, f"MovL({x:f},{y:f},{z:f},{r:f},SpeedL=101)").startswith("-40005,")
    assert raw(motion, f"MovL({x:f},{y:f},{z:f},{r:f},SpeedJ=10)").startswith("-20000,")  # MovL takes SpeedL
    assert raw(motion, "Sync()") == "0,{},Sync();"
    assert emulator.pose == pytest.approx((x, y, z - 5.0, r), abs=1e-6)
    moves = emulator.executed_motions()
    # SpeedFactor 50 % x SpeedL 50 % of 1000 mm/s = 250 mm/s, AccL 50 % of 10 m/s^2: the 10 mm MovL is too short
    # to reach 250 mm/s (a triangular profile peaking at sqrt(5000 mm/s^2 x 10 mm))
    assert moves[0].peak_speed_mm_s == pytest.approx(math.sqrt(5000.0 * 10.0), rel=1e-6)
    assert moves[0].accel_mm_s2 == pytest.approx(5000.0, rel=1e-6)
    assert moves[0].duration_s == pytest.approx(2.0 * math.sqrt(10.0 / 5000.0), rel=1e-6)
    assert moves[1].end_pose[:3] == pytest.approx((x, y + 5.0, z + 10.0))  # RelMovL: from the current target
    # MovJ's own SpeedJ=10 (x SpeedFactor 50 %) of 400 deg/s: its fastest joint at 20 deg/s
    assert moves[2].peak_joint_deg_s == pytest.approx(20.0, rel=1e-6)
    assert raw(dashboard, "RobotMode()") == f"0,{{{int(RobotMode.ENABLED)}}},RobotMode();"
