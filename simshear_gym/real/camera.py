"""The real TacTip camera: frame sources and the preprocessing that turns a camera frame into a tactile image.

Preprocessing follows the Bristol ``tactile_image_processing`` pipeline that produced the published
``tactip331`` real images: colour -> grey (OpenCV BGR weights) -> crop ``crop_bbox_px`` (source pixels)
-> resize to ``output_size_px`` (INTER_AREA) -> adaptive mean threshold (``threshold_block_px``,
``threshold_c``) -> optional circle mask -> optional invert. The result is a uint8 (H, W) image with values
{0, 255}: pins and bright edges 255, background 0. The shipped ``tactip_preprocess.json`` holds the parameters
calibrated against the published images (``simshear evaluate camera``); it reproduces them pixel for pixel.

Frame sources share one small interface, ``read() -> frame`` and ``close()``, so a simulated camera
(``VirtualCamera``) and the real one (``CameraSource``) are interchangeable. A source whose class sets
``renders_on_read = True`` makes each frame when ``read()`` asks for it, in lockstep with its reader (the rehearsal
rig's simulated TacTip): its frames are as new as the read, and how long a read takes is the computer's speed, not
a camera's delay, so a reader does not age its frames by the wall clock (:func:`renders_on_read`).
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from simshear_gym.data.tactile_set import TactileDataError, decode_image

DEFAULT_CONFIG_PATH = Path(__file__).with_name("tactip_preprocess.json")
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


# --------------------------------------------------------------------------------------------------------------
# Preprocessing
# --------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PreprocessConfig:
    """How a camera frame becomes a binary tactile image.

    Attributes:
        crop_bbox_px: (x0, y0, x1, y1) crop in source-frame pixels, x to the right, y down; x1, y1 exclusive.
        threshold_block_px: side of the adaptive-threshold neighbourhood, in output pixels (odd, >= 3).
        threshold_c: the constant subtracted from the neighbourhood mean (grey levels); a pixel becomes 255
            when it is brighter than ``mean - threshold_c``, so negative values keep only clearly bright pixels.
        output_size_px: (width, height) of the output image.
        mask_centre_px: (x, y) centre of the circle mask in output pixels, or None for no mask.
        mask_radius_px: radius of the circle mask in output pixels; pixels outside are set to 0.
        invert: swap 0 and 255 after thresholding and masking.
    """

    crop_bbox_px: tuple[int, int, int, int]
    threshold_block_px: int
    threshold_c: float
    output_size_px: tuple[int, int] = (128, 128)
    mask_centre_px: tuple[float, float] | None = None
    mask_radius_px: float | None = None
    invert: bool = False

    def __post_init__(self) -> None:
        # JSON gives lists; store tuples so the config stays hashable and immutable.
        object.__setattr__(self, "crop_bbox_px", _int_tuple("crop_bbox_px", self.crop_bbox_px, 4))
        object.__setattr__(self, "output_size_px", _int_tuple("output_size_px", self.output_size_px, 2))
        x0, y0, x1, y1 = self.crop_bbox_px
        if x0 < 0 or y0 < 0 or x1 <= x0 or y1 <= y0:
            raise ValueError(
                f"crop_bbox_px must be (x0, y0, x1, y1) with 0 <= x0 < x1 and 0 <= y0 < y1, got {self.crop_bbox_px}"
            )
        if min(self.output_size_px) < 1:
            raise ValueError(f"output_size_px must be (width, height) > 0, got {self.output_size_px}")
        if (
            isinstance(self.threshold_block_px, bool)
            or not isinstance(self.threshold_block_px, (int, np.integer))
            or self.threshold_block_px < 3
            or self.threshold_block_px % 2 == 0
        ):
            raise ValueError(f"threshold_block_px must be an odd integer >= 3, got {self.threshold_block_px!r}")
        object.__setattr__(self, "threshold_block_px", int(self.threshold_block_px))
        if not np.isfinite(self.threshold_c):
            raise ValueError(f"threshold_c must be finite, got {self.threshold_c!r}")
        object.__setattr__(self, "threshold_c", float(self.threshold_c))
        if (self.mask_centre_px is None) != (self.mask_radius_px is None):
            raise ValueError(
                "mask_centre_px and mask_radius_px must be given together (both or neither), got "
                f"{self.mask_centre_px!r} and {self.mask_radius_px!r}"
            )
        if self.mask_centre_px is not None:
            centre = tuple(float(v) for v in self.mask_centre_px)
            if len(centre) != 2:
                raise ValueError(f"mask_centre_px must be (x, y), got {self.mask_centre_px!r}")
            object.__setattr__(self, "mask_centre_px", centre)
            if not self.mask_radius_px > 0:
                raise ValueError(f"mask_radius_px must be > 0, got {self.mask_radius_px!r}")
            object.__setattr__(self, "mask_radius_px", float(self.mask_radius_px))
        if not isinstance(self.invert, bool):
            raise ValueError(f"invert must be true or false, got {self.invert!r}")

    def to_dict(self) -> dict:
        """A JSON-ready dict of the fields."""
        return {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict, source: str = "config") -> PreprocessConfig:
        """Build from a dict; ``source`` names where it came from in errors. Unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{source}: unknown preprocessing field(s) {unknown}; expected some of {sorted(known)}")
        try:
            return cls(**values)
        except TypeError as error:  # a required field is missing
            raise ValueError(f"{source}: {error}") from None
        except ValueError as error:
            raise ValueError(f"{source}: {error}") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the config as JSON (atomically) and return the path."""
        from simshear_gym.io import write_json

        return write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | os.PathLike) -> PreprocessConfig:
        """Read a config written by :meth:`save`.

        Raises:
            FileNotFoundError: the file does not exist.
            ValueError: the file is not valid JSON or holds invalid fields (the message names the file).
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"preprocessing config {path} does not exist")
        try:
            values = json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise ValueError(f"preprocessing config {path} is not valid JSON: {error}") from None
        if not isinstance(values, dict):
            raise ValueError(f"preprocessing config {path} must hold a JSON object, got {type(values).__name__}")
        return cls.from_dict(values, source=str(path))


