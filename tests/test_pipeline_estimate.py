"""``simshear pipeline estimate``: a profile's training counted before it runs (rows, epochs, optimiser steps per
epoch, the order of the lanes) and timed by short probes of the package's trainers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simshear_gym.data.adapter import adapt_dataset, split_sizes
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.estimate import estimate, format_estimate, lanes, planned_steps
from simshear_gym.pipelines.run import run_pipeline
from simshear_gym.pipelines.stages import Step, order_steps
from simshear_gym.train.step_timing import posenet_step_time, translation_s_per_row, translator_step_time
from tests.test_pipeline_check import write_lab
from tests.test_pipeline_run import POOLED

ROOT = Path(__file__).resolve().parents[1]


def _noop(runner, done):  # never called: the lanes only read names, needs and costs
    raise AssertionError("not run")


def test_the_lanes_start_steps_as_the_run_does():
    steps = [Step("real", _noop, cost=3.0), Step("side", _noop, cost=1.0),
             Step("tilt", _noop, needs=("real",), cost=2.0), Step("gdnn", _noop, needs=("tilt", "side"), cost=1.0)]
    assert order_steps(steps) == ["real", "tilt", "side", "gdnn"]
    seconds = {"real": 10.0, "side": 4.0, "tilt": 6.0, "gdnn": 5.0}
    assert lanes(steps, seconds, jobs=2) == {"real": (0.0, 10.0), "side": (0.0, 4.0), "tilt": (10.0, 16.0),
                                             "gdnn": (16.0, 21.0)}
    assert lanes(steps, seconds, jobs=1) == {"real": (0.0, 10.0), "tilt": (10.0, 16.0), "side": (16.0, 20.0),
                                             "gdnn": (20.0, 25.0)}  # one lane: the priority order, needs first


def test_split_sizes_are_the_adapted_splits_without_reading_an_image(tmp_path):
    config = load_config(write_lab(tmp_path, rows=30))
    dataset = config.datasets["tap"]
    adapted = adapt_dataset(dataset, config.frame, tmp_path)
    assert split_sizes(dataset, tmp_path) == {split: len(part.image_paths) for split, part in adapted.items()}
    assert split_sizes(dataset, tmp_path, max_rows_per_split=5) == {"train": 5, "val": 5}
    for image in (tmp_path / "frames").iterdir():
        image.unlink()
    assert split_sizes(dataset, tmp_path) == {"train": 20, "val": 10}  # labels alone


def test_the_estimate_counts_the_optimiser_steps_the_run_takes(tmp_path):
    data = tmp_path / "data"
    config = load_config(write_lab(data, rows=30, config=POOLED))
    result = estimate(config, data, "smoke", jobs=1, probe_steps=2, log=lambda line: None)
    manifest = run_pipeline(config, tmp_path / "run", data, "smoke", ("adapt", "collect", "translator", "posenet"),
                            workers=1)
    trained = {r["stage"]: r["metrics"] for r in manifest["results"] if r["stage"].split("/")[0] in
               ("translator", "posenet")}
    estimated = {s["name"]: s for s in result["steps"]}
    assert set(estimated) == set(trained)  # every training step of the run, none more
    for name, metrics in trained.items():
        step = estimated[name]
        assert step["epochs"] * step["steps_per_epoch"] == metrics["steps"], name
        assert step["seconds"] > 0 and step["end_s"] == pytest.approx(step["start_s"] + step["seconds"], abs=0.01)
    gdnn = estimated["posenet/surface_shpix2pix"]
    assert gdnn["rows"] == 20 + 12 and gdnn["translate_s"] > 0  # the replays and the random contacts, translated
    assert estimated["posenet/surface_real"]["translate_s"] == 0
    assert estimated["translator/surface_tilt"]["start_s"] >= estimated["posenet/surface_real"]["end_s"]
    assert result["device"] == "auto"  # the smoke profile's: its probes train where its steps would
    assert result["jobs"] == 1 and result["training_wall_min"] * 60 == pytest.approx(  # one lane: end to end
        sum(s["seconds"] for s in result["steps"]), abs=6)
    assert "training about" in format_estimate(result)


def test_probes_time_the_trainers_with_the_runs_settings():
    plain = translator_step_time({"arch": "pix2pix", "base_channels": 4, "max_channels": 8}, 32, steps=2)
    pose = translator_step_time({"arch": "shpix2pix", "base_channels": 4, "max_channels": 8, "pose_weight": 1.0},
                                32, steps=2)
    gdnn = posenet_step_time({"image_size_px": 32, "batch_size": 8}, "surface", views=3, steps=2)
    assert min(plain.step_s, pose.step_s, gdnn.step_s) > 0
    assert min(plain.holdout_s_per_row, pose.holdout_s_per_row, gdnn.holdout_s_per_row) > 0
    assert translation_s_per_row({"arch": "shpix2pix", "base_channels": 4, "max_channels": 8}, 32, batch=4) > 0


def test_probes_train_on_the_device_the_run_would_and_cuda_without_one_is_one_clear_error(monkeypatch):
    import torch

    from simshear_gym.train import step_timing

    seen = []
    monkeypatch.setattr(step_timing, "_time_trainer",
                        lambda trainer, rows, steps, ready, device: seen.append((trainer.device.type, device)))
    translator_step_time({"base_channels": 4, "max_channels": 8}, 32, steps=1, device="cpu")
    posenet_step_time({"image_size_px": 32, "batch_size": 8}, "surface", steps=1, device="auto")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert seen == [("cpu", "cpu"), (expected, expected)]
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device 'cuda'.*finds no CUDA device"):
            posenet_step_time({"image_size_px": 32, "batch_size": 8}, "surface", steps=1, device="cuda")


def test_the_command_takes_a_device_and_records_it(tmp_path, capsys, monkeypatch):
    from simshear_gym.cli import main
    from simshear_gym.pipelines import estimate as estimate_module

    asked = {}

    def fake(config, root, profile, jobs, probe_steps, device):
        asked.update(profile=profile, device=device)
        return {"config": "c", "sensor": "lab", "profile": profile, "jobs": 1, "device": device, "probe_s": 0.0,
                "training_wall_min": 1.0, "lane_busy_min": 1.0, "steps": []}

    monkeypatch.setattr(estimate_module, "estimate", fake)
    data = tmp_path / "data"
    config = write_lab(data, rows=30, config=POOLED)
    assert main(["pipeline", "estimate", str(config), "--profile", "smoke", "--data", str(data), "--device", "cpu",
                 "--json", str(tmp_path / "e.json")]) == 0
    assert asked == {"profile": "smoke", "device": "cpu"}
    assert "device cpu" in capsys.readouterr().out
    record = json.loads((tmp_path / "e.json").read_text())
    assert "--device cpu" in record["command"] and record["device"] == "cpu"


def test_the_lanes_give_the_measured_wall_time_of_the_shipped_recipe_from_its_steps_times():
    """The empty-cache run of the full profile (results/ablations/pipeline_full_tactip331_empty_cache.json): its
    steps' measured times, laid on two lanes as the estimate lays them, give its measured wall time."""
    record = json.loads((ROOT / "results" / "ablations" / "pipeline_full_tactip331_empty_cache.json").read_text())
    wall_s = {stage["stage"]: stage["wall_s"] for stage in record["stages"]}
    steps = planned_steps(load_config(ROOT / "configs" / "tactip331.toml"), "full")
    assert {step.name for step in steps} <= set(wall_s)
    laid = lanes(steps, {step.name: wall_s[step.name] for step in steps}, jobs=2)
    data_and_evaluation_s = sum(s for name, s in wall_s.items() if name.split("/")[0] in ("adapt", "collect",
                                                                                           "evaluate"))
    minutes = (max(end for _, end in laid.values()) + data_and_evaluation_s) / 60
    assert minutes == pytest.approx(record["wall_min"], rel=0.02)  # 135.8 against 136.1
