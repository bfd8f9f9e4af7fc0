"""Pushing by touch: keep the TacTip square to the pushed face, steer the object onto its path, correct with shear.

State (``SimShearPush-v0``'s oracle holds the same, with the path's bearing)::

    (depth mm, shear x mm, face yaw deg)

``depth``: the labels' z; ``shear x``: the skin's stretch along the face (sensor x, horizontal); ``face yaw``: the
face's turn against the sensor about the vertical (the surface labels' Ry). The task's ``goal`` (the env's
observation: the target and the path's direction in the sensor frame, from the arm's pose) gives the rest.

The law, per step, in the sensor frame (z the pushing direction, x along the face), after the published
pose-based pushing controllers (a normal-alignment term and a target-alignment term):

* estimate the object's centre ``half_width_mm`` ahead of the apex and, with shear, ``k_shear * shear x /
  indentation`` across (below); aim at the point of the path (produced past the target) ``lookahead_mm`` ahead of
  the centre's projection on it (pure pursuit); ``bearing`` = the aim's angle from the sensor's axis (+ towards
  sensor +x), ``side`` = the path's distance from the centre;
* ``dRz = k_yaw * face_yaw`` turns the sensor square to the face (its axis along the face's normal);
* ``dx = -k_bearing * bearing - ki_side * sum(side)``, at most ``max_slide_mm``, moves the sensor across the push:
  the object, held by the skin, is dragged and turned with it; pushing off the object's centre of pressure turns
  it away from the contact's side, so a move towards -x turns the push towards +x (the other sign diverges);
* ``dz = step_mm``: push on at the set speed (the indentation follows from the object's friction).

Why the shear: the tangential force on the object is the skin's stretch (the shear) times its stiffness, the
normal force the indentation times the dome's. Pushed straight, an object whose centre of pressure lies ``b`` to
the side of the contact turns unless the tangential force balances the turn: ``F_t / F_n = b / d`` (``d`` the
centre's distance from the face), so ``b`` is about ``d (k_t / k_n) shear / indentation``: the shear tells the
law where the object's centre is, which the face's yaw shows only after the object has turned. ``k_shear`` lumps
``d k_t / k_n`` (chosen on the oracle: 3-12.5 mm all lower the path deviation, the opposite sign raises it).

:class:`PushServoController` reads (depth, shear, face yaw) from the tactile image with the surface GDNN and the
Bayesian filter (:class:`~simshear_gym.control.servo6d.TiltEstimator`: depth, shear x, y, Rz, Rx, Ry);
:class:`PushOracleController` from the oracle. ``use_shear=False`` is the ablation: the same law with the shear
term off (the centre taken on the sensor's axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from simshear_gym.contract import ActionScale, TacTipMount, push_goal, sensor_axes_xy
from simshear_gym.control.estimator import EstimatorConfig
from simshear_gym.control.policy import EstimateThenLaw, as_action_scale, estimator_for_env
from simshear_gym.data.labels import SURFACE_DEPTH_MM

PUSH_PROCESS_STD_MM = 0.5
"""The push filter's process noise on depth and shear per step (the object's unknown turn and slip; the
``servo_hints.process_std_mm`` of ``SimShearPush-v0``)."""


@dataclass(frozen=True)
class PushGains:
    """Gains of :class:`PushLaw` (chosen on ``SimShearPush-v0``'s randomised seeds 100-159 with the oracle; the
    benchmark runs seeds 0-99).

    Attributes:
        k_yaw: turn per degree of face yaw (deg/deg), the normal alignment.
        k_bearing: move across the push per degree of bearing to the aim point (mm/deg).
        ki_side: move per mm of the path side's running sum (mm per mm step): an object pushed off its centre of
            pressure needs a steady move to go straight, which leaves the bearing near zero off the path; the
            integral of the centre's distance from the path supplies it.
        integral_limit_mm: the integral term's largest move per step.
        max_slide_mm: the largest move across the push per step (a larger one slips the skin and spins the object).
        k_shear: the centre of pressure's offset from the contact per unit of shear over indentation (mm); 0: the
            ablation without shear (see the module docstring).
        min_indentation_mm: the indentation the ratio divides by is at least this (a noisy reading of a light
            touch would blow it up).
        max_centre_offset_mm: the centre's estimated offset across the push is clipped to this.
        lookahead_mm: how far ahead along the path the law aims.
        half_width_mm: the object's nominal half width (its centre this far ahead of the apex).
    """

    k_yaw: float = 1.0
    k_bearing: float = 0.05
    ki_side: float = 0.0005
    integral_limit_mm: float = 0.5
    max_slide_mm: float = 0.5
    k_shear: float = 6.0
    min_indentation_mm: float = 0.4
    max_centre_offset_mm: float = 4.0
    lookahead_mm: float = 40.0
    half_width_mm: float = 25.0

    def __post_init__(self) -> None:
        for name in ("k_yaw", "k_bearing", "ki_side", "integral_limit_mm", "k_shear"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and 0.0 <= value <= 50.0):
                raise ValueError(f"PushGains.{name} must be a finite number in [0, 50], got {value!r}")
        if not (self.lookahead_mm > 0 and self.half_width_mm >= 0 and self.max_slide_mm > 0
                and self.min_indentation_mm > 0 and self.max_centre_offset_mm >= 0):
            raise ValueError(f"PushGains: lookahead_mm, max_slide_mm > 0 and half_width_mm >= 0, got {self}")


def aim_bearing_deg(goal: np.ndarray, half_width_mm: float, lookahead_mm: float,
                    centre_x_mm: float = 0.0) -> tuple[float, float]:
    """(bearing deg, path side mm) from ``goal`` (target x, z mm and the path's direction x, z in the sensor frame):
    the bearing (+ towards sensor +x) from the sensor's axis to the path's point ``lookahead_mm`` ahead of the
    object's estimated centre (``half_width_mm`` ahead of the apex), the path produced past the target so the aim
    does not swing at the end; the path side: how far the path lies from the centre, + towards sensor +x."""
    target = np.array([goal[0], goal[1]], dtype=np.float64)
    direction = np.array([goal[2], goal[3]], dtype=np.float64)
    direction /= max(float(np.linalg.norm(direction)), 1e-9)
    centre = np.array([centre_x_mm, half_width_mm])
    projection = target - float((target - centre) @ direction) * direction
    aim = projection + lookahead_mm * direction
    to_path = projection - centre
    side = float(np.sign(to_path[0]) * np.linalg.norm(to_path))
    return math.degrees(math.atan2(aim[0] - centre[0], aim[1] - centre[1])), side


class PushLaw:
    """(depth, shear x, face yaw) and the goal -> action in [-1, 1]^4: the law of the module docstring."""

    def __init__(self, action_scale: np.ndarray, step_mm: float, gains: PushGains = PushGains(),
                 use_shear: bool = True) -> None:
        self._scale = np.asarray(action_scale, dtype=np.float64)
        if self._scale.shape != (4,) or not np.all(self._scale > 0):
            raise ValueError(f"action_scale must be 4 positive full-scale moves, got {action_scale}")
        if not (math.isfinite(step_mm) and 0.0 <= step_mm <= self._scale[2]):
            raise ValueError(f"the push per step must be in [0, {self._scale[2]:g}] mm (the action's full scale), "
                             f"got {step_mm!r}")
        self.step_mm = float(step_mm)
        self.gains = gains
        self.use_shear = bool(use_shear)
        self._integral = 0.0

    def reset(self) -> None:
        self._integral = 0.0

    def __call__(self, state: np.ndarray, goal: np.ndarray) -> np.ndarray:
        values = np.asarray(state, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        if values.shape != (3,) or not np.all(np.isfinite(values)):
            raise ValueError(f"state must be 3 finite values (depth mm, shear x mm, face yaw deg), got {values}")
        if goal.shape != (4,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal must be 4 finite values (target x, z mm, path direction x, z), got {goal}")
        depth, shear_x, face_yaw = values
        g = self.gains
        centre_x = 0.0
        if self.use_shear:  # the centre of pressure's side, from the tangential over the normal force
            indentation = max(depth - SURFACE_DEPTH_MM, g.min_indentation_mm)
            centre_x = min(max(g.k_shear * shear_x / indentation, -g.max_centre_offset_mm), g.max_centre_offset_mm)
        bearing, side_mm = aim_bearing_deg(goal, g.half_width_mm, g.lookahead_mm, centre_x)
        if g.ki_side > 0:
            limit = g.integral_limit_mm / g.ki_side
            self._integral = min(max(self._integral + side_mm, -limit), limit)
        dx = -g.k_bearing * bearing - g.ki_side * self._integral
        dx = min(max(dx, -g.max_slide_mm), g.max_slide_mm)
        move = np.array([dx, 0.0, self.step_mm, g.k_yaw * face_yaw])
        return np.clip(move / self._scale, -1.0, 1.0).astype(np.float32)


def _push_estimator(config: EstimatorConfig, reading_slots: bool = False):
    """The surface GDNN + filter over (depth, shear x, y, Rz, Rx, Ry) with the pushing motion model: the sensor's
    turn about the vertical turns the face's yaw (Ry) back by as much; a push or a slide moves the object too (how
    much, its friction decides), so depth and shear are left to the readings (a random walk). ``reading_slots``:
    the estimator of ``SimShearPush-v0``'s ``estimate`` observations, its state and the GDNN's last reading
    (``last_reading``) in the observation's four slots (:func:`push_estimate_slots`), at one GDNN pass per image."""
    from simshear_gym.control.estimator import SlotEstimates
    from simshear_gym.control.servo6d import TiltEstimator

    class PushEstimator(TiltEstimator):
        @staticmethod
        def _state_delta(commanded_move: np.ndarray) -> np.ndarray:
            return np.array([0.0, 0.0, 0.0, 0.0, 0.0, -float(commanded_move[3])])

    class PushReadingEstimator(SlotEstimates, PushEstimator):
        slots = staticmethod(push_estimate_slots)

    return PushReadingEstimator(config) if reading_slots else PushEstimator(config)


