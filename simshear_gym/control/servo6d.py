"""6-DoF tactile servo control: depth, shear and the contact's tilt from one GDNN reading, into two PI laws.

:class:`Servo6DController` drives a 6-DoF follower (``SimShearTracking6D-v0`` with the Panda): it sees only the
observation's ``tactile`` image, reads it with the shipped ``surface`` GDNN, which predicts
``z_mm, rx_deg, ry_deg, shear_x_mm, shear_y_mm, shear_rz_deg`` (mean and std each), and fuses the six over time
with the discriminative Kalman filter (:mod:`simshear_gym.models.bayes_filter`), predicted forward by the move it
commanded. State, sensor frame, the labels' conventions::

    (depth mm, shear x mm, shear y mm, shear Rz deg, Rx deg, Ry deg)

Rx, Ry: the sensor's tilt against the contact's surface (0 = normal to it); a commanded rotation ``(dRx, dRy)``
about the sensor's own x, y changes them by ``(+dRx, +dRy)`` (for a sensor turned little about its axis against
the surface). Laws (:class:`~simshear_gym.control.pi_law.PILaw`, anti-windup): the servo controller's law on
(depth, shear x, y, shear Rz), and a second one that turns the sensor against its tilt, (Rx, Ry) in the law's two
in-plane slots. Shear Rz is not controlled (gains 0): the GDNN cannot read it (its MAE equals chance).

The action is the 6-D one of :func:`~simshear_gym.contract.action_space_6d`: ``(dx, dy, dz, dRz, dRx, dRy)`` in
[-1, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simshear_gym.contract import TILT_STEP_DEG, ActionScale
from simshear_gym.control.estimator import STATE_VARIABLES, EstimatorConfig, TactileEstimator
from simshear_gym.control.pi_law import PIGains, PILaw
from simshear_gym.control.policy import EstimateThenLaw, as_action_scale, estimator_for_env
from simshear_gym.control.servo import SERVO_GAINS

STATE_VARIABLES_6D: tuple[str, ...] = STATE_VARIABLES + ("rx_deg", "ry_deg")
"""The estimated state, in order (GDNN variable names)."""


@dataclass(frozen=True)
class Servo6DGains:
    """Gains of :class:`Servo6DController`, per step, in full-scale actions.

    Attributes:
        planar: the law on (shear x, shear y, depth, shear Rz): the servo controller's gains by default.
        tilt_kp, tilt_ki: proportional and integral gain of the tilt law (both axes).
        tilt_process_std_deg: per-step std of the contact's unknown tilting (the filter's process noise for Rx,
            Ry): the 6-DoF tracking plate tilts by up to 0.63 deg per step at 4 mm/s and 10 Hz.
    """

    planar: PIGains = SERVO_GAINS
    tilt_kp: float = 0.6
    tilt_ki: float = 0.2
    tilt_process_std_deg: float = 0.8
    tilt: PIGains = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tilt_process_std_deg) and self.tilt_process_std_deg > 0):
            raise ValueError(f"Servo6DGains.tilt_process_std_deg must be > 0, got {self.tilt_process_std_deg!r}")
        # PIGains checks the range; the tilts take its x and y slots
        object.__setattr__(self, "tilt", PIGains(kp=(self.tilt_kp, self.tilt_kp, 0.0, 0.0),
                                                 ki=(self.tilt_ki, self.tilt_ki, 0.0, 0.0)))


class TiltEstimator(TactileEstimator):
    """Image -> (mean (6,), std (6,)) of :data:`STATE_VARIABLES_6D`: one GDNN pass, the Bayesian filter over the
    six (as :class:`~simshear_gym.control.estimator.TactileEstimator` over four). Call :meth:`reset` per episode;
    the commanded move is ``(dx, dy, dz mm, dRz, dRx, dRy deg)``.

    Args:
        config: the GDNN (``posenet``; None: the shipped ``surface`` one), process noise of depth and shear (mm)
            and of shear Rz (deg), filtering on/off, torch threads.
        tilt_process_std_deg: the filter's process noise of Rx, Ry, deg per step.
    """

    state_variables = STATE_VARIABLES_6D

    def __init__(self, config: EstimatorConfig = EstimatorConfig(), tilt_process_std_deg: float = 0.8) -> None:
        self.tilt_process_std_deg = tilt_process_std_deg
        super().__init__(config)

    def _check_variables(self, path: Path, names: tuple[str, ...]) -> None:
        missing = [name for name in ("z_mm", "rx_deg", "ry_deg") if name not in names]
        if missing:
            raise ValueError(f"{path}: the GDNN predicts {names}; the 6-DoF servo needs depth and tilt, missing "
                             f"{missing} (use a surface GDNN)")

    def _make_filter(self, process_mm: float):
        from simshear_gym.models.bayes_filter import BayesFilterConfig, DiscriminativeKalmanFilter

        process = (process_mm,) * 3 + (self.config.process_std_deg, self.tilt_process_std_deg,
                                       self.tilt_process_std_deg)
        return DiscriminativeKalmanFilter(BayesFilterConfig(
            process_std=process, prior_std=(math.inf,) * 6, names=STATE_VARIABLES_6D))

    @staticmethod
    def _state_delta(commanded_move: np.ndarray) -> np.ndarray:
        dx, dy, dz, drz, drx, dry = np.asarray(commanded_move, dtype=np.float64)
        return np.array([dz, dx, dy, drz, drx, dry])


class Servo6DController(EstimateThenLaw):
    """Tactile image -> 6-D action: :class:`TiltEstimator` then the two PI laws (module docstring). Call
    :meth:`reset` per episode; ``last_estimate`` holds the last (mean (6,), std (6,)).

    Args:
        reference_depth_mm: the depth to hold (labels' convention, as the env's ``reference_depth_mm``).
        action_scale: the env's :class:`~simshear_gym.contract.ActionScale`.
        tilt_step_deg: the env's full-scale tilt rate, deg per step.
        gains: :class:`Servo6DGains`.
        estimator: the GDNN and the filter's settings.
    """

    name = "servo6d"
    who = "the 6-DoF servo controller"

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 tilt_step_deg: float = TILT_STEP_DEG, gains: Servo6DGains = Servo6DGains(),
                 estimator: EstimatorConfig = EstimatorConfig()) -> None:
        self.action_scale = as_action_scale(action_scale, "Servo6DController")
        if not (math.isfinite(tilt_step_deg) and tilt_step_deg > 0):
            raise ValueError(f"Servo6DController: tilt_step_deg must be > 0, got {tilt_step_deg!r}")
        self._scale = np.concatenate([self.action_scale.as_array(), [tilt_step_deg, tilt_step_deg]])
        self.gains = gains
        self.estimator = TiltEstimator(estimator, gains.tilt_process_std_deg)
        self.law = PILaw(reference_depth_mm, self._scale[:4], gains.planar)
        self.tilt_law = PILaw(0.0, np.array([tilt_step_deg, tilt_step_deg, 1.0, 1.0]), gains.tilt)

    @classmethod
    def for_env(cls, env, gains: Servo6DGains = Servo6DGains(),
                estimator: EstimatorConfig = EstimatorConfig()) -> Servo6DController:
        """A controller matched to a 6-DoF env's reference depth, action scale, tilt rate and shipped GDNN."""
        base = env.unwrapped
        if getattr(base, "action_space", None) is not None and base.action_space.shape != (6,):
            raise ValueError(f"Servo6DController needs a 6-D action space (a 6-DoF follower), the env has "
                             f"{base.action_space.shape}: use ServoController for a 4-DoF one")
        estimator = estimator_for_env(env, estimator, process=False)
        return cls(base.reference_depth_mm, base.action_scale, base.tilt_step_deg, gains, estimator)

    def reset(self) -> None:
        super().reset()
        self.tilt_law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        mean, std = self._estimate(observation)
        self.last_estimate = (mean, std)
        planar = self.law(mean[:4])
        tilt = self.tilt_law(np.array([0.0, mean[4], mean[5], 0.0]))[:2]
        return self._command(np.concatenate([planar, tilt]).astype(np.float32))
