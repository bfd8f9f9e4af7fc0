"""Stimuli: rigid shapes the sensor touches, spawned into a :class:`World`.

Each stimulus has its own frame (mm): the origin on the top face, +z the top face's outward normal. For the
straight edge (the edge of a square prism) the origin is on the edge line, +x runs along the edge and the
material lies at y < 0; the surface is a large flat box centred on its origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet

from simshear_gym.sim.world import World
from simshear_gym.transforms import matrix_to_pybullet


@dataclass(frozen=True)
class FlatSurface:
    """A flat box: ``size_mm`` = (length x, width y, thickness z)."""

    size_mm: tuple[float, float, float] = (200.0, 200.0, 20.0)

    def __post_init__(self) -> None:
        if min(self.size_mm) <= 0:
            raise ValueError(f"FlatSurface.size_mm must be positive, got {self.size_mm}")

    def box_centre_mm(self) -> np.ndarray:
        return np.array([0.0, 0.0, -self.size_mm[2] / 2.0])


@dataclass(frozen=True)
class StraightEdge:
    """A square prism whose top edge runs along x: ``size_mm`` = (length x, width y, height z)."""

    size_mm: tuple[float, float, float] = (200.0, 100.0, 20.0)

    def __post_init__(self) -> None:
        if min(self.size_mm) <= 0:
            raise ValueError(f"StraightEdge.size_mm must be positive, got {self.size_mm}")

    def box_centre_mm(self) -> np.ndarray:
        return np.array([0.0, -self.size_mm[1] / 2.0, -self.size_mm[2] / 2.0])


Stimulus = FlatSurface | StraightEdge

STIMULI: dict[str, type] = {"surface": FlatSurface, "edge": StraightEdge}


def make_stimulus(contact: str) -> Stimulus:
    """The default stimulus of a contact type (``surface`` | ``edge``)."""
    try:
        return STIMULI[contact]()
    except KeyError:
        raise ValueError(f"unknown contact type {contact!r}; expected one of {sorted(STIMULI)}") from None


def spawn(world: World, stimulus: Stimulus, T_world_stimulus: np.ndarray, lateral_friction: float = 1.0) -> int:
    """Create the stimulus as a static body whose frame is ``T_world_stimulus`` (4x4, mm); returns its id."""
    client = world.client
    half_m = (np.asarray(stimulus.size_mm) / 2000.0).tolist()
    collision = client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_m)
    visual = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_m, rgbaColor=[0.7, 0.7, 0.7, 1.0])
    T_world_box = np.array(T_world_stimulus, dtype=np.float64)
    T_world_box[:3, 3] = T_world_box[:3, 3] + T_world_box[:3, :3] @ stimulus.box_centre_mm()
    position_m, quaternion = matrix_to_pybullet(T_world_box)
    body = client.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
        basePosition=position_m, baseOrientation=quaternion,
    )
    client.changeDynamics(body, -1, lateralFriction=lateral_friction)
    return body


def move(world: World, body: int, T_world_stimulus: np.ndarray, stimulus: Stimulus) -> None:
    """Place an existing stimulus body at a new frame."""
    T_world_box = np.array(T_world_stimulus, dtype=np.float64)
    T_world_box[:3, 3] = T_world_box[:3, 3] + T_world_box[:3, :3] @ stimulus.box_centre_mm()
    position_m, quaternion = matrix_to_pybullet(T_world_box)
    world.client.resetBasePositionAndOrientation(body, position_m, quaternion)
