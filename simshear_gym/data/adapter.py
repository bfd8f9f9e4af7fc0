"""Bring a lab's own tactile data set into the package's format: which files, which columns, which units and
signs, which frame, which splits, and how its images become the canonical square grey image.

A :class:`DatasetConfig` (one per task, from the experiment config's ``[datasets.<name>]`` table) names CSV files
and image folders, maps the lab's label columns onto the twelve variables (:data:`VARIABLES`: the sensor pose
``pose_x .. pose_rz`` and the shear move ``move_x .. move_rz``) with units and scale (a sign, or a factor), declares
the variables the lab did not record as absent (a tap-only set has no shear: its moves are zero), and says how the
rows split into train and val: per file, by a column, or as a seeded fraction. A :class:`FrameConfig` maps the lab's
work frame onto the simulation's (axis permutation and signs, where the work origin lies, the sensor's mount angle
about its axis).

:func:`adapt_dataset` reads and validates everything (every image present and decodable, one image size, finite
labels, no declared variable constant, no empty split) and raises :class:`~simshear_gym.data.tactile_set.
TactileDataError` naming the file, column, row or value on the first problem; :func:`write_canonical` writes each
split as a tactile set (``images/image_N.png`` at the canonical size, ``targets.csv`` with ``sensor_image``,
``pose_1..6``, ``move_1..6``, ``meta.json``), which every later step (replay, training, evaluation) reads.

The simulation's frame (see :mod:`simshear_gym.data.labels`): x, y in the stimulus plane, z into the stimulus
(a pose's z is the indentation), angles in degrees (extrinsic x-y-z), moves in the same frame as the pose.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import pandas as pd

from simshear_gym.data.labels import IMAGE_COLUMN, MOVE_COLUMNS, POSE_COLUMNS, label_limit
from simshear_gym.data.tactile_set import (
    TactileDataError,
    check_header,
    decode_image,
    image_name,
    write_image,
    write_targets,
)

VARIABLES: tuple[str, ...] = (
    "pose_x", "pose_y", "pose_z", "pose_rx", "pose_ry", "pose_rz",
    "move_x", "move_y", "move_z", "move_rx", "move_ry", "move_rz",
)
CANONICAL_COLUMNS: dict[str, str] = dict(zip(VARIABLES, POSE_COLUMNS + MOVE_COLUMNS))
LENGTH_UNITS: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3}  # -> mm
ANGLE_UNITS: dict[str, float] = {"deg": 1.0, "rad": 180.0 / math.pi}  # -> deg
SPLITS: tuple[str, ...] = ("train", "val")
CONTACTS: tuple[str, ...] = ("surface", "edge")  # the stimuli the simulation has
_AXES = {"x": 0, "y": 1, "z": 2}


def is_angle(variable: str) -> bool:
    return variable.rpartition("_")[2].startswith("r")


@dataclass(frozen=True)
class LabelSource:
    """Where one variable comes from: a CSV ``column`` in ``unit`` times ``scale`` (a sign flip is -1), or a
    ``value`` (constant, in mm or deg) for a variable the lab held fixed and did not record."""

    column: str | None = None
    unit: str | None = None
    scale: float = 1.0
    value: float | None = None

    def __post_init__(self) -> None:
        if (self.column is None) == (self.value is None):
            raise ValueError(f"give either column (with unit) or value, got column={self.column!r}, "
                             f"value={self.value!r}")
        if self.column is not None and self.unit is None:
            raise ValueError(f"column {self.column!r} needs a unit: one of {sorted(LENGTH_UNITS | ANGLE_UNITS)}")
        if not (math.isfinite(self.scale) and self.scale != 0.0):
            raise ValueError(f"scale must be finite and non-zero, got {self.scale!r}")
        if self.value is not None and not math.isfinite(self.value):
            raise ValueError(f"value must be finite, got {self.value!r}")


@dataclass(frozen=True)
class ImageAdapter:
    """How a lab's image becomes the canonical one: grey, cropped to ``crop_px`` (x0, y0, x1, y1; x1, y1
    exclusive), resized to ``size_px`` square (area interpolation), blurred, thresholded (``binary`` at
    ``threshold_level``, or ``otsu``), inverted."""

    size_px: int = 128
    crop_px: tuple[int, int, int, int] | None = None
    blur_sigma_px: float = 0.0
    threshold: Literal["none", "binary", "otsu"] = "none"
    threshold_level: int = 128
    invert: bool = False

    def __post_init__(self) -> None:
        if self.size_px not in (64, 128, 256):
            raise ValueError(f"size_px must be 64, 128 or 256, got {self.size_px!r}")
        if self.crop_px is not None:
            x0, y0, x1, y1 = self.crop_px
            if x0 < 0 or y0 < 0 or x1 <= x0 or y1 <= y0:
                raise ValueError(f"crop_px must be (x0, y0, x1, y1) with 0 <= x0 < x1, 0 <= y0 < y1, "
                                 f"got {list(self.crop_px)}")
        if not (math.isfinite(self.blur_sigma_px) and self.blur_sigma_px >= 0):
            raise ValueError(f"blur_sigma_px must be >= 0, got {self.blur_sigma_px!r}")
        if not 0 <= self.threshold_level <= 255:
            raise ValueError(f"threshold_level must be in [0, 255], got {self.threshold_level!r}")

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """uint8 (H, W) grey or (H, W, 3) BGR -> uint8 (size_px, size_px)."""
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self.crop_px is not None:
            x0, y0, x1, y1 = self.crop_px
            if x1 > image.shape[1] or y1 > image.shape[0]:
                raise ValueError(f"crop_px {list(self.crop_px)} exceeds the {image.shape[1]}x{image.shape[0]} px "
                                 "image")
            image = image[y0:y1, x0:x1]
        if image.shape != (self.size_px, self.size_px):
            image = cv2.resize(image, (self.size_px, self.size_px), interpolation=cv2.INTER_AREA)
        if self.blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.blur_sigma_px)
        if self.threshold == "binary":
            image = np.where(image >= self.threshold_level, 255, 0).astype(np.uint8)
        elif self.threshold == "otsu":
            image = cv2.threshold(image, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)[1]
        if self.invert:
            image = 255 - image
        return np.ascontiguousarray(image, dtype=np.uint8)


@dataclass(frozen=True)
class FrameConfig:
    """The lab's work frame -> the simulation's.

    Attributes:
        axes: for each simulation axis x, y, z, the lab axis it is, with a sign: ``("x", "-z", "y")`` says sim x is
            lab x, sim y is lab -z and sim z (into the stimulus) is lab y. Angles and moves follow the same
            permutation; it must be a rotation (a reflection would turn a right-handed frame left-handed).
        origin_mm: where the simulation's work origin lies in the lab frame (lab axes, mm), subtracted from the
            lab's positions first: for a depth recorded as a height with the stimulus touched at height h, the
            depth axis's origin is h.
        angle_origin_deg: lab angles (Rx, Ry, Rz, lab axes) that correspond to the simulation's zero.
        mount_rz_deg: the sensor's rotation about its own axis that the labels do not already include: x/y of
            the pose and of the move turn by this angle about z, and it is added to Rz.
    """

    axes: tuple[str, str, str] = ("x", "y", "z")
    origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angle_origin_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rz_deg: float = 0.0

    def __post_init__(self) -> None:
        self.matrix()  # validates

    def matrix(self) -> np.ndarray:
        """(3, 3) signed permutation: sim vector = matrix @ lab vector."""
        matrix = np.zeros((3, 3))
        for row, axis in enumerate(self.axes):
            name = axis.lstrip("+-")
            if name not in _AXES:
                raise ValueError(f"axes must name lab axes x, y, z with an optional sign (e.g. '-z'), got {axis!r}")
            matrix[row, _AXES[name]] = -1.0 if axis.startswith("-") else 1.0
        if sorted(np.abs(matrix).argmax(axis=1)) != [0, 1, 2]:
            raise ValueError(f"axes must use each of x, y, z once, got {list(self.axes)}")
        if np.linalg.det(matrix) < 0:
            raise ValueError(f"axes {list(self.axes)} describe a reflection, not a rotation: flip one sign")
        return matrix

    def to_sim(self, pose_lab: np.ndarray, move_lab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 6) lab poses and moves (mm, deg) -> simulation-frame poses and moves."""
        matrix = self.matrix()
        pose = np.empty_like(pose_lab)
        move = np.empty_like(move_lab)
        pose[:, :3] = (pose_lab[:, :3] - np.asarray(self.origin_mm)) @ matrix.T
        pose[:, 3:] = (pose_lab[:, 3:] - np.asarray(self.angle_origin_deg)) @ matrix.T
        move[:, :3] = move_lab[:, :3] @ matrix.T
        move[:, 3:] = move_lab[:, 3:] @ matrix.T
        if self.mount_rz_deg:
            c, s = math.cos(math.radians(self.mount_rz_deg)), math.sin(math.radians(self.mount_rz_deg))
            turn = np.array([[c, -s], [s, c]])
            pose[:, :2] = pose[:, :2] @ turn.T
            move[:, :2] = move[:, :2] @ turn.T
            pose[:, 5] += self.mount_rz_deg
        pose[:, 3:] = (pose[:, 3:] + 180.0) % 360.0 - 180.0
        return pose, move


