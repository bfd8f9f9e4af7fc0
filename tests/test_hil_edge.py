"""Edge following rehearsed on the real path: ``simshear rollout --camera sim-edge --controller edge`` drives the MG400
emulator over TCP round a simulated object's edge (the sim TacTip rendered where the emulator says the flange is,
translated by the shipped edge shPix2pix, as a 640x480 frame through the real preprocessing), every command inside
the safety limits."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from simshear_gym import cli
from simshear_gym.real.camera import default_config, preprocess
from simshear_gym.real.hil import embed_in_frame
from simshear_gym.real.hil_edge import EdgeObjectConfig, SimEdgeCamera
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
from tests.rehearsal import check_servo_commands_within_limits

START = (300.0, 0.0, 0.0, 0.0)
STEPS = 60
PERIOD_S = 0.1


def test_the_edge_camera_starts_on_the_edge_and_its_frames_survive_the_preprocessing():
    camera = SimEdgeCamera(lambda: START, START, EdgeObjectConfig(outline="clover", start_arc_mm=20.0))
    try:
        image = camera.read()
        truth = camera.history[-1]
        assert truth.in_contact and truth.penetration_mm == pytest.approx(1.8, abs=1e-6)
        assert truth.contact_error_mm == pytest.approx(0.0, abs=1e-6)
        back = preprocess(embed_in_frame(image, default_config()), default_config())
        assert np.mean((back > 127) == (image > 127)) > 0.98
        # 2 mm across the edge, over the air: the distance to the edge follows the flange
        moved = SimEdgeCamera(lambda: (START[0], START[1] + 2.0, START[2], START[3]), START,
                              EdgeObjectConfig(outline="clover", start_arc_mm=20.0))
        moved.read()
        assert moved.history[-1].contact_error_mm == pytest.approx(2.0, abs=0.05)
        moved.close()
    finally:
        camera.close()
    with pytest.raises(ValueError, match="outline"):
        EdgeObjectConfig(outline="triangle")


def test_edge_following_rollout_runs_on_the_emulator_within_the_limits(tmp_path):
    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0)).start()
    out = tmp_path / "rollout"
    try:
        code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-edge", "--controller", "edge",
                         "--outline", "wavy", "--steps", str(STEPS), "--period-s", str(PERIOD_S), "--out", str(out),
                         "--dashboard-port", str(emulator.dashboard_port), "--motion-port",
                         str(emulator.motion_port), "--feedback-port", str(emulator.feedback_port)])
        sent = emulator.received_commands("motion")
    finally:
        emulator.stop()
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0, summary
    assert summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["commands_sent"] == STEPS
    assert summary["controller"] == "edge_servo" and "--controller edge" in summary["command"]
    # round the edge, not off it: 0.5 mm a command along it, centred on it
    assert summary["truth_progress_mm"] > 0.6 * STEPS * 0.5
    assert summary["truth_contact_error_mm"]["mean"] < 1.0 and summary["truth_contact_error_mm"]["max"] < 3.0
    with open(out / "steps.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert {"estimate_y_mm", "estimate_depth_mm", "estimate_edge_angle_deg"} <= set(rows[0])
    check_servo_commands_within_limits(sent, START, STEPS, PERIOD_S)


def test_edge_rollout_refuses_what_it_cannot_do(tmp_path, capsys):
    code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-edge", "--controller", "edge",
                     "--min-depth-mm", "3", "--steps", "1", "--out", str(tmp_path)])
    assert code != 0 and "--min-depth-mm" in capsys.readouterr().err
    assert not (tmp_path / "rollout.json").exists()  # refused before anything connected or moved


def test_the_shipped_edge_policy_follows_the_edge_on_the_emulator_with_the_edge_estimator(tmp_path):
    """``simshear rollout --task edge-follow --policy``: the policy's estimate observation is made by the edge
    law's estimator (the edge GDNN, its four slots), as in ``SimShearEdgeFollow-v0``."""
    from simshear_gym.models.zoo import policy_folder

    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0)).start()
    out = tmp_path / "rollout"
    try:
        code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-edge", "--task", "edge-follow",
                         "--policy", str(policy_folder("edge_ppo") / "model.pt"), "--outline", "wavy", "--steps",
                         str(STEPS), "--period-s", str(PERIOD_S), "--out", str(out), "--dashboard-port",
                         str(emulator.dashboard_port), "--motion-port", str(emulator.motion_port),
                         "--feedback-port", str(emulator.feedback_port)])
        sent = emulator.received_commands("motion")
    finally:
        emulator.stop()
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0 and summary["termination"] == "" and summary["safety_events"] == []
    assert summary["controller"].startswith("ppo") and summary["config"]["observation"] == "estimate"
    assert summary["truth_progress_mm"] > 0.6 * STEPS * 0.5
    assert summary["truth_contact_error_mm"]["mean"] < 1.0 and summary["truth_contact_error_mm"]["max"] < 3.0
    check_servo_commands_within_limits(sent, START, STEPS, PERIOD_S)


def test_the_task_picks_the_law_and_refuses_another(tmp_path, capsys):
    from simshear_gym.models.zoo import policy_folder

    base = ["rollout", "--robot", "127.0.0.1", "--steps", "1", "--out", str(tmp_path)]
    code = cli.main([*base, "--camera", "sim-edge", "--task", "edge-follow", "--controller", "servo"])
    assert code != 0 and "--task edge-follow runs the edge law; got --controller servo" in capsys.readouterr().err
    code = cli.main([*base, "--camera", "sim-surface", "--task", "tracking", "--policy",
                     str(policy_folder("edge_ppo") / "model.pt")])
    assert code != 0 and "a policy trained on edge" in capsys.readouterr().err
    assert not (tmp_path / "rollout.json").exists()
