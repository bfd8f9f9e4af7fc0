"""``RealTactileEnv``: the real TacTip on a Dobot MG400 behind the same Gymnasium interface as the sim envs.

A policy trained on ``SimShearTracking-v0`` (or the servo controller) drives the real arm unchanged: the action
and observation spaces are the sim env's, from the one definition both use
(:func:`simshear_gym.contract.policy_spaces`), and so are the action scaling and the mount
(:class:`~simshear_gym.contract.ActionScale`, :class:`~simshear_gym.contract.TacTipMount`).

**Action** ``Box(-1, 1, (4,), float32)``: a relative move of the sensor in its own frame per step, scaled by
``ActionScale`` (dx, dy, dz mm; dRz deg), as in the sim env. Each action becomes one ``ServoP`` target for the
flange: the last *commanded* flange target moved by the action in the sensor frame (the commanded target, not the
measured pose, so that a lagging arm does not shorten the moves the estimator's motion model assumes). The target
passes the :class:`~simshear_gym.real.safety.SafetyLayer` in :meth:`MG400Client.servo_p` (reachability and joint
limits through the kinematics, the workspace box, the step and the speed per command); a refused target is never
sent and ends the episode (``info["termination"] == "safety_refused"``, the reason in ``info["safety_event"]``). An
action that is not finite (a NaN estimate) is refused the same way.

**Observation** ``Dict``, the sim envs' for the same ``RealEnvConfig.observation`` and ``history`` (one definition,
:func:`~simshear_gym.contract.observation_space`, built by the sim envs' own
:class:`~simshear_gym.envs.observation.PolicyObservation`): ``observation="tactile"`` (default): ``tactile``
uint8 (k, S, S), the camera frame preprocessed (:func:`~simshear_gym.real.camera.preprocess`, 128 px binary) and
resized to S = ``image_size_px`` as the sim env halves its 128 px image (the last k = ``history`` frames, k = 1
by default), and ``tcp_pose`` float32 (4,): dome apex x, y, z mm and flange R deg in the robot's base frame, from
the 30004 feedback's flange pose and the mount (the controller's tool frame must be the flange, ``Tool(0)``);
``"estimate"``: ``estimate`` float32 (16 k,), the servo controller's estimator (GDNN ``RealEnvConfig.posenet``
+ Bayesian filter, fed with the moves commanded) on those images, normalised relative to
``RealEnvConfig.reference_depth_mm`` (:func:`~simshear_gym.contract.estimate_features`); ``"tactile+estimate"``:
both.

**Reward** 0 every step: the real robot has no ground truth to score against.

**Termination** (``info["termination"]``): ``safety_refused`` (a target outside the limits, too large a step or
too fast, or an action that is not finite), ``feedback_mismatch`` (the robot's joint feedback and its reported
pose disagree: where it is is not known), ``robot_error`` (the controller refused a command or is in error mode),
``lost_connection`` (a connection dropped, a reply timed out, or the feedback is older than
``SafetyConfig.max_feedback_age_s``), ``camera_stall`` (no new frame, one older than
``SafetyConfig.max_camera_frame_age_s``, or ``frozen_frame_limit`` identical frames in a row; a source that renders
on read, :func:`~simshear_gym.real.camera.renders_on_read`, has no frame age: its stalls are its errors and frozen
frames), ``camera_ended`` (a
recording ran out) and ``lost_contact`` (the optional ``contact_check`` callback says so and
``SafetyConfig.stop_on_lost_contact``); ``controller_error`` when the loop driving the env could not compute an
action (the controller refused a NaN estimate) and ended the episode with :meth:`RealTactileEnv.end_episode`. After
a termination nothing more is sent: the arm stops at its last servo target; :meth:`RealTactileEnv.reset` starts
again.

**Timing**: ``step`` sends its command at once, waits until one control period after the previous observation
and then reads the camera and the feedback, so commands go out at a fixed period as long as the caller's compute
fits in it; ``info["overrun_s"]`` says by how much it did not.

**Dry run** (``RealEnvConfig.dry_run``): nothing that moves or changes the robot is sent (no EnableRobot, MovJ,
Sync, ServoP); targets are still checked by the safety layer and logged, and the commanded target advances as if
they had been sent. Camera and feedback are read as usual.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np

from simshear_gym.contract import (
    ESTIMATE_OBSERVATIONS,
    IMAGE_SIZES_PX,
    TCP_POSE_LOW,
    ActionScale,
    HorizontalTacTipMount,
    ServoHints,
    TacTipMount,
    action_to_move,
    check_observation,
    policy_spaces,
    resize_tactile,
)
from simshear_gym.data.labels import wrap_deg
from simshear_gym.envs.observation import Estimator, PolicyObservation
from simshear_gym.real.camera import (
    CameraError,
    CameraSource,
    EndOfStream,
    FrameSource,
    PreprocessConfig,
    default_config,
    preprocess,
    renders_on_read,
    to_gray,
)
from simshear_gym.real.mg400_client import (
    FeedbackStaleError,
    MG400Client,
    MG400ClientConfig,
    MG400ConnectionError,
    MG400Error,
    MG400TimeoutError,
    wait_at_pose,
)
from simshear_gym.real.safety import (
    FeedbackMismatchError,
    MotionKind,
    MotionRefusedError,
    SafetyConfig,
    SafetyError,
    SafetyLayer,
    StatusSnapshot,
    StopReason,
)
from simshear_gym.robots.mg400.frames import (
    T_base_flange_to_pose,
    pose_to_T_base_flange,
)
from simshear_gym.robots.mg400.protocol import (
    ProtocolError,
    RobotMode,
)
from simshear_gym.transforms import invert, rz_matrix

logger = logging.getLogger(__name__)

TERMINATIONS: tuple[str, ...] = ("safety_refused", "feedback_mismatch", "robot_error", "lost_connection",
                                 "camera_stall", "camera_ended", "lost_contact", "controller_error")
"""Every value ``info["termination"]`` takes besides ``""``."""

STOP_TERMINATIONS: dict[StopReason, str] = {
    StopReason.LOST_CONNECTION: "lost_connection",
    StopReason.STALE_FEEDBACK: "lost_connection",
    StopReason.ROBOT_ERROR_MODE: "robot_error",
    StopReason.CAMERA_STALLED: "camera_stall",
    StopReason.LOST_CONTACT: "lost_contact",
}
"""The termination of each stop condition of :meth:`SafetyLayer.check_status`."""

ContactCheck = Callable[[dict[str, np.ndarray]], bool]
"""Observation -> whether the sensor still touches the contact (e.g. from a pose estimator's depth)."""


class RealEnvError(RuntimeError):
    """The robot is not in a state an episode can start from (error mode, unreachable); nothing was moved."""


# ----------------------------------------------------------------------------------------------------------------
# Pieces shared with the benchmark and the HIL camera


def tactile_from_frame(frame: np.ndarray, preprocess_config: PreprocessConfig | None,
                       image_size_px: int) -> np.ndarray:
    """Camera frame -> uint8 (S, S) tactile image: :func:`preprocess` (unless ``None``: the frame already is a
    tactile image, as a simulated camera's) then :func:`resize_tactile`."""
    image = preprocess(frame, preprocess_config) if preprocess_config is not None else to_gray(frame)
    return resize_tactile(image, image_size_px)


def tcp_pose_from_flange(flange_pose_mm_deg, mount: TacTipMount) -> np.ndarray:
    """Flange pose ``(x, y, z mm, R deg)`` -> the sim env's ``tcp_pose``: dome apex x, y, z and flange R."""
    flange = np.asarray(flange_pose_mm_deg, dtype=np.float64)
    T_base_sensor = pose_to_T_base_flange(flange) @ mount.T_flange_sensor()
    return np.array([T_base_sensor[0, 3], T_base_sensor[1, 3], T_base_sensor[2, 3], flange[3]])


def move_to_flange_target(flange_pose_mm_deg, move_sensor, mount: TacTipMount) -> np.ndarray:
    """The flange pose that moves the sensor by ``move_sensor`` = (dx, dy, dz mm, dRz deg) in its own frame, as
    the sim env's step does (a horizontal sensor, :class:`~simshear_gym.contract.HorizontalTacTipMount`, turns about
    the vertical through its apex); R is unwrapped next to the given flange R."""
    flange = np.asarray(flange_pose_mm_deg, dtype=np.float64)
    dx, dy, dz, drz = (float(v) for v in move_sensor)
    T_flange_sensor = mount.T_flange_sensor()
    T_base_sensor = pose_to_T_base_flange(flange) @ T_flange_sensor
    if isinstance(mount, HorizontalTacTipMount):
        target_sensor = T_base_sensor.copy()
        target_sensor[:3, 3] += T_base_sensor[:3, :3] @ np.array([dx, dy, dz])
        target_sensor[:3, :3] = rz_matrix(drz)[:3, :3] @ T_base_sensor[:3, :3]
    else:
        T_move = rz_matrix(drz)
        T_move[:3, 3] = (dx, dy, dz)
        target_sensor = T_base_sensor @ T_move
    T_base_flange = target_sensor @ invert(T_flange_sensor)
    target = T_base_flange_to_pose(T_base_flange)
    target[3] = flange[3] + wrap_deg(target[3] - flange[3])
    return target


# ----------------------------------------------------------------------------------------------------------------
# Configuration


ENV_CLIENT = MG400ClientConfig(reply_timeout_s=1.0, sync_timeout_s=30.0)
"""The client a control loop talks through: the client's defaults, but a reply waits at most 1 s (a loop that
commands every 0.1 s and waits longer has lost the arm; the client's 2 s is for one-off commands) and ``reset``'s
move to the start pose at most 30 s."""


def env_client(host: str, dashboard_port: int, motion_port: int, feedback_port: int,
               **settings) -> MG400ClientConfig:
    """:data:`ENV_CLIENT` at another address (``settings``: other client fields replaced too)."""
    return replace(ENV_CLIENT, host=host, dashboard_port=dashboard_port, motion_port=motion_port,
                   feedback_port=feedback_port, **settings)


@dataclass(frozen=True)
class RealEnvConfig:
    """Settings of :class:`RealTactileEnv`.

    Attributes:
        client: where the MG400 controller is and how long to wait for it (:data:`ENV_CLIENT`; its
            ``sync_timeout_s`` bounds ``reset``'s move to the start pose, its ``connect_timeout_s`` the first
            feedback; the safety layer's ``max_feedback_age_s`` replaces its ``feedback_max_age_s``).
        control_period_s: time between servo commands (and observations), s.
        servo_margin_s: added to the period for each ServoP's ``t`` so the arm never idles between targets, s:
            generous, because a cycle that runs late must not let the arm reach its target and stop (the next
            command would then start it again from rest, which the client's acceleration check bounds).
        camera_source: device index, video file or image folder (:class:`CameraSource`), used unless a frame
            source is passed to the env.
        camera_stall_timeout_s: a live camera that gives no new frame for this long raises (ends the episode), s.
        frozen_frame_limit: this many byte-identical camera frames in a row end the episode (a frozen driver; a
            real camera's noise makes two equal frames all but impossible); None for a noise-free simulated camera.
        preprocess: camera frame -> 128 px binary tactile image; None when the source already gives tactile
            images (a simulated camera, a folder of processed images).
        image_size_px: S of the ``tactile`` observation, 128 or 64 (as the sim env).
        observation, history: what the policy sees (see the module docstring; the sim envs' arguments).
        reference_depth_mm: the depth the task holds (labels' convention): the estimate's depth is relative to it.
        posenet: the GDNN of the estimate observation (None: the shipped ``surface`` one, as the servo controller).
        estimator_process_std_mm: the estimator's process noise, mm per step (the env's
            :class:`~simshear_gym.contract.ServoHints`: the estimate observation's and the servo controller's;
            None: the estimator's default).
        start_pose_mm_deg: flange pose ``(x, y, z mm, R deg)`` in the base frame that ``reset`` moves to (with
            one MovJ, so the robot must be within ``safety.max_move_mm`` of it), checked against the arm's limits
            and the safety workspace on construction.
        action_scale: full-scale move per step (the sim env's ``ActionScale``).
        mount: the TacTip on the flange (the sim env's ``TacTipMount``).
        safety: limits, step sizes, speeds and stop thresholds (the safe defaults; loosening them takes an
            :class:`~simshear_gym.real.safety.UnsafeSafetyConfig`); its ``dry_run`` must stay False (use
            ``dry_run`` here).
        dry_run: check and log motion commands instead of sending them (see the module docstring).
        enable_robot: send EnableRobot on reset when the robot is disabled.
    """

    client: MG400ClientConfig = ENV_CLIENT
    control_period_s: float = 0.1
    servo_margin_s: float = 0.08
    camera_source: str = "0"
    camera_stall_timeout_s: float = 0.5
    frozen_frame_limit: int | None = 20
    preprocess: PreprocessConfig | None = field(default_factory=default_config)
    image_size_px: int = 128
    observation: str = "tactile"
    history: int = 1
    reference_depth_mm: float = 4.0
    posenet: str | None = None
    estimator_process_std_mm: float | None = None
    start_pose_mm_deg: tuple[float, float, float, float] = (300.0, 0.0, 0.0, 0.0)
    action_scale: ActionScale = ActionScale()
    mount: TacTipMount = TacTipMount()
    safety: SafetyConfig = SafetyConfig()
    dry_run: bool = False
    enable_robot: bool = True

    def __post_init__(self) -> None:
        if self.image_size_px not in IMAGE_SIZES_PX:
            raise ValueError(f"RealEnvConfig.image_size_px must be one of {IMAGE_SIZES_PX}, got {self.image_size_px!r}")
        check_observation(self.observation, self.history, "RealEnvConfig")
        if not (isinstance(self.reference_depth_mm, (int, float)) and math.isfinite(self.reference_depth_mm)):
            raise ValueError(f"RealEnvConfig.reference_depth_mm must be a finite depth, mm, got "
                             f"{self.reference_depth_mm!r}")
        if not (math.isfinite(self.control_period_s) and 0.004 <= self.control_period_s <= 1.0):
            raise ValueError(f"RealEnvConfig.control_period_s must be in [0.004, 1] s, got {self.control_period_s!r}")
        for name in ("servo_margin_s",):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f"RealEnvConfig.{name} must be in [0, 1] s, got {value!r}")
        noise = self.estimator_process_std_mm
        if noise is not None and not (math.isfinite(noise) and noise > 0.0):
            raise ValueError(f"RealEnvConfig.estimator_process_std_mm must be None or > 0 mm, got {noise!r}")
        if not (math.isfinite(self.camera_stall_timeout_s) and self.camera_stall_timeout_s > 0.0):
            raise ValueError(f"RealEnvConfig.camera_stall_timeout_s must be finite and > 0 s, got "
                             f"{self.camera_stall_timeout_s!r}")
        if self.safety.dry_run:
            raise ValueError("set dry_run on RealEnvConfig, not on its SafetyConfig (one place decides)")
        limit = self.frozen_frame_limit
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 2):
            raise ValueError(f"RealEnvConfig.frozen_frame_limit must be None or an int >= 2, got {limit!r}")
        start = tuple(float(v) for v in self.start_pose_mm_deg)
        if len(start) != 4 or not all(math.isfinite(v) for v in start):
            raise ValueError(f"RealEnvConfig.start_pose_mm_deg must be 4 finite numbers (x, y, z mm, R deg), "
                             f"got {self.start_pose_mm_deg!r}")
        object.__setattr__(self, "start_pose_mm_deg", start)
        try:  # reachability, joint limits and the workspace box: the checks every target passes
            SafetyLayer(self.safety).check_target(start, start, MotionKind.JOINT)
        except SafetyError as error:
            raise ValueError(f"RealEnvConfig.start_pose_mm_deg {start} cannot be reached safely: {error}") from None
        step_mm = math.sqrt(3.0) * self.action_scale.step_mm
        if step_mm > self.safety.max_step_mm or self.action_scale.step_deg > self.safety.max_step_deg:
            logger.warning("a full-scale action (%.3f mm, %.3f deg) exceeds the safety step limit (%g mm, %g deg): "
                           "such actions end the episode", step_mm, self.action_scale.step_deg,
                           self.safety.max_step_mm, self.safety.max_step_deg)
        # A stream of full-scale actions moves the arm one step per control period (not per ServoP t).
        period_s = self.control_period_s
        if (step_mm / period_s > self.safety.max_speed_mm_s
                or self.action_scale.step_deg / period_s > self.safety.max_speed_deg_s):
            logger.warning("a stream of full-scale actions (%.3f mm, %.3f deg every %g s) exceeds the safety speed "
                           "limit (%g mm/s, %g deg/s): the client refuses such commands (or clamps them, "
                           "servo_over_limit = 'clamp')", step_mm, self.action_scale.step_deg, period_s,
                           self.safety.max_speed_mm_s, self.safety.max_speed_deg_s)

    @property
    def servo_time_s(self) -> float:
        """The ``t`` of each ServoP: period + margin, s."""
        return self.control_period_s + self.servo_margin_s

    def client_config(self) -> MG400ClientConfig:
        """The client's config: :attr:`client` with the safety layer's feedback age (one place decides it)."""
        return replace(self.client, feedback_max_age_s=self.safety.max_feedback_age_s)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (for run logs)."""
        return {
            "robot_ip": self.client.host,
            "ports": [self.client.dashboard_port, self.client.motion_port, self.client.feedback_port],
            "control_period_s": self.control_period_s, "servo_time_s": self.servo_time_s,
            "camera_source": self.camera_source, "frozen_frame_limit": self.frozen_frame_limit,
            "preprocess": None if self.preprocess is None else self.preprocess.to_dict(),
            "image_size_px": self.image_size_px, "observation": self.observation, "history": self.history,
            "reference_depth_mm": self.reference_depth_mm, "posenet": self.posenet,
            "estimator_process_std_mm": self.estimator_process_std_mm,
            "start_pose_mm_deg": list(self.start_pose_mm_deg),
            "action_scale": dict(vars(self.action_scale)), "mount": dict(vars(self.mount)),  # a horizontal one's drop
            "safety": {key: (list(value) if isinstance(value, tuple) else value)
                       for key, value in vars(self.safety).items() if key not in ("geometry", "limits")},
            "safety_unsafe": list(self.safety.loosened()),
            "dry_run": self.dry_run,
        }


# ----------------------------------------------------------------------------------------------------------------
# The env


class RealTactileEnv(gym.Env):
    """The real (or emulated) MG400 with a TacTip, as ``SimShearTracking-v0`` (see the module docstring).

    Args:
        config: robot, camera, timing and safety settings.
        camera: a frame source to read instead of opening ``config.camera_source`` (a simulated camera, a
            recording); the env closes it on :meth:`close`.
        contact_check: called with each step's image and pose (``{"tactile": (1, S, S), "tcp_pose": (4,)}``,
            whatever the observation); returning False means contact is lost (ends the episode when
            ``config.safety.stop_on_lost_contact``).
        estimator: the estimate observation's estimator (None: built like the servo controller's, from
            ``config.posenet``; :func:`~simshear_gym.control.env_estimator.env_estimator`).

    The robot is connected on the first :meth:`reset`, so building the env needs no robot.

    ``info`` of every step: ``time_s`` (since reset), ``flange_pose_mm_deg`` (measured), ``tcp_pose`` (measured,
    as the ``tactile`` observation's ``tcp_pose``, whatever the observation), ``flange_target_mm_deg``
    and ``tcp_target`` (the last target sent, or that would have been sent in a dry run), ``action``,
    ``robot_mode``, ``feedback_age_s``, ``camera_frame_age_s`` (None for a camera that renders on read),
    ``in_contact`` (None without a contact check),
    ``overrun_s``, ``commands_sent``, ``termination`` and, when something stopped the episode, ``safety_event``.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: RealEnvConfig = RealEnvConfig(), camera: FrameSource | None = None,
                 contact_check: ContactCheck | None = None, estimator: Estimator | None = None) -> None:
        self.config = config
        self.observation_space, self.action_space = policy_spaces(config.image_size_px, config.observation,
                                                                  config.history)
        self.action_scale = config.action_scale
        self.reference_depth_mm = config.reference_depth_mm
        self.servo_hints = ServoHints(posenet=config.posenet or "surface",  # what ServoController.for_env reads
                                      process_std_mm=config.estimator_process_std_mm)
        if config.observation in ESTIMATE_OBSERVATIONS and estimator is None:
            from simshear_gym.control.env_estimator import env_estimator

            estimator = env_estimator(self)
        self._policy_observation = PolicyObservation(config.observation, config.history, config.reference_depth_mm,
                                                     estimator if config.observation in ESTIMATE_OBSERVATIONS else None,
                                                     config.action_scale.as_array())
        self.safety = SafetyLayer(replace(config.safety, dry_run=config.dry_run))
        self.client = MG400Client(config.client_config(), self.safety)
        self._camera = camera
        self._owns_camera = camera is None
        self.contact_check = contact_check
        self._connected = False
        self._commanded: np.ndarray | None = None  # flange target of the last command (sent or dry-run)
        self._next_tick = 0.0
        self._t0 = 0.0
        self._last_frame_time: float | None = None
        self._last_obs: dict[str, np.ndarray] | None = None
        self._last_image: np.ndarray | None = None  # the last tactile image (S, S) and tcp pose (4,) read
        self._last_tcp: np.ndarray | None = None
        self._termination: str | None = None  # None: no episode; "": running
        self.commands_sent = 0
        self.safety_events: list[str] = []
        self._flange: np.ndarray | None = None  # measured flange pose of the last observation
        self._snapshot = StatusSnapshot(connected=False)
        self._camera_frame_age_s: float | None = None
        self._in_contact: bool | None = None
        self._previous_frame: np.ndarray | None = None
        self._repeated_frames = 0

    # -- connection ----------------------------------------------------------------------------------------------

    @property
    def camera(self) -> FrameSource | None:
        return self._camera

    def _connect(self) -> None:
        if self._camera is None:
            self._camera = CameraSource(self.config.camera_source, stall_timeout_s=self.config.camera_stall_timeout_s)
        if self._connected and self.client.connected:
            return
        self.client.close()
        self.client.connect()
        self._connected = True
        client = self.config.client
        try:  # the first feedback packet; the env reads tcp_pose from it
            self.client.wait_feedback(client.connect_timeout_s)
        except FeedbackStaleError as error:
            raise MG400ConnectionError(f"no feedback from the MG400 at {client.host}:{client.feedback_port} within "
                                       f"{client.connect_timeout_s:g} s: {error}") from error

    def close(self) -> None:
        """Close the robot connections and the camera (the robot stops at its last servo target)."""
        self.client.close()
        self._connected = False
        if self._camera is not None:
            self._camera.close()
            if self._owns_camera:
                self._camera = None
        self._termination = None

    # -- gym API -------------------------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Connect if needed, move to the start pose (``options["start_pose_mm_deg"]`` overrides the config's;
        it passes the safety layer like every target) and return the first observation.

        Raises:
            RealEnvError: the robot is in error mode or the move to the start pose failed.
            SafetyError: the start pose is refused, e.g. farther than ``max_move_mm`` (nothing is sent), or
                :class:`~simshear_gym.real.safety.FeedbackMismatchError`: the robot's joints and pose disagree.
            MG400ConnectionError: the robot cannot be reached.
        """
        super().reset(seed=seed)
        options = options or {}
        start = np.asarray(options.get("start_pose_mm_deg", self.config.start_pose_mm_deg), dtype=np.float64)
        self._termination = None
        self._connect()
        mode = self.client.robot_mode()
        if mode == RobotMode.ERROR:
            alarms = self.client.get_error_id().all_ids
            raise RealEnvError(f"the MG400 is in error mode (alarms {list(alarms)}); clear the cause, send "
                               "ClearError() and Continue(), then reset again")
        dry_run = self.config.dry_run
        if not dry_run and self.config.enable_robot and mode in (RobotMode.DISABLED, RobotMode.POWER_OFF):
            self.client.enable_robot()
        self.client.reset_reference()
        try:
            self.client.mov_j(*start)  # safety: reachability, workspace, path, max_move_*
            self.client.sync()
        except MG400Error as error:
            raise RealEnvError(f"moving to the start pose {start.tolist()} failed: {error}") from error
        if not dry_run:
            self._wait_until_at(start)
            # from rest, a servo command may ask for max_accel times the time at rest: start the stream with a t's
            self.client.wait_until_still(self.config.servo_time_s, timeout_s=self.config.client.sync_timeout_s)
        self._commanded = start.copy()
        self.commands_sent = 0
        self.safety_events = []
        self._last_frame_time = None
        self._previous_frame = None
        self._repeated_frames = 0
        self._t0 = time.monotonic()
        self._termination = ""
        self._last_obs = self._last_image = self._last_tcp = None
        obs, stop = self._observe(None)
        self._next_tick = time.monotonic() + self.config.control_period_s
        info = self._info(stop_reason="", action=np.zeros(4), overrun_s=0.0)
        if stop:
            # An episode that cannot start is an error, not a zero-length episode.
            self._termination = None
            raise RealEnvError(f"cannot start the episode: {stop[1]}")
        return obs, info

    def step(self, action):
        if self._termination is None:
            raise RuntimeError("call reset() before step()")
        if self._termination:
            raise RuntimeError(f"the episode ended ({self._termination}); call reset() before step()")
        array = np.asarray(action, dtype=np.float64)
        if array.shape == (4,) and not np.all(np.isfinite(array)):
            stop: tuple[str, str] | None = ("safety_refused", f"action {array.tolist()} is not finite (a NaN / inf "
                                            "estimate?): nothing sent")
        else:
            move = action_to_move(action, self.action_scale)
            target = move_to_flange_target(self._commanded, move, self.config.mount)
            stop = self._send(target)
        overrun_s = 0.0
        if stop is None:
            delay_s = self._next_tick - time.monotonic()
            if delay_s > 0.0:
                time.sleep(delay_s)
            else:
                overrun_s = -delay_s
            self._next_tick = max(self._next_tick + self.config.control_period_s, time.monotonic())
            obs, stop = self._observe(move)
        else:
            obs = self._last_obs
        if stop is None:
            return obs, 0.0, False, False, self._info(stop_reason="", action=array, overrun_s=overrun_s)
        return obs, 0.0, True, False, self._stop_episode(*stop, array, overrun_s)

    def end_episode(self, termination: str, event: str):
        """End the running episode without sending anything (the caller could not compute an action, e.g. the
        controller refused a NaN estimate): ``step``'s return value with ``terminated`` True."""
        if termination not in TERMINATIONS:
            raise ValueError(f"termination must be one of {TERMINATIONS}, got {termination!r}")
        if self._termination != "":
            raise RuntimeError("no episode is running; call reset() first")
        return self._last_obs, 0.0, True, False, self._stop_episode(termination, event, np.full(4, np.nan), 0.0)

    def _stop_episode(self, termination: str, event: str, action: np.ndarray, overrun_s: float) -> dict[str, Any]:
        """End the episode with ``termination`` (``event`` says why: logged and kept); the step's ``info``."""
        self.safety_events.append(event)
        logger.warning("real env: episode stopped (%s): %s", termination, event)
        self._termination = termination
        info = self._info(stop_reason=termination, action=action, overrun_s=overrun_s)
        info["safety_event"] = event
        return info

    def _wait_until_at(self, pose: np.ndarray, tolerance: float = 0.5, timeout_s: float = 2.0) -> None:
        """Wait for a feedback packet that shows the queue done and the arm at ``pose`` (Sync answers before the
        newest packet shows it)."""
        reached = wait_at_pose(self.client, pose, tolerance, timeout_s, 0.002)
        if reached is not None:
            raise RealEnvError(f"the MG400 stopped at {reached.round(3).tolist()} instead of the start pose "
                               f"{pose.tolist()} (tolerance {tolerance} mm / deg)")

    def _send(self, target: np.ndarray) -> tuple[str, str] | None:
        """One ServoP through the safety layer; (termination, reason) when it was refused or failed."""
        try:
            sent = self.client.servo_p(*target, t_s=self.config.servo_time_s)
        except MotionRefusedError as error:  # stale or missing feedback, error mode: the client sent nothing
            return STOP_TERMINATIONS[error.reason], f"target {target.round(3).tolist()} not sent: {error}"
        except FeedbackMismatchError as error:
            return "feedback_mismatch", f"target {target.round(3).tolist()} not sent: {error}"
        except SafetyError as error:
            return "safety_refused", f"target {target.round(3).tolist()} refused, not sent: {error}"
        except MG400Error as error:
            return "robot_error", str(error)
        except (MG400ConnectionError, MG400TimeoutError, ProtocolError) as error:
            return "lost_connection", str(error)
        # the pose sent: with SafetyConfig.servo_over_limit = "clamp", the client may have moved it back toward the arm
        self._commanded = np.asarray(sent, dtype=np.float64) if sent is not None else target
        if not self.config.dry_run:
            self.commands_sent += 1
        return None

    def _observe(self, move: np.ndarray | None) -> tuple[dict[str, np.ndarray], tuple[str, str] | None]:
        """Read the camera and the feedback; the observation and (termination, reason) if something must stop.
        ``move``: the sensor move (dx, dy, dz mm, dRz deg) commanded since the last observation (None at reset)."""
        stop: tuple[str, str] | None = None
        try:
            frame = self._camera.read()
        except EndOfStream as error:
            frame, stop = None, ("camera_ended", str(error))
        except CameraError as error:
            frame, stop = None, ("camera_stall", str(error))
        # The camera's frame age: how old the newest frame had become when this one arrived (or now, without one).
        # A source that renders on read makes its frame when asked: the time between reads is the computer's.
        now = time.monotonic()
        aged = self._last_frame_time is not None and not renders_on_read(self._camera)
        frame_age_s = now - self._last_frame_time if aged else None
        if frame is not None:
            self._last_frame_time = now
            stop = stop or self._frozen(frame)
            tactile = tactile_from_frame(frame, self.config.preprocess, self.config.image_size_px)
        else:
            tactile = (self._last_image if self._last_image is not None
                       else np.zeros((self.config.image_size_px,) * 2, np.uint8))
        self._camera_frame_age_s = frame_age_s
        try:
            flange = np.asarray(self.client.latest_feedback().tool_vector_actual, dtype=np.float64)
        except FeedbackStaleError as error:
            flange = None
            stop = stop or ("lost_connection", f"robot feedback lost: {error}")
        mismatch = self.client.feedback_mismatch
        if mismatch is not None:
            stop = stop or ("feedback_mismatch", f"robot feedback: {mismatch}")
        if flange is not None:
            tcp = tcp_pose_from_flange(flange, self.config.mount)
            self._flange = flange
        else:
            tcp = self._last_tcp if self._last_tcp is not None else np.zeros(4)
            self._flange = None
        self._last_image, self._last_tcp = tactile, tcp
        if move is None or self._last_obs is None:
            obs = self._policy_observation.reset(tactile, tcp)
        else:
            obs = self._policy_observation.step(tactile, tcp, move)
        self._last_obs = obs
        in_contact = None
        if self.contact_check is not None and frame is not None:
            seen = {"tactile": tactile[None].copy(),
                    "tcp_pose": np.clip(tcp, TCP_POSE_LOW, -TCP_POSE_LOW).astype(np.float32)}
            in_contact = bool(self.contact_check(seen))
        self._in_contact = in_contact
        snapshot = self.client.status_snapshot(camera_frame_age_s=frame_age_s, in_contact=in_contact)
        self._snapshot = snapshot
        decision = self.safety.check_status(snapshot)
        if stop is None and decision.stop:
            stop = (self._classify(decision.reason), "; ".join(decision.reasons))
        return obs, stop

    def _frozen(self, frame: np.ndarray) -> tuple[str, str] | None:
        """("camera_stall", why) once ``frozen_frame_limit`` byte-identical frames came in a row."""
        limit = self.config.frozen_frame_limit
        if limit is None:
            return None
        previous = self._previous_frame
        same = previous is not None and previous.shape == frame.shape and np.array_equal(previous, frame)
        self._repeated_frames = self._repeated_frames + 1 if same else 1
        self._previous_frame = np.array(frame, copy=True)
        if self._repeated_frames >= limit:
            return "camera_stall", (f"camera frozen: {self._repeated_frames} identical frames in a row "
                                    f"(frozen_frame_limit = {limit})")
        return None

    @staticmethod
    def _classify(reason: StopReason) -> str:
        """The termination (``info["termination"]``) of a stop condition."""
        return STOP_TERMINATIONS[reason]

    def _info(self, stop_reason: str, action: np.ndarray, overrun_s: float) -> dict[str, Any]:
        snapshot = self._snapshot
        commanded = self._commanded
        return {
            "time_s": time.monotonic() - self._t0,
            "flange_pose_mm_deg": None if self._flange is None else self._flange.copy(),
            "tcp_pose": None if self._last_tcp is None else np.asarray(self._last_tcp, dtype=np.float64).copy(),
            "flange_target_mm_deg": commanded.copy(),
            "tcp_target": tcp_pose_from_flange(commanded, self.config.mount),
            "action": np.asarray(action, dtype=np.float64).copy(),
            "robot_mode": snapshot.robot_mode,
            "feedback_age_s": snapshot.feedback_age_s,
            "camera_frame_age_s": self._camera_frame_age_s,
            "in_contact": self._in_contact,
            "overrun_s": overrun_s,
            "commands_sent": self.commands_sent,
            "dry_run": self.config.dry_run,
            "termination": stop_reason,
        }


