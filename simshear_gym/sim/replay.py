"""Replay labelled contacts in simulation: a stimulus in a work frame and a TacTip placed at each label's pose.

Frames: the stimulus frame is the world frame. The **work frame** of the labels has its z axis into the
stimulus and sits above it, so a pose's ``z`` is the indentation (see :mod:`simshear_gym.data.labels`).
Where exactly the stimulus lies in the work frame is a property of the collecting rig, not of the sensor;
:class:`ReplayGeometry` holds it, with defaults calibrated so that our renders of the published label rows agree
with the published Tactile Gym renders of the same rows (``simshear evaluate render``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simshear_gym.data.labels import SURFACE_DEPTH_MM
from simshear_gym.sim.parallel import map_chunks
from simshear_gym.sim.stimuli import make_stimulus, spawn
from simshear_gym.sim.tactip import TacTip, TacTipConfig
from simshear_gym.sim.world import ClosedOnExit, World
from simshear_gym.transforms import invert, pose_to_matrix


@dataclass(frozen=True)
class ReplayGeometry:
    """Where the stimulus lies in the labels' work frame.

    Attributes:
        surface_depth_mm: work-frame z of the stimulus's top face; a contact's penetration of the dome apex
            is ``pose z - surface_depth_mm``.
        edge_y_mm: work-frame y of the edge line (edge stimulus only); the edge runs along work x.
        edge_material_side: +1 if the prism's material lies at work y > ``edge_y_mm``, -1 if at y < it.
    """

    surface_depth_mm: float = SURFACE_DEPTH_MM
    edge_y_mm: float = -0.25
    edge_material_side: int = 1

    def __post_init__(self) -> None:
        if self.edge_material_side not in (1, -1):
            raise ValueError(f"edge_material_side must be +1 or -1, got {self.edge_material_side}")

    def T_work_stimulus(self) -> np.ndarray:
        """4x4 transform (mm) of the stimulus frame in the work frame."""
        transform = np.eye(4)
        if self.edge_material_side == 1:  # stimulus y (towards air) = -work y; z out of the top face = -work z
            transform[:3, :3] = np.diag([1.0, -1.0, -1.0])
        else:
            transform[:3, :3] = np.diag([-1.0, 1.0, -1.0])
        transform[:3, 3] = [0.0, self.edge_y_mm, self.surface_depth_mm]
        return transform


class ReplayScene(ClosedOnExit):
    """A world with one stimulus (``surface`` | ``edge``) and a TacTip that renders label poses.

    Owns its :class:`World`; close it (or use ``with``) when done.
    """

    def __init__(
        self,
        contact: str,
        tactip_config: TacTipConfig = TacTipConfig(),
        geometry: ReplayGeometry = ReplayGeometry(),
    ) -> None:
        self.contact = contact
        self.geometry = geometry
        self.world = World()
        self.stimulus = make_stimulus(contact)
        spawn(self.world, self.stimulus, np.eye(4))
        self.tactip = TacTip(self.world, tactip_config)
        self._T_world_work = invert(geometry.T_work_stimulus())

    def T_world_sensor(self, pose_work_mm_deg: np.ndarray) -> np.ndarray:
        return self._T_world_work @ pose_to_matrix(pose_work_mm_deg)

    def render(self, pose_work_mm_deg: np.ndarray) -> np.ndarray:
        """uint8 (H, W) tactile image of the contact at a label pose (x, y, z mm, Rx, Ry, Rz deg)."""
        return self.tactip.render(self.T_world_sensor(pose_work_mm_deg))

    def close(self) -> None:
        self.world.close()


def _render_chunk(args: tuple[str, np.ndarray, TacTipConfig, ReplayGeometry]) -> np.ndarray:
    contact, poses, tactip_config, geometry = args
    size = tactip_config.image_size_px
    images = np.empty((len(poses), size, size), dtype=np.uint8)
    with ReplayScene(contact, tactip_config, geometry) as scene:
        for index, pose in enumerate(poses):
            images[index] = scene.render(pose)
    return images


def render_poses(
    contact: str,
    poses_work: np.ndarray,
    tactip_config: TacTipConfig = TacTipConfig(),
    geometry: ReplayGeometry = ReplayGeometry(),
    workers: int = 1,
    ray_address: str | None = None,
) -> np.ndarray:
    """Render many label poses: uint8 (N, H, W), in order, split into ``workers`` chunks that run in as many
    processes, or as Ray tasks at ``ray_address`` (:func:`~simshear_gym.sim.parallel.map_chunks`)."""
    poses = np.asarray(poses_work, dtype=np.float64).reshape(-1, 6)
    size = tactip_config.image_size_px
    if not len(poses):
        return np.empty((0, size, size), dtype=np.uint8)
    chunks = [(contact, part, tactip_config, geometry) for part in np.array_split(poses, max(workers, 1)) if len(part)]
    return np.concatenate(map_chunks(_render_chunk, chunks, workers, ray_address))
