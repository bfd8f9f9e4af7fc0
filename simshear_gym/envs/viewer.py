"""``render_mode="human"``: a window that shows what ``render_mode="rgb_array"`` returns (the scene beside the
tactile image), refreshed on every ``reset`` and ``step`` at the env's ``render_fps`` (simulated time at wall-clock
pace, as Gymnasium's human mode does).

The window is plain Tk (``tkinter``, in the standard library): the package's OpenCV is the headless build, and a
matplotlib window would switch the process's matplotlib backend. It needs a display (``$DISPLAY``; on a machine
without a screen, ``xvfb-run python ...``). Without one the env runs on with no window: the first frame logs one
warning that says what to do (``logging``: shown on stderr unless the application routes it), the way an env
checker or a headless test run can still make the env in every declared render mode.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

log = logging.getLogger(__name__)


class HumanViewer:
    """One Tk window, opened on the first frame; ``zoom``: each pixel shown as zoom x zoom; ``clock`` and
    ``sleep``: where the frame pacing reads and waits (injected in tests)."""

    def __init__(self, title: str, fps: float, zoom: int = 2, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not fps > 0 or zoom < 1:
            raise ValueError(f"HumanViewer needs fps > 0 and zoom >= 1, got {fps}, {zoom}")
        self.title, self.period_s, self.zoom = title, 1.0 / fps, int(zoom)
        self._clock, self._sleep = clock, sleep
        self._root = None
        self._label = None
        self._photo = None
        self._last_s: float | None = None
        self.closed_by_user = False
        self.no_display: str | None = None  # why no window could open (then frames are dropped)
        self.frames_shown = 0

    def show(self, frame: np.ndarray) -> None:
        """Show an RGB uint8 (H, W, 3) frame, at most ``fps`` frames per second; a window the user closed stays
        closed (the env runs on)."""
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"a frame is RGB uint8 (H, W, 3), got {frame.dtype} {frame.shape}")
        if self.closed_by_user or self.no_display:
            return
        if self._root is None and not self._open():
            return
        if self._last_s is not None:
            wait_s = self._last_s + self.period_s - self._clock()
            if wait_s > 0:
                self._sleep(wait_s)
        import tkinter

        height, width = frame.shape[:2]
        ppm = b"P6 %d %d 255\n" % (width, height) + np.ascontiguousarray(frame).tobytes()
        photo = tkinter.PhotoImage(master=self._root, data=ppm, format="PPM")
        self._photo = photo.zoom(self.zoom) if self.zoom > 1 else photo
        self._label.configure(image=self._photo)
        self._root.update()
        self._last_s = self._clock()
        self.frames_shown += 1

    def close(self) -> None:
        if self._root is not None:
            root, self._root = self._root, None
            try:
                root.destroy()
            except Exception:  # noqa: BLE001  (already gone with its display: nothing left to close)
                pass

    def _open(self) -> bool:
        """Open the window; False (and one warning) where no display answers."""
        import tkinter

        try:
            self._root = tkinter.Tk()
        except tkinter.TclError as error:
            self.no_display = str(error)
            log.warning("render_mode='human' shows no window: no display answered (%s); set DISPLAY, run under a "
                        "virtual one (xvfb-run python ...) or use render_mode='rgb_array'", error)
            return False
        self._root.title(self.title)
        self._root.protocol("WM_DELETE_WINDOW", self._closed)
        self._label = tkinter.Label(self._root, borderwidth=0)
        self._label.pack()
        return True

    def _closed(self) -> None:
        self.closed_by_user = True
        self.close()
