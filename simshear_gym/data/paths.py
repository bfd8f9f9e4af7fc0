"""Where data and caches live. Real data never enters the repository: its root comes from the command line,
else the ``SIMSHEAR_DATA`` environment variable, else ``../shared/data`` (relative to the working directory)."""

from __future__ import annotations

import os
from pathlib import Path

DATA_ENV = "SIMSHEAR_DATA"
CACHE_ENV = "SIMSHEAR_CACHE"
DEFAULT_DATA_ROOT = Path("../shared/data")

# The four published tactip331 tasks: (contact type, kind) -> relative directory.
TACTIP331_TASKS: dict[tuple[str, str], str] = {
    ("surface", "tap"): "surface_3d/tap",
    ("surface", "shear"): "surface_3d/shear",
    ("edge", "tap"): "edge_2d/tap",
    ("edge", "shear"): "edge_2d/shear",
}
SPLITS: tuple[str, ...] = ("csv_train", "csv_val")


def data_root(explicit: str | os.PathLike | None = None, holding: str = "tactip331/") -> Path:
    """The data root: ``explicit`` if given, else ``$SIMSHEAR_DATA``, else ``../shared/data``; ``holding``: what
    the caller expects in it (a sensor config's files: :func:`simshear_gym.data.adapter.config_files`), for the
    error.

    Raises:
        FileNotFoundError: naming the path tried, what it should hold and how to point at it.
    """
    root = Path(explicit) if explicit is not None else Path(os.environ.get(DATA_ENV, DEFAULT_DATA_ROOT))
    if not root.is_dir():
        raise FileNotFoundError(
            f"data root {root} (resolved {root.resolve()}) does not exist; pass --data or set {DATA_ENV} "
            f"to the folder holding {holding}"
        )
    return root


def real_set_dir(root: Path, contact: str, kind: str, split: str) -> Path:
    """``tactip331/real/<task>/<split>`` under ``root``."""
    return root / "tactip331" / "real" / _task(contact, kind) / _split(split)


def published_sim_set_dir(root: Path, contact: str, kind: str, split: str, size_px: int = 128) -> Path:
    """``tactip331/sim/<task>/<size>x<size>/<split>``: the published Tactile Gym renders of the same rows."""
    return root / "tactip331" / "sim" / _task(contact, kind) / f"{size_px}x{size_px}" / _split(split)


def cache_dir() -> Path:
    """Cache of decoded arrays: ``$SIMSHEAR_CACHE``, else ``~/.cache/simshear-gym``."""
    path = Path(os.environ.get(CACHE_ENV, Path.home() / ".cache" / "simshear-gym"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def _task(contact: str, kind: str) -> str:
    try:
        return TACTIP331_TASKS[(contact, kind)]
    except KeyError:
        raise ValueError(
            f"unknown task ({contact!r}, {kind!r}); expected one of {sorted(TACTIP331_TASKS)}"
        ) from None


def _split(split: str) -> str:
    name = split if split.startswith("csv_") else f"csv_{split}"
    if name not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected 'train' or 'val'")
    return name


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
