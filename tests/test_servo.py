"""Servo control: the PI law on a moving contact, anti-windup, and the estimator + law on images."""

import numpy as np
import pytest
import torch

from simshear_gym.contract import ActionScale
from simshear_gym.control.estimator import (
    STATE_VARIABLES,
    EstimatorConfig,
    TactileEstimator,
)
from simshear_gym.control.pi_law import PIGains, PILaw
from simshear_gym.control.servo import SERVO_GAINS, ServoController
from simshear_gym.models.gdnn import GDNN, GDNNConfig
from simshear_gym.models.posenet_io import save_posenet

torch.set_num_threads(1)
SCALE = np.array([1.0, 1.0, 1.0, 2.0])


def test_pi_law_removes_the_lag_behind_a_ramp():
    """The contact drifts 0.3 mm per step in x; the law's moves keep the sensor on its target with no lag."""
    law = PILaw(reference_depth_mm=4.0, action_scale=SCALE, gains=PIGains(kp=(1, 1, 1, 1), ki=(0.5, 0.5, 0.5, 0.5)))
    offset = 0.0  # sensor displacement from its target = shear x
    history = []
    for _ in range(60):
        action = law(np.array([4.0, offset, 0.0, 0.0]))
        offset += action[0] * SCALE[0] - 0.3  # our move, minus the contact's drift
        history.append(offset)
    assert abs(history[-1]) < 1e-3
    proportional = PILaw(4.0, SCALE, PIGains(kp=(1, 1, 1, 1), ki=(0, 0, 0, 0)))
    offset = 0.0
    for _ in range(60):
        offset += proportional(np.array([4.0, offset, 0.0, 0.0]))[0] - 0.3
    assert offset == pytest.approx(-0.3, abs=1e-3)  # a P law keeps one step's drift behind


def test_the_velocity_form_fed_its_own_last_action_is_the_pi_law():
    rng = np.random.default_rng(0)
    law = PILaw(4.0, SCALE, PIGains(kp=(0.6, 0.6, 0.5, 0.0), ki=(0.2, 0.2, 0.1, 0.0), integral_limit=10.0))
    twin = PILaw(4.0, SCALE, law.gains)
    previous, last = np.array([4.0, 0.0, 0.0, 0.0]), np.zeros(4)
    for step in range(30):
        state = np.array([4.0 + rng.normal(0, 0.2), *rng.normal(0, 0.3, 2), rng.normal(0, 1.0)])
        action = law(state)
        velocity = twin.velocity_form(state, state if step == 0 else previous, last)
        if step:  # the first step: the velocity form has no earlier error to take the change from
            np.testing.assert_allclose(velocity, action, atol=1e-6)
        assert velocity[3] == 0.0  # Rz: both gains 0, not controlled
        previous, last = state, action
    np.testing.assert_array_equal(twin.velocity_form(np.array([9.0, 50.0, -50.0, 0.0]), previous, np.ones(4)),
                                  np.array([-1.0, 1.0, -1.0, 0.0], np.float32))  # clipped, as the law
    with pytest.raises(ValueError, match="last_action must be 4 finite values"):
        twin.velocity_form(previous, previous, np.array([np.nan, 0, 0, 0]))


def test_pi_law_depth_sign_saturation_and_anti_windup():
    law = PILaw(4.0, SCALE, PIGains(kp=(1, 1, 1, 1), ki=(0.5, 0.5, 0.5, 0.5), integral_limit=1.0))
    action = law(np.array([3.0, 0.0, 0.0, 0.0]))  # 1 mm too shallow: push in (+z)
    assert action[2] > 0 and np.all(np.abs(action) <= 1)
    for _ in range(200):  # a stuck, large error saturates; the integral stays bounded
        law(np.array([4.0, 50.0, 0.0, 0.0]))
    assert np.abs(law._integral[0] * 0.5) <= 1.0 + 1e-9
    with pytest.raises(ValueError, match="4 finite values"):
        law(np.array([np.nan, 0, 0, 0]))
    with pytest.raises(ValueError, match="kp and ki need 4"):
        PIGains(kp=(1, 1, 1))


@pytest.fixture(scope="module")
def tiny_posenet(tmp_path_factory):
    torch.manual_seed(0)
    return save_posenet(tmp_path_factory.mktemp("gdnn") / "gdnn.pt", GDNN(GDNNConfig(variables="surface")).eval())


def test_estimator_reads_filters_and_rejects_bad_images(tiny_posenet):
    estimator = TactileEstimator(EstimatorConfig(posenet=str(tiny_posenet)))
    image = np.zeros((1, 128, 128), np.uint8)
    mean, std = estimator(image)
    assert mean.shape == std.shape == (len(STATE_VARIABLES),) and np.all(std > 0)
    _, filtered_std = estimator(image, commanded_move=np.zeros(4))
    assert np.all(filtered_std < std)  # a second consistent reading narrows the belief
    with pytest.raises(ValueError, match="uint8"):
        estimator(np.zeros((128, 128), np.float32))