def default_config() -> PreprocessConfig:
    """The shipped config calibrated for the 331-pin TacTip's 640x480 camera (``tactip_preprocess.json``)."""
    return PreprocessConfig.load(DEFAULT_CONFIG_PATH)


def preprocess_config(value: str) -> PreprocessConfig | None:
    """A ``--preprocess`` value: ``"none"`` (None: the frames are tactile images), ``"shipped"``
    (:func:`default_config`) or a preprocessing JSON's path."""
    if value == "none":
        return None
    if value == "shipped":
        return default_config()
    return PreprocessConfig.load(value)


def to_gray(frame: np.ndarray) -> np.ndarray:
    """A uint8 (H, W) grey image from a uint8 grey (H, W), (H, W, 1), BGR (H, W, 3) or BGRA (H, W, 4) frame."""
    if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8:
        raise ValueError(
            f"frame must be a uint8 numpy array, got {type(frame).__name__} "
            f"{getattr(frame, 'dtype', '')}".rstrip()
        )
    if frame.ndim == 2:
        return frame
    if frame.ndim == 3 and frame.shape[2] == 1:
        return frame[:, :, 0]
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    raise ValueError(f"frame must be (H, W), (H, W, 1), (H, W, 3) BGR or (H, W, 4) BGRA, got shape {frame.shape}")


