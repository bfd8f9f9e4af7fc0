"""Simulated TacTip: a depth camera inside the undeformed dome renders how far a stimulus penetrates it.

Geometry (sensor frame, mm): the TCP is the dome apex; +z points out of the dome, towards the stimulus; the
dome is a hemisphere of radius ``dome_radius_mm`` whose centre lies ``dome_radius_mm`` behind the apex; the
camera sits ``camera_to_dome_centre_mm`` behind the centre, looks along +z, image columns along +x, rows along
+y. These are the Tactile Gym TacTip's dimensions (camera 30 mm from the body origin, tip link at 65 mm,
TCP at 85 mm, FOV 60 deg), so the image spans the 40 mm dome like the real sensor's.

Image: for each pixel, ``penetration_mm = depth of the undeformed dome - depth of the stimulus`` along the
optical axis (metric depth, not the non-linear depth buffer), where the stimulus is inside the dome; zero
elsewhere and outside the sensor disc. As uint8 it is ``floor(255 * penetration_mm / full_scale_mm)``; the
default full scale (14.5 mm) gives about the same grey levels as the published Tactile Gym images, whose scale is
0.05 of the raw depth buffer (about 17 levels per mm at the apex).

Speed: the tip's own surface is analytic (never rendered); PyBullet renders only the stimuli, first at a coarse
resolution over the whole view, then at full resolution over the bounding box of the coarse contact region
only (an off-axis frustum). Everything beyond the dome is outside the far plane, so the rest of a scene
(arms, tables) never shows in the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet

from simshear_gym.sim.world import World

SUPPORTED_SIZES_PX = (64, 128, 256)


@dataclass(frozen=True)
class TacTipConfig:
    """TacTip geometry and image settings.

    Attributes:
        image_size_px: square image side (64, 128 or 256).
        dome_radius_mm: radius of the hemispherical tip (40 mm dome).
        camera_to_dome_centre_mm: distance from the camera to the dome's centre along the axis.
        fov_deg: camera field of view.
        full_scale_mm: penetration that maps to grey level 255.
        coarse_size_px: resolution of the first, whole-view pass that finds the contact region.
        roi_margin_px: margin (full-resolution pixels) added around the coarse contact region.
    """

    image_size_px: int = 128
    dome_radius_mm: float = 20.0
    camera_to_dome_centre_mm: float = 35.0
    fov_deg: float = 60.0
    full_scale_mm: float = 14.5
    coarse_size_px: int = 32
    roi_margin_px: int = 4

    def __post_init__(self) -> None:
        if self.image_size_px not in SUPPORTED_SIZES_PX:
            raise ValueError(f"image_size_px must be one of {SUPPORTED_SIZES_PX}, got {self.image_size_px}")
        if self.dome_radius_mm <= 0 or self.camera_to_dome_centre_mm <= self.dome_radius_mm:
            raise ValueError(
                "need 0 < dome_radius_mm < camera_to_dome_centre_mm (camera outside the dome), got "
                f"{self.dome_radius_mm} and {self.camera_to_dome_centre_mm}"
            )
        if not 0 < self.fov_deg < 170:
            raise ValueError(f"fov_deg must be in (0, 170), got {self.fov_deg}")
        if self.full_scale_mm <= 0:
            raise ValueError(f"full_scale_mm must be > 0, got {self.full_scale_mm}")
        if self.image_size_px % self.coarse_size_px:
            raise ValueError(
                f"coarse_size_px {self.coarse_size_px} must divide image_size_px {self.image_size_px}"
            )

    @property
    def camera_to_apex_mm(self) -> float:
        return self.camera_to_dome_centre_mm + self.dome_radius_mm

    @property
    def near_mm(self) -> float:
        return 0.5 * self.camera_to_dome_centre_mm

    @property
    def far_mm(self) -> float:
        return self.camera_to_apex_mm + 1.0


def dome_depth_mm(config: TacTipConfig, size_px: int) -> np.ndarray:
    """Depth along the optical axis of the undeformed dome's surface for each pixel; 0 off the dome.

    A pixel's ray is ``t * (a, b, 1)`` (``t`` = depth). It leaves the sphere of radius R centred at depth D at
    ``t = (D + sqrt(D^2 - |v|^2 (D^2 - R^2))) / |v|^2``; pixels whose ray misses the front hemisphere are off.
    """
    tangents = _pixel_tangents(config.fov_deg, size_px)
    a, b = np.meshgrid(tangents, tangents)  # a: columns (+x), b: rows (+y)
    norm2 = a * a + b * b + 1.0
    d, r = config.camera_to_dome_centre_mm, config.dome_radius_mm
    disc = d * d - norm2 * (d * d - r * r)
    depth = np.zeros((size_px, size_px))
    hit = disc >= 0
    depth[hit] = (d + np.sqrt(disc[hit])) / norm2[hit]
    depth[depth < d] = 0.0  # the back half of the sphere is not part of the dome
    return depth


def _pixel_tangents(fov_deg: float, size_px: int) -> np.ndarray:
    """tan of the angle to the axis at each pixel centre, along one image axis."""
    half = math.tan(math.radians(fov_deg) / 2.0)
    return (2.0 * (np.arange(size_px) + 0.5) / size_px - 1.0) * half


class TacTip:
    """Renders tactile depth images of the stimuli in a :class:`World` for a given sensor pose."""

    def __init__(self, world: World, config: TacTipConfig = TacTipConfig()) -> None:
        self.world = world
        self.config = config
        self._dome_depth = dome_depth_mm(config, config.image_size_px)
        self._dome_depth_coarse = dome_depth_mm(config, config.coarse_size_px)
        self._half_tan = math.tan(math.radians(config.fov_deg) / 2.0)
        near, far = config.near_mm / 1000.0, config.far_mm / 1000.0
        self._near_m, self._far_m = near, far
        self._coarse_projection = world.client.computeProjectionMatrixFOV(config.fov_deg, 1.0, near, far)

    def render(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """uint8 (H, W) tactile image at the sensor pose ``T_world_sensor`` (4x4, mm)."""
        penetration = self.render_penetration_mm(T_world_sensor)
        scaled = np.minimum(penetration * (255.0 / self.config.full_scale_mm), 255.0)
        return scaled.astype(np.uint8)

    def render_penetration_mm(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """float32 (H, W) penetration of the stimuli into the undeformed dome, mm along the optical axis."""
        config = self.config
        view = self._view_matrix(np.asarray(T_world_sensor, dtype=np.float64))
        coarse_depth = self._render_depth_mm(view, self._coarse_projection, config.coarse_size_px,
                                             config.coarse_size_px)
        coarse_contact = coarse_depth < self._dome_depth_coarse
        full = config.image_size_px
        out = np.zeros((full, full), dtype=np.float32)
        if not coarse_contact.any():
            return out
        scale = full // config.coarse_size_px
        rows, cols = np.nonzero(coarse_contact)
        margin = config.roi_margin_px + scale
        v0, v1 = max(rows.min() * scale - margin, 0), min((rows.max() + 1) * scale + margin, full)
        u0, u1 = max(cols.min() * scale - margin, 0), min((cols.max() + 1) * scale + margin, full)
        depth = self._render_depth_mm(view, self._window_projection(u0, u1, v0, v1), u1 - u0, v1 - v0)
        penetration = self._dome_depth[v0:v1, u0:u1] - depth
        out[v0:v1, u0:u1] = np.where(penetration > 0, penetration, 0.0)
        return out

    def _view_matrix(self, T_world_sensor: np.ndarray) -> tuple[float, ...]:
        rotation = T_world_sensor[:3, :3]
        axis, down = rotation[:, 2], rotation[:, 1]
        camera_m = (T_world_sensor[:3, 3] - self.config.camera_to_apex_mm * axis) / 1000.0
        return self.world.client.computeViewMatrix(
            cameraEyePosition=camera_m.tolist(),
            cameraTargetPosition=(camera_m + axis).tolist(),
            cameraUpVector=(-down).tolist(),  # image rows grow along sensor +y
        )

    def _window_projection(self, u0: int, u1: int, v0: int, v1: int) -> tuple[float, ...]:
        """Off-axis frustum that renders pixel columns [u0, u1) and rows [v0, v1) of the full image."""
        n, size, near = self._half_tan, self.config.image_size_px, self._near_m
        left, right = (2.0 * u0 / size - 1.0) * n * near, (2.0 * u1 / size - 1.0) * n * near
        top, bottom = (1.0 - 2.0 * v0 / size) * n * near, (1.0 - 2.0 * v1 / size) * n * near
        return self.world.client.computeProjectionMatrix(left, right, bottom, top, near, self._far_m)

    def _render_depth_mm(self, view, projection, width: int, height: int) -> np.ndarray:
        """Metric depth (mm along the optical axis) of the rendered stimuli; ``far`` where nothing is seen."""
        _, _, _, buffer, _ = self.world.client.getCameraImage(
            width, height, view, projection, renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
        )
        buffer = np.asarray(buffer, dtype=np.float64).reshape(height, width)
        near, far = self._near_m, self._far_m
        return 1000.0 * far * near / (far - (far - near) * buffer)


def pose_to_image_px(config: TacTipConfig, point_sensor_mm: np.ndarray) -> np.ndarray:
    """Project points in the sensor frame (mm, (..., 3)) to (column, row) pixel coordinates (float)."""
    point = np.asarray(point_sensor_mm, dtype=np.float64)
    depth = point[..., 2] + config.camera_to_apex_mm
    half = math.tan(math.radians(config.fov_deg) / 2.0)
    size = config.image_size_px
    col = ((point[..., 0] / depth) / half + 1.0) * size / 2.0 - 0.5
    row = ((point[..., 1] / depth) / half + 1.0) * size / 2.0 - 0.5
    return np.stack([col, row], axis=-1)


