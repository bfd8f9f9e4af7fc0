"""A policy of ``simshear train rl`` runs unchanged through ``simshear rollout --policy`` on the hardware-in-the-loop
path: the MG400 emulator over TCP with the simulated camera (``sim-surface``: the sim TacTip rendered at the pose the
emulator reports, translated by the shipped shPix2pix, as a 640x480 frame through the real preprocessing), the
policy's observation rebuilt from its run folder (estimate of the servo controller's estimator, history,
VecNormalize), and every command inside the safety limits."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator

import numpy as np
import pytest
import torch

from simshear_gym import cli
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
from simshear_gym.train.rl import RLTrainConfig, train
from tests.rehearsal import check_servo_commands_within_limits as check_within_limits

torch.set_num_threads(1)
STEPS = 20
PERIOD_S = 0.1


@pytest.fixture
def emulator() -> Iterator[MG400Emulator]:
    emu = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0)).start()
    yield emu
    emu.stop()


@pytest.mark.parametrize("residual_bound", [0.0, 0.3])
def test_a_trained_policy_runs_through_rollout_on_the_emulator_within_the_limits(emulator, tmp_path, residual_bound):
    run_dir = tmp_path / "ppo"
    config = RLTrainConfig(timesteps=32, observation="tactile+estimate", history=2, obs_mode="real",
                           image_size_px=64, n_steps=16, batch_size=16, n_epochs=2, checkpoint_steps=32,
                           residual_bound=residual_bound)
    train(config, run_dir, progress=False)
    out = tmp_path / "rollout"
    code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", "sim-surface", "--policy",
                     str(run_dir / "model.zip"), "--steps", str(STEPS), "--period-s", str(PERIOD_S), "--out",
                     str(out), "--dashboard-port", str(emulator.dashboard_port), "--motion-port",
                     str(emulator.motion_port), "--feedback-port", str(emulator.feedback_port)])
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0, summary
    assert summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["commands_sent"] == STEPS
    assert summary["controller"].startswith("ppo:")
    env_config = summary["config"]
    assert (env_config["observation"], env_config["history"], env_config["image_size_px"]) == (
        "tactile+estimate", 2, 64)  # the policy's settings, from its run folder
    assert "--policy" in summary["command"]
    with open(out / "steps.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    actions = np.array([[float(row[f"action_{i}"]) for i in range(4)] for row in rows[1:]])
    assert actions.shape == (STEPS, 4) and np.all(np.abs(actions) <= 1.0)
    check_servo_commands_within_limits(emulator, STEPS, PERIOD_S)
    assert "truth_contact_error_mm" in summary  # the simulated camera's ground truth was logged


SHIPPED_TRACKING = "simshear_gym/models/weights/policies/tracking_ppo/model.pt"


def check_servo_commands_within_limits(emulator: MG400Emulator, steps: int, period_s: float) -> None:
    """Every ServoP the emulator received passes the safety layer's checks again (from the rollout's start)."""
    check_within_limits(emulator.received_commands("motion"), (300.0, 0.0, 0.0, 0.0), steps, period_s)


@pytest.mark.parametrize("camera", ["sim-surface", pytest.param("replayed", marks=pytest.mark.data)])
def test_the_shipped_tracking_policy_runs_unchanged_on_the_emulator_within_the_limits(emulator, tmp_path, camera,
                                                                                       request):
    """The shipped policy folder, as it is, through ``simshear rollout --policy``: with the simulated camera, and
    with a replayed camera (the 100 raw 640x480 TacTip frames of the data set through the real preprocessing).
    The robot side never sees a command outside the default limits."""
    from pathlib import Path

    source = "sim-surface"
    if camera == "replayed":
        source = str(request.getfixturevalue("data_root") / "tactip331_raw" / "images")
    out = tmp_path / "rollout"
    code = cli.main(["rollout", "--robot", "127.0.0.1", "--camera", source, "--policy", SHIPPED_TRACKING,
                     "--steps", str(STEPS), "--period-s", str(PERIOD_S), "--out", str(out),
                     "--dashboard-port", str(emulator.dashboard_port), "--motion-port", str(emulator.motion_port),
                     "--feedback-port", str(emulator.feedback_port)])
    summary = json.loads((out / "rollout.json").read_text())
    assert code == 0, summary
    assert Path(SHIPPED_TRACKING).is_file()
    assert summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["controller"].startswith("ppo:")
    assert (summary["config"]["observation"], summary["config"]["history"]) == ("estimate", 4)
    check_servo_commands_within_limits(emulator, STEPS, PERIOD_S)
