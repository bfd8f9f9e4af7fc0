"""The sim-to-real contract: what the simulated envs and the real robot share, so that a controller or policy
cannot tell which one it drives.

- The TacTip's mount on the MG400 flange (:class:`TacTipMount`) and the action: a sensor-frame move
  ``(dx, dy, dz mm, dRz deg)`` scaled from ``[-1, 1]`` by :class:`ActionScale` (:func:`action_to_move`).
- What a controller made for an env takes from it (:class:`ServoHints`: its law, GDNN and filter settings).
- The spaces (:func:`observation_space`, :func:`action_space`): one definition for ``SimShearEnv`` and
  ``RealTactileEnv``; a 6-DoF follower's action adds the two tilt rates (:func:`action_space_6d`,
  :func:`action_to_move_6d`).
- The observation image: the TacTip renders at :data:`RENDER_SIZE_PX` (the translator's size); in the translated
  modes the shipped translator turns (sim image, shear) into a real-looking image (:func:`finish_tactile`), and
  every image, sim or camera, is brought to the observation size by :func:`resize_tactile`.

The GDNN's own input (resize to its size, scale to [0, 1]) belongs to the model:
:mod:`simshear_gym.models.gdnn_input`; the translator's shear input (mask and scale) to
:func:`simshear_gym.models.translator.normalise_shear`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from gymnasium import spaces

from simshear_gym.models.translator_runtime import translator_from
from simshear_gym.models.zoo import shipped_translator
from simshear_gym.transforms import pose_to_matrix, rz_matrix

OBS_MODES: tuple[str, ...] = ("real", "sim", "oracle", "oracle_real")
TRANSLATED_MODES: tuple[str, ...] = ("real", "oracle_real")
ORACLE_MODES: tuple[str, ...] = ("oracle", "oracle_real")
IMAGE_SIZES_PX: tuple[int, ...] = (64, 128)
RENDER_SIZE_PX = 128  # the TacTip renders at the translator's size

# Observation bounds: wide enough that a running episode never leaves them (it terminates long before).
TCP_POSE_LOW = np.array([-1000.0, -1000.0, -1000.0, -720.0], dtype=np.float32)
TRUE_POSE_SHEAR_LIMIT = np.array([50.0, 50.0, 50.0, 180.0], dtype=np.float32)


@dataclass(frozen=True)
class TacTipMount:
    """How the TacTip sits on the follower's flange: ``T_flange_sensor`` = down ``tcp_offset_mm`` along the
    flange's -z (the flange faces down), turned ``mount_rz_deg`` about the axis, with the sensor's +z pointing
    down (a half turn about x, so sensor y = -flange y).

    Attributes:
        tcp_offset_mm: flange to dome apex (TacTip body 85 mm plus a 10 mm adapter).
        mount_rz_deg: rotation of the sensor about its axis on the flange.
    """

    tcp_offset_mm: float = 95.0
    mount_rz_deg: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tcp_offset_mm) and self.tcp_offset_mm > 0):
            raise ValueError(f"TacTipMount.tcp_offset_mm must be > 0, got {self.tcp_offset_mm!r}")

    def T_flange_sensor(self) -> np.ndarray:
        return pose_to_matrix(np.array([0.0, 0.0, -self.tcp_offset_mm, 0.0, 0.0, self.mount_rz_deg])) @ np.diag(
            [1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class HorizontalTacTipMount(TacTipMount):
    """The TacTip lying horizontally under the follower's level flange on an L-bracket: its axis (sensor +z) along
    the flange's +x, ``drop_mm`` below the flange, the dome apex ``tcp_offset_mm`` ahead of the flange's axis;
    sensor +y points down (image rows run down the world), sensor +x = flange -y. ``mount_rz_deg`` turns the
    sensor about its own axis.

    Attributes:
        tcp_offset_mm: flange axis to dome apex along the sensor axis (TacTip body 85 mm plus a 10 mm adapter).
        drop_mm: sensor axis below the flange.
    """

    drop_mm: float = 60.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.drop_mm) and self.drop_mm >= 0):
            raise ValueError(f"HorizontalTacTipMount.drop_mm must be >= 0, got {self.drop_mm!r}")

    def T_flange_sensor(self) -> np.ndarray:
        T_flange_sensor = np.array([[0.0, 0.0, 1.0, self.tcp_offset_mm], [-1.0, 0.0, 0.0, 0.0],
                                    [0.0, -1.0, 0.0, -self.drop_mm], [0.0, 0.0, 0.0, 1.0]])
        return T_flange_sensor @ rz_matrix(self.mount_rz_deg)


@dataclass(frozen=True)
class ActionScale:
    """Full-scale action (|a| = 1) per step, in the sensor frame: ``step_mm`` for x, y, z and ``step_deg`` for Rz."""

    step_mm: float = 1.0
    step_deg: float = 2.0

    def __post_init__(self) -> None:
        if not (self.step_mm > 0 and self.step_deg > 0 and math.isfinite(self.step_mm + self.step_deg)):
            raise ValueError(f"ActionScale needs step_mm, step_deg > 0, got {self.step_mm!r}, {self.step_deg!r}")

    def as_array(self) -> np.ndarray:
        return np.array([self.step_mm, self.step_mm, self.step_mm, self.step_deg])


CONTROLLER_LAWS: tuple[str, ...] = ("servo", "edge", "push")
"""The controllers an env is made for (:attr:`ServoHints.law`)."""


@dataclass(frozen=True)
class ServoHints:
    """What a controller made for an env (the controllers' ``for_env``) takes from it besides its spaces, reference
    depth and action scale. Every sim env and ``RealTactileEnv`` carries one, ``servo_hints``.

    Attributes:
        law: the controller the env is for (:data:`CONTROLLER_LAWS`): ``"servo"`` (depth and shear PI law),
            ``"edge"`` (edge following) or ``"push"`` (pushing); the estimate observation runs that law's estimator.
        posenet: the GDNN an image-based controller reads the env's images with: a shipped GDNN's name
            (:func:`~simshear_gym.models.zoo.posenet_weights`) or a sensor's own weights file (``.pt``).
        process_std_mm: the estimator's process noise, mm per step (how far the contact moves in a step unknown
            to the follower); None: the estimator's default.
        hold_load: the servo law holds the shear of the episode's first image (a carried load's) instead of zero.
        load_margin_mm: (x, y) mm added to that held shear, sensor frame (along the weight: carry more).
        shear_gains: the servo law's (kp, ki) on shear x and y while it holds a load; None: its defaults.
    """

    law: str = "servo"
    posenet: str = "surface"
    process_std_mm: float | None = None
    hold_load: bool = False
    load_margin_mm: tuple[float, float] = (0.0, 0.0)
    shear_gains: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.law not in CONTROLLER_LAWS:
            raise ValueError(f"ServoHints.law must be one of {CONTROLLER_LAWS}, got {self.law!r}")
        if not (isinstance(self.posenet, str) and self.posenet):
            raise ValueError(f"ServoHints.posenet must be a shipped GDNN's name or a .pt path, got {self.posenet!r}")
        if self.process_std_mm is not None and not (math.isfinite(self.process_std_mm) and self.process_std_mm > 0):
            raise ValueError(f"ServoHints.process_std_mm must be None or > 0 mm, got {self.process_std_mm!r}")
        if len(self.load_margin_mm) != 2 or not all(math.isfinite(v) for v in self.load_margin_mm):
            raise ValueError(f"ServoHints.load_margin_mm must be 2 finite values (x, y mm), got "
                             f"{self.load_margin_mm!r}")
        if self.shear_gains is not None and (len(self.shear_gains) != 2 or not all(
                math.isfinite(v) and v >= 0 for v in self.shear_gains)):
            raise ValueError(f"ServoHints.shear_gains must be None or (kp, ki) >= 0, got {self.shear_gains!r}")


def servo_hints(env) -> ServoHints:
    """The :class:`ServoHints` of an env (wrappers looked through)."""
    base = env.unwrapped
    try:
        hints = base.servo_hints
    except AttributeError:
        hints = None
    if not isinstance(hints, ServoHints):
        raise TypeError(f"{type(base).__name__} has no servo_hints (a simshear_gym.contract.ServoHints: the law, "
                        "GDNN and filter settings a controller made for an env reads); the sim envs and "
                        "RealTactileEnv have theirs: give this env one, or build the controller with its own "
                        "arguments")
    return hints


def action_to_move(action, action_scale: ActionScale) -> np.ndarray:
    """Validate an action (shape (4,), finite, in [-1, 1]) and scale it to a sensor-frame move
    ``(dx, dy, dz mm, dRz deg)``; the sim envs and the real env share it."""
    array = np.asarray(action, dtype=np.float64)
    if array.shape != (4,):
        raise ValueError(f"action must have shape (4,) (dx, dy, dz, dRz in [-1, 1]), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"action must be finite, got {array.tolist()}")
    if np.any(np.abs(array) > 1.0 + 1e-6):
        raise ValueError(f"action must lie in [-1, 1] (the action space), got {array.tolist()}")
    return np.clip(array, -1.0, 1.0) * action_scale.as_array()


def check_image_size(image_size_px: int, owner: str = "image_size_px") -> None:
    if image_size_px not in IMAGE_SIZES_PX:
        raise ValueError(f"{owner} must be one of {IMAGE_SIZES_PX}, got {image_size_px!r}")


OBSERVATIONS: tuple[str, ...] = ("tactile", "estimate", "tactile+estimate", "estimate+action")
"""What a policy observes (the ``observation`` argument of the sim envs and ``RealTactileEnv``); which image the
``tactile`` key holds is the separate ``obs_mode``."""
TACTILE_OBSERVATIONS: tuple[str, ...] = ("tactile", "tactile+estimate")  # those with the ``tactile`` image
ESTIMATE_OBSERVATIONS: tuple[str, ...] = ("estimate", "tactile+estimate", "estimate+action")  # with an estimator
ACTION_OBSERVATIONS: tuple[str, ...] = ("estimate+action",)  # those with the ``last_action``
ESTIMATE_VARIABLES: tuple[str, ...] = ("depth_mm", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
ESTIMATE_SCALE = np.array([2.0, 7.5, 7.5, 7.5])
"""Per variable (depth mm, shear x, y mm, shear Rz deg): the unit of the normalised estimate (about the GDNN's
half range: depth 2-5.5 mm, shear +-7.5)."""
ESTIMATE_MEAN_LIMIT = 4.0  # normalised means are clipped to +-this (8 mm of depth error, 30 mm of shear)
ESTIMATE_SIZE = 16  # per frame: reading mean, reading std, filter mean, filter std, 4 variables each
MAX_HISTORY = 16


def check_observation(observation: str, history: int, owner: str = "") -> None:
    """Refuse an unknown observation or a history outside [1, MAX_HISTORY] (``owner`` prefixes the message)."""
    prefix = f"{owner}: " if owner else ""
    if observation not in OBSERVATIONS:
        raise ValueError(f"{prefix}observation must be one of {OBSERVATIONS}, got {observation!r}")
    if isinstance(history, bool) or not isinstance(history, int) or not 1 <= history <= MAX_HISTORY:
        raise ValueError(f"{prefix}history must be an int in [1, {MAX_HISTORY}] (frames or estimates stacked), "
                         f"got {history!r}")


def observation_space(image_size_px: int, oracle: bool = False, observation: str = "tactile",
                      history: int = 1) -> spaces.Dict:
    """The observation of the sim envs and ``RealTactileEnv``, ``k = history`` (oldest first, newest last):

    - ``observation="tactile"``: ``tactile`` uint8 (k, S, S) channel-first (k = 1: the one image, as ever) and
      ``tcp_pose`` float32 (4,): apex x, y, z mm and flange R deg in the robot base frame;
    - ``"estimate"``: ``estimate`` float32 (16 k,): per frame :func:`estimate_features` (the estimator's GDNN
      reading and filter state, normalised); no image, no pose (an absolute pose in the robot's base frame
      differs between the sim scene and a real cell: a policy must not lean on it);
    - ``"tactile+estimate"``: ``tactile`` and ``estimate``;
    - ``"estimate+action"``: ``estimate`` and ``last_action`` float32 (4,) in [-1, 1]: the move commanded since
      the previous image over the action's full scale (the action as the arm took it; zeros at reset). With it
      and two frames a policy can hold a PI law's integral (velocity form: ``a_t = a_t-1 + ...``);
    - with ``oracle`` (sim only), ``true_pose_shear``: float32 (4,).
    """
    check_observation(observation, history)
    observations: dict[str, spaces.Space] = {}
    if observation in TACTILE_OBSERVATIONS:
        observations["tactile"] = spaces.Box(0, 255, (history, image_size_px, image_size_px), dtype=np.uint8)
    if observation == "tactile":
        observations["tcp_pose"] = spaces.Box(TCP_POSE_LOW, -TCP_POSE_LOW, dtype=np.float32)
    if observation in ESTIMATE_OBSERVATIONS:
        observations["estimate"] = spaces.Box(-ESTIMATE_MEAN_LIMIT, ESTIMATE_MEAN_LIMIT, (ESTIMATE_SIZE * history,),
                                              dtype=np.float32)
    if observation in ACTION_OBSERVATIONS:
        observations["last_action"] = spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)
    if oracle:
        observations["true_pose_shear"] = spaces.Box(-TRUE_POSE_SHEAR_LIMIT, TRUE_POSE_SHEAR_LIMIT, dtype=np.float32)
    return spaces.Dict(observations)


GOAL_LIMIT_MM = 1000.0
"""Bound of a pushing task's ``goal`` observation (:func:`push_goal`)."""


