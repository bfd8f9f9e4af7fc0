"""Edge following: the edge's offset, the depth and the edge's angle, into a law that slides along the edge.

State, the edge labels' conventions (``SimShearEdgeFollow-v0``'s oracle holds the same)::

    (offset mm, depth mm, edge angle deg)

``offset``: the dome apex's distance across the edge, + over the material (the labels' y minus the edge line's);
``depth``: the labels' z; ``edge angle``: the labels' Rz, the sensor's turn against the edge's direction. The sensor
does not turn (an MG400's J4 has less than a lap): the angle tells the law which way the edge runs in the sensor
frame. Per step, in the edge's frame (x along the edge, y across it towards the material), the law asks for::

    along  = step_mm                                         (speed_mm_s over the control rate)
    across = -(kp_offset * (offset - offset_ref) + ki_offset * integral)
    depth  = -(kp_depth * (depth - reference) + ki_depth * integral)

and turns (along, across) into the sensor frame by the angle. Integrals are clipped (anti-windup); the move is
clipped to the action's full scale.

:class:`EdgeServoController` sees only the ``tactile`` image: the edge GDNN (``y_mm, z_mm, edge_angle_deg``, mean
and std each) fused over time by the discriminative Kalman filter (the angle on the circle), predicted forward by
the move it commanded (a sensor-frame move ``(dx, dy)`` shifts the offset by ``sin(a) dx + cos(a) dy``).
:class:`EdgeOracleController` reads the oracle's true state (``obs_mode="oracle"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from simshear_gym.contract import ActionScale
from simshear_gym.control.estimator import EstimatorConfig, SlotEstimates, TactileEstimator
from simshear_gym.control.policy import EstimateThenLaw, as_action_scale, estimator_for_env

EDGE_STATE: tuple[str, ...] = ("y_mm", "z_mm", "edge_angle_deg")
"""The estimated state, in order (GDNN variable names)."""
EDGE_Y_MM = -0.25
"""The edge line's y in the edge labels' work frame (:class:`~simshear_gym.sim.replay.ReplayGeometry`)."""


@dataclass(frozen=True)
class EdgeGains:
    """Gains of :class:`EdgeLaw`, per step (move per mm of error), and the integrals' limit (mm of move).

    Attributes:
        kp_offset, ki_offset: across the edge.
        kp_depth, ki_depth: along the sensor's axis.
        integral_limit_mm: each integral term is clipped to this many mm of move.
        angle_process_std_deg: the filter's process noise on the edge angle per step (the edge turns under a
            sensor that slides along a bend: 2 deg a step on the tightest, 14 mm radius at 5 mm/s and 10 Hz).
    """

    kp_offset: float = 0.5
    ki_offset: float = 0.1
    kp_depth: float = 0.5
    ki_depth: float = 0.1
    integral_limit_mm: float = 1.0
    angle_process_std_deg: float = 3.0

    def __post_init__(self) -> None:
        gains = (self.kp_offset, self.ki_offset, self.kp_depth, self.ki_depth)
        if not all(math.isfinite(k) and 0.0 <= k <= 1.0 for k in gains):
            raise ValueError(f"EdgeGains: kp and ki must lie in [0, 1] for a stable loop, got {self}")
        if not (self.integral_limit_mm >= 0 and self.angle_process_std_deg > 0):
            raise ValueError(f"EdgeGains: integral_limit_mm >= 0 and angle_process_std_deg > 0, got {self}")


class EdgeLaw:
    """(offset, depth, edge angle) -> action in [-1, 1]^4: the law of the module docstring."""

    def __init__(self, reference_depth_mm: float, action_scale: np.ndarray, step_mm: float,
                 gains: EdgeGains = EdgeGains(), offset_reference_mm: float = 0.0) -> None:
        self.reference_depth_mm = float(reference_depth_mm)
        self.offset_reference_mm = float(offset_reference_mm)
        self._scale = np.asarray(action_scale, dtype=np.float64)
        if self._scale.shape != (4,) or not np.all(self._scale > 0):
            raise ValueError(f"action_scale must be 4 positive full-scale moves, got {action_scale}")
        if not (math.isfinite(step_mm) and 0.0 <= step_mm <= self._scale[0]):
            raise ValueError(f"the step along the edge must be in [0, {self._scale[0]:g}] mm (the action's full "
                             f"scale), got {step_mm!r}")
        self.step_mm = float(step_mm)
        self.gains = gains
        self._integral = np.zeros(2)

    def reset(self) -> None:
        self._integral = np.zeros(2)

    def __call__(self, state: np.ndarray) -> np.ndarray:
        values = np.asarray(state, dtype=np.float64)
        if values.shape != (3,) or not np.all(np.isfinite(values)):
            raise ValueError(f"state must be 3 finite values (offset mm, depth mm, edge angle deg), got {values}")
        offset, depth, angle_deg = values
        g = self.gains
        error = np.array([offset - self.offset_reference_mm, depth - self.reference_depth_mm])
        ki = np.array([g.ki_offset, g.ki_depth])
        limit = g.integral_limit_mm / np.maximum(ki, 1e-9)
        self._integral = np.where(ki > 0, np.clip(self._integral + error, -limit, limit), 0.0)
        across, dz = -(np.array([g.kp_offset, g.kp_depth]) * error + ki * self._integral)
        angle = math.radians(angle_deg)
        cos, sin = math.cos(angle), math.sin(angle)
        along = self.step_mm
        move = np.array([cos * along + sin * across, -sin * along + cos * across, dz, 0.0])
        return np.clip(move / self._scale, -1.0, 1.0).astype(np.float32)


class EdgeEstimator(TactileEstimator):
    """Image -> (mean (3,), std (3,)) of :data:`EDGE_STATE` (the edge GDNN's y, z and edge angle, fused over
    time). Call :meth:`reset` per episode; the commanded move is the envs' ``(dx, dy, dz mm, dRz deg)``."""

    state_variables = EDGE_STATE

    def __init__(self, config: EstimatorConfig, angle_process_std_deg: float = 3.0) -> None:
        self.angle_process_std_deg = angle_process_std_deg
        super().__init__(config)

    def _check_variables(self, path: Path, names: tuple[str, ...]) -> None:
        missing = [name for name in EDGE_STATE if name not in names]
        if missing:
            raise ValueError(f"{path}: the GDNN predicts {names}; edge following needs {EDGE_STATE}, missing "
                             f"{missing} (use an edge GDNN)")

    def _make_filter(self, process_mm: float):
        from simshear_gym.models.bayes_filter import BayesFilterConfig, DiscriminativeKalmanFilter

        names = self.model.variables.names
        specs = [self.model.variables.variables[names.index(name)] for name in EDGE_STATE]
        return DiscriminativeKalmanFilter(BayesFilterConfig.from_output_specs(
            specs, (process_mm, process_mm, self.angle_process_std_deg), prior_std=(math.inf,) * 3))

    def _state_delta(self, commanded_move: np.ndarray) -> np.ndarray:
        dx, dy, dz, drz = np.asarray(commanded_move, dtype=np.float64)
        angle = math.radians(float(self._filter.mean[2]))
        return np.array([math.sin(angle) * dx + math.cos(angle) * dy, dz, drz])


