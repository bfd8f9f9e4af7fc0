"""The ``[collect]`` protocol (lab/collect_protocol.py): its rows from the seed, the arm's path through the work
frame and the mount, the robot time per row, and the settings refused before the arm moves."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from simshear_gym.cli import main
from simshear_gym.data.tactile_set import read_set
from simshear_gym.lab.collect_protocol import CollectProtocol
from simshear_gym.pipelines.config import load_config
from simshear_gym.real.safety import SafetyConfig
from simshear_gym.tables import ConfigError

SURFACE = CollectProtocol(stimulus="surface", work_origin_base_mm=(300.0, 0.0, -100.0), rows=200, seed=3,
                          ranges={"pose_x": (-2.0, 2.0), "pose_z": (3.0, 5.0), "pose_rz": (-10.0, 10.0),
                                  "move_x": (-3.0, 3.0), "move_y": (-3.0, 3.0), "move_rz": (-5.0, 5.0)})
TOML = """
name = "lab"
[replay]
surface_depth_mm = 2.2
[datasets.tap]
contact = "surface"
kind = "tap"
image_pattern = "f{index}.png"
val_fraction = 0.2
absent = ["move"]
files = [{ csv = "labels.csv", images = "frames" }]
[datasets.tap.labels]
pose_x = { value = 0.0 }
pose_y = { value = 0.0 }
pose_z = { column = "z", unit = "mm" }
pose_rx = { value = 0.0 }
pose_ry = { value = 0.0 }
pose_rz = { value = 0.0 }
[collect]
stimulus = "surface"
work_origin_base_mm = [300.0, 0.0, -100.0]
rows = 6
seed = 1
ranges = { pose_z = [3.0, 5.0], move_x = [-2.0, 2.0], move_y = [-2.0, 2.0] }
"""


def test_rows_follow_the_seed_the_ranges_and_the_tap_share():
    rows = SURFACE.draw_rows()
    assert rows.equals(SURFACE.draw_rows()) and not rows.equals(replace(SURFACE, seed=4).draw_rows())
    assert len(rows) == 200 and set(rows["kind"]) == {"tap", "shear"}
    assert 3.0 <= rows["pose_3"].min() and rows["pose_3"].max() <= 5.0
    assert (rows.loc[rows["kind"] == "tap", [f"move_{i}" for i in range(1, 7)]] == 0).all().all()
    assert (rows[["pose_2", "pose_4", "pose_5", "move_3", "move_4", "move_5"]] == 0).all().all()
    assert rows["pose_6"].is_monotonic_increasing  # visited in order of the sensor's turn


def test_waypoints_put_the_dome_on_the_face_through_the_mount():
    T_base_work = SURFACE.T_base_work()
    touching = SURFACE.flange_pose(np.array([0.0, 0.0, 2.2, 0.0, 0.0, 0.0]), T_base_work)
    np.testing.assert_allclose(touching, [300.0, 0.0, -100.0 + 95.0, 0.0], atol=1e-9)  # apex on the face
    pressed = SURFACE.flange_pose(np.array([0.0, 0.0, 4.2, 0.0, 0.0, 0.0]), T_base_work)
    assert pressed[2] == pytest.approx(touching[2] - 2.0)  # 2 mm into the stimulus
    turned = replace(SURFACE, work_rz_deg=90.0)
    moved = turned.flange_pose(np.array([10.0, 0.0, 2.2, 0.0, 0.0, 0.0]), turned.T_base_work())
    np.testing.assert_allclose(moved[:3], [300.0, 10.0, -5.0], atol=1e-9)  # work x along base y
    row = pd.Series({**{f"pose_{i}": 0.0 for i in range(1, 7)}, **{f"move_{i}": 0.0 for i in range(1, 7)},
                     "pose_3": 4.0, "move_1": 2.0})
    points = SURFACE.row_waypoints(row, T_base_work)
    np.testing.assert_allclose(points["hover"][:3], [298.0, 0.0, -100.0 + 95.0 + 3.0], atol=1e-9)
    np.testing.assert_allclose(points["touch"][:3], [298.0, 0.0, -100.0 + 95.0 - 1.8], atol=1e-9)
    np.testing.assert_allclose(points["pose"][:3], [300.0, 0.0, -100.0 + 95.0 - 1.8], atol=1e-9)


def test_a_row_takes_under_a_second_at_the_default_speeds():
    _, waypoints, times = SURFACE.plan()
    assert len(times) == 200 and times.max() < 1.0 and 0.3 < times.mean()
    assert SURFACE.move_time_s(100.0) == pytest.approx(100.0 / 50.0 + 50.0 / 800.0)
    assert SURFACE.move_time_s(1.0) == pytest.approx(2.0 * np.sqrt(1.0 / 800.0))  # never reaches full speed
    safety = SafetyConfig()
    SURFACE.check_reach(waypoints, lambda pose: True, safety.max_move_mm, safety.max_move_deg,
                        safety.max_speed_mm_s)


@pytest.mark.parametrize("change, message", [
    (dict(ranges={"pose_z": (3.0, 5.0), "pose_rx": (-5.0, 5.0)}), r"ranges\.pose_rx: the MG400 cannot tilt"),
    (dict(ranges={"pose_z": (1.0, 5.0)}), r"ranges\.pose_z = \[1\.0, 5\.0\]: the indentation must lie past"),
    (dict(ranges={"pose_z": (3.0, 5.0), "pose_q": (0.0, 1.0)}), r"unknown variable 'pose_q'"),
    (dict(hover_mm=-1.0), r"hover_mm = -1\.0: the hover points must lie above the stimulus's face"),
    (dict(tap_share=1.5), r"tap_share must be in \[0, 1\]"),
])
def test_bad_settings_are_refused_before_anything_moves(change, message):
    with pytest.raises(ValueError, match=message):
        replace(SURFACE, **change)


def test_unreachable_or_unsafe_paths_are_refused_naming_row_and_point():
    far = replace(SURFACE, work_origin_base_mm=(900.0, 0.0, -100.0))
    _, waypoints, _ = far.plan()
    with pytest.raises(ValueError, match=r"row 0: the hover point .* out of the arm's reach"):
        far.check_reach(waypoints, lambda pose: True, 50.0, 45.0, 50.0)
    _, waypoints, _ = SURFACE.plan()
    with pytest.raises(ValueError, match=r"outside the safety layer's workspace"):
        SURFACE.check_reach(waypoints, lambda pose: pose[0] < 299.0, 50.0, 45.0, 50.0)
    with pytest.raises(ValueError, match=r"mm, over the 2 mm one queued move may jump"):
        SURFACE.check_reach(waypoints, lambda pose: True, 2.0, 45.0, 50.0)
    with pytest.raises(ValueError, match=r"speed_mm_s = 50 exceeds the safety layer's 20 mm/s"):
        SURFACE.check_reach(waypoints, lambda pose: True, 50.0, 45.0, 20.0)


def test_the_config_table_takes_the_replays_depth_and_refuses_unknown_keys(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text(TOML)
    protocol = load_config(path).collect
    assert protocol.surface_depth_mm == 2.2 and protocol.rows == 6 and protocol.ranges["pose_z"] == (3.0, 5.0)
    path.write_text(TOML + "speed = 3\n")
    with pytest.raises(ConfigError, match=r"\[collect\] unknown key 'collect\.speed'"):
        load_config(path)
    path.write_text(TOML + "surface_depth_mm = 2.0\n")
    with pytest.raises(ConfigError, match=r"\[replay\] surface_depth_mm's \(one place for it\)"):
        load_config(path)


def test_simulation_renders_the_protocols_rows_in_order(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text(TOML)
    assert main(["collect", "--protocol", str(path), "--out", str(tmp_path / "sim"), "--workers", "1"]) == 0
    rendered = read_set(tmp_path / "sim")
    rows = load_config(path).collect.draw_rows()
    columns = [f"pose_{i}" for i in range(1, 7)] + [f"move_{i}" for i in range(1, 7)]
    np.testing.assert_allclose(rendered.targets[columns].to_numpy(), rows[columns].to_numpy())
    assert len(list((tmp_path / "sim" / "images").iterdir())) == 6
