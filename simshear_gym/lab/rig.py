"""The rehearsal rig: two emulated MG400s and a camera that sees what the two emulated arms do.

Two :class:`~simshear_gym.real.mg400_emulator.MG400Emulator` instances (leader, follower) listen on loopback
ephemeral ports; a :class:`RigCamera` renders the simulated TacTip on the follower's flange touching a flat face
wherever a callable puts it. For the tracking experiment the face is the plate on the emulated leader's flange,
placed in the follower's frame through the rig's (known, true) base-to-base transform; the data collection
passes a fixed face instead. Images are made as the envs make them (sim render, shear tracker, the shipped
shPix2pix: :func:`~simshear_gym.contract.finish_tactile`) and embedded in a 640x480 camera frame
(:func:`~simshear_gym.real.hil.embed_in_frame`), so the real camera preprocessing runs on them.

Where the arms are: the emulators' own state (what their feedback reports), read by the camera on every frame,
so a stalled feedback stream does not freeze the camera's world (as it would not a real camera's).

Faults beyond the emulators' own (:meth:`~simshear_gym.real.mg400_emulator.MG400Emulator.inject_alarm`,
``pause_feedback``, ``drop_connections``, ``set_faults``): :meth:`RigCamera.freeze` (the driver hands out the same
frame again and again) and :meth:`RigCamera.cut` (the stream is lost). The frame's border, outside the
preprocessing's crop, carries seeded sensor noise as a real camera's does, so that a frozen driver shows as
byte-identical frames while the tactile image stays the envs' exactly.

Ground truth: every frame appends a :class:`RigTruth` (penetration, contact, and after :meth:`RigCamera.
mark_target` the true contact error: the sensor's distance from the point of the face it stood on at the mark,
carried with the face). :meth:`RehearsalRig.audit` checks every motion command either emulator received against
the safety limits (its own record, not the client's).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from simshear_gym.contract import RENDER_SIZE_PX, TacTipMount, finish_tactile
from simshear_gym.lab.endpoints import ArmEndpoint
from simshear_gym.lab.frames import (
    LEADER_START_POSE,
    BaseToBase,
    PlateMount,
    T_face_work,
    flange_pose_for_sensor,
    sensor_on_face,
)
from simshear_gym.real.camera import CameraError, PreprocessConfig, default_config
from simshear_gym.real.hil import SimTacTipCamera, embed_in_frame, touch_face
from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator, MotionRecord
from simshear_gym.real.safety import MotionKind, SafetyConfig, SafetyError, SafetyLayer
from simshear_gym.robots.mg400.kinematics import inverse
from simshear_gym.robots.mg400.protocol import FEEDBACK_PERIOD_S
from simshear_gym.sim import stimuli
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.sim.shear import ShearTracker
from simshear_gym.transforms import invert


@dataclass(frozen=True)
class RigTruth:
    """What the simulation knows at one frame (follower base frame, mm)."""

    time_s: float
    follower_flange_mm_deg: np.ndarray
    sensor_mm: np.ndarray
    target_mm: np.ndarray | None
    penetration_mm: float
    in_contact: bool
    contact_error_mm: float  # nan before mark_target()


class RigCamera(SimTacTipCamera):
    """A frame source: the simulated TacTip at the follower's flange, touching a flat face (module docstring).

    It renders on read (:func:`~simshear_gym.real.camera.renders_on_read`): each ``read()`` makes the frame of the
    arms' poses at that moment, however long the render takes on this computer, so the follower's env does not age
    its frames by the wall clock; its stalls are the injected ones (:meth:`cut`, :meth:`freeze`).

    Args:
        follower_pose: returns the follower's flange pose ``(x, y, z mm, R deg)`` in its base frame.
        T_follower_face: returns the face frame in the follower's base frame (origin on the face, +z out of it).
        face_size_mm: the face's box (x, y, thickness), mm.
        mount: the TacTip on the flange.
        raw_frame_layout: the preprocessing whose crop box the image fills in a 640x480 frame; None: hand out the
            128 px tactile image itself (no frozen-frame detection possible then: no noise).
        noise_seed: seed of the border noise.
        noise_grey: the border noise's largest grey value.
        contact: the translator's contact type.
        clock: monotonic time source, s.
        stimulus: what the face is (default: a flat box of ``face_size_mm``; a
            :class:`~simshear_gym.sim.stimuli.StraightEdge` for edge contacts, its frame ``T_follower_face``).
    """

    def __init__(self, follower_pose: Callable[[], object], T_follower_face: Callable[[], np.ndarray],
                 face_size_mm: tuple[float, float, float] = PlateMount().size_mm, mount: TacTipMount = TacTipMount(),
                 raw_frame_layout: PreprocessConfig | None = None, noise_seed: int = 0, noise_grey: int = 8,
                 contact: str = "surface", clock: Callable[[], float] = time.monotonic,
                 stimulus: stimuli.Stimulus | None = None) -> None:
        if not (callable(follower_pose) and callable(T_follower_face)):
            raise ValueError("RigCamera needs callables for the follower's pose and the face's frame")
        super().__init__(follower_pose, contact, True, mount, raw_frame_layout, clock, "rehearsal rig camera")
        self.contact = contact
        self._T_follower_face = T_follower_face
        self._rng = np.random.default_rng(noise_seed)
        self._noise_grey = int(noise_grey)
        self._T_work_face = invert(T_face_work())
        self._half_extents_mm = (face_size_mm[0] / 2.0, face_size_mm[1] / 2.0)
        self._stimulus = stimuli.FlatSurface(size_mm=tuple(face_size_mm)) if stimulus is None else stimulus
        self._body = self._spawn(T_follower_face())
        self._tracker = ShearTracker()
        self._target_face_mm: np.ndarray | None = None
        self._last_sensor_face_mm: np.ndarray | None = None
        self._last_frame: np.ndarray | None = None
        self._frozen = False
        self._cut = False

    # -- faults ----------------------------------------------------------------------------------------------------

    def freeze(self) -> None:
        """From now on hand out the last frame again, byte for byte (a frozen driver)."""
        with self._lock:
            self._frozen = True

    def cut(self) -> None:
        """From now on every read fails (the stream is lost)."""
        with self._lock:
            self._cut = True

    def restore(self) -> None:
        """Undo :meth:`freeze` and :meth:`cut`."""
        with self._lock:
            self._frozen = self._cut = False

    # -- truth -----------------------------------------------------------------------------------------------------

    def mark_target(self, flange_pose_mm_deg: object | None = None) -> None:
        """Take the sensor's place on the face as the target of the true contact error: where the sensor stands
        with the follower's flange at ``flange_pose_mm_deg`` on the face where it is now (the pose a run marks its
        own target at, so that both marks are of one instant however long a render takes), or at the last frame
        (None)."""
        with self._lock:
            if flange_pose_mm_deg is not None:
                T_base_sensor = self.T_base_sensor_at(flange_pose_mm_deg)
                T_base_face = np.asarray(self._T_follower_face(), dtype=np.float64)
                self._target_face_mm = (invert(T_base_face) @ T_base_sensor)[:3, 3].copy()
                return
            if self._last_sensor_face_mm is None:
                raise RuntimeError("RigCamera.mark_target() before the first read()")
            self._target_face_mm = self._last_sensor_face_mm.copy()

    # -- frames ----------------------------------------------------------------------------------------------------

    def read(self) -> np.ndarray:
        with self._lock:
            if self._closed:
                raise CameraError(f"{self.name}: read() after close()")
            if self._cut:
                raise CameraError(f"{self.name}: the stream is lost (no frame)")
            if self._frozen and self._last_frame is not None:
                return self._last_frame.copy()
            now = self._clock()
            if self._t0 is None:
                self._t0 = now
            flange = np.asarray(self._flange_pose(), dtype=np.float64)[:4]
            T_base_sensor = self.T_base_sensor_at(flange)
            T_base_face, penetration_mm, in_contact, shear = self._touch(T_base_sensor)
            self._last_sensor_face_mm = (invert(T_base_face) @ T_base_sensor)[:3, 3].copy()
            target = error = None
            if self._target_face_mm is not None:
                target = T_base_face[:3, :3] @ self._target_face_mm + T_base_face[:3, 3]
                error = float(np.linalg.norm(T_base_sensor[:3, 3] - target))
            image = finish_tactile(self.tactip.render(T_base_sensor)[None], shear[None], "real", RENDER_SIZE_PX,
                                   self.contact)[0]
            self.history.append(self._truth(now - self._t0, flange, T_base_sensor[:3, 3].copy(), target,
                                            penetration_mm, in_contact, math.nan if error is None else error))
            frame = image if self.raw_frame_layout is None else self._frame(image)
            self._last_frame = frame
            return frame.copy()

    # -- what the sensor touches (a subclass's scene overrides these) ----------------------------------------------

    def _spawn(self, T_base_face: np.ndarray) -> int:
        """The rendered body in the camera's world."""
        return stimuli.spawn(self.world, self._stimulus, T_base_face)

    def _touch(self, T_base_sensor: np.ndarray) -> tuple[np.ndarray, float, bool, np.ndarray]:
        """Place the scene for this frame: (the face frame the truth's target is carried by, penetration mm, in
        contact, the shear (6,) that conditions the translator)."""
        T_base_face = np.asarray(self._T_follower_face(), dtype=np.float64)
        penetration_mm, in_contact, shear = touch_face(self.world, self._body, self._stimulus, T_base_face,
                                                       T_base_sensor, self._half_extents_mm, self._T_work_face,
                                                       self._tracker)
        return T_base_face, penetration_mm, in_contact, shear

    def _truth(self, time_s: float, flange: np.ndarray, sensor_mm: np.ndarray, target_mm: np.ndarray | None,
               penetration_mm: float, in_contact: bool, contact_error_mm: float) -> RigTruth:
        return RigTruth(time_s, flange, sensor_mm, target_mm, penetration_mm, in_contact, contact_error_mm)

    def _frame(self, image: np.ndarray) -> np.ndarray:
        frame = embed_in_frame(image, self.raw_frame_layout)
        x0, y0, x1, y1 = self.raw_frame_layout.crop_bbox_px
        border = np.ones(frame.shape, dtype=bool)
        border[y0:y1, x0:x1] = False
        frame[border] = self._rng.integers(0, self._noise_grey + 1, int(border.sum()), dtype=np.uint8)
        return frame


