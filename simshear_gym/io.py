"""Atomic file writes: a crash never leaves a half-written checkpoint, set or result behind."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: str | os.PathLike, write: Callable[[str], object], suffix: str = "") -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over ``path``.

    ``suffix`` keeps an extension that the writer insists on (``np.save`` appends ``.npy`` otherwise).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{suffix}", dir=target.parent)
    os.close(handle)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results and checkpoints are ordinary files
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return target


def write_json(path: str | os.PathLike, payload: dict) -> Path:
    """Write ``payload`` as indented JSON, atomically."""
    import json

    return atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(payload, indent=2, default=float) + "\n"))


def recorded_path(path: str | os.PathLike) -> str:
    """``path`` as a results file or a card records it: relative to the working directory (the repository root)
    where it lies under it; else as given when relative, else its file name alone, so that no absolute path of
    this machine lands in ``results/`` or a card."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return Path(path).name if Path(path).is_absolute() else str(path)
