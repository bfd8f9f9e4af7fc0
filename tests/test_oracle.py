"""The oracle controller: its law, and tracking within 0.5 mm mean contact error on every trajectory."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simshear_gym import cli
from simshear_gym.control.oracle import (
    OracleController,
    OracleGains,
    true_pose_shear_from_info,
)
from simshear_gym.envs.trajectories import TRAJECTORIES
from simshear_gym.evaluate.oracle import run_episode


def observation(depth=4.0, x=0.0, y=0.0, rz=0.0):
    return {"true_pose_shear": np.array([depth, x, y, rz], dtype=np.float32)}


def test_the_law_moves_against_the_error_in_full_scale_units():
    controller = OracleController(gains=OracleGains(ki=(0.0,) * 4))
    action = controller(observation(depth=4.25, x=0.5, y=-0.2, rz=1.0))
    np.testing.assert_allclose(action, [-0.5, 0.2, -0.25, -0.5], atol=1e-6)  # 1 mm and 2 deg full scale
    assert action.dtype == np.float32
    np.testing.assert_allclose(controller(observation(x=7.0, rz=-9.0)), [-1.0, 0.0, 0.0, 1.0])  # clipped


def test_the_integral_removes_the_lag_behind_a_moving_plate():
    """A 1-D loop like the env's: the plate moves 0.4 mm per step; the error is the sensor's displacement."""
    def steady_error(ki):
        controller, error = OracleController(gains=OracleGains(ki=(ki,) * 4)), 0.0
        for _ in range(60):
            error += controller(observation(x=error))[0] * 1.0 - 0.4
        return abs(error)
    assert steady_error(0.0) == pytest.approx(0.4, abs=1e-6)  # proportional only: one step behind
    assert steady_error(0.5) < 1e-6


def test_the_oracle_needs_the_true_pose_and_shear():
    with pytest.raises(ValueError, match="obs_mode='oracle'"):
        OracleController()({"tactile": np.zeros((1, 128, 128), np.uint8)})
    with pytest.raises(ValueError, match="PIGains"):
        OracleGains(kp=(1.0, 1.0, 1.0))


def test_true_pose_shear_from_a_batched_info():
    info = {"depth_mm": np.array([4.0, 3.5]), "shear_sensor_mm_deg": np.arange(12.0).reshape(2, 6)}
    np.testing.assert_allclose(true_pose_shear_from_info(info), [[4.0, 0, 1, 5], [3.5, 6, 7, 11]])


@pytest.mark.parametrize("trajectory", TRAJECTORIES)
def test_oracle_tracks_every_trajectory_within_half_a_millimetre(trajectory):
    episode = run_episode(trajectory, seed=1, randomise=True)
    assert episode["termination"] == "" and len(episode["errors_mm"]) == 500
    assert episode["errors_mm"].mean() <= 0.5 and episode["steps_out_of_contact"] == 0


def test_evaluate_oracle_writes_results_with_the_command(tmp_path):
    assert cli.main(["evaluate", "oracle", "--seeds", "0", "--out", str(tmp_path)]) == 0  # nominal episodes
    result = json.loads((tmp_path / "oracle.json").read_text())
    assert result["command"] == f"simshear evaluate oracle --seeds 0 --out {tmp_path}" and result["all_goals_met"]
    for trajectory in TRAJECTORIES:
        row = result["trajectories"][trajectory]
        assert row["all"]["episodes"] == 1 and row["all"]["mean_mm"] <= 0.5
        assert {"mean_mm", "std_mm", "max_mm", "contact_losses_steps"} <= set(row["all"])