def crop_and_resize(gray: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """The grey frame cropped to ``config.crop_bbox_px`` and resized (INTER_AREA) to ``config.output_size_px``.

    Raises:
        ValueError: the crop does not fit inside the frame.
    """
    x0, y0, x1, y1 = config.crop_bbox_px
    height, width = gray.shape[:2]
    if x1 > width or y1 > height:
        raise ValueError(
            f"crop_bbox_px {config.crop_bbox_px} does not fit a {width}x{height} frame (need x1 <= {width}, "
            f"y1 <= {height})"
        )
    return cv2.resize(gray[y0:y1, x0:x1], config.output_size_px, interpolation=cv2.INTER_AREA)


def threshold_and_mask(small_gray: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """Adaptive mean threshold, circle mask and invert of an already cropped and resized grey image."""
    binary = cv2.adaptiveThreshold(
        small_gray, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY, config.threshold_block_px, config.threshold_c
    )
    if config.mask_centre_px is not None:
        binary[~circle_mask(config.output_size_px, config.mask_centre_px, config.mask_radius_px)] = 0
    if config.invert:
        binary = 255 - binary
    return binary


def circle_mask(size_px: tuple[int, int], centre_px: tuple[float, float], radius_px: float) -> np.ndarray:
    """Boolean (height, width) array, True within ``radius_px`` of ``centre_px`` (x, y) at pixel centres."""
    width, height = size_px
    ys, xs = np.mgrid[0:height, 0:width]
    return (xs - centre_px[0]) ** 2 + (ys - centre_px[1]) ** 2 <= radius_px**2


def preprocess(frame: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """A camera frame (uint8 BGR or grey) -> uint8 (height, width) tactile image with values in {0, 255}.

    Same convention as the published ``tactip331`` real images: pins and bright edges 255, background 0.
    """
    return threshold_and_mask(crop_and_resize(to_gray(frame), config), config)


# --------------------------------------------------------------------------------------------------------------
# Frame sources
# --------------------------------------------------------------------------------------------------------------


class CameraError(RuntimeError):
    """A frame source cannot be opened, a read failed, or a live camera stalled."""


class EndOfStream(CameraError):
    """A finite source (video file, image folder) has no more frames."""


@runtime_checkable
class FrameSource(Protocol):
    """Anything that hands out camera frames: the real camera, a recording or a simulated sensor."""

    def read(self) -> np.ndarray:
        """The next frame, uint8 (H, W) grey or (H, W, 3) BGR. Raises CameraError (EndOfStream at the end)."""
        ...

    def close(self) -> None:
        """Release the source; safe to call twice."""
        ...


def renders_on_read(source: object) -> bool:
    """Whether ``source`` makes each frame when read (the module docstring): False for a camera that runs on its
    own clock (``CameraSource``, ``VirtualCamera``) and for any source that does not say."""
    return getattr(type(source), "renders_on_read", False) is True


class SourceBase:
    """Context manager and iteration shared by the frame sources below and the simulated cameras of
    :mod:`simshear_gym.real.hil` (a base class; :class:`FrameSource` is the protocol they meet)."""

    def read(self) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def __iter__(self) -> Iterator[np.ndarray]:
        """Frames until the source ends (a live camera never does)."""
        while True:
            try:
                yield self.read()
            except EndOfStream:
                return


class VirtualCamera(SourceBase):
    """A frame source backed by a callable, e.g. a simulated TacTip's renderer.

    Args:
        render: called with no arguments for every ``read()``; returns a uint8 (H, W) or (H, W, 3) frame,
            or None when it has no more frames (then ``read()`` raises EndOfStream).
        name: shown in errors.
    """

    def __init__(self, render: Callable[[], np.ndarray | None], name: str = "virtual camera") -> None:
        if not callable(render):
            raise ValueError(f"{name}: render must be callable, got {type(render).__name__}")
        self._render = render
        self.name = name
        self._closed = False

    def read(self) -> np.ndarray:
        if self._closed:
            raise CameraError(f"{self.name}: read() after close()")
        frame = self._render()
        if frame is None:
            raise EndOfStream(f"{self.name}: no more frames")
        _check_frame(frame, self.name)
        return frame

    def close(self) -> None:
        self._closed = True


class CameraSource(SourceBase):
    """Frames from an OpenCV camera device, a video file or a folder of images.

    Args:
        source: a device index (int, or a string of digits), a video file path, or an image folder path.
            Folder images (png, jpg, bmp, tif) are read in natural order: image_2 before image_10.
        warmup_frames: frames read and discarded after opening a device (auto-exposure settles); ignored for
            files and folders.
        stall_timeout_s: a device that delivers no new frame within this time raises CameraError.
        exposure: value for ``CAP_PROP_EXPOSURE`` on a device (the TacTip rigs use -7), or None to leave it.
        frame_size_px: (width, height) requested from a device, or None to leave it.

    A device is read by a background thread that keeps only the newest frame, so ``read()`` never returns a
    stale buffered frame and a stalled camera is detected by timeout instead of blocking forever. Files and
    folders are read in order, frame by frame; at their end ``read()`` raises EndOfStream.

    Raises:
        CameraError: the file, folder or device cannot be opened (the message names it).
    """

    def __init__(
        self,
        source: int | str | os.PathLike,
        *,
        warmup_frames: int = 5,
        stall_timeout_s: float = 2.0,
        exposure: float | None = None,
        frame_size_px: tuple[int, int] | None = None,
    ) -> None:
        self._init_state(str(source), stall_timeout_s)
        is_index = isinstance(source, (int, np.integer)) and not isinstance(source, bool)
        if is_index or (isinstance(source, str) and source.isdigit()):
            index = int(source)
            self.name = f"camera device {index}"
            capture = cv2.VideoCapture(index)
            if not capture.isOpened():
                capture.release()
                raise CameraError(f"cannot open {self.name}: no such device, or it is in use")
            if frame_size_px is not None:
                capture.set(cv2.CAP_PROP_FRAME_WIDTH, int(frame_size_px[0]))
                capture.set(cv2.CAP_PROP_FRAME_HEIGHT, int(frame_size_px[1]))
            if exposure is not None:
                capture.set(cv2.CAP_PROP_EXPOSURE, float(exposure))
            self._start_live(capture, warmup_frames)
            return

        path = Path(source)
        if path.is_dir():
            self.name = f"image folder {path}"
            self._files = sorted(
                (p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                key=natural_sort_key,
            )
            if not self._files:
                raise CameraError(f"image folder {path} holds no images (expected {', '.join(IMAGE_SUFFIXES)})")
        elif path.is_file():
            self.name = f"video file {path}"
            self._capture = cv2.VideoCapture(str(path))
            if not self._capture.isOpened():
                self._capture.release()
                raise CameraError(f"cannot open video file {path}: not a video OpenCV can decode")
        else:
            raise CameraError(
                f"camera source {str(source)!r} is neither a device index, an existing video file nor an image "
                f"folder (resolved {path.resolve()})"
            )

    @classmethod
    def from_capture(
        cls, capture, *, name: str = "capture", warmup_frames: int = 0, stall_timeout_s: float = 2.0
    ) -> CameraSource:
        """Wrap an already opened live capture (anything with ``read() -> (ok, frame)`` and ``release()``).

        It is read like a device: a background thread, warm-up frames discarded, stall timeout.
        """
        source = cls.__new__(cls)
        source._init_state(name, stall_timeout_s)
        source._start_live(capture, warmup_frames)
        return source

    @property
    def is_live(self) -> bool:
        """True for a device (or wrapped live capture), False for a file or folder."""
        return self._live is not None

    def read(self) -> np.ndarray:
        """The next frame (uint8, BGR for colour sources).

        Raises:
            CameraError: the source is closed, a read failed, or a live camera stalled for ``stall_timeout_s``.
            EndOfStream: a file or folder has no more frames.
        """
        if self._closed:
            raise CameraError(f"{self.name}: read() after close()")
        if self._live is not None:
            return self._live.next_frame(self.stall_timeout_s)
        if self._files is not None:
            if self._next_file >= len(self._files):
                raise EndOfStream(f"{self.name}: no more images after {len(self._files)}")
            path = self._files[self._next_file]
            self._next_file += 1
            try:  # the size guard of the data sets: a decompression bomb is refused unread
                return decode_image(path, cv2.IMREAD_COLOR, where=f"{self.name}: ", unreadable="cannot decode image")
            except TactileDataError as error:
                raise CameraError(str(error)) from None
        ok, frame = self._capture.read()
        if not ok or frame is None:
            raise EndOfStream(f"{self.name}: no more frames")
        return frame

    def close(self) -> None:
        """Stop the reader thread and release the device or file; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._live is not None:
            self._live.stop()
        if self._capture is not None:
            self._capture.release()

    def _init_state(self, name: str, stall_timeout_s: float) -> None:
        if not stall_timeout_s > 0:
            raise ValueError(f"stall_timeout_s must be > 0, got {stall_timeout_s}")
        self.name = name
        self.stall_timeout_s = float(stall_timeout_s)
        self._closed = False
        self._files: list[Path] | None = None
        self._next_file = 0
        self._capture = None
        self._live: _LiveReader | None = None

    def _start_live(self, capture, warmup_frames: int) -> None:
        if warmup_frames < 0:
            capture.release()
            raise ValueError(f"warmup_frames must be >= 0, got {warmup_frames}")
        self._live = _LiveReader(capture, self.name)
        try:
            for _ in range(warmup_frames):
                self._live.next_frame(self.stall_timeout_s)
        except CameraError:
            self._live.stop()
            self._closed = True
            raise


class _LiveReader:
    """A thread that reads a live capture continuously and keeps the newest frame."""

    def __init__(self, capture, name: str) -> None:
        self._capture = capture
        self._name = name
        self._condition = threading.Condition()
        self._frame: np.ndarray | None = None
        self._frame_id = 0
        self._returned_id = 0
        self._error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"CameraSource({name})", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ok, frame = self._capture.read()
            except Exception as error:  # a driver error must reach the caller, not die with the thread
                ok, frame = False, None
                message = f"{self._name}: read failed: {error}"
            else:
                message = f"{self._name}: read failed (device unplugged or stopped?)"
            with self._condition:
                if not ok or frame is None:
                    self._error = message
                    self._condition.notify_all()
                    return
                self._frame = frame
                self._frame_id += 1
                self._condition.notify_all()

    def next_frame(self, timeout_s: float) -> np.ndarray:
        """The newest frame not yet returned, waiting up to ``timeout_s`` for one."""
        deadline = time.monotonic() + timeout_s
        with self._condition:
            while self._frame_id == self._returned_id:
                if self._error is not None:
                    raise CameraError(self._error)
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise CameraError(f"{self._name}: stalled, no new frame within {timeout_s:g} s")
                self._condition.wait(remaining)
            self._returned_id = self._frame_id
            return self._frame

    def stop(self) -> None:
        self._stop.set()
        # Release after the thread has left read() where possible; a driver blocked in read() (a stalled camera)
        # cannot be interrupted, and releasing the capture is then the only way to unblock it.
        self._thread.join(timeout=1.0)
        self._capture.release()


def natural_sort_key(path: str | os.PathLike) -> tuple:
    """Sort key that orders numbered names numerically: image_2 before image_10."""
    name = Path(path).name
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in re.split(r"(\d+)", name))


def _check_frame(frame: object, name: str) -> None:
    if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.ndim not in (2, 3):
        raise CameraError(
            f"{name}: a frame must be a uint8 (H, W) or (H, W, C) numpy array, got "
            f"{type(frame).__name__} {getattr(frame, 'dtype', '')} {getattr(frame, 'shape', '')}"
        )


def _int_tuple(field: str, value: object, length: int) -> tuple[int, ...]:
    try:
        items = tuple(value)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{field} must be a sequence of {length} integers, got {value!r}") from None
    if len(items) != length or not all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in items
    ):
        raise ValueError(f"{field} must be {length} integers, got {value!r}")
    return tuple(int(v) for v in items)
