"""Hardware in the loop: the whole real path closes over the MG400 emulator.

simulated TacTip (sim render + shear + shipped shPix2pix, as a 640x480 camera frame) -> preprocessing -> GDNN +
Bayesian filter + PI law (ServoController) -> ServoP over TCP -> emulator (realistic 125 Hz feedback and ServoP
interpolation) -> the arm's new pose -> the simulated camera. The surface moves 20 mm; the follower must stay on it.
"""

from __future__ import annotations

import numpy as np
import pytest

from simshear_gym.real.camera import default_config
from simshear_gym.real.env import RealEnvConfig, RealTactileEnv, env_client, tcp_pose_from_flange
from simshear_gym.real.hil import MovingSurfaceConfig, SimSurfaceCamera, embed_in_frame
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
from simshear_gym.real.safety import SafetyConfig

START = (300.0, 0.0, 0.0, 0.0)
RATE_HZ = 15.0
STEPS = 150  # 10 s
VELOCITY_MM_S = (2.0, 1.0, 0.0)
TRAVEL_MM = 20.0


def posenet_path() -> str:
    """The shipped surface GDNN (the one the servo controller uses by default)."""
    from simshear_gym.models.zoo import posenet_weights

    return str(posenet_weights("surface"))


def test_sim_camera_frame_survives_the_real_preprocessing():
    camera = SimSurfaceCamera(lambda: (300.0, 0.0, -1.0, 0.0), START, MovingSurfaceConfig(velocity_mm_s=(0, 0, 0)))
    try:
        image = camera.read()
        truth = camera.history[-1]
        assert image.shape == (128, 128) and image.dtype == np.uint8
        assert truth.in_contact and truth.penetration_mm == pytest.approx(2.8)
        assert truth.contact_error_mm == pytest.approx(1.0)
        from simshear_gym.real.camera import preprocess

        back = preprocess(embed_in_frame(image, default_config()), default_config())
        assert np.mean((back > 127) == (image > 127)) > 0.98
    finally:
        camera.close()


def test_servo_controller_follows_a_moving_surface_through_the_emulator(tmp_path):
    import torch

    from simshear_gym.contract import ActionScale
    from simshear_gym.control.estimator import EstimatorConfig
    from simshear_gym.control.servo import ServoController
    from simshear_gym.real.rollout import run_rollout

    torch.set_num_threads(1)
    controller = ServoController(4.0, ActionScale(step_mm=1.0, step_deg=2.0),
                                 estimator=EstimatorConfig(posenet=posenet_path()))
    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0)).start()
    preprocess_config = default_config()
    camera = SimSurfaceCamera(lambda: emulator.pose, START,
                              MovingSurfaceConfig(velocity_mm_s=VELOCITY_MM_S, max_travel_mm=TRAVEL_MM),
                              raw_frame_layout=preprocess_config)
    config = RealEnvConfig(client=env_client("127.0.0.1", emulator.dashboard_port, emulator.motion_port,
                                             emulator.feedback_port),
                           control_period_s=1.0 / RATE_HZ, preprocess=preprocess_config, image_size_px=64,
                           start_pose_mm_deg=START,
                           # the emulator, the render and the translation share this process on 2 cores: a 0.1 s
                           # stall of the feedback thread is the test machine's, not the link's (the stop on stale
                           # feedback has its own test, test_real_env.py::test_lost_connection_stops_safely)
                           safety=SafetyConfig(max_feedback_age_s=0.5),
                           frozen_frame_limit=None)  # a noise-free simulated camera: equal frames are no fault
    env = RealTactileEnv(config, camera=camera)
    try:
        summary = run_rollout(env, controller, STEPS, tmp_path, command="test_hil")
    finally:
        env.close()
        emulator.stop()

    assert summary["termination"] == "" and summary["safety_events"] == []
    assert summary["steps_run"] == STEPS and summary["commands_sent"] == STEPS
    history = camera.history
    errors = np.array([h.contact_error_mm for h in history])
    offsets = np.array([h.surface_offset_mm for h in history])
    travel = float(np.linalg.norm(offsets[-1]))
    assert travel == pytest.approx(TRAVEL_MM, abs=0.5)  # the surface went all the way
    assert all(h.in_contact for h in history)
    assert all(0.5 < h.penetration_mm < 3.5 for h in history)  # reference 1.8 mm into the surface
    assert errors.max() < 2.0 and errors.mean() < 1.0, (errors.max(), errors.mean())  # vs 20 mm of travel
    # the arm itself went along with the surface (not just the error metric): TCP displacement ~ surface travel
    tcp_moved = tcp_pose_from_flange(history[-1].flange_pose_mm_deg, env.config.mount)[:3] - \
        tcp_pose_from_flange(START, env.config.mount)[:3]
    assert np.linalg.norm(tcp_moved - offsets[-1]) < 2.0
    assert summary["truth_contact_error_mm"]["max"] < 2.0
    print(f"HIL: surface travel {travel:.1f} mm, contact error mean {errors.mean():.3f} mm, max {errors.max():.3f} mm,"
          f" final {errors[-1]:.3f} mm; period overruns {summary['period_overruns']}, policy "
          f"{summary['policy_ms_median']} ms median")
    assert (tmp_path / "steps.csv").is_file() and (tmp_path / "trajectory.png").is_file()
