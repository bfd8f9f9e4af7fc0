"""Paired sets: replay labelled real contacts (or random ones) in simulation.

A **paired set** is a tactile-data set (see :mod:`simshear_gym.data.tactile_set`) whose ``images/`` are our sim
renders and whose ``targets.csv`` carries, per row: ``sensor_image`` (our render), ``real_image`` (the real
image of the same contact, a file in the real set named by ``meta.json``'s ``real_set``; empty for random
contacts), the labels ``pose_*`` and ``move_*``, and the shear vector in the sensor frame ``shear_sensor_*``
(from the :class:`~simshear_gym.sim.shear.ShearTracker`). ``meta.json`` records the contact type, the sensor
and geometry settings and where the real set lies (relative to the data root when it is under it).

``simshear collect --replay DIR [DIR ...] --out OUT`` and ``simshear collect --replay-all --out OUT`` (the eight
tactip331 sets) replay real sets; ``simshear collect --task surface|edge --n N --seed S --out OUT`` draws
random contacts over the real sets' ranges.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from simshear_gym.data.labels import (
    IMAGE_COLUMN, MOVE_COLUMNS, POSE_COLUMNS, SHEAR_COLUMNS, mount_rz_deg, task_ranges,
)
from simshear_gym.data.paths import SPLITS, TACTIP331_TASKS, data_root, real_set_dir
from simshear_gym.data.tactile_set import TactileDataError, TactileSet, image_name, read_set, write_image, write_targets
from simshear_gym.sim.replay import ReplayGeometry, ReplayScene, map_chunks
from simshear_gym.sim.shear import ShearTracker, ShearTrackerConfig
from simshear_gym.sim.tactip import TacTipConfig

REAL_IMAGE_COLUMN = "real_image"


@dataclass(frozen=True)
class CollectConfig:
    """Settings of one collection run (saved in each paired set's meta.json)."""

    tactip: TacTipConfig = TacTipConfig()
    geometry: ReplayGeometry = ReplayGeometry()
    shear: ShearTrackerConfig = ShearTrackerConfig()
    workers: int = 2

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")


def infer_task(directory: Path) -> tuple[str, str]:
    """(contact, kind) from a tactip331 path such as ``.../edge_2d/shear/csv_val``."""
    parts = set(Path(directory).resolve().parts)
    for (contact, kind), relative in TACTIP331_TASKS.items():
        if set(Path(relative).parts) <= parts:
            return contact, kind
    raise ValueError(
        f"cannot tell the contact type of {directory}: expected a path containing one of "
        f"{sorted(TACTIP331_TASKS.values())}, or pass --contact"
    )


def replay_shear(poses: np.ndarray, moves: np.ndarray, config: ShearTrackerConfig) -> np.ndarray:
    """Shear vectors (sensor frame) of labelled rows: the tracker anchored at ``pose - move``, read at ``pose``."""
    tracker = ShearTracker(config)
    shear = np.empty_like(poses)
    for index, (pose, move) in enumerate(zip(poses, moves)):
        tracker.touch(pose - move)
        shear[index] = tracker.update(pose, in_contact=True)
    return shear


def _render_and_write_chunk(args: tuple[str, np.ndarray, list[str], Path, CollectConfig]) -> int:
    contact, poses, names, images_dir, config = args
    with ReplayScene(contact, config.tactip, config.geometry) as scene:
        for name, pose in zip(names, poses):
            write_image(images_dir, name, scene.render(pose))
    return len(names)


def write_paired_set(out_dir: Path, contact: str, poses: np.ndarray, targets: pd.DataFrame, meta: dict,
                     config: CollectConfig) -> None:
    """Render ``poses`` into ``out_dir/images`` (named by ``targets.sensor_image``), then write the targets.

    Each worker renders and writes its own share of the images; ``targets.csv`` comes last, so a set without
    it is an interrupted one.
    """
    images_dir = out_dir / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    names = targets[IMAGE_COLUMN].to_list()
    shares = np.array_split(np.arange(len(names)), config.workers)
    chunks = [(contact, poses[share], [names[i] for i in share], images_dir, config) for share in shares if len(share)]
    map_chunks(_render_and_write_chunk, chunks, config.workers)
    write_targets(out_dir, targets, meta)


def replay_set(real_dir: Path, out_dir: Path, config: CollectConfig, root: Path | None = None,
               contact: str | None = None) -> int:
    """Render every row of a real set; returns the number of rows written."""
    real = read_set(real_dir, required_columns=POSE_COLUMNS)
    contact = contact or infer_task(real_dir)[0]
    poses, moves = real.poses(), real.moves()
    _check_mount(real)
    targets = pd.DataFrame({IMAGE_COLUMN: [image_name(i) for i in range(len(real))],
                            REAL_IMAGE_COLUMN: real.targets[IMAGE_COLUMN].to_numpy()})
    for column, values in zip(POSE_COLUMNS + MOVE_COLUMNS, np.hstack([poses, moves]).T):
        targets[column] = values
    for column, values in zip(SHEAR_COLUMNS, replay_shear(poses, moves, config.shear).T):
        targets[column] = values
    meta = _meta(config, contact, source="replay")
    meta["real_set"] = _relative_to(real_dir, root)
    meta["real_set_relative_to_data_root"] = meta["real_set"] != str(Path(real_dir).resolve())
    write_paired_set(out_dir, contact, poses, targets, meta, config)
    return len(real)


def random_set(contact: str, n: int, seed: int, out_dir: Path, config: CollectConfig) -> int:
    """Render ``n`` random contacts drawn uniformly over the real shear sets' ranges of a contact type."""
    rng = np.random.default_rng(seed)
    labels = np.zeros((n, 12))
    columns = list(POSE_COLUMNS + MOVE_COLUMNS)
    for label_range in task_ranges(contact, "shear"):
        labels[:, columns.index(label_range.column)] = rng.uniform(label_range.low, label_range.high, n)
    poses, moves = labels[:, :6], labels[:, 6:]
    targets = pd.DataFrame({IMAGE_COLUMN: [image_name(i) for i in range(n)], REAL_IMAGE_COLUMN: [""] * n})
    for column, values in zip(columns, labels.T):
        targets[column] = values
    for column, values in zip(SHEAR_COLUMNS, replay_shear(poses, moves, config.shear).T):
        targets[column] = values
    meta = _meta(config, contact, source="random")
    meta["seed"] = seed
    write_paired_set(out_dir, contact, poses, targets, meta, config)
    return n


def load_paired(directory: str | os.PathLike, root: str | os.PathLike | None = None
                ) -> tuple[TactileSet, TactileSet | None]:
    """A paired set and, for replayed sets, the real set it pairs with (None for random contacts).

    The real set's ``targets`` are reordered to the paired set's rows, so image ``i`` of both belong together.
    """
    paired = read_set(directory, required_columns=POSE_COLUMNS + MOVE_COLUMNS + SHEAR_COLUMNS)
    real_relative = paired.meta.get("real_set")
    if not real_relative:
        return paired, None
    real_dir = Path(real_relative)
    if paired.meta.get("real_set_relative_to_data_root"):
        real_dir = data_root(root) / real_dir
    real = read_set(real_dir)
    index = pd.Index(real.targets[IMAGE_COLUMN])
    positions = index.get_indexer(paired.targets[REAL_IMAGE_COLUMN])
    if (positions < 0).any():
        missing = paired.targets[REAL_IMAGE_COLUMN].iloc[int(np.flatnonzero(positions < 0)[0])]
        raise TactileDataError(f"{paired.root}/targets.csv: real_image {missing!r} is not in {real_dir}")
    real = TactileSet(real.root, real.targets.iloc[positions].reset_index(drop=True), real.meta)
    return paired, real


def _check_mount(real: TactileSet) -> None:
    if "obj_pose" in real.targets.columns:
        mounts = {mount_rz_deg(cell) for cell in real.targets["obj_pose"].unique()}
        if mounts != {-48.0}:
            raise TactileDataError(
                f"{real.root}/targets.csv: obj_pose Rz {sorted(mounts)}; the label conventions are verified for "
                "the -48 deg mount of the tactip331 sets (see simshear_gym.data.labels)"
            )


def _meta(config: CollectConfig, contact: str, source: str) -> dict:
    return {"contact": contact, "source": source, "tactip": asdict(config.tactip),
            "geometry": asdict(config.geometry), "shear_tracker": asdict(config.shear)}


def _relative_to(path: Path, root: Path | None) -> str:
    resolved = Path(path).resolve()
    if root is not None:
        try:
            return str(resolved.relative_to(Path(root).resolve()))
        except ValueError:
            pass
    return str(resolved)


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--replay", nargs="+", type=Path, metavar="REAL_SET_DIR",
                        help="real set directories to replay (images/ + targets.csv)")
    source.add_argument("--replay-all", action="store_true",
                        help="replay the eight tactip331 sets under the data root into OUT/<contact>_<kind>/<split>")
    source.add_argument("--task", choices=("surface", "edge"), help="random contacts of this type")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--n", type=int, default=5000, help="number of random contacts (--task)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random contacts (--task)")
    parser.add_argument("--contact", choices=("surface", "edge"), help="contact type of --replay sets "
                        "(default: read from the path)")
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--image-size", type=int, default=128, choices=(64, 128, 256))
    parser.add_argument("--workers", type=int, default=2, help="rendering processes")


