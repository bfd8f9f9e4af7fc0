"""Atomic file and folder writes: a crash never leaves a half-written checkpoint, set, result or model folder behind;
a full disk is one clear error naming the file and the free space; weights files carry a sha256 beside them, checked
when read."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

CHECKSUM_SUFFIX = ".sha256"
"""A weights file ``x.pt`` carries its sha256 in ``x.pt.sha256`` (``sha256sum`` format: ``<hex>  x.pt``)."""


class DiskFullError(OSError):
    """A write failed because the disk (or the user's quota) is full; the message names the file and the space."""


class ChecksumError(ValueError):
    """A file whose sha256 differs from the one recorded beside it (corrupt, truncated or replaced)."""


LOW_SPACE_BYTES = 1 << 20
"""Below this much free space, a writer's failure to write (torch's says only "file write failed") is a full disk."""


def _disk_full(error: BaseException, directory: Path) -> bool:
    """Whether ``error`` (from a writer: OSError, or the RuntimeError torch's writer raises) is a full disk."""
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(error)
    if "No space left on device" in text or "Disk quota exceeded" in text:
        return True
    if "write failed" in text or "failed writing" in text:
        try:
            return shutil.disk_usage(directory).free < LOW_SPACE_BYTES
        except OSError:
            return False
    return False


def _free_space(directory: Path) -> str:
    try:
        free = shutil.disk_usage(directory).free
    except OSError:
        return "unknown free space"
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if free >= scale:
            return f"{free / scale:.1f} {unit} free"
    return f"{free} bytes free"


def disk_full(target: Path, more: str = "") -> DiskFullError:
    """The error of a write to ``target`` that the full disk stopped: it names the file and the free space."""
    error = DiskFullError(f"{target}: cannot be written: the disk is full ({_free_space(target.parent)} in "
                          f"{target.parent}){more}")
    error.errno = errno.ENOSPC
    return error


def atomic_write(path: str | os.PathLike, write: Callable[[str], object], suffix: str = "") -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over ``path``.

    ``suffix`` keeps an extension that the writer insists on (``np.save`` appends ``.npy`` otherwise).

    Raises:
        DiskFullError: the disk filled up (the previous ``path``, if any, is left whole).
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{suffix}", dir=target.parent)
    except OSError as error:
        if _disk_full(error, target.parent):
            raise disk_full(target) from None
        raise
    os.close(handle)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results and checkpoints are ordinary files
        os.replace(tmp, target)
    except BaseException as error:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(error, Exception) and not isinstance(error, DiskFullError) and _disk_full(error, target.parent):
            raise disk_full(target, "; the previous file, if any, is left as it was") from None
        raise
    return target


def atomic_folder(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp_folder)`` on a temporary folder beside ``path``, then put it in place of ``path`` (a folder
    there before is replaced whole): a reader sees the old folder or the new one, never a half-written one.

    Raises:
        DiskFullError: the disk filled up (the previous folder, if any, is left whole).
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    except OSError as error:
        if _disk_full(error, target.parent):
            raise disk_full(target) from None
        raise
    try:
        write(tmp)
        os.chmod(tmp, 0o755)  # mkdtemp creates 0700 (and some writers 0600 files): a model folder is an ordinary one
        for item in tmp.rglob("*"):
            os.chmod(item, 0o755 if item.is_dir() else 0o644)
        if target.is_dir() and not target.is_symlink():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old / target.name)
            try:
                os.replace(tmp, target)
            except BaseException:
                os.replace(old / target.name, target)  # the previous folder back in place
                raise
            finally:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException as error:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(error, Exception) and not isinstance(error, DiskFullError) and _disk_full(error, target.parent):
            raise disk_full(target, "; the previous folder, if any, is left as it was") from None
        raise
    return target


def file_sha256(path: str | os.PathLike) -> str:
    """The sha256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checksum_path(path: str | os.PathLike) -> Path:
    """Where a file's sha256 lies: ``<file>.sha256``."""
    return Path(path).with_name(Path(path).name + CHECKSUM_SUFFIX)


def write_checksum(path: str | os.PathLike) -> Path:
    """Record a file's sha256 beside it (:func:`checksum_path`), atomically."""
    path = Path(path)
    line = f"{file_sha256(path)}  {path.name}\n"
    return atomic_write(checksum_path(path), lambda tmp: Path(tmp).write_text(line))


def verify_checksum(path: str | os.PathLike) -> bool:
    """Check a file against the sha256 recorded beside it; returns whether one was recorded (False: nothing to
    check).

    Raises:
        ChecksumError: the file's sha256 differs, naming the file: a flipped bit or a truncated copy is an error
            here, not a model that loads and computes garbage.
    """
    path = Path(path)
    recorded = checksum_path(path)
    if not recorded.is_file():
        return False
    expected = recorded.read_text().split()[0] if recorded.read_text().split() else ""
    actual = file_sha256(path)
    if actual != expected:
        raise ChecksumError(f"{path}: sha256 {actual[:12]}... differs from the {expected[:12] or '(empty)'}... "
                            f"recorded in {recorded.name}: the file is corrupt (a flipped bit, a truncated copy) or "
                            f"was replaced; restore it (or, if you replaced it on purpose, delete {recorded.name})")
    return True


def write_json(path: str | os.PathLike, payload: dict) -> Path:
    """Write ``payload`` as indented JSON, atomically."""
    import json

    return atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(payload, indent=2, default=float) + "\n"))


def recorded_path(path: str | os.PathLike, outside: str = "name") -> str:
    """``path`` as a results file or a card records it: relative to the working directory (the repository root)
    where it lies under it; else (``outside`` "name") as given when relative, else its file name alone, so that no
    absolute path of this machine lands in ``results/`` or a card; or (``outside`` "relpath", as the pipeline sweep
    records its run folder and figure) relative to the working directory, ``..`` and all."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        if outside == "relpath":
            return os.path.relpath(path)
        return Path(path).name if Path(path).is_absolute() else str(path)
