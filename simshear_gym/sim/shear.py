"""Shear from kinematics: how far the sensor has moved over the contact since it touched.

The simulator's contact is rigid and frictionless in the image (the dome does not deform sideways), so the
shear a real TacTip would show is computed instead of simulated: at contact onset the tracker stores an
**anchor**, the sensor's pose in the contacted object's frame; while in contact the shear is the sensor's pose
minus the anchor, componentwise (x, y, z mm, Rx, Ry, Rz deg) like the data's ``move``, then expressed in the
sensor frame (:func:`simshear_gym.data.labels.shear_to_sensor_frame`). Replaying a labelled row with anchor
``pose - move`` therefore gives exactly the row's move in the sensor frame.

Stick-slip: a real membrane sticks until the traction exceeds friction, then slips. The tracker models this
with limits: when the in-plane displacement exceeds ``slip_limit_mm`` (or |Rz| exceeds ``slip_limit_deg``), the
anchor is dragged along so that the shear stays on the limit. The defaults (7.5 mm, 7.5 deg) are beyond the
largest shear in the real data (|move x, y| <= 5 mm each, |move Rz| <= 5 deg), so everything the translator
learned from stays in stick, and larger motions saturate rather than leave the training distribution.
Losing contact clears the anchor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simshear_gym.data.labels import shear_to_sensor_frame, wrap_deg


@dataclass(frozen=True)
class ShearTrackerConfig:
    """Stick-slip limits: in-plane displacement (mm) and twist about the sensor axis (deg)."""

    slip_limit_mm: float = 7.5
    slip_limit_deg: float = 7.5

    def __post_init__(self) -> None:
        if self.slip_limit_mm <= 0 or self.slip_limit_deg <= 0:
            raise ValueError(
                f"slip limits must be > 0, got slip_limit_mm={self.slip_limit_mm}, "
                f"slip_limit_deg={self.slip_limit_deg}"
            )


class ShearTracker:
    """Tracks the anchor of one contact and returns the shear vector in the sensor frame."""

    def __init__(self, config: ShearTrackerConfig = ShearTrackerConfig()) -> None:
        self.config = config
        self._anchor: np.ndarray | None = None

    @property
    def anchor_object(self) -> np.ndarray | None:
        """The anchor pose (x, y, z mm, Rx, Ry, Rz deg) in the object frame, or None out of contact."""
        return None if self._anchor is None else self._anchor.copy()

    def reset(self) -> None:
        self._anchor = None

    def touch(self, anchor_pose_object: np.ndarray) -> None:
        """Start a contact at a given anchor (used by replay, where the touch pose is known)."""
        self._anchor = np.asarray(anchor_pose_object, dtype=np.float64).copy()

    def update(self, sensor_pose_object: np.ndarray, in_contact: bool) -> np.ndarray:
        """Advance with the sensor's current pose in the object frame; returns the (6,) sensor-frame shear.

        Out of contact the shear is zero and the anchor is cleared; at contact onset the anchor is set here.
        """
        pose = np.asarray(sensor_pose_object, dtype=np.float64)
        if pose.shape != (6,):
            raise ValueError(f"sensor_pose_object must be (x, y, z mm, Rx, Ry, Rz deg), got shape {pose.shape}")
        if not in_contact:
            self._anchor = None
            return np.zeros(6)
        if self._anchor is None:
            self._anchor = pose.copy()
        move = pose - self._anchor
        move[3:] = wrap_deg(move[3:])
        planar = float(np.hypot(move[0], move[1]))
        if planar > self.config.slip_limit_mm:  # slip: drag the anchor behind the sensor
            excess = (planar - self.config.slip_limit_mm) / planar
            self._anchor[:2] += excess * move[:2]
            move[:2] -= excess * move[:2]
        if abs(move[5]) > self.config.slip_limit_deg:
            excess = move[5] - np.sign(move[5]) * self.config.slip_limit_deg
            self._anchor[5] += excess
            move[5] -= excess
        return shear_to_sensor_frame(move, pose[5])


def replay_shear(poses: np.ndarray, moves: np.ndarray, config: ShearTrackerConfig) -> np.ndarray:
    """Shear vectors (sensor frame) of labelled rows: the tracker anchored at ``pose - move``, read at ``pose``."""
    tracker = ShearTracker(config)
    shear = np.empty_like(poses)
    for index, (pose, move) in enumerate(zip(poses, moves)):
        tracker.touch(pose - move)
        shear[index] = tracker.update(pose, in_contact=True)
    return shear
