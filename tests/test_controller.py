"""The one controller interface (servo, oracle, SB3) driven by both rollout loops, the action scale taken the same
way by both laws, and the safety layer's stop reasons mapped to the real env's terminations without any text
matching."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from collections.abc import Iterator

import numpy as np
import pytest
import torch

from simshear_gym.contract import ActionScale
from simshear_gym.control.estimator import EstimatorConfig
from simshear_gym.control.oracle import OracleController
from simshear_gym.control.pi_law import PIGains
from simshear_gym.control.policy import Controller, EstimatingController, SB3Controller, as_action_scale
from simshear_gym.control.servo import ServoController
from simshear_gym.models.gdnn import GDNN, GDNNConfig
from simshear_gym.models.posenet_io import save_posenet
from simshear_gym.real.env import STOP_TERMINATIONS, TERMINATIONS, RealEnvConfig, RealTactileEnv, env_client
from simshear_gym.real.safety import SafetyConfig, SafetyLayer, StatusSnapshot, StopReason

torch.set_num_threads(1)


class ConstantController:
    """The trivial controller: the same action every step; counts its resets and calls."""

    def __init__(self, action=(0.0, 0.0, 0.0, 0.0)) -> None:
        self.action = np.asarray(action, dtype=np.float32)
        self.resets = 0
        self.observations: list[dict] = []

    def reset(self) -> None:
        self.resets += 1

    def __call__(self, observation: dict) -> np.ndarray:
        self.observations.append(observation)
        return self.action.copy()


class FakeSB3Model:
    """SB3's predict interface: records how it was asked, answers with a (1, 4) float64 action."""

    def __init__(self) -> None:
        self.calls: list[dict] = []

    def predict(self, observation, deterministic=False):
        self.calls.append({"observation": observation, "deterministic": deterministic})
        return np.array([[0.25, -0.5, 0.0, 1.0]]), None


@pytest.fixture(scope="module")
def tiny_posenet(tmp_path_factory):
    torch.manual_seed(0)
    return str(save_posenet(tmp_path_factory.mktemp("gdnn") / "gdnn.pt", GDNN(GDNNConfig(variables="surface")).eval()))


# -- the protocol --------------------------------------------------------------------------------------------------


def test_servo_oracle_and_sb3_controllers_are_controllers(tiny_posenet):
    servo = ServoController(4.0, ActionScale(), estimator=EstimatorConfig(posenet=tiny_posenet))
    controllers = [servo, OracleController(), SB3Controller(FakeSB3Model()), ConstantController()]
    assert all(isinstance(controller, Controller) for controller in controllers)
    # only the servo controller keeps a state estimate, which the real rollout logs
    assert [isinstance(controller, EstimatingController) for controller in controllers] == [True, False, False, False]
    assert not isinstance(lambda observation: np.zeros(4), Controller)  # no reset()
    assert not isinstance(object(), Controller)


def test_sb3_adapter_predicts_deterministically_and_gives_a_float32_action():
    model = FakeSB3Model()
    controller = SB3Controller(model, name="ppo:model.zip")
    controller.reset()
    observation = {"tactile": np.zeros((1, 64, 64), np.uint8), "tcp_pose": np.zeros(4, np.float32)}
    action = controller(observation)
    assert action.dtype == np.float32 and action.shape == (4,)
    np.testing.assert_array_equal(action, [0.25, -0.5, 0.0, 1.0])
    assert model.calls == [{"observation": observation, "deterministic": True}]
    assert controller.name == "ppo:model.zip"


def test_importing_the_controllers_does_not_import_sb3_or_torch():
    code = ("import sys, simshear_gym.control.policy, simshear_gym.control.servo, simshear_gym.control.oracle; "
            "print(sorted(m for m in ('torch', 'stable_baselines3', 'pybullet') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# -- the action scale ----------------------------------------------------------------------------------------------


def test_both_laws_take_an_action_scale_and_scale_by_it(tiny_posenet):
    scale = ActionScale(step_mm=2.0, step_deg=4.0)
    oracle = OracleController(4.0, scale)
    servo = ServoController(4.0, scale, estimator=EstimatorConfig(posenet=tiny_posenet))
    assert oracle.action_scale == servo.action_scale == scale
    np.testing.assert_array_equal(servo.law._scale, oracle.law._scale)
    # 1 mm of shear x is half a full-scale action at 2 mm per step (proportional part only: kp 1, first step)
    action = OracleController(4.0, scale, PIGains(ki=(0.0,) * 4))(
        {"true_pose_shear": np.array([4.0, 1.0, 0.0, 0.0], np.float32)})
    np.testing.assert_allclose(action, [-0.5, 0.0, 0.0, 0.0])
    with pytest.raises(TypeError, match="ServoController: action_scale must be an ActionScale"):
        as_action_scale(np.array([2.0, 2.0, 2.0, 4.0]), "ServoController")
    with pytest.raises(TypeError, match="OracleController"):
        OracleController(4.0, 1.0)


# -- the rollout loops ---------------------------------------------------------------------------------------------


def test_the_sim_rollout_loop_drives_a_constant_controller():
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401  (registers the envs)
    from simshear_gym.evaluate.servo import run_episode

    env = gym.make("SimShearTracking-v0", obs_mode="sim", image_size_px=64)
    controller = ConstantController()
    try:
        result = run_episode(env, controller, seed=0, max_steps=5)
    finally:
        env.close()
    assert controller.resets == 1 and len(controller.observations) == 5 == result["steps"]
    assert all(env.observation_space.contains(observation) for observation in controller.observations)
    target, sensor = result.pop("_paths")
    assert target.shape == sensor.shape == (5, 3)
    assert result["termination"] == "" and np.isfinite(result["contact_error_mean_mm"])


@pytest.fixture
def emulator() -> Iterator:
    from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator

    emu = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                       joint_speed_deg_s=400.0)).start()
    yield emu
    emu.stop()


