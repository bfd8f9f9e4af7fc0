"""What the SimShear envs share: the follower arm with its TacTip, actions, observations, translation, the
contact bookkeeping (shear, depth, contact error), reward, termination and the rgb render.

How a task plugs in (``SimShearTracking-v0`` in :mod:`simshear_gym.envs.tracking` is the worked example; a
``SimShearCoLift-v0`` subclasses the same way): subclass :class:`SimShearEnv`, call ``super().__init__(...)``
(after ``EzPickle.__init__(self, **your_kwargs)`` so the env pickles), and implement five hooks:

- ``_build_scene()``: spawn the task's bodies into ``self.world``, create the follower with
  :meth:`SimShearEnv._add_follower` (an MG400; another :class:`~simshear_gym.sim.arm.Arm` with
  :meth:`SimShearEnv._use_follower`) and any other arm with :meth:`SimShearEnv._add_arm` (added arms are moved on
  by the base every step), and set ``self.face_half_extents_mm`` (the touched face's half size, x and y).
- ``_reset_scene(rng, options)``: put everything at the episode's start, drawing all randomness from ``rng``;
  the follower must end in contact (:meth:`SimShearEnv.T_world_sensor_on_face` gives the sensor pose at a point
  of the face at a depth). Its pose then is the target the contact error is measured against.
- ``_command_scene(time_s, dt_s)``: send the servo commands that take the task (leader arm) to ``time_s``.
- ``_sync_scene()``: move bodies that follow arms (a held plate or object) to where the arms now are.
- ``_T_world_face()``: the touched face's frame (origin on the face, z out of the face, like a stimulus frame).

Optionally override ``_task_info()`` (extra info entries), ``_reward``/``_termination`` and ``_oracle_variables``
(which four pose/shear variables the oracle sees). A horizontal sensor (co-lift, pushing) passes a
:class:`~simshear_gym.contract.HorizontalTacTipMount` as ``mount``: the action's turn is then about the vertical,
as a level flange allows (``_sensor_target``). Everything else (actions, observations and translation, shear,
contact error, reward, termination, render, pickling, the batched vector env of :mod:`simshear_gym.envs.vector`)
comes with the base.

Frames: the **sensor** frame is the TacTip's (apex origin, +z out of the dome into the face); the **work** frame
of a face is the labels' frame (z into the face, at the face plus ``ReplayGeometry.surface_depth_mm``), so the
sensor's pose in it is a label pose and its z is the depth a pose-and-shear network predicts.

Images: the TacTip renders at 128 px (the translator's size); for ``image_size_px=64`` the finished 128 px image
(sim, or translated) is averaged over 2x2 pixels, so a 64 px observation is the 128 px one at half resolution in
every mode. The translator's shear input is the tracker's shear with its z component zeroed: the paired training
data never moved along z during a shear (indentation shows in the sim image itself).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import EzPickle

from simshear_gym.contract import (
    ESTIMATE_OBSERVATIONS,
    OBS_MODES,
    ORACLE_MODES,
    RAW_SHEAR_KEY,
    RENDER_SIZE_PX,
    TRANSLATED_MODES,
    TRUE_POSE_SHEAR_LIMIT,
    ActionScale,
    HorizontalTacTipMount,
    ServoHints,
    TacTipMount,
    action_space,
    action_to_move,
    check_image_size,
    check_observation,
    finish_tactile,
    observation_space,
)
from simshear_gym.data.labels import wrap_deg
from simshear_gym.envs.observation import Estimator, PolicyObservation
from simshear_gym.models.translator_runtime import choose_translator, choose_translator_device
from simshear_gym.models.zoo import load_sensor, translator_weights
from simshear_gym.robots.mg400.frames import T_base_flange_to_pose
from simshear_gym.robots.mg400.kinematics import KinematicsError
from simshear_gym.sim.arm import Arm
from simshear_gym.sim.mg400_arm import MG400ArmConfig, SimMG400
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.sim.shear import ShearTracker, ShearTrackerConfig
from simshear_gym.sim.tactip import TacTip, TacTipConfig
from simshear_gym.sim.world import World
from simshear_gym.transforms import (
    invert,
    matrix_to_pose,
    pose_from_matrix_fast,
    pose_to_matrix,
    rz_matrix,
)
from simshear_gym.transforms import matrix_to_pybullet_fast as pybullet_pose_fast


@dataclass(frozen=True)
class RewardConfig:
    """Per step, with ``e`` the contact error (mm)::

        reward = alive_bonus - min(e / error_scale_mm, max_error_term)
                 + precision_bonus * exp(-(e / precision_scale_mm) ** 2)
                 - contact_loss_penalty * (not in contact) - termination_penalty * (the step ends the episode)

    Why this shape: while in contact the reward never drops below ``alive_bonus - max_error_term`` = 0, so ending
    an episode early never pays (with the earlier ``max_error_term`` of 2 the reward went negative beyond 5 mm of
    contact error, where ending the episode paid; the PPO runs of ``results/servo_ppo.json`` all ended early, too
    deep or 15 mm off); the linear term pulls from far
    (up to 5 mm), the precision term (a 1 mm Gaussian) rewards the last fraction of a millimetre, where the
    linear term's slope alone is too weak a signal; an early end costs ``termination_penalty`` on top of the
    reward forfeited. Truncation at the time limit is not an end: no penalty. Per step in [0, 2] in contact."""

    alive_bonus: float = 1.0
    error_scale_mm: float = 5.0
    max_error_term: float = 1.0
    precision_bonus: float = 1.0
    precision_scale_mm: float = 1.0
    contact_loss_penalty: float = 1.0
    termination_penalty: float = 10.0

    def __post_init__(self) -> None:
        if not (self.error_scale_mm > 0 and self.precision_scale_mm > 0) or min(
                self.max_error_term, self.contact_loss_penalty, self.precision_bonus, self.termination_penalty) < 0:
            raise ValueError(f"RewardConfig: need error_scale_mm, precision_scale_mm > 0 and non-negative terms, "
                             f"got {self}")


@dataclass(frozen=True)
class TerminationConfig:
    """An episode ends when the sensor lifts more than ``lost_contact_mm`` off the face (or leaves the face's
    extent), the contact error exceeds ``max_contact_error_mm``, the dome is pressed in deeper than
    ``max_penetration_mm``, or an arm refuses a target."""

    lost_contact_mm: float = 1.0
    max_contact_error_mm: float = 15.0
    max_penetration_mm: float = 5.0

    def __post_init__(self) -> None:
        if min(self.lost_contact_mm, self.max_contact_error_mm, self.max_penetration_mm) <= 0:
            raise ValueError(f"TerminationConfig thresholds must be > 0, got {self}")


@dataclass(frozen=True)
class ContactState:
    """The follower's contact after a step (sensor frame / labels' conventions, mm and deg)."""

    pose_work: np.ndarray  # (6,) sensor pose in the face's work frame (a label pose)
    penetration_mm: float  # apex below the face (negative: above it)
    on_face: bool  # the apex lies within the face's extent
    in_contact: bool
    shear_sensor: np.ndarray  # (6,) ShearTracker output, sensor frame
    contact_error_mm: float  # |apex - target point carried with the face|
    rz_error_deg: float  # sensor Rz relative to the face minus the target's
    T_world_sensor: np.ndarray

    @property
    def depth_mm(self) -> float:
        return float(self.pose_work[2])

    def true_pose_shear(self) -> np.ndarray:
        """float32 (4,): depth (label z), shear x, shear y (mm), shear Rz (deg), sensor frame."""
        values = np.array([self.depth_mm, self.shear_sensor[0], self.shear_sensor[1], self.shear_sensor[5]])
        return np.clip(values, -TRUE_POSE_SHEAR_LIMIT, TRUE_POSE_SHEAR_LIMIT).astype(np.float32)


class SimShearEnv(gym.Env, EzPickle):
    """Base of the SimShear envs (abstract: see the module docstring for the hooks a task implements).

    Args:
        obs_mode: ``"real"`` (TacTip image translated by the shipped shPix2pix translator), ``"sim"`` (raw depth
            image), ``"oracle"`` (sim image plus ``true_pose_shear``), ``"oracle_real"`` (translated image plus
            ``true_pose_shear``).
        image_size_px: 128 or 64 (see the module docstring).
        control_rate_hz: steps per second of simulated time; each step's servo command takes one period.
        render_mode: None; ``"rgb_array"``: ``render()`` returns uint8 (180, 420, 3), a TinyRenderer view of the
            arms, the TacTip and the face (240 px wide) beside the newest tactile image (180 px square); ``"human"``:
            the same frame in a window (:class:`~simshear_gym.envs.viewer.HumanViewer`, Tk; needs a display, e.g.
            ``xvfb-run``: without one, one logged warning and no window), refreshed on every ``reset`` and
            ``step`` at ``metadata["render_fps"]`` (the control rate: simulated time at wall-clock pace);
            ``render()`` then returns None.
        reference_depth_mm: the depth to keep, label convention (face at ``SURFACE_DEPTH_MM`` = 2.2 mm).
        action_scale, reward, termination, mount, arm_config, shear_config: see their classes.
        sensor: a sensor's own models instead of the shipped ones (its ``configs/<name>.toml``, the folder of its
            ``simshear pipeline run`` or that run's ``sensor.json``; :func:`~simshear_gym.models.zoo.load_sensor`):
            the TacTip renders with its dome and camera settings, its translator makes the images, and an
            image-based controller reads them with its GDNN (``servo_hints.posenet``).
        raw_tactile: return the raw 128 px sim image and leave finishing it (:func:`finish_tactile`) to the
            caller (the batched vector env); the observation space's image is then 1x128x128 (``observation``
            ``"tactile"`` with ``history`` 1 only), and the observation carries the shear to finish it with
            (:data:`~simshear_gym.contract.RAW_SHEAR_KEY`, float32 (6,)).
        observation: what the policy sees (:func:`~simshear_gym.contract.observation_space`, the same in
            ``RealTactileEnv``): ``"tactile"`` (the image of ``obs_mode`` and ``tcp_pose``: the default, as
            before), ``"estimate"`` (the estimator's GDNN reading and Bayesian filter state of that image,
            normalised), ``"tactile+estimate"`` or ``"estimate+action"`` (the estimate and ``last_action``, the
            move commanded since the previous image over the action's full scale).
        history: k: the observation stacks the last k images (``tactile`` (k, S, S)) and estimates (``estimate``
            (16 k,)), oldest first; at reset all k are the first frame.
        estimator: for the estimate observations: the servo controller's estimator, or a callable that builds
            it from this env (``simshear_gym.control.env_estimator.env_estimator``: the GDNN the env names in
            ``servo_hints`` and its process noise, as ``ServoController.for_env``). Envs do not import the
            controllers (same floor), so it is passed in; it is called once, at construction.
        device: where the translator runs (``"cpu"``, ``"cuda"``, ``"auto"``; default ``$SIMSHEAR_TRANSLATOR_DEVICE``
            or ``"cpu"``: :func:`~simshear_gym.models.translator_runtime.choose_translator_device`); the physics
            runs on the CPU.
        translator: which shipped translator makes the images: ``"full"`` (the shipped shPix2pix) or
            ``"student"`` (its distilled student, the fast path); default ``$SIMSHEAR_TRANSLATOR`` or ``"full"``
            (:func:`~simshear_gym.models.translator_runtime.choose_translator`). A ``sensor``'s own translator takes
            no student.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}
    translator_contact = "surface"
    servo_hints = ServoHints()  # what a controller made for this env takes from it (the shipped surface GDNN)

    def __init__(self, *, obs_mode: str = "real", image_size_px: int = 128, control_rate_hz: float = 10.0,
                 render_mode: str | None = None, reference_depth_mm: float = 4.0,
                 action_scale: ActionScale = ActionScale(), reward: RewardConfig = RewardConfig(),
                 termination: TerminationConfig = TerminationConfig(), mount: TacTipMount = TacTipMount(),
                 arm_config: MG400ArmConfig = MG400ArmConfig(),
                 shear_config: ShearTrackerConfig = ShearTrackerConfig(), raw_tactile: bool = False,
                 sensor: str | None = None, observation: str = "tactile", history: int = 1,
                 estimator: Estimator | Callable[[Any], Estimator] | None = None, device: str | None = None,
                 translator: str | None = None) -> None:
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        check_observation(observation, history)
        if raw_tactile and (observation != "tactile" or history != 1):
            raise ValueError(f"raw_tactile (the batched vector env) gives the image alone: it needs observation="
                             f"'tactile' and history=1, got {observation!r}, {history}; use SB3's or gymnasium's "
                             "vector envs for the other observations")
        check_image_size(image_size_px)
        if not (isinstance(control_rate_hz, (int, float)) and 1.0 <= control_rate_hz <= 250.0):
            raise ValueError(f"control_rate_hz must be in [1, 250] Hz, got {control_rate_hz!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if not SURFACE_DEPTH_MM < reference_depth_mm < SURFACE_DEPTH_MM + termination.max_penetration_mm:
            raise ValueError(
                f"reference_depth_mm must put the dome into the face: within ({SURFACE_DEPTH_MM}, "
                f"{SURFACE_DEPTH_MM + termination.max_penetration_mm}) mm, got {reference_depth_mm!r}")
        self.obs_mode = obs_mode
        self.image_size_px = image_size_px
        self.control_rate_hz = float(control_rate_hz)
        self.dt_s = 1.0 / self.control_rate_hz
        self.render_mode = render_mode
        self._viewer = None  # render_mode="human": its window, opened on the first frame
        self.reference_depth_mm = float(reference_depth_mm)
        self.action_scale = action_scale
        self.reward_config = reward
        self.termination_config = termination
        self.mount = mount
        self.arm_config = arm_config
        self.raw_tactile = raw_tactile
        self.translator_device = choose_translator_device(device) if obs_mode in TRANSLATED_MODES else "cpu"
        self.metadata = {**self.metadata, "render_fps": self.control_rate_hz}

        self.world = World()
        tactip_config = TacTipConfig(image_size_px=RENDER_SIZE_PX)
        self.translator_weights: str | None = None
        self.translator = choose_translator(translator) if obs_mode in TRANSLATED_MODES else "full"
        if self.translator == "student":
            if sensor is not None:
                raise ValueError(f"translator 'student' is the shipped translator's student; sensor {sensor!r} "
                                 "brings its own translator: leave translator (and $SIMSHEAR_TRANSLATOR) unset")
            self.translator_weights = str(translator_weights(self.translator_contact, student=True))
        if sensor is not None:
            models = load_sensor(sensor)
            tactip_config = TacTipConfig(**{**models.tactip, "image_size_px": RENDER_SIZE_PX})
            self.translator_weights = models.translator(self.translator_contact)
            self.servo_hints = replace(self.servo_hints, posenet=models.posenet(self.translator_contact))
        self.tactip = TacTip(self.world, tactip_config)
        self.shear_tracker = ShearTracker(shear_config)
        self.T_work_face = np.diag([1.0, -1.0, -1.0, 1.0])
        self.T_work_face[2, 3] = SURFACE_DEPTH_MM
        self._T_face_work = invert(self.T_work_face)
        self.follower: Arm | None = None
        self._arms: list[Arm] = []
        self.face_half_extents_mm = (np.inf, np.inf)
        self._build_scene()
        if self.follower is None:
            raise TypeError(f"{type(self).__name__}._build_scene must create the follower with _add_follower()")

        self.observation = observation
        self.history = history
        self.observation_space = observation_space(RENDER_SIZE_PX if raw_tactile else image_size_px,
                                                   oracle=obs_mode in ORACLE_MODES, observation=observation,
                                                   history=history)
        if raw_tactile:
            self.observation_space = gym.spaces.Dict({**self.observation_space.spaces, RAW_SHEAR_KEY: gym.spaces.Box(
                -np.inf, np.inf, (6,), dtype=np.float32)})
        self.action_space = action_space()
        if observation in ESTIMATE_OBSERVATIONS:
            if estimator is None:
                raise ValueError(f"observation={observation!r} needs estimator=: pass simshear_gym.control."
                                 "env_estimator.env_estimator (the servo controller's GDNN + filter)")
            if not isinstance(estimator, Estimator):
                estimator = estimator(self)
        self._policy_observation = PolicyObservation(observation, history, self.reference_depth_mm,
                                                     estimator if observation in ESTIMATE_OBSERVATIONS else None,
                                                     self.action_scale.as_array())

        self._time_s = 0.0
        self._steps_out_of_contact = 0
        self._target_face_mm = np.zeros(3)
        self._target_rz_deg = 0.0
        self._state: ContactState | None = None
        self._last_tactile: np.ndarray | None = None
        self._scene_bodies: dict[str, int] = {}

    # ------------------------------------------------------------ task hooks
    def _build_scene(self) -> None:
        raise NotImplementedError

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        raise NotImplementedError

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        raise NotImplementedError

    def _sync_scene(self) -> None:
        raise NotImplementedError

    def _T_world_face(self) -> np.ndarray:
        raise NotImplementedError

    def _task_info(self) -> dict[str, Any]:
        return {}

    def _sensor_target(self, T_world_sensor: np.ndarray, move: np.ndarray) -> np.ndarray:
        """Where a scaled action ``(dx, dy, dz mm, dRz deg)`` sends the sensor: a move in the sensor frame and a
        turn about its axis (vertical for a downward sensor); a horizontal sensor
        (:class:`~simshear_gym.contract.HorizontalTacTipMount`) turns about the vertical through the apex instead,
        the only rotation a level MG400 flange has."""
        if isinstance(self.mount, HorizontalTacTipMount):
            target = T_world_sensor.copy()
            target[:3, 3] += T_world_sensor[:3, :3] @ move[:3]
            target[:3, :3] = rz_matrix(move[3])[:3, :3] @ T_world_sensor[:3, :3]
            return target
        T_move = rz_matrix(move[3])
        T_move[:3, 3] = move[:3]
        return T_world_sensor @ T_move

    def _oracle_variables(self, state: ContactState) -> np.ndarray:
        """``true_pose_shear``: depth, shear x, y, Rz (override with the task's four variables)."""
        return state.true_pose_shear()

    # --------------------------------------------------------- for the tasks
    def _add_arm(self, T_world_base: np.ndarray, pose_mm_deg: np.ndarray,
                 T_flange_tool: np.ndarray = np.eye(4)) -> SimMG400:
        """An MG400 that the base moves on every step. Its link boxes exist only with a render mode: TinyRenderer
        transforms every shape in the world for each tactile image too (10 boxes: +0.08 ms on ~1 ms)."""
        arm = SimMG400(self.world, T_world_base, pose_mm_deg, T_flange_tool, self.arm_config,
                       bodies=self.render_mode is not None)
        self._arms.append(arm)
        return arm

    def _add_follower(self, T_world_base: np.ndarray, pose_mm_deg: np.ndarray,
                      T_flange_sensor: np.ndarray | None = None) -> SimMG400:
        """The MG400 carrying the TacTip; its tool point is the sensor's TCP. ``T_flange_sensor`` defaults to
        ``mount.T_flange_sensor()`` (pointing down); a task with a horizontal sensor passes its own."""
        T_flange_sensor = self.mount.T_flange_sensor() if T_flange_sensor is None else T_flange_sensor
        self.follower = self._add_arm(T_world_base, pose_mm_deg, T_flange_sensor)
        return self.follower

    def _use_follower(self, arm: Arm) -> Arm:
        """Make an arm built by the task (any :class:`~simshear_gym.sim.arm.Arm`, e.g. the 6-DoF
        :class:`~simshear_gym.sim.panda_arm.SimPanda`; its tool the sensor's TCP) the follower, moved on every
        step like the others."""
        self._arms.append(arm)
        self.follower = arm
        return arm

    def T_world_sensor_on_face(self, T_world_face: np.ndarray, x_work_mm: float, y_work_mm: float,
                               depth_mm: float, rz_work_deg: float = 0.0) -> np.ndarray:
        """Sensor pose at a point of a face given in its work frame (label pose ``(x, y, depth, 0, 0, Rz)``)."""
        pose_work = np.array([x_work_mm, y_work_mm, depth_mm, 0.0, 0.0, rz_work_deg])
        return T_world_face @ self._T_face_work @ pose_to_matrix(pose_work)

    def flange_pose_for_sensor(self, T_world_base: np.ndarray, T_world_sensor: np.ndarray) -> np.ndarray:
        """The flange pose (x, y, z mm, R deg in an arm's base frame) that puts the TacTip at ``T_world_sensor``."""
        return T_base_flange_to_pose(invert(T_world_base) @ T_world_sensor @ invert(self.mount.T_flange_sensor()))

    # ------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.shear_tracker.reset()
        self._time_s = 0.0
        self._steps_out_of_contact = 0
        self._reset_scene(self.np_random, options)
        self._sync_scene()
        for arm in self._arms:
            arm.update_bodies()
        T_face_sensor = invert(self._T_world_face()) @ self.follower.T_world_tool()
        self._target_face_mm = T_face_sensor[:3, 3].copy()
        self._target_rz_deg = float(matrix_to_pose(self._T_face_work @ T_face_sensor)[5])
        state = self._measure()
        if not state.in_contact:
            raise RuntimeError(f"{type(self).__name__}._reset_scene left the sensor out of contact "
                               f"(penetration {state.penetration_mm:.3f} mm)")
        self._state = state
        observation = self._observation(state, None)
        if self.render_mode == "human":
            self.render()
        return observation, self._info(state, "")

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        move = self._action_to_move(action)
        arm_error = ""
        try:
            self.follower.servo_tool(self._sensor_target(self._state.T_world_sensor, move), self.dt_s)
        except ValueError as error:  # LimitError / UnreachableError: the real arm refuses (alarm)
            arm_error = f"follower refused the target: {error}"
        self._time_s += self.dt_s
        try:
            self._command_scene(self._time_s, self.dt_s)
        except KinematicsError as error:
            arm_error = arm_error or f"leader refused the target: {error}"
        for arm in self._arms:
            try:
                arm.advance(self.dt_s)
            except KinematicsError as error:
                arm_error = arm_error or f"arm stopped at a limit: {error}"
        self._sync_scene()
        state = self._measure()
        self._state = state
        self._steps_out_of_contact += int(not state.in_contact)
        reason = self._termination(state, arm_error)
        info = self._info(state, reason)
        if arm_error:
            info["arm_error"] = arm_error
        observation = self._observation(state, move)
        if self.render_mode == "human":
            self.render()
        return observation, float(self._reward(state, reason)), bool(reason), False, info

    def render(self):
        if self.render_mode is None:
            return None
        frame = np.concatenate([self._scene_view(), self._tactile_view()], axis=1)
        if self.render_mode == "rgb_array":
            return frame
        if self._viewer is None:
            from simshear_gym.envs.viewer import HumanViewer

            self._viewer = HumanViewer(f"{self.spec.id if self.spec else type(self).__name__}: scene | tactile "
                                       f"({self.obs_mode})", self.metadata["render_fps"])
        self._viewer.show(frame)
        return None

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.world.close()

    def __getstate__(self) -> dict:
        """Pickled: the construction arguments (EzPickle) and the registry spec; a copy is a fresh env that
        behaves like the original after the same ``reset(seed=...)``."""
        return {**EzPickle.__getstate__(self), "spec": self.spec}

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        spec = state.pop("spec", None)
        EzPickle.__setstate__(self, state)
        self.spec = spec

    # -------------------------------------------------------------- pieces
    def _action_to_move(self, action) -> np.ndarray:
        return action_to_move(action, self.action_scale)

    def _measure(self) -> ContactState:
        T_world_sensor = self.follower.T_world_tool()
        T_world_face = self._T_world_face()
        T_face_sensor = invert(T_world_face) @ T_world_sensor
        penetration = -float(T_face_sensor[2, 3])
        half_x, half_y = self.face_half_extents_mm
        on_face = abs(T_face_sensor[0, 3]) <= half_x and abs(T_face_sensor[1, 3]) <= half_y
        in_contact = on_face and penetration > 0.0
        pose_work = pose_from_matrix_fast(self.T_work_face @ T_face_sensor)
        shear = self.shear_tracker.update(pose_work, in_contact)
        target_world = T_world_face[:3, :3] @ self._target_face_mm + T_world_face[:3, 3]
        error = float(np.linalg.norm(T_world_sensor[:3, 3] - target_world))
        return ContactState(pose_work, penetration, bool(on_face), bool(in_contact), shear, error,
                            float(wrap_deg(pose_work[5] - self._target_rz_deg)), T_world_sensor)

    def _observation(self, state: ContactState, move: np.ndarray | None) -> dict[str, np.ndarray]:
        """The observation after reset (``move`` None) or after a step that commanded ``move``."""
        sim = self.tactip.render(state.T_world_sensor)
        if self.raw_tactile:
            image = sim
        else:
            image = finish_tactile(sim[None], state.shear_sensor[None], self.obs_mode, self.image_size_px,
                                   self.translator_contact, self.translator_weights,
                                   translator_device=self.translator_device)[0]
        self._last_tactile = image
        tcp = self.follower.tool_pose_mm_deg()
        if move is None:
            obs = self._policy_observation.reset(image, tcp)
        else:
            obs = self._policy_observation.step(image, tcp, move)
        if self.obs_mode in ORACLE_MODES:
            obs["true_pose_shear"] = self._oracle_variables(state)
        if self.raw_tactile:
            obs[RAW_SHEAR_KEY] = state.shear_sensor.astype(np.float32)
        return obs

    def _info(self, state: ContactState, termination: str) -> dict[str, Any]:
        return {
            "contact_error_mm": state.contact_error_mm,
            "rz_error_deg": state.rz_error_deg,
            "in_contact": state.in_contact,
            "penetration_mm": state.penetration_mm,
            "depth_mm": state.depth_mm,
            "shear_sensor_mm_deg": state.shear_sensor.copy(),
            "sensor_world_mm": state.T_world_sensor[:3, 3].copy(),
            "target_world_mm": self._target_world_mm(),
            "time_s": self._time_s,
            "steps_out_of_contact": self._steps_out_of_contact,
            "termination": termination,
            **self._task_info(),
        }

    def _target_world_mm(self) -> np.ndarray:
        """(3,) the contact error's target point now, world frame, mm: the sensor's place at reset, carried with
        the face."""
        face = self._T_world_face()
        return face[:3, :3] @ self._target_face_mm + face[:3, 3]

    def _reward(self, state: ContactState, termination: str = "") -> float:
        """:class:`RewardConfig`'s formula; ``termination``: the reason this step ends the episode, or ``""``."""
        config = self.reward_config
        error = state.contact_error_mm
        error_term = min(error / config.error_scale_mm, config.max_error_term)
        precision = config.precision_bonus * math.exp(-(error / config.precision_scale_mm) ** 2)
        return (config.alive_bonus - error_term + precision - config.contact_loss_penalty * (not state.in_contact)
                - config.termination_penalty * bool(termination))

    def _termination(self, state: ContactState, arm_error: str) -> str:
        """The reason the episode ends now, or ``""``."""
        config = self.termination_config
        if arm_error:
            return "arm_limit"
        if not state.on_face or state.penetration_mm < -config.lost_contact_mm:
            return "contact_lost"
        if state.contact_error_mm > config.max_contact_error_mm:
            return "contact_error"
        if state.penetration_mm > config.max_penetration_mm:
            return "too_deep"
        return ""

    # -------------------------------------------------------------- render
    _SCENE_SIZE_PX = (240, 180)  # width, height

    def _scene_target_world_mm(self) -> np.ndarray:
        return self._T_world_face()[:3, 3]

    def _scene_view(self) -> np.ndarray:
        """A small TinyRenderer view of the arms, the TacTip and the face, uint8 (180, 240, 3)."""
        client = self.world.client
        self._place_scene_bodies()
        width, height = self._SCENE_SIZE_PX
        target_m = (self._scene_target_world_mm() / 1000.0).tolist()
        view = client.computeViewMatrixFromYawPitchRoll(target_m, 0.75, 35.0, -25.0, 0.0, 2)
        projection = client.computeProjectionMatrixFOV(50.0, width / height, 0.02, 3.0)
        import pybullet

        _, _, rgba, _, _ = client.getCameraImage(width, height, view, projection, renderer=pybullet.ER_TINY_RENDERER,
                                                 flags=pybullet.ER_NO_SEGMENTATION_MASK)
        self._park_dome()
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3].copy()

    def _tactile_view(self) -> np.ndarray:
        height = self._SCENE_SIZE_PX[1]
        image = self._last_tactile if self._last_tactile is not None else np.zeros((RENDER_SIZE_PX,) * 2, np.uint8)
        rows = np.minimum((np.arange(height) * image.shape[0]) // height, image.shape[0] - 1)
        square = image[rows][:, rows]
        return np.repeat(square[..., None], 3, axis=2)

    def _place_scene_bodies(self) -> None:
        """Arm boxes at their joints; the TacTip body (flange to camera) and dome, which the tactile camera
        must never see, exist only for this view: the dome is parked far away again afterwards."""
        import pybullet

        client = self.world.client
        for arm in self._arms:
            arm.update_bodies()
        tactip = self.tactip.config
        body_mm = self.mount.tcp_offset_mm - tactip.camera_to_apex_mm  # flange to the camera
        if not self._scene_bodies:
            half_m = [0.02, 0.02, max(body_mm, 2.0) / 2000.0]
            body = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_m, rgbaColor=[0.2, 0.2, 0.25, 1])
            dome = client.createVisualShape(pybullet.GEOM_SPHERE, radius=tactip.dome_radius_mm / 1000.0,
                                            rgbaColor=[0.95, 0.95, 0.95, 1])
            self._scene_bodies = {"tactip_body": client.createMultiBody(baseVisualShapeIndex=body),
                                  "tactip_dome": client.createMultiBody(baseVisualShapeIndex=dome)}
        T_world_sensor = self.follower.T_world_tool()
        # body: centred between the flange and 1 mm behind the camera, along the sensor axis
        centre = np.array([0.0, 0.0, -(tactip.camera_to_apex_mm + 1.0 + max(body_mm, 2.0) / 2.0), 1.0])
        T_body = T_world_sensor.copy()
        T_body[:3, 3] = (T_world_sensor @ centre)[:3]
        client.resetBasePositionAndOrientation(self._scene_bodies["tactip_body"], *pybullet_pose_fast(T_body))
        T_dome = T_world_sensor.copy()
        T_dome[:3, 3] = (T_world_sensor @ np.array([0.0, 0.0, -tactip.dome_radius_mm, 1.0]))[:3]
        client.resetBasePositionAndOrientation(self._scene_bodies["tactip_dome"], *pybullet_pose_fast(T_dome))

    def _park_dome(self) -> None:
        self.world.client.resetBasePositionAndOrientation(self._scene_bodies["tactip_dome"], [0.0, 0.0, -50.0],
                                                          [0.0, 0.0, 0.0, 1.0])
