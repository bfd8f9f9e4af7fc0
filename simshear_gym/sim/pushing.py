"""Quasi-static planar pushing: a TacTip's dome pushes a block across a table, its skin sticking or slipping.

Objects (:data:`PUSH_SHAPES`): a 50 mm ``cube``, a ``cylinder`` of 25 mm radius and a ``prism`` (equilateral
triangle, 60 mm sides), each 40 mm tall, lying on a table. Slow pushing (a few mm/s) is quasi-static: inertia is
negligible and the object moves only when the contact's wrench reaches the table's friction limit.

Frames (mm, world z up): the **object** frame has its origin at the outline's centre on the top face, z up; the
object's planar pose is ``(x, y mm, yaw rad)`` of that frame in the world, its top face at ``table_z_mm + 40``.

The model, per sub-step of the apex's motion (:meth:`PushedObject.push`):

* **The dome** is a sphere of the dome's radius behind the apex; its penetration into the object's side, along
  the outward normal of the nearest face, is the contact's indentation ``p``, and the normal force ``k_n p``
  (``normal_stiffness_n_per_mm``: a TacTip's few newtons over a few millimetres).
* **The skin** sticks to the object at an anchor set when the contact starts; the sensor's displacement from the
  anchor, along the face, stretches it: a tangential force ``k_t e`` on the object, and the **shear** the image
  shows (the sensor's displacement from where it touched, as :class:`~simshear_gym.sim.shear.ShearTracker`
  defines it). When ``k_t |e|`` exceeds ``contact_friction * k_n p`` the skin slips: the anchor is dragged so the
  stretch stays on the friction cone.
* **The table** resists with the friction limit surface of a uniform pressure under the object (an ellipsoid:
  ``(fx^2 + fy^2) / f_max^2 + m^2 / (c f_max)^2 <= 1``, ``f_max = table_friction * m g``, ``c`` the mean distance
  of the footprint from its centre of pressure). While the contact's wrench lies inside it, nothing moves; beyond
  it the object slides along the surface's normal (twist ``(fx, fy, m / c^2)``: Lynch, Maekawa and Tanie's
  quasi-static pushing) just far enough that the wrench returns to the surface.

So a push through the centre of pressure slides the object straight; off it, the object turns, and the turn drags
the skin sideways before the face's tilt against the sensor grows: the shear shows the object's turn and slip
first. Heavier or stickier objects are pushed at a larger indentation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PUSH_SHAPES: tuple[str, ...] = ("cube", "cylinder", "prism")
HEIGHT_MM = 40.0
GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class PushShape:
    """An object's outline: convex polygon faces (outward unit normal, distance from the centre) or a circle.

    Attributes:
        name: one of :data:`PUSH_SHAPES`.
        faces: ``((nx, ny, h), ...)`` of a polygon; empty for the cylinder.
        radius_mm: the cylinder's radius (0 for a polygon).
    """

    name: str
    faces: tuple[tuple[float, float, float], ...] = ()
    radius_mm: float = 0.0

    def distance(self, x_mm: float, y_mm: float) -> tuple[float, float, float]:
        """Signed distance of an object-frame point from the outline (negative inside) and the outward normal of
        the nearest face there ``(d, nx, ny)`` (for a polygon, the face of the largest signed distance)."""
        if self.radius_mm > 0.0:
            r = math.hypot(x_mm, y_mm)
            if r < 1e-9:
                return -self.radius_mm, 1.0, 0.0
            return r - self.radius_mm, x_mm / r, y_mm / r
        best = -math.inf
        normal = (1.0, 0.0)
        for nx, ny, h in self.faces:
            d = nx * x_mm + ny * y_mm - h
            if d > best:
                best, normal = d, (nx, ny)
        return best, normal[0], normal[1]

    def outline_mm(self, count: int = 72) -> np.ndarray:
        """(N, 2) counter-clockwise outline points (the polygon's corners, or ``count`` points of the circle)."""
        if self.radius_mm > 0.0:
            angles = np.linspace(0.0, 2.0 * math.pi, count, endpoint=False)
            return self.radius_mm * np.c_[np.cos(angles), np.sin(angles)]
        corners = []
        for (n1x, n1y, h1), (n2x, n2y, h2) in zip(self.faces, self.faces[1:] + self.faces[:1]):
            det = n1x * n2y - n1y * n2x
            corners.append(((h1 * n2y - h2 * n1y) / det, (n1x * h2 - n2x * h1) / det))
        return np.asarray(corners)

    def half_width_mm(self) -> float:
        """The centre's distance from a face (the cylinder's radius, a polygon's inradius)."""
        return self.radius_mm if self.radius_mm > 0.0 else min(h for _, _, h in self.faces)


def push_shape(name: str) -> PushShape:
    """The shape named ``name`` (:data:`PUSH_SHAPES`); its face at angle 0 (normal +x) is the one pushed at reset."""
    if name == "cube":
        return PushShape(name, tuple((math.cos(a), math.sin(a), 25.0) for a in np.radians([0, 90, 180, 270])))
    if name == "cylinder":
        return PushShape(name, radius_mm=25.0)
    if name == "prism":
        inradius = 60.0 / (2.0 * math.sqrt(3.0))
        return PushShape(name, tuple((math.cos(a), math.sin(a), inradius) for a in np.radians([0, 120, 240])))
    raise ValueError(f"unknown push shape {name!r}; expected one of {PUSH_SHAPES}")


@dataclass(frozen=True)
class PushPhysicsConfig:
    """The contact and the table (see the module docstring).

    Attributes:
        mass_kg: the object's mass.
        table_friction: object-table friction coefficient.
        contact_friction: skin-object friction coefficient (the skin slips beyond it).
        centre_of_pressure_mm: the footprint's centre of pressure (where the weight bears) in the object frame.
        normal_stiffness_n_per_mm: the dome's stiffness along the face normal.
        shear_stiffness_n_per_mm: the skin's stiffness along the face.
        max_substep_mm: the apex's largest move per mechanics sub-step.
    """

    mass_kg: float = 0.15
    table_friction: float = 0.3
    contact_friction: float = 0.8
    centre_of_pressure_mm: tuple[float, float] = (0.0, 0.0)
    normal_stiffness_n_per_mm: float = 0.5
    shear_stiffness_n_per_mm: float = 0.25
    max_substep_mm: float = 0.25

    def __post_init__(self) -> None:
        for name in ("mass_kg", "table_friction", "contact_friction", "normal_stiffness_n_per_mm",
                     "shear_stiffness_n_per_mm", "max_substep_mm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"PushPhysicsConfig.{name} must be a finite number > 0, got {value!r}")
        if len(self.centre_of_pressure_mm) != 2 or not all(math.isfinite(v) for v in self.centre_of_pressure_mm):
            raise ValueError(f"PushPhysicsConfig.centre_of_pressure_mm must be (x, y) mm, got "
                             f"{self.centre_of_pressure_mm!r}")

    @property
    def friction_limit_n(self) -> float:
        """The largest force the table's friction resists, N."""
        return self.table_friction * self.mass_kg * GRAVITY_M_S2


def torque_arm_mm(shape: PushShape, centre_mm: tuple[float, float], samples: int = 64) -> float:
    """``c`` of the limit surface: the mean distance of the footprint (uniform pressure) from ``centre_mm``."""
    half = shape.radius_mm if shape.radius_mm > 0 else max(np.linalg.norm(shape.outline_mm(), axis=1))
    grid = np.linspace(-half, half, samples)
    x, y = np.meshgrid(grid, grid)
    inside = np.array([shape.distance(px, py)[0] <= 0.0 for px, py in zip(x.ravel(), y.ravel())])
    distances = np.hypot(x.ravel()[inside] - centre_mm[0], y.ravel()[inside] - centre_mm[1])
    return float(distances.mean())


@dataclass(frozen=True)
class DomeContact:
    """The dome against the object now (object frame, mm): indentation, the nearest face's outward normal, the
    contact point, the skin's stretch along the face (sensor minus anchor, 3D) and the forces on the object."""

    penetration_mm: float
    normal: tuple[float, float]
    point_mm: tuple[float, float]
    stretch_mm: tuple[float, float, float]
    force_n: tuple[float, float]
    moment_n_mm: float


class PushedObject:
    """One object on the table, pushed by the dome (see the module docstring). ``pose`` is its planar pose
    ``(x, y mm, yaw rad)`` in the world; :meth:`push` moves it for the apex's motion."""

    def __init__(self, shape: PushShape, config: PushPhysicsConfig, dome_radius_mm: float, table_z_mm: float,
                 pose: tuple[float, float, float]) -> None:
        if not dome_radius_mm > 0:
            raise ValueError(f"dome_radius_mm must be > 0, got {dome_radius_mm!r}")
        self.shape = shape
        self.config = config
        self.dome_radius_mm = float(dome_radius_mm)
        self.table_z_mm = float(table_z_mm)
        self.pose = tuple(float(v) for v in pose)
        self._c_mm = torque_arm_mm(shape, config.centre_of_pressure_mm)
        self._anchor: tuple[float, float, float] | None = None
        self._apex: np.ndarray | None = None
        self._axis: np.ndarray | None = None
        self.slipping = False

    def T_world_object(self) -> np.ndarray:
        """The object frame (top face centre, z up) in the world."""
        x, y, yaw = self.pose
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, self.table_z_mm + HEIGHT_MM],
                         [0.0, 0.0, 0.0, 1.0]])

    def _to_object(self, pose, point) -> tuple[float, float]:
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = point[0] - x, point[1] - y
        return c * dx + s * dy, -s * dx + c * dy

    def _contact(self, pose, apex, axis, anchor) -> DomeContact | None:
        """The contact at an object pose for the apex (world, 3) and sensor axis (world, 3); ``anchor`` the
        skin's, None: where it would touch now."""
        r = self.dome_radius_mm
        centre = (apex[0] - r * axis[0], apex[1] - r * axis[1])
        cx, cy = self._to_object(pose, centre)
        d, nx, ny = self.shape.distance(cx, cy)
        penetration = r - d
        if penetration <= 0.0 or not (self.table_z_mm < apex[2] < self.table_z_mm + HEIGHT_MM):
            return None
        px, py = cx - d * nx, cy - d * ny
        ax, ay = self._to_object(pose, apex)
        z_rel = apex[2] - (self.table_z_mm + HEIGHT_MM)
        if anchor is None:  # where the skin would stick now: under the apex, no stretch
            anchor = (ax, ay, z_rel)
        ex, ey, ez = ax - anchor[0], ay - anchor[1], z_rel - anchor[2]
        along_normal = ex * nx + ey * ny
        ex, ey = ex - along_normal * nx, ey - along_normal * ny
        k_n, k_t = self.config.normal_stiffness_n_per_mm, self.config.shear_stiffness_n_per_mm
        fx, fy = -k_n * penetration * nx + k_t * ex, -k_n * penetration * ny + k_t * ey
        cop = self.config.centre_of_pressure_mm
        moment = (px - cop[0]) * fy - (py - cop[1]) * fx
        return DomeContact(penetration, (nx, ny), (px, py), (ex, ey, ez), (fx, fy), moment)

    def contact(self) -> DomeContact | None:
        """The contact at the last pushed apex pose (None: not touching)."""
        if self._apex is None:
            return None
        return self._contact(self.pose, self._apex, self._axis, self._anchor)

    def _load(self, contact: DomeContact) -> float:
        fx, fy = contact.force_n
        f = self.config.friction_limit_n
        return (fx * fx + fy * fy) / (f * f) + (contact.moment_n_mm / (self._c_mm * f)) ** 2

    def _slip(self, apex, axis) -> None:
        """Drag the skin's anchor so its stretch stays within the friction cone."""
        contact = self._contact(self.pose, apex, axis, self._anchor)
        if contact is None:
            self._anchor = None
            return
        if self._anchor is None:
            ax, ay = self._to_object(self.pose, apex)
            self._anchor = (ax, ay, apex[2] - self.table_z_mm - HEIGHT_MM)
            return
        ex, ey, ez = contact.stretch_mm
        stretch = math.sqrt(ex * ex + ey * ey + ez * ez)
        limit = self.config.contact_friction * self.config.normal_stiffness_n_per_mm * contact.penetration_mm
        limit /= self.config.shear_stiffness_n_per_mm
        if stretch > limit:
            excess = 1.0 - limit / stretch
            ax, ay, az = self._anchor
            self._anchor = (ax + excess * ex, ay + excess * ey, az + excess * ez)
            self.slipping = True

    def _yield(self, apex, axis) -> None:
        """Slide the object along the limit surface's normal until the wrench is back on the surface."""
        contact = self._contact(self.pose, apex, axis, self._anchor)
        if contact is None or self._load(contact) <= 1.0:
            return
        x0, y0, yaw0 = self.pose
        c0, s0 = math.cos(yaw0), math.sin(yaw0)
        fx, fy = contact.force_n  # object frame: the twist's translation turned into the world
        twist = (c0 * fx - s0 * fy, s0 * fx + c0 * fy, contact.moment_n_mm / self._c_mm ** 2)
        cop = self.config.centre_of_pressure_mm
        cop_world = (x0 + c0 * cop[0] - s0 * cop[1], y0 + s0 * cop[0] + c0 * cop[1])

        def moved(alpha: float) -> tuple[float, float, float]:
            dyaw = alpha * twist[2]  # turn about the centre of pressure, which translates by alpha (fx, fy)
            c, s = math.cos(dyaw), math.sin(dyaw)
            rx, ry = x0 - cop_world[0], y0 - cop_world[1]
            return (cop_world[0] + alpha * twist[0] + c * rx - s * ry,
                    cop_world[1] + alpha * twist[1] + s * rx + c * ry, yaw0 + dyaw)

        force = math.hypot(fx, fy)
        low, high = 0.0, (contact.penetration_mm + math.sqrt(sum(e * e for e in contact.stretch_mm)) + 1.0) / force
        for _ in range(40):  # make sure ``high`` unloads the contact
            probe = self._contact(moved(high), apex, axis, self._anchor)
            if probe is None or self._load(probe) <= 1.0:
                break
            high *= 2.0
        for _ in range(16):
            mid = 0.5 * (low + high)
            probe = self._contact(moved(mid), apex, axis, self._anchor)
            if probe is None or self._load(probe) <= 1.0:
                high = mid
            else:
                low = mid
        self.pose = moved(high)

    def push(self, T_world_sensor: np.ndarray) -> None:
        """Move the dome to ``T_world_sensor`` (the apex frame, +z the sensor axis) in sub-steps from its last
        pose, the object yielding as it must."""
        apex = np.asarray(T_world_sensor[:3, 3], dtype=np.float64)
        axis = np.asarray(T_world_sensor[:3, 2], dtype=np.float64)
        start, start_axis = (apex, axis) if self._apex is None else (self._apex, self._axis)
        count = max(1, math.ceil(float(np.linalg.norm(apex - start)) / self.config.max_substep_mm))
        self.slipping = False
        for index in range(1, count + 1):
            f = index / count
            a = start + f * (apex - start)
            u = start_axis + f * (axis - start_axis)
            u = u / np.linalg.norm(u)
            self._slip(a, u)
            self._yield(a, u)
            self._slip(a, u)
        self._apex, self._axis = apex, axis

    def place(self, pose: tuple[float, float, float], T_world_sensor: np.ndarray) -> None:
        """Put the object at ``pose`` and the dome at ``T_world_sensor`` without moving anything; the skin
        anchors where the dome touches."""
        self.pose = tuple(float(v) for v in pose)
        self._anchor = None
        self._apex = np.asarray(T_world_sensor[:3, 3], dtype=np.float64)
        self._axis = np.asarray(T_world_sensor[:3, 2], dtype=np.float64)
        self._slip(self._apex, self._axis)

    def penetration_mm(self, T_world_sensor: np.ndarray) -> float:
        """How far the dome at ``T_world_sensor`` reaches into the object (negative: its gap to it), mm."""
        r = self.dome_radius_mm
        centre = T_world_sensor[:3, 3] - r * T_world_sensor[:3, 2]
        x, y = self._to_object(self.pose, centre)
        return r - self.shape.distance(x, y)[0]

    def shear_sensor(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """(6,) the skin's shear in the sensor frame (:class:`~simshear_gym.sim.shear.ShearTracker`'s layout: the
        sensor's displacement from where the skin sticks, x and y; zeros out of contact)."""
        shear = np.zeros(6)
        contact = self.contact()
        if contact is not None:
            stretch_world = self.T_world_object()[:3, :3] @ np.asarray(contact.stretch_mm)
            shear[0] = float(stretch_world @ T_world_sensor[:3, 0])
            shear[1] = float(stretch_world @ T_world_sensor[:3, 1])
        return shear


def spawn_push_object(world, shape: PushShape, T_world_object: np.ndarray) -> int:
    """The object's visual body for the TacTip's renderer (its outline extruded down from the top face)."""
    from simshear_gym.sim.contours import spawn_extruded

    return spawn_extruded(world, shape.outline_mm(), HEIGHT_MM, T_world_object, rgba=(0.8, 0.5, 0.3, 1.0))


__all__ = ["GRAVITY_M_S2", "HEIGHT_MM", "PUSH_SHAPES", "DomeContact", "PushPhysicsConfig", "PushShape",
           "PushedObject", "push_shape", "spawn_push_object", "torque_arm_mm"]
