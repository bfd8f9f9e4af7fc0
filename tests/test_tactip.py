"""Simulated TacTip: golden images, geometry, the region-of-interest render, sizes."""

from pathlib import Path

import numpy as np
import pybullet
import pytest

from simshear_gym.sim.replay import ReplayGeometry, ReplayScene
from simshear_gym.sim.tactip import (
    TacTip,
    TacTipConfig,
    dome_depth_mm,
    pose_to_image_px,
)
from simshear_gym.sim.world import World, WorldConfig
from tests.fixtures.regenerate_golden import GOLDEN_CASES, render_case

GOLDEN = np.load(Path(__file__).parent / "fixtures" / "golden_tactip.npz")


@pytest.mark.parametrize("name", sorted(GOLDEN_CASES))
def test_golden_render(name):
    image = render_case(*GOLDEN_CASES[name])
    golden = GOLDEN[name]
    assert image.shape == golden.shape and image.dtype == np.uint8
    assert golden.max() > 20, "the golden case must show a real contact"
    diff = np.abs(image.astype(int) - golden.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.005


def test_dome_depth_is_analytic():
    config = TacTipConfig(image_size_px=128)
    depth = dome_depth_mm(config, 128)
    # the pixels next to the axis see the apex, 55 mm from the camera
    assert depth[63:65, 63:65] == pytest.approx(config.camera_to_apex_mm, abs=0.05)
    assert depth[0, 0] == 0.0  # the image corner sees past the dome
    assert 0.7 < (depth > 0).mean() < np.pi / 4 + 0.01  # a disc inscribed in the square


def test_no_contact_renders_black_and_depth_offset_sets_penetration():
    geometry = ReplayGeometry(surface_depth_mm=2.2)
    with ReplayScene("surface", geometry=geometry) as scene:
        assert scene.render(np.array([0, 0, 2.0, 0, 0, 0])).max() == 0  # hovering 0.2 mm above
        penetration = scene.tactip.render_penetration_mm(scene.T_world_sensor(np.array([0, 0, 4.2, 0, 0, 0])))
    assert penetration.max() == pytest.approx(2.0, abs=0.02)


@pytest.mark.parametrize("rx, ry", [(10.0, 0.0), (0.0, -12.0), (8.0, 8.0)])
def test_tilt_moves_contact_to_projected_point(rx, ry):
    """The deepest point of the dome in a plane tilted by (Rx, Ry) lies where the sphere's normal meets it."""
    config = TacTipConfig()
    with ReplayScene("surface", config) as scene:
        pose = np.array([0, 0, 4.5, rx, ry, 0.0])
        image = scene.render(pose)
        T = scene.T_world_sensor(pose)
    normal_sensor = T[:3, :3].T @ np.array([0.0, 0.0, -1.0])  # into the surface (world -z) in the sensor frame
    centre = np.array([0.0, 0.0, -config.dome_radius_mm])
    expected = pose_to_image_px(config, centre + config.dome_radius_mm * normal_sensor)
    rows, cols = np.nonzero(image == image.max())
    assert np.hypot(cols.mean() - expected[0], rows.mean() - expected[1]) < 1.5


def test_region_of_interest_render_equals_full_render():
    with World() as world:
        client = world.client
        half = [0.05, 0.05, 0.01]
        body = client.createMultiBody(0, client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half),
                                      client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half))
        client.resetBasePositionAndOrientation(body, [0.003, -0.002, -0.0085], [0.05, 0.03, 0, 1])
        tactip = TacTip(world, TacTipConfig())
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down
        fast = tactip.render_penetration_mm(T)
        full = tactip._render_depth_mm(tactip._view_matrix(T), tactip._window_projection(0, 128, 0, 128), 128, 128)
        reference = np.where(tactip._dome_depth - full > 0, tactip._dome_depth - full, 0.0)
    assert fast.max() > 1.0
    np.testing.assert_allclose(fast, reference, atol=1e-3)


@pytest.mark.parametrize("size", [64, 128, 256])
def test_sizes(size):
    with ReplayScene("edge", TacTipConfig(image_size_px=size)) as scene:
        image = scene.render(np.array([0, 1.0, 4.0, 0, 0, 45.0]))
    assert image.shape == (size, size) and image.max() > 0


def test_config_validation():
    with pytest.raises(ValueError, match="image_size_px must be one of"):
        TacTipConfig(image_size_px=100)
    with pytest.raises(ValueError, match="camera outside the dome"):
        TacTipConfig(dome_radius_mm=40.0)
    with pytest.raises(ValueError, match="time_step_s"):
        WorldConfig(time_step_s=0.0)


def test_world_closes():
    world = World()
    world.close()
    with pytest.raises(RuntimeError, match="closed"):
        world.client
