"""Shear tracker: stick, slip (anchor dragged), contact loss, and replay = the row's move in the sensor frame."""

import numpy as np
import pytest

from simshear_gym.data.labels import shear_to_sensor_frame
from simshear_gym.sim.shear import ShearTracker, ShearTrackerConfig


def pose(x=0.0, y=0.0, z=3.0, rz=0.0):
    return np.array([x, y, z, 0.0, 0.0, rz])


def test_stick_reports_displacement_since_touch():
    tracker = ShearTracker()
    np.testing.assert_allclose(tracker.update(pose(1.0, 2.0), in_contact=True), 0.0)  # onset: anchor here
    np.testing.assert_allclose(tracker.update(pose(3.0, 1.0, z=3.5), in_contact=True), [2.0, -1.0, 0.5, 0, 0, 0])


def test_shear_is_expressed_in_the_sensor_frame():
    tracker = ShearTracker()
    tracker.update(pose(rz=90.0), in_contact=True)
    shear = tracker.update(pose(x=2.0, rz=90.0), in_contact=True)
    np.testing.assert_allclose(shear[:2], [0.0, -2.0], atol=1e-12)


def test_slip_drags_anchor_and_saturates():
    tracker = ShearTracker(ShearTrackerConfig(slip_limit_mm=2.0, slip_limit_deg=3.0))
    tracker.update(pose(), in_contact=True)
    np.testing.assert_allclose(tracker.update(pose(x=5.0), in_contact=True)[0], 2.0)  # slipped 3 mm
    np.testing.assert_allclose(tracker.anchor_object[0], 3.0)
    # moving back 1 mm is inside the stick region again: shear follows the displacement from the dragged anchor
    np.testing.assert_allclose(tracker.update(pose(x=4.0), in_contact=True)[0], 1.0)
    np.testing.assert_allclose(tracker.update(pose(x=4.0, rz=10.0), in_contact=True)[5], 3.0)


def test_contact_loss_clears_anchor():
    tracker = ShearTracker()
    tracker.update(pose(), in_contact=True)
    np.testing.assert_allclose(tracker.update(pose(x=1.0), in_contact=False), 0.0)
    assert tracker.anchor_object is None
    np.testing.assert_allclose(tracker.update(pose(x=1.5), in_contact=True), 0.0)  # new contact, new anchor


def test_replay_gives_the_rows_move_in_sensor_frame():
    rng = np.random.default_rng(1)
    tracker = ShearTracker()
    for _ in range(20):
        p = rng.uniform(-5, 5, 6)
        p[5] = rng.uniform(-180, 180)
        move = rng.uniform(-5, 5, 6)
        tracker.touch(p - move)
        np.testing.assert_allclose(tracker.update(p, in_contact=True), shear_to_sensor_frame(move, p[5]), atol=1e-9)


def test_config_rejects_non_positive_limits():
    with pytest.raises(ValueError, match="slip limits"):
        ShearTrackerConfig(slip_limit_mm=0.0)
