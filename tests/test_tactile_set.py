"""The tactile-data reader: round trip, cache, and one clear error per kind of malformed input."""

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS
from simshear_gym.data.tactile_set import (
    TactileDataError,
    read_set,
    write_image,
    write_targets,
)


def make_set(root: Path, n: int = 4, size: int = 32) -> Path:
    images = root / "images"
    images.mkdir(parents=True)
    rng = np.random.default_rng(0)
    rows = []
    for i in range(n):
        name = f"image_{i + 1}.png"
        write_image(images, name, rng.integers(0, 255, (size, size), dtype=np.uint8))
        rows.append({"sensor_image": name, **{c: float(i) for c in POSE_COLUMNS}, **{c: 0.5 for c in MOVE_COLUMNS}})
    write_targets(root, pd.DataFrame(rows), {"note": "test"})
    return root


def test_round_trip_and_cache(tmp_path):
    root = make_set(tmp_path / "set")
    tactile_set = read_set(root, image_size_px=32)
    assert len(tactile_set) == 4 and tactile_set.meta == {"note": "test"}
    images = tactile_set.load_images()
    assert images.shape == (4, 32, 32) and images.dtype == np.uint8
    np.testing.assert_array_equal(images[2], cv2.imread(str(root / "images/image_3.png"), cv2.IMREAD_GRAYSCALE))
    np.testing.assert_array_equal(tactile_set.load_images(), images)  # second call served from the cache
    np.testing.assert_allclose(tactile_set.poses()[3], 3.0)
    assert tactile_set.shear_sensor().shape == (4, 6)


def test_missing_targets_file(tmp_path):
    with pytest.raises(TactileDataError, match="targets.csv: missing"):
        read_set(tmp_path)


def test_missing_column_is_named(tmp_path):
    root = make_set(tmp_path / "set")
    pd.read_csv(root / "targets.csv").drop(columns=["pose_3"]).to_csv(root / "targets.csv", index=False)
    with pytest.raises(TactileDataError, match="column 'pose_3' is missing"):
        read_set(root)


def test_non_numeric_label_names_row_and_column(tmp_path):
    root = make_set(tmp_path / "set")
    targets = pd.read_csv(root / "targets.csv")
    targets["pose_5"] = targets["pose_5"].astype(object)
    targets.loc[2, "pose_5"] = "twelve"
    targets.to_csv(root / "targets.csv", index=False)
    with pytest.raises(TactileDataError, match=r"row 3, column 'pose_5': value 'twelve' is not a finite number"):
        read_set(root)


def test_missing_image_file_is_named(tmp_path):
    root = make_set(tmp_path / "set")
    (root / "images/image_2.png").unlink()
    with pytest.raises(TactileDataError, match=r"image_2.png: missing \(row 2 of targets.csv\)"):
        read_set(root)


def test_wrong_image_size_is_named(tmp_path):
    root = make_set(tmp_path / "set")
    write_image(root / "images", "image_3.png", np.zeros((16, 16), np.uint8))
    tactile_set = read_set(root)
    with pytest.raises(TactileDataError, match=r"image_3.png: image size 16x16 px, expected 32x32 px"):
        tactile_set.load_images(use_cache=False)
    with pytest.raises(TactileDataError, match=r"expected 64x64 px"):
        read_set(root, image_size_px=64)


def test_corrupt_image_is_named(tmp_path):
    root = make_set(tmp_path / "set")
    (root / "images/image_4.png").write_bytes(b"not a png")
    with pytest.raises(TactileDataError, match="image_4.png: cannot be read"):
        read_set(root).load_images(use_cache=False)


@pytest.mark.data
def test_reads_published_real_set(data_root):
    from simshear_gym.data.paths import real_set_dir

    tactile_set = read_set(real_set_dir(data_root, "edge", "shear", "val"), POSE_COLUMNS + MOVE_COLUMNS, 128)
    assert len(tactile_set) == 2000
    poses = tactile_set.poses()
    assert poses[:, 1].min() >= -6 and poses[:, 1].max() <= 6  # offset across the edge, mm
