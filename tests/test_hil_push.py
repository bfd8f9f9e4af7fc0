"""Pushing rehearsed on the real path: ``simshear rollout --camera sim-push --controller push`` drives the MG400
emulator over TCP while the horizontal sim TacTip pushes an object (rendered where the emulator says the flange is,
translated by the shipped surface shPix2pix, as a 640x480 frame through the real preprocessing), every command
inside the safety limits."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simshear_gym import cli
from simshear_gym.contract import HorizontalTacTipMount, TacTipMount
from simshear_gym.real.env import move_to_flange_target, tcp_pose_from_flange
from simshear_gym.real.hil_push import PushObjectConfig, SimPushCamera
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
from simshear_gym.real.rollout import PUSH_START_POSE_MM_DEG
from simshear_gym.robots.mg400.kinematics import inverse
from tests.rehearsal import check_servo_commands_within_limits

START = PUSH_START_POSE_MM_DEG
STEPS = 60
PERIOD_S = 0.1


def test_a_horizontal_sensor_turns_about_the_vertical_through_its_apex():
    mount = HorizontalTacTipMount()
    target = move_to_flange_target(np.array(START), [0.0, 0.0, 1.0, 5.0], mount)
    before, after = tcp_pose_from_flange(np.array(START), mount), tcp_pose_from_flange(target, mount)
    assert target[3] == pytest.approx(START[3] + 5.0)
    # 1 mm along the sensor's axis (the base's +y at R = 90), then the turn leaves the apex where it is
    np.testing.assert_allclose(after[:3] - before[:3], [0.0, 1.0, 0.0], atol=1e-9)
    # a downward sensor turns about its own axis, as before
    down = move_to_flange_target(np.array([300.0, 0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 5.0], TacTipMount())
    np.testing.assert_allclose(down, [301.0, 0.0, 0.0, -5.0], atol=1e-9)


def test_the_push_camera_starts_touching_the_object_and_pushes_it_forward():
    flange = list(START)
    camera = SimPushCamera(lambda: tuple(flange), START, PushObjectConfig(target_xy_mm=(340.0, 100.0)))
    try:
        camera.read()
        truth = camera.history[-1]
        assert truth.in_contact and truth.penetration_mm == pytest.approx(0.4, abs=1e-6)
        start_distance = camera.target_distance_mm()
        for _ in range(20):  # 10 mm along the sensor's axis (+y)
            flange[1] += 0.5
            camera.read()
        assert camera.target_distance_mm() == pytest.approx(start_distance - 10.0 + 0.5, abs=0.2)
        assert camera.history[-1].contact_error_mm < 0.01 and camera.history[-1].in_contact
    finally:
        camera.close()
    with pytest.raises(ValueError, match="shape"):
        PushObjectConfig(shape="sphere")
    with pytest.raises(ValueError, match="HorizontalTacTipMount"):
        SimPushCamera(lambda: START, START, mount=TacTipMount())


def test_pushing_rollout_runs_on_the_emulator_within_the_limits(tmp_path):
    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                            initial_joints_deg=tuple(inverse(*START)))).start()
    out = tmp_path / "rollout"
    try:
        code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-push", "--controller", "push",
                         "--reference-depth-mm", "2.6", "--steps", str(STEPS), "--period-s", str(PERIOD_S),
                         "--out", str(out), "--dashboard-port", str(emulator.dashboard_port), "--motion-port",
                         str(emulator.motion_port), "--feedback-port", str(emulator.feedback_port)])
        sent = emulator.received_commands("motion")
    finally:
        emulator.stop()
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0, summary
    assert summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["commands_sent"] == STEPS
    assert summary["controller"] == "push_servo" and "--controller push" in summary["command"]
    # pushed towards the target (150 mm ahead at the start), 0.5 mm a command, on the path
    assert summary["truth_target_distance_mm"] < 150.0 - 0.6 * STEPS * 0.5
    assert summary["truth_contact_error_mm"]["max"] < 3.0
    check_servo_commands_within_limits(sent, START, STEPS, PERIOD_S)


def test_push_rollout_refuses_what_it_cannot_do(tmp_path, capsys):
    base = ["rollout", "--robot", "127.0.0.1", "--steps", "1", "--out", str(tmp_path)]
    code = cli.main([*base, "--camera", "sim-push", "--controller", "servo"])
    assert code != 0 and "--controller push" in capsys.readouterr().err
    code = cli.main([*base, "--camera", "sim-push", "--controller", "push", "--min-depth-mm", "2.5"])
    assert code != 0 and "--min-depth-mm" in capsys.readouterr().err
    assert not (tmp_path / "rollout.json").exists()  # refused before anything connected or moved


def test_the_shipped_push_policy_pushes_on_the_emulator_with_the_goal_and_the_push_estimator(tmp_path):
    """``simshear rollout --task push --policy``: the policy gets SimShearPush-v0's observation on the real path:
    the push law's estimator (four slots) and the goal from the measured pose and the target."""
    from simshear_gym.control.env_estimator import reading_estimator
    from simshear_gym.control.push_servo import PUSH_PROCESS_STD_MM, PushServoController
    from simshear_gym.models.zoo import policy_folder

    estimator = reading_estimator("push", PushServoController())
    assert type(estimator).__name__ == "PushReadingEstimator"
    assert estimator.config.process_std_mm == PUSH_PROCESS_STD_MM
    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                            initial_joints_deg=tuple(inverse(*START)))).start()
    out = tmp_path / "rollout"
    try:
        code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-push", "--task", "push", "--policy",
                         str(policy_folder("push_ppo") / "model.pt"), "--steps", str(STEPS), "--period-s",
                         str(PERIOD_S), "--out", str(out), "--dashboard-port", str(emulator.dashboard_port),
                         "--motion-port", str(emulator.motion_port), "--feedback-port", str(emulator.feedback_port)])
        sent = emulator.received_commands("motion")
    finally:
        emulator.stop()
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0 and summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["config"]["reference_depth_mm"] == 2.6
    assert summary["controller"].startswith("ppo")
    # pushed towards the target (150 mm ahead at the start) and kept on the path, as the servo above
    assert summary["truth_target_distance_mm"] < 150.0 - 0.6 * STEPS * 0.5
    assert summary["truth_contact_error_mm"]["max"] < 3.0
    check_servo_commands_within_limits(sent, START, STEPS, PERIOD_S)