@dataclass(frozen=True)
class DataFile:
    """One CSV of labels and the folder of its images (paths relative to the data root, or absolute); ``split``
    puts all its rows in one split (else the dataset's ``split_column`` or ``val_fraction`` decides)."""

    csv: str
    images: str
    split: Literal["train", "val"] | None = None


@dataclass(frozen=True)
class DatasetConfig:
    """One task of a lab's data set (see the module docstring).

    Attributes:
        contact: the stimulus the simulation replays it with: ``surface`` (a flat face) or ``edge`` (a
            straight edge along sim x at sim y = 0).
        kind: ``tap`` (straight down, no shear) or ``shear`` (touched, then slid in contact).
        files: the CSVs and image folders.
        labels: variable name (:data:`VARIABLES`, in the lab's own frame: ``[frame]`` maps them to the
            simulation's) -> :class:`LabelSource`.
        absent: variables the lab did not record (read as 0); ``"move"`` declares all six moves absent.
        image_column: the CSV column holding each row's image file name; or
        image_pattern: a file name with ``{index}`` (the row's position in its CSV), e.g. ``"frame_{index:05d}.png"``.
        split_column / split_values: a CSV column and the value that marks each split, e.g.
            ``{train = "tr", val = "te"}``; or
        val_fraction / split_seed: a seeded random share of the rows held out for validation.
        image: how each image becomes the canonical one.
    """

    contact: str
    kind: Literal["tap", "shear"]
    files: tuple[DataFile, ...]
    labels: Mapping[str, LabelSource] = field(default_factory=dict)
    absent: tuple[str, ...] = ()
    image_column: str | None = None
    image_pattern: str | None = None
    split_column: str | None = None
    split_values: Mapping[str, str] = field(default_factory=dict)
    val_fraction: float | None = None
    split_seed: int = 0
    image: ImageAdapter = ImageAdapter()

    def __post_init__(self) -> None:
        if self.contact not in CONTACTS:
            raise ValueError(f"contact must be one of {list(CONTACTS)} (the simulated stimuli), got {self.contact!r}")
        if not self.files:
            raise ValueError("files must list at least one {csv, images} entry")
        absent = set(self.absent_variables())
        unknown = sorted((set(self.labels) | set(self.absent) - {"move", "pose"}) - set(VARIABLES))
        if unknown:
            raise ValueError(f"unknown variable {unknown[0]!r} in labels/absent; expected one of {list(VARIABLES)}")
        both = sorted(absent & set(self.labels))
        if both:
            raise ValueError(f"variable {both[0]!r} is both in labels and declared absent")
        undeclared = [name for name in VARIABLES if name not in self.labels and name not in absent]
        if undeclared:
            raise ValueError(f"variable {undeclared[0]!r} is neither mapped in labels nor declared absent "
                             f"(every one of {list(VARIABLES)} must be one or the other)")
        for name, source in self.labels.items():
            if source.unit is None:
                continue
            units = ANGLE_UNITS if is_angle(name) else LENGTH_UNITS
            if source.unit not in units:
                raise ValueError(f"labels.{name}.unit = {source.unit!r}; expected one of {sorted(units)} for "
                                 f"{'an angle' if is_angle(name) else 'a length'}")
        if self.kind == "shear" and all(name in absent for name in VARIABLES[6:]):
            raise ValueError("kind 'shear' needs at least one move variable; declare kind = 'tap' for a set "
                             "without shear")
        if (self.image_column is None) == (self.image_pattern is None):
            raise ValueError("give exactly one of image_column (a CSV column of file names) or image_pattern "
                             "(e.g. 'image_{index}.png')")
        ways = [any(f.split for f in self.files), self.split_column is not None, self.val_fraction is not None]
        if sum(ways) != 1:
            raise ValueError("say how rows split in exactly one way: files[].split, split_column (with "
                             "split_values) or val_fraction")
        if ways[0] and any(f.split is None for f in self.files):
            raise ValueError("with files[].split, every file needs its split ('train' or 'val')")
        if self.split_column is not None and sorted(self.split_values) != list(SPLITS):
            raise ValueError(f"split_values must map both splits {list(SPLITS)} to the column's values, got "
                             f"{dict(self.split_values)}")
        if self.val_fraction is not None and not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction!r}")

    def absent_variables(self) -> tuple[str, ...]:
        names = []
        for entry in self.absent:
            names += [v for v in VARIABLES if v.startswith(entry + "_")] if entry in ("pose", "move") else [entry]
        return tuple(names)

    def present_variables(self) -> tuple[str, ...]:
        """Variables read from a column (not constant, not absent)."""
        return tuple(name for name in VARIABLES if name in self.labels and self.labels[name].column is not None)


