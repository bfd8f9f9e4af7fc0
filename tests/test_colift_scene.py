"""Co-lift scene: friction alone holds every object while the tip follows the plate, and drops it when the tip
lets go; images agree with the physics depth; masses matter; runs repeat bit for bit."""

import numpy as np
import pytest

from simshear_gym.sim.colift_scene import CoLiftScene, CoLiftSceneConfig, upright_plate
from simshear_gym.sim.objects import OBJECTS, object_spec, spawn_object
from simshear_gym.sim.world import World
from simshear_gym.transforms import invert

NAMES = sorted(OBJECTS)
T_WORLD_PLATE = upright_plate([0.0, 0.0, 300.0])


def _translation(x=0.0, y=0.0, z=0.0):
    transform = np.eye(4)
    transform[:3, 3] = [x, y, z]
    return transform


def leader_path_mm(t_s: float) -> np.ndarray:
    """World offset of the plate: a 30 mm lift over 1 s, then a horizontal circle of radius 20 mm in 2 s."""
    if t_s < 1.0:
        return np.array([0.0, 0.0, 30.0 * t_s])
    angle = 2.0 * np.pi * (t_s - 1.0) / 2.0
    return np.array([20.0 * (np.cos(angle) - 1.0), 20.0 * np.sin(angle), 30.0])


def follow(scene: CoLiftScene, T_plate_sensor: np.ndarray, duration_s: float, record: bool = False):
    """Move the plate along the leader path with the tip following it rigidly; returns per-step records."""
    period = scene.config.control_period_s
    rows = []
    for k in range(1, round(duration_s / period) + 1):
        T_world_plate = _translation(*leader_path_mm(k * period)) @ T_WORLD_PLATE
        scene.step(T_world_plate, T_world_plate @ T_plate_sensor)
        rows.append((scene.object_slip_mm(), scene.contact_depth_mm(), scene.object_pose() if record else None))
    return rows


@pytest.mark.parametrize("name", NAMES)
def test_object_is_held_by_friction_while_the_tip_follows(name):
    with CoLiftScene(CoLiftSceneConfig(object_name=name)) as scene:
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        depth0 = scene.contact_depth_mm()
        assert scene.touching() == (True, True)
        assert 1.5 < depth0 <= 3.05  # 3 mm squeeze; a soft object gives part of it to the plate side
        T_world_object0 = scene.object_pose()
        rows = follow(scene, invert(T_WORLD_PLATE) @ T_world_sensor, duration_s=3.0)
        slips, depths = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        assert not scene.dropped()
        assert slips.max() < 2.0, f"{name} slipped {slips.max():.2f} mm relative to the plate"
        assert np.abs(depths - depth0).max() < 0.5
        # it really travelled with the plate: up 30 mm and round the circle back to its start
        travelled = scene.object_pose()[:3, 3] - T_world_object0[:3, 3]
        assert travelled == pytest.approx([0.0, 0.0, 30.0], abs=2.0)
        error = scene.pose_target_sensor()
        assert np.abs(error[:3]).max() < 0.1 and np.abs(error[3:]).max() < 0.1  # the tip is where it was sent
        assert scene.render_tactile().max() > 0


@pytest.mark.parametrize("name", NAMES)
def test_object_drops_when_the_tip_lets_go(name):
    with CoLiftScene(CoLiftSceneConfig(object_name=name)) as scene:
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        z0 = scene.object_pose()[2, 3]
        assert not scene.dropped()
        for k in range(1, 16):  # back off 15 mm along the optical axis in 0.75 s, plate still
            scene.step(T_WORLD_PLATE, T_world_sensor @ _translation(z=-min(k * 2.0, 15.0)))
        assert scene.dropped()
        assert scene.object_pose()[2, 3] < z0 - 50.0  # it fell
        assert scene.touching() == (False, False)
        assert scene.contact_depth_mm() == 0.0
        assert scene.render_tactile().max() == 0  # the tip's own sphere never shows in its image


