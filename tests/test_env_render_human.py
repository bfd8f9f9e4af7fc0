"""``render_mode="human"``: a window with the scene and the tactile image, tested on a virtual display (Xvfb): the
window shows the env's ``rgb_array`` frame pixel for pixel (a screenshot of the display, kept in the test's
artifacts: ``$SIMSHEAR_TEST_ARTIFACTS`` or the test's tmp folder), frames are paced to the control rate on an
injected clock, and without a display the env runs on while one warning says what to do."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import simshear_gym.envs  # noqa: F401  (registers the envs)
from simshear_gym.envs.viewer import HumanViewer


@pytest.fixture(scope="module")
def display():
    """A virtual X display for this module's tests, or a skip that says why there is none."""
    if shutil.which("Xvfb") is None:
        pytest.skip("no X server to open a window on: Xvfb is not installed (apt-get install -y xvfb)")
    for number in range(91, 120):
        if not Path(f"/tmp/.X11-unix/X{number}").exists() and not Path(f"/tmp/.X{number}-lock").exists():
            break
    else:
        pytest.skip("no free X display number in :91-:119 for Xvfb")
    server = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    socket = Path(f"/tmp/.X11-unix/X{number}")
    for _ in range(200):  # until the server listens (or it died)
        if socket.exists() or server.poll() is not None:
            break
        time.sleep(0.05)
    if not socket.exists():
        server.kill()
        pytest.skip(f"Xvfb :{number} did not start: {server.stderr.read().decode(errors='replace')[-300:]}")
    yield f":{number}"
    server.terminate()
    server.wait(timeout=10)


def artifacts(tmp_path: Path) -> Path:
    folder = Path(os.environ.get("SIMSHEAR_TEST_ARTIFACTS", tmp_path))
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.mark.slow
def test_human_mode_opens_a_window_showing_the_scene_and_the_tactile_image(display, monkeypatch, tmp_path):
    from PIL import ImageGrab

    monkeypatch.setenv("DISPLAY", display)
    env = gym.make("SimShearTracking-v0", render_mode="human", obs_mode="sim", image_size_px=64)
    try:
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(4, dtype=np.float32))
        base = env.unwrapped
        viewer = base._viewer
        assert viewer is not None and viewer.frames_shown == 4  # the reset and every step
        assert base.render() is None and viewer.frames_shown == 5  # human mode returns nothing
        frame = np.concatenate([base._scene_view(), base._tactile_view()], axis=1)  # what rgb_array returns
        root, label = viewer._root, viewer._label
        root.update()
        x, y = label.winfo_rootx(), label.winfo_rooty()
        height, width = frame.shape[0] * viewer.zoom, frame.shape[1] * viewer.zoom
        assert (label.winfo_width(), label.winfo_height()) == (width, height)
        screen = ImageGrab.grab(xdisplay=display)
        screen.save(artifacts(tmp_path) / "render_human_screenshot.png")
        shown = np.asarray(screen.convert("RGB"))[y:y + height, x:x + width]
        expected = frame.repeat(viewer.zoom, axis=0).repeat(viewer.zoom, axis=1)
        assert shown.shape == expected.shape
        assert np.abs(shown.astype(int) - expected.astype(int)).max() <= 2
        assert root.title().startswith("SimShearTracking-v0: scene | tactile")
    finally:
        env.close()
    assert env.unwrapped._viewer is None


def test_frames_are_paced_to_the_control_rate_on_the_viewers_clock(display, monkeypatch):
    monkeypatch.setenv("DISPLAY", display)
    now, waits = [100.0], []

    def sleep(seconds: float) -> None:
        waits.append(round(seconds, 6))
        now[0] += seconds

    viewer = HumanViewer("pacing", fps=10.0, zoom=1, clock=lambda: now[0], sleep=sleep)
    frame = np.zeros((4, 6, 3), dtype=np.uint8)
    try:
        viewer.show(frame)  # the first frame: no wait
        now[0] += 0.03  # 30 ms of stepping: wait the other 70
        viewer.show(frame)
        now[0] += 0.25  # slower than the rate: no wait
        viewer.show(frame)
    finally:
        viewer.close()
    assert waits == [0.07] and viewer.frames_shown == 3
    with pytest.raises(ValueError, match="RGB uint8"):
        viewer.show(np.zeros((4, 6), dtype=np.uint8))


def test_without_a_display_the_env_runs_on_and_one_warning_says_what_to_do(monkeypatch, caplog):
    monkeypatch.delenv("DISPLAY", raising=False)
    viewer = HumanViewer("no display", fps=10.0)
    with caplog.at_level("WARNING", logger="simshear_gym.envs.viewer"):
        for _ in range(3):
            viewer.show(np.zeros((4, 6, 3), dtype=np.uint8))
    messages = [record.getMessage() for record in caplog.records]
    assert len(messages) == 1 and "xvfb-run python ..." in messages[0] and "render_mode='rgb_array'" in messages[0]
    assert viewer.no_display and viewer.frames_shown == 0
    viewer.close()


def test_every_env_lists_both_render_modes():
    for env_id in ("SimShearTracking-v0", "SimShearCoLift-v0"):
        assert gym.spec(env_id).entry_point
        env_class = gym.envs.registration.load_env_creator(gym.spec(env_id).entry_point)
        assert env_class.metadata["render_modes"] == ["rgb_array", "human"]
    with pytest.raises(ValueError, match="render_mode must be None or one of"):
        gym.make("SimShearTracking-v0", render_mode="window", obs_mode="sim")