def goal_space() -> spaces.Box:
    """The ``goal`` observation of a pushing task (``SimShearPush-v0``, and the real path's
    :class:`~simshear_gym.control.push_servo.PushGoalObservation`): float32 (4,)."""
    return spaces.Box(-GOAL_LIMIT_MM, GOAL_LIMIT_MM, (4,), dtype=np.float32)


def push_goal(apex_xy_mm, side_xy, axis_xy, target_xy_mm, direction_xy) -> np.ndarray:
    """float32 (4,): a pushing task's goal in the horizontal sensor's frame: the target's place (x, z mm) and the
    path's direction (x, z, unit), from the apex's place, the sensor's x and z axes (all in the horizontal plane of
    the world or the robot's base frame, the same for every argument) and the target and path direction there."""
    apex, side, axis = (np.asarray(v, dtype=np.float64)[:2] for v in (apex_xy_mm, side_xy, axis_xy))
    to_target = np.asarray(target_xy_mm, dtype=np.float64)[:2] - apex
    direction = np.asarray(direction_xy, dtype=np.float64)[:2]
    values = [to_target @ side, to_target @ axis, direction @ side, direction @ axis]
    return np.clip(np.array(values), -GOAL_LIMIT_MM, GOAL_LIMIT_MM).astype(np.float32)


