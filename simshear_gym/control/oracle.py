"""The oracle controller: the true depth and shear (``obs_mode="oracle"``) into a proportional-integral law.

The follower's target is where it touched the plate, so the shear since touching *is* the tracking error (until
the contact would slip, beyond 7.5 mm): drive shear x, y, Rz to zero and the depth to the reference. Per step,
in the sensor frame (the action's frame)::

    error  = (shear_x, shear_y, depth - reference, shear_Rz)      (mm, mm, mm, deg)
    move   = -(kp * error + ki * sum of past errors)               (anti-windup: the sum is clipped)
    action = clip(move / action full scale, -1, 1)

Why the integral term: a moving plate is a ramp disturbance; a proportional law alone lags it by one step's
travel (0.4 mm at 4 mm/s and 10 Hz); the integral removes that lag (a type-2 loop). With ``kp = 1`` the loop is
deadbeat for a still plate, and ``ki`` in (0, 1] keeps it stable (closed-loop pole at ``1 - ki``).

Sign: the error is the sensor's displacement from its target on the plate, expressed in the sensor frame, so
moving by ``-error`` cancels it; depth is positive into the plate like the action's z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simshear_gym.envs.base import ActionScale


@dataclass(frozen=True)
class OracleGains:
    """Gains per variable (x, y, depth, Rz), per step, and the integral's limit in full-scale actions.

    Attributes:
        kp: proportional gains (dimensionless: move per unit of error).
        ki: integral gains, per step.
        integral_limit: the integral term is clipped to this many full-scale actions (anti-windup).
    """

    kp: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    ki: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 0.5)
    integral_limit: float = 1.0

    def __post_init__(self) -> None:
        if len(self.kp) != 4 or len(self.ki) != 4:
            raise ValueError(f"OracleGains.kp and ki need 4 values (x, y, depth, Rz), got {self.kp}, {self.ki}")
        if not all(0.0 <= k <= 2.0 for k in self.kp + self.ki):
            raise ValueError(f"OracleGains must lie in [0, 2] for a stable loop, got kp={self.kp}, ki={self.ki}")
        if self.integral_limit < 0:
            raise ValueError(f"OracleGains.integral_limit must be >= 0, got {self.integral_limit}")


class OracleController:
    """Maps an oracle observation to an action; call :meth:`reset` at each episode start.

    Args:
        reference_depth_mm: the env's reference depth (label convention).
        action_scale: the env's :class:`~simshear_gym.envs.base.ActionScale`.
        gains: see :class:`OracleGains`.
    """

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 gains: OracleGains = OracleGains()) -> None:
        self.reference_depth_mm = float(reference_depth_mm)
        self.gains = gains
        self._scale = action_scale.as_array()
        self._kp = np.asarray(gains.kp, dtype=np.float64)
        self._ki = np.asarray(gains.ki, dtype=np.float64)
        self._integral = np.zeros(4)

    @classmethod
    def for_env(cls, env, gains: OracleGains = OracleGains()) -> "OracleController":
        """A controller matched to an env's reference depth and action scale (wrappers are looked through)."""
        base = env.unwrapped
        return cls(base.reference_depth_mm, base.action_scale, gains)

    def reset(self) -> None:
        self._integral = np.zeros(4)

    def error(self, true_pose_shear: np.ndarray) -> np.ndarray:
        """(x mm, y mm, depth mm, Rz deg) error of an observation's ``true_pose_shear``
        (depth, shear x, shear y, shear Rz)."""
        values = np.asarray(true_pose_shear, dtype=np.float64)
        if values.shape != (4,):
            raise ValueError(f"true_pose_shear must have shape (4,) (depth, shear x, y, Rz), got {values.shape}")
        depth, shear_x, shear_y, shear_rz = values
        return np.array([shear_x, shear_y, depth - self.reference_depth_mm, shear_rz])

    def __call__(self, observation: dict) -> np.ndarray:
        if "true_pose_shear" not in observation:
            raise ValueError("the oracle controller needs obs_mode='oracle' (or 'oracle_real'): "
                             f"the observation has only {sorted(observation)}")
        error = self.error(observation["true_pose_shear"]) / self._scale  # in full-scale actions
        self._integral = np.clip(self._integral + error, -self.gains.integral_limit / np.maximum(self._ki, 1e-9),
                                 self.gains.integral_limit / np.maximum(self._ki, 1e-9))
        action = -(self._kp * error + self._ki * self._integral)
        return np.clip(action, -1.0, 1.0).astype(np.float32)


def true_pose_shear_from_info(info: dict) -> np.ndarray:
    """The oracle variables (depth, shear x, y, Rz) from a step's ``info`` (one env: (4,); a vector env's
    batched info: (N, 4)), for driving the oracle from an env in another observation mode."""
    depth = np.asarray(info["depth_mm"], dtype=np.float64)
    shear = np.asarray(info["shear_sensor_mm_deg"], dtype=np.float64)
    return np.stack([depth, shear[..., 0], shear[..., 1], shear[..., 5]], axis=-1).astype(np.float32)
