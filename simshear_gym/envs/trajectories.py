"""Leader trajectories: how the plate (or a held object) moves from its start, at constant speed along a path.

A trajectory is an offset from the start pose as a function of time: ``(dx_mm, dy_mm, dz_mm, dr_deg)``, the
translation in world axes and the rotation about the vertical through the moved frame's origin. The paths
(scale 1, all starting at the origin):

=================  ==========================================================================  ===========
name               path                                                                        length, mm
=================  ==========================================================================  ===========
``circle``         horizontal circle, radius 25 mm, one turn                                   157
``tilted_square``  square of side 40 mm in a plane tilted by ``tilt_deg`` (30) about world x   160
``spiral``         upward spiral: radius 20 mm, 1.5 turns, rising 30 mm                        191
``loop``           looped line (prolate cycloid): 2 loops of radius 12 mm, 25 mm pitch         155
``circular_wave``  co-lift: horizontal circle, radius 25 mm, one turn, with 3 vertical waves    191
                   of amplitude 8 mm riding on it (the grip axis is world x: the circle moves
                   the object along the grip and across it, the waves lift and lower it)
``star``           co-lift: five-pointed star outline (10 edges) in the vertical world y-z      182
                   plane (parallel to the co-lift plate), outer radius 25 mm, inner 9.5 mm,
                   pointing up; starts at the lower-left point, so it first lifts the object
=================  ==========================================================================  ===========

:data:`TRAJECTORIES` are the tracking env's, :data:`COLIFT_TRAJECTORIES` the co-lift env's; a
:class:`TrajectoryConfig` accepts either (:data:`ALL_TRAJECTORIES`).

The plate itself stays level along every path (the MG400 flange is level); "tilted" is the plane of the
square's corners. Along the path the frame turns about the vertical by ``rotation_deg * sin(2 pi s)``, with
``s`` in [0, 1] the fraction of the path travelled. The speed along the path is constant (``speed_mm_s``);
after the end the trajectory holds its final pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TRAJECTORIES: tuple[str, ...] = ("circle", "tilted_square", "spiral", "loop")
COLIFT_TRAJECTORIES: tuple[str, ...] = ("circular_wave", "star")
ALL_TRAJECTORIES: tuple[str, ...] = TRAJECTORIES + COLIFT_TRAJECTORIES
_SAMPLES = 4001  # path samples for the arc-length table; spacing < 0.1 mm at scale 1


@dataclass(frozen=True)
class TrajectoryConfig:
    """One leader trajectory.

    Attributes:
        name: one of :data:`TRAJECTORIES` or :data:`COLIFT_TRAJECTORIES`.
        scale: multiplies the path's size (not its speed).
        speed_mm_s: speed along the path.
        rotation_deg: amplitude of the rotation about the vertical (signed).
        tilt_deg: tilt of the tilted square's plane about world x.
    """

    name: str = "circle"
    scale: float = 1.0
    speed_mm_s: float = 4.0
    rotation_deg: float = 15.0
    tilt_deg: float = 30.0

    def __post_init__(self) -> None:
        if self.name not in ALL_TRAJECTORIES:
            raise ValueError(f"unknown trajectory {self.name!r}; expected one of {ALL_TRAJECTORIES}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"trajectory scale must be > 0, got {self.scale!r}")
        if not (math.isfinite(self.speed_mm_s) and self.speed_mm_s > 0):
            raise ValueError(f"trajectory speed_mm_s must be > 0, got {self.speed_mm_s!r}")
        if not (math.isfinite(self.rotation_deg) and abs(self.rotation_deg) <= 90.0):
            raise ValueError(f"trajectory rotation_deg must be within [-90, 90] deg, got {self.rotation_deg!r}")
        if not (math.isfinite(self.tilt_deg) and abs(self.tilt_deg) < 90.0):
            raise ValueError(f"trajectory tilt_deg must be within (-90, 90) deg, got {self.tilt_deg!r}")


def path_points_mm(config: TrajectoryConfig, s: np.ndarray) -> np.ndarray:
    """Points (N, 3) in mm of the path at parameters ``s`` in [0, 1] (not arc length); starts at the origin."""
    s = np.asarray(s, dtype=np.float64)
    k = config.scale
    if config.name == "circle":
        radius, theta = 25.0 * k, 2.0 * np.pi * s
        return np.stack([radius * (np.cos(theta) - 1.0), radius * np.sin(theta), np.zeros_like(s)], axis=-1)
    if config.name == "spiral":
        radius, theta = 20.0 * k, 3.0 * np.pi * s
        return np.stack([radius * (np.cos(theta) - 1.0), radius * np.sin(theta), 30.0 * k * s], axis=-1)
    if config.name == "loop":
        radius, pitch, theta = 12.0 * k, 25.0 * k, 4.0 * np.pi * s
        return np.stack([pitch * theta / (2.0 * np.pi) - radius * np.sin(theta), radius * (1.0 - np.cos(theta)),
                         np.zeros_like(s)], axis=-1)
    if config.name == "circular_wave":
        radius, amplitude, theta = 25.0 * k, 8.0 * k, 2.0 * np.pi * s
        return np.stack([radius * (np.cos(theta) - 1.0), radius * np.sin(theta), amplitude * np.sin(3.0 * theta)],
                        axis=-1)
    if config.name == "star":
        return _polyline(_star_corners_yz(25.0 * k), s)
    # tilted_square: corners (0,0) (a,0) (a,a) (0,a) in the plane's (u, v), v tilted about world x
    side = 40.0 * k
    uv = _polyline(np.array([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side], [0.0, 0.0]]), s)
    tilt = math.radians(config.tilt_deg)
    return np.stack([uv[..., 0], uv[..., 1] * math.cos(tilt), uv[..., 1] * math.sin(tilt)], axis=-1)


def _star_corners_yz(outer_mm: float) -> np.ndarray:
    """The 11 corners (closed) of an upward five-pointed star's outline in world (x=0, y, z), from its lower-left
    point anticlockwise seen from +x; the inner corners lie on the pentagram's inner pentagon."""
    inner_mm = outer_mm * math.sin(math.radians(18.0)) / math.sin(math.radians(126.0))
    angles = np.radians(234.0 + 36.0 * np.arange(11))
    radii = np.where(np.arange(11) % 2 == 0, outer_mm, inner_mm)
    corners = np.stack([np.zeros(11), radii * np.cos(angles), radii * np.sin(angles)], axis=-1)
    return corners - corners[0]


