"""The oracle controller: the true depth and shear (``obs_mode="oracle"``) into the PI servo law.

The follower's target is where it touched the contact, so the shear since touching *is* the tracking error (until
the contact would slip, beyond 7.5 mm): :class:`~simshear_gym.control.pi_law.PILaw` drives shear x, y, Rz to zero
and the depth to the reference. Default gains kp 1, ki 0.5 on every component (deadbeat on an exact state).
"""

from __future__ import annotations

import numpy as np

from simshear_gym.contract import ActionScale
from simshear_gym.control.pi_law import PIGains, PILaw
from simshear_gym.control.policy import as_action_scale

OracleGains = PIGains
"""The oracle's gains are the PI law's (:class:`~simshear_gym.control.pi_law.PIGains`)."""


class OracleController:
    """Maps an oracle observation to an action; call :meth:`reset` at each episode start.

    A :class:`~simshear_gym.control.policy.Controller`.

    Args:
        reference_depth_mm: the env's reference depth (label convention).
        action_scale: the env's :class:`~simshear_gym.contract.ActionScale` (as the servo controller's).
        gains: the PI law's gains.
    """

    name = "oracle"
    """For logs."""

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 gains: PIGains = PIGains()) -> None:
        self.action_scale = as_action_scale(action_scale, "OracleController")
        self.law = PILaw(reference_depth_mm, self.action_scale.as_array(), gains)

    @classmethod
    def for_env(cls, env, gains: PIGains = PIGains()) -> OracleController:
        """A controller matched to an env's reference depth and action scale (wrappers are looked through)."""
        base = env.unwrapped
        return cls(base.reference_depth_mm, base.action_scale, gains)

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        if "true_pose_shear" not in observation:
            raise ValueError("the oracle controller needs obs_mode='oracle' (or 'oracle_real'): "
                             f"the observation has only {sorted(observation)}")
        return self.law(observation["true_pose_shear"])


def true_pose_shear_from_info(info: dict) -> np.ndarray:
    """The oracle variables (depth, shear x, y, Rz) from a step's ``info`` (one env: (4,); a vector env's
    batched info: (N, 4)), for driving the oracle from an env in another observation mode."""
    depth = np.asarray(info["depth_mm"], dtype=np.float64)
    shear = np.asarray(info["shear_sensor_mm_deg"], dtype=np.float64)
    return np.stack([depth, shear[..., 0], shear[..., 1], shear[..., 5]], axis=-1).astype(np.float32)