def push_estimate_slots(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A pushing estimate (depth, shear x, y, Rz, Rx, Ry: the surface GDNN's six) in the four slots of the policies'
    ``estimate`` observation (:func:`~simshear_gym.contract.estimate_features`): (depth mm, shear x mm, shear y mm,
    face yaw deg), the face yaw (the labels' Ry) where the tracking envs keep the shear's Rz."""
    mean = np.asarray(mean, dtype=np.float64)
    std = np.asarray(std, dtype=np.float64)
    if mean.shape != (6,) or std.shape != (6,):
        raise ValueError(f"a pushing estimate is (mean (6,), std (6,)) of depth, shear x, y, Rz, Rx, Ry; got shapes "
                         f"{mean.shape}, {std.shape}")
    slots = [0, 1, 2, 5]
    return mean[slots], std[slots]


def push_state_from_slots(slots: np.ndarray) -> np.ndarray:
    """(depth mm, shear x mm, face yaw deg), :class:`PushLaw`'s state, of an estimate's four slots
    (:func:`push_estimate_slots`)."""
    depth, shear_x, _, face_yaw = np.asarray(slots, dtype=np.float64)
    return np.array([depth, shear_x, face_yaw])


def push_reading_estimator(config: EstimatorConfig):
    """The estimator of a pushing policy's ``estimate`` observation: the push servo controller's (its GDNN and
    filter settings, ``config``), its estimates in the observation's four slots (:func:`push_estimate_slots`)."""
    return _push_estimator(config, reading_slots=True)


@dataclass(frozen=True)
class PushTarget:
    """Where to push on the real path, which gives no ``goal``: the target in the robot's base frame; the path runs
    straight to it from the object's centre at the first observation (``half_width_mm`` ahead of the apex).

    Attributes:
        target_xy_mm: the target (x, y mm, base frame).
        mount: the horizontal TacTip on the flange (the sensor's axes from the flange's R).
        half_width_mm: the object's nominal half width.
    """

    target_xy_mm: tuple[float, float]
    mount: TacTipMount
    half_width_mm: float = 25.0

    def __post_init__(self) -> None:
        if len(self.target_xy_mm) != 2 or not all(math.isfinite(v) for v in self.target_xy_mm):
            raise ValueError(f"PushTarget.target_xy_mm must be 2 finite numbers (x, y mm), got {self.target_xy_mm!r}")


class _GoalOf:
    """obs -> goal: the observation's own, or a :class:`PushTarget`'s from the observation's ``tcp_pose``."""

    def __init__(self, target: PushTarget | None, who: str) -> None:
        self.target = target
        self.who = who
        self._direction: np.ndarray | None = None

    def reset(self) -> None:
        self._direction = None

    def __call__(self, observation: dict) -> np.ndarray:
        if "goal" in observation:
            return np.asarray(observation["goal"], dtype=np.float64)
        if self.target is None or "tcp_pose" not in observation:
            raise ValueError(f"{self.who} needs the observation's 'goal' (SimShearPush-v0's), or a PushTarget and "
                             f"the observation's 'tcp_pose'; got {sorted(observation)}")
        tcp = np.asarray(observation["tcp_pose"], dtype=np.float64)
        side, axis = sensor_axes_xy(float(tcp[3]), self.target.mount)
        target = np.asarray(self.target.target_xy_mm, dtype=np.float64)
        if self._direction is None:
            to_target = target - (tcp[:2] + self.target.half_width_mm * axis)
            self._direction = to_target / max(float(np.linalg.norm(to_target)), 1e-9)
        return push_goal(tcp[:2], side, axis, target, self._direction).astype(np.float64)


class PushGoalObservation(gym.Wrapper):
    """A real pushing env's observation with ``SimShearPush-v0``'s ``goal`` added (from each step's measured
    ``info["tcp_pose"]`` and a :class:`PushTarget`), so that a pushing policy trained in sim gets the observation
    it was trained on."""

    def __init__(self, env: gym.Env, target: PushTarget) -> None:
        from gymnasium import spaces

        from simshear_gym.contract import goal_space

        super().__init__(env)
        self.observation_space = spaces.Dict({**env.observation_space.spaces, "goal": goal_space()})
        self._goal = _GoalOf(target, "PushGoalObservation")

    def _with_goal(self, observation: dict, info: dict) -> dict:
        if info.get("tcp_pose") is None:
            raise ValueError("PushGoalObservation needs the env's info['tcp_pose'] (the measured apex pose)")
        return {**observation, "goal": self._goal({"tcp_pose": info["tcp_pose"]}).astype(np.float32)}

    def reset(self, **kwargs):
        self._goal.reset()
        observation, info = self.env.reset(**kwargs)
        return self._with_goal(observation, info), info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        if info.get("tcp_pose") is None:  # an episode that stopped before observing: its observation as it is
            return observation, reward, terminated, truncated, info
        return self._with_goal(observation, info), reward, terminated, truncated, info


class PushServoController(EstimateThenLaw):
    """Tactile image and goal -> action: the surface GDNN + filter (depth, shear x, face yaw), then
    :class:`PushLaw`. Call :meth:`reset` per episode.

    Args:
        action_scale: the env's :class:`~simshear_gym.contract.ActionScale`.
        step_mm: the push per step (the env's speed over its control rate).
        gains: :class:`PushGains`.
        use_shear: False: the law without its shear term (the ablation).
        estimator: the GDNN (``posenet``; None: the shipped ``surface`` one) and the filter's settings.
        target: on the real path (no ``goal`` in the observation): where to push (:class:`PushTarget`).
    """

    name = "push_servo"
    who = "the push servo controller"
    state_names: tuple[str, ...] = ("depth_mm", "shear_x_mm", "face_yaw_deg")

    def __init__(self, action_scale: ActionScale = ActionScale(), step_mm: float = 0.5,
                 gains: PushGains = PushGains(), use_shear: bool = True,
                 estimator: EstimatorConfig = EstimatorConfig(), target: PushTarget | None = None) -> None:
        from dataclasses import replace

        self.action_scale = as_action_scale(action_scale, "PushServoController")
        self.target = target
        self._goal = _GoalOf(target, "the push servo controller")
        if estimator.process_std_mm is None:
            estimator = replace(estimator, process_std_mm=PUSH_PROCESS_STD_MM)
        self._scale = self.action_scale.as_array()
        self.estimator = _push_estimator(estimator)
        self.law = PushLaw(self._scale, step_mm, gains, use_shear)
        self.name = "push_servo" if use_shear else "push_servo_no_shear"

    @classmethod
    def for_env(cls, env, gains: PushGains = PushGains(), use_shear: bool = True,
                estimator: EstimatorConfig = EstimatorConfig()) -> PushServoController:
        """A controller matched to a pushing env's action scale, speed, GDNN and process noise (its
        :class:`~simshear_gym.contract.ServoHints`)."""
        base = env.unwrapped
        estimator = estimator_for_env(env, estimator, shipped=False)
        return cls(base.action_scale, base.speed_mm_s * base.dt_s, gains, use_shear, estimator)

    def reset(self) -> None:
        super().reset()
        self._goal.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        self._check_tactile(observation)
        goal = self._goal(observation)
        mean, std = self.estimator(observation["tactile"], self._last_move)
        # TiltEstimator's state: depth, shear x, y, Rz, Rx, Ry
        state = np.array([mean[0], mean[1], mean[5]])
        self.last_estimate = (state, np.array([std[0], std[1], std[5]]))
        return self._command(self.law(state, goal))


class PushOracleController:
    """The oracle's true (depth, shear x, face yaw) (``obs_mode="oracle"`` of ``SimShearPush-v0``) into
    :class:`PushLaw`: what the law does with a perfect reading."""

    def __init__(self, action_scale: ActionScale = ActionScale(), step_mm: float = 0.5,
                 gains: PushGains = PushGains(), use_shear: bool = True) -> None:
        self.action_scale = as_action_scale(action_scale, "PushOracleController")
        self.law = PushLaw(self.action_scale.as_array(), step_mm, gains, use_shear)
        self.name = "push_oracle" if use_shear else "push_oracle_no_shear"
        self._goal = _GoalOf(None, "the push oracle")

    @classmethod
    def for_env(cls, env, gains: PushGains = PushGains(), use_shear: bool = True) -> PushOracleController:
        base = env.unwrapped
        return cls(base.action_scale, base.speed_mm_s * base.dt_s, gains, use_shear)

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        if "true_pose_shear" not in observation:
            raise ValueError("the push oracle needs obs_mode='oracle' (or 'oracle_real'): the observation has only "
                             f"{sorted(observation)}")
        depth, shear_x, face_yaw, _ = np.asarray(observation["true_pose_shear"], dtype=np.float64)
        return self.law(np.array([depth, shear_x, face_yaw]), self._goal(observation))


__all__ = ["PUSH_PROCESS_STD_MM", "PushGains", "PushGoalObservation", "PushLaw", "PushOracleController",
           "PushServoController", "PushTarget", "aim_bearing_deg", "push_estimate_slots", "push_reading_estimator",
           "push_state_from_slots"]
