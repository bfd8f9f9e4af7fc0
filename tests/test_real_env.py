"""RealTactileEnv against the loopback MG400 emulator: spaces, safety refusals, dry run, camera stall, lost
connection, robot error mode, lost contact."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np
import pytest

from simshear_gym.contract import (
    ActionScale,
    TacTipMount,
    policy_spaces,
    resize_tactile,
)
from simshear_gym.real.camera import CameraSource, VirtualCamera, default_config
from simshear_gym.real.env import (
    RealEnvConfig,
    RealEnvError,
    RealTactileEnv,
    env_client,
    move_to_flange_target,
    tactile_from_frame,
    tcp_pose_from_flange,
)
from simshear_gym.real.mg400_emulator import EmulatorConfig, FaultConfig, MG400Emulator
from simshear_gym.real.safety import SafetyConfig, UnsafeSafetyConfig
from tests.clocks import wait_for

START = (300.0, 0.0, 0.0, 0.0)
PERIOD_S = 0.05


@pytest.fixture
def make_emulator() -> Iterator[Callable[..., MG400Emulator]]:
    started: list[MG400Emulator] = []

    def make(faults: FaultConfig | None = None, **overrides) -> MG400Emulator:
        settings = dict(dashboard_port=0, motion_port=0, feedback_port=0, joint_speed_deg_s=400.0)
        emu = MG400Emulator(EmulatorConfig(**{**settings, **overrides}, faults=faults or FaultConfig())).start()
        started.append(emu)
        return emu

    yield make
    for emu in started:
        emu.stop()


@pytest.fixture
def emulator(make_emulator) -> MG400Emulator:
    return make_emulator()



def tactile_camera(size: int = 128) -> VirtualCamera:
    rng = np.random.default_rng(0)
    return VirtualCamera(lambda: rng.integers(0, 256, (size, size), dtype=np.uint8))


FEEDBACK_AGE_S = 1.0  # the tests' limit on feedback age (the default 0.1 s is the real arm's 8 ms stream's)


def make_env(emu: MG400Emulator, camera=None, **overrides) -> RealTactileEnv:
    settings = dict(client=env_client("127.0.0.1", emu.dashboard_port, emu.motion_port, emu.feedback_port),
                    control_period_s=PERIOD_S, preprocess=None,
                    start_pose_mm_deg=START, image_size_px=64)
    contact_check = overrides.pop("contact_check", None)
    safety = overrides.get("safety", SafetyConfig())
    if safety.max_feedback_age_s == SafetyConfig().max_feedback_age_s:
        # the emulator's feedback thread shares this process with the test: on a busy machine it can lag 0.1 s (the
        # real arm's default); a dropped link still stops at once (test_lost_connection_stops_safely)
        overrides["safety"] = replace(safety, max_feedback_age_s=FEEDBACK_AGE_S)
    config = RealEnvConfig(**{**settings, **overrides})
    camera = camera if camera is not None else tactile_camera()
    return RealTactileEnv(config, camera=camera, contact_check=contact_check)


def servo_commands(emu: MG400Emulator) -> list[str]:
    return [c for c in emu.received_commands("motion") if c.lower().startswith("servop")]


# -- spaces and pure pieces ------------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [64, 128])
def test_spaces_equal_the_sim_envs(size):
    from simshear_gym.envs.tracking import SimShearTrackingEnv

    sim = SimShearTrackingEnv(obs_mode="real", image_size_px=size)
    try:
        real = RealTactileEnv(RealEnvConfig(image_size_px=size, preprocess=None))  # connects only on reset
        assert real.observation_space == sim.observation_space
        assert real.action_space == sim.action_space
        assert policy_spaces(size) == (sim.observation_space, sim.action_space)
        assert real.action_scale == sim.action_scale
    finally:
        sim.close()


def test_action_moves_the_sensor_in_its_own_frame_like_the_sim_env():
    mount = TacTipMount()
    flange = np.array([300.0, 10.0, 0.0, 30.0])
    tcp = tcp_pose_from_flange(flange, mount)
    assert tcp[:3] == pytest.approx([300.0, 10.0, -mount.tcp_offset_mm])
    # +z of the sensor points down (into the contact): dz = +1 moves the flange down by 1 mm
    assert move_to_flange_target(flange, (0, 0, 1.0, 0), mount) == pytest.approx([300, 10, -1, 30])
    # sensor x is the flange x (turned by R); sensor y is minus the flange y; sensor +Rz is flange -R
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    assert move_to_flange_target(flange, (1.0, 0, 0, 0), mount) == pytest.approx([300 + c, 10 + s, 0, 30])
    assert move_to_flange_target(flange, (0, 1.0, 0, 0), mount) == pytest.approx([300 + s, 10 - c, 0, 30])
    assert move_to_flange_target(flange, (0, 0, 0, 2.0), mount) == pytest.approx([300, 10, 0, 28])


def test_tactile_from_frame_preprocesses_raw_frames_and_halves_like_the_sim():
    rng = np.random.default_rng(1)
    raw = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    image = tactile_from_frame(raw, default_config(), 128)
    assert image.shape == (128, 128) and image.dtype == np.uint8 and set(np.unique(image)) <= {0, 255}
    tactile = rng.integers(0, 256, (128, 128), dtype=np.uint8)
    half = resize_tactile(tactile, 64)
    assert half.shape == (64, 64)
    assert half[3, 5] == np.rint(tactile[6:8, 10:12].mean())
    assert tactile_from_frame(tactile, None, 128) is tactile


def test_config_validation_names_the_value():
    with pytest.raises(ValueError, match="start_pose_mm_deg"):
        RealEnvConfig(start_pose_mm_deg=(600.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="image_size_px"):
        RealEnvConfig(image_size_px=96)
    with pytest.raises(ValueError, match="dry_run on RealEnvConfig"):
        RealEnvConfig(safety=SafetyConfig(dry_run=True))
    with pytest.raises(ValueError, match="control_period_s"):
        RealEnvConfig(control_period_s=0.0)


# -- against the emulator ----------------------------------------------------------------------------------------


def test_reset_moves_to_the_start_pose_and_steps_send_servo_p(emulator):
    env = make_env(emulator)
    try:
        obs, info = env.reset()
        assert env.observation_space.contains(obs)
        assert emulator.pose == pytest.approx(START, abs=1e-6)
        assert obs["tcp_pose"] == pytest.approx(tcp_pose_from_flange(START, TacTipMount()), abs=1e-3)
        motion = emulator.received_commands("motion")
        assert motion[0].startswith("MovJ(300,0,0,0,SpeedJ=")
        start = time.monotonic()
        for _ in range(5):
            obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0, 0.5, 0.0], np.float32))
            assert not terminated and not truncated and reward == 0.0
            assert env.observation_space.contains(obs)
        elapsed = time.monotonic() - start
        assert elapsed >= 5 * PERIOD_S * 0.9  # paced at the control period (a lower bound: a busy machine only adds)
        commands = servo_commands(emulator)
        assert len(commands) == 5 == info["commands_sent"]
        assert commands[0].endswith(f"t={PERIOD_S + RealEnvConfig().servo_margin_s:g})")
        # five full-scale steps: +5 mm along sensor x (flange x at R=0), +2.5 mm into the contact (flange -z)
        assert info["flange_target_mm_deg"] == pytest.approx([305.0, 0.0, -2.5, 0.0], abs=1e-6)
        assert wait_for(lambda: emulator.pose == pytest.approx([305.0, 0.0, -2.5, 0.0], abs=1e-3))
    finally:
        env.close()


def test_too_large_step_is_refused_never_sent_and_ends_the_episode(emulator):
    env = make_env(emulator, action_scale=ActionScale(step_mm=4.0), safety=SafetyConfig(max_step_mm=5.0))
    try:
        env.reset()
        obs, _, terminated, _, info = env.step(np.array([0.5, 0.0, 0.0, 0.0]))  # 2 mm: fine
        assert not terminated
        obs, _, terminated, _, info = env.step(np.array([1.0, 1.0, 0.0, 0.0]))  # 5.66 mm > 5 mm
        assert terminated and info["termination"] == "safety_refused"
        assert "max_step_mm" in info["safety_event"] and "not sent" in info["safety_event"]
        assert len(servo_commands(emulator)) == 1
        assert info["flange_target_mm_deg"] == pytest.approx([302.0, 0.0, 0.0, 0.0])
        with pytest.raises(RuntimeError, match="safety_refused"):
            env.step(np.zeros(4))
        time.sleep(0.1)
        assert len(servo_commands(emulator)) == 1
    finally:
        env.close()


def test_target_outside_the_workspace_is_refused_and_never_sent(emulator):
    safety = SafetyConfig(z_range_mm=(-1.5, 150.0))
    env = make_env(emulator, safety=safety)
    try:
        env.reset()
        terminated, info, steps = False, {}, 0
        while not terminated:  # full scale into the contact: -1 mm of flange z per step
            _, _, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0, 0.0]))
            steps += 1
        assert steps == 2 and info["termination"] == "safety_refused"
        assert "z_mm = -2.000 mm is outside the workspace" in info["safety_event"]
        sent = servo_commands(emulator)
        assert len(sent) == 1 and sent[0].startswith("ServoP(300,0,-1,0")
        assert not any(",-2," in c for c in emulator.received_commands())
    finally:
        env.close()


def test_target_beyond_the_arms_reach_is_refused(emulator):
    # a workspace wider than the safe default, and a 141 mm move to the start: loosened by name
    env = make_env(emulator, start_pose_mm_deg=(441.0, 0.0, 0.0, 0.0), action_scale=ActionScale(step_mm=4.0),
                   safety=UnsafeSafetyConfig(x_range_mm=(150.0, 500.0), radius_range_mm=(180.0, 500.0),
                                             max_move_mm=200.0, max_move_deg=90.0))
    try:
        env.reset()
        _, _, terminated, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0]))  # flange x 445: out of reach
        assert terminated and info["termination"] == "safety_refused"
        assert "beyond the arm's limits" in info["safety_event"]
        assert servo_commands(emulator) == []
    finally:
        env.close()


def test_start_pose_is_validated_by_the_safety_layer_on_reset(make_emulator):
    emulator = make_emulator(initial_joints_deg=(0.0, 0.0, 0.0, 0.0))  # the flange 118 mm from START
    env = make_env(emulator)  # the safe default jump: max_move_mm = 50
    try:
        with pytest.raises(Exception, match=r"step of 119.080 mm .* exceeds max_move_mm = 50 mm"):
            env.reset()
        assert emulator.received_commands("motion") == []
    finally:
        env.close()


def test_dry_run_sends_nothing(emulator):
    env = make_env(emulator, dry_run=True)
    try:
        pose_before = emulator.pose
        obs, info = env.reset()
        for _ in range(3):
            obs, _, terminated, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0]))
            assert not terminated
        assert emulator.received_commands("motion") == []
        dashboard = [c.split("(")[0].lower() for c in emulator.received_commands("dashboard")]
        assert set(dashboard) <= {"robotmode", "geterrorid", "getpose", "getangle"}
        assert emulator.pose == pose_before
        assert info["commands_sent"] == 0 and info["dry_run"]
        # the dry-run target still advances from the start pose, as if sent
        assert info["flange_target_mm_deg"] == pytest.approx([303.0, 0.0, 0.0, 0.0])
    finally:
        env.close()


class _StallingCapture:
    """A live capture that delivers ``frames`` frames, then blocks (a stalled camera)."""

    def __init__(self, frames: int) -> None:
        self.left = frames
        self.released = threading.Event()

    def read(self):
        if self.left > 0:
            self.left -= 1
            time.sleep(0.01)
            return True, np.full((128, 128), 200, np.uint8)
        self.released.wait(5.0)
        return False, None

    def release(self) -> None:
        self.released.set()


def test_camera_stall_stops_safely(emulator):
    camera = CameraSource.from_capture(_StallingCapture(frames=3), name="stalling camera", stall_timeout_s=0.2)
    env = make_env(emulator, camera=camera)
    try:
        env.reset()
        terminations = []
        for _ in range(5):
            _, _, terminated, _, info = env.step(np.zeros(4))
            if terminated:
                terminations.append(info)
                break
        assert terminations and terminations[0]["termination"] == "camera_stall"
        assert "stalled" in terminations[0]["safety_event"]
        sent = len(servo_commands(emulator))
        time.sleep(0.15)
        assert len(servo_commands(emulator)) == sent  # nothing more after the stop
    finally:
        env.close()


def test_slow_camera_frames_stop_on_frame_age(emulator):
    slow = {"delay": 0.0}

    def render():
        time.sleep(slow["delay"])
        return np.zeros((128, 128), np.uint8)

    env = make_env(emulator, camera=VirtualCamera(render), safety=SafetyConfig(max_camera_frame_age_s=0.2))
    try:
        env.reset()
        assert not env.step(np.zeros(4))[2]
        slow["delay"] = 0.3
        _, _, terminated, _, info = env.step(np.zeros(4))
        assert terminated and info["termination"] == "camera_stall"
        assert "max_camera_frame_age_s" in info["safety_event"]
    finally:
        env.close()


def test_lost_connection_stops_safely(emulator):
    env = make_env(emulator)
    try:
        env.reset()
        env.step(np.zeros(4))
        emulator.drop_connections()
        time.sleep(0.05)
        _, _, terminated, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0]))
        assert terminated and info["termination"] == "lost_connection"
        with pytest.raises(RuntimeError, match="lost_connection"):
            env.step(np.zeros(4))
        # a new episode reconnects
        obs, _ = env.reset()
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_robot_error_mode_stops_and_blocks_reset(make_emulator):
    # a collision alarm 60 ms into the first motion that lasts that long: the first ServoP (t = 120 ms, period
    # 100 ms); the move to the start pose is faster than that
    emulator = make_emulator(FaultConfig(alarm_during_motion=112, alarm_after_s=0.06), joint_speed_deg_s=5000.0)
    env = make_env(emulator, control_period_s=0.1)
    try:
        env.reset()
        assert emulator.alarms == ()
        infos = [env.step(np.array([0.5, 0.0, 0.0, 0.0]))[4]]
        while not infos[-1]["termination"] and len(infos) < 5:
            infos.append(env.step(np.zeros(4))[4])
        assert infos[-1]["termination"] == "robot_error"
        assert "error mode" in infos[-1]["safety_event"] or "ErrorID" in infos[-1]["safety_event"]
        assert emulator.alarms == (112,)
        with pytest.raises(RealEnvError, match="error mode"):
            env.reset()
    finally:
        env.close()


def test_lost_contact_from_the_callback_stops(emulator):
    touching = {"value": True}
    env = make_env(emulator, contact_check=lambda obs: touching["value"])
    try:
        env.reset()
        _, _, terminated, _, info = env.step(np.zeros(4))
        assert not terminated and info["in_contact"] is True
        touching["value"] = False
        _, _, terminated, _, info = env.step(np.zeros(4))
        assert terminated and info["termination"] == "lost_contact" and info["in_contact"] is False
    finally:
        env.close()


def test_actions_outside_the_space_raise(emulator):
    env = make_env(emulator)
    try:
        env.reset()
        with pytest.raises(ValueError, match=r"\[-1, 1\]"):
            env.step(np.array([1.5, 0.0, 0.0, 0.0]))
        with pytest.raises(ValueError, match="shape"):
            env.step(np.zeros(3))
        assert servo_commands(emulator) == []
    finally:
        env.close()


def test_joint_feedback_that_disagrees_with_the_pose_ends_the_episode_and_a_reset_recovers(emulator):
    from simshear_gym.real.mg400_emulator import FeedbackFault

    env = make_env(emulator)
    try:
        env.reset()
        assert not env.step(np.array([0.5, 0.0, 0.0, 0.0]))[2]
        emulator.set_faults(FaultConfig(corrupt_feedback_every=1, feedback_faults=(FeedbackFault.INCONSISTENT,)))
        infos = [env.step(np.array([0.5, 0.0, 0.0, 0.0]))[4]]
        while not infos[-1]["termination"] and len(infos) < 4:
            infos.append(env.step(np.array([0.5, 0.0, 0.0, 0.0]))[4])
        assert infos[-1]["termination"] == "feedback_mismatch"
        assert "max_pose_mismatch_mm" in infos[-1]["safety_event"]
        sent = len(servo_commands(emulator))
        time.sleep(0.1)
        assert len(servo_commands(emulator)) == sent
        before = emulator.received_commands("motion")
        with pytest.raises(Exception, match="max_pose_mismatch_mm"):
            env.reset()  # still disagreeing: nothing is sent
        assert emulator.received_commands("motion") == before
        emulator.set_faults(FaultConfig())
        time.sleep(0.05)
        env.reset()  # agreeing again: a new episode
        assert not env.step(np.zeros(4))[2]
    finally:
        env.close()


def test_an_action_that_is_not_finite_is_refused_and_never_sent(emulator):
    env = make_env(emulator)
    try:
        env.reset()
        _, _, terminated, _, info = env.step(np.array([np.nan, 0.0, 0.0, 0.0]))
        assert terminated and info["termination"] == "safety_refused"
        assert "not finite" in info["safety_event"] and servo_commands(emulator) == []
    finally:
        env.close()


class _RendersOnRead(VirtualCamera):
    renders_on_read = True


def test_a_camera_that_renders_on_read_is_not_aged_by_the_wall_clock(emulator):
    """A slow render (the computer's speed, as on a loaded machine) is no camera stall for a source that makes its
    frame when read; its frames carry no age. The same render from a camera on its own clock stops (above)."""
    slow = {"delay": 0.0}

    def render():
        time.sleep(slow["delay"])
        return np.zeros((128, 128), np.uint8)

    # the feedback's age is not this test's: generous, so that only the camera could stop the episode
    env = make_env(emulator, camera=_RendersOnRead(render),
                   safety=SafetyConfig(max_camera_frame_age_s=0.2, max_feedback_age_s=5.0))
    try:
        env.reset()
        slow["delay"] = 0.3
        for _ in range(2):
            _, _, terminated, _, info = env.step(np.zeros(4))
            assert not terminated, info.get("safety_event")
            assert info["camera_frame_age_s"] is None
    finally:
        env.close()


def test_frozen_camera_frames_stop_the_episode(emulator):
    frame = np.full((128, 128), 90, np.uint8)
    env = make_env(emulator, camera=VirtualCamera(lambda: frame.copy()), frozen_frame_limit=3)
    try:
        env.reset()  # frame 1
        assert not env.step(np.zeros(4))[2]  # frame 2, the same
        _, _, terminated, _, info = env.step(np.zeros(4))  # frame 3, the same
        assert terminated and info["termination"] == "camera_stall"
        assert "3 identical frames in a row" in info["safety_event"]
    finally:
        env.close()
    with pytest.raises(ValueError, match="frozen_frame_limit"):
        RealEnvConfig(frozen_frame_limit=1)