def run(args: argparse.Namespace) -> int:
    config = CollectConfig(tactip=TacTipConfig(image_size_px=args.image_size), workers=args.workers)
    start = time.perf_counter()
    if args.task:
        jobs = [(f"random {args.task}", lambda: random_set(args.task, args.n, args.seed, args.out, config))]
    else:
        root = data_root(args.data) if (args.replay_all or args.data) else _optional_root()
        if args.replay_all:
            pairs = [(real_set_dir(root, contact, kind, split), args.out / f"{contact}_{kind}" / split)
                     for contact, kind in TACTIP331_TASKS for split in SPLITS]
        elif len(args.replay) == 1:
            pairs = [(args.replay[0], args.out)]
        else:
            pairs = [(d, args.out / "_".join(Path(d).resolve().parts[-3:])) for d in args.replay]
        jobs = [(str(real), lambda r=real, o=out: replay_set(r, o, config, root, args.contact)) for real, out in pairs]
    total = 0
    for name, job in jobs:
        rows = job()
        total += rows
        print(f"{name}: {rows} rows")
    elapsed = time.perf_counter() - start
    print(f"wrote {total} paired rows to {args.out} in {elapsed:.1f} s ({total / max(elapsed, 1e-9):.0f} rows/s)")
    return 0


def _optional_root() -> Path | None:
    try:
        return data_root()
    except FileNotFoundError:
        return None