def _polyline(corners: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at parameters ``s`` in [0, 1] along a polyline whose edges (all equally long) share s equally."""
    edges = len(corners) - 1
    position = np.clip(s, 0.0, 1.0) * edges
    edge = np.minimum(position.astype(int), edges - 1)
    fraction = (position - edge)[..., None]
    return corners[edge] + fraction * (corners[edge + 1] - corners[edge])


class Trajectory:
    """A :class:`TrajectoryConfig` sampled once into an arc-length table; :meth:`offset_at` is cheap."""

    def __init__(self, config: TrajectoryConfig) -> None:
        self.config = config
        s = np.linspace(0.0, 1.0, _SAMPLES)
        self._points = path_points_mm(config, s)
        steps = np.linalg.norm(np.diff(self._points, axis=0), axis=1)
        self._arc_mm = np.concatenate([[0.0], np.cumsum(steps)])

    @property
    def length_mm(self) -> float:
        return float(self._arc_mm[-1])

    @property
    def duration_s(self) -> float:
        """Time to the end of the path; the trajectory holds its last pose afterwards."""
        return self.length_mm / self.config.speed_mm_s

    def offset_at(self, time_s: float) -> np.ndarray:
        """``(dx_mm, dy_mm, dz_mm, dr_deg)`` from the start pose at ``time_s`` (world axes; rotation about the
        vertical)."""
        arc = min(max(time_s, 0.0) * self.config.speed_mm_s, self.length_mm)
        index = int(np.searchsorted(self._arc_mm, arc, side="right")) - 1
        index = min(max(index, 0), len(self._arc_mm) - 2)
        span = self._arc_mm[index + 1] - self._arc_mm[index]
        weight = 0.0 if span <= 0.0 else (arc - self._arc_mm[index]) / span
        point = self._points[index] + weight * (self._points[index + 1] - self._points[index])
        fraction = arc / self.length_mm
        return np.array([point[0], point[1], point[2], self.config.rotation_deg * math.sin(2.0 * math.pi * fraction)])

    def path_mm(self) -> np.ndarray:
        """The sampled path, (N, 3) mm, for drawing."""
        return self._points.copy()
