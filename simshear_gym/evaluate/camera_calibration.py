"""Calibrate the real-camera preprocessing on raw TacTip frames against the published processed images.

Data (under the data root): ``tactip331_raw/images/image_N.png`` are raw 640x480 frames and
``tactip331/real/surface_3d/tap/csv_train/images/image_N.png`` (N = 1..100) the published 128x128 binary images
of the same contacts. The search maximises pixel agreement (share of equal pixels) over the crop box, the
adaptive-threshold block and constant, the polarity and an optional circle mask:

1. seed: polarity and threshold from the values seen in the Bristol code, at the start crop (110, 0, 550, 440);
2. coarse: square crops on an 8-pixel grid of centres and a 16-pixel grid of sides around the start;
3. fine: pattern search over the four crop edges with steps 4, 2, 1, then every +-1 combination;
4. threshold: every odd block 3..31 and constant -60..20, then the crop again, until neither changes;
5. mask: a circle mask, kept only if it raises agreement.

The search runs on every ``search_stride``-th pair; the report covers all pairs, with pixel agreement and SSIM
(``skimage.metrics.structural_similarity``, data_range=255) per image.

Command: ``simshear evaluate camera [--data ROOT] [--out results] [--write-config [PATH]]``.
"""

from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from simshear_gym.data.tactile_set import decode_image
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record
from simshear_gym.real.camera import (
    DEFAULT_CONFIG_PATH,
    PreprocessConfig,
    circle_mask,
    crop_and_resize,
    preprocess,
    threshold_and_mask,
    to_gray,
)

RAW_DIR = Path("tactip331_raw") / "images"
PUBLISHED_DIR = Path("tactip331") / "real" / "surface_3d" / "tap" / "csv_train" / "images"
N_PAIRS = 100
START_BBOX_PX = (110, 0, 550, 440)  # the "midi" 331-pin TacTip crop in the Bristol code
SEED_THRESHOLDS: tuple[tuple[int, float], ...] = ((61, 5.0), (11, -30.0), (501, 1.0))  # (block, C) seen there
BLOCKS_PX: tuple[int, ...] = tuple(range(3, 32, 2))
CONSTANTS: tuple[float, ...] = tuple(float(c) for c in range(-60, 21))


@dataclass(frozen=True)
class PairSet:
    """Raw grey frames and the published images of the same contacts.

    Attributes:
        ids: image numbers N.
        raw_gray: uint8 (480, 640) grey raw frames.
        published: uint8 (128, 128) published binary images.
    """

    ids: tuple[int, ...]
    raw_gray: tuple[np.ndarray, ...]
    published: tuple[np.ndarray, ...]

    def subset(self, stride: int) -> PairSet:
        """Every ``stride``-th pair, starting with the first."""
        return PairSet(self.ids[::stride], self.raw_gray[::stride], self.published[::stride])


@dataclass(frozen=True)
class CalibrationResult:
    """The best config found and how the search went.

    Attributes:
        config: the calibrated preprocessing.
        search_agreement: mean pixel agreement on the search pairs.
        start_agreement: mean pixel agreement of the best seed at the start crop.
        evaluations: configs scored.
        stages: (stage name, agreement after it) in order.
    """

    config: PreprocessConfig
    search_agreement: float
    start_agreement: float
    evaluations: int
    stages: tuple[tuple[str, float], ...]


def load_pairs(root: Path, ids: range | tuple[int, ...] = range(1, N_PAIRS + 1)) -> PairSet:
    """Load raw frames (as grey) and published images ``image_N.png`` for ``ids`` from the data root.

    Raises:
        FileNotFoundError: a folder or image is missing (the message names it).
    """
    raw_dir, published_dir = root / RAW_DIR, root / PUBLISHED_DIR
    for folder in (raw_dir, published_dir):
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder} does not exist; pass --data or set SIMSHEAR_DATA to the data root")
    raw, published = [], []
    for n in ids:
        raw.append(to_gray(_imread(raw_dir / f"image_{n}.png", cv2.IMREAD_COLOR)))
        published.append(_imread(published_dir / f"image_{n}.png", cv2.IMREAD_GRAYSCALE))
    return PairSet(tuple(ids), tuple(raw), tuple(published))