def sensor_axes_xy(flange_r_deg: float, mount: TacTipMount) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal sensor's x and z axes (x, y in the robot's base frame) at a flange R: a level flange turns the
    mount about the vertical."""
    rotation = rz_matrix(flange_r_deg)[:3, :3] @ mount.T_flange_sensor()[:3, :3]
    return rotation[:2, 0], rotation[:2, 2]


def estimate_features(reading: tuple[np.ndarray, np.ndarray], filtered: tuple[np.ndarray, np.ndarray],
                      reference_depth_mm: float) -> np.ndarray:
    """float32 (16,): one frame of the ``estimate`` observation from an estimator's (mean (4,), std (4,)) of
    (depth mm, shear x, y mm, shear Rz deg): the GDNN's raw ``reading``, then the Bayesian filter's state
    ``filtered``; each as ``(mean - (reference depth, 0, 0, 0)) / ESTIMATE_SCALE`` clipped to +-4, then
    ``clip(std / ESTIMATE_SCALE, 0, 2) - 1`` (in [-1, 1]; 1 for a variable the GDNN cannot read)."""
    offset = np.array([reference_depth_mm, 0.0, 0.0, 0.0])
    parts = []
    for mean, std in (reading, filtered):
        mean, std = np.asarray(mean, dtype=np.float64), np.asarray(std, dtype=np.float64)
        if mean.shape != (4,) or std.shape != (4,):
            raise ValueError(f"an estimate is (mean (4,), std (4,)) of {ESTIMATE_VARIABLES}, got shapes "
                             f"{mean.shape}, {std.shape}")
        parts.append(np.clip((mean - offset) / ESTIMATE_SCALE, -ESTIMATE_MEAN_LIMIT, ESTIMATE_MEAN_LIMIT))
        parts.append(np.clip(std / ESTIMATE_SCALE, 0.0, 2.0) - 1.0)
    return np.nan_to_num(np.concatenate(parts), nan=0.0).astype(np.float32)


def filter_mean_from_estimate(estimate: np.ndarray, reference_depth_mm: float) -> np.ndarray:
    """The filter's mean (depth, shear x, y mm, shear Rz deg) of the newest frame of an ``estimate`` observation
    (16 k,): the inverse of :func:`estimate_features` (exact within the +-4 clip)."""
    values = np.asarray(estimate, dtype=np.float64).reshape(-1)
    if values.size == 0 or values.size % ESTIMATE_SIZE:
        raise ValueError(f"an estimate observation holds 16 values per frame, got {values.size}")
    newest = values[-ESTIMATE_SIZE:]
    return newest[8:12] * ESTIMATE_SCALE + np.array([reference_depth_mm, 0.0, 0.0, 0.0])


def action_space() -> spaces.Box:
    """float32 (4,) in [-1, 1]: the sensor-frame move scaled by :class:`ActionScale`."""
    return spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)


TILT_STEP_DEG = 1.0
"""Full-scale tilt rate of the 6-DoF action (|a| = 1): deg per step about the sensor's x and y."""


