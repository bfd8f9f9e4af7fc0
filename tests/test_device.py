"""Device selection (``--device auto|cpu|cuda``), checkpoints across devices, and the CUDA-only code paths of the
trainers (mixed precision, channels_last) exercised on the CPU."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import torch

from simshear_gym.models.device import DEVICES, OnDevice, check_device_name, resolve_device
from simshear_gym.models.gdnn_input import predict
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.translator import Translator
from simshear_gym.pipelines.config import Profile
from simshear_gym.train import posenet_trainer, translator_trainer
from simshear_gym.train.posenet_trainer import PosenetTrainer
from simshear_gym.train.precision import MixedPrecision, autocast_dtype, memory_format
from simshear_gym.train.rl_config import RLTrainConfig
from simshear_gym.train.translator_trainer import TranslatorTrainer
from tests.test_posenet import tiny_config as tiny_posenet_config
from tests.test_posenet import toy_labelled
from tests.test_translator import tiny_config as tiny_translator_config
from tests.test_translator import toy_pairs


@pytest.fixture
def no_cuda(monkeypatch):
    """A machine without CUDA, whatever this one has."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


def test_auto_is_cuda_where_there_is_one_else_the_cpu():
    assert DEVICES == ("auto", "cpu", "cuda")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == torch.device("cpu")


def test_auto_on_a_machine_without_cuda_is_the_cpu(no_cuda):
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device("auto", index=1) == torch.device("cpu")


def test_cuda_without_cuda_is_one_clear_error(no_cuda):
    with pytest.raises(ValueError, match=r"device 'cuda'.*finds no CUDA device.*--device cpu"):
        resolve_device("cuda")


def test_unknown_device_names_the_choices():
    with pytest.raises(ValueError, match=r"device must be one of \('auto', 'cpu', 'cuda'\), got 'gpu'"):
        resolve_device("gpu")
    for make in (lambda: tiny_posenet_config(device="gpu"), lambda: tiny_translator_config(device="gpu"),
                 lambda: RLTrainConfig(device="gpu"), lambda: Profile(device="gpu")):
        with pytest.raises(ValueError, match="device must be one of"):
            make()
    assert check_device_name("cuda") == "cuda"