@dataclass(frozen=True, eq=False)
class AdaptedSplit:
    """One split of an adapted dataset: image files (absolute) and the canonical labels (sim frame, mm, deg)."""

    image_paths: tuple[Path, ...]
    targets: pd.DataFrame  # pose_1..6, move_1..6
    images: np.ndarray  # uint8 (N, size, size), adapted
    source_size_px: tuple[int, int]  # (width, height) of the lab's images
    lab_values: np.ndarray  # (N, 12) the variables in the lab's frame (mm, deg), before [frame]


@dataclass(frozen=True)
class VariableSummary:
    """A simulation-frame variable's range over a dataset."""

    name: str
    low: float
    high: float
    varies: bool


def config_files(datasets: Iterable[DatasetConfig], config_path: str | Path = "") -> str:
    """What a sensor config's data root holds, in words for an error: the top entries of its datasets' CSVs and
    image folders (relative ones: absolute paths need no root), e.g. ``labels.csv and frames/
    (configs/example_lab.toml's datasets)``, ``tactip331/ (configs/tactip331.toml's datasets)``."""
    paths = [Path(path) for dataset in datasets for data_file in dataset.files
             for path in (data_file.csv, data_file.images)]
    names = list(dict.fromkeys(path.parts[0] + ("" if path.suffix and len(path.parts) == 1 else "/")
                               for path in paths if not path.is_absolute()))
    listed = ", ".join(names[:-1]) + (" and " if len(names) > 1 else "") + names[-1] if names else "its files"
    return listed + (f" ({config_path}'s datasets)" if config_path else "")


