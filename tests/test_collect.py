"""Replay and random collection of paired sets, through the library and the command line."""

import shutil

import numpy as np
import pandas as pd
import pytest

from simshear_gym.cli import main
from simshear_gym.data.labels import SHEAR_COLUMNS, shear_to_sensor_frame, task_ranges
from simshear_gym.data.paired import load_paired
from simshear_gym.data.paths import infer_task, published_sim_set_dir, real_set_dir
from simshear_gym.data.tactile_set import read_set
from simshear_gym.evaluate.render_agreement import contact_agreement
from simshear_gym.sim.collect import CollectConfig, random_set, replay_set


def real_subset(data_root, tmp_path, contact, rows=8):
    """A copy of the first rows of a real val shear set, laid out like tactip331."""
    source = real_set_dir(data_root, contact, "shear", "val")
    target = tmp_path / "tactip331" / "real" / source.relative_to(data_root / "tactip331" / "real")
    (target / "images").mkdir(parents=True)
    targets = pd.read_csv(source / "targets.csv").iloc[:rows]
    targets.to_csv(target / "targets.csv", index=False)
    for name in targets["sensor_image"]:
        shutil.copy(source / "images" / name, target / "images" / name)
    return target


@pytest.mark.data
@pytest.mark.parametrize("contact", ["surface", "edge"])
def test_replay_of_real_rows(data_root, tmp_path, contact):
    real_dir = real_subset(data_root, tmp_path, contact)
    out = tmp_path / "paired"
    assert replay_set(real_dir, out, CollectConfig(workers=2), root=tmp_path) == 8
    paired, real = load_paired(out, root=tmp_path)
    assert paired.meta["contact"] == contact and paired.meta["real_set_relative_to_data_root"]
    # the shear vector is the row's move in the sensor frame
    np.testing.assert_allclose(paired.targets[list(SHEAR_COLUMNS)].to_numpy(),
                               shear_to_sensor_frame(real.moves(), real.poses()[:, 5]), atol=1e-9)
    # the renders agree with the published Tactile Gym renders of the same rows
    published = read_set(published_sim_set_dir(data_root, contact, "shear", "val")).load_images()[:8]
    agreement = contact_agreement(paired.load_images(), published)
    assert np.median(agreement["iou"]) > 0.8
    assert real.load_images().shape == (8, 128, 128)


def test_random_set_covers_ranges(tmp_path):
    out = tmp_path / "random"
    assert random_set("edge", 12, seed=3, out_dir=out, config=CollectConfig(workers=1)) == 12
    paired, real = load_paired(out)
    assert real is None and paired.meta["seed"] == 3
    for label_range in task_ranges("edge", "shear"):
        values = paired.targets[label_range.column]
        assert values.between(label_range.low, label_range.high).all()
    images = paired.load_images()
    assert images.shape == (12, 128, 128) and (images.max(axis=(1, 2)) > 0).mean() > 0.5
    # same seed -> same set
    random_set("edge", 12, seed=3, out_dir=tmp_path / "again", config=CollectConfig(workers=1))
    np.testing.assert_array_equal(load_paired(tmp_path / "again")[0].load_images(), images)


def test_random_set_may_draw_a_share_of_taps(tmp_path):
    config = CollectConfig(workers=1)
    random_set("surface", 10, seed=4, out_dir=tmp_path / "all", config=config)
    random_set("surface", 10, seed=4, out_dir=tmp_path / "half", config=config, tap_share=0.5)
    every, half = load_paired(tmp_path / "all")[0], load_paired(tmp_path / "half")[0]
    moves = [f"move_{i}" for i in range(1, 7)]
    taps = (half.targets[moves] == 0).all(axis=1)
    assert taps.sum() == 5 and not (every.targets[moves] == 0).all(axis=1).any()
    assert (half.targets.loc[taps, list(SHEAR_COLUMNS)] == 0).all().all()
    poses = [f"pose_{i}" for i in range(1, 7)]
    np.testing.assert_array_equal(half.targets[poses], every.targets[poses])  # the poses do not change with it
    np.testing.assert_array_equal(half.targets.loc[~taps, moves], every.targets.loc[~taps, moves])
    assert half.meta["tap_share"] == 0.5
    with pytest.raises(ValueError, match="tap_share must be a share in \\[0, 1\\], got 2"):
        random_set("surface", 2, seed=4, out_dir=tmp_path / "bad", config=config, tap_share=2)


def test_collect_command_line(tmp_path, capsys):
    assert main(["collect", "--task", "surface", "--n", "6", "--seed", "1", "--out", str(tmp_path / "cli"),
                 "--image-size", "64", "--workers", "1"]) == 0
    assert "wrote 6 paired rows" in capsys.readouterr().out
    assert load_paired(tmp_path / "cli")[0].load_images().shape == (6, 64, 64)


def test_collect_reports_bad_input(tmp_path, capsys):
    assert main(["collect", "--replay", str(tmp_path / "nowhere" / "surface_3d" / "tap" / "csv_val"),
                 "--out", str(tmp_path / "o")]) == 2
    assert "targets.csv: missing" in capsys.readouterr().err


def test_infer_task_from_path(tmp_path):
    assert infer_task(tmp_path / "tactip331/real/edge_2d/tap/csv_train") == ("edge", "tap")
    with pytest.raises(ValueError, match="cannot tell the contact type"):
        infer_task(tmp_path / "elsewhere")