def test_the_command_refuses_cuda_without_cuda_in_one_line(no_cuda, tmp_path, capsys):
    from simshear_gym.cli import main
    from tests.test_train_loop import _paired_set_on_disk

    paired = str(_paired_set_on_disk(tmp_path / "sets"))
    code = main(["train", "posenet", "--source", "sim", "--contact", "surface", "--paired", paired, "--image-size",
                 "16", "--batch-size", "8", "--holdout", "0.2", "--threads", "1", "--epochs", "1", "--device", "cuda",
                 "--out", str(tmp_path / "run")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and error.startswith("simshear: error: device 'cuda'") and "\n" not in error
    assert not (tmp_path / "run").exists()


def test_trainers_default_to_auto_and_rl_to_the_cpu():
    assert tiny_posenet_config().device == tiny_translator_config().device == "auto"
    assert tiny_posenet_config().amp and tiny_translator_config().amp
    assert RLTrainConfig().device == "cpu" and Profile().device == "auto"


def test_a_checkpoint_round_trips_through_map_location(tmp_path):
    device = resolve_device("auto")
    run_dir = tmp_path / "run"
    trainer = PosenetTrainer(tiny_posenet_config(epochs=1), run_dir, toy_labelled())
    trainer.fit(progress=False)
    state = torch.load(run_dir / "checkpoint.pt", map_location=device, weights_only=False)
    weights = state["model"]["state_dict"]
    assert all(value.device.type == device.type for value in weights.values())
    assert not any(name.startswith("module.") for name in weights)
    fresh = PosenetTrainer(tiny_posenet_config(epochs=1), tmp_path / "other", toy_labelled())
    fresh.model.load_state_dict(weights)
    for name, value in fresh.model.state_dict().items():
        assert torch.equal(value.cpu(), trainer.model.state_dict()[name].cpu()), name
    resumed = PosenetTrainer(tiny_posenet_config(epochs=2), run_dir, toy_labelled())
    assert resumed.resume() and resumed.epoch == 1
    model, card = load_posenet(run_dir / "best.pt")  # map_location="cpu" inside
    assert card["epoch"] == 1 and next(model.parameters()).device.type == "cpu"


def test_on_device_gives_a_cpu_interface_and_the_same_numbers(tmp_path):
    trainer = PosenetTrainer(tiny_posenet_config(epochs=1), tmp_path / "run", toy_labelled())
    images = np.random.default_rng(0).integers(0, 255, (5, 16, 16), dtype=np.uint8)
    mean, std = predict(trainer.model, images)
    wrapped = OnDevice(trainer.model, resolve_device("auto"))
    assert wrapped.variables is trainer.model.variables and wrapped.config is trainer.model.config
    mean_on, std_on = predict(wrapped, images)
    assert mean_on.device.type == "cpu" and torch.allclose(mean, mean_on, atol=1e-5)
    assert torch.allclose(std, std_on, atol=1e-5)


def test_a_translator_on_device_keeps_its_uint8_call():
    from simshear_gym.evaluate.translation import on_device
    from simshear_gym.models.unet import UNetConfig, UNetGenerator

    torch.manual_seed(0)
    generator = UNetGenerator(UNetConfig(image_size_px=32, depth=5, base_channels=4, max_channels=8, shear_dim=6))
    plain = Translator(generator)
    assert on_device(plain, torch.device("cpu")) is plain  # the CPU keeps the fast frozen copy
    wrapped = Translator(OnDevice(generator, resolve_device("auto")), fast=False)
    rng = np.random.default_rng(0)
    sim, shear = rng.integers(0, 60, (3, 32, 32), dtype=np.uint8), rng.uniform(-3, 3, (3, 6))
    out, expected = wrapped(sim, shear), plain(sim, shear)
    assert out.dtype == np.uint8 and np.abs(out.astype(int) - expected.astype(int)).max() <= 1


def test_mixed_precision_acts_on_cuda_only_and_is_the_plain_step_elsewhere():
    assert autocast_dtype(torch.device("cpu"), amp=True) is None
    assert autocast_dtype(torch.device("cuda"), amp=False) is None
    assert memory_format(torch.device("cpu")) == memory_format(torch.device("cuda")) == torch.channels_last
    plain = MixedPrecision(torch.device("cpu"), None)
    assert not plain.enabled and not plain.scaler.is_enabled()


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16], ids=["bf16", "fp16+scaler"])
def test_the_cuda_code_paths_run_on_the_cpu(tmp_path, monkeypatch, dtype):
    """Autocast (bf16, or fp16 with a GradScaler) and channels_last, forced on the CPU: both trainers train, the
    checkpoints stay float32 and load for inference."""
    for module in (posenet_trainer, translator_trainer):
        monkeypatch.setattr(module, "autocast_dtype", lambda device, amp: dtype)
        monkeypatch.setattr(module, "memory_format", lambda device: torch.channels_last)
    posenet = PosenetTrainer(tiny_posenet_config(epochs=1), tmp_path / "posenet", toy_labelled())
    assert posenet.precision.enabled and posenet.fit(progress=False)["epochs"] == 1
    model, _ = load_posenet(tmp_path / "posenet" / "best.pt")
    assert all(value.dtype == torch.float32 for value in model.state_dict().values() if value.is_floating_point())
    translator = TranslatorTrainer(tiny_translator_config(epochs=1, gan_weight=1.0), tmp_path / "translator",
                                   toy_pairs())
    summary = translator.fit(progress=False)
    assert summary["epochs"] == 1 and np.isfinite(summary["best_holdout_l1"])
    state = torch.load(tmp_path / "translator" / "checkpoint.pt", map_location="cpu", weights_only=False)
    assert all(value.dtype == torch.float32 for value in state["generator"]["state_dict"].values()
               if value.is_floating_point())
    out = Translator.load(tmp_path / "translator" / "best.pt")(np.zeros((2, 32, 32), np.uint8), np.zeros((2, 6)))
    assert out.shape == (2, 32, 32)


