"""The frame check of ``simshear pipeline check`` (pipelines/check.py): real images that change with each
label the way the replayed renders do pass; a label the wrong way round, a wrong mount angle or a set recorded with
another mount under one ``[frame]`` fails, naming the config key.

The first tests use a stand-in sensor whose "real" images are a blurred, saturated copy of the renders with pin
texture and noise; the data tests flip each sign of the shipped and the example lab's configs in turn."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from simshear_gym.data.tactile_set import TactileDataError
from simshear_gym.pipelines.check import MIN_T, check, check_frame, flipped, turned
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.example_sensor import make_example
from simshear_gym.sim.replay import ReplayScene

ROOT = Path(__file__).resolve().parents[1]
ROWS = 240


def stand_in_sensor(renders: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """"Real" images of the rows: pins (a fixed dot texture) whose brightness follows the blurred contact, plus
    noise; another response than the renders', in the same places."""
    pins = (rng.random(renders.shape[1:]) > 0.7).astype(np.float32)
    images = []
    for render in renders.astype(np.float32):
        contact = np.tanh(cv2.GaussianBlur(render, (0, 0), 3.0) / 8.0)
        image = 120.0 + 80.0 * pins * (1.0 - contact) + 60.0 * contact + rng.normal(0.0, 20.0, render.shape)
        images.append(np.clip(image, 0, 255).astype(np.uint8))
    return np.stack(images)


@pytest.fixture(scope="module")
def surface_rows():
    """(poses, real images, render function) of a surface tap set seen by the stand-in sensor."""
    rng = np.random.default_rng(0)
    poses = np.zeros((ROWS, 6))
    poses[:, 2] = rng.uniform(2.5, 5.0, ROWS)
    poses[:, 3:5] = rng.uniform(-15.0, 15.0, (ROWS, 2))
    scene = ReplayScene("surface")
    render = lambda batch: np.stack([scene.render(pose) for pose in batch])  # noqa: E731
    yield poses, stand_in_sensor(render(poses), rng), render
    scene.close()


def test_labels_that_match_the_images_pass(surface_rows):
    poses, images, render = surface_rows
    found = check_frame(poses, images, render, "surface")
    assert [v.variable for v in found.variables] == ["pose_z", "pose_rx", "pose_ry"]
    assert all(v.verdict == "ok" and v.flip_t < 0 for v in found.variables), found
    assert found.best_turn_deg() is None and found.agreement > 0.1


@pytest.mark.parametrize("index, variable", [(2, "pose_z"), (3, "pose_rx"), (4, "pose_ry")])
def test_a_label_the_wrong_way_round_is_found(surface_rows, index, variable):
    poses, images, render = surface_rows
    found = check_frame(flipped(poses, index), images, render, "surface")
    verdicts = {v.variable: v.verdict for v in found.variables}
    assert verdicts[variable] == "flipped", found
    assert [v.flip_t > MIN_T for v in found.variables].count(True) == 1  # only that one


def test_a_turned_mount_is_found(surface_rows):
    poses, images, render = surface_rows
    found = check_frame(turned(poses, "surface", 90), images, render, "surface")
    assert found.best_turn_deg() == 270  # turning the labels back agrees best


def test_images_without_signal_raise_no_alarm(surface_rows):
    poses, _, render = surface_rows
    noise = np.random.default_rng(1).integers(0, 256, (ROWS, 128, 128), dtype=np.uint8)
    found = check_frame(poses, noise, render, "surface")
    assert found.best_turn_deg() is None and all(v.verdict in ("ok", "unchecked") for v in found.variables)


# ------------------------------------------------------------------------------------- the shipped configs
def tactip331_config(tmp_path: Path, dataset: str, replace: tuple[str, str] | None = None) -> Path:
    """configs/tactip331.toml with ``dataset`` alone and no profiles (and a text replacement)."""
    text = (ROOT / "configs" / "tactip331.toml").read_text()
    text = text[:text.index("[profiles.")]  # the profiles name both contact types
    head, _, tables = text.partition("[datasets.")
    blocks = re.split(r"(?m)^(?=\[datasets\.)", "[datasets." + tables)
    keep = "".join(block for block in blocks if block.startswith((f"[datasets.{dataset}]",
                                                                  f"[datasets.{dataset}.")))
    text = head + keep
    if replace is not None:
        assert replace[0] in text
        text = text.replace(*replace)
    path = tmp_path / "tactip331.toml"
    path.write_text(text)
    return path


