"""``simshear rollout`` end to end against the MG400 emulator with a folder camera (and an SB3 policy)."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from simshear_gym import cli
from simshear_gym.contract import policy_spaces
from simshear_gym.control.policy import SB3Controller
from simshear_gym.control.policy_files import save_policy
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
from simshear_gym.real.rollout import sb3_algorithm

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def posenet_path() -> str:
    """The shipped surface GDNN (the one the servo controller uses by default)."""
    from simshear_gym.models.zoo import posenet_weights

    return str(posenet_weights("surface"))


@pytest.fixture
def emulator() -> Iterator[MG400Emulator]:
    emu = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                       joint_speed_deg_s=400.0)).start()
    yield emu
    emu.stop()


@pytest.fixture
def raw_frames(tmp_path) -> Path:
    """Six 640x480 camera-like frames: bright pins on a dark membrane, shifted a little from frame to frame."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for index in range(6):
        frame = np.full((480, 640, 3), 30, np.uint8)
        for y in range(40, 470, 24):
            for x in range(95, 520, 24):
                cv2.circle(frame, (x + index, y), 6, (230, 230, 230), -1)
        cv2.imwrite(str(folder / f"image_{index + 1}.png"), frame)
    return folder


def rollout_args(emu: MG400Emulator, camera: Path, controller: str, out: Path, steps: int, *extra: str) -> list[str]:
    return ["rollout", "--robot", "127.0.0.1", "--camera", str(camera), "--controller", controller,
            "--steps", str(steps), "--out", str(out), "--period-s", "0.05", "--image-size", "64",
            "--dashboard-port", str(emu.dashboard_port), "--motion-port", str(emu.motion_port),
            "--feedback-port", str(emu.feedback_port), *extra]


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def servo_commands(emu: MG400Emulator) -> list[str]:
    return [c for c in emu.received_commands("motion") if c.lower().startswith("servop")]


def test_servo_rollout_writes_its_log_and_figure(emulator, raw_frames, tmp_path, capsys):
    out = tmp_path / "run"
    code = cli.main(rollout_args(emulator, raw_frames, "servo", out, 4, "--posenet", posenet_path()))
    assert code == 0, capsys.readouterr()
    rows = read_rows(out / "steps.csv")
    assert [int(row["step"]) for row in rows] == [0, 1, 2, 3, 4]
    for key in ("time_s", "tcp_x_mm", "tcp_target_z_mm", "flange_r_deg", "action_0", "estimate_depth_mm",
                "estimate_std_shear_x_mm", "policy_ms", "robot_mode", "safety_event"):
        assert key in rows[0]
    assert all(np.isfinite(float(row["estimate_depth_mm"])) for row in rows[1:])
    times = [float(row["time_s"]) for row in rows]
    assert times == sorted(times) and times[-1] >= 4 * 0.05 * 0.9
    summary = json.loads((out / "rollout.json").read_text())
    assert summary["termination"] == "" and summary["steps_run"] == 4 and summary["commands_sent"] == 4
    assert summary["command"].startswith("simshear rollout --robot 127.0.0.1")
    assert summary["config"]["control_period_s"] == 0.05
    assert (out / "trajectory.png").read_bytes()[:8] == PNG_MAGIC
    sent = servo_commands(emulator)
    assert len(sent) == 4
    # the last commanded target in the log is the one the emulator received last
    last = rows[-1]
    numbers = [float(v) for v in sent[-1][len("ServoP("):].split(",")[:4]]
    assert numbers == pytest.approx([float(last[f"flange_target_{n}"]) for n in ("x_mm", "y_mm", "z_mm", "r_deg")],
                                    abs=1e-5)


def test_rollout_stops_when_the_recording_ends(emulator, raw_frames, tmp_path, capsys):
    out = tmp_path / "run"
    code = cli.main(rollout_args(emulator, raw_frames, "servo", out, 20, "--posenet", posenet_path()))
    assert code == 1
    summary = json.loads((out / "rollout.json").read_text())
    assert summary["termination"] == "camera_ended" and summary["steps_run"] == 6  # reset reads frame 1
    assert "no more images" in summary["safety_events"][0]
    assert "ended: camera_ended" in capsys.readouterr().out


def _save_ppo(path: Path, image_size_px: int) -> Path:
    import gymnasium as gym
    from stable_baselines3 import PPO

    observation_space, action_space = policy_spaces(image_size_px)

    class Spaces(gym.Env):
        def __init__(self) -> None:
            self.observation_space, self.action_space = observation_space, action_space

        def reset(self, *, seed=None, options=None):
            return self.observation_space.sample(), {}

        def step(self, action):
            return self.observation_space.sample(), 0.0, False, False, {}

    model = PPO("MultiInputPolicy", Spaces(), n_steps=8, batch_size=8, device="cpu", seed=0)
    model.save(path)
    save_policy(model, path)  # the pickle-free files beside the .zip, as simshear train rl writes them
    return path