class EstimatedContact:
    """A ``contact_check`` from a pose estimator's raw reading: in contact while the estimated depth is at least
    ``min_depth_mm`` (labels' convention: the face lies at 2.2 mm).

    Args:
        estimator: anything with ``read(tactile) -> (mean, std)`` whose mean starts with the depth, mm
            (:class:`~simshear_gym.control.estimator.TactileEstimator`; share the controller's to load it once).
        min_depth_mm: the depth below which contact counts as lost.
    """

    def __init__(self, estimator, min_depth_mm: float) -> None:
        if not math.isfinite(min_depth_mm):
            raise ValueError(f"min_depth_mm must be finite, got {min_depth_mm!r}")
        self.estimator = estimator
        self.min_depth_mm = float(min_depth_mm)
        self.last_depth_mm: float | None = None

    def __call__(self, observation: dict[str, np.ndarray]) -> bool:
        mean, _ = self.estimator.read(observation["tactile"])
        self.last_depth_mm = float(mean[0])
        return self.last_depth_mm >= self.min_depth_mm


__all__ = ["STOP_TERMINATIONS", "TERMINATIONS", "ContactCheck", "EstimatedContact", "RealEnvConfig", "RealEnvError",
           "RealTactileEnv", "action_to_move", "move_to_flange_target", "tactile_from_frame", "tcp_pose_from_flange"]
