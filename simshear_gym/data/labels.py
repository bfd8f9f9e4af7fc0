"""Label conventions of the tactile-data format: the one place that defines poses, shear and their frames.

A row of ``targets.csv`` describes one contact:

- ``pose_1..pose_6`` = ``x, y, z`` [mm], ``Rx, Ry, Rz`` [deg]: the sensor (its TCP, the dome apex) in the
  **work frame**. The work frame's z axis points into the stimulus, so ``z`` is the indentation depth.
  Rotations are extrinsic x-y-z Euler angles (``scipy`` ``"xyz"``), as in the common robot interface.
- ``move_1..move_6``: the shear. The sensor first touched the stimulus at ``pose - move`` and then slid, in
  contact, to ``pose``; the image was taken at ``pose``. ``move`` is expressed in the work frame.
- ``obj_pose``: ``[0, 0, 0, 0, 0, -48]`` in the published sets: the TacTip is mounted rotated by -48 deg about
  its axis on the collecting robot's flange. That rotation was compensated when the data were made: at
  ``Rz = 0`` the real images' axes are the work frame's axes (tilting about work x moves the contact along the
  image rows, about work y along the columns, in the real images as in the published sim images). So the
  **sensor frame** used here is the TCP frame: the work frame turned by the pose's own ``Rz``, and the mount
  angle is not applied a second time. :func:`mount_rz_deg` reads it so that a set with another mount is noticed.

The **shear vector in the sensor frame** (``shear_sensor_*``) is the move with its x/y components rotated by
``-Rz`` (the convention of the public shPix2pix code); z and the angles are kept as they are.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

POSE_COLUMNS: tuple[str, ...] = ("pose_1", "pose_2", "pose_3", "pose_4", "pose_5", "pose_6")
MOVE_COLUMNS: tuple[str, ...] = ("move_1", "move_2", "move_3", "move_4", "move_5", "move_6")
SHEAR_COLUMNS: tuple[str, ...] = (
    "shear_sensor_x_mm", "shear_sensor_y_mm", "shear_sensor_z_mm",
    "shear_sensor_rx_deg", "shear_sensor_ry_deg", "shear_sensor_rz_deg",
)
IMAGE_COLUMN = "sensor_image"
POSE_NAMES: tuple[str, ...] = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")

CONTACT_TYPES: tuple[str, ...] = ("surface", "edge")

SURFACE_DEPTH_MM = 2.2
"""Work-frame z of the stimulus's face in the labels (the touch: a pose's z past it is the indentation), as
calibrated against the published sim images of the same rows (``sim.replay.ReplayGeometry``'s default)."""

LENGTH_LIMIT_MM = 1000.0
"""The declared range of every length label (poses, moves, shear; mm): |value| <= 1 m. A tactile contact lies
within an arm's reach of the work origin (an MG400 reaches 440 mm); a larger value is a unit or parsing error."""
ANGLE_LIMIT_DEG = 360.0
"""The declared range of every angle label (deg): |value| <= 360 (angles are degrees, not radians x 1000)."""


def label_limit(column: str) -> tuple[float, str]:
    """The declared range (+- limit, unit) of a label column of the format: an angle (``pose_4..6``,
    ``move_4..6``, ``shear_sensor_r*_deg``) or a length."""
    angle = column in POSE_COLUMNS[3:] + MOVE_COLUMNS[3:] or column.endswith("_deg")
    return (ANGLE_LIMIT_DEG, "deg") if angle else (LENGTH_LIMIT_MM, "mm")


@dataclass(frozen=True)
class LabelRange:
    """Inclusive range of one label column, in its own unit (mm or deg)."""

    column: str
    low: float
    high: float

    def __post_init__(self) -> None:
        if not self.low <= self.high:
            raise ValueError(f"LabelRange {self.column}: low {self.low} must not exceed high {self.high}")

    @property
    def centre(self) -> float:
        return 0.5 * (self.low + self.high)


# Collection ranges of the published tactip331 sets (../shared/data/README.md); columns not listed are 0.
_SHEAR_MOVES = (
    LabelRange("move_1", -5, 5), LabelRange("move_2", -5, 5),
    LabelRange("move_4", -5, 5), LabelRange("move_5", -5, 5), LabelRange("move_6", -5, 5),
)
TASK_RANGES: dict[tuple[str, str], tuple[LabelRange, ...]] = {
    ("surface", "tap"): (LabelRange("pose_3", 2, 5), LabelRange("pose_4", -15, 15), LabelRange("pose_5", -15, 15)),
    ("surface", "shear"): (LabelRange("pose_3", 2.5, 5.5), LabelRange("pose_4", -15, 15),
                           LabelRange("pose_5", -15, 15)) + _SHEAR_MOVES,
    ("edge", "tap"): (LabelRange("pose_2", -6, 6), LabelRange("pose_3", 3, 5), LabelRange("pose_6", -180, 180)),
    ("edge", "shear"): (LabelRange("pose_2", -6, 6), LabelRange("pose_3", 3, 5),
                        LabelRange("pose_6", -180, 180)) + _SHEAR_MOVES,
}


def task_ranges(contact: str, kind: str) -> tuple[LabelRange, ...]:
    """The collection ranges of a contact type (``surface`` | ``edge``) and kind (``tap`` | ``shear``)."""
    try:
        return TASK_RANGES[(contact, kind)]
    except KeyError:
        raise ValueError(
            f"unknown task ({contact!r}, {kind!r}); expected contact in {CONTACT_TYPES} and kind in ('tap', 'shear')"
        ) from None


def shear_to_sensor_frame(move: np.ndarray, pose_rz_deg: np.ndarray) -> np.ndarray:
    """Express work-frame moves in the sensor frame.

    Args:
        move: (..., 6) ``move_1..move_6`` (mm, deg) in the work frame.
        pose_rz_deg: (...) the sensor's ``Rz`` at the image (``pose_6``).

    Returns:
        (..., 6) float64: x/y rotated by ``-pose_rz_deg``; z, Rx, Ry, Rz unchanged.
    """
    move = np.asarray(move, dtype=np.float64)
    if move.shape[-1] != 6:
        raise ValueError(f"move must have 6 components (x, y, z mm, Rx, Ry, Rz deg); got shape {move.shape}")
    angle = np.deg2rad(np.asarray(pose_rz_deg, dtype=np.float64))
    cos, sin = np.cos(angle), np.sin(angle)
    out = move.copy()
    out[..., 0] = cos * move[..., 0] + sin * move[..., 1]
    out[..., 1] = -sin * move[..., 0] + cos * move[..., 1]
    return out


def shear_to_work_frame(shear_sensor: np.ndarray, pose_rz_deg: np.ndarray) -> np.ndarray:
    """Inverse of :func:`shear_to_sensor_frame`."""
    return shear_to_sensor_frame(shear_sensor, -np.asarray(pose_rz_deg, dtype=np.float64))


def mount_rz_deg(obj_pose: str) -> float:
    """Parse an ``obj_pose`` cell (``"[0, 0, 0, 0, 0, -48]"`` or ``"[0.0 0.0 ... -48.0]"``) to its Rz in deg."""
    text = str(obj_pose).strip()
    try:
        values = json.loads(text) if "," in text else [float(v) for v in text.strip("[]").split()]
    except (json.JSONDecodeError, ValueError):
        raise ValueError(f"obj_pose {obj_pose!r}: expected 6 numbers like '[0, 0, 0, 0, 0, -48]'") from None
    if len(values) != 6:
        raise ValueError(f"obj_pose {obj_pose!r}: expected 6 numbers, got {len(values)}")
    return float(values[5])


def wrap_deg(angle_deg: float | np.ndarray) -> float | np.ndarray:
    """Wrap angles to [-180, 180) deg: a float for a scalar, an array for an array."""
    wrapped = (np.asarray(angle_deg, dtype=np.float64) + 180.0) % 360.0 - 180.0
    return float(wrapped) if wrapped.ndim == 0 else wrapped