EDGE_SLOT_SCALE = 7.5
"""The estimate observation's unit of the shear slots (:data:`~simshear_gym.contract.ESTIMATE_SCALE`): the edge
angle's cosine and sine are written there times this, so they come out of the normalisation as they are."""


def edge_estimate_slots(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An edge estimate (y, z mm, edge angle deg) in the four slots of the policies' ``estimate`` observation
    (:func:`~simshear_gym.contract.estimate_features`: depth, then three slots in units of
    :data:`EDGE_SLOT_SCALE`): (depth, offset from the edge, 7.5 cos(angle), 7.5 sin(angle)); the angle's std
    (rad, times 7.5) on both of its slots."""
    y, z, angle = np.asarray(mean, dtype=np.float64)
    std_y, std_z, std_angle = np.asarray(std, dtype=np.float64)
    radians = math.radians(angle)
    angle_std = EDGE_SLOT_SCALE * math.radians(std_angle)
    return (np.array([z, y - EDGE_Y_MM, EDGE_SLOT_SCALE * math.cos(radians), EDGE_SLOT_SCALE * math.sin(radians)]),
            np.array([std_z, std_y, angle_std, angle_std]))


def edge_state_from_slots(slots: np.ndarray) -> np.ndarray:
    """(offset mm, depth mm, edge angle deg) of an estimate's four slots (:func:`edge_estimate_slots`)."""
    depth, offset, cos, sin = np.asarray(slots, dtype=np.float64)
    return np.array([offset, depth, math.degrees(math.atan2(sin, cos))])


class EdgeReadingEstimator(SlotEstimates, EdgeEstimator):
    """The edge estimator of ``SimShearEdgeFollow-v0``'s ``estimate`` observations: its filter state and the GDNN's
    reading of the last image, both in the observation's four slots (:func:`edge_estimate_slots`)."""

    slots = staticmethod(edge_estimate_slots)


class EdgeServoController(EstimateThenLaw):
    """Tactile image -> action: :class:`EdgeEstimator` then :class:`EdgeLaw`. Call :meth:`reset` per episode.

    Args:
        reference_depth_mm: the depth to hold (labels' z, as the env's ``reference_depth_mm``).
        action_scale: the env's :class:`~simshear_gym.contract.ActionScale`.
        step_mm: the move along the edge per step (the env's speed over its control rate).
        gains: :class:`EdgeGains`.
        estimator: the GDNN (``posenet``; None: the shipped ``edge`` one) and the filter's settings.
    """

    name = "edge_servo"
    who = "the edge servo controller"
    state_names: tuple[str, ...] = ("y_mm", "depth_mm", "edge_angle_deg")
    """The state estimate's names, for logs (the GDNN's y, z and edge angle)."""

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 step_mm: float = 0.5, gains: EdgeGains = EdgeGains(),
                 estimator: EstimatorConfig = EstimatorConfig()) -> None:
        from simshear_gym.models.zoo import posenet_weights

        self.action_scale = as_action_scale(action_scale, "EdgeServoController")
        self._scale = self.action_scale.as_array()
        if estimator.posenet is None:
            estimator = replace(estimator, posenet=str(posenet_weights("edge")))
        self.estimator = EdgeEstimator(estimator, gains.angle_process_std_deg)
        self.law = EdgeLaw(reference_depth_mm, self._scale, step_mm, gains)

    @classmethod
    def for_env(cls, env, gains: EdgeGains = EdgeGains(),
                estimator: EstimatorConfig = EstimatorConfig()) -> EdgeServoController:
        """A controller matched to an edge env's reference depth, action scale, speed and GDNN and process noise
        (its :class:`~simshear_gym.contract.ServoHints`)."""
        base = env.unwrapped
        estimator = estimator_for_env(env, estimator, shipped=False)
        return cls(base.reference_depth_mm, base.action_scale, base.speed_mm_s * base.dt_s, gains, estimator)

    def __call__(self, observation: dict) -> np.ndarray:
        mean, std = self._estimate(observation)
        self.last_estimate = (mean, std)
        return self._command(self.law(np.array([mean[0] - EDGE_Y_MM, mean[1], mean[2]])))


