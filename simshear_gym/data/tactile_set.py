"""Read and write tactile-data sets: ``images/`` + ``targets.csv`` + optional ``meta.json``.

The format is the one of the published TacTip sets (``../shared/data/tactip331``); label conventions live in
:mod:`simshear_gym.data.labels`. Decoded images are cached as one ``.npy`` per set, keyed on the files themselves
(the set's path, ``targets.csv`` and every image's path, size and modification time in ns), so loading 7000 images
again takes milliseconds and an image overwritten in place is decoded afresh, never served stale.

Every malformed input is one :class:`TactileDataError` naming the file, row or column and what was expected: a
``targets.csv`` with a column twice in its header, a label that is not a finite number or lies outside the format's
declared range (:func:`~simshear_gym.data.labels.label_limit`), an image that cannot be decoded or whose header
claims more than :data:`MAX_IMAGE_PIXELS` (a decompression bomb), a missing image.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import struct
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
    label_limit,
    shear_to_sensor_frame,
)
from simshear_gym.data.paths import cache_dir
from simshear_gym.io import atomic_write

MAX_IMAGE_PIXELS = 4096 * 4096
"""The most pixels an image may claim in its header before it is decoded: tactile and camera frames are well under
it (640 x 480); a file claiming more is refused as a decompression bomb (a few KB that decode to GBs)."""


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
            try:
                images = np.load(cache_file)
            except (OSError, ValueError, EOFError):  # a torn or foreign cache file: decode again, rewrite it
                images = np.empty((0,), np.uint8)
            if images.ndim == 3 and images.shape[0] == len(self):
                return images
        images = _decode_images(self.image_paths())
        if cache_file is not None:
            atomic_write(cache_file, lambda path: np.save(path, images), suffix=".npy")
        return images

    def cache_key(self) -> str:
        """A key that changes when any of the set's files does (the decoded-image cache's file name): the set's
        path, ``targets.csv``'s and every image's size and modification time (ns), so an image overwritten in place
        (same name, same folder) gets a new key."""
        digest = hashlib.sha1(f"{self.root.resolve()}|{len(self)}".encode())
        for path in [self.root / "targets.csv", *self.image_paths()]:
            try:
                stat = path.stat()
            except OSError:
                raise TactileDataError(f"{path}: missing (listed in {self.root / 'targets.csv'})") from None
            digest.update(f"|{path.name}|{stat.st_size}|{stat.st_mtime_ns}".encode())
        return digest.hexdigest()[:16]


def _png_size(data: np.ndarray) -> tuple[int, int] | None:
    """(width, height) from a PNG's header, or None for another format."""
    if len(data) >= 24 and bytes(data[:8]) == b"\x89PNG\r\n\x1a\n" and bytes(data[12:16]) == b"IHDR":
        return struct.unpack(">II", bytes(data[16:24]))
    return None


def decode_image(path: Path, flags: int = cv2.IMREAD_GRAYSCALE, where: str = "",
                 unreadable: str = "cannot be read as an image") -> np.ndarray:
    """One image file decoded (``cv2.imdecode`` with ``flags``), checked before decoding: a header that claims more
    than :data:`MAX_IMAGE_PIXELS` is refused unread. ``unreadable``: what the error says of a file that does not
    decode.

    Raises:
        TactileDataError: ``where`` + the file, and what is wrong (missing, a decompression bomb, not decodable).
    """
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        state = "missing" if not Path(path).exists() else f"cannot be read ({error.strerror})"
        raise TactileDataError(f"{where}{path}: {state}") from None
    size = _png_size(data)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise TactileDataError(f"{where}{path}: its header claims {size[0]}x{size[1]} px, more than the "
                               f"{MAX_IMAGE_PIXELS} px an image may have here (a decompression bomb?); expected a "
                               "tactile or camera frame")
    try:
        image = cv2.imdecode(data, flags) if len(data) else None
    except cv2.error as error:
        reason = " ".join(str(error).split())[-160:]
        raise TactileDataError(f"{where}{path}: {unreadable} ({reason})") from None
    if image is None:
        raise TactileDataError(f"{where}{path}: {unreadable} (missing or corrupt file)")
    if image.size > MAX_IMAGE_PIXELS * (image.shape[2] if image.ndim == 3 else 1):
        raise TactileDataError(f"{where}{path}: {image.shape[1]}x{image.shape[0]} px, more than the "
                               f"{MAX_IMAGE_PIXELS} px an image may have here")
    return image


def _decode_images(paths: list[Path]) -> np.ndarray:
    images: np.ndarray | None = None
    for index, path in enumerate(paths):
        image = decode_image(path)
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
    check_header(targets_file)
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
        limit, unit = label_limit(column)
        outside = np.abs(numeric.to_numpy(np.float64)) > limit
        if outside.any():
            row = int(np.flatnonzero(outside)[0])
            raise TactileDataError(
                f"{targets_file}: row {row + 1}, column {column!r}: value {float(numeric.iloc[row]):g} lies "
                f"outside the declared range [-{limit:g}, {limit:g}] {unit} of the data format"
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
        image = decode_image(first)
        if image.shape != (image_size_px, image_size_px):
            raise TactileDataError(f"{first}: image is {image.shape[1]}x{image.shape[0]} px, expected "
                                   f"{image_size_px}x{image_size_px} px")
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


def check_header(csv_path: Path, where: str = "") -> list[str]:
    """A CSV file's header, refused when a column appears twice (pandas would rename the second ``x.1`` and read
    the first: silently the wrong column); returns the column names.

    Raises:
        TactileDataError: naming the file and the repeated column.
    """
    try:
        with open(csv_path, newline="", encoding="utf-8") as handle:
            header = next(csv.reader(handle), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return []  # unreadable: the CSV reader's own error names it
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise TactileDataError(f"{where}{csv_path}: column {name!r} appears twice in the header; expected each "
                                   "column once")
        seen.add(name)
    return header


def image_name(index: int) -> str:
    """File name of the ``index``-th (0-based) image of a set we write: ``image_1.png``, ``image_2.png``, ..."""
    return f"image_{index + 1}.png"


def write_image(images_dir: Path, name: str, image: np.ndarray) -> None:
    if image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError(f"{name}: expected a uint8 (H, W) image, got {image.dtype} {image.shape}")
    if not cv2.imwrite(str(images_dir / name), image):
        import shutil

        free = shutil.disk_usage(images_dir).free if images_dir.is_dir() else 0
        raise OSError(f"{images_dir / name}: could not be written ({free / 2**20:.1f} MiB free in {images_dir})")


def write_targets(directory: Path, targets: pd.DataFrame, meta: dict) -> None:
    """Write ``targets.csv`` and ``meta.json`` atomically (images are written before, by :func:`write_image`)."""
    atomic_write(directory / "meta.json", lambda path: Path(path).write_text(json.dumps(meta, indent=2, default=str)))
    atomic_write(directory / "targets.csv", lambda path: targets.to_csv(path, index=False))
