"""Training step time of the package's trainers in each memory layout: ``simshear evaluate train-speed``.

Times optimiser steps of the GDNN trainer (batch 64 of 64 px images, with its shift augmentation) and of the
translator trainer (batch 16 of 128 px pairs, the pipeline's density loss; decoder scale 0.5 as the shipped
translators, 1.0 as the pose-consistency generators) on random rows, with the networks in torch's default layout
(NCHW) and in ``channels_last`` (what the trainers use: :func:`simshear_gym.train.precision.memory_format`).
``--processes`` copies of each measurement run side by side on ``--threads`` threads each: ``--processes 2
--threads 1`` is how the pipeline trains on a 2-core CPU (two steps at a time, one thread each). Writes
``<out>/train_speed.json`` (default ``results/ablations``) with the command. CPU only: on CUDA both trainers
already ran in ``channels_last`` before it was the default everywhere.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

#: the measured trainer steps: name -> (trainer, the translator's decoder scale or None)
MODELS = {"gdnn": ("posenet", None), "translator_decoder0.5": ("translator", 0.5),
          "translator_decoder1.0": ("translator", 1.0)}
LAYOUTS = ("default", "channels_last")


def _trainer(model: str, threads: int, run_dir: Path):
    """A trainer of ``model`` on random rows, and the index of one batch."""
    import torch

    from simshear_gym.models.gdnn import variable_set
    from simshear_gym.train.posenet_config import PosenetTrainConfig
    from simshear_gym.train.posenet_trainer import LabelledImages, PosenetTrainer
    from simshear_gym.train.translator_config import TranslatorTrainConfig
    from simshear_gym.train.translator_trainer import PairedTensors, TranslatorTrainer

    kind, decoder_scale = MODELS[model]
    generator = torch.Generator().manual_seed(0)
    if kind == "posenet":
        config = PosenetTrainConfig(source="real", contact="surface", paired_dirs=("random",), threads=threads,
                                    device="cpu", holdout=0.1)
        width = len(variable_set(config.contact).variables)  # labels in the variables' units
        rows = LabelledImages(torch.randint(0, 256, (160, 64, 64), dtype=torch.uint8, generator=generator),
                              torch.rand(160, width, generator=generator))
        return PosenetTrainer(config, run_dir, rows), np.arange(config.batch_size)
    config = TranslatorTrainConfig(arch="shpix2pix", paired_dirs=("random",), decoder_scale=decoder_scale,
                                   density_weight=100.0, threads=threads, device="cpu")
    pairs = PairedTensors(torch.randint(0, 256, (40, 128, 128), dtype=torch.uint8, generator=generator),
                          torch.randn(40, 6, generator=generator),
                          torch.randint(0, 256, (40, 128, 128), dtype=torch.uint8, generator=generator))
    return TranslatorTrainer(config, run_dir, pairs), np.arange(config.batch_size)


def step_ms(model: str, layout: str, steps: int, threads: int) -> float:
    """Median wall time (ms) of one training step of ``model`` with its networks in ``layout``."""
    import torch

    from simshear_gym.train.step_timing import median_s

    torch.set_num_threads(threads)
    fmt = torch.channels_last if layout == "channels_last" else torch.contiguous_format
    with tempfile.TemporaryDirectory() as folder:
        trainer, batch = _trainer(model, threads, Path(folder))
        networks = [trainer.model] if hasattr(trainer, "model") else [trainer.generator]
        for network in networks:
            network.to(memory_format=fmt)
        trainer.memory_format = fmt  # the layout each batch is moved into
        trainer.train_mode()
        return 1000.0 * median_s(lambda: trainer.train_batch(batch), steps, warmup=3)  # after 3 warm-up steps


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--models", nargs="+", choices=sorted(MODELS), default=list(MODELS),
                        help="trainer steps to time (default all)")
    parser.add_argument("--steps", type=int, default=30, help="timed steps per measurement (default 30)")
    parser.add_argument("--processes", type=int, default=2,
                        help="copies of each measurement side by side (default 2: the pipeline's two lanes)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per process (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results/ablations"),
                        help="directory for train_speed.json (default results/ablations)")


def run(args: argparse.Namespace) -> int:
    import multiprocessing

    for name in ("steps", "processes", "threads"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} must be a positive integer, got {getattr(args, name)!r}")
    rows = []
    with multiprocessing.get_context("spawn").Pool(args.processes) as pool:
        for model in args.models:
            row = {"model": model}
            for layout in LAYOUTS:  # every process times the same step at the same time
                times = pool.starmap(step_ms, [(model, layout, args.steps, args.threads)] * args.processes)
                row[f"ms_per_step_{layout}"] = round(float(np.mean(times)), 2)
            row["speedup"] = round(row["ms_per_step_default"] / row["ms_per_step_channels_last"], 3)
            rows.append(row)
            print(f"{model:22s} default {row['ms_per_step_default']:7.1f} ms   channels_last "
                  f"{row['ms_per_step_channels_last']:7.1f} ms   {row['speedup']:.2f}x")
    write_record("simshear evaluate train-speed", add_arguments, args, args.out / "train_speed.json", {
        "what": "median wall time of one training step per process (mean over the processes running side by side)"
                ", networks and batches in each memory layout; random rows (timing only)",
        "machine": machine_info(),
        "processes": args.processes, "torch_threads": args.threads, "models": rows,
    })
    print(f"wrote {args.out / 'train_speed.json'}")
    return 0