def action_space_6d() -> spaces.Box:
    """float32 (6,) in [-1, 1]: the 4 of :func:`action_space` (dx, dy, dz, dRz) then dRx, dRy: the 6-DoF
    follower's sensor-frame move (:func:`action_to_move_6d`)."""
    return spaces.Box(-1.0, 1.0, (6,), dtype=np.float32)


def action_to_move_6d(action, action_scale: ActionScale, tilt_step_deg: float = TILT_STEP_DEG) -> np.ndarray:
    """Validate a 6-DoF action (shape (6,), finite, in [-1, 1]) and scale it to a sensor-frame move
    ``(dx, dy, dz mm, dRz, dRx, dRy deg)``: the first four as :func:`action_to_move`, the tilts by
    ``tilt_step_deg``."""
    array = np.asarray(action, dtype=np.float64)
    if array.shape != (6,):
        raise ValueError(f"action must have shape (6,) (dx, dy, dz, dRz, dRx, dRy in [-1, 1]), got shape "
                         f"{array.shape}")
    if not (math.isfinite(tilt_step_deg) and tilt_step_deg > 0):
        raise ValueError(f"tilt_step_deg must be finite and > 0, got {tilt_step_deg!r}")
    move = action_to_move(array[:4], action_scale)
    if np.any(np.abs(array[4:]) > 1.0 + 1e-6) or not np.all(np.isfinite(array[4:])):
        raise ValueError(f"action must be finite and lie in [-1, 1] (the action space), got {array.tolist()}")
    return np.concatenate([move, np.clip(array[4:], -1.0, 1.0) * tilt_step_deg])