def resolve(path: str, root: Path) -> Path:
    candidate = Path(path)
    return candidate if candidate.is_absolute() else root / candidate


def read_labels(config: DatasetConfig, root: Path, where: str = "") -> list[tuple[DataFile, Path, pd.DataFrame]]:
    """Each file with its CSV's path and table, checked for the columns the config names."""
    tables = []
    for data_file in config.files:
        csv_path = resolve(data_file.csv, root)
        if not csv_path.is_file():
            raise TactileDataError(f"{where}{csv_path}: no such CSV file (files[].csv = {data_file.csv!r})")
        check_header(csv_path, where)
        try:
            table = pd.read_csv(csv_path)
        except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as error:
            raise TactileDataError(f"{where}{csv_path}: cannot be read as CSV ({error})") from None
        needed = [s.column for s in config.labels.values() if s.column is not None]
        needed += [c for c in (config.image_column, config.split_column) if c is not None]
        missing = [column for column in needed if column not in table.columns]
        if missing:
            raise TactileDataError(f"{where}{csv_path}: missing column {missing[0]!r}; it has {list(table.columns)}")
        tables.append((data_file, csv_path, table))
    return tables


def canonical_labels(config: DatasetConfig, frame: FrameConfig, table: pd.DataFrame, csv_path: Path
                     ) -> tuple[pd.DataFrame, np.ndarray]:
    """Lab columns -> (``pose_1..6`` and ``move_1..6`` in the simulation's frame, the (N, 12) lab-frame values),
    mm and deg."""
    lab = np.zeros((len(table), 12))
    for index, name in enumerate(VARIABLES):
        source = config.labels.get(name)
        if source is None:
            continue
        if source.value is not None:
            lab[:, index] = source.value
            continue
        values = pd.to_numeric(table[source.column], errors="coerce").to_numpy(np.float64)
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            raise TactileDataError(f"{csv_path}: column {source.column!r} ({name}) row {int(bad[0])} is "
                                   f"{table[source.column].iloc[int(bad[0])]!r}; expected a finite number")
        factor = (ANGLE_UNITS if is_angle(name) else LENGTH_UNITS)[source.unit]
        lab[:, index] = values * factor * source.scale
        limit, unit = label_limit(CANONICAL_COLUMNS[name])
        outside = np.flatnonzero(np.abs(lab[:, index]) > limit)
        if len(outside):
            row = int(outside[0])
            raise TactileDataError(f"{csv_path}: column {source.column!r} ({name}) row {row} is "
                                   f"{table[source.column].iloc[row]!r} ({lab[row, index]:.6g} {unit}); expected "
                                   f"a value within the declared range [-{limit:g}, {limit:g}] {unit}")
    pose, move = frame.to_sim(lab[:, :6], lab[:, 6:])
    return pd.DataFrame(np.hstack([pose, move]), columns=list(POSE_COLUMNS + MOVE_COLUMNS)), lab


