import numpy as np
import pytest

from simshear_gym.data.labels import (
    mount_rz_deg,
    shear_to_sensor_frame,
    shear_to_work_frame,
    task_ranges,
    wrap_deg,
)


def test_shear_rotated_by_minus_rz_into_sensor_frame():
    move = np.array([1.0, 0.0, 0.5, 1.0, 2.0, 3.0])
    # Sensor turned +90 deg about z: a work-frame +x move is a sensor-frame -y move.
    shear = shear_to_sensor_frame(move, 90.0)
    np.testing.assert_allclose(shear, [0.0, -1.0, 0.5, 1.0, 2.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(shear_to_sensor_frame(move, 0.0), move)


def test_shear_frame_round_trip_batched():
    rng = np.random.default_rng(0)
    move = rng.uniform(-5, 5, (50, 6))
    rz = rng.uniform(-180, 180, 50)
    np.testing.assert_allclose(shear_to_work_frame(shear_to_sensor_frame(move, rz), rz), move, atol=1e-12)
    # rotation keeps the in-plane length
    np.testing.assert_allclose(np.hypot(*shear_to_sensor_frame(move, rz)[:, :2].T), np.hypot(*move[:, :2].T))


def test_shear_needs_six_components():
    with pytest.raises(ValueError, match="6 components"):
        shear_to_sensor_frame(np.zeros(4), 0.0)


@pytest.mark.parametrize("cell", ["[0, 0, 0, 0, 0, -48]", "[0.000000 0.000000 0.000000 0.000000 0.000000 -48.000000]"])
def test_mount_parsed_from_both_published_spellings(cell):
    assert mount_rz_deg(cell) == -48.0


def test_mount_rejects_malformed_cell():
    with pytest.raises(ValueError, match="obj_pose"):
        mount_rz_deg("[0, 0, -48]")


def test_wrap_and_ranges():
    np.testing.assert_allclose(wrap_deg([180.0, -190.0, 359.0]), [-180.0, 170.0, -1.0])
    assert {r.column for r in task_ranges("edge", "tap")} == {"pose_2", "pose_3", "pose_6"}
    with pytest.raises(ValueError, match="unknown task"):
        task_ranges("cylinder", "tap")
