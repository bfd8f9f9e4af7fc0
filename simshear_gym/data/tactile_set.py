"""Read and write tactile-data sets: ``images/`` + ``targets.csv`` + optional ``meta.json``.

The format is the one of the published TacTip sets (``../shared/data/tactip331``); label conventions live in
:mod:`simshear_gym.data.labels`. Decoded images are cached as one ``.npy`` per set (keyed by the set's path,
its file sizes and modification times), so loading 7000 images again takes milliseconds.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from simshear_gym.data.labels import (
    IMAGE_COLUMN,
    MOVE_COLUMNS,
    POSE_COLUMNS,
    SHEAR_COLUMNS,
    shear_to_sensor_frame,
)
from simshear_gym.data.paths import cache_dir
from simshear_gym.io import atomic_write


class TactileDataError(ValueError):
    """A tactile-data set is malformed; the message names the file, row or column and what was expected."""


LABEL_COLUMNS: tuple[str, ...] = POSE_COLUMNS + MOVE_COLUMNS + SHEAR_COLUMNS
"""Label columns that, wherever a set has them, must hold finite numbers (checked when the set is read)."""


@dataclass(frozen=True, eq=False)
class TactileSet:
    """One set directory. ``targets`` has one row per image; ``meta`` is ``meta.json`` (empty if absent)."""

    root: Path
    targets: pd.DataFrame
    meta: dict = field(default_factory=dict)

    @property
    def images_dir(self) -> Path:
        return self.root / "images"

    def __len__(self) -> int:
        return len(self.targets)

    def image_paths(self) -> list[Path]:
        return [self.images_dir / name for name in self.targets[IMAGE_COLUMN]]

    def poses(self) -> np.ndarray:
        """(N, 6) float64 poses x, y, z [mm], Rx, Ry, Rz [deg] in the work frame."""
        return self.targets[list(POSE_COLUMNS)].to_numpy(np.float64)

    def moves(self) -> np.ndarray:
        """(N, 6) float64 moves in the work frame (zeros for a set without ``move_*`` columns)."""
        if not set(MOVE_COLUMNS) <= set(self.targets.columns):
            return np.zeros((len(self), 6))
        return self.targets[list(MOVE_COLUMNS)].to_numpy(np.float64)

    def shear_sensor(self) -> np.ndarray:
        """(N, 6) float64 shear vectors in the sensor frame (see :mod:`simshear_gym.data.labels`)."""
        return shear_to_sensor_frame(self.moves(), self.poses()[:, 5])

    def load_images(self, use_cache: bool = True) -> np.ndarray:
        """All images as uint8 (N, H, W), in ``targets`` order. Every image must have the same size."""
        key = self.cache_key() if use_cache else None
        cache_file = cache_dir() / f"images-{key}.npy" if key else None
        if cache_file is not None and cache_file.exists():
            images = np.load(cache_file)
            if images.shape[0] == len(self):
                return images
        images = _decode_images(self.image_paths())
        if cache_file is not None:
            atomic_write(cache_file, lambda path: np.save(path, images), suffix=".npy")
        return images

    def cache_key(self) -> str:
        """A key that changes when the set's files do (the decoded-image cache's file name)."""
        targets_file = self.root / "targets.csv"
        stat = targets_file.stat()
        images_stat = self.images_dir.stat()
        text = f"{self.root.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{images_stat.st_mtime_ns}|{len(self)}"
        return hashlib.sha1(text.encode()).hexdigest()[:16]


def _decode_images(paths: list[Path]) -> np.ndarray:
    images: np.ndarray | None = None
    for index, path in enumerate(paths):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise TactileDataError(f"{path}: cannot be read as an image (missing or corrupt file)")
        if images is None:
            images = np.empty((len(paths),) + image.shape, dtype=np.uint8)
        elif image.shape != images.shape[1:]:
            raise TactileDataError(
                f"{path}: image size {image.shape[1]}x{image.shape[0]} px, expected "
                f"{images.shape[2]}x{images.shape[1]} px like {paths[0].name}"
            )
        images[index] = image
    if images is None:
        return np.empty((0, 0, 0), dtype=np.uint8)
    return images


def read_set(
    directory: str | os.PathLike,
    required_columns: tuple[str, ...] = POSE_COLUMNS,
    image_size_px: int | None = None,
) -> TactileSet:
    """Read a set directory and check it.

    Args:
        directory: holds ``targets.csv``, ``images/`` and optionally ``meta.json``.
        required_columns: label columns that must exist and be numeric (besides ``sensor_image``). Every other
            label column the set has (:data:`LABEL_COLUMNS`) must hold finite numbers too: NaN / inf labels are
            refused here, not found as NaN metrics later.
        image_size_px: if given, the first image must be this many pixels square (all are checked on load).

    Raises:
        TactileDataError: naming the file, row (1-based data row of targets.csv) or column that is wrong.
    """
    root = Path(directory)
    targets_file = root / "targets.csv"
    if not targets_file.is_file():
        raise TactileDataError(f"{targets_file}: missing; a set directory needs targets.csv and images/")
    try:
        targets = pd.read_csv(targets_file)
    except pd.errors.EmptyDataError:
        raise TactileDataError(f"{targets_file}: empty; expected a header with {IMAGE_COLUMN!r} and the label "
                               "columns, then one row per image") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as error:
        reason = " ".join(str(error).split())
        raise TactileDataError(f"{targets_file}: not a readable CSV ({reason})") from None
    for column in (IMAGE_COLUMN,) + tuple(required_columns):
        if column not in targets.columns:
            raise TactileDataError(
                f"{targets_file}: column {column!r} is missing; found columns {list(targets.columns)}"
            )
    if targets.empty:
        raise TactileDataError(f"{targets_file}: no data rows (only the header); expected one row per image")
    for column in dict.fromkeys(tuple(required_columns) + tuple(c for c in LABEL_COLUMNS if c in targets.columns)):
        numeric = pd.to_numeric(targets[column], errors="coerce")
        bad = numeric.isna() | ~np.isfinite(numeric.to_numpy(np.float64, na_value=np.nan))
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise TactileDataError(
                f"{targets_file}: row {row + 1}, column {column!r}: value {targets[column].iloc[row]!r} "
                "is not a finite number"
            )
        targets[column] = numeric.astype(np.float64)
    names = targets[IMAGE_COLUMN]
    empty = names.isna() | (names.astype(str).str.strip() == "")
    if empty.any():
        row = int(np.flatnonzero(empty.to_numpy())[0])
        raise TactileDataError(f"{targets_file}: row {row + 1}, column {IMAGE_COLUMN!r}: empty; expected an image "
                               "file name in images/")
    targets[IMAGE_COLUMN] = names.astype(str)
    images_dir = root / "images"
    if not images_dir.is_dir():
        raise TactileDataError(f"{images_dir}: missing; expected the images named in {targets_file.name}")
    present = set(os.listdir(images_dir))
    for row, name in enumerate(targets[IMAGE_COLUMN]):
        if name not in present:
            raise TactileDataError(f"{images_dir / str(name)}: missing (row {row + 1} of {targets_file.name})")
    if image_size_px is not None and len(targets):
        first = images_dir / targets[IMAGE_COLUMN].iloc[0]
        image = cv2.imread(str(first), cv2.IMREAD_GRAYSCALE)
        if image is None or image.shape != (image_size_px, image_size_px):
            got = "unreadable" if image is None else f"{image.shape[1]}x{image.shape[0]} px"
            raise TactileDataError(f"{first}: image is {got}, expected {image_size_px}x{image_size_px} px")
    meta_file = root / "meta.json"
    meta = {}
    if meta_file.is_file():
        try:
            meta = json.loads(meta_file.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise TactileDataError(f"{meta_file}: not valid JSON ({error})") from None
        if not isinstance(meta, dict):
            raise TactileDataError(f"{meta_file}: expected a JSON object (keys such as 'contact'), got "
                                   f"{type(meta).__name__}")
    return TactileSet(root=root, targets=targets, meta=meta)


def image_name(index: int) -> str:
    """File name of the ``index``-th (0-based) image of a set we write: ``image_1.png``, ``image_2.png``, ..."""
    return f"image_{index + 1}.png"


def write_image(images_dir: Path, name: str, image: np.ndarray) -> None:
    if image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError(f"{name}: expected a uint8 (H, W) image, got {image.dtype} {image.shape}")
    if not cv2.imwrite(str(images_dir / name), image):
        raise OSError(f"{images_dir / name}: could not be written")


def write_targets(directory: Path, targets: pd.DataFrame, meta: dict) -> None:
    """Write ``targets.csv`` and ``meta.json`` atomically (images are written before, by :func:`write_image`)."""
    atomic_write(directory / "meta.json", lambda path: Path(path).write_text(json.dumps(meta, indent=2, default=str)))
    atomic_write(directory / "targets.csv", lambda path: targets.to_csv(path, index=False))