@dataclass(frozen=True)
class RigConfig:
    """The rehearsal rig's layout.

    Attributes:
        leader_in_follower: where the emulated leader's base truly stands in the follower's frame (the value a
            calibration must find).
        leader_start_pose_mm_deg: where the emulated leader's flange starts (its base frame).
        hover_mm: the emulated follower starts with its sensor this far above the plate's centre, mm.
        plate: the plate on the leader's flange.
        mount: the TacTip on the follower's flange.
        feedback_period_s: the emulators' feedback period, s.
        preprocess: the camera preprocessing whose crop the rig's frames fill (None: bare tactile images).
        camera_seed: seed of the camera's border noise.
    """

    leader_in_follower: BaseToBase = BaseToBase()
    leader_start_pose_mm_deg: tuple[float, float, float, float] = LEADER_START_POSE
    hover_mm: float = 5.0
    plate: PlateMount = PlateMount()
    mount: TacTipMount = TacTipMount()
    feedback_period_s: float = FEEDBACK_PERIOD_S
    preprocess: PreprocessConfig | None = field(default_factory=default_config)
    camera_seed: int = 0

    def __post_init__(self) -> None:
        name = type(self).__name__
        if not (math.isfinite(self.hover_mm) and 0.0 < self.hover_mm <= 50.0):
            raise ValueError(f"{name}.hover_mm must be in (0, 50] mm, got {self.hover_mm!r}")
        start = tuple(float(v) for v in self.leader_start_pose_mm_deg)
        if len(start) != 4 or not all(math.isfinite(v) for v in start):
            raise ValueError(f"{name}.leader_start_pose_mm_deg must be 4 finite numbers, got {start!r}")
        object.__setattr__(self, "leader_start_pose_mm_deg", start)

    @classmethod
    def for_run(cls, config, **changes) -> RigConfig:
        """The rig laid out as a run's ``config`` (an :class:`~simshear_gym.lab.experiment.ExperimentConfig`) has
        it: its plate, mount, leader start pose and camera preprocessing (``changes``: the rest)."""
        return cls(plate=config.plate, mount=config.real_env.mount,
                   leader_start_pose_mm_deg=config.leader_start_pose_mm_deg, preprocess=config.real_env.preprocess,
                   **changes)

    def follower_start_pose(self) -> np.ndarray:
        """The follower flange pose with the sensor ``hover_mm`` above the plate's centre at the leader's start."""
        T_face = self.plate.T_follower_face(self.leader_start_pose_mm_deg,
                                            self.leader_in_follower.T_follower_leader())
        T_sensor = sensor_on_face(T_face, 0.0, 0.0, SURFACE_DEPTH_MM - self.hover_mm)
        return flange_pose_for_sensor(T_sensor, self.mount.T_flange_sensor())


