"""Hardware-in-the-loop camera for pushing: the simulated TacTip against an object it pushes across a table.

:class:`SimPushCamera` is :class:`~simshear_gym.real.hil_edge.SimEdgeCamera`'s twin for ``SimShearPush-v0``'s task: a
frame source for :class:`~simshear_gym.real.env.RealTactileEnv` that, on every ``read()``, places the horizontal
TacTip at the arm's flange pose (a callable: the emulator's state, or the robot's feedback), lets the object yield to
it (:class:`~simshear_gym.sim.pushing.PushedObject`: the env's quasi-static pushing), and renders and translates
the contact with the shipped surface shPix2pix and the skin's shear, as the env's ``"real"`` mode does. So
``simshear rollout --camera sim-push --controller push`` closes the real path of pushing: camera -> surface GDNN +
filter -> push law -> TCP/IP -> emulator -> camera.

Frames (the robot's base frame is the world frame, mm): the object stands so that the sensor at
``start_flange_pose_mm_deg`` touches the middle of its face 0, square to it, at the reference depth; the table's
top lies half the object's height below the sensor's axis. Ground truth: each read appends a
:class:`~simshear_gym.real.hil.ContactTruth` to :attr:`SimPushCamera.history` (``surface_offset_mm``: the object's
displacement since the start; ``contact_error_mm``: its centre's distance from the straight path to
``PushObjectConfig.target_xy_mm``, where one is given, else 0).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from simshear_gym.contract import HorizontalTacTipMount
from simshear_gym.real.camera import PreprocessConfig
from simshear_gym.real.hil import ContactTruth, SimTacTipCamera
from simshear_gym.sim.pushing import (
    HEIGHT_MM,
    PUSH_SHAPES,
    PushedObject,
    PushPhysicsConfig,
    push_shape,
    spawn_push_object,
)
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.transforms import matrix_to_pybullet_fast


@dataclass(frozen=True)
class PushObjectConfig:
    """The object the simulated TacTip pushes.

    Attributes:
        shape: one of :data:`~simshear_gym.sim.pushing.PUSH_SHAPES`.
        physics: its mass and frictions (:class:`~simshear_gym.sim.pushing.PushPhysicsConfig`).
        reference_depth_mm: the depth of the first touch (labels' convention), mm.
        target_xy_mm: the target (base frame x, y mm) the truth's path deviation is measured against; None: none.
        translate: True: the shPix2pix-translated image (what a real TacTip shows); False: the raw sim image.
    """

    shape: str = "cube"
    physics: PushPhysicsConfig = PushPhysicsConfig()
    reference_depth_mm: float = 2.6
    target_xy_mm: tuple[float, float] | None = None
    translate: bool = True

    def __post_init__(self) -> None:
        if self.shape not in PUSH_SHAPES:
            raise ValueError(f"PushObjectConfig.shape must be one of {PUSH_SHAPES}, got {self.shape!r}")
        if not SURFACE_DEPTH_MM < self.reference_depth_mm < SURFACE_DEPTH_MM + 4.0:
            raise ValueError(f"PushObjectConfig.reference_depth_mm must press the dome into the object: within "
                             f"({SURFACE_DEPTH_MM}, {SURFACE_DEPTH_MM + 4.0}) mm, got {self.reference_depth_mm!r}")


class SimPushCamera(SimTacTipCamera):
    """A frame source rendering the simulated TacTip against an object it pushes (see the module docstring).

    Args:
        flange_pose: returns the arm's current flange pose ``(x, y, z mm, R deg)`` in its base frame.
        start_flange_pose_mm_deg: the flange pose at which the sensor touches the object at the reference depth.
        config: the object.
        mount: the horizontal TacTip on the flange.
        raw_frame_layout, clock: see :class:`~simshear_gym.real.hil.SimTacTipCamera`.
    """

    def __init__(self, flange_pose: Callable[[], object], start_flange_pose_mm_deg,
                 config: PushObjectConfig = PushObjectConfig(), mount: HorizontalTacTipMount = HorizontalTacTipMount(),
                 raw_frame_layout: PreprocessConfig | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        if not isinstance(mount, HorizontalTacTipMount):
            raise ValueError(f"the pushing TacTip lies horizontally: mount must be a HorizontalTacTipMount, got "
                             f"{type(mount).__name__}")
        super().__init__(flange_pose, "surface", config.translate, mount, raw_frame_layout, clock,
                         "simulated TacTip camera (push)")
        self.config = config
        T_base_sensor = self.T_base_sensor_at(start_flange_pose_mm_deg)
        apex, axis = T_base_sensor[:3, 3], T_base_sensor[:3, 2]
        shape = push_shape(config.shape)
        r = self.tactip.config.dome_radius_mm
        # the dome's sphere (centre r behind the apex) sinks the indentation into face 0, square to the axis
        face = apex - r * axis + (r - (config.reference_depth_mm - SURFACE_DEPTH_MM)) * axis
        centre = face + shape.half_width_mm() * axis
        yaw = math.atan2(-axis[1], -axis[0])  # face 0's normal (object +x) against the push
        self.object = PushedObject(shape, config.physics, r, float(apex[2]) - HEIGHT_MM / 2.0,
                                   (float(centre[0]), float(centre[1]), yaw))
        self.object.place(self.object.pose, T_base_sensor)
        self._start_xy = np.array(self.object.pose[:2])
        self._body = spawn_push_object(self.world, shape, self.object.T_world_object())

    def target_distance_mm(self) -> float | None:
        """The object's centre's distance from the target now (None without a target)."""
        if self.config.target_xy_mm is None:
            return None
        return float(np.linalg.norm(np.asarray(self.object.pose[:2]) - np.asarray(self.config.target_xy_mm)))

    def _path_deviation_mm(self) -> float:
        if self.config.target_xy_mm is None:
            return 0.0
        path = np.asarray(self.config.target_xy_mm) - self._start_xy
        direction = path / max(float(np.linalg.norm(path)), 1e-9)
        offset = np.asarray(self.object.pose[:2]) - self._start_xy
        return abs(float(offset[0] * direction[1] - offset[1] * direction[0]))

    def _touch(self, time_s: float, flange: np.ndarray, T_base_sensor: np.ndarray
               ) -> tuple[np.ndarray, ContactTruth]:
        self.object.push(T_base_sensor)
        self.world.client.resetBasePositionAndOrientation(self._body,
                                                          *matrix_to_pybullet_fast(self.object.T_world_object()))
        shear = self.object.shear_sensor(T_base_sensor)
        moved = np.r_[np.asarray(self.object.pose[:2]) - self._start_xy, 0.0]
        return shear, ContactTruth(time_s, flange, moved, self.object.penetration_mm(T_base_sensor),
                                   self.object.contact() is not None, self._path_deviation_mm(), shear.copy())


__all__ = ["PushObjectConfig", "SimPushCamera"]
