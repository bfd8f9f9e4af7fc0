"""Posenet: data loading from sets on disk, a tiny training run, resume, weights files, evaluation metrics."""

import json
from argparse import Namespace

import numpy as np
import pandas as pd
import pytest
import torch

from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS, SHEAR_COLUMNS
from simshear_gym.data.paths import cache_dir
from simshear_gym.data.tactile_set import image_name, write_image, write_targets
from simshear_gym.evaluate import metrics as evaluate_metrics
from simshear_gym.evaluate import posenet as evaluate_posenet
from simshear_gym.models.gdnn import variable_set
from simshear_gym.models.gdnn_input import label_matrix
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.translator import save_generator
from simshear_gym.models.unet import UNetConfig, UNetGenerator
from simshear_gym.train.posenet_config import PosenetTrainConfig
from simshear_gym.train.posenet_trainer import (
    LabelledImages,
    PosenetTrainer,
    load_source,
    random_blur,
    random_erase,
    random_shift,
)
from tests.clocks import StepClock

SIZE = 16


def toy_labelled(n=48, seed=0):
    """Surface labels; the image is a bright blob whose position and size follow z, rx, ry."""
    rng = np.random.default_rng(seed)
    variables = variable_set("surface")
    labels = np.stack([rng.uniform(s.low, s.high, n) for s in variables.variables], axis=1).astype(np.float32)
    images = np.zeros((n, SIZE, SIZE), np.uint8)
    for i, (z, rx, ry) in enumerate(labels[:, :3]):
        x, y, r = int(8 + ry / 4), int(8 + rx / 4), int(z)
        images[i, max(y - r, 0):y + r, max(x - r, 0):x + r] = 255
    return LabelledImages(torch.from_numpy(images), torch.from_numpy(labels))


def tiny_config(**overrides):
    settings = dict(paired_dirs=("toy",), image_size_px=SIZE, conv_channels=(4, 8), conv_kernels=(3, 3),
                    dense=(16,), epochs=3, batch_size=8, lr=3e-3, holdout=0.2, threads=1)
    settings.update(overrides)
    return PosenetTrainConfig(**settings)


def test_tiny_training_run_resume_and_weights(tmp_path):
    run_dir = tmp_path / "run"
    trainer = PosenetTrainer(tiny_config(), run_dir, toy_labelled())
    before = trainer.holdout_nll()
    summary = trainer.fit(progress=False)
    assert summary["epochs"] == 3 and summary["best_holdout_nll"] < before
    for name in ("config.json", "history.json", "checkpoint.pt", "best.pt"):
        assert (run_dir / name).is_file()
    history = json.loads((run_dir / "history.json").read_text())["epochs"]
    assert [h["epoch"] for h in history] == [1, 2, 3]
    assert all({"elapsed_s", "train_nll", "holdout_nll"} <= set(h) for h in history)

    resumed = PosenetTrainer(tiny_config(epochs=4), run_dir, toy_labelled())
    assert resumed.resume() and resumed.epoch == 3 and len(resumed.history) == 3
    assert resumed.fit(progress=False)["epochs"] == 4
    with pytest.raises(ValueError, match="other settings"):
        PosenetTrainer(tiny_config(lr=1e-2), run_dir, toy_labelled()).resume()

    model, card = load_posenet(run_dir / "best.pt")
    assert card["contact"] == "surface" and card["source"] == "real"
    mean, std = model(torch.rand(2, 1, SIZE, SIZE))
    assert mean.shape == std.shape == (2, 6) and (std > 0).all()


