"""Hardware-in-the-loop camera for edge following: the simulated TacTip on a flat object's edge, wherever the arm is.

:class:`SimEdgeCamera` is :class:`~simshear_gym.real.hil.SimSurfaceCamera`'s twin for ``SimShearEdgeFollow-v0``'s
task: a frame source for :class:`~simshear_gym.real.env.RealTactileEnv` that, on every ``read()``, places the TacTip
at the arm's flange pose (a callable: the emulator's state, or the robot's feedback) over a still flat object
(:mod:`simshear_gym.sim.contours`), measures the contact against its edge
(:func:`~simshear_gym.sim.contours.edge_contact`), tracks the skin's shear (the env's slip limit) and translates the
render with the shipped edge shPix2pix, as the env's ``"real"`` mode does. So ``simshear rollout --camera sim-edge
--controller edge`` closes the real path round an edge: camera -> edge GDNN + filter -> edge law -> TCP/IP ->
emulator -> camera.

Frames (the robot's base frame is the world frame, mm): the object lies so that the sensor at
``start_flange_pose_mm_deg`` sits on the edge at ``EdgeObjectConfig.start_arc_mm`` at the reference depth, centred
on it, its x along the edge (edge angle 0). Ground truth: each read appends a
:class:`~simshear_gym.real.hil.ContactTruth` to :attr:`SimEdgeCamera.history` (``contact_error_mm``: the apex's
distance from the edge, as the env's) and advances :attr:`SimEdgeCamera.progress_mm` (along the edge, clockwise).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from simshear_gym.contract import TacTipMount
from simshear_gym.envs.edge_follow import EDGE_GEOMETRY, EDGE_SHEAR
from simshear_gym.real.camera import PreprocessConfig
from simshear_gym.real.hil import ContactTruth, SimTacTipCamera
from simshear_gym.sim.contours import OUTLINES, Contour, ContourObject, edge_contact, spawn_contour_object
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.sim.shear import ShearTracker
from simshear_gym.transforms import invert, pose_from_matrix_fast, pose_to_matrix


@dataclass(frozen=True)
class EdgeObjectConfig:
    """The flat object the simulated TacTip follows the edge of.

    Attributes:
        outline: one of :data:`~simshear_gym.sim.contours.OUTLINES`.
        size_mm: its nominal radius (half side), mm.
        start_arc_mm: where on the outline the sensor starts (arc length from its first point, ccw), mm.
        reference_depth_mm: the depth the sensor at the start pose has (labels' convention), mm.
        translate: True: the shPix2pix-translated image (what a real TacTip shows); False: the raw sim image.
    """

    outline: str = "disk"
    size_mm: float = 40.0
    start_arc_mm: float = 0.0
    reference_depth_mm: float = 4.0
    translate: bool = True

    def __post_init__(self) -> None:
        if self.outline not in OUTLINES:
            raise ValueError(f"EdgeObjectConfig.outline must be one of {OUTLINES}, got {self.outline!r}")
        if not math.isfinite(self.start_arc_mm):
            raise ValueError(f"EdgeObjectConfig.start_arc_mm must be finite, got {self.start_arc_mm!r}")
        if not SURFACE_DEPTH_MM < self.reference_depth_mm < SURFACE_DEPTH_MM + 5.0:
            raise ValueError(f"EdgeObjectConfig.reference_depth_mm must press the dome into the object: within "
                             f"({SURFACE_DEPTH_MM}, {SURFACE_DEPTH_MM + 5.0}) mm, got {self.reference_depth_mm!r}")
        ContourObject(self.outline, self.size_mm)  # checks the size


class SimEdgeCamera(SimTacTipCamera):
    """A frame source rendering the simulated TacTip over a flat object's edge (see the module docstring).

    Args:
        flange_pose: returns the arm's current flange pose ``(x, y, z mm, R deg)`` in its base frame.
        start_flange_pose_mm_deg: the flange pose at which the sensor sits on the edge at the reference depth.
        config: the object.
        mount, raw_frame_layout, clock: see :class:`~simshear_gym.real.hil.SimTacTipCamera`.
    """

    def __init__(self, flange_pose: Callable[[], object], start_flange_pose_mm_deg,
                 config: EdgeObjectConfig = EdgeObjectConfig(), mount: TacTipMount = TacTipMount(),
                 raw_frame_layout: PreprocessConfig | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(flange_pose, "edge", config.translate, mount, raw_frame_layout, clock,
                         "simulated TacTip camera (edge)")
        self.config = config
        self._T_work_edge = EDGE_GEOMETRY.T_work_stimulus()
        self._T_work_face = np.diag([1.0, -1.0, -1.0, 1.0])  # the object's top face, the labels' surface frame
        self._T_work_face[2, 3] = SURFACE_DEPTH_MM
        self.contour = Contour(ContourObject(config.outline, config.size_mm))
        point, tangent = self.contour.point_at(config.start_arc_mm)
        label = pose_to_matrix(np.array([0.0, EDGE_GEOMETRY.edge_y_mm, config.reference_depth_mm, 0.0, 0.0, 0.0]))
        # T_base_sensor = T_base_object @ T_object_edge @ T_edge_work @ label
        self.T_base_object = self.T_base_sensor_at(start_flange_pose_mm_deg) @ invert(label) @ self._T_work_edge \
            @ invert(self.contour.T_object_edge(point, tangent))
        self._T_object_base = invert(self.T_base_object)
        spawn_contour_object(self.world, self.contour, self.T_base_object)
        self._tracker = ShearTracker(EDGE_SHEAR)
        self._arc_mm: float | None = None
        self.progress_mm = 0.0
        """How far along the edge (clockwise, seen from above) the sensor has gone since the first read, mm."""

    def _touch(self, time_s: float, flange: np.ndarray, T_base_sensor: np.ndarray
               ) -> tuple[np.ndarray, ContactTruth]:
        T_object_sensor = self._T_object_base @ T_base_sensor
        edge = edge_contact(self.contour, T_object_sensor, self._T_work_edge, EDGE_GEOMETRY.edge_y_mm)
        in_contact = edge.touches(self.tactip.config.dome_radius_mm)
        shear = self._tracker.update(pose_from_matrix_fast(self._T_work_face @ T_object_sensor), in_contact)
        if self._arc_mm is not None:
            half = self.contour.perimeter_mm / 2.0
            self.progress_mm += (self._arc_mm - edge.arc_mm + half) % self.contour.perimeter_mm - half
        self._arc_mm = edge.arc_mm
        return shear, ContactTruth(time_s, flange, np.zeros(3), edge.penetration_mm, in_contact,
                                   abs(edge.offset_mm), shear.copy())


__all__ = ["EdgeObjectConfig", "SimEdgeCamera"]