def split_rows(config: DatasetConfig, data_file: DataFile, table: pd.DataFrame, csv_path: Path) -> np.ndarray:
    """(N,) split name per row."""
    if data_file.split is not None:
        return np.full(len(table), data_file.split, dtype=object)
    if config.split_column is not None:
        column = table[config.split_column].astype(str).to_numpy()
        out = np.full(len(table), "", dtype=object)
        for split, value in config.split_values.items():
            out[column == str(value)] = split
        unknown = sorted(set(column[out == ""]))
        if unknown:
            raise TactileDataError(f"{csv_path}: column {config.split_column!r} has value {unknown[0]!r}, which "
                                   f"split_values {dict(config.split_values)} does not name")
        return out
    rng = np.random.default_rng(config.split_seed)
    out = np.full(len(table), "train", dtype=object)
    out[rng.permutation(len(table))[:int(round(config.val_fraction * len(table)))]] = "val"
    return out


def image_file_names(config: DatasetConfig, table: pd.DataFrame) -> list[str]:
    if config.image_column is not None:
        return table[config.image_column].astype(str).tolist()
    return [config.image_pattern.format(index=index) for index in range(len(table))]


def adapt_dataset(config: DatasetConfig, frame: FrameConfig, root: Path, name: str = "",
                  max_rows_per_split: int | None = None) -> dict[str, AdaptedSplit]:
    """Read, validate and adapt a dataset: {split: AdaptedSplit} (see the module docstring for the checks).

    ``max_rows_per_split`` keeps the first rows of each split (a quick look, or a smoke run)."""
    where = f"dataset {name!r}: " if name else ""
    parts: dict[str, list[tuple[list[Path], pd.DataFrame, np.ndarray]]] = {split: [] for split in SPLITS}
    for data_file, csv_path, table in read_labels(config, root, where):
        labels, lab = canonical_labels(config, frame, table, csv_path)
        splits = split_rows(config, data_file, table, csv_path)
        images_dir = resolve(data_file.images, root)
        paths = [images_dir / file_name for file_name in image_file_names(config, table)]
        for split in SPLITS:
            rows = np.flatnonzero(splits == split)
            parts[split].append(([paths[i] for i in rows], labels.iloc[rows].reset_index(drop=True), lab[rows]))
    adapted = {}
    for split in SPLITS:
        paths = [path for chunk, _, _ in parts[split] for path in chunk]
        targets = pd.concat([labels for _, labels, _ in parts[split]], ignore_index=True) if parts[split] else None
        lab = np.concatenate([values for _, _, values in parts[split]]) if parts[split] else None
        if not paths:
            raise TactileDataError(f"{where}the {split!r} split is empty: no row of {[f.csv for f in config.files]} "
                                   "falls in it")
        if max_rows_per_split is not None:
            paths, targets = paths[:max_rows_per_split], targets.iloc[:max_rows_per_split].reset_index(drop=True)
            lab = lab[:max_rows_per_split]
        images, size = _read_images(paths, config.image, where)
        adapted[split] = AdaptedSplit(tuple(paths), targets, images, size, lab)
    return adapted