def policy_spaces(image_size_px: int, observation: str = "tactile", history: int = 1) -> tuple[spaces.Dict, spaces.Box]:
    """(observation space, action space) a controller or policy sees: the sim envs' in their non-oracle modes
    and ``RealTactileEnv``'s, for the same ``observation`` and ``history``."""
    check_image_size(image_size_px)
    return observation_space(image_size_px, observation=observation, history=history), action_space()


def resize_tactile(images: np.ndarray, image_size_px: int) -> np.ndarray:
    """uint8 (..., H, W) tactile images at ``image_size_px`` square: block means rounded when the size divides
    evenly (how a 64 px observation is the 128 px one at half resolution), INTER_AREA otherwise."""
    images = np.asarray(images)
    height, width = images.shape[-2:]
    if (height, width) == (image_size_px, image_size_px):
        return images
    lead = images.shape[:-2]
    if height == width and height % image_size_px == 0:
        factor = height // image_size_px
        blocks = images.reshape(*lead, image_size_px, factor, image_size_px, factor).mean(axis=(-3, -1))
        return np.rint(blocks).astype(np.uint8)
    flat = images.reshape(-1, height, width)
    resized = np.stack([cv2.resize(image, (image_size_px, image_size_px), interpolation=cv2.INTER_AREA)
                        for image in flat])
    return resized.reshape(*lead, image_size_px, image_size_px)


RAW_SHEAR_KEY = "shear_sensor_mm_deg"
"""The key of a raw observation's shear (``raw_tactile``: the batched vector env's sub-envs): float32 (6,), mm and
deg, sensor frame, the shear the image was rendered at, which :func:`finish_tactile` takes with it."""


def finish_tactile(sim_uint8: np.ndarray, shear_sensor: np.ndarray, obs_mode: str, image_size_px: int,
                   contact: str, translator_weights: str | None = None,
                   translator_runtime: str | None = None, translator_device: str | None = None) -> np.ndarray:
    """Raw sim images (B, R, R) -> observation images (B, S, S): translated in the translated modes (one
    batched call, the shear as the tracker gives it; by ``translator_weights`` if given, else the shipped
    translator of ``contact``; on ``translator_runtime`` and ``translator_device``, see
    :mod:`simshear_gym.models.translator_runtime`), then resized by :func:`resize_tactile`."""
    images = np.asarray(sim_uint8)
    if obs_mode in TRANSLATED_MODES:
        shear = np.asarray(shear_sensor, dtype=np.float32).reshape(len(images), 6)
        translator = (translator_from(translator_weights, translator_runtime, translator_device)
                      if translator_weights else
                      shipped_translator(contact, runtime=translator_runtime, device=translator_device))
        images = translator(resize_tactile(images, translator.image_size_px), shear)
    return resize_tactile(images, image_size_px)
