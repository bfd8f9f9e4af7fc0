"""Hardware-in-the-loop camera: the simulated TacTip, looking at a moving surface, wherever the (emulated) arm is.

:class:`SimSurfaceCamera` is a frame source for :class:`~simshear_gym.real.env.RealTactileEnv`. On every
``read()`` it asks where the arm's flange is (a callable: the emulator's state, or the robot's feedback), places
the TacTip there with the env's mount, moves a flat surface along its configured path, renders the sim TacTip
(:mod:`simshear_gym.sim.tactip`), tracks the shear of the contact (:class:`~simshear_gym.sim.shear.ShearTracker`)
and translates the image with the shipped shPix2pix, exactly as ``SimShearTracking-v0`` does in its ``"real"``
mode (:func:`~simshear_gym.contract.finish_tactile`). So the whole real path closes: camera -> estimator ->
controller -> TCP/IP -> emulator -> camera.

Frames (the robot's base frame is the world frame, mm): the surface's face frame has its origin on the top face
and +z out of the face (up); at the start it is placed so that the sensor at ``start_flange_pose_mm_deg`` touches
it at ``reference_depth_mm`` (labels' convention, the face at 2.2 mm) with the sensor's x along the face's x.
The surface then moves at ``velocity_mm_s`` (base frame) until it has travelled ``max_travel_mm``, timed by the
wall clock from the first ``read()``.

Ground truth, for tests and logs: each read appends a :class:`ContactTruth` to :attr:`SimSurfaceCamera.history`
(``contact_error_mm``: the TCP's distance from where it touched the surface, carried along with the surface, as the
sim env's contact error).

Optionally (``raw_frame_layout``) the image is returned as a 640x480 camera-like frame, the tactile image scaled
into the preprocessing's crop box, so that :func:`~simshear_gym.real.camera.preprocess` runs on it too.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from simshear_gym.contract import RENDER_SIZE_PX, TacTipMount, finish_tactile
from simshear_gym.real.camera import CameraError, PreprocessConfig, SourceBase
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange
from simshear_gym.sim import stimuli
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.sim.shear import ShearTracker
from simshear_gym.sim.tactip import TacTip, TacTipConfig
from simshear_gym.sim.world import World
from simshear_gym.transforms import invert, pose_from_matrix_fast, pose_to_matrix

RAW_FRAME_SIZE_PX = (640, 480)  # (width, height) of the TacTip camera's frames


@dataclass(frozen=True)
class MovingSurfaceConfig:
    """The surface the simulated TacTip touches and how it moves.

    Attributes:
        velocity_mm_s: the surface's velocity in the robot's base frame (x, y, z), mm/s.
        max_travel_mm: the surface stops after moving this far, mm.
        reference_depth_mm: where the sensor at the start pose touches it (labels' convention), mm.
        size_mm: the surface box (length x, width y, thickness z), mm.
        translate: True: shPix2pix-translated image (what a real TacTip shows); False: the raw sim depth image.
        contact: the translator's contact type.
    """

    velocity_mm_s: tuple[float, float, float] = (2.0, 0.0, 0.0)
    max_travel_mm: float = 20.0
    reference_depth_mm: float = 4.0
    size_mm: tuple[float, float, float] = (120.0, 120.0, 10.0)
    translate: bool = True
    contact: str = "surface"

    def __post_init__(self) -> None:
        velocity = tuple(float(v) for v in self.velocity_mm_s)
        if len(velocity) != 3 or not all(math.isfinite(v) for v in velocity):
            raise ValueError(f"MovingSurfaceConfig.velocity_mm_s must be 3 finite numbers, got {self.velocity_mm_s!r}")
        object.__setattr__(self, "velocity_mm_s", velocity)
        if not (math.isfinite(self.max_travel_mm) and self.max_travel_mm >= 0.0):
            raise ValueError(f"MovingSurfaceConfig.max_travel_mm must be >= 0, got {self.max_travel_mm!r}")
        if not SURFACE_DEPTH_MM < self.reference_depth_mm < SURFACE_DEPTH_MM + 10.0:
            raise ValueError(f"MovingSurfaceConfig.reference_depth_mm must press the dome into the surface: within "
                             f"({SURFACE_DEPTH_MM}, {SURFACE_DEPTH_MM + 10.0}) mm, got {self.reference_depth_mm!r}")
        if self.contact != "surface":
            raise ValueError(f"MovingSurfaceConfig.contact must be 'surface' (a flat surface), got {self.contact!r}")

    def offset_at(self, time_s: float) -> np.ndarray:
        """The surface's displacement from its start after ``time_s`` seconds, base frame, mm."""
        velocity = np.asarray(self.velocity_mm_s)
        speed = float(np.linalg.norm(velocity))
        if speed == 0.0:
            return np.zeros(3)
        return velocity * min(max(time_s, 0.0), self.max_travel_mm / speed)


def touch_face(world: World, body: int, stimulus: stimuli.Stimulus, T_base_face: np.ndarray, T_base_sensor: np.ndarray,
               half_extents_mm: tuple[float, float], T_work_face: np.ndarray, tracker: ShearTracker
               ) -> tuple[float, bool, np.ndarray]:
    """Move the flat face's ``body`` to ``T_base_face`` and touch it with the sensor at ``T_base_sensor``:
    (penetration mm, in contact (on the face's ``half_extents_mm`` and pressed in), the (6,) shear ``tracker``
    gives for the sensor's pose in the work frame, ``T_work_face`` the face in it)."""
    stimuli.move(world, body, T_base_face, stimulus)
    T_face_sensor = invert(T_base_face) @ T_base_sensor
    penetration_mm = -float(T_face_sensor[2, 3])
    on_face = abs(T_face_sensor[0, 3]) <= half_extents_mm[0] and abs(T_face_sensor[1, 3]) <= half_extents_mm[1]
    in_contact = bool(on_face and penetration_mm > 0.0)
    shear = tracker.update(pose_from_matrix_fast(T_work_face @ T_face_sensor), in_contact)
    return penetration_mm, in_contact, shear


@dataclass(frozen=True)
class ContactTruth:
    """What the simulation knows at one read (base frame, mm)."""

    time_s: float
    flange_pose_mm_deg: np.ndarray
    surface_offset_mm: np.ndarray
    penetration_mm: float
    in_contact: bool
    contact_error_mm: float
    shear_sensor: np.ndarray


class SimTacTipCamera(SourceBase):
    """What the simulated cameras share: the lock, the clock, the world with its TacTip, the history, the image
    finishing and the frame (the context manager: the frame sources' of :mod:`~simshear_gym.real.camera`). A
    subclass builds its scene and implements :meth:`_touch`; ``read()`` places the TacTip at the arm's flange pose,
    asks ``_touch`` for the contact's shear and ground truth, renders and translates.

    Args:
        flange_pose: returns the arm's current flange pose ``(x, y, z mm, R deg)`` in its base frame.
        contact: the translator's contact type; ``translate``: False gives the raw sim image.
        mount: the TacTip on the flange (as the env's).
        raw_frame_layout: a preprocessing config to emit 640x480 frames for (the image fills its crop box);
            None: emit the 128 px tactile image itself.
        clock: monotonic time source, s.
    """

    renders_on_read = True  # each read() renders the arm's pose now: no wall-clock frame age (real.camera)

    def __init__(self, flange_pose: Callable[[], object], contact: str, translate: bool, mount: TacTipMount,
                 raw_frame_layout: PreprocessConfig | None, clock: Callable[[], float], name: str) -> None:
        if not callable(flange_pose):
            raise ValueError(f"flange_pose must be callable, got {type(flange_pose).__name__}")
        self.name = name
        self.mount = mount
        self.raw_frame_layout = raw_frame_layout
        self._contact = contact
        self._mode = "real" if translate else "sim"
        self._flange_pose = flange_pose
        self._clock = clock
        self._lock = threading.Lock()
        self._T_flange_sensor = mount.T_flange_sensor()
        self.world = World()
        self.tactip = TacTip(self.world, TacTipConfig(image_size_px=RENDER_SIZE_PX))
        self._t0: float | None = None
        self._closed = False
        self.history: list[ContactTruth] = []

    def T_base_sensor_at(self, flange_pose_mm_deg) -> np.ndarray:
        """The TacTip's pose in the base frame for a flange pose."""
        return pose_to_T_base_flange(np.asarray(flange_pose_mm_deg, dtype=np.float64)[:4]) @ self._T_flange_sensor

    def _touch(self, time_s: float, flange: np.ndarray, T_base_sensor: np.ndarray
               ) -> tuple[np.ndarray, ContactTruth]:
        """Move the scene to ``time_s`` and touch it with the sensor: (the (6,) sensor-frame shear, the truth)."""
        raise NotImplementedError

    def read(self) -> np.ndarray:
        """The tactile image (uint8 128x128, or a 640x480 frame with ``raw_frame_layout``) at the arm's pose now."""
        with self._lock:
            if self._closed:
                raise CameraError(f"{self.name}: read() after close()")
            now = self._clock()
            if self._t0 is None:
                self._t0 = now
            flange = np.asarray(self._flange_pose(), dtype=np.float64)[:4]
            T_base_sensor = self.T_base_sensor_at(flange)
            shear, truth = self._touch(now - self._t0, flange, T_base_sensor)
            sim = self.tactip.render(T_base_sensor)
            image = finish_tactile(sim[None], shear[None], self._mode, RENDER_SIZE_PX, self._contact)[0]
            self.history.append(truth)
        if self.raw_frame_layout is None:
            return image
        return embed_in_frame(image, self.raw_frame_layout)

    def close(self) -> None:
        with self._lock:
            if not self._closed:
                self._closed = True
                self.world.close()


class SimSurfaceCamera(SimTacTipCamera):
    """A frame source rendering the simulated TacTip on a moving surface (see the module docstring).

    Args:
        flange_pose: returns the arm's current flange pose ``(x, y, z mm, R deg)`` in its base frame.
        start_flange_pose_mm_deg: the flange pose at which the sensor touches the surface at the reference depth.
        config: the surface and its motion.
        mount, raw_frame_layout, clock: see :class:`SimTacTipCamera`.
    """

    def __init__(self, flange_pose: Callable[[], object], start_flange_pose_mm_deg, config: MovingSurfaceConfig =
                 MovingSurfaceConfig(), mount: TacTipMount = TacTipMount(),
                 raw_frame_layout: PreprocessConfig | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(flange_pose, config.contact, config.translate, mount, raw_frame_layout, clock,
                         "simulated TacTip camera")
        self.config = config
        self._T_work_face = np.diag([1.0, -1.0, -1.0, 1.0])
        self._T_work_face[2, 3] = SURFACE_DEPTH_MM
        T_base_sensor = self.T_base_sensor_at(start_flange_pose_mm_deg)
        T_work_sensor = pose_to_matrix(np.array([0.0, 0.0, config.reference_depth_mm, 0.0, 0.0, 0.0]))
        # T_base_sensor = T_base_face @ T_face_work @ T_work_sensor
        self._T_base_face_start = T_base_sensor @ invert(T_work_sensor) @ self._T_work_face
        self._target_face_mm = (invert(self._T_base_face_start) @ T_base_sensor)[:3, 3]
        self._half_extents_mm = (config.size_mm[0] / 2.0, config.size_mm[1] / 2.0)
        self._stimulus = stimuli.FlatSurface(size_mm=config.size_mm)
        self._body = stimuli.spawn(self.world, self._stimulus, self._T_base_face_start)
        self._tracker = ShearTracker()

    def T_base_face(self, time_s: float) -> np.ndarray:
        """The surface's face frame in the base frame at ``time_s`` after the first read."""
        T = self._T_base_face_start.copy()
        T[:3, 3] += self.config.offset_at(time_s)
        return T

    def _touch(self, time_s: float, flange: np.ndarray, T_base_sensor: np.ndarray
               ) -> tuple[np.ndarray, ContactTruth]:
        T_base_face = self.T_base_face(time_s)
        penetration_mm, in_contact, shear = touch_face(self.world, self._body, self._stimulus, T_base_face,
                                                       T_base_sensor, self._half_extents_mm, self._T_work_face,
                                                       self._tracker)
        target_base = T_base_face[:3, :3] @ self._target_face_mm + T_base_face[:3, 3]
        error_mm = float(np.linalg.norm(T_base_sensor[:3, 3] - target_base))
        return shear, ContactTruth(time_s, flange, T_base_face[:3, 3] - self._T_base_face_start[:3, 3],
                                   penetration_mm, in_contact, error_mm, shear.copy())


def embed_in_frame(image: np.ndarray, layout: PreprocessConfig, frame_size_px: tuple[int, int] = RAW_FRAME_SIZE_PX
                   ) -> np.ndarray:
    """A grey uint8 frame (``frame_size_px`` = width, height) with ``image`` scaled into ``layout.crop_bbox_px``,
    so that ``preprocess(frame, layout)`` gives (close to) ``image`` back."""
    x0, y0, x1, y1 = layout.crop_bbox_px
    width, height = frame_size_px
    if x1 > width or y1 > height:
        raise ValueError(f"crop_bbox_px {layout.crop_bbox_px} does not fit a {width}x{height} frame")
    frame = np.zeros((height, width), np.uint8)
    frame[y0:y1, x0:x1] = cv2.resize(image, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
    return frame
