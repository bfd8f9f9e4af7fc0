"""``simshear pipeline make-example --out DIR``: a second lab's data set, made from the real tactip331 surface tap
images, for ``configs/example_lab.toml`` (the README's "Bring your own sensor" walk-through and its tests).

It is meant to look like another lab's recording, not a renamed copy:

- images: 256 px, placed off-centre in a 300x280 px grey frame (the config crops and resizes them back), named
  ``frame_00000.png``.. in a column ``file``;
- one CSV ``labels.csv`` with its own column names and a split column ``subset`` (``tr`` / ``te``);
- tap only: no shear labels;
- another frame: the sensor pushes horizontally, along the lab's +y, so depth is ``sensor_y_m`` (metres, relative
  to where it touched, not an indentation), and the tilts are ``roll_rad`` (about lab x) and ``yaw_rad`` (about lab
  z, the sensor's pitch in the simulation's frame), in radians.

``configs/example_lab.toml`` maps it back (axes ``["x", "-z", "y"]``, origin 2.2 mm behind the touch) and also
simulates another dome (22 mm radius).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from simshear_gym.data.labels import SURFACE_DEPTH_MM
from simshear_gym.data.paths import data_root, real_set_dir
from simshear_gym.data.tactile_set import decode_image, read_set

CANVAS_PX = (300, 280)  # (width, height)
IMAGE_PX = 256
OFFSET_PX = (22, 12)  # (x, y) of the image in the canvas
SPLIT_VALUES = {"csv_train": "tr", "csv_val": "te"}


def make_example(root: Path, out: Path, rows_per_split: int | None = None, seed: int = 0) -> Path:
    """Write the example lab set under ``out`` (``labels.csv``, ``frames/``); returns ``out``."""
    rng = np.random.default_rng(seed)
    frames = out / "frames"
    frames.mkdir(parents=True, exist_ok=True)
    records = []
    for split, value in SPLIT_VALUES.items():
        real = read_set(real_set_dir(root, "surface", "tap", split))
        count = len(real) if rows_per_split is None else min(rows_per_split, len(real))
        rows = np.sort(rng.choice(len(real), count, replace=False)) if count < len(real) else np.arange(count)
        poses = real.poses()[rows]
        paths = real.image_paths()
        for row, pose in zip(rows, poses):
            name = f"frame_{len(records):05d}.png"
            image = decode_image(paths[row], cv2.IMREAD_GRAYSCALE)
            image = cv2.resize(image, (IMAGE_PX, IMAGE_PX), interpolation=cv2.INTER_LINEAR)
            canvas = np.full((CANVAS_PX[1], CANVAS_PX[0]), 40, dtype=np.uint8)
            canvas[OFFSET_PX[1]:OFFSET_PX[1] + IMAGE_PX, OFFSET_PX[0]:OFFSET_PX[0] + IMAGE_PX] = image
            cv2.imwrite(str(frames / name), canvas)
            records.append({
                "file": name,
                "subset": value,
                "sensor_y_m": (pose[2] - SURFACE_DEPTH_MM) / 1000.0,  # lab y = sim z, relative to the touch
                "roll_rad": math.radians(pose[3]),  # lab Rx = sim Rx
                "yaw_rad": math.radians(-pose[4]),  # lab Rz = -sim Ry (sim y = -lab z)
                "trial": len(records),
            })
    pd.DataFrame.from_records(records).to_csv(out / "labels.csv", index=False)
    return out


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="folder to write labels.csv and frames/ into")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root holding tactip331/ (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--rows", type=int, default=None,
                        help="rows per split drawn from the real surface tap sets (default: all, 5000 + 2000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the row draw")


def run(args: argparse.Namespace) -> int:
    out = make_example(data_root(args.data), args.out, args.rows, args.seed)
    print(f"wrote {out / 'labels.csv'} and {out / 'frames'}; check it with: simshear pipeline check "
          f"configs/example_lab.toml --data {out}")
    return 0
