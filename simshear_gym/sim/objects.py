"""Graspable objects for the co-lift task: a square prism, a rigid egg, a soft "brain" and a rubber duck.

Object frame (mm): the origin is the object's centre of mass; +y is the object's up; +z is the grip axis, the
direction from the leader's plate to the follower's TacTip when the object is held (see
:mod:`simshear_gym.sim.colift_scene`); +x = y x z. Every object is a free rigid body with real mass and
inertia; nothing but contact friction holds it.

Shapes:
    prism: a box, ``size_mm`` = (x, y, z); gripped across its z faces.
    egg:   a surface of revolution about y, blunt end down; ``size_mm`` = (width, height, width).
    brain: an ellipsoid with semi-axes ``size_mm / 2``; soft (compliant contact, see below).
    ducky: PyBullet's ``duck.obj`` (visual) and its convex decomposition ``duck_vhacd.obj`` (collision),
           scaled uniformly so that its length (x) is ``size_mm[0]``; y and z follow (the default 50 mm
           duck is about 47 mm tall and 35 mm wide); gripped across its flanks.

The egg and brain are triangle meshes built here; PyBullet collides with their convex hull (both shapes are
convex) and renders the same triangles. The duck collides with its five convex hulls, a slightly fuller
shape than the visual mesh (up to about a millimetre on its flanks).

Soft contact: ``contact_stiffness_npm`` / ``contact_damping_nspm`` (None = Bullet's rigid contact) set an
implicit spring-damper on the object's contacts. Bullet combines two bodies' stiffnesses in series
(``1 / (1/k1 + 1/k2)``) and adds their dampings, so a soft object is soft against the plate and the tip alike.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

import numpy as np
import pybullet
import pybullet_data

from simshear_gym.sim.world import World
from simshear_gym.transforms import matrix_to_pybullet

SHAPES = ("box", "egg", "ellipsoid", "duck")
_HULL_MARGIN_M = 1e-4  # Bullet's default hull margin (1 mm) would inflate the collision shape past the visual one
_MESH_FILE_MARGIN_M = 1e-3  # that default, kept by the hulls of a mesh file (the duck)


@dataclass(frozen=True)
class ObjectSpec:
    """One graspable object.

    Attributes:
        name: key in :data:`OBJECTS`.
        shape: ``box`` | ``egg`` | ``ellipsoid`` | ``duck``.
        size_mm: extent along the object's x, y (up), z (grip axis).
        mass_kg: mass.
        lateral_friction: Coulomb friction coefficient of its surface (Bullet multiplies the two bodies').
        spinning_friction: torsional friction (m: torque limit per newton of normal force) the object's own
            surface adds; Bullet combines ``spin_a * friction_b + spin_b * friction_a``. The grippers carry
            the contact patch's torsion (:class:`~simshear_gym.sim.colift_scene.CoLiftSceneConfig`).
        rolling_friction: rolling resistance (m), combined the same way.
        contact_stiffness_npm: contact stiffness (N/m) of a soft object, None for a rigid one.
        contact_damping_nspm: contact damping (N s/m) of a soft object, None for a rigid one.
        rgba: visual colour.
    """

    name: str
    shape: str
    size_mm: tuple[float, float, float]
    mass_kg: float = 0.03
    lateral_friction: float = 1.0
    spinning_friction: float = 0.0
    rolling_friction: float = 0.0
    contact_stiffness_npm: float | None = None
    contact_damping_nspm: float | None = None
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"ObjectSpec.shape must be one of {SHAPES}, got {self.shape!r}")
        if len(self.size_mm) != 3 or min(self.size_mm) <= 0:
            raise ValueError(f"ObjectSpec.size_mm must be three positive extents (x, y, z mm), got {self.size_mm}")
        if not 0 < self.mass_kg <= 5.0:
            raise ValueError(f"ObjectSpec.mass_kg must be in (0, 5] kg, got {self.mass_kg}")
        if self.lateral_friction < 0 or self.spinning_friction < 0 or self.rolling_friction < 0:
            raise ValueError(
                f"friction coefficients must be >= 0, got lateral={self.lateral_friction}, "
                f"spinning={self.spinning_friction}, rolling={self.rolling_friction}"
            )
        soft = (self.contact_stiffness_npm, self.contact_damping_nspm)
        if (soft[0] is None) != (soft[1] is None):
            raise ValueError(
                "give both contact_stiffness_npm and contact_damping_nspm (soft object) or neither (rigid), "
                f"got {soft}"
            )
        if soft[0] is not None and (soft[0] <= 0 or soft[1] < 0):
            raise ValueError(f"contact stiffness must be > 0 and damping >= 0, got {soft}")

    @property
    def soft(self) -> bool:
        return self.contact_stiffness_npm is not None


OBJECTS: dict[str, ObjectSpec] = {
    "prism": ObjectSpec("prism", "box", (30.0, 40.0, 30.0), rgba=(0.2, 0.4, 0.8, 1.0)),
    "egg": ObjectSpec("egg", "egg", (42.0, 54.0, 42.0), rgba=(0.95, 0.9, 0.8, 1.0)),
    "brain": ObjectSpec(
        "brain", "ellipsoid", (46.0, 36.0, 40.0), contact_stiffness_npm=600.0, contact_damping_nspm=3.0,
        rolling_friction=0.01,  # a soft body's own contact patches (1-2 cm across when squeezed) resist rolling
        rgba=(0.9, 0.6, 0.65, 1.0),
    ),
    "ducky": ObjectSpec("ducky", "duck", (50.0, 46.0, 35.0), rgba=(1.0, 0.85, 0.2, 1.0)),
}


PAYLOADS = ("light", "heavy")
HEAVY_OBJECTS: dict[str, ObjectSpec] = {
    # the same shapes filled: a 2 kg block (the prism's size at about 55 g/cm3: a weight, not a material), a 1.5 kg
    # egg-shaped weight, a 1 kg cast duck, and a 0.5 kg soft ball (the brain's shape, its skin firm enough that a
    # grip can carry it: at the light brain's 600 N/m it slides out of any squeeze the dome allows)
    "prism": replace(OBJECTS["prism"], mass_kg=2.0),
    "egg": replace(OBJECTS["egg"], mass_kg=1.5),
    "brain": replace(OBJECTS["brain"], mass_kg=0.5, contact_stiffness_npm=2000.0, contact_damping_nspm=5.5),
    "ducky": replace(OBJECTS["ducky"], mass_kg=1.0),
}
"""The heavy co-lift set (0.5-2.0 kg), carried with the firm TacTip of
:data:`~simshear_gym.sim.colift_scene.FIRM_TIP`; the light set is :data:`OBJECTS` (30 g each)."""


def object_spec(name: str, mass_kg: float | None = None, payload: str = "light") -> ObjectSpec:
    """The spec of a named object of the ``light`` (:data:`OBJECTS`) or ``heavy`` (:data:`HEAVY_OBJECTS`) set,
    optionally with another mass."""
    if payload not in PAYLOADS:
        raise ValueError(f"payload must be one of {PAYLOADS}, got {payload!r}")
    objects = HEAVY_OBJECTS if payload == "heavy" else OBJECTS
    try:
        spec = objects[name]
    except KeyError:
        raise ValueError(f"unknown object {name!r}; expected one of {sorted(objects)}") from None
    return spec if mass_kg is None else replace(spec, mass_kg=mass_kg)


def spawn_object(world: World, spec: ObjectSpec, T_world_object: np.ndarray) -> int:
    """Create the object as a free dynamic body whose frame is ``T_world_object`` (4x4, mm); returns its id."""
    client = world.client
    collision, visual = _shapes(world, spec)
    position_m, quaternion = matrix_to_pybullet(np.asarray(T_world_object, dtype=np.float64))
    body = client.createMultiBody(
        baseMass=spec.mass_kg, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
        basePosition=position_m, baseOrientation=quaternion, useMaximalCoordinates=True,
    )
    dynamics = dict(
        lateralFriction=spec.lateral_friction, spinningFriction=spec.spinning_friction,
        rollingFriction=spec.rolling_friction, linearDamping=0.0, angularDamping=0.0,
    )
    if spec.shape != "box":
        dynamics["collisionMargin"] = _HULL_MARGIN_M
    if spec.soft:
        dynamics.update(contactStiffness=spec.contact_stiffness_npm, contactDamping=spec.contact_damping_nspm)
    client.changeDynamics(body, -1, **dynamics)
    return body


def _shapes(world: World, spec: ObjectSpec) -> tuple[int, int]:
    """(collision shape, visual shape) ids, both centred on the centre of mass."""
    client = world.client
    size_m = np.asarray(spec.size_mm) / 1000.0
    if spec.shape == "box":
        half = (size_m / 2.0).tolist()
        return (client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half),
                client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half, rgbaColor=list(spec.rgba)))
    if spec.shape == "duck":
        return _duck_shapes(world, spec)
    vertices, indices = egg_mesh(size_m) if spec.shape == "egg" else ellipsoid_mesh(size_m)
    vertices = vertices - mesh_centroid(vertices, indices)
    normals = _vertex_normals(vertices, indices)
    collision = client.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices.tolist())
    visual = client.createVisualShape(
        pybullet.GEOM_MESH, vertices=vertices.tolist(), indices=indices.ravel().tolist(),
        normals=normals.tolist(), rgbaColor=list(spec.rgba),
    )
    return collision, visual


def _surface_grid(n_lat: int, n_lon: int) -> np.ndarray:
    """Triangle indices of a (n_lat + 1) x n_lon latitude-longitude grid whose first and last rings are poles."""
    faces = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            faces += [(a, c, b), (b, c, d)]  # outward (counter-clockwise seen from outside)
    return np.array(faces, dtype=np.int64)


def _revolve(height_m: np.ndarray, radius_m: np.ndarray, radius_x_m: np.ndarray, n_lon: int):
    angle = np.linspace(0.0, 2.0 * math.pi, n_lon, endpoint=False)
    x = radius_x_m[:, None] * np.cos(angle)[None, :]
    z = radius_m[:, None] * np.sin(angle)[None, :]
    y = np.broadcast_to(height_m[:, None], x.shape)
    return np.stack([x, y, z], axis=-1).reshape(-1, 3)


def egg_mesh(size_m: np.ndarray, n_lat: int = 24, n_lon: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) m and triangles (M, 3) of an egg: blunt end down (-y), widest below the middle.

    Profile: ``r(t) = w/2 * sqrt(1 - t^2) * (1 - 0.12 t) / max``, ``t = 2 y / h``.
    """
    width, height = float(size_m[0]), float(size_m[1])
    t = -np.cos(np.linspace(0.0, math.pi, n_lat + 1))  # -1 (bottom pole) .. 1 (top pole)
    profile = np.sqrt(np.clip(1.0 - t * t, 0.0, None)) * (1.0 - 0.12 * t)
    radius = 0.5 * width * profile / profile.max()
    vertices = _revolve(0.5 * height * t, radius, radius, n_lon)
    return vertices, _surface_grid(n_lat, n_lon)


def ellipsoid_mesh(size_m: np.ndarray, n_lat: int = 24, n_lon: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) m and triangles (M, 3) of an ellipsoid with semi-axes ``size_m / 2``."""
    t = -np.cos(np.linspace(0.0, math.pi, n_lat + 1))
    ring = np.sqrt(np.clip(1.0 - t * t, 0.0, None))
    vertices = _revolve(0.5 * size_m[1] * t, 0.5 * size_m[2] * ring, 0.5 * size_m[0] * ring, n_lon)
    return vertices, _surface_grid(n_lat, n_lon)


def mesh_centroid(vertices: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Centre of volume of a closed triangle mesh (signed tetrahedra from the origin)."""
    a, b, c = (vertices[indices[:, k]] for k in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    return (volume[:, None] * (a + b + c) / 4.0).sum(axis=0) / volume.sum()


def _vertex_normals(vertices: np.ndarray, indices: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[indices[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, indices[:, k], face)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def _read_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3) and triangles (M, 3) of a Wavefront file, in file units."""
    vertices, faces = [], []
    with open(path) as file:
        for line in file:
            if line.startswith("v "):
                vertices.append([float(value) for value in line.split()[1:4]])
            elif line.startswith("f "):
                faces.append([int(token.split("/")[0]) - 1 for token in line.split()[1:4]])
    return np.array(vertices), np.array(faces, dtype=np.int64)


def _duck_shapes(world: World, spec: ObjectSpec) -> tuple[int, int]:
    client = world.client
    data = pybullet_data.getDataPath()
    vertices, faces = _read_obj(os.path.join(data, "duck.obj"))  # closed mesh: its centroid is the duck's
    scale_m = spec.size_mm[0] / 1000.0 / np.ptp(vertices[:, 0])  # size_mm[0] sets the length; y, z follow
    vertices_m = vertices * scale_m
    centre_m = mesh_centroid(vertices_m, faces)
    collision = client.createCollisionShape(
        pybullet.GEOM_MESH, fileName=os.path.join(data, "duck_vhacd.obj"), meshScale=[scale_m] * 3,
        collisionFramePosition=(-centre_m).tolist(),
    )
    # The hulls of a mesh file keep Bullet's default margin (changeDynamics does not reach a compound's
    # children), which inflates them by 1 mm; inflate the visual mesh alike about its box centre, so that the
    # tactile image shows the same penetration as the physics on the duck's flanks.
    low, high = vertices_m.min(axis=0), vertices_m.max(axis=0)
    inflate = (high - low + 2.0 * _MESH_FILE_MARGIN_M) / (high - low)
    box_centre_m = (low + high) / 2.0
    visual = client.createVisualShape(
        pybullet.GEOM_MESH, fileName=os.path.join(data, "duck.obj"), meshScale=(scale_m * inflate).tolist(),
        visualFramePosition=(box_centre_m * (1.0 - inflate) - centre_m).tolist(), rgbaColor=list(spec.rgba),
    )
    return collision, visual
