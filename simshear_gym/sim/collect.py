"""Render paired sets: replay each row of a real set (or random contacts over its ranges) in simulation and
write our sim image, the shear vector and the labels beside the real image (format: :mod:`simshear_gym.data.paired`).

Rendering is split into ``workers`` chunks (:func:`~simshear_gym.sim.parallel.map_chunks`), each rendered with
its own scene: in as many processes that also write their images, or, with ``ray_address``, as Ray tasks that
return their images to this process, which writes them (a cluster's nodes need not see the output disk). The
labels (random contacts included) are drawn here before the split, and an image depends only on its row's pose,
so a set is the same, byte for byte, whatever the number of workers and whichever executor renders it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from simshear_gym.data.labels import (
    IMAGE_COLUMN,
    MOVE_COLUMNS,
    POSE_COLUMNS,
    SHEAR_COLUMNS,
    mount_rz_deg,
    task_ranges,
)
from simshear_gym.data.paired import REAL_IMAGE_COLUMN
from simshear_gym.data.paths import infer_task
from simshear_gym.data.tactile_set import (
    TactileDataError,
    TactileSet,
    image_name,
    read_set,
    write_image,
    write_targets,
)
from simshear_gym.sim.parallel import check_ray_address, map_chunks
from simshear_gym.sim.replay import ReplayGeometry, ReplayScene, render_poses
from simshear_gym.sim.shear import ShearTrackerConfig, replay_shear
from simshear_gym.sim.tactip import TacTipConfig


@dataclass(frozen=True)
class CollectConfig:
    """Settings of one collection run (the sensor, geometry and shear settings are saved in each paired set's
    meta.json; ``workers`` and ``ray_address`` only say where it runs).

    Attributes:
        workers: chunks the rows are split into, rendered in as many processes (or Ray tasks).
        ray_address: None (plain processes), ``"local"`` (a Ray on this machine), ``"auto"`` or ``HOST:PORT``
            (a running Ray cluster); see :mod:`simshear_gym.sim.parallel`.
    """

    tactip: TacTipConfig = TacTipConfig()
    geometry: ReplayGeometry = ReplayGeometry()
    shear: ShearTrackerConfig = ShearTrackerConfig()
    workers: int = 2
    ray_address: str | None = None

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        check_ray_address(self.ray_address)


def _render_and_write_chunk(args: tuple[str, np.ndarray, list[str], Path, CollectConfig]) -> int:
    contact, poses, names, images_dir, config = args
    with ReplayScene(contact, config.tactip, config.geometry) as scene:
        for name, pose in zip(names, poses):
            write_image(images_dir, name, scene.render(pose))
    return len(names)


def write_paired_set(out_dir: Path, contact: str, poses: np.ndarray, targets: pd.DataFrame, meta: dict,
                     config: CollectConfig) -> None:
    """Render ``poses`` into ``out_dir/images`` (named by ``targets.sensor_image``), then write the targets.

    Each worker process renders and writes its own share of the images (Ray tasks render theirs, and this
    process writes them); ``targets.csv`` comes last, so a set without it is an interrupted one.
    """
    images_dir = out_dir / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    names = targets[IMAGE_COLUMN].to_list()
    if config.ray_address is None:
        shares = np.array_split(np.arange(len(names)), config.workers)
        chunks = [(contact, poses[share], [names[i] for i in share], images_dir, config)
                  for share in shares if len(share)]
        map_chunks(_render_and_write_chunk, chunks, config.workers)
    else:
        images = render_poses(contact, poses, config.tactip, config.geometry, config.workers, config.ray_address)
        for name, image in zip(names, images):
            write_image(images_dir, name, image)
    write_targets(out_dir, targets, meta)


def replay_set(real_dir: Path, out_dir: Path, config: CollectConfig, root: Path | None = None,
               contact: str | None = None) -> int:
    """Render every row of a real set; returns the number of rows written."""
    real = read_set(real_dir, required_columns=POSE_COLUMNS)
    contact = contact or infer_task(real_dir)[0]
    labels = np.hstack([real.poses(), real.moves()])
    _check_mount(real)
    real_set = _relative_to(real_dir, root)
    extra = {"real_set": real_set, "real_set_relative_to_data_root": real_set != str(Path(real_dir).resolve())}
    return labelled_set(contact, labels, out_dir, config, "replay", extra, real.targets[IMAGE_COLUMN].to_numpy())


def random_set(contact: str, n: int, seed: int, out_dir: Path, config: CollectConfig,
               ranges: dict[str, tuple[float, float]] | None = None, tap_share: float = 0.0) -> int:
    """Render ``n`` random contacts drawn uniformly over label ranges: ``ranges`` ({``pose_1..6`` / ``move_1..6``
    column: (low, high)}; the columns it leaves out stay 0), by default the tactip331 shear sets' ranges of the
    contact type. ``tap_share`` of the rows (drawn at random, after the labels, so that the poses do not change
    with it) are taps: their move columns 0, so no shear."""
    if not 0.0 <= tap_share <= 1.0:
        raise ValueError(f"random contacts: tap_share must be a share in [0, 1], got {tap_share!r}")
    rng = np.random.default_rng(seed)
    labels = np.zeros((n, 12))
    columns = list(POSE_COLUMNS + MOVE_COLUMNS)
    if ranges is None:
        ranges = {r.column: (r.low, r.high) for r in task_ranges(contact, "shear")}
    unknown = sorted(set(ranges) - set(columns))
    if unknown:
        raise ValueError(f"random contacts: unknown label column {unknown[0]!r}; expected some of {columns}")
    for column, (low, high) in ranges.items():
        labels[:, columns.index(column)] = rng.uniform(low, high, n)
    taps = rng.permutation(n)[:round(tap_share * n)] if tap_share else []
    labels[taps, 6:] = 0.0
    extra = {"seed": seed, **({"tap_share": tap_share} if tap_share else {})}
    return labelled_set(contact, labels, out_dir, config, "random", extra)


def labelled_set(contact: str, labels: np.ndarray, out_dir: Path, config: CollectConfig, source: str,
                 extra_meta: dict | None = None, real_images: np.ndarray | None = None) -> int:
    """Render the contacts of ``labels`` ((N, 12): ``pose_1..6``, ``move_1..6``) as a paired set, without real
    images or beside ``real_images`` (their names, one per row); ``source`` and ``extra_meta`` go into its meta.
    Returns the number of rows."""
    labels = np.asarray(labels, dtype=np.float64)
    if labels.ndim != 2 or labels.shape[1] != 12:
        raise ValueError(f"labels must be (N, 12) pose_1..6 and move_1..6, got shape {labels.shape}")
    n = len(labels)
    poses, moves = labels[:, :6], labels[:, 6:]
    targets = pd.DataFrame({IMAGE_COLUMN: [image_name(i) for i in range(n)],
                            REAL_IMAGE_COLUMN: [""] * n if real_images is None else real_images})
    for column, values in zip(POSE_COLUMNS + MOVE_COLUMNS, labels.T):
        targets[column] = values
    for column, values in zip(SHEAR_COLUMNS, replay_shear(poses, moves, config.shear).T):
        targets[column] = values
    meta = {**_meta(config, contact, source=source), **(extra_meta or {})}
    write_paired_set(out_dir, contact, poses, targets, meta, config)
    return n


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