def test_a_weak_grip_or_a_heavy_object_slips_out():
    """What holds the object is friction from the squeeze: too little squeeze or too much mass drops it."""
    period = CoLiftSceneConfig().control_period_s

    def dropped_after_lift(config: CoLiftSceneConfig, squeeze_mm: float) -> bool:
        with CoLiftScene(config) as scene:
            T_plate_sensor = invert(T_WORLD_PLATE) @ scene.reset(T_WORLD_PLATE, squeeze_mm)
            for k in range(1, 21):
                T_world_plate = _translation(z=30.0 * k * period) @ T_WORLD_PLATE
                scene.step(T_world_plate, T_world_plate @ T_plate_sensor)
            return scene.dropped()

    assert not dropped_after_lift(CoLiftSceneConfig(object_name="prism", mass_kg=0.15), 3.0)
    assert dropped_after_lift(CoLiftSceneConfig(object_name="prism", mass_kg=0.5), 3.0)
    assert dropped_after_lift(CoLiftSceneConfig(object_name="prism"), 0.2)


@pytest.mark.parametrize("name", NAMES)
def test_image_shows_the_physics_depth(name):
    config = CoLiftSceneConfig(object_name=name)
    with CoLiftScene(config) as scene:
        scene.reset(T_WORLD_PLATE)
        image = scene.render_tactile()
        assert image.shape == (128, 128) and image.dtype == np.uint8
        image_depth_mm = image.max() * config.tactip.full_scale_mm / 255.0
        assert image_depth_mm == pytest.approx(scene.contact_depth_mm(), abs=0.3)
        assert scene.render_tactile(64).shape == (64, 64)


def test_masses_are_configurable():
    assert {spec.mass_kg for spec in OBJECTS.values()} == {0.03}
    with World() as world:
        body = spawn_object(world, object_spec("egg", mass_kg=0.045), np.eye(4))
        assert world.client.getDynamicsInfo(body, -1)[0] == pytest.approx(0.045)
    with CoLiftScene(CoLiftSceneConfig(object_name="ducky", mass_kg=0.02)) as scene:
        scene.reset(T_WORLD_PLATE)
        assert scene.world.client.getDynamicsInfo(scene._object, -1)[0] == pytest.approx(0.02)
    with pytest.raises(ValueError, match="mass_kg"):
        CoLiftSceneConfig(mass_kg=0.0)


def test_bad_names_and_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match=r"unknown object 'teapot'.*\['brain', 'ducky', 'egg', 'prism'\]"):
        CoLiftSceneConfig(object_name="teapot")
    with pytest.raises(ValueError, match="unknown object 'teapot'"):
        object_spec("teapot")
    with pytest.raises(ValueError, match="squeeze_mm"):
        CoLiftSceneConfig(squeeze_mm=-1.0)
    with pytest.raises(ValueError, match="substeps"):
        CoLiftSceneConfig(substeps=0)
    with pytest.raises(ValueError, match="skin_shear_stiffness_npm must be >= 0 N/m, got -1"):
        CoLiftSceneConfig(skin_shear_stiffness_npm=-1.0)
    with pytest.raises(ValueError, match="tip rolling arm -2.0 mm"):
        CoLiftSceneConfig(tip_rolling_arm_mm=-2.0)
    with CoLiftScene() as scene:
        with pytest.raises(RuntimeError, match="reset"):
            scene.step(T_WORLD_PLATE, T_WORLD_PLATE)
        with pytest.raises(ValueError, match="T_world_plate must be a 4x4 rigid transform"):
            scene.reset(np.zeros((4, 4)))
        with pytest.raises(ValueError, match="squeeze_mm"):
            scene.reset(T_WORLD_PLATE, squeeze_mm=25.0)


