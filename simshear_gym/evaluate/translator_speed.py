"""Translator inference latency on this CPU: per image at batch 1 and at batch 32, for the shipped models.

``simshear evaluate translator-speed`` writes ``results/translator_speed.json``. The envs call the translator
every step, so batch 1 is the single-env cost and batch 32 the per-image cost of a vectorised env.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from simshear_gym.io import write_json


def latency_ms(translator, batch: int, repeats: int, rng: np.random.Generator) -> float:
    """Median wall time per image (ms) of translating random contacts in batches of ``batch``."""
    size = translator.image_size_px
    sim = rng.integers(0, 60, (batch, size, size), dtype=np.uint8)
    shear = rng.uniform(-5, 5, (batch, 6)).astype(np.float32)
    translator(sim, shear)  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        translator(sim, shear)
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times)) / batch


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--repeats", type=int, default=30,
                        help="timed batches at batch 1 (a fifth, at least 3, at batch 32); the median counts "
                             "(default 30)")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results directory for translator_speed.json (default results)")


def run(args: argparse.Namespace) -> int:
    import torch

    from simshear_gym.models.translator import Translator, shipped_models

    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    rows = []
    for (arch, contact), path in sorted(shipped_models().items()):
        translator = Translator.load(path)
        row = {"model": arch, "contact": contact, "weights": path.name,
               "ms_per_image_batch1": round(latency_ms(translator, 1, args.repeats, rng), 3),
               "ms_per_image_batch32": round(latency_ms(translator, 32, max(args.repeats // 5, 3), rng), 3)}
        rows.append(row)
        print(f"{arch:10s} {contact:8s} batch 1: {row['ms_per_image_batch1']:.2f} ms/image   "
              f"batch 32: {row['ms_per_image_batch32']:.2f} ms/image")
    write_json(args.out / "translator_speed.json", {
        "command": f"simshear evaluate translator-speed --threads {args.threads}",
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "torch_threads": args.threads, "models": rows,
    })
    print(f"wrote {args.out / 'translator_speed.json'}")
    return 0