def split_sizes(config: DatasetConfig, root: Path, name: str = "",
                max_rows_per_split: int | None = None) -> dict[str, int]:
    """{split: rows} of a dataset, from its label files alone (no image is read): the sizes of
    :func:`adapt_dataset`'s splits."""
    where = f"dataset {name!r}: " if name else ""
    sizes = dict.fromkeys(SPLITS, 0)
    for data_file, csv_path, table in read_labels(config, root, where):
        splits = split_rows(config, data_file, table, csv_path)
        for split in SPLITS:
            sizes[split] += int(np.count_nonzero(splits == split))
    if max_rows_per_split is not None:
        sizes = {split: min(rows, max_rows_per_split) for split, rows in sizes.items()}
    return sizes


def _read_images(paths: list[Path], adapter: ImageAdapter, where: str) -> tuple[np.ndarray, tuple[int, int]]:
    out = np.empty((len(paths), adapter.size_px, adapter.size_px), dtype=np.uint8)
    first_shape = None
    for index, path in enumerate(paths):
        image = decode_image(path, cv2.IMREAD_UNCHANGED, where, unreadable="not a readable image")
        if image.ndim == 3 and image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        if image.dtype != np.uint8:
            raise TactileDataError(f"{where}{path}: {image.dtype} pixels; expected 8-bit images")
        if first_shape is None:
            first_shape = image.shape[:2]
        elif image.shape[:2] != first_shape:
            raise TactileDataError(f"{where}{path}: {image.shape[1]}x{image.shape[0]} px, but {paths[0]} is "
                                   f"{first_shape[1]}x{first_shape[0]} px: every image of a dataset must have one size")
        try:
            out[index] = adapter(image)
        except ValueError as error:
            raise TactileDataError(f"{where}{path}: {error}") from None
    return out, (int(first_shape[1]), int(first_shape[0]))


def summarise_variables(config: DatasetConfig, adapted: Mapping[str, AdaptedSplit], name: str = ""
                        ) -> tuple[VariableSummary, ...]:
    """Range of each variable in the simulation's frame over both splits; raises if a variable the lab declared
    present (read from a column, in its own frame) does not vary."""
    lab = np.concatenate([split.lab_values for split in adapted.values()])
    for index, variable in enumerate(VARIABLES):
        source = config.labels.get(variable)
        if source is not None and source.column is not None and np.ptp(lab[:, index]) <= 1e-9:
            where = f"dataset {name!r}: " if name else ""
            raise TactileDataError(
                f"{where}labels.{variable} (column {source.column!r}) is constant ({lab[0, index]:g}) over all rows: "
                "a variable declared present must vary; give it as value = ... or declare it absent")
    targets = pd.concat([split.targets for split in adapted.values()], ignore_index=True)
    summaries = []
    for variable in VARIABLES:
        values = targets[CANONICAL_COLUMNS[variable]].to_numpy()
        low, high = float(values.min()), float(values.max())
        summaries.append(VariableSummary(variable, low, high, high - low > 1e-9))
    return tuple(summaries)


def write_canonical(adapted: AdaptedSplit, out_dir: Path, meta: dict) -> Path:
    """Write one adapted split as a tactile set (``targets.csv`` last, so a set without it is incomplete)."""
    images_dir = Path(out_dir) / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    names = [image_name(i) for i in range(len(adapted.image_paths))]
    for file_name, image in zip(names, adapted.images):
        write_image(images_dir, file_name, image)
    targets = adapted.targets.copy()
    targets.insert(0, IMAGE_COLUMN, names)
    write_targets(Path(out_dir), targets, meta)
    return Path(out_dir)