class EdgeOracleController:
    """The oracle's true (offset, depth, edge angle) (``obs_mode="oracle"`` of ``SimShearEdgeFollow-v0``) into
    :class:`EdgeLaw`: what the law does with a perfect reading."""

    name = "edge_oracle"

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 step_mm: float = 0.5, gains: EdgeGains = EdgeGains()) -> None:
        self.action_scale = as_action_scale(action_scale, "EdgeOracleController")
        self.law = EdgeLaw(reference_depth_mm, self.action_scale.as_array(), step_mm, gains)

    @classmethod
    def for_env(cls, env, gains: EdgeGains = EdgeGains()) -> EdgeOracleController:
        base = env.unwrapped
        return cls(base.reference_depth_mm, base.action_scale, base.speed_mm_s * base.dt_s, gains)

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        if "true_pose_shear" not in observation:
            raise ValueError("the edge oracle needs obs_mode='oracle' (or 'oracle_real'): the observation has only "
                             f"{sorted(observation)}")
        offset, depth, _, angle = np.asarray(observation["true_pose_shear"], dtype=np.float64)
        return self.law(np.array([offset, depth, angle]))


__all__ = ["EDGE_STATE", "EdgeEstimator", "EdgeGains", "EdgeLaw", "EdgeOracleController", "EdgeReadingEstimator",
           "EdgeServoController", "edge_estimate_slots", "edge_state_from_slots"]
