"""Translator inference latency: per image at batch 1 and at batch 32 (or ``--batch-sizes``), for the shipped models.

``simshear evaluate translator-speed`` writes ``results/translator_speed.json`` (``--device cuda``:
``<out>/translator_speed_cuda.json``). The envs call the translator every step, so batch 1 is the single-env
cost and batch 32 the per-image cost of a vectorised env. On CUDA the time is the whole call as an env makes it:
uint8 images in, the copy to the GPU, the generator, the copy back, uint8 images out.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info


def latency_ms(translator, batch: int, repeats: int, rng: np.random.Generator) -> float:
    """Median wall time per image (ms) of translating random contacts in batches of ``batch`` (after one warm-up
    batch)."""
    from simshear_gym.train.step_timing import median_s

    size = translator.image_size_px
    sim = rng.integers(0, 60, (batch, size, size), dtype=np.uint8)
    shear = rng.uniform(-5, 5, (batch, 6)).astype(np.float32)
    return 1000.0 * median_s(lambda: translator(sim, shear), repeats, warmup=1) / batch


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.models.device import DEVICES

    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--device", choices=DEVICES, default="cpu",
                        help="where the generator runs (default cpu; auto: CUDA where there is one)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 32],
                        help="batch sizes to time (default 1 32); batch 1 takes --repeats batches, the others a "
                             "fifth of them (at least 3)")
    parser.add_argument("--repeats", type=int, default=30,
                        help="timed batches at batch 1 (a fifth, at least 3, at batch 32); the median counts "
                             "(default 30)")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results directory for translator_speed.json (default results)")


def run(args: argparse.Namespace) -> int:
    import torch

    from simshear_gym.evaluate.translation import on_device
    from simshear_gym.models.device import resolve_device
    from simshear_gym.models.translator import Translator
    from simshear_gym.models.zoo import shipped_translators

    bad = [size for size in args.batch_sizes if size < 1]
    if bad:
        raise ValueError(f"--batch-sizes must be positive integers, got {bad}")
    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    machine = {**machine_info(),
               "device": str(device)}
    if device.type == "cuda":
        machine["gpu"] = torch.cuda.get_device_name(device)
    rng = np.random.default_rng(0)
    rows = []
    for (arch, contact), path in sorted(shipped_translators().items()):
        translator = on_device(Translator.load(path), device)  # on a GPU: the generator there, the same uint8 calls
        row = {"model": arch, "contact": contact, "weights": path.name}
        for size in args.batch_sizes:
            repeats = args.repeats if size == 1 else max(args.repeats // 5, 3)
            row[f"ms_per_image_batch{size}"] = round(latency_ms(translator, size, repeats, rng), 4)
        rows.append(row)
        print(f"{arch:10s} {contact:8s} " + "   ".join(f"batch {size}: {row[f'ms_per_image_batch{size}']:.3f} ms/image"
                                                    for size in args.batch_sizes))
    name = "translator_speed.json" if device.type == "cpu" else f"translator_speed_{device.type}.json"
    write_record("simshear evaluate translator-speed", add_arguments, args, args.out / name, {
        "machine": machine, "torch_threads": args.threads, "models": rows,
    })
    print(f"wrote {args.out / name}")
    return 0