@pytest.mark.data
@pytest.mark.parametrize("dataset, key, column, message", [
    ("surface_tap", "pose_z", "pose_3", r"make contact in simulation .*labels\.pose_z \(column 'pose_3', scale -1\)"),
    ("surface_tap", "pose_rx", "pose_4", r"sim pose_rx the opposite way .*labels\.pose_rx \(column 'pose_4'"),
    ("surface_tap", "pose_ry", "pose_5", r"sim pose_ry the opposite way .*labels\.pose_ry \(column 'pose_5'"),
    ("edge_tap", "pose_y", "pose_2", r"sim pose_y the opposite way .*labels\.pose_y \(column 'pose_2'"),
    ("edge_tap", "pose_rz", "pose_6", r"sim pose_rz the opposite way .*labels\.pose_rz \(column 'pose_6'"),
])
def test_tactip331_with_a_sign_flipped_fails_naming_the_key(data_root, tmp_path, dataset, key, column, message):
    unit = "deg" if key.startswith("pose_r") else "mm"
    path = tactip331_config(tmp_path, dataset, (f'{key} = {{ column = "{column}", unit = "{unit}" }}',
                                                f'{key} = {{ column = "{column}", unit = "{unit}", scale = -1 }}'))
    with pytest.raises(TactileDataError, match=message):
        check(load_config(path), data_root)


@pytest.mark.data
@pytest.mark.parametrize("dataset", ["surface_tap", "edge_tap", "surface_shear", "edge_shear"])
def test_tactip331_sets_pass_the_frame_check(data_root, tmp_path, dataset):
    (report,) = check(load_config(tactip331_config(tmp_path, dataset)), data_root)
    assert report.frame is not None and report.frame["rows"] == 480
    assert all(v["verdict"] == "ok" for v in report.frame["variables"])


@pytest.fixture(scope="module")
def example_data(data_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("example_lab")
    make_example(data_root, out, rows_per_split=600)
    return out


def example_config(tmp_path: Path, old: str = "", new: str = "") -> Path:
    text = (ROOT / "configs" / "example_lab.toml").read_text()
    assert old in text
    path = tmp_path / "example_lab.toml"
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.data
def test_the_example_lab_passes_the_frame_check(example_data, tmp_path):
    (report,) = check(load_config(example_config(tmp_path)), example_data)
    assert report.frame["rows"] == 480 and all(v["verdict"] == "ok" for v in report.frame["variables"])


@pytest.mark.data
@pytest.mark.parametrize("key, column, unit, message", [
    ("pose_y", "sensor_y_m", "m", r"labels\.pose_y \(column 'sensor_y_m', scale -1\)"),
    ("pose_rx", "roll_rad", "rad", r"sim pose_rx the opposite way .*labels\.pose_rx \(column 'roll_rad'"),
    ("pose_rz", "yaw_rad", "rad", r"sim pose_ry the opposite way .*labels\.pose_rz \(column 'yaw_rad'"),
])
def test_the_example_lab_with_a_sign_flipped_fails_naming_the_key(example_data, tmp_path, key, column, unit,
                                                                   message):
    path = example_config(tmp_path, f'{key} = {{ column = "{column}", unit = "{unit}" }}',
                          f'{key} = {{ column = "{column}", unit = "{unit}", scale = -1 }}')
    with pytest.raises(TactileDataError, match=message):
        check(load_config(path), example_data)


@pytest.mark.data
def test_a_turned_mount_fails_naming_mount_rz(data_root, tmp_path):
    path = tactip331_config(tmp_path, "edge_tap", ("mount_rz_deg = 0.0", "mount_rz_deg = 90.0"))
    with pytest.raises(TactileDataError, match=r"dataset 'edge_tap': .*\[frame\] mount_rz_deg = 90"):
        check(load_config(path), data_root)  # the edge offset turned onto sim x, along the edge


@pytest.mark.data
def test_tilt_axes_turned_fail_naming_the_frame_axes(example_data, tmp_path):
    """The lab's roll read as sim Ry and its yaw as sim Rx: the tilt vector turned by 90 deg."""
    path = example_config(tmp_path, 'axes = ["x", "-z", "y"]', 'axes = ["-z", "-x", "y"]')
    with pytest.raises(TactileDataError, match=r"sensor turned (90|270) deg about its axis.*\[frame\] axes"):
        check(load_config(path), example_data)


@pytest.mark.data
def test_two_mounts_under_one_frame_fail_and_pass_with_a_frame_each(data_root, example_data, tmp_path):
    """The example lab's horizontal mount and tactip331's downward one in one config."""
    shipped = tactip331_config(tmp_path, "surface_tap").read_text()
    shipped_tables = shipped[shipped.index("[datasets.surface_tap]"):]
    shipped_tables = shipped_tables.replace("tactip331/", f"{data_root.resolve()}/tactip331/")
    shipped_tables = shipped_tables.replace("[datasets.surface_tap", "[datasets.downward_tap")
    text = (ROOT / "configs" / "example_lab.toml").read_text() + "\n" + shipped_tables
    one_frame = tmp_path / "one_frame.toml"
    one_frame.write_text(text)
    with pytest.raises(TactileDataError, match=r"dataset 'downward_tap'.*labels\.pose_"):
        check(load_config(one_frame), example_data)
    own_frame = tmp_path / "own_frame.toml"
    own_frame.write_text(text + '\n[datasets.downward_tap.frame]\naxes = ["x", "y", "z"]\n')
    reports = check(load_config(own_frame), example_data)
    assert [r.name for r in reports] == ["surface_tap", "downward_tap"]
    assert all(v["verdict"] == "ok" for r in reports for v in r.frame["variables"])
