"""The GPU path of the trainers, checked on the CPU: training rows held on the device (``data_on_device = "on"``)
give the batches, augmentations and weights of the CPU path for a seed; the batch-scaled, warmed-up learning rate;
``torch.compile``'s fallback; the ``gpu`` profile of configs/tactip331.toml (the full recipe at large batches) and
its probes at the profile's batch sizes."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from simshear_gym.pipelines.config import load_config
from simshear_gym.tables import ConfigError
from simshear_gym.train import precision
from simshear_gym.train.posenet_config import PosenetTrainConfig
from simshear_gym.train.posenet_trainer import LabelledImages, PosenetTrainer
from simshear_gym.train.runs import batch_scaled_lr, check_same_settings, run_lr, warmup_factor
from simshear_gym.train.translator_config import TranslatorTrainConfig
from simshear_gym.train.translator_trainer import TranslatorTrainer
from tests.test_posenet import tiny_config as posenet_config
from tests.test_posenet import toy_labelled
from tests.test_translator import tiny_config, toy_pairs

ROOT = Path(__file__).resolve().parents[1]


def _weights(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {name: value.detach().clone() for name, value in module.state_dict().items()}


def test_the_device_sampler_gives_the_cpu_paths_batches_and_covers_the_set(tmp_path):
    pairs = toy_pairs(n=24, size=16)
    config = {"image_size_px": 16, "base_channels": 2, "max_channels": 4, "epochs": 1, "batch_size": 4}
    trainers = {placement: TranslatorTrainer(tiny_config(**config, data_on_device=placement), tmp_path / placement,
                                             pairs) for placement in ("off", "on")}
    assert trainers["off"].device_pairs is None and trainers["on"].device_pairs is not None
    for _ in range(2):  # two epochs: the same order for the seed, a new one each epoch
        batches = {placement: trainer.epoch_batches() for placement, trainer in trainers.items()}
        assert all(np.array_equal(a, b) for a, b in zip(batches["off"], batches["on"], strict=True))
        drawn = np.concatenate(batches["on"])
        assert np.array_equal(np.sort(drawn), np.arange(len(trainers["on"].train_pairs)))  # each row once
        for index in batches["on"]:
            cpu, device = trainers["off"].train_pairs.batch(index), trainers["on"].device_pairs.batch(index)
            for a, b in zip(cpu[:3], device[:3], strict=True):
                assert torch.equal(a, b)
    weights = {}
    for placement in ("off", "on"):  # one after another: each run from its seed's torch generator
        trainer = TranslatorTrainer(tiny_config(**config, data_on_device=placement), tmp_path / f"fit_{placement}",
                                    pairs)
        trainer.fit(progress=False)
        weights[placement] = _weights(trainer.generator)
    assert all(torch.equal(weights["off"][name], weights["on"][name]) for name in weights["off"])


def test_gdnn_batches_augmented_on_the_device_are_the_cpu_paths(tmp_path):
    data = toy_labelled(n=32)
    data = LabelledImages(torch.stack([data.images, 255 - data.images], dim=1), data.labels)  # two renditions
    results = {}
    for placement in ("off", "on"):  # one after another: each run from its seed's torch generator (dropout)
        trainer = PosenetTrainer(posenet_config(epochs=2, shift=0.05, blur_px=1.0, erase=0.2,
                                                data_on_device=placement), tmp_path / placement, data)
        assert (trainer.device_data is not None) == (placement == "on")
        results[placement] = trainer.fit(progress=False)["best_holdout_nll"], _weights(trainer.model)
    (nll_off, off), (nll_on, on) = results["off"], results["on"]
    assert nll_off == nll_on and all(torch.equal(off[name], on[name]) for name in off)


def test_the_rate_scales_with_the_batch_and_warms_up():
    assert batch_scaled_lr(1e-3, 256, 16, "none") == 1e-3
    assert batch_scaled_lr(1e-3, 256, 16, "linear") == pytest.approx(16e-3)
    assert batch_scaled_lr(1e-3, 256, 16, "sqrt") == pytest.approx(4e-3)
    assert batch_scaled_lr(1e-3, 1024, 64, "sqrt") == pytest.approx(4e-3)
    with pytest.raises(ValueError, match=r"lr_scaling must be one of \('none', 'linear', 'sqrt'\)"):
        batch_scaled_lr(1e-3, 32, 16, "cubic")
    assert [warmup_factor(p, 0.1) for p in (0.0, 0.05, 0.1, 0.7)] == [0.0, 0.5, 1.0, 1.0]
    assert warmup_factor(0.0, 0.0) == 1.0
    config = TranslatorTrainConfig(paired_dirs=("toy",), epochs=10, batch_size=64, lr_scaling="sqrt",
                                   warmup_epochs=1.0, lr_schedule="cosine")
    assert run_lr(config, 0.05) == pytest.approx(2e-3 * 0.5 * (1 + math.cos(math.pi * 0.05)) * 0.5)
    assert run_lr(config, 0.5) == pytest.approx(1e-3)  # the peak 2e-3, half-way down the cosine
    assert config.lr_at(0.5) == run_lr(config, 0.5)
    default = TranslatorTrainConfig(paired_dirs=("toy",), batch_size=256)  # no scaling asked: the rate as given
    assert run_lr(default, 0.0) == default.lr and PosenetTrainConfig(paired_dirs=("toy",)).reference_batch == 64
    with pytest.raises(ValueError, match=r"warmup_epochs must be in \[0, epochs = 3\]"):
        TranslatorTrainConfig(paired_dirs=("toy",), epochs=3, warmup_epochs=4.0)
    with pytest.raises(ValueError, match=r"data_on_device must be one of \('auto', 'on', 'off'\)"):
        PosenetTrainConfig(paired_dirs=("toy",), data_on_device="gpu")


def test_a_checkpoint_from_before_the_gpu_knobs_resumes(tmp_path):
    config = tiny_config()
    saved = {k: v for k, v in vars(config).items()
             if k not in ("lr_scaling", "warmup_epochs", "data_on_device", "compile", "tf32")}
    check_same_settings(tmp_path / "checkpoint.pt", saved, config, TranslatorTrainer.resume_free)
    with pytest.raises(ValueError, match="lr_scaling"):
        check_same_settings(tmp_path / "checkpoint.pt", saved, tiny_config(lr_scaling="sqrt"),
                            TranslatorTrainer.resume_free)


def test_compile_falls_back_to_the_eager_network_with_one_warning(monkeypatch):
    model = torch.nn.Linear(3, 2)
    x = torch.ones(4, 3)

    def unavailable(module):
        raise RuntimeError("Dynamo is not supported on this platform")

    monkeypatch.setattr(torch, "compile", unavailable)
    with pytest.warns(RuntimeWarning, match=r"torch\.compile is unavailable here \(RuntimeError: Dynamo is not "
                                            r"supported on this platform\); the net trains uncompiled \(eager\)"):
        compiled = precision.Compiled(model, True, "the net")
    assert torch.equal(compiled(x), model(x))

    def fails_when_called(module):
        def run(*args):
            raise RuntimeError("no C++ compiler for inductor")
        return run

    monkeypatch.setattr(torch, "compile", fails_when_called)
    compiled = precision.Compiled(model, True, "the net")
    with pytest.warns(RuntimeWarning, match=r"no C\+\+ compiler for inductor\); the net trains uncompiled"):
        first = compiled(x)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one warning only: later calls run eagerly without a word
        assert torch.equal(compiled(x), first) and torch.equal(first, model(x))
    assert precision.Compiled(model, False).compiled is None  # off: the module itself, torch.compile not called


def test_the_gpu_profile_is_the_full_recipe_at_large_batches():
    from simshear_gym.pipelines.estimate import planned_steps

    config = load_config(ROOT / "configs" / "tactip331.toml")
    gpu, full = config.profile("gpu"), config.profile("full")
    assert (gpu.jobs, gpu.device, gpu.base, gpu.pool) == (1, "cuda", "full", full.pool)
    full_steps = {step.name: step.work for step in planned_steps(config, "full")}
    gpu_steps = {step.name: step.work for step in planned_steps(config, "gpu")}
    assert list(gpu_steps) == list(full_steps) and len(gpu_steps) == 21
    gpu_knobs = {"translator": {"batch_size": 256, "lr_scaling": "sqrt", "warmup_epochs": 1.0, "amp": False},
                 "posenet": {"batch_size": 1024, "lr_scaling": "sqrt", "warmup_epochs": 1.0}}
    for name, work in gpu_steps.items():
        knobs = gpu_knobs[work["trainer"]]
        assert work["settings"] == {**full_steps[name]["settings"], **knobs}, name  # same epochs, seeds, losses
        trainer_config = TranslatorTrainConfig if work["trainer"] == "translator" else PosenetTrainConfig
        peak = batch_scaled_lr(1e-3, knobs["batch_size"], trainer_config.reference_batch, "sqrt")
        assert peak == pytest.approx(4e-3)


def test_a_profile_base_must_be_defined_above_it(tmp_path):
    text = (ROOT / "configs" / "tactip331.toml").read_text()
    path = tmp_path / "lab.toml"
    path.write_text(text.replace('base = "full"', 'base = "later"'))
    with pytest.raises(ConfigError, match=r"\[profiles\.gpu\] base = 'later'; expected a profile built in or "
                                          r"defined above it"):
        load_config(path)
    path.write_text(text.replace('[profiles.gpu.posenet]\n', '[profiles.gpu.posenet]\nepochs = 5\n'))
    gpu = load_config(path).profile("gpu")
    assert gpu.posenet.setting("epochs") == 5 and gpu.posenet.contact_epochs == {"surface": 60}  # key by key


def test_a_probe_times_whole_batches_of_the_profiles_size():
    from simshear_gym.train.step_timing import PROBE_ROWS, posenet_step_time, probe_rows

    assert probe_rows(64, 0.1) == PROBE_ROWS
    assert probe_rows(1024, 0.1) == math.ceil(2048 / 0.9) + 2  # two whole batches beside the holdout
    timed = posenet_step_time({"image_size_px": 16, "conv_channels": [4, 8], "conv_kernels": [3, 3], "dense": [8],
                               "batch_size": 600, "data_on_device": "on"}, "surface", steps=1)
    assert timed.step_s > 0 and timed.holdout_s_per_row > 0


def test_translation_stays_on_the_cpu_unless_the_run_trains_on_a_gpu():
    from simshear_gym.train.posenet_trainer import on_translation_device

    translators = [object()]
    assert on_translation_device(translators, "cpu", 64) == (translators, 64)
    if not torch.cuda.is_available():
        assert on_translation_device(translators, "auto", 64) == (translators, 64)