@pytest.mark.parametrize("command", ["posenet", "translator", "rl"])
def test_every_trainer_takes_device_and_the_torch_trainers_amp(command):
    import importlib

    module = importlib.import_module(f"simshear_gym.train.{command}")
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    required = {"posenet": ["--source", "real", "--contact", "surface", "--paired", "p"],
                "translator": ["--paired", "p"], "rl": []}[command]
    args = parser.parse_args(["--out", "o", *required, "--device", "cpu"])
    assert args.device == "cpu"
    if command != "rl":
        assert parser.parse_args(["--out", "o", *required, "--no-amp"]).amp is False
    with pytest.raises(SystemExit):
        parser.parse_args(["--out", "o", *required, "--device", "gpu"])


@pytest.mark.parametrize("command", ["posenet", "translation"])
def test_the_evaluators_take_device(command):
    import importlib

    module = importlib.import_module(f"simshear_gym.evaluate.{command}")
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    required = ["--model", "a=b.pt"] if command == "posenet" else []
    assert parser.parse_args([*required]).device == "auto"
    assert parser.parse_args([*required, "--device", "cpu"]).device == "cpu"


def test_the_pipeline_takes_device_from_the_profile_or_the_flag(tmp_path):
    from simshear_gym.pipelines import run as pipeline_run
    from simshear_gym.pipelines.config import default_profiles, load_config

    parser = argparse.ArgumentParser()
    pipeline_run.add_arguments(parser)
    assert parser.parse_args(["c.toml"]).device is None
    assert parser.parse_args(["c.toml", "--device", "cpu"]).device == "cpu"
    assert all(profile.device == "auto" for profile in default_profiles().values())
    path = tmp_path / "sensor.toml"
    path.write_text(open("configs/tactip331.toml").read() + '\n[profiles.cpu_only]\ndevice = "cpu"\n')
    config = load_config(path)
    profile = config.profile("cpu_only")
    assert profile.device == "cpu"
    paired = {name: {"train": f"collect/{name}/train"} for name in config.datasets}
    variables = {dataset.contact: "" for dataset in config.datasets.values()}
    stages = ("translator", "posenet")
    for device, expected in ((None, "cpu"), ("cuda", "cuda")):
        steps = pipeline_run.training_steps(config, profile, {}, paired, {}, variables, stages, device)
        assert steps and all(step.action.keywords == {"device": expected} for step in steps)
    bad = tmp_path / "bad.toml"
    bad.write_text(open("configs/tactip331.toml").read() + '\n[profiles.on_gpu]\ndevice = "gpu"\n')
    with pytest.raises(ValueError, match=r"profiles.on_gpu.*device must be one of"):
        load_config(bad)


def test_translator_speed_times_each_batch_size_and_names_the_device(tmp_path):
    """``simshear evaluate translator-speed --batch-sizes``: one latency per shipped model and batch size, the
    device and the exact command in the file (``translator_speed.json`` on the CPU)."""
    import json

    from simshear_gym import cli

    assert cli.main(["evaluate", "translator-speed", "--threads", "1", "--repeats", "2", "--device", "cpu",
                     "--batch-sizes", "1", "3", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "translator_speed.json").read_text())
    assert result["machine"]["device"] == "cpu"
    # the options that differ from their defaults, in the parser's order (--device cpu is the default)
    assert result["command"] == ("simshear evaluate translator-speed --threads 1 --batch-sizes 1 3 --repeats 2 "
                                 f"--out {tmp_path}")
    assert {(row["model"], row["contact"]) for row in result["models"]} >= {("shpix2pix", "surface")}
    for row in result["models"]:
        assert row["ms_per_image_batch1"] > 0 and row["ms_per_image_batch3"] > 0


