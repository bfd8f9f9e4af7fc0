"""Agreement of our sim renders with the published Tactile Gym renders of the same label rows.

The published sim images are spatially aligned with the real images, so agreeing with them places our contacts
where the real contacts are. Per row: IoU of the contact regions (pixels > 0) and the distance between their
centroids (px); rows where both images are empty count as IoU 1, distance 0; where one is empty, IoU 0 and the
distance is undefined (reported as a count). Also the mean grey level inside the common contact region, ours
over theirs. ``simshear evaluate render`` writes ``results/render_agreement.json`` and a montage
(ours | published sim | real) per set.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from simshear_gym.data.paths import (
    TACTIP331_TASKS,
    data_root,
    published_sim_set_dir,
    real_set_dir,
)
from simshear_gym.data.tactile_set import read_set
from simshear_gym.evaluate.records import write_record

# pybullet (via simshear_gym.sim) is imported inside evaluate and run, so that --help stays light.
if TYPE_CHECKING:
    from simshear_gym.sim.replay import ReplayGeometry
    from simshear_gym.sim.tactip import TacTipConfig


def contact_agreement(ours: np.ndarray, theirs: np.ndarray) -> dict[str, np.ndarray]:
    """Per-image IoU, centroid distance (px, NaN where undefined) and grey-level ratio of two (N, H, W) stacks."""
    mine, other = ours > 0, theirs > 0
    intersection = (mine & other).sum(axis=(1, 2))
    union = (mine | other).sum(axis=(1, 2))
    iou = np.where(union > 0, intersection / np.maximum(union, 1), 1.0)
    distance = np.linalg.norm(_centroids(mine) - _centroids(other), axis=1)
    distance[(union == 0)] = 0.0
    both = mine & other
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = (ours * both).sum(axis=(1, 2)) / (theirs * both).sum(axis=(1, 2))
    return {"iou": iou, "centroid_error_px": distance, "grey_ratio": ratio}


def _centroids(masks: np.ndarray) -> np.ndarray:
    rows, cols = np.indices(masks.shape[1:])
    count = masks.sum(axis=(1, 2)).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([(masks * cols).sum(axis=(1, 2)) / count, (masks * rows).sum(axis=(1, 2)) / count], axis=1)


def summarise(values: dict[str, np.ndarray]) -> dict[str, float]:
    iou, distance, ratio = values["iou"], values["centroid_error_px"], values["grey_ratio"]
    finite = distance[np.isfinite(distance)]
    return {
        "n": int(len(iou)),
        "iou_median": float(np.median(iou)), "iou_mean": float(np.mean(iou)),
        "iou_p10": float(np.percentile(iou, 10)),
        "centroid_error_px_median": float(np.median(finite)) if len(finite) else float("nan"),
        "centroid_error_px_p90": float(np.percentile(finite, 90)) if len(finite) else float("nan"),
        "one_side_empty": int((~np.isfinite(distance)).sum()),
        "grey_ratio_median": float(np.nanmedian(ratio)),
    }


def evaluate(root: Path, split: str = "val", n_rows: int | None = None, workers: int = 2,
             tactip: TacTipConfig | None = None, geometry: ReplayGeometry | None = None
             ) -> tuple[dict, dict[tuple[str, str], tuple[np.ndarray, ...]]]:
    """Agreement per tactip331 set (``tactip``, ``geometry``: None for the defaults); returns the summary and
    (ours, published, real) stacks for figures."""
    from simshear_gym.sim.replay import ReplayGeometry, render_poses
    from simshear_gym.sim.tactip import TacTipConfig

    tactip = TacTipConfig() if tactip is None else tactip
    geometry = ReplayGeometry() if geometry is None else geometry
    summary: dict = {}
    stacks = {}
    for contact, kind in TACTIP331_TASKS:
        published = read_set(published_sim_set_dir(root, contact, kind, split, tactip.image_size_px))
        real = read_set(real_set_dir(root, contact, kind, split))
        rows = slice(0, n_rows)
        poses = published.poses()[rows]
        if not np.allclose(poses, real.poses()[rows], atol=1e-9):
            raise ValueError(f"{published.root} and {real.root}: label rows differ; expected the same contacts")
        ours = render_poses(contact, poses, tactip, geometry, workers=workers)
        theirs = published.load_images()[rows]
        summary[f"{contact}_{kind}"] = summarise(contact_agreement(ours, theirs))
        stacks[(contact, kind)] = (ours, theirs, real.load_images()[rows])
    return summary, stacks


def montage(stacks: dict, path: Path, per_set: int = 4) -> None:
    """Rows of (ours | published sim | real) triplets, ``per_set`` per set; grey levels stretched for display."""
    import cv2

    rows = []
    for (contact, kind), (ours, theirs, real) in stacks.items():
        picks = np.linspace(0, len(ours) - 1, per_set).astype(int)
        tiles = []
        for i in picks:
            scale = 255.0 / max(int(ours[i].max()), int(theirs[i].max()), 1)
            triplet = [np.clip(ours[i] * scale, 0, 255), np.clip(theirs[i] * scale, 0, 255), real[i]]
            gap = np.full((ours.shape[1], 4), 128, np.uint8)
            tiles.append(np.hstack([t.astype(np.uint8) for t in triplet] + [gap]))
        row = np.hstack(tiles)
        cv2.putText(row, f"{contact} {kind}: ours | published sim | real", (4, 12), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, 255, 1)
        rows.append(row)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.vstack(rows))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--split", default="val", choices=("train", "val"),
                        help="which split of the eight tactip331 sets to render and compare (default val)")
    parser.add_argument("--rows", type=int, default=None, help="only the first ROWS of each set (default all)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes (default 2)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.sim.replay import ReplayGeometry
    from simshear_gym.sim.tactip import TacTipConfig

    start = time.perf_counter()
    summary, stacks = evaluate(data_root(args.data), args.split, args.rows, args.workers)
    figure = args.out / "render_agreement.png"
    montage(stacks, figure)
    payload = {
        "split": args.split, "tactip": TacTipConfig().__dict__, "geometry": ReplayGeometry().__dict__,
        "goal": {"iou_median_min": 0.8, "centroid_error_px_median_max": 2.0},
        "sets": summary, "figure": str(figure), "seconds": round(time.perf_counter() - start, 1),
    }
    write_record("simshear evaluate render", add_arguments, args, args.out / "render_agreement.json", payload)
    for name, figures in summary.items():
        print(f"{name:14s} IoU median {figures['iou_median']:.3f} (p10 {figures['iou_p10']:.3f})  "
              f"centroid error median {figures['centroid_error_px_median']:.2f} px  "
              f"one side empty {figures['one_side_empty']}  grey ratio {figures['grey_ratio_median']:.2f}")
    print(f"wrote {args.out / 'render_agreement.json'} and {figure}")
    return 0
