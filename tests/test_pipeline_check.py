"""Experiment configs and ``simshear pipeline check``: each bad config or bad data set gives one clear error naming
the file, key, column or value before anything trains; the shipped and the example sensor's configs pass."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from simshear_gym.data.adapter import FrameConfig, adapt_dataset
from simshear_gym.data.tactile_set import TactileDataError
from simshear_gym.pipelines.check import check
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.example_sensor import make_example
from simshear_gym.tables import ConfigError

ROOT = Path(__file__).resolve().parents[1]

GOOD = """
name = "lab"
[frame]
axes = ["x", "-z", "y"]
origin_mm = [0.0, -2.2, 0.0]
[check]
replay_rows = 8
[datasets.tap]
contact = "surface"
kind = "tap"
image_column = "file"
split_column = "subset"
split_values = { train = "tr", val = "te" }
absent = ["move"]
files = [{ csv = "labels.csv", images = "frames" }]
[datasets.tap.labels]
pose_x = { value = 0.0 }
pose_y = { column = "depth_m", unit = "m" }
pose_z = { value = 0.0 }
pose_rx = { column = "roll_rad", unit = "rad" }
pose_ry = { value = 0.0 }
pose_rz = { value = 0.0 }
"""


def write_lab(root: Path, rows: int = 12, size_px: int = 40, config: str = GOOD) -> Path:
    """A tiny lab set: ``labels.csv`` (depth 0.5..3 mm past the touch, roll +-10 deg) and grey frames."""
    (root / "frames").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    table = pd.DataFrame({
        "file": [f"f{i}.png" for i in range(rows)],
        "subset": ["tr" if i % 3 else "te" for i in range(rows)],
        "depth_m": np.linspace(0.5e-3, 3e-3, rows),
        "roll_rad": np.radians(np.linspace(-10, 10, rows)),
    })
    table.to_csv(root / "labels.csv", index=False)
    for name in table["file"]:
        cv2.imwrite(str(root / "frames" / name), rng.integers(0, 255, (size_px, size_px), dtype=np.uint8))
    path = root / "lab.toml"
    path.write_text(config)
    return path


def test_a_good_lab_set_passes_and_lands_in_the_simulations_frame(tmp_path):
    config = load_config(write_lab(tmp_path))
    reports = check(config, tmp_path)
    assert reports[0].rows == {"train": 8, "val": 4}
    assert reports[0].contact_share == 1.0
    adapted = adapt_dataset(config.datasets["tap"], config.frame, tmp_path)
    both = pd.concat([adapted["train"].targets, adapted["val"].targets])
    assert both["pose_3"].min() == pytest.approx(2.7) and both["pose_3"].max() == pytest.approx(5.2)  # 2.2 + depth
    assert both["pose_4"].abs().max() == pytest.approx(10.0)  # roll, rad -> deg, lab x = sim x
    assert adapted["train"].images.shape[1:] == (128, 128)


def test_frame_permutes_positions_angles_and_moves_as_a_rotation():
    frame = FrameConfig(axes=("x", "-z", "y"), origin_mm=(1.0, 2.0, 3.0))
    pose, move = frame.to_sim(np.array([[1.0, 5.0, 7.0, 10.0, 20.0, 30.0]]), np.array([[1.0, 2.0, 3.0, 4, 5, 6]]))
    np.testing.assert_allclose(pose, [[0.0, -4.0, 3.0, 10.0, -30.0, 20.0]])
    np.testing.assert_allclose(move, [[1.0, -3.0, 2.0, 4.0, -6.0, 5.0]])
    with pytest.raises(ValueError, match="reflection"):
        FrameConfig(axes=("x", "z", "y"))
    with pytest.raises(ValueError, match="each of x, y, z once"):
        FrameConfig(axes=("x", "x", "y"))


def test_unknown_key_names_file_and_key(tmp_path):
    path = write_lab(tmp_path, config=GOOD.replace("[check]", "[check]\nreplay_row = 3"))
    with pytest.raises(ConfigError, match=r"lab\.toml: \[check\] unknown key 'check\.replay_row'"):
        load_config(path)


def test_a_value_of_the_wrong_type_for_an_optional_key_names_key_and_value(tmp_path):
    config = GOOD + '\n[profiles.smoke.translator]\ncap_minutes = "ten"\n'
    path = write_lab(tmp_path, config=config)
    with pytest.raises(ConfigError, match=r"lab\.toml: .*translator\.cap_minutes = 'ten'; expected a number"):
        load_config(path)


def test_wrong_unit_name_says_which_units_are_valid(tmp_path):
    path = write_lab(tmp_path, config=GOOD.replace('unit = "rad"', 'unit = "radian"'))
    message = r"lab\.toml: \[datasets\.tap\] labels\.pose_rx\.unit = 'radian'.*'deg', 'rad'"
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_a_variable_neither_mapped_nor_absent_is_refused(tmp_path):
    path = write_lab(tmp_path, config=GOOD.replace("pose_rz = { value = 0.0 }\n", ""))
    with pytest.raises(ConfigError, match="'pose_rz' is neither mapped in labels nor declared absent"):
        load_config(path)


def test_missing_column_names_csv_and_column(tmp_path):
    path = write_lab(tmp_path, config=GOOD.replace('column = "roll_rad"', 'column = "roll"'))
    with pytest.raises(TactileDataError, match=r"labels\.csv: missing column 'roll'"):
        check(load_config(path), tmp_path)


def test_images_of_mixed_sizes_name_the_odd_file(tmp_path):
    path = write_lab(tmp_path)
    cv2.imwrite(str(tmp_path / "frames" / "f4.png"), np.zeros((30, 40), np.uint8))
    with pytest.raises(TactileDataError, match=r"f4\.png: 40x30 px, but .*f1\.png is 40x40 px"):
        check(load_config(path), tmp_path)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_labels_name_column_and_row(tmp_path, bad):
    path = write_lab(tmp_path)
    table = pd.read_csv(tmp_path / "labels.csv")
    table.loc[5, "depth_m"] = bad
    table.to_csv(tmp_path / "labels.csv", index=False)
    with pytest.raises(TactileDataError, match=r"column 'depth_m' \(pose_y\) row 5 is .*expected a finite number"):
        check(load_config(path), tmp_path)


def test_a_present_variable_that_is_constant_is_refused(tmp_path):
    path = write_lab(tmp_path)
    table = pd.read_csv(tmp_path / "labels.csv")
    table["roll_rad"] = 0.1
    table.to_csv(tmp_path / "labels.csv", index=False)
    with pytest.raises(TactileDataError, match=r"labels\.pose_rx \(column 'roll_rad'\) is constant"):
        check(load_config(path), tmp_path)


def test_an_empty_split_is_refused(tmp_path):
    path = write_lab(tmp_path)
    table = pd.read_csv(tmp_path / "labels.csv")
    table["subset"] = "tr"
    table.to_csv(tmp_path / "labels.csv", index=False)
    with pytest.raises(TactileDataError, match="the 'val' split is empty"):
        check(load_config(path), tmp_path)


def test_a_missing_image_is_named(tmp_path):
    path = write_lab(tmp_path)
    (tmp_path / "frames" / "f7.png").unlink()
    with pytest.raises(TactileDataError, match=r"f7\.png: missing"):
        check(load_config(path), tmp_path)


def test_a_corrupt_image_is_named(tmp_path):
    path = write_lab(tmp_path)
    (tmp_path / "frames" / "f2.png").write_bytes(b"not a png")
    with pytest.raises(TactileDataError, match=r"f2\.png: not a readable image"):
        check(load_config(path), tmp_path)


def test_a_wrong_frame_gives_blank_renders_and_an_error(tmp_path):
    path = write_lab(tmp_path, config=GOOD.replace('axes = ["x", "-z", "y"]', 'axes = ["x", "y", "z"]'))
    with pytest.raises(TactileDataError, match="make contact in simulation.*frame or depth mapping is wrong"):
        check(load_config(path), tmp_path)


def test_shipped_configs_parse():
    shipped = load_config(ROOT / "configs" / "tactip331.toml")
    assert set(shipped.datasets) == {"surface_shear", "surface_tap", "edge_shear", "edge_tap"}
    example = load_config(ROOT / "configs" / "example_lab.toml")
    assert example.sensor.dome_radius_mm == 22.0


@pytest.mark.data
def test_tactip331_config_passes_check(data_root):
    reports = check(load_config(ROOT / "configs" / "tactip331.toml"), data_root, max_rows_per_split=200)
    assert {report.name for report in reports} == {"surface_shear", "surface_tap", "edge_shear", "edge_tap"}
    assert all(report.contact_share >= 0.9 for report in reports)


@pytest.mark.data
def test_example_lab_maps_back_to_the_real_labels(data_root, tmp_path):
    make_example(data_root, tmp_path, rows_per_split=40)
    config = load_config(ROOT / "configs" / "example_lab.toml")
    reports = check(config, tmp_path)
    assert reports[0].source_image_px == (300, 280) and reports[0].contact_share >= 0.9
    adapted = adapt_dataset(config.datasets["surface_tap"], config.frame, tmp_path)
    varying = {v["name"] for v in reports[0].variables if v["varies"]}
    assert varying == {"pose_z", "pose_rx", "pose_ry"}
    z = adapted["train"].targets["pose_3"]
    assert 2.0 - 1e-9 <= z.min() and z.max() <= 5.0 + 1e-9  # the surface tap set's indentation range
    assert math.isclose(float(adapted["train"].targets["pose_6"].abs().max()), 0.0, abs_tol=1e-9)


def test_a_varying_label_the_chain_cannot_represent_is_refused(tmp_path):
    """A slide that changes the depth (sim move z: the lab's y here): the translator masks it and no GDNN reads it,
    so it is an error."""
    config = GOOD.replace('absent = ["move"]', 'absent = ["move_x", "move_z", "move_rx", "move_ry", "move_rz"]')
    config = config.replace('kind = "tap"', 'kind = "shear"') + 'move_y = { column = "depth_m", unit = "m" }\n'
    path = write_lab(tmp_path, config=config)
    with pytest.raises(TactileDataError, match=r"move_z varies \(a slide that changes the depth.*would be dropped"):
        check(load_config(path), tmp_path)
