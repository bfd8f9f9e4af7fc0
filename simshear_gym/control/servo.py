"""Tactile servo control: estimated depth and shear into a PI law, into the envs' action.

One class, :class:`ServoController`, drives the simulated envs and the real robot alike: it sees only the
observation's ``tactile`` image (never ground truth), estimates (depth, shear x, y, Rz) with a
:class:`~simshear_gym.control.estimator.TactileEstimator` (GDNN + Bayesian filter), and moves the sensor back to
where it touched the contact, at the reference depth.

Servo law (:class:`PILaw`), per step, in the sensor frame (the action's frame), all in full-scale actions::

    error    = (shear_x, shear_y, depth - reference, shear_Rz) / action full scale
    integral = clip(integral + error, -limit / ki, limit / ki)         (anti-windup)
    action   = clip(-(kp * error + ki * integral), -1, 1)

The shear since touching *is* the displacement from the target, so moving by ``-error`` cancels it; the integral
removes the lag a proportional law alone keeps behind a moving contact (a ramp disturbance). Default gains: kp 1,
ki 0.5 for the oracle (exact state, deadbeat); the servo controller's defaults are lower (kp 0.6, ki 0.2 on shear,
kp 0.5, ki 0.1 on depth, Rz off) because its state is an estimate whose noise the law would otherwise amplify. A
variable whose gains are 0 is not controlled (shear Rz, which our networks cannot read from an image).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simshear_gym.control.estimator import EstimatorConfig, TactileEstimator


@dataclass(frozen=True)
class PIGains:
    """Gains per action component (x, y, depth, Rz), per step, and the integral's limit in full-scale actions.

    Attributes:
        kp: proportional gains (move per unit of error).
        ki: integral gains, per step.
        integral_limit: the integral term is clipped to this many full-scale actions (anti-windup).
    """

    kp: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    ki: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 0.5)
    integral_limit: float = 1.0

    def __post_init__(self) -> None:
        if len(self.kp) != 4 or len(self.ki) != 4:
            raise ValueError(f"PIGains.kp and ki need 4 values (x, y, depth, Rz), got {self.kp}, {self.ki}")
        if not all(0.0 <= k <= 2.0 for k in self.kp + self.ki):
            raise ValueError(f"PIGains must lie in [0, 2] for a stable loop, got kp={self.kp}, ki={self.ki}")
        if self.integral_limit < 0:
            raise ValueError(f"PIGains.integral_limit must be >= 0, got {self.integral_limit}")


SERVO_GAINS = PIGains(kp=(0.6, 0.6, 0.5, 0.0), ki=(0.2, 0.2, 0.1, 0.0))
"""Default gains of :class:`ServoController` (see the module docstring)."""


class PILaw:
    """The servo law of the module docstring; ``action_scale`` is the env's full scale (x, y, z mm, Rz deg)."""

    def __init__(self, reference_depth_mm: float, action_scale: np.ndarray, gains: PIGains = PIGains()) -> None:
        self.reference_depth_mm = float(reference_depth_mm)
        self.gains = gains
        self._scale = np.asarray(action_scale, dtype=np.float64)
        if self._scale.shape != (4,) or not np.all(self._scale > 0):
            raise ValueError(f"action_scale must be 4 positive full-scale moves, got {action_scale}")
        self._kp = np.asarray(gains.kp, dtype=np.float64)
        self._ki = np.asarray(gains.ki, dtype=np.float64)
        self._integral = np.zeros(4)

    def reset(self) -> None:
        self._integral = np.zeros(4)

    def error(self, state: np.ndarray) -> np.ndarray:
        """(x mm, y mm, depth mm, Rz deg) error of a state (depth, shear x, shear y, shear Rz)."""
        values = np.asarray(state, dtype=np.float64)
        if values.shape != (4,) or not np.all(np.isfinite(values)):
            raise ValueError(f"state must be 4 finite values (depth, shear x, y, Rz), got {values}")
        depth, shear_x, shear_y, shear_rz = values
        return np.array([shear_x, shear_y, depth - self.reference_depth_mm, shear_rz])

    def __call__(self, state: np.ndarray) -> np.ndarray:
        """State -> action in [-1, 1]^4 (float32)."""
        error = self.error(state) / self._scale
        limit = self.gains.integral_limit / np.maximum(self._ki, 1e-9)
        self._integral = np.where(self._ki > 0, np.clip(self._integral + error, -limit, limit), 0.0)
        action = -(self._kp * error + self._ki * self._integral)
        return np.clip(action, -1.0, 1.0).astype(np.float32)


class ServoController:
    """Tactile image -> action: :class:`TactileEstimator` then :class:`PILaw`. Call :meth:`reset` per episode.

    Args:
        reference_depth_mm: the depth to hold (labels' convention, as the env's ``reference_depth_mm``).
        action_scale: the env's full-scale move (x, y, z mm, Rz deg).
        gains: the law's gains (default :data:`SERVO_GAINS`).
        estimator: settings of the estimator (GDNN weights, filter on/off, process noise).
    """

    def __init__(self, reference_depth_mm: float, action_scale: np.ndarray, gains: PIGains = SERVO_GAINS,
                 estimator: EstimatorConfig = EstimatorConfig()) -> None:
        self.estimator = TactileEstimator(estimator)
        self.law = PILaw(reference_depth_mm, action_scale, gains)
        self._scale = np.asarray(action_scale, dtype=np.float64)
        self._last_move: np.ndarray | None = None
        self.last_estimate: tuple[np.ndarray, np.ndarray] | None = None
        """(mean (4,), std (4,)) of the last step's state estimate, for logging."""

    @classmethod
    def for_env(cls, env, gains: PIGains = SERVO_GAINS,
                estimator: EstimatorConfig = EstimatorConfig()) -> "ServoController":
        """A controller matched to an env's reference depth and action scale (wrappers are looked through)."""
        base = env.unwrapped
        return cls(base.reference_depth_mm, base.action_scale.as_array(), gains, estimator)

    def reset(self) -> None:
        self.estimator.reset()
        self.law.reset()
        self._last_move = None
        self.last_estimate = None

    def __call__(self, observation: dict) -> np.ndarray:
        if "tactile" not in observation:
            raise ValueError(f"the servo controller needs the observation's 'tactile' image; got {sorted(observation)}")
        mean, std = self.estimator(observation["tactile"], self._last_move)
        self.last_estimate = (mean, std)
        action = self.law(mean)
        self._last_move = action.astype(np.float64) * self._scale
        return action
