"""Real TacTip camera: preprocessing config, frame sources, and the shipped config against the published images."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from simshear_gym.real.camera import (
    CameraError,
    CameraSource,
    EndOfStream,
    FrameSource,
    PreprocessConfig,
    VirtualCamera,
    default_config,
    natural_sort_key,
    preprocess,
)

VALID = dict(crop_bbox_px=(80, 25, 530, 475), threshold_block_px=11, threshold_c=-30.0)


def _frame(seed: int, size_px: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A BGR frame of bright dots on a dark disc, like a TacTip camera frame."""
    rng = np.random.default_rng(seed)
    width, height = size_px
    frame = np.full((height, width, 3), 200, np.uint8)
    cv2.circle(frame, (width // 2, height // 2), min(width, height) // 2 - 10, (20, 20, 20), -1)
    for x, y in rng.integers((80, 40), (width - 80, height - 40), size=(150, 2)):
        cv2.circle(frame, (int(x), int(y)), 6, (230, 220, 200), -1)
    return frame


# ---------------------------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(crop_bbox_px=(100, 0, 50, 440)), "crop_bbox_px"),
        (dict(crop_bbox_px=(-1, 0, 50, 440)), "crop_bbox_px"),
        (dict(crop_bbox_px=(0, 0, 50)), "crop_bbox_px"),
        (dict(crop_bbox_px=(0.5, 0, 50, 40)), "crop_bbox_px"),
        (dict(threshold_block_px=10), "threshold_block_px"),
        (dict(threshold_block_px=1), "threshold_block_px"),
        (dict(threshold_c=float("nan")), "threshold_c"),
        (dict(output_size_px=(0, 128)), "output_size_px"),
        (dict(mask_centre_px=(64, 64)), "mask_radius_px"),
        (dict(mask_centre_px=(64, 64), mask_radius_px=0), "mask_radius_px"),
        (dict(invert="yes"), "invert"),
    ],
)
def test_config_validation_names_the_field(change: dict, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        PreprocessConfig(**{**VALID, **change})


def test_config_json_round_trip(tmp_path: Path) -> None:
    config = PreprocessConfig(**VALID, mask_centre_px=(63.5, 63.5), mask_radius_px=60, invert=True)
    path = config.save(tmp_path / "pre.json")
    assert PreprocessConfig.load(path) == config
    assert json.loads(path.read_text())["crop_bbox_px"] == [80, 25, 530, 475]


def test_config_load_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.json"):
        PreprocessConfig.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**VALID, "crop_bbox_px": [0, 0, 10, 10], "threshold": 3}))
    with pytest.raises(ValueError, match=r"bad\.json.*threshold"):
        PreprocessConfig.load(bad)


def test_shipped_config_loads() -> None:
    config = default_config()
    assert config.output_size_px == (128, 128)


# ---------------------------------------------------------------------------------------------- preprocess


@pytest.mark.parametrize("as_gray", [False, True])
def test_preprocess_output_is_binary_uint8(as_gray: bool) -> None:
    frame = _frame(0)
    if as_gray:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    image = preprocess(frame, PreprocessConfig(**VALID))
    assert image.shape == (128, 128) and image.dtype == np.uint8
    assert set(np.unique(image)) <= {0, 255} and image.max() == 255


def test_preprocess_mask_invert_and_size() -> None:
    config = PreprocessConfig(**{**VALID, "output_size_px": (96, 64)}, mask_centre_px=(47.5, 31.5),
                              mask_radius_px=20)
    image = preprocess(_frame(1), config)
    assert image.shape == (64, 96)
    assert image[0, 0] == 0 and image[-1, -1] == 0
    inverted = preprocess(_frame(1), PreprocessConfig(**{**config.to_dict(), "invert": True}))
    np.testing.assert_array_equal(inverted, 255 - image)


def test_preprocess_rejects_a_crop_outside_the_frame() -> None:
    with pytest.raises(ValueError, match="does not fit a 320x240 frame"):
        preprocess(_frame(0, (320, 240)), PreprocessConfig(**VALID))


# ---------------------------------------------------------------------------------------------- sources


def test_natural_sort_key() -> None:
    names = ["image_10.png", "image_2.png", "image_1.png"]
    assert sorted(names, key=natural_sort_key) == ["image_1.png", "image_2.png", "image_10.png"]


