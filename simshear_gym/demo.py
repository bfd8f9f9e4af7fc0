"""``simshear demo``: the embedded default job, runnable on a fresh machine without the real data.

Renders random surface and edge contacts with the simulated TacTip and the shear tracker (the same code that
builds the paired training sets), writes them as paired sets under ``--out``, and a montage with each contact's
labels and shear vector. Later stages of the project extend this into the tracking demo.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory")
    parser.add_argument("--n", type=int, default=200, help="contacts per contact type")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)


def run(args: argparse.Namespace) -> int:
    import cv2

    from simshear_gym.data.collect import CollectConfig, load_paired, random_set
    from simshear_gym.data.labels import SHEAR_COLUMNS

    config = CollectConfig(workers=args.workers)
    tiles = []
    print(f"{'contact':8s} {'rows':>5s} {'s':>6s} {'rows/s':>7s} {'in contact':>10s} {'mean |shear xy| mm':>19s}")
    for contact in ("surface", "edge"):
        start = time.perf_counter()
        random_set(contact, args.n, args.seed, args.out / contact, config)
        seconds = time.perf_counter() - start
        paired, _ = load_paired(args.out / contact)
        images = paired.load_images()
        shear = paired.targets[list(SHEAR_COLUMNS)].to_numpy()
        touching = (images.max(axis=(1, 2)) > 0).mean()
        print(f"{contact:8s} {len(images):5d} {seconds:6.2f} {len(images) / seconds:7.0f} {touching:10.0%} "
              f"{np.hypot(shear[:, 0], shear[:, 1]).mean():19.2f}")
        for i in range(4):
            tile = cv2.cvtColor(np.clip(images[i].astype(np.float32) * 4, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
            pose = paired.poses()[i]
            lines = (f"{contact} z {pose[2]:.1f}mm", f"Rx {pose[3]:.0f} Ry {pose[4]:.0f} Rz {pose[5]:.0f}",
                     f"shear {shear[i, 0]:+.1f},{shear[i, 1]:+.1f}mm")
            for row, line in enumerate(lines):
                cv2.putText(tile, line, (2, 10 + 11 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.32, (0, 255, 255), 1)
            tiles.append(tile)
    figure = args.out / "demo.png"
    cv2.imwrite(str(figure), np.vstack([np.hstack(tiles[:4]), np.hstack(tiles[4:])]))
    print(f"wrote paired sets under {args.out} and the montage {figure}")
    return 0
