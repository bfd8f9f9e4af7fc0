"""Where the co-lift's arms, plate and object stand: the co-lift scene's layout (:mod:`simshear_gym.envs.colift`,
equal by test, kept here so that the command modules import no simulator) and the held object's face.

Frames as :mod:`simshear_gym.lab.frames`: the leader's and the follower's base frames, and the plate's face frame
on the leader's flange: upright, its +z (out of the face) along the grip axis towards the follower, its +y up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simshear_gym.lab.frames import FaceOnFlange
from simshear_gym.transforms import pose_to_matrix

# The co-lift scene's layout (simshear_gym.envs.colift; equal by test, kept here so that the command modules import
# no simulator): the leader's base at the world origin, the follower's 750 mm away turned a half turn; the upright
# plate's face 50 mm beyond and 60 mm below the leader's flange, its +z (out of the face) along the grip axis
# towards the follower, its +y up.
COLIFT_LEADER_IN_FOLLOWER_MM_DEG = (750.0, 0.0, 0.0, 180.0)
COLIFT_LEADER_START_POSE_MM_DEG = (280.0, 0.0, 0.0, 0.0)
COLIFT_T_FLANGE_PLATE = ((0.0, 0.0, 1.0, 50.0), (1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, -60.0), (0.0, 0.0, 0.0, 1.0))
OBJECT_FACE_MM: dict[str, tuple[float, float, float]] = {
    "prism": (30.0, 40.0, 30.0), "egg": (42.0, 54.0, 42.12), "brain": (46.0, 36.0, 40.2),
    "ducky": (50.0, 46.0, 36.29)}
"""Per object (``sim.objects.OBJECTS``): its extent across the grip (x, y up) and its thickness along the grip axis
on the plate's centre line (mm), as the co-lift scene places it against the plate (equal by test)."""
OBJECT_NAMES: tuple[str, ...] = tuple(OBJECT_FACE_MM)
OBJECT_THICKNESS_MM = {name: size[2] for name, size in OBJECT_FACE_MM.items()}


@dataclass(frozen=True)
class ObjectFace(FaceOnFlange):
    """The face of the held object the TacTip squeezes, as a frame on the leader's flange: the upright plate's face
    moved out by the object's thickness (origin on the grip axis, +z out of the face towards the follower, +y up).
    It stands where the tracking experiment's :class:`~simshear_gym.lab.frames.PlateMount` does.

    Attributes:
        object_name: one of :data:`OBJECT_NAMES`.
        T_flange_plate_rows: the plate's face frame on the leader's flange (4x4 rows, mm).
    """

    object_name: str = "prism"
    T_flange_plate_rows: tuple[tuple[float, ...], ...] = COLIFT_T_FLANGE_PLATE

    def __post_init__(self) -> None:
        if self.object_name not in OBJECT_FACE_MM:
            raise ValueError(f"ObjectFace.object_name must be one of {OBJECT_NAMES}, got {self.object_name!r}")
        rows = np.asarray(self.T_flange_plate_rows, dtype=np.float64)
        if rows.shape != (4, 4) or not np.all(np.isfinite(rows)) or not np.allclose(
                rows[:3, :3] @ rows[:3, :3].T, np.eye(3), atol=1e-6) or not np.allclose(rows[3], (0, 0, 0, 1)):
            raise ValueError(f"ObjectFace.T_flange_plate_rows must be a 4x4 rigid transform, got "
                             f"{self.T_flange_plate_rows!r}")

    @property
    def thickness_mm(self) -> float:
        return OBJECT_THICKNESS_MM[self.object_name]

    @property
    def size_mm(self) -> tuple[float, float]:
        return OBJECT_FACE_MM[self.object_name][:2]

    def T_flange_plate(self) -> np.ndarray:
        return np.asarray(self.T_flange_plate_rows, dtype=np.float64)

    def T_flange_face(self) -> np.ndarray:
        return self.T_flange_plate() @ pose_to_matrix(np.array([0.0, 0.0, self.thickness_mm, 0.0, 0.0, 0.0]))