def pixel_agreement(ours: np.ndarray, published: np.ndarray) -> float:
    """Share of pixels with equal values (1.0 = identical)."""
    if ours.shape != published.shape:
        raise ValueError(f"image shapes differ: {ours.shape} vs {published.shape}")
    return float(np.mean(ours == published))


def ssim(ours: np.ndarray, published: np.ndarray) -> float:
    """Structural similarity of two uint8 images (data_range 255)."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(ours, published, data_range=255))


def calibrate(pairs: PairSet, start_bbox_px: tuple[int, int, int, int] = START_BBOX_PX) -> CalibrationResult:
    """Search the preprocessing that best reproduces ``pairs.published`` from ``pairs.raw_gray``."""
    search = _Search(pairs)
    frame_h, frame_w = pairs.raw_gray[0].shape
    stages: list[tuple[str, float]] = []

    # 1. seed polarity and threshold at the start crop
    seeds = [
        PreprocessConfig(start_bbox_px, block, c, invert=invert)
        for (block, c), invert in itertools.product(SEED_THRESHOLDS, (False, True))
    ]
    best, best_score = search.best_of(seeds)
    start_score = best_score
    stages.append(("seed", best_score))

    # 2. coarse square crops, each scored with every seed threshold of the chosen polarity
    x0, y0, x1, y1 = start_bbox_px
    centre_x, centre_y, side = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0
    candidates = []
    for dx, dy, dside in itertools.product(range(-64, 65, 8), range(-64, 65, 8), range(-80, 81, 16)):
        s = side + dside
        bx0, by0 = int(round(centre_x + dx - s / 2)), int(round(centre_y + dy - s / 2))
        if bx0 < 0 or by0 < 0 or bx0 + s > frame_w or by0 + s > frame_h:
            continue
        for block, c in SEED_THRESHOLDS:
            candidates.append(replace(best, crop_bbox_px=(bx0, by0, bx0 + s, by0 + s), threshold_block_px=block,
                                      threshold_c=c))
    best, best_score = search.best_of(candidates + [best])
    stages.append(("coarse crop", best_score))

    # 3-4. alternate fine crop and threshold search until neither improves
    for _ in range(4):
        before = best_score
        best, best_score = search.refine_crop(best, best_score, (frame_w, frame_h))
        stages.append(("fine crop", best_score))
        best, best_score = search.best_threshold(best, best_score)
        stages.append(("threshold", best_score))
        if best_score <= before:
            break

    # 5. circle mask, kept only if it helps
    best, best_score = search.best_mask(best, best_score)
    stages.append(("mask", best_score))
    return CalibrationResult(best, best_score, start_score, search.evaluations, tuple(stages))


def evaluate(pairs: PairSet, config: PreprocessConfig) -> dict:
    """Per-image pixel agreement and SSIM of ``preprocess(raw, config)`` against the published images."""
    rows = []
    for n, gray, published in zip(pairs.ids, pairs.raw_gray, pairs.published):
        ours = preprocess(gray, config)
        rows.append({"image": n, "pixel_agreement": pixel_agreement(ours, published), "ssim": ssim(ours, published)})
    summary = {}
    for key in ("pixel_agreement", "ssim"):
        values = np.array([row[key] for row in rows])
        summary[key] = {"mean": float(values.mean()), "median": float(np.median(values)), "min": float(values.min()),
                        "max": float(values.max())}
    return {"n_images": len(rows), "summary": summary, "per_image": rows}


def save_montage(path: Path, pairs: PairSet, config: PreprocessConfig, n_rows: int = 4) -> Path:
    """Figure with rows of (raw crop | ours | published | difference) for the first ``n_rows`` pairs."""
    plt = pyplot()
    n_rows = min(n_rows, len(pairs.ids))
    figure, axes = plt.subplots(n_rows, 4, figsize=(10, 2.6 * n_rows), squeeze=False)
    x0, y0, x1, y1 = config.crop_bbox_px
    for row, (n, gray, published) in enumerate(zip(pairs.ids, pairs.raw_gray, pairs.published)):
        if row == n_rows:
            break
        ours = preprocess(gray, config)
        panels = (
            (gray[y0:y1, x0:x1], f"raw crop image_{n}"),
            (ours, "ours"),
            (published, "published"),
            (np.where(ours == published, 0, 255).astype(np.uint8), f"differs: {np.mean(ours != published):.2%}"),
        )
        for axis, (image, title) in zip(axes[row], panels):
            axis.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
            axis.set_title(title, fontsize=9)
            axis.set_axis_off()
    save_figure(figure, path, dpi=100)
    return path


class _Search:
    """Scores configs on a pair set, caching the cropped-and-resized grey images per crop."""

    def __init__(self, pairs: PairSet) -> None:
        self._pairs = pairs
        self._small: dict[tuple, list[np.ndarray]] = {}
        self.evaluations = 0

    def small_gray(self, config: PreprocessConfig) -> list[np.ndarray]:
        key = (config.crop_bbox_px, config.output_size_px)
        if key not in self._small:
            if len(self._small) >= 256:  # bound the memory; the search revisits only recent crops
                self._small.clear()
            self._small[key] = [crop_and_resize(gray, config) for gray in self._pairs.raw_gray]
        return self._small[key]

    def score(self, config: PreprocessConfig) -> float:
        self.evaluations += 1
        smalls = self.small_gray(config)
        return float(np.mean([
            np.mean(threshold_and_mask(small, config) == published)
            for small, published in zip(smalls, self._pairs.published)
        ]))

    def best_of(self, configs: list[PreprocessConfig]) -> tuple[PreprocessConfig, float]:
        best, best_score = None, -1.0
        for config in configs:
            score = self.score(config)
            if score > best_score:
                best, best_score = config, score
        return best, best_score

    def refine_crop(
        self, config: PreprocessConfig, score: float, frame_size_px: tuple[int, int]
    ) -> tuple[PreprocessConfig, float]:
        """Pattern search over the crop edges with steps 4, 2, 1, then every +-1 combination of the edges."""
        moves = []
        for edge in range(4):
            for sign in (-1, 1):
                move = [0, 0, 0, 0]
                move[edge] = sign
                moves.append(move)
        for sign in (-1, 1):  # shift the whole box
            moves += [[sign, 0, sign, 0], [0, sign, 0, sign]]
        for step in (4, 2, 1):
            improved = True
            while improved:
                candidates = [self._moved(config, [m * step for m in move], frame_size_px) for move in moves]
                best, best_score = self.best_of([c for c in candidates if c is not None])
                improved = best_score > score
                if improved:
                    config, score = best, best_score
        while True:
            candidates = [
                self._moved(config, list(move), frame_size_px) for move in itertools.product((-1, 0, 1), repeat=4)
            ]
            best, best_score = self.best_of([c for c in candidates if c is not None])
            if best_score <= score:
                return config, score
            config, score = best, best_score

    def best_threshold(self, config: PreprocessConfig, score: float) -> tuple[PreprocessConfig, float]:
        blocks = sorted(set(BLOCKS_PX) | {config.threshold_block_px})
        candidates = [replace(config, threshold_block_px=b, threshold_c=c) for b in blocks for c in CONSTANTS]
        best, best_score = self.best_of(candidates)
        return (best, best_score) if best_score > score else (config, score)

    def best_mask(self, config: PreprocessConfig, score: float) -> tuple[PreprocessConfig, float]:
        width, height = config.output_size_px
        centre_x, centre_y = (width - 1) / 2, (height - 1) / 2
        half = min(width, height) / 2
        unmasked = replace(config, mask_centre_px=None, mask_radius_px=None)
        thresholded = [threshold_and_mask(s, unmasked) for s in self.small_gray(config)]
        outside_value = 255 if config.invert else 0  # threshold_and_mask masks before it inverts
        best, best_score = config, score
        for dx, dy in itertools.product(range(-6, 7, 2), repeat=2):
            for radius in np.arange(0.75 * half, 1.15 * half, 1.0):
                self.evaluations += 1
                inside = circle_mask(config.output_size_px, (centre_x + dx, centre_y + dy), float(radius))
                masked_score = float(np.mean([
                    np.mean(np.where(inside, t, outside_value) == published)
                    for t, published in zip(thresholded, self._pairs.published)
                ]))
                if masked_score > best_score:
                    best_score = masked_score
                    best = replace(config, mask_centre_px=(centre_x + dx, centre_y + dy), mask_radius_px=float(radius))
        return best, best_score

    @staticmethod
    def _moved(config: PreprocessConfig, move: list[int], frame_size_px: tuple[int, int]) -> PreprocessConfig | None:
        x0, y0, x1, y1 = (a + b for a, b in zip(config.crop_bbox_px, move))
        width, height = frame_size_px
        if x0 < 0 or y0 < 0 or x1 > width or y1 > height or x1 - x0 < 16 or y1 - y0 < 16:
            return None
        return replace(config, crop_bbox_px=(x0, y0, x1, y1))


def _imread(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"cannot read image {path} (missing)")
    return decode_image(path, flags)  # the data sets' size guard; a TactileDataError names the file


# --------------------------------------------------------------------------------------------------------------
# Command
# --------------------------------------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``simshear evaluate camera``."""
    parser.add_argument("--data", default=None, help="data root holding tactip331/ and tactip331_raw/ "
                        "(default: $SIMSHEAR_DATA, else ../shared/data)")
    parser.add_argument("--out", default="results", help="folder for camera_calibration.json/.png (default: results)")
    parser.add_argument("--write-config", nargs="?", const=str(DEFAULT_CONFIG_PATH), default=None, metavar="PATH",
                        help="save the calibrated config as JSON (default path: the shipped "
                             f"{DEFAULT_CONFIG_PATH.name})")
    parser.add_argument("--search-stride", type=int, default=5,
                        help="search on every N-th of the 100 pairs (default 5: 20 pairs); all are evaluated")