class RehearsalRig:
    """Two loopback MG400 emulators and the rig camera between them (a context manager; see the module docstring).

    Attributes (after :meth:`start`): ``leader``, ``follower`` (the emulators), ``camera`` (:class:`RigCamera`),
    ``leader_endpoint``, ``follower_endpoint`` (:class:`~simshear_gym.lab.endpoints.ArmEndpoint`).
    """

    def __init__(self, config: RigConfig = RigConfig()) -> None:
        self.config = config
        self.leader: MG400Emulator | None = None
        self.follower: MG400Emulator | None = None
        self.camera: RigCamera | None = None

    def start(self) -> RehearsalRig:
        cfg = self.config
        try:
            self.leader = loopback_emulator(cfg.leader_start_pose_mm_deg, cfg.feedback_period_s).start()
            self.follower = loopback_emulator(cfg.follower_start_pose(), cfg.feedback_period_s).start()
            self.new_camera()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop both emulators and close the camera (idempotent)."""
        for emulator in (self.leader, self.follower):
            if emulator is not None:
                emulator.stop()
        if self.camera is not None:
            self.camera.close()

    def __enter__(self) -> RehearsalRig:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @staticmethod
    def _endpoint(emulator: MG400Emulator | None) -> ArmEndpoint:
        if emulator is None:
            raise RuntimeError("RehearsalRig is not started; call start() first")
        return ArmEndpoint(emulator.config.host, emulator.dashboard_port, emulator.motion_port,
                           emulator.feedback_port)

    @property
    def leader_endpoint(self) -> ArmEndpoint:
        return self._endpoint(self.leader)

    @property
    def follower_endpoint(self) -> ArmEndpoint:
        return self._endpoint(self.follower)

    def new_camera(self) -> RigCamera:
        """A fresh rig camera on the emulators (each run closes its camera; the old one is closed)."""
        if self.camera is not None:
            self.camera.close()
        cfg = self.config
        T_follower_leader = cfg.leader_in_follower.T_follower_leader()
        leader, follower = self.leader, self.follower
        self.camera = RigCamera(lambda: follower.pose, lambda: cfg.plate.T_follower_face(leader.pose,
                                                                                        T_follower_leader),
                                cfg.plate.size_mm, cfg.mount, cfg.preprocess, noise_seed=cfg.camera_seed)
        return self.camera

    def clear_alarms(self) -> None:
        """ClearError() and Continue() on both emulated arms, as an operator does after a fault."""
        from simshear_gym.real.mg400_client import MG400Client, MG400ClientConfig

        for endpoint in (self.leader_endpoint, self.follower_endpoint):
            with MG400Client(MG400ClientConfig(**asdict(endpoint), use_feedback=False)) as client:
                client.clear_error()
                client.continue_()

    def audit(self, safety: SafetyConfig = SafetyConfig()) -> dict[str, list[str]]:
        """Per arm (``"leader"``, ``"follower"``), every motion command its emulator received that the safety
        limits refuse, checked from the state the emulator was in when it arrived (empty lists: none)."""
        return {"leader": audit_motion_records(self.leader.motion_records(), safety),
                "follower": audit_motion_records(self.follower.motion_records(), safety)}


def loopback_emulator(pose_mm_deg, feedback_period_s: float = FEEDBACK_PERIOD_S) -> MG400Emulator:
    """An MG400 emulator (not started) on loopback ephemeral ports, its flange at ``pose_mm_deg``."""
    joints = tuple(float(v) for v in inverse(*pose_mm_deg))
    return MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                        feedback_period_s=feedback_period_s, initial_joints_deg=joints))


def audit_motion_records(records: list[MotionRecord], safety: SafetyConfig = SafetyConfig()) -> list[str]:
    """The records whose command asked for more than ``safety`` allows (its step from where the arm was heading,
    its speed over its ``t``, the workspace and the joint limits), one line each."""
    layer = SafetyLayer(safety)
    out: list[str] = []
    for record in records:
        name = record.command.split("(", 1)[0].strip().lower()
        try:
            if record.target_pose is None:
                raise SafetyError("the target has no solution (unreachable)")
            if name == "servop":
                layer.check_target(record.in_force_pose, record.target_pose, MotionKind.SERVO, record.duration_s,
                                   record.in_force_joints)
            elif name == "servoj":
                layer.check_joint_target(record.in_force_joints, record.target_joints, MotionKind.SERVO,
                                         record.duration_s, record.in_force_pose)
            elif name == "jointmovj":
                layer.check_joint_target(record.in_force_joints, record.target_joints, MotionKind.JOINT, None,
                                         record.in_force_pose)
            else:
                kind = MotionKind.LINEAR if name == "movl" else MotionKind.JOINT
                layer.check_target(record.in_force_pose, record.target_pose, kind, None, record.in_force_joints)
        except SafetyError as error:
            out.append(f"t = {record.time_s:.3f} s: {record.command}: {error}")
    return out
