"""Where the two arms stand to each other, and the plate on the leader's flange.

**Frames** (mm, deg; ``T_a_b`` maps frame b coordinates into frame a): ``follower`` and ``leader`` are the two
MG400s' base frames (level, z up, origins on their J2 axes as the controllers report poses); ``face`` is the
plate's top face (origin on the face centre, +z out of the face, as a stimulus frame). Everything the two-arm
workflows compute (the leader's trajectory seen by the follower, the contact error, the drift bound) is in the
follower's base frame, through :class:`BaseToBase` (the leader's base in the follower's frame, from
``simshear calibrate-arms``).

Both bases stand level on one table, so the transform is four numbers: the leader base's origin in the follower
frame and its turn about the vertical. The defaults are the simulated tracking scene's
(:mod:`simshear_gym.envs.tracking`): the arms face each other 690 mm apart.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.data.labels import SURFACE_DEPTH_MM
from simshear_gym.io import write_json
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange
from simshear_gym.transforms import invert, pose_to_matrix

CALIBRATION_VERSION = 1

# The simulated tracking scene's layout (simshear_gym.envs.tracking; equal by test, kept here so that the command
# modules import no simulator): the leader base at the world origin, the follower's 690 mm away turned a half turn.
SCENE_LEADER_IN_FOLLOWER_MM_DEG = (690.0, 0.0, 0.0, 180.0)
SCENE_LEADER_START_POSE_MM_DEG = (310.0, 0.0, -40.0, 0.0)
SCENE_T_FLANGE_FACE_POSE = (70.0, 0.0, -20.0, 0.0, 0.0, 180.0)
SCENE_PLATE_SIZE_MM = (120.0, 120.0, 10.0)


@dataclass(frozen=True)
class BaseToBase:
    """The leader's base frame in the follower's: ``T_follower_leader`` = translation then a turn about z.

    Attributes:
        x_mm, y_mm, z_mm: the leader base's origin in the follower's base frame, mm.
        rz_deg: the leader base's turn about the vertical, deg, in (-180, 180].
    """

    x_mm: float = SCENE_LEADER_IN_FOLLOWER_MM_DEG[0]
    y_mm: float = SCENE_LEADER_IN_FOLLOWER_MM_DEG[1]
    z_mm: float = SCENE_LEADER_IN_FOLLOWER_MM_DEG[2]
    rz_deg: float = SCENE_LEADER_IN_FOLLOWER_MM_DEG[3]

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm", "z_mm", "rz_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"BaseToBase.{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if math.hypot(self.x_mm, self.y_mm) > 2000.0 or abs(self.z_mm) > 500.0:
            raise ValueError(f"BaseToBase: the leader base at ({self.x_mm:g}, {self.y_mm:g}, {self.z_mm:g}) mm is "
                             "not within 2 m (and 0.5 m in height) of the follower's: a unit or sign mistake?")
        object.__setattr__(self, "rz_deg", float((self.rz_deg + 180.0) % 360.0 - 180.0) or 0.0)
        if self.rz_deg == -180.0:
            object.__setattr__(self, "rz_deg", 180.0)

    def T_follower_leader(self) -> np.ndarray:
        """4x4: leader base frame -> follower base frame."""
        return pose_to_matrix(np.array([self.x_mm, self.y_mm, self.z_mm, 0.0, 0.0, self.rz_deg]))

    @classmethod
    def from_matrix(cls, T_follower_leader: np.ndarray) -> BaseToBase:
        T = np.asarray(T_follower_leader, dtype=np.float64)
        return cls(float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), math.degrees(math.atan2(T[1, 0], T[0, 0])))

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.x_mm, self.y_mm, self.z_mm, self.rz_deg)

    def difference(self, other: BaseToBase) -> tuple[float, float]:
        """(distance of the origins, mm; difference of the turns, deg) between two calibrations."""
        distance = math.dist(self.as_tuple()[:3], other.as_tuple()[:3])
        turn = abs((self.rz_deg - other.rz_deg + 180.0) % 360.0 - 180.0)
        return distance, turn


@dataclass(frozen=True)
class ArmsCalibration:
    """The calibration file of ``simshear calibrate-arms``, read by ``simshear experiment``.

    Attributes:
        leader_in_follower: the leader's base in the follower's frame.
        method: how it was measured (``"touch"``: the follower's TacTip held points on the leader's plate;
            ``"fixture"``: entered from a fixture's drawing).
        residual_rms_mm: the fit's RMS residual, mm (0 for a fixture).
        points: how many poses the fit used.
        command: the command that wrote it.
    """

    leader_in_follower: BaseToBase
    method: str = "fixture"
    residual_rms_mm: float = 0.0
    points: int = 0
    command: str = ""

    def __post_init__(self) -> None:
        if self.method not in ("touch", "fixture"):
            raise ValueError(f"ArmsCalibration.method must be 'touch' or 'fixture', got {self.method!r}")
        if not (math.isfinite(self.residual_rms_mm) and self.residual_rms_mm >= 0.0):
            raise ValueError(f"ArmsCalibration.residual_rms_mm must be >= 0, got {self.residual_rms_mm!r}")

    def to_dict(self) -> dict[str, Any]:
        b = self.leader_in_follower
        return {"version": CALIBRATION_VERSION, "frames": "leader base in the follower's base frame (mm, deg)",
                "leader_in_follower": {"x_mm": b.x_mm, "y_mm": b.y_mm, "z_mm": b.z_mm, "rz_deg": b.rz_deg},
                "T_follower_leader": b.T_follower_leader().round(9).tolist(), "method": self.method,
                "residual_rms_mm": self.residual_rms_mm, "points": self.points, "command": self.command}

    def save(self, path: str | Path) -> Path:
        return write_json(path, self.to_dict())  # its folder made, written atomically

    @classmethod
    def load(cls, path: str | Path) -> ArmsCalibration:
        """Read a calibration file; errors name the file and the field."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"calibration file {path}: no such file (write it with simshear calibrate-arms)"
                                    ) from None
        except json.JSONDecodeError as error:
            raise ValueError(f"calibration file {path}: not JSON ({error})") from None
        if not isinstance(data, dict) or data.get("version") != CALIBRATION_VERSION:
            raise ValueError(f"calibration file {path}: expected a JSON object with version {CALIBRATION_VERSION}, "
                             f"got version {data.get('version') if isinstance(data, dict) else type(data).__name__}")
        pose = data.get("leader_in_follower")
        keys = ("x_mm", "y_mm", "z_mm", "rz_deg")
        if not isinstance(pose, dict) or any(key not in pose for key in keys):
            raise ValueError(f"calibration file {path}: field leader_in_follower must hold {keys}, got {pose!r}")
        try:
            return cls(BaseToBase(*(pose[key] for key in keys)), str(data.get("method", "fixture")),
                       float(data.get("residual_rms_mm", 0.0)), int(data.get("points", 0)),
                       str(data.get("command", "")))
        except (TypeError, ValueError) as error:
            raise ValueError(f"calibration file {path}: {error}") from None