def run(args: argparse.Namespace) -> int:
    """Calibrate, evaluate on all pairs, write the report and figure; print a short summary."""
    from simshear_gym.data.paths import data_root

    if args.search_stride < 1:
        raise ValueError(f"--search-stride must be >= 1, got {args.search_stride}")
    root = data_root(args.data)
    out = Path(args.out)
    started = time.perf_counter()
    pairs = load_pairs(root)
    search_pairs = pairs.subset(args.search_stride)
    result = calibrate(search_pairs)
    search_s = time.perf_counter() - started
    report = evaluate(pairs, result.config)
    held_out = [row for row in report["per_image"] if row["image"] not in set(search_pairs.ids)]
    payload = {
        "config": result.config.to_dict(),
        "search": {
            "pairs": list(search_pairs.ids),
            "start_bbox_px": list(START_BBOX_PX),
            "start_agreement": result.start_agreement,
            "search_agreement": result.search_agreement,
            "stages": [{"stage": name, "pixel_agreement": value} for name, value in result.stages],
            "configs_scored": result.evaluations,
            "seconds": round(search_s, 1),
        },
        "held_out_pixel_agreement_mean": float(np.mean([r["pixel_agreement"] for r in held_out])) if held_out else None,
        **report,
    }
    write_record("simshear evaluate camera", add_arguments, args, out / "camera_calibration.json", payload)
    save_montage(out / "camera_calibration.png", pairs.subset(25), result.config)
    if args.write_config:
        result.config.save(args.write_config)

    summary = report["summary"]
    print(f"calibrated config: {result.config.to_dict()}")
    print(f"search on {len(search_pairs.ids)} pairs: {result.evaluations} configs in {search_s:.0f} s")
    for key in ("pixel_agreement", "ssim"):
        s = summary[key]
        print(f"{key:16s} over {report['n_images']} images: mean {s['mean']:.4f}  median {s['median']:.4f}  "
              f"min {s['min']:.4f}")
    print(f"wrote {out / 'camera_calibration.json'}, {out / 'camera_calibration.png'}"
          + (f", {args.write_config}" if args.write_config else ""))
    return 0

