"""What a training run's work costs on this machine, measured on random rows of the real shapes before any data is
loaded: the wall time of a trainer's optimiser step and of its holdout pass, and of a generator's translation of
a batch (the GDNN on translated images translates its sets first). The trainers are the package's own
(:class:`~simshear_gym.train.translator_trainer.TranslatorTrainer`,
:class:`~simshear_gym.train.posenet_trainer.PosenetTrainer`), built with the run's settings, so a step is the
step a run takes (layout, losses, augmentation, batch size; on a GPU the device-resident batches of the run's
``data_on_device``); a pose-consistency translator reads its images with a GDNN of
the real-image reference's architecture (random weights). Used by :mod:`simshear_gym.pipelines.estimate`.

Times are per process: run the probes as many side by side as the run will train (its ``jobs``), since two
trainers on a 2-core CPU each run slower than one alone. A probe runs on the ``device`` the run will train on
("cpu", "cuda" or "auto"); on a GPU each timed step ends with a synchronisation, so that it counts the GPU's work,
not only its launch.
"""

from __future__ import annotations

import itertools
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simshear_gym.models.device import resolve_device

PROBE_ROWS = 512
"""Rows of the random set a probe trains on (the holdout pass is timed on its share of them and scaled), or more
where the run's batch needs them (:func:`probe_rows`)."""


def probe_rows(batch_size: int, holdout: float) -> int:
    """Rows of a probe's random set: :data:`PROBE_ROWS`, or enough for two whole training batches of
    ``batch_size`` beside the ``holdout`` share (a GPU run's batch of 1024 is timed at 1024 rows, not cut to what
    512 rows leave)."""
    return max(PROBE_ROWS, math.ceil(2 * batch_size / (1.0 - holdout)) + 2)


@dataclass(frozen=True)
class StepTime:
    """Seconds of one optimiser step, and of the holdout pass per holdout row."""

    step_s: float
    holdout_s_per_row: float


def _synchronise(device: str) -> None:
    """Wait for a CUDA device's queued work (nothing to wait for on the CPU)."""
    if device != "cpu":
        import torch

        torch.cuda.synchronize()