def test_shear_is_the_skins_deflection_while_it_sticks_to_the_object():
    with CoLiftScene(CoLiftSceneConfig(object_name="prism")) as scene:
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        assert np.allclose(scene.shear_sensor(), 0.0)
        T_plate_sensor = invert(T_WORLD_PLATE) @ T_world_sensor
        follow(scene, T_plate_sensor, duration_s=1.0)  # carried together: the skin takes a share of the weight
        shear = scene.shear_sensor()
        assert abs(shear[0]) < 0.1 and abs(shear[2]) < 0.1 and abs(shear[1]) < 1.0 and np.abs(shear[3:]).max() < 0.5

        T_world_plate = _translation(*leader_path_mm(1.0)) @ T_WORLD_PLATE
        T_world_sensor = T_world_plate @ T_plate_sensor
        T_object_sensor0 = invert(scene.object_pose()) @ scene.sensor_pose()
        shear0, slip0 = scene.shear_sensor(), scene.object_slip_mm()
        # the sensor alone moves 2 mm along its own +x: the skin shears, the prism stays on the plate
        for k in range(1, 11):
            scene.step(T_world_plate, T_world_sensor @ _translation(x=0.2 * k))
        assert not scene.dropped()
        assert scene.object_slip_mm() - slip0 < 0.1
        T_object_sensor = invert(scene.object_pose()) @ scene.sensor_pose()
        moved_sensor_mm = (invert(T_object_sensor0) @ T_object_sensor)[:3, 3]  # in the sensor's earlier axes
        shear = scene.shear_sensor() - shear0
        assert 1.5 < shear[0] < 2.1
        assert shear[:3] == pytest.approx(moved_sensor_mm, abs=0.1)  # the skin creeps < 0.1 mm on the object
        skin_mm = (invert(scene.sensor_pose()) @ scene.skin_pose())[:3, 3]
        assert skin_mm[0] < -1.0  # the skin stayed behind on the object


@pytest.mark.parametrize("name", ["prism", "egg", "brain", "ducky"])
def test_a_lagging_sensor_shears_the_skin_and_leaves_the_object_on_the_plate(name):
    """3 mm of lag across the grip or downwards (the follower's errors in closed loop): every object stays put
    (< 0.5 mm) and the skin's shear shows most of the lag."""
    for axis in (0, 1):
        with CoLiftScene(CoLiftSceneConfig(object_name=name)) as scene:
            T_world_sensor = scene.reset(T_WORLD_PLATE)
            for k in range(1, 21):
                lag_mm = 0.3 * min(k, 10)
                scene.step(T_WORLD_PLATE, T_world_sensor @ _translation(**{"xy"[axis]: lag_mm}))
            assert not scene.dropped() and scene.object_slip_mm() < 0.5, (name, axis)
            assert 2.0 < scene.shear_sensor()[axis] < 3.1, (name, axis, scene.shear_sensor())