def test_servo_controller_gives_bounded_actions(tiny_posenet):
    controller = ServoController(4.0, ActionScale(step_mm=1.0, step_deg=2.0), SERVO_GAINS,
                                EstimatorConfig(posenet=str(tiny_posenet)))
    controller.reset()
    for _ in range(3):
        action = controller({"tactile": np.random.default_rng(0).integers(0, 255, (1, 128, 128), dtype=np.uint8)})
        assert action.shape == (4,) and action.dtype == np.float32 and np.all(np.abs(action) <= 1)
    assert action[3] == 0.0  # Rz is not controlled by default
    assert controller.last_estimate is not None
    with pytest.raises(ValueError, match="tactile"):
        controller({"tcp_pose": np.zeros(4)})


def test_for_env_reads_each_env_with_its_own_shipped_gdnn_and_process_noise():
    """Tracking images are read with the shipped surface GDNN, co-lift images with the one trained on co-lift; the
    co-lift filter allows for its faster, reversing plate; an explicit setting wins."""
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401
    from simshear_gym.control.estimator import EstimatorConfig

    for env_id, variables, process_mm in (("SimShearTracking-v0", "surface", None), ("SimShearCoLift-v0", "env", 1.5)):
        env = gym.make(env_id, obs_mode="sim")
        try:
            controller = ServoController.for_env(env)
            assert controller.estimator.model.variables.name == variables, env_id
            assert controller.estimator.config.process_std_mm == process_mm, env_id
            explicit = ServoController.for_env(env, estimator=EstimatorConfig(process_std_mm=0.7))
            assert explicit.estimator.config.process_std_mm == 0.7
        finally:
            env.close()


def test_the_law_holds_a_shear_reference_and_the_servo_holds_its_first_reading_when_asked(tiny_posenet):
    """hold_load: the shear of the episode's first estimate becomes the law's reference (a heavy co-lift's load);
    reset forgets it; without hold_load the reference stays zero."""
    law = PILaw(4.0, np.ones(4), PIGains(kp=(1.0, 1.0, 1.0, 0.0), ki=(0.0, 0.0, 0.0, 0.0)))
    law.shear_reference_mm = np.array([0.5, -3.0])
    np.testing.assert_allclose(law(np.array([4.0, 0.5, -3.0, 0.0])), 0.0)
    law.reset()
    np.testing.assert_allclose(law.shear_reference_mm, 0.0)

    rng = np.random.default_rng(0)
    image = {"tactile": rng.integers(0, 255, (1, 128, 128), dtype=np.uint8)}
    for hold_load in (False, True):
        controller = ServoController(estimator=EstimatorConfig(posenet=str(tiny_posenet), filtered=False),
                                     hold_load=hold_load)
        controller.reset()
        controller(image)
        first = controller.last_estimate[0][1:3]
        expected = first if hold_load else np.zeros(2)
        np.testing.assert_allclose(controller.law.shear_reference_mm, expected)
        controller({"tactile": rng.integers(0, 255, (1, 128, 128), dtype=np.uint8)})
        np.testing.assert_allclose(controller.law.shear_reference_mm, expected)  # kept for the episode
        controller.reset()
        np.testing.assert_allclose(controller.law.shear_reference_mm, 0.0)


def test_a_held_load_takes_the_envs_margin_and_shear_gains(tiny_posenet):
    """Heavy co-lift asks the servo to carry 0.4 mm more shear along the weight than the grasp's, with deadbeat
    shear gains; the light task and tracking keep the defaults; explicit gains win over the env's."""
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401
    from simshear_gym.control.servo import SERVO_GAINS, servo_law_for_env

    heavy = gym.make("SimShearCoLift-v0", obs_mode="sim", payload="heavy")
    light = gym.make("SimShearCoLift-v0", obs_mode="sim")
    try:
        gains, hold, margin = servo_law_for_env(heavy)
        assert hold and np.allclose(margin, [0.0, -0.4])
        assert gains.kp == (1.0, 1.0, 0.5, 0.0) and gains.ki == (0.5, 0.5, 0.1, 0.0)
        mine = PIGains(kp=(0.3, 0.3, 0.3, 0.0), ki=(0.1, 0.1, 0.1, 0.0))
        assert servo_law_for_env(heavy, mine)[0] == mine
        assert servo_law_for_env(heavy, SERVO_GAINS)[0] == SERVO_GAINS  # the defaults asked for explicitly
        assert servo_law_for_env(light) == (SERVO_GAINS, False, pytest.approx(np.zeros(2)))
        assert servo_law_for_env(light, hold_load=True)[2] == pytest.approx(np.zeros(2))  # no margin asked
    finally:
        heavy.close()
        light.close()
    controller = ServoController(estimator=EstimatorConfig(posenet=str(tiny_posenet), filtered=False),
                                 hold_load=True, load_margin_mm=(0.0, -0.3))
    controller.reset()
    controller({"tactile": np.random.default_rng(1).integers(0, 255, (1, 128, 128), dtype=np.uint8)})
    np.testing.assert_allclose(controller.law.shear_reference_mm, controller.last_estimate[0][1:3] + [0.0, -0.3])
    with pytest.raises(ValueError, match="load_margin_mm must be 2 finite values"):
        ServoController(estimator=EstimatorConfig(posenet=str(tiny_posenet)), load_margin_mm=(0.0, np.nan))