def test_image_folder_source_reads_in_natural_order(tmp_path: Path) -> None:
    for n in (10, 2, 1):  # the mean grey level tags each image with its number
        cv2.imwrite(str(tmp_path / f"image_{n}.png"), np.full((8, 8, 3), n * 10, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    with CameraSource(tmp_path) as source:
        assert isinstance(source, FrameSource) and not source.is_live
        levels = [int(frame[0, 0, 0]) for frame in source]
        with pytest.raises(EndOfStream):
            source.read()
    assert levels == [10, 20, 100]
    with pytest.raises(CameraError, match="after close"):
        source.read()


def test_image_folder_source_refuses_a_decompression_bomb_and_a_corrupt_image(tmp_path: Path) -> None:
    from tests.test_bad_input import png_bomb

    cv2.imwrite(str(tmp_path / "image_1.png"), np.full((8, 8, 3), 10, np.uint8))
    (tmp_path / "image_2.png").write_bytes(png_bomb())
    (tmp_path / "image_3.png").write_bytes(b"\x89PNG not really")
    with CameraSource(tmp_path) as source:
        source.read()
        with pytest.raises(CameraError, match=r"image_2.png: its header claims 8000x8000 px"):
            source.read()
        with pytest.raises(CameraError, match=r"image_3.png: cannot decode image"):
            source.read()


def test_missing_or_empty_sources_raise(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="nothing_here"):
        CameraSource(tmp_path / "nothing_here")
    with pytest.raises(CameraError, match="holds no images"):
        CameraSource(tmp_path)
    not_video = tmp_path / "clip.avi"
    not_video.write_text("not a video")
    with pytest.raises(CameraError, match="clip.avi"):
        CameraSource(not_video)


def test_video_file_source(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    assert writer.isOpened()
    for n in range(5):
        writer.write(np.full((48, 64, 3), 40 * n, np.uint8))
    writer.release()
    with CameraSource(path) as source:
        frames = list(source)
    assert len(frames) == 5 and frames[0].shape == (48, 64, 3)
    np.testing.assert_allclose([f.mean() for f in frames], [0, 40, 80, 120, 160], atol=3)


class _FakeCapture:
    """A live capture that delivers ``n_frames`` frames at 50 Hz and then hangs (a stalled camera) until released."""

    def __init__(self, n_frames: int) -> None:
        self.n_frames = n_frames
        self.count = 0
        self.released = threading.Event()

    def read(self):
        if self.count >= self.n_frames:
            self.released.wait(5.0)
            return False, None
        time.sleep(0.02)
        self.count += 1
        return True, np.full((4, 4, 3), self.count, np.uint8)

    def release(self) -> None:
        self.released.set()


def test_live_source_discards_warmup_and_detects_a_stall() -> None:
    capture = _FakeCapture(n_frames=6)
    with CameraSource.from_capture(capture, warmup_frames=2, stall_timeout_s=0.3) as source:
        assert source.is_live
        seen = [int(source.read()[0, 0, 0])]
        assert seen[0] >= 3  # frames 1 and 2 (at least) went to the warm-up
        with pytest.raises(CameraError, match="stalled, no new frame within 0.3 s"):
            while True:  # the reader keeps only the newest frame, so fewer reads than frames may succeed
                seen.append(int(source.read()[0, 0, 0]))
        assert seen == sorted(set(seen)) and seen[-1] == 6  # never a stale or repeated frame
    assert capture.released.is_set()


def test_live_source_reports_a_failed_read() -> None:
    class Unplugged(_FakeCapture):
        def read(self):
            return False, None

    with pytest.raises(CameraError, match="read failed"):
        CameraSource.from_capture(Unplugged(0), warmup_frames=1, stall_timeout_s=1.0)


def test_missing_device_raises() -> None:
    with pytest.raises(CameraError, match="device 97"):
        CameraSource(97)


def test_virtual_camera() -> None:
    frames = iter([_frame(0), _frame(1)])
    with VirtualCamera(lambda: next(frames, None), name="sim tactip") as camera:
        assert isinstance(camera, FrameSource)
        assert len(list(camera)) == 2
    with pytest.raises(CameraError, match="sim tactip"):
        VirtualCamera(lambda: np.zeros(3, np.float32), name="sim tactip").read()


# ---------------------------------------------------------------------------------------------- real data

RAW_IMAGES = Path("tactip331_raw") / "images"
PUBLISHED_IMAGES = Path("tactip331") / "real" / "surface_3d" / "tap" / "csv_train" / "images"


@pytest.mark.data
def test_shipped_config_reproduces_published_images() -> None:
    # Measured with the shipped config: pixel agreement 1.0 on all 100 pairs (simshear evaluate camera).
    root = Path(os.environ.get("SIMSHEAR_DATA", "../shared/data"))
    for folder in (root / RAW_IMAGES, root / PUBLISHED_IMAGES):
        if not folder.is_dir():
            pytest.fail(f"real data folder {folder} (resolved {folder.resolve()}) is missing; set SIMSHEAR_DATA to "
                        "the data root holding tactip331/ and tactip331_raw/")
    config = default_config()
    for n in (1, 17, 58, 100):
        raw = cv2.imread(str(root / RAW_IMAGES / f"image_{n}.png"), cv2.IMREAD_COLOR)
        published = cv2.imread(str(root / PUBLISHED_IMAGES / f"image_{n}.png"), cv2.IMREAD_GRAYSCALE)
        assert raw is not None and published is not None, f"cannot read image_{n}.png under {root}"
        agreement = float(np.mean(preprocess(raw, config) == published))
        assert agreement >= 0.99, f"image_{n}: pixel agreement {agreement:.4f} < 0.99"


def test_calibration_command_arguments() -> None:
    import argparse

    from simshear_gym.evaluate import camera_calibration

    parser = argparse.ArgumentParser()
    camera_calibration.add_arguments(parser)
    args = parser.parse_args(["--data", "somewhere", "--write-config"])
    assert args.data == "somewhere" and args.out == "results" and args.write_config.endswith("tactip_preprocess.json")
    assert parser.parse_args([]).write_config is None