def real_env(emu) -> RealTactileEnv:
    from simshear_gym.real.camera import VirtualCamera

    rng = np.random.default_rng(0)
    config = RealEnvConfig(client=env_client("127.0.0.1", emu.dashboard_port, emu.motion_port, emu.feedback_port),
                           control_period_s=0.02, preprocess=None,
                           image_size_px=64, dry_run=True)
    return RealTactileEnv(config, camera=VirtualCamera(lambda: rng.integers(0, 256, (128, 128), dtype=np.uint8)))


class EstimatingConstant(ConstantController):
    name = "constant"

    def __init__(self) -> None:
        super().__init__((0.1, 0.0, 0.0, 0.0))
        self.last_estimate = None

    def __call__(self, observation: dict) -> np.ndarray:
        self.last_estimate = (np.full(4, float(len(self.observations))), np.ones(4))
        return super().__call__(observation)


def test_the_real_rollout_loop_drives_a_constant_controller(emulator, tmp_path):
    import csv

    from simshear_gym.real.rollout import run_rollout

    for controller, with_estimate in ((ConstantController(), False), (EstimatingConstant(), True)):
        env = real_env(emulator)
        out = tmp_path / type(controller).__name__
        try:
            summary = run_rollout(env, controller, 3, out)
        finally:
            env.close()
        assert controller.resets == 1 and len(controller.observations) == 3
        assert summary["steps_run"] == 3 and summary["termination"] == "" and summary["commands_sent"] == 0
        assert summary["controller"] == getattr(controller, "name", "ConstantController")
        with open(out / "steps.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        assert [float(row["action_0"]) for row in rows[1:]] == pytest.approx([float(controller.action[0])] * 3)
        assert ("estimate_depth_mm" in rows[0]) is with_estimate
        if with_estimate:  # the estimate after each call is logged on that step's row
            assert [float(row["estimate_depth_mm"]) for row in rows[1:]] == [0.0, 1.0, 2.0]
        assert json.loads((out / "rollout.json").read_text())["controller"] == summary["controller"]
    assert emulator.received_commands("motion") == []  # dry run


# -- stop reasons --------------------------------------------------------------------------------------------------


def substring_classify(reasons: tuple[str, ...]) -> str:
    """How the real env named a status stop before the reasons had an enum: by words in the sentences."""
    text = " ".join(reasons)
    for key, name in (("connection", "lost_connection"), ("feedback", "lost_connection"),
                      ("error mode", "robot_error"), ("camera", "camera_stall"), ("contact", "lost_contact")):
        if key in text:
            return name
    return "robot_error"


ROBOT_MODE_ERROR, ROBOT_MODE_RUNNING = 9, 7
CONDITIONS: dict[StopReason, dict] = {
    StopReason.LOST_CONNECTION: {"connected": False},
    StopReason.STALE_FEEDBACK: {"feedback_age_s": 0.5},
    StopReason.ROBOT_ERROR_MODE: {"robot_mode": ROBOT_MODE_ERROR},
    StopReason.CAMERA_STALLED: {"camera_frame_age_s": 1.0},
    StopReason.LOST_CONTACT: {"in_contact": False},
}
HEALTHY = {"connected": True, "robot_mode": ROBOT_MODE_RUNNING, "feedback_age_s": 0.01, "camera_frame_age_s": 0.05,
           "in_contact": True}


def test_every_stop_reason_maps_to_the_termination_the_sentences_gave():
    safety = SafetyLayer(SafetyConfig())
    assert set(CONDITIONS) == set(StopReason) == set(STOP_TERMINATIONS)
    assert set(STOP_TERMINATIONS.values()) <= set(TERMINATIONS)
    assert safety.check_status(StatusSnapshot(**HEALTHY)).reason is None
    for reason, condition in CONDITIONS.items():
        decision = safety.check_status(StatusSnapshot(**{**HEALTHY, **condition}))
        assert decision.stop and decision.reason is reason and len(decision.reasons) == 1
        assert RealTactileEnv._classify(decision.reason) == substring_classify(decision.reasons), reason
    expected = {StopReason.LOST_CONNECTION: "lost_connection", StopReason.STALE_FEEDBACK: "lost_connection",
                StopReason.ROBOT_ERROR_MODE: "robot_error", StopReason.CAMERA_STALLED: "camera_stall",
                StopReason.LOST_CONTACT: "lost_contact"}
    assert {reason: RealTactileEnv._classify(reason) for reason in StopReason} == expected


def test_when_several_conditions_hold_the_termination_is_the_one_the_sentences_gave():
    safety = SafetyLayer(SafetyConfig())
    for count in range(2, len(CONDITIONS) + 1):
        for reasons in itertools.combinations(CONDITIONS, count):
            snapshot = StatusSnapshot(**{**HEALTHY, **{k: v for r in reasons for k, v in CONDITIONS[r].items()}})
            decision = safety.check_status(snapshot)
            assert RealTactileEnv._classify(decision.reason) == substring_classify(decision.reasons), reasons
            assert decision.reason is min(decision.stops, key=lambda s: list(StopReason).index(s.reason)).reason