def test_translator_speed_refuses_a_batch_size_below_one(tmp_path, capsys):
    from simshear_gym import cli

    assert cli.main(["evaluate", "translator-speed", "--batch-sizes", "1", "0", "--out", str(tmp_path)]) == 2
    assert "--batch-sizes must be positive integers, got [0]" in capsys.readouterr().err
    assert not (tmp_path / "translator_speed.json").exists()


def test_translator_speed_on_cuda_without_cuda_is_one_clear_error(no_cuda, tmp_path, capsys):
    from simshear_gym import cli

    assert cli.main(["evaluate", "translator-speed", "--device", "cuda", "--out", str(tmp_path)]) == 2
    assert "device 'cuda'" in capsys.readouterr().err


def test_the_envs_translator_runs_on_the_cpu_by_default_and_on_cuda_only_where_there_is_one(no_cuda, monkeypatch):
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401
    from simshear_gym.models.translator_runtime import TRANSLATOR_DEVICE_ENV, choose_translator_device

    monkeypatch.delenv(TRANSLATOR_DEVICE_ENV, raising=False)
    assert choose_translator_device() == "cpu" and choose_translator_device("auto") == "cpu"
    with pytest.raises(ValueError, match=r"device 'cuda'.*finds no CUDA device"):
        choose_translator_device("cuda")
    with pytest.raises(ValueError, match=r"^device must be one of .*where the translator runs.*got 'tpu'"):
        choose_translator_device("tpu")
    monkeypatch.setenv(TRANSLATOR_DEVICE_ENV, "gpu")
    with pytest.raises(ValueError, match=r"SIMSHEAR_TRANSLATOR_DEVICE must be one of .*got 'gpu'"):
        choose_translator_device()
    monkeypatch.delenv(TRANSLATOR_DEVICE_ENV)
    with pytest.raises(ValueError, match="finds no CUDA device"):
        gym.make("SimShearTracking-v0", device="cuda")
    assert gym.make("SimShearTracking-v0", obs_mode="sim", device="cuda").unwrapped.translator_device == "cpu"


def test_a_gpu_translator_is_torchs_and_vector_workers_leave_the_gpu_to_the_main_process(monkeypatch):
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401
    from simshear_gym.envs import base
    from simshear_gym.models.translator_runtime import load_translator
    from simshear_gym.models.zoo import shipped_translators

    weights = shipped_translators()[("shpix2pix", "surface")]
    with pytest.raises(ValueError, match="ONNX Runtime runs here on the CPU only"):
        load_translator(weights, "onnx", device="cuda:0")
    with pytest.raises(ValueError, match="ONNX Runtime runs here on the CPU only"):
        load_translator(weights.with_suffix(".onnx"), "auto", device="cuda:0")
    # as on a machine with a GPU: the env would translate on cuda:0
    monkeypatch.setattr(base, "choose_translator_device", lambda device=None: "cuda:0" if device else "cpu")
    with pytest.raises(ValueError, match="worker processes cannot share the GPU.*translate_in='main'"):
        gym.make_vec("SimShearTracking-v0", num_envs=2, workers=2, device="cuda")


def test_train_speed_times_both_layouts_of_each_trainer(tmp_path):
    """`simshear evaluate train-speed` times a step of each trainer in both layouts and records the command."""
    from simshear_gym.cli import main

    assert main(["evaluate", "train-speed", "--models", "gdnn", "translator_decoder0.5", "--steps", "1",
                 "--processes", "1", "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "train_speed.json").read_text())
    assert record["command"].startswith("simshear evaluate train-speed --models gdnn translator_decoder0.5")
    assert [row["model"] for row in record["models"]] == ["gdnn", "translator_decoder0.5"]
    for row in record["models"]:
        assert row["ms_per_step_default"] > 0 and row["ms_per_step_channels_last"] > 0
        assert row["speedup"] == pytest.approx(row["ms_per_step_default"] / row["ms_per_step_channels_last"],
                                               rel=0.01)
