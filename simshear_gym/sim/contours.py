"""Flat objects with a closed outline, for edge following: the outline, the nearest edge point, the solid's mesh.

An object's frame (mm): origin at the outline's centre on the top face, +z out of the top face; the solid is the
outline extruded ``height_mm`` down. The outline is star-shaped about the origin, given as a radius per polar
angle, and sampled counter-clockwise (seen from above) with points spaced so that no chord strays more than
``max_sag_mm`` from the true curve (straight sides take two points, tight bends many).

The **edge frame** at an outline point is the straight-edge stimulus's frame of the labels
(:class:`~simshear_gym.sim.stimuli.StraightEdge`): origin on the edge, +x along the edge with the material on its
right (clockwise round the outline, seen from above), +y out of the material, +z out of the top face. A sensor's
pose in it, through :meth:`simshear_gym.sim.replay.ReplayGeometry.T_work_stimulus`, is an edge label pose
(offset across the edge, depth, edge angle), so the shipped edge models read the contact as they read the data.

Outlines (:data:`OUTLINES`): ``disk``; ``rounded_square`` (corners of a quarter of the half side);
``clover`` (three lobes, r = R (1 + 0.18 cos 3 phi): concave between the lobes, 0.84 R radius of curvature);
``wavy`` (a disk with six waves, r = R (1 + 0.06 cos 6 phi)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from simshear_gym.transforms import invert, matrix_to_pybullet, pose_from_matrix_fast

if TYPE_CHECKING:
    from simshear_gym.sim.world import World

OUTLINES: tuple[str, ...] = ("disk", "rounded_square", "clover", "wavy")


def _radius_mm(outline: str, size_mm: float, phi: np.ndarray) -> np.ndarray:
    """Radius of the outline at polar angles ``phi`` (rad); ``size_mm`` its nominal radius (half side)."""
    if outline == "disk":
        return np.full_like(phi, size_mm)
    if outline == "clover":
        return size_mm * (1.0 + 0.18 * np.cos(3.0 * phi))
    if outline == "wavy":
        return size_mm * (1.0 + 0.06 * np.cos(6.0 * phi))
    if outline == "rounded_square":
        # a square of half side a with corner radius c: the ray at phi meets its boundary
        a, c = size_mm, size_mm / 4.0
        u, v = np.abs(np.cos(phi)), np.abs(np.sin(phi))
        flat = a / np.maximum(u, v)  # on a flat side
        # in the corner region the ray meets the circle of radius c centred at (a - c, a - c)
        b = (a - c) * (u + v)
        corner = b + np.sqrt(np.maximum(b * b - 2.0 * (a - c) ** 2 + c * c, 0.0))
        in_corner = (flat * u > a - c) & (flat * v > a - c)
        return np.where(in_corner, corner, flat)
    raise ValueError(f"unknown outline {outline!r}; expected one of {OUTLINES}")


@dataclass(frozen=True)
class ContourObject:
    """A flat object with a closed outline: ``outline`` (one of :data:`OUTLINES`), nominal radius (or half side)
    ``size_mm``, thickness ``height_mm``; the outline sampled to within ``max_sag_mm`` of the curve."""

    outline: str = "disk"
    size_mm: float = 40.0
    height_mm: float = 20.0
    max_sag_mm: float = 0.01

    def __post_init__(self) -> None:
        if self.outline not in OUTLINES:
            raise ValueError(f"ContourObject.outline must be one of {OUTLINES}, got {self.outline!r}")
        if not (20.0 <= self.size_mm <= 80.0):
            raise ValueError(f"ContourObject.size_mm must be in [20, 80] mm (the MG400's reach round the object, "
                             f"and curves the 20 mm dome can follow), got {self.size_mm!r}")
        if not (self.height_mm > 0 and self.max_sag_mm > 0):
            raise ValueError(f"ContourObject: height_mm and max_sag_mm must be > 0, got {self}")


class Contour:
    """The sampled outline of a :class:`ContourObject` in its object frame, and where a point lies against it.

    Attributes:
        points_mm: (N, 2) outline points, counter-clockwise, not closed (the last joins the first).
        perimeter_mm: the outline's length.
    """

    def __init__(self, spec: ContourObject) -> None:
        self.spec = spec
        dense = 20000
        phi = np.linspace(0.0, 2.0 * np.pi, dense, endpoint=False)
        radius = _radius_mm(spec.outline, spec.size_mm, phi)
        curve = np.stack([radius * np.cos(phi), radius * np.sin(phi)], axis=1)
        self.points_mm = _thin(curve, spec.max_sag_mm)
        self._start = self.points_mm
        self._segment = np.roll(self.points_mm, -1, axis=0) - self.points_mm
        self._length = np.linalg.norm(self._segment, axis=1)
        self._cumulative = np.concatenate([[0.0], np.cumsum(self._length)[:-1]])
        self.perimeter_mm = float(self._length.sum())
        direction = self._segment / self._length[:, None]
        vertex = direction + np.roll(direction, 1, axis=0)  # at each point, between its two segments
        self._vertex_tangent = vertex / np.linalg.norm(vertex, axis=1)[:, None]

    def _tangent(self, index: int, t: float) -> np.ndarray:
        """The unit tangent at ``t`` along segment ``index``, blended between its ends' (continuous round the
        outline, so an angle read off it does not jump by a segment's turn)."""
        blend = (1.0 - t) * self._vertex_tangent[index] + t * self._vertex_tangent[(index + 1) % len(self._length)]
        return blend / float(np.hypot(*blend))

    def nearest(self, point_mm: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
        """For a point (x, y mm, object frame): (arc length of the nearest outline point from the first,
        counter-clockwise, mm; signed distance, + inside the material, mm; that outline point (2,);
        the unit tangent there, counter-clockwise (2,))."""
        p = np.asarray(point_mm, dtype=np.float64)[:2]
        t = np.clip(((p - self._start) * self._segment).sum(axis=1) / self._length ** 2, 0.0, 1.0)
        foot = self._start + t[:, None] * self._segment
        distance = np.hypot(*(p - foot).T)
        index = int(np.argmin(distance))
        tangent = self._tangent(index, float(t[index]))
        offset = p - foot[index]
        chord = self._segment[index]
        inside = chord[0] * offset[1] - chord[1] * offset[0]  # the left of a ccw segment is the material
        signed = math.copysign(float(distance[index]), inside)
        return (float(self._cumulative[index] + t[index] * self._length[index]), signed, foot[index].copy(),
                tangent)

    def point_at(self, arc_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """(outline point (2,), its ccw unit tangent (2,)) at an arc length from the first point."""
        arc = float(arc_mm) % self.perimeter_mm
        index = int(np.searchsorted(self._cumulative, arc, side="right") - 1)
        t = (arc - self._cumulative[index]) / self._length[index]
        return self._start[index] + t * self._segment[index], self._tangent(index, t)

    def T_object_edge(self, point_mm: np.ndarray, tangent_ccw: np.ndarray) -> np.ndarray:
        """4x4 edge frame (module docstring) at an outline point with its ccw tangent, in the object frame."""
        x_axis = -np.array([tangent_ccw[0], tangent_ccw[1], 0.0])  # clockwise: the material on the right
        z_axis = np.array([0.0, 0.0, 1.0])
        transform = np.eye(4)
        transform[:3, 0], transform[:3, 1], transform[:3, 2] = x_axis, np.cross(z_axis, x_axis), z_axis
        transform[:2, 3] = point_mm
        return transform


@dataclass(frozen=True)
class EdgeContact:
    """Where a sensor is against an outline's edge (mm, deg).

    Attributes:
        label_pose: (6,) the sensor's pose as an edge label (x, y = the edge line's y + the offset, z = the depth,
            Rx, Ry, Rz = the edge angle), in the labels' work frame of the nearest edge point.
        offset_mm: the apex's distance from the outline in the top face's plane, + over the material.
        penetration_mm: the apex below the top face (negative: above it).
        arc_mm: the nearest outline point's arc length from the first point, counter-clockwise.
        point_mm: (2,) that point, object frame.
    """

    label_pose: np.ndarray
    offset_mm: float
    penetration_mm: float
    arc_mm: float
    point_mm: np.ndarray

    def touches(self, dome_radius_mm: float) -> bool:
        """Whether a dome of that radius, pressed this deep, reaches the material: the edge lies within the
        circle where the dome cuts the top face's plane."""
        depth = self.penetration_mm
        footprint_mm = math.sqrt(max(2.0 * dome_radius_mm * depth - depth * depth, 0.0))
        return depth > 0.0 and self.offset_mm > -footprint_mm


def edge_contact(contour: Contour, T_object_sensor: np.ndarray, T_work_edge: np.ndarray,
                 edge_y_mm: float) -> EdgeContact:
    """The sensor (pose in the object frame, 4x4 mm) against the outline's nearest edge; ``T_work_edge`` and
    ``edge_y_mm``: where the edge lies in the labels' work frame (``ReplayGeometry.T_work_stimulus()`` and its
    ``edge_y_mm``)."""

    arc, _, point, tangent = contour.nearest(T_object_sensor[:2, 3])
    T_edge_sensor = invert(contour.T_object_edge(point, tangent)) @ T_object_sensor
    label = pose_from_matrix_fast(T_work_edge @ T_edge_sensor)
    return EdgeContact(label, float(label[1] - edge_y_mm), -float(T_edge_sensor[2, 3]), arc, point)


def _thin(curve: np.ndarray, max_sag_mm: float) -> np.ndarray:
    """Points of a dense closed curve (M, 2) kept so that every dropped point lies within ``max_sag_mm`` of the
    chord that replaces it (greedy, walking round once)."""
    kept = [0]
    count = len(curve)
    index = 0
    while index < count - 1:
        best = index + 1
        for candidate in range(index + 2, count + 1):
            end = curve[candidate % count]
            chord = end - curve[index]
            length = float(np.hypot(*chord))
            between = curve[index + 1:candidate]
            sag = np.abs(chord[0] * (between[:, 1] - curve[index, 1]) - chord[1] * (between[:, 0] - curve[index, 0]))
            if length == 0 or float(sag.max()) / length > max_sag_mm:
                break
            best = candidate
        if best >= count:
            break
        kept.append(best)
        index = best
    return curve[kept].copy()


def spawn_contour_object(world: World, contour: Contour, T_world_object: np.ndarray) -> int:
    """The object as a static visual body (the TacTip's renderer sees visual shapes): its top face (a fan from the
    centre, which the outline is star-shaped about) and side walls; returns its id."""
    return spawn_extruded(world, contour.points_mm, contour.spec.height_mm, T_world_object)


def spawn_extruded(world: World, points_mm: np.ndarray, height_mm: float, T_world_object: np.ndarray,
                   rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)) -> int:
    """A static visual body extruded from a closed outline (``points_mm`` (N, 2), counter-clockwise, star-shaped
    about the origin): its top face at z = 0 (a fan from the origin) and side walls down to ``-height_mm``; returns
    its id."""
    import pybullet

    points = np.asarray(points_mm, dtype=np.float64)
    count = len(points)
    vertices = np.vstack([[0.0, 0.0, 0.0], np.c_[points, np.zeros(count)],
                          np.c_[points, np.full(count, -float(height_mm))]]) / 1000.0
    indices = []
    for i in range(count):
        j = (i + 1) % count
        indices += [0, 1 + i, 1 + j, 1 + i, 1 + count + i, 1 + j, 1 + j, 1 + count + i, 1 + count + j]
    client = world.client
    visual = client.createVisualShape(pybullet.GEOM_MESH, vertices=vertices.tolist(), indices=indices,
                                      rgbaColor=list(rgba))
    position_m, quaternion = matrix_to_pybullet(np.asarray(T_world_object, dtype=np.float64))
    return client.createMultiBody(baseMass=0.0, baseVisualShapeIndex=visual, basePosition=position_m,
                                  baseOrientation=quaternion)


__all__ = ["OUTLINES", "Contour", "ContourObject", "EdgeContact", "edge_contact", "spawn_contour_object",
           "spawn_extruded"]