def test_a_plate_turning_under_a_round_object_rolls_it_unseen():
    """Why the co-lift paths do not turn the plate by default: a 10 deg turn about the vertical rolls the egg
    3-4 mm along the plate (its orientation held by the skin's patch) while the skin shows no shear."""
    turn = np.eye(4)
    with CoLiftScene(CoLiftSceneConfig(object_name="egg")) as scene:
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        for k in range(1, 21):
            angle = np.radians(min(k, 10))
            turn[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
            T_world_plate = T_WORLD_PLATE.copy()
            T_world_plate[:3, :3] = turn[:3, :3] @ T_WORLD_PLATE[:3, :3]
            scene.step(T_world_plate, T_world_sensor)
        assert 2.5 < scene.object_slip_mm() < 5.0 and np.abs(scene.shear_sensor()[:2]).max() < 0.5


def test_a_rigid_tip_drags_the_object_along_the_plate():
    """Without the skin's compliance (and rolling resistance) the tip's lag moves the object, not the skin."""
    config = CoLiftSceneConfig(object_name="egg", skin_shear_stiffness_npm=0.0, tip_rolling_arm_mm=0.0)
    with CoLiftScene(config) as scene:
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        for k in range(1, 11):
            scene.step(T_WORLD_PLATE, T_world_sensor @ _translation(x=0.3 * k))
        assert scene.object_slip_mm() > 1.0 and scene.shear_sensor()[0] < 0.5


def test_same_inputs_give_the_same_run():
    def run(scene: CoLiftScene):
        T_world_sensor = scene.reset(T_WORLD_PLATE)
        rows = follow(scene, invert(T_WORLD_PLATE) @ T_world_sensor, duration_s=1.5, record=True)
        return np.stack([r[2] for r in rows]), scene.render_tactile(), scene.shear_sensor()

    config = CoLiftSceneConfig(object_name="ducky")
    with CoLiftScene(config) as first, CoLiftScene(config) as second:
        a, b, c = run(first), run(second), run(first)  # a fresh scene, and the first scene reset again
    for x, y in ((a, b), (a, c)):
        assert all(np.array_equal(u, v) for u, v in zip(x, y))


def test_a_heavy_object_shows_its_weight_as_shear_follows_the_plate_and_stays_while_the_sensor_holds_still():
    """FIRM_TIP, 4 mm squeeze, rubber-padded plate: the skin carries a share of the load, a steady shear from the
    first image (counted from placement). The plate's static friction holds the 2 kg block: a plate that lifts
    drags the block along (the skin sees the move), where the plate of friction 1 slid up past it unseen. A sensor
    holding still keeps the object in place; one that moves to cancel the load's shear, as for a light object,
    walks the object along the plate."""
    from dataclasses import replace

    from simshear_gym.sim.colift_scene import FIRM_TIP

    config = CoLiftSceneConfig(object_name="prism", payload="heavy", squeeze_mm=4.0, **FIRM_TIP)
    assert config.object.mass_kg == 2.0 and config.plate_friction == 2.0
    for plate_friction, follows in ((2.0, True), (1.0, False)):
        with CoLiftScene(replace(config, plate_friction=plate_friction)) as scene:
            T_world_sensor = scene.reset(T_WORLD_PLATE)
            settled = scene.shear_sensor()
            assert settled[1] < -0.4 and abs(settled[0]) < 0.2  # the skin sags under the load
            for _ in range(30):
                scene.step(T_WORLD_PLATE, T_world_sensor)
            assert not scene.dropped() and scene.object_slip_mm() < 1.0
            assert scene.shear_sensor()[1] == pytest.approx(settled[1], abs=0.3)
            before, slip_before = scene.shear_sensor()[1], scene.object_slip_mm()
            for step in range(1, 16):  # the plate lifts 1.5 mm, the sensor holds its place
                scene.step(_translation(z=0.1 * step) @ T_WORLD_PLATE, T_world_sensor)
            seen, slid = scene.shear_sensor()[1] - before, scene.object_slip_mm() - slip_before
            if follows:  # the block went up with the plate: the skin shows the lift
                assert seen > 1.0 and slid < 0.3
            else:  # the plate slid up past the block: the skin saw almost nothing
                assert seen < 0.4 and slid > 0.4
    slips = {}
    for walk in (False, True):  # the 1.5 kg egg: 2.1 mm of the load's shear
        with CoLiftScene(replace(config, object_name="egg")) as scene:
            T_world_sensor = scene.reset(T_WORLD_PLATE)
            assert scene.shear_sensor()[1] < -1.5
            for _ in range(60):
                shear = scene.shear_sensor()
                if walk:
                    T_world_sensor = T_world_sensor @ _translation(-0.5 * shear[0], -0.5 * shear[1])
                scene.step(T_WORLD_PLATE, T_world_sensor)
            slips[walk] = scene.object_slip_mm()
    assert slips[True] > 2.0 * slips[False]  # servoing the load's shear to zero walks the object along the plate
    light = CoLiftSceneConfig(object_name="prism", shear_from_placement=True)
    with CoLiftScene(light) as scene:  # a 30 g object on the soft tip: its sag is no shear worth the name
        scene.reset(T_WORLD_PLATE)
        assert np.abs(scene.shear_sensor()[:2]).max() < 0.3
    with pytest.raises(ValueError, match="payload"):
        CoLiftSceneConfig(payload="medium")