def test_a_training_stopped_by_its_cap_resumes_to_the_straight_runs_weights(tmp_path):
    """A slow machine: each run stops at its cap, back at its last finished epoch; the reruns end with the weights
    of the straight run (the pipeline's stages rerun so, see tests/test_pipeline_schedule.py)."""
    straight = PosenetTrainer(tiny_config(epochs=5), tmp_path / "straight", toy_labelled())
    straight.fit(progress=False)
    stops = []
    for _ in range(15):
        trainer = PosenetTrainer(tiny_config(epochs=5, cap_minutes=1.0 / 60), tmp_path / "capped", toy_labelled())
        trainer.resume()
        trainer.clock = clock = StepClock()  # a slower machine: 1/16 s a step, 5 steps an epoch, 1 s a run
        step = trainer.train_batch
        trainer.train_batch = lambda index, step=step, clock=clock: (clock.advance(1 / 16), step(index))[1]
        stops.append(trainer.fit(progress=False)["stopped_by"])
        if stops[-1] == "epochs":
            break
    assert stops == ["wall-clock cap", "epochs"] and trainer.epoch == 5
    for key, value in straight.model.state_dict().items():
        torch.testing.assert_close(trainer.model.state_dict()[key], value, rtol=0, atol=0)


def test_training_on_several_renditions_per_row(tmp_path):
    """Rows with two renditions (a bright one and a dim one): training draws both; the holdout reads the first."""
    data = toy_labelled(n=64)
    views = LabelledImages(torch.stack([data.images, data.images // 2], dim=1), data.labels)
    trainer = PosenetTrainer(tiny_config(), tmp_path / "run", views)
    assert trainer.holdout_data.images.shape[1] == 2
    before = trainer.holdout_nll()
    summary = trainer.fit(progress=False)
    assert summary["epochs"] == 3 and summary["best_holdout_nll"] < before


def test_cosine_schedule_decays_the_learning_rate_over_the_run(tmp_path):
    trainer = PosenetTrainer(tiny_config(lr_schedule="cosine"), tmp_path / "run", toy_labelled())
    trainer.fit(progress=False)
    assert 0.0 < trainer.optimiser.param_groups[0]["lr"] < 0.1 * trainer.config.lr
    with pytest.raises(ValueError, match="lr_schedule must be one of"):
        tiny_config(lr_schedule="step")


def test_random_shift_keeps_shape_and_is_identity_at_zero():
    images = torch.rand(4, 1, SIZE, SIZE)
    generator = torch.Generator().manual_seed(0)
    assert torch.equal(random_shift(images, 0.0, generator), images)
    shifted = random_shift(images, 0.1, generator)
    assert shifted.shape == images.shape and not torch.allclose(shifted, images)


def test_random_blur_is_a_per_image_gaussian_with_edges_repeated():
    import cv2

    images = torch.rand(5, 1, SIZE, SIZE)
    assert torch.equal(random_blur(images, 0.0, torch.Generator().manual_seed(0)), images)
    blurred = random_blur(images, 1.5, torch.Generator().manual_seed(3))
    sigmas = torch.rand(5, 1, generator=torch.Generator().manual_seed(3)) * 1.5  # the draws random_blur makes
    for image, sigma, result in zip(images, sigmas, blurred):
        expected = cv2.GaussianBlur(image[0].numpy(), (11, 11), float(sigma), borderType=cv2.BORDER_REPLICATE)
        np.testing.assert_allclose(result[0].numpy(), expected, atol=1e-5)
    flat = torch.full((2, 1, SIZE, SIZE), 0.4)
    torch.testing.assert_close(random_blur(flat, 2.0, torch.Generator().manual_seed(0)), flat)


def test_random_erase_blacks_out_one_disc_within_the_radius():
    images = torch.ones(64, 1, 32, 32)
    assert torch.equal(random_erase(images, 0.0, torch.Generator().manual_seed(0)), images)
    erased = random_erase(images, 0.2, torch.Generator().manual_seed(0))
    dark_share = (erased == 0).float().mean(dim=(1, 2, 3))
    assert torch.all(dark_share <= np.pi * 0.2 ** 2 + 0.01)  # at most the largest disc
    assert (dark_share > 0).float().mean() > 0.8 and dark_share.std() > 0  # random sizes, rarely empty
    assert torch.all((erased == 0) | (erased == 1))  # untouched outside the disc
    assert torch.all(erased[:, :, [0, -1], :] == 1) and torch.all(erased[:, :, :, [0, -1]] == 1)  # away from borders


def test_config_and_labels_reject_bad_input():
    with pytest.raises(ValueError, match="source must be one of"):
        tiny_config(source="cyclegan")
    with pytest.raises(ValueError, match="blur_px must be in"):
        tiny_config(blur_px=-1.0)
    with pytest.raises(ValueError, match="erase must be in"):
        tiny_config(erase=0.6)
    with pytest.raises(ValueError, match="missing"):
        label_matrix(pd.DataFrame({"pose_3": [1.0]}), variable_set("surface"))


def _write_set(directory, images, targets, meta):
    (directory / "images").mkdir(parents=True)
    for name, image in zip(targets["sensor_image"], images):
        write_image(directory / "images", name, image)
    write_targets(directory, targets, meta)


def test_load_source_real_and_sim_from_sets_on_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("SIMSHEAR_CACHE", str(tmp_path / "cache"))  # this test's own cache
    n, rng = 6, np.random.default_rng(1)
    poses = np.zeros((n, 6))
    poses[:, 2], poses[:, 3] = rng.uniform(2, 5, n), rng.uniform(-10, 10, n)
    moves = rng.uniform(-3, 3, (n, 6))
    names = [image_name(i) for i in range(n)]
    real_targets = pd.DataFrame({"sensor_image": names[::-1], **dict(zip(POSE_COLUMNS, poses[::-1].T)),
                                 **dict(zip(MOVE_COLUMNS, moves[::-1].T))})
    real_images = np.stack([np.full((SIZE, SIZE), 200 + i, np.uint8) for i in range(n)])[::-1]
    _write_set(tmp_path / "real", real_images, real_targets, {})
    paired_targets = pd.DataFrame({"sensor_image": names, "real_image": names,
                                   **dict(zip(POSE_COLUMNS, poses.T)), **dict(zip(MOVE_COLUMNS, moves.T)),
                                   **dict(zip(SHEAR_COLUMNS, moves.T))})
    sim_images = np.stack([np.full((SIZE, SIZE), i, np.uint8) for i in range(n)])
    _write_set(tmp_path / "paired", sim_images, paired_targets,
               {"contact": "surface", "real_set": str(tmp_path / "real"), "real_set_relative_to_data_root": False})

    real = load_source("real", "surface", [str(tmp_path / "paired")], image_size_px=SIZE)
    sim = load_source("sim", "surface", [str(tmp_path / "paired")], image_size_px=SIZE)
    assert real.images[:, 0, 0].tolist() == [200 + i for i in range(n)]  # real rows reordered to the paired ones
    assert sim.images[:, 0, 0].tolist() == list(range(n))
    np.testing.assert_allclose(real.labels[:, 0], poses[:, 2], rtol=1e-6)
    np.testing.assert_allclose(sim.labels[:, 3], moves[:, 0], rtol=1e-6)
    with pytest.raises(ValueError, match="'surface' paired set"):
        load_source("sim", "edge", [str(tmp_path / "paired")], image_size_px=SIZE)

    # several translators: one rendition per generator, drawn at random per row in training
    weights = []
    for index, (grey, shear_dim) in enumerate([(0.2, 6), (0.8, 6), (0.5, 0)]):
        generator = UNetGenerator(UNetConfig(image_size_px=SIZE, depth=4, base_channels=2, max_channels=4,
                                             shear_dim=shear_dim))
        generator.init_template(torch.full((SIZE, SIZE), grey))  # outputs the grey level everywhere
        weights.append(save_generator(tmp_path / f"g{index}.pt", generator))
    both = load_source("shpix2pix", "surface", [str(tmp_path / "paired")], image_size_px=SIZE,
                       translators=weights[:2])
    assert both.images.shape == (n, 2, SIZE, SIZE)
    assert both.first.unique().tolist() == [51] and both.images[:, 1].unique().tolist() == [204]
    drawn = torch.stack([both.drawn(np.random.default_rng(seed)) for seed in range(8)])  # (8, n, H, W)
    assert drawn.unique().tolist() == [51, 204] and drawn.shape[1:] == (n, SIZE, SIZE)
    # a generator listed twice is drawn twice as often (one view per entry), translated once
    weighted = load_source("shpix2pix", "surface", [str(tmp_path / "paired")], image_size_px=SIZE,
                           translators=[weights[0], weights[1], weights[0]])
    assert [weighted.images[:, k].unique().tolist() for k in range(3)] == [[51], [204], [51]]
    # the translations are cached: a second load reads the files instead of running the generators
    cached = sorted(cache_dir().glob("translated-*.npy"))
    assert len(cached) == 2
    for path in cached:
        np.save(path, np.zeros_like(np.load(path)))
    again = load_source("shpix2pix", "surface", [str(tmp_path / "paired")], image_size_px=SIZE,
                        translators=weights[:2])
    assert again.images.unique().tolist() == [0]
    with pytest.raises(ValueError, match="a pix2pix generator, but --source shpix2pix"):
        load_source("shpix2pix", "surface", [str(tmp_path / "paired")], image_size_px=SIZE, translators=weights)
    with pytest.raises(ValueError, match="generator weights for a translator source"):
        load_source("sim", "surface", [str(tmp_path / "paired")], image_size_px=SIZE, translators=weights[:1])


@pytest.mark.parametrize("contact", ["surface", "edge"])
def test_metrics_of_a_perfect_and_of_a_constant_predictor(contact):
    variables = variable_set(contact)
    rng = np.random.default_rng(0)
    truth = np.stack([rng.uniform(s.low, s.high, 50) for s in variables.variables], axis=1)
    encoded = variables.encode(truth)
    perfect = evaluate_metrics.metrics(encoded, torch.full_like(encoded, 0.05), truth, variables)
    for figures in perfect["variables"].values():
        assert figures["mae"] < 1e-3 and figures["within_1_std"] == 1.0 and figures["chance_mae"] > 0
    centre = np.array([0.0 if s.periodic else s.centre for s in variables.variables])
    constant = variables.encode(np.broadcast_to(centre, truth.shape).copy())
    guess = evaluate_metrics.metrics(constant, torch.full_like(constant, 0.05), truth, variables)
    for figures in guess["variables"].values():
        assert figures["mae"] == pytest.approx(figures["chance_mae"], abs=1e-3)
    assert guess["mean_nll"] > perfect["mean_nll"]


def test_mae_by_depth_puts_each_row_in_its_third_by_true_depth():
    variables = variable_set("surface")
    truth = np.zeros((90, variables.dim))
    truth[:, 0] = np.linspace(2.5, 5.5, 90)  # z_mm
    absolute = np.zeros_like(truth)
    absolute[60:, 1] = 1.0  # errors only on the deepest third's rx
    bins = evaluate_metrics.mae_by_depth(absolute, truth, variables)
    assert [b["rows"] for b in bins] == [30, 30, 30]
    assert bins[0]["depth_mm"][0] == 2.5 and bins[-1]["depth_mm"][1] == 5.5
    assert [b["mae"]["rx_deg"] for b in bins] == [0.0, 0.0, 1.0] and bins[2]["mae"]["z_mm"] == 0.0


def test_periodic_errors_wrap():
    variables = variable_set("edge")
    predicted, truth = np.zeros((1, variables.dim)), np.zeros((1, variables.dim))
    predicted[0, 2], truth[0, 2] = 179.0, -179.0
    assert evaluate_metrics.errors(predicted, truth, variables)[0, 2] == pytest.approx(-2.0)


def test_evaluate_command_on_a_fake_val_set(tmp_path):
    n = 8
    root = tmp_path / "data"
    val_dir = root / "tactip331" / "real" / "surface_3d" / "shear" / "csv_val"
    toy = toy_labelled(n, seed=3)
    poses = np.zeros((n, 6))
    poses[:, 2:5] = toy.labels[:, :3].numpy()
    moves = np.zeros((n, 6))
    targets = pd.DataFrame({"sensor_image": [image_name(i) for i in range(n)], **dict(zip(POSE_COLUMNS, poses.T)),
                            **dict(zip(MOVE_COLUMNS, moves.T))})
    _write_set(val_dir, toy.images.numpy(), targets, {})
    run_dir = tmp_path / "run"
    PosenetTrainer(tiny_config(epochs=1), run_dir, toy_labelled()).fit(progress=False)
    out = tmp_path / "results"
    args = Namespace(model=[f"tiny={run_dir / 'best.pt'}", f"real={tmp_path / 'r{contact}n' / 'best.pt'}",
                            f"edge_only:edge={tmp_path / 'missing.pt'}"],  # another contact's: not loaded
                     contact=["surface"], val_set=None, data=root, rows=5, out=out, name="posenet", threads=1,
                     device="auto")
    (tmp_path / "rsurfacen").mkdir()
    (tmp_path / "rsurfacen" / "best.pt").write_bytes((run_dir / "best.pt").read_bytes())
    assert evaluate_posenet.run(args) == 0
    result = json.loads((out / "posenet.json").read_text())
    assert "--contact surface" in result["command"] and (out / "posenet_surface.png").is_file()
    assert f"--out {out}" in result["command"]  # the recorded command writes where this run wrote
    assert set(result["contacts"]["surface"]["models"]) == {"tiny", "real"}
    figures = result["contacts"]["surface"]["models"]["tiny"]
    assert figures["rows"] == 5 and set(figures["variables"]) == set(variable_set("surface").names)


def test_evaluate_command_on_another_sensors_set(tmp_path):
    """--set: any real tactile set whose meta names its contact (a pipeline run's adapted validation split)."""
    n = 6
    toy = toy_labelled(n, seed=4)
    poses = np.zeros((n, 6))
    poses[:, 2:5] = toy.labels[:, :3].numpy()
    targets = pd.DataFrame({"sensor_image": [image_name(i) for i in range(n)], **dict(zip(POSE_COLUMNS, poses.T)),
                            **dict(zip(MOVE_COLUMNS, np.zeros((n, 6)).T))})
    val_dir = tmp_path / "adapt" / "tap" / "val"
    _write_set(val_dir, toy.images.numpy(), targets, {"contact": "surface", "dataset": "tap", "split": "val"})
    run_dir = tmp_path / "run"
    PosenetTrainer(tiny_config(epochs=1), run_dir, toy_labelled()).fit(progress=False)
    out = tmp_path / "results"
    args = Namespace(model=[f"tiny={run_dir / 'best.pt'}"], contact=None, val_set=val_dir, data=tmp_path, rows=None,
                     out=out, name="lab", threads=1, device="auto")
    assert evaluate_posenet.run(args) == 0
    result = json.loads((out / "lab.json").read_text())
    command = result["command"]
    assert command.startswith("simshear evaluate posenet --model ") and f" --set {val_dir} " in command
    assert result["contacts"]["surface"]["set"] == str(val_dir)
    assert result["contacts"]["surface"]["models"]["tiny"]["rows"] == n
    with pytest.raises(ValueError, match="give --contact .* or --set DIR"):
        evaluate_posenet.run(Namespace(**{**vars(args), "contact": ["surface"]}))


def test_acceptance_compares_only_variables_the_reference_reads():
    def model(maes, chances):
        return {"variables": {f"v{i}": {"mae": m, "chance_mae": c} for i, (m, c) in enumerate(zip(maes, chances))}}

    models = {"real": model([0.1, 2.0], [1.0, 2.0]), "shpix2pix": model([0.11, 5.0], [1.0, 2.0])}
    result = evaluate_posenet.acceptance(models)
    assert result["met"] and result["variables"]["v0"]["reference_reads"]
    assert not result["variables"]["v1"]["reference_reads"]  # at chance: not compared
    models["shpix2pix"] = model([0.13, 2.0], [1.0, 2.0])
    assert not evaluate_posenet.acceptance(models)["met"]
    assert evaluate_posenet.acceptance({"real": models["real"]}) == {}
