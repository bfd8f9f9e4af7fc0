"""Env-collected sets: the env's translated images with its true state, loadable as posenet training data."""

import json

import numpy as np
import pytest

from simshear_gym.data.tactile_set import read_set
from simshear_gym.models.gdnn import variable_set
from simshear_gym.pipelines.env_collect import STATE_COLUMNS, EnvCollectConfig, collect
from simshear_gym.train.posenet_config import PosenetTrainConfig
from simshear_gym.train.posenet_trainer import PosenetTrainer, load_source


@pytest.fixture(scope="module")
def colift_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("colift_set")
    assert collect(EnvCollectConfig(task="colift", rows=30, episode_steps=6, seed=3), out, progress=False) == 30
    return out


def test_collected_set_holds_the_envs_images_and_true_state(colift_set):
    found = read_set(colift_set, required_columns=STATE_COLUMNS)
    assert len(found) == 30 and found.meta["kind"] == "env" and found.meta["env_id"] == "SimShearCoLift-v0"
    targets = found.targets
    assert set(targets["object_name"]) == {"prism", "egg", "brain", "ducky"}  # five 6-step episodes in turn
    assert targets["episode"].nunique() == 5 and targets["step"].max() == 5
    # near the co-lift reference depth (5.2 mm), with the noise's shear
    assert 3.0 < targets["z_mm"].mean() < 7.0
    assert targets[["shear_x_mm", "shear_y_mm"]].abs().to_numpy().max() > 0.05
    images = found.load_images()
    assert images.shape == (30, 128, 128) and images.dtype == np.uint8
    assert 20 < images.mean() < 235  # translated TacTip images, not blank renders
    json.dumps(found.meta)


def test_env_sets_train_a_gdnn_on_the_env_variables(colift_set, tmp_path):
    data = load_source("env", "env", [str(colift_set)], image_size_px=32)
    assert tuple(data.images.shape) == (30, 32, 32) and tuple(data.labels.shape) == (30, 4)
    assert variable_set("env").names == STATE_COLUMNS
    config = PosenetTrainConfig(source="env", contact="env", paired_dirs=(str(colift_set),), image_size_px=32,
                                conv_channels=(4, 8), conv_kernels=(3, 3), dense=(16,), epochs=2, batch_size=8,
                                holdout=0.2, threads=1)
    summary = PosenetTrainer(config, tmp_path / "run", data).fit(progress=False)
    assert summary["epochs"] == 2 and (tmp_path / "run" / "best.pt").is_file()


def test_env_source_and_contact_go_together_and_bad_settings_are_named():
    with pytest.raises(ValueError, match="source 'env'"):
        PosenetTrainConfig(source="env", contact="surface", paired_dirs=("x",))
    with pytest.raises(ValueError, match="source 'env'"):
        PosenetTrainConfig(source="real", contact="env", paired_dirs=("x",))
    with pytest.raises(ValueError, match="task must be one of"):
        EnvCollectConfig(task="push")
    with pytest.raises(ValueError, match="gain_min"):
        EnvCollectConfig(gain_min=1.5)


def test_a_paired_set_is_not_taken_for_an_env_set(tmp_path, colift_set):
    meta = json.loads((colift_set / "meta.json").read_text())
    (tmp_path / "images").symlink_to(colift_set / "images")
    (tmp_path / "targets.csv").write_text((colift_set / "targets.csv").read_text())
    (tmp_path / "meta.json").write_text(json.dumps({**meta, "kind": "paired"}))
    with pytest.raises(ValueError, match="not a set of simshear collect-env"):
        load_source("env", "env", [str(tmp_path)])


def test_the_servo_controller_can_drive_the_collection(tmp_path):
    """DAgger's collection: the image-based controller moves the follower, the labels are still the truth."""
    config = EnvCollectConfig(task="tracking", rows=8, episode_steps=8, noise=0.0, driver="servo", seed=1)
    assert collect(config, tmp_path, progress=False) == 8
    found = read_set(tmp_path, required_columns=STATE_COLUMNS)
    assert found.meta["config"]["driver"] == "servo" and found.meta["env_id"] == "SimShearTracking-v0"
    assert np.abs(found.targets["z_mm"] - 4.0).max() < 1.5  # the servo keeps the tracking reference depth
    with pytest.raises(ValueError, match="driver must be one of"):
        EnvCollectConfig(driver="ppo")


def test_the_noise_goes_only_where_the_driver_steers(tmp_path):
    """The servo controller does not steer the co-lift yaw, so its collection adds no noise there: the yaw stays
    at its start instead of random-walking while the shear takes the noise."""
    config = EnvCollectConfig(task="colift", rows=12, episode_steps=12, noise=0.5, driver="servo", seed=3)
    assert collect(config, tmp_path, progress=False) == 12
    targets = read_set(tmp_path, required_columns=STATE_COLUMNS).targets
    assert np.abs(targets["shear_rz_deg"]).max() < 0.5
    assert np.abs(targets[["shear_x_mm", "shear_y_mm"]].to_numpy()).max() > 0.2


def test_a_heavy_set_labels_the_shear_the_image_shows(tmp_path):
    """payload="heavy": the shear labels are the skin's deflection, the held load's sag included (what the image
    shows): the load makes it negative in y (sensor +y is down), most for the round 1.5 kg egg."""
    out = tmp_path / "heavy"
    assert collect(EnvCollectConfig(task="colift", rows=16, episode_steps=4, seed=3, payload="heavy"), out,
                   progress=False) == 16
    found = read_set(out, required_columns=STATE_COLUMNS)
    assert found.meta["config"]["payload"] == "heavy"
    targets = found.targets
    assert (targets.loc[targets["object_name"] == "egg", "shear_y_mm"] < -1.5).all()
    assert (targets.loc[targets["object_name"] == "prism", "shear_y_mm"] < -0.4).all()
    assert targets["shear_y_mm"].mean() < -0.4
    with pytest.raises(ValueError, match="payload"):
        EnvCollectConfig(task="tracking", payload="heavy")