def test_sb3_policy_rollout_in_dry_run_sends_nothing(emulator, raw_frames, tmp_path):
    model = _save_ppo(tmp_path / "ppo.zip", 64)
    assert sb3_algorithm(model) == "ppo"
    out = tmp_path / "run"
    code = cli.main(rollout_args(emulator, raw_frames, str(model), out, 3, "--dry-run"))
    assert code == 0
    summary = json.loads((out / "rollout.json").read_text())
    assert summary["controller"].startswith("ppo:") and summary["dry_run"] and summary["commands_sent"] == 0
    assert emulator.received_commands("motion") == []
    rows = read_rows(out / "steps.csv")
    assert len(rows) == 4 and "estimate_depth_mm" not in rows[0]
    actions = np.array([[float(row[f"action_{i}"]) for i in range(4)] for row in rows[1:]])
    assert np.all(np.abs(actions) <= 1.0)
    assert (out / "trajectory.png").is_file()


def test_sb3_policy_for_other_spaces_is_refused(emulator, raw_frames, tmp_path, capsys):
    model = _save_ppo(tmp_path / "ppo128.zip", 128)
    with pytest.raises(ValueError, match="trained on observations"):
        SB3Controller.load(model, *policy_spaces(64))
    not_a_model = tmp_path / "x.zip"
    not_a_model.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model"):
        sb3_algorithm(not_a_model)
    with pytest.raises(ValueError, match=r"x\.zip: a Stable-Baselines3 \.zip without its pickle-free x\.pt"):
        SB3Controller.load(not_a_model, *policy_spaces(64))  # a .zip alone is never unpickled
    with pytest.raises(FileNotFoundError, match=r"no policy at .*missing\.zip.: expected <stem>\.pt"):
        SB3Controller.load(tmp_path / "missing.zip", *policy_spaces(64))
    # the command line names its flags (before anything moves: nothing reaches the robot)
    assert cli.main(rollout_args(emulator, raw_frames, str(model), tmp_path / "run", 2)) == 2
    assert "check --image-size" in capsys.readouterr().err
    assert cli.main(rollout_args(emulator, raw_frames, str(tmp_path / "missing.zip"), tmp_path / "run", 2)) == 2
    assert "is neither one of ('servo', 'edge', 'push') nor" in capsys.readouterr().err
    assert emulator.received_commands("motion") == []


def test_real_cycle_measures_every_stage_against_the_emulator(emulator, raw_frames):
    from simshear_gym.evaluate.real_cycle import measure
    from simshear_gym.real.camera import CameraSource

    with CameraSource(raw_frames) as source:
        frames = list(source)
    ports = (emulator.dashboard_port, emulator.motion_port, emulator.feedback_port)
    result = measure(frames, ports, cycles=12, warmup=2, image_size_px=64, posenet=posenet_path())
    for stage in ("preprocess", "controller", "command", "total", "gdnn_alone"):
        assert 0.0 < result[stage]["median_ms"] <= result[stage]["p95_ms"] <= result[stage]["max_ms"]
    total = result["total"]["median_ms"]
    assert total >= result["controller"]["median_ms"] and total >= result["command"]["median_ms"]
    assert result["servo_p_commands_sent"] == 14 == len(servo_commands(emulator))


@pytest.mark.parametrize("module", ["simshear_gym.real.rollout", "simshear_gym.evaluate.servo", "simshear_gym.demo"])
def test_every_option_says_what_it_is_for(module):
    import argparse
    import importlib

    parser = argparse.ArgumentParser()
    importlib.import_module(module).add_arguments(parser)
    options = [action for action in parser._actions if action.option_strings and action.dest != "help"]
    assert options and [a.option_strings for a in options if not (a.help or "").strip()] == []


def test_sensor_option_names_what_is_missing_and_excludes_posenet(emulator, raw_frames, tmp_path, capsys):
    args = rollout_args(emulator, raw_frames, "servo", tmp_path / "run", 2)
    assert cli.main(args + ["--sensor", str(tmp_path / "nowhere")]) == 2
    assert "run `simshear pipeline run CONFIG` first" in capsys.readouterr().err
    assert cli.main(args + ["--sensor", str(tmp_path), "--posenet", "w.pt"]) == 2
    assert "not both" in capsys.readouterr().err
    assert emulator.received_commands("motion") == []