class FaceOnFlange:
    """A face held on the leader's flange (its frame ``T_flange_face()``, its extent ``size_mm``): a
    :class:`PlateMount` or the co-lift's :class:`~simshear_gym.lab.colift_layout.ObjectFace`."""

    @property
    def half_extents_mm(self) -> tuple[float, float]:
        return (self.size_mm[0] / 2.0, self.size_mm[1] / 2.0)

    def T_follower_face(self, leader_flange_pose_mm_deg, T_follower_leader: np.ndarray) -> np.ndarray:
        """The face frame in the follower's base frame, for the leader's flange pose (its base frame)."""
        return T_follower_leader @ pose_to_T_base_flange(leader_flange_pose_mm_deg) @ self.T_flange_face()


@dataclass(frozen=True)
class PlateMount(FaceOnFlange):
    """The flat plate the leader holds: its top face's frame on the leader's flange, and its size.

    Attributes:
        T_flange_face_pose: ``(x, y, z mm, rx, ry, rz deg)`` of the face frame on the flange (default the sim
            scene's: 70 mm out, 20 mm below, turned a half turn).
        size_mm: the plate (x, y, thickness), mm.
    """

    T_flange_face_pose: tuple[float, ...] = SCENE_T_FLANGE_FACE_POSE
    size_mm: tuple[float, float, float] = SCENE_PLATE_SIZE_MM

    def __post_init__(self) -> None:
        pose = tuple(float(v) for v in self.T_flange_face_pose)
        if len(pose) != 6 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"PlateMount.T_flange_face_pose must be 6 finite numbers, got {self.T_flange_face_pose!r}")
        if abs(pose[3]) > 1e-9 or abs(pose[4]) > 1e-9:
            raise ValueError("PlateMount.T_flange_face_pose: the plate must lie level on the flange (rx = ry = 0)")
        object.__setattr__(self, "T_flange_face_pose", pose)
        size = tuple(float(v) for v in self.size_mm)
        if len(size) != 3 or min(size) <= 0.0:
            raise ValueError(f"PlateMount.size_mm must be 3 sizes > 0 mm, got {self.size_mm!r}")
        object.__setattr__(self, "size_mm", size)

    def T_flange_face(self) -> np.ndarray:
        return pose_to_matrix(np.array(self.T_flange_face_pose))


LEADER_START_POSE: tuple[float, float, float, float] = SCENE_LEADER_START_POSE_MM_DEG
"""The leader's flange at the start of a tracking run (its base frame), the sim scene's."""


def T_face_work() -> np.ndarray:
    """The labels' work frame in a face frame: x along the face's x, z into the face, origin
    ``SURFACE_DEPTH_MM`` (the labels' face) above it (so a sensor's work z is the depth a GDNN reads)."""
    T_work_face = np.diag([1.0, -1.0, -1.0, 1.0])
    T_work_face[2, 3] = SURFACE_DEPTH_MM
    return invert(T_work_face)


def sensor_on_face(T_base_face: np.ndarray, x_mm: float, y_mm: float, depth_mm: float) -> np.ndarray:
    """The sensor frame (pointing into the face, x along the face's x) at ``(x, y)`` of the face at a depth
    (labels' convention: the face at 2.2 mm, so a depth below 2.2 mm is above the face)."""
    return T_base_face @ T_face_work() @ pose_to_matrix(np.array([x_mm, y_mm, depth_mm, 0.0, 0.0, 0.0]))


def flange_pose_for_sensor(T_base_sensor: np.ndarray, T_flange_sensor: np.ndarray) -> np.ndarray:
    """The MG400 flange pose ``(x, y, z mm, R deg)`` that puts the sensor at ``T_base_sensor``."""
    from simshear_gym.robots.mg400.frames import T_base_flange_to_pose

    return T_base_flange_to_pose(T_base_sensor @ invert(T_flange_sensor))
