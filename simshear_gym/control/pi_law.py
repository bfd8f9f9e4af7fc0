"""The servo law shared by the oracle and the tactile servo controller: a PI law with anti-windup.

Per step, in the sensor frame (the envs' action frame), all in full-scale actions::

    error    = (shear_x - ref_x, shear_y - ref_y, depth - reference, shear_Rz) / action full scale
    integral = clip(integral + error, -limit / ki, limit / ki)         (anti-windup)
    action   = clip(-(kp * error + ki * integral), -1, 1)

The shear since touching *is* the sensor's displacement from its target on the contact, so moving by ``-error``
cancels it; depth is positive into the contact like the action's z. The integral removes the lag a proportional
law alone keeps behind a moving contact (a ramp disturbance: 0.4 mm at 4 mm/s and 10 Hz); with ``kp = 1`` the loop
is deadbeat for a still contact and ``ki`` in (0, 1] keeps it stable (closed-loop pole at ``1 - ki``). A
component whose gains are both 0 is not controlled. The shear reference ``(ref_x, ref_y)`` is zero (move back to
where the contact began) unless set for an episode (:attr:`PILaw.shear_reference_mm`: a held load's shear).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    @property
    def controlled(self) -> np.ndarray:
        """(4,) bool: the components the law steers (a component whose gains are both 0 is not controlled)."""
        return (np.asarray(self.kp) > 0) | (np.asarray(self.ki) > 0)


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
        self.shear_reference_mm = np.zeros(2)
        """(x, y) mm: the shear the law holds this episode (zero: none; :meth:`reset` clears it)."""

    def reset(self) -> None:
        self._integral = np.zeros(4)
        self.shear_reference_mm = np.zeros(2)

    def velocity_form(self, state: np.ndarray, previous_state: np.ndarray, last_action: np.ndarray) -> np.ndarray:
        """The law without an integral of its own: ``clip(last_action - kp * (error - previous error) - ki *
        error, -1, 1)`` (errors over the full scale as in :meth:`__call__`), float32 (4,). Fed its own last action
        it gives :meth:`__call__`'s actions while neither clips (the difference of two PI steps), so a policy that
        sees the last action and two frames can hold the integral; the clip stands for the anti-windup."""
        last = np.asarray(last_action, dtype=np.float64).reshape(-1)
        if last.shape != (4,) or not np.all(np.isfinite(last)):
            raise ValueError(f"last_action must be 4 finite values in [-1, 1], got {last_action!r}")
        error = self.error(state) / self._scale
        change = error - self.error(previous_state) / self._scale
        action = last - (self._kp * change + self._ki * error)
        return np.clip(np.where(self.gains.controlled, action, 0.0), -1.0, 1.0).astype(np.float32)

    def error(self, state: np.ndarray) -> np.ndarray:
        """(x mm, y mm, depth mm, Rz deg) error of a state (depth, shear x, shear y, shear Rz)."""
        values = np.asarray(state, dtype=np.float64)
        if values.shape != (4,) or not np.all(np.isfinite(values)):
            raise ValueError(f"state must be 4 finite values (depth, shear x, y, Rz), got {values}")
        depth, shear_x, shear_y, shear_rz = values
        reference_x, reference_y = self.shear_reference_mm
        return np.array([shear_x - reference_x, shear_y - reference_y, depth - self.reference_depth_mm, shear_rz])

    def __call__(self, state: np.ndarray) -> np.ndarray:
        """State -> action in [-1, 1]^4 (float32)."""
        error = self.error(state) / self._scale
        limit = self.gains.integral_limit / np.maximum(self._ki, 1e-9)
        self._integral = np.where(self._ki > 0, np.clip(self._integral + error, -limit, limit), 0.0)
        action = -(self._kp * error + self._ki * self._integral)
        return np.clip(action, -1.0, 1.0).astype(np.float32)