def median_s(action, repeats: int, warmup: int, device: str = "cpu") -> float:
    """Median seconds of ``repeats`` calls of ``action`` after ``warmup`` untimed ones (on a GPU ``device`` each
    call ends with a synchronisation)."""
    for _ in range(warmup):
        action()
    _synchronise(device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        _synchronise(device)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _time_trainer(trainer, holdout_rows: int, steps: int, ready=None, device: str = "cpu") -> StepTime:
    if ready is not None:
        ready()
    trainer.train_mode()
    size = trainer.config.batch_size
    batches = itertools.cycle([index for index in trainer.epoch_batches() if len(index) == size])  # whole ones
    step_s = median_s(lambda: trainer.train_batch(next(batches)), steps, warmup=3, device=device)
    start = time.perf_counter()
    trainer.holdout_metric()
    _synchronise(device)
    return StepTime(step_s, (time.perf_counter() - start) / holdout_rows)


def translator_step_time(settings: dict, image_size_px: int, steps: int = 10, threads: int = 1,
                         ready=None, device: str = "cpu") -> StepTime:
    """A translator run's step with ``settings`` (:class:`~simshear_gym.train.translator_config.TranslatorTrainConfig`
    fields; ``pose_weight`` > 0: with the pose-consistency loss); ``ready`` (if given) is called once the trainer
    is built, before the first step (a barrier, so that probes side by side time their steps together)."""
    import torch

    from simshear_gym.models.gdnn import GDNN
    from simshear_gym.models.posenet_io import save_posenet
    from simshear_gym.train.pose_consistency import PoseConsistency
    from simshear_gym.train.posenet_config import PosenetTrainConfig
    from simshear_gym.train.translator_config import TranslatorTrainConfig
    from simshear_gym.train.translator_trainer import PairedTensors, TranslatorTrainer

    torch.set_num_threads(threads)
    device = resolve_device(device).type  # "cpu" or "cuda": where the run trains here
    generator = torch.Generator().manual_seed(0)
    with tempfile.TemporaryDirectory() as folder:
        pose, pose_settings = None, {}
        if settings.get("pose_weight", 0) > 0:
            reader = GDNN(PosenetTrainConfig(paired_dirs=("random",)).gdnn_config())
            path = save_posenet(Path(folder) / "reader.pt", reader)
            pose = PoseConsistency(path)
            pose_settings = {"pose_net": str(path), "pose_variables": ()}
        config = TranslatorTrainConfig(**{**settings, **pose_settings, "paired_dirs": ("random",),
                                          "image_size_px": image_size_px, "device": device, "threads": threads})
        rows = probe_rows(config.batch_size, config.holdout)
        shape = (rows, image_size_px, image_size_px)
        pairs = PairedTensors(torch.randint(0, 256, shape, dtype=torch.uint8, generator=generator),
                              torch.randn(rows, 6, generator=generator),
                              torch.randint(0, 256, shape, dtype=torch.uint8, generator=generator),
                              torch.rand(rows, pose.variables.encoded_dim if pose else 1,
                                         generator=generator) if pose else None)
        trainer = TranslatorTrainer(config, Path(folder) / "run", pairs, pose=pose)
        return _time_trainer(trainer, len(trainer.holdout_pairs), steps, ready, device)


def posenet_step_time(settings: dict, variables: str, views: int = 1, steps: int = 10, threads: int = 1,
                      ready=None, device: str = "cpu") -> StepTime:
    """A GDNN run's step with ``settings`` (:class:`~simshear_gym.train.posenet_config.PosenetTrainConfig` fields)
    reading ``variables`` (a variable set's name or inline spec), on rows of ``views`` renditions each; ``ready``
    as for :func:`translator_step_time`."""
    import torch

    from simshear_gym.models.gdnn import variable_set
    from simshear_gym.train.posenet_config import PosenetTrainConfig
    from simshear_gym.train.posenet_trainer import LabelledImages, PosenetTrainer

    torch.set_num_threads(threads)
    device = resolve_device(device).type  # "cpu" or "cuda": where the run trains here
    generator = torch.Generator().manual_seed(0)
    config = PosenetTrainConfig(**{**settings, "paired_dirs": ("random",), "variables": variables, "device": device,
                                   "threads": threads})
    size, rows = config.image_size_px, probe_rows(config.batch_size, config.holdout)
    shape = (rows, views, size, size) if views > 1 else (rows, size, size)
    specs = variable_set(variables).variables
    low, high = torch.tensor([v.low for v in specs]), torch.tensor([v.high for v in specs])
    labels = low + (high - low) * torch.rand(rows, len(low), generator=generator)
    data = LabelledImages(torch.randint(0, 256, shape, dtype=torch.uint8, generator=generator), labels)
    with tempfile.TemporaryDirectory() as folder:
        trainer = PosenetTrainer(config, Path(folder) / "run", data)
        return _time_trainer(trainer, len(trainer.holdout_data), steps, ready, device)


def translation_s_per_row(settings: dict, image_size_px: int, batch: int = 64, repeats: int = 3,
                          threads: int = 1, device: str = "cpu") -> float:
    """Seconds per row of a generator with ``settings`` translating batches of ``batch`` sim renders on ``device``
    (on a GPU as a GDNN's rows are translated there: :func:`~simshear_gym.train.posenet_trainer.load_source`)."""
    import torch

    from simshear_gym.models.translator import Translator
    from simshear_gym.models.unet import UNetGenerator
    from simshear_gym.train.translator_config import TranslatorTrainConfig

    torch.set_num_threads(threads)
    config = TranslatorTrainConfig(**{**settings, "paired_dirs": ("random",), "image_size_px": image_size_px,
                                      "pose_weight": 0.0, "pose_net": ""})
    from simshear_gym.train.posenet_trainer import on_translation_device

    (translator,), batch = on_translation_device([Translator(UNetGenerator(config.generator_config()))],
                                                 resolve_device(device).type, batch)
    rng = np.random.default_rng(0)
    sim = rng.integers(0, 256, (batch, image_size_px, image_size_px), dtype=np.uint8)
    shear = rng.normal(size=(batch, 6)).astype(np.float32)
    return median_s(lambda: translator(sim, shear), repeats, warmup=1) / batch
