"""Tactile servo control: estimated depth and shear into a PI law, into the envs' action.

One class, :class:`ServoController`, drives the simulated envs and the real robot alike: it sees only the
observation's ``tactile`` image (never ground truth), estimates (depth, shear x, y, Rz) with a
:class:`~simshear_gym.control.estimator.TactileEstimator` (GDNN + Bayesian filter), and moves the sensor back to
where it touched the contact, at the reference depth.

Servo law: :class:`~simshear_gym.control.pi_law.PILaw` (shared with the oracle). Default gains: kp 1, ki 0.5 for
the oracle (exact state, deadbeat); the servo controller's defaults are lower (kp 0.6, ki 0.2 on shear,
kp 0.5, ki 0.1 on depth, Rz off) because its state is an estimate whose noise the law would otherwise amplify. A
variable whose gains are 0 is not controlled (shear Rz, which our networks cannot read from an image).

Holding a load (``hold_load``, heavy co-lift): a heavy object's weight deflects the skin from the first image on,
and that shear is what carries the object. The law then holds the shear it reads at the episode's first image
(the grasp) instead of zero: it keeps its place relative to the grasp, where moving to zero shear would walk the
skin down and let the object slide. An env asks for it in its ``servo_hints``
(:class:`~simshear_gym.contract.ServoHints`: ``hold_load``; ``SimShearCoLift-v0`` with ``payload="heavy"``), and
may ask for a margin (``load_margin_mm``: shear added to the grasp's, mm, sensor frame: along the weight, the
follower carries more than it felt at the grasp) and shear gains of its own (``shear_gains``: (kp, ki) on shear x
and y); :meth:`ServoController.for_env` reads them (:func:`servo_law_for_env`).
"""

from __future__ import annotations

import numpy as np

from simshear_gym.contract import ActionScale, servo_hints
from simshear_gym.control.estimator import EstimatorConfig, TactileEstimator
from simshear_gym.control.pi_law import PIGains, PILaw
from simshear_gym.control.policy import EstimateThenLaw, as_action_scale, estimator_for_env

LAW_VARIABLES = ("shear_x_mm", "shear_y_mm", "z_mm", "shear_rz_deg")
"""The estimated variable each of the law's components (x, y, depth, Rz) steers on."""
SERVO_GAINS = PIGains(kp=(0.6, 0.6, 0.5, 0.0), ki=(0.2, 0.2, 0.1, 0.0))
"""Default gains of :class:`ServoController` (see the module docstring)."""


def with_shear_gains(gains: PIGains, kp: float, ki: float) -> PIGains:
    """``gains`` with (kp, ki) on shear x and y (depth and Rz kept)."""
    return PIGains(kp=(kp, kp, *gains.kp[2:]), ki=(ki, ki, *gains.ki[2:]), integral_limit=gains.integral_limit)


def servo_law_for_env(env, gains: PIGains | None = None, hold_load: bool | None = None
                      ) -> tuple[PIGains, bool, np.ndarray]:
    """(gains, hold_load, load margin (x, y) mm) of the servo law for an env (wrappers looked through), from its
    :class:`~simshear_gym.contract.ServoHints`: its ``hold_load`` where ``hold_load`` is None; while holding a load,
    its ``load_margin_mm`` and, where ``gains`` is None, :data:`SERVO_GAINS` with its ``shear_gains`` (kp, ki) on
    shear x and y."""
    hints = servo_hints(env)
    explicit = gains is not None
    gains = gains if explicit else SERVO_GAINS
    if hold_load is None:
        hold_load = hints.hold_load
    margin = np.zeros(2)
    if hold_load:
        margin = np.asarray(hints.load_margin_mm, dtype=np.float64).reshape(2)
        if hints.shear_gains is not None and not explicit:
            gains = with_shear_gains(gains, *hints.shear_gains)
    return gains, bool(hold_load), margin


class ServoController(EstimateThenLaw):
    """Tactile image -> action: :class:`TactileEstimator` then :class:`PILaw`. Call :meth:`reset` per episode.

    A :class:`~simshear_gym.control.policy.Controller` that keeps a state estimate (``last_estimate``).

    Args:
        reference_depth_mm: the depth to hold (labels' convention, as the env's ``reference_depth_mm``).
        action_scale: the env's :class:`~simshear_gym.contract.ActionScale` (as the oracle's).
        gains: the law's gains (default :data:`SERVO_GAINS`).
        estimator: settings of the estimator (GDNN weights, filter on/off, process noise).
        hold_load: hold the shear of the episode's first estimate (a carried load's) rather than zero.
        load_margin_mm: (x, y) mm added to that held shear (sensor frame; along the weight: carry more).
    """

    name = "servo"
    """For logs (the real rollout's ``controller``)."""
    who = "the servo controller"

    def __init__(self, reference_depth_mm: float = 4.0, action_scale: ActionScale = ActionScale(),
                 gains: PIGains = SERVO_GAINS, estimator: EstimatorConfig = EstimatorConfig(),
                 hold_load: bool = False, load_margin_mm: tuple[float, float] = (0.0, 0.0)) -> None:
        self.action_scale = as_action_scale(action_scale, "ServoController")
        self.hold_load = bool(hold_load)
        self.load_margin_mm = np.asarray(load_margin_mm, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(self.load_margin_mm)):
            raise ValueError(f"load_margin_mm must be 2 finite values (x, y mm), got {load_margin_mm!r}")
        self._scale = self.action_scale.as_array()
        self.estimator = TactileEstimator(estimator)
        steered = [name for name, on in zip(LAW_VARIABLES, gains.controlled) if on]
        unread = [name for name in steered if name in self.estimator.unread]
        if unread:
            raise ValueError(
                f"the GDNN {self.estimator.config.posenet or 'surface'} does not read {unread}, which the servo law "
                f"steers on (gains kp={gains.kp}, ki={gains.ki} for x, y, depth, Rz): train the sensor on data "
                f"that varies them (a shear set), or give gains of 0 for those components")
        self.law = PILaw(reference_depth_mm, self._scale, gains)

    @classmethod
    def for_env(cls, env, gains: PIGains | None = None,
                estimator: EstimatorConfig = EstimatorConfig(), hold_load: bool | None = None,
                load_margin_mm: tuple[float, float] | None = None) -> ServoController:
        """A controller matched to an env's reference depth and action scale (wrappers are looked through).

        The env's :class:`~simshear_gym.contract.ServoHints` fill in what is not given: without
        ``estimator.posenet`` the estimator reads the env's images with the GDNN the env names (``posenet``, e.g.
        ``surface``); without ``estimator.process_std_mm`` it takes the env's ``process_std_mm`` (how far its
        contact moves in a step unknown to the follower; None: the estimator's default); the law's gains (None: the
        defaults, or the env's), load hold and margin (None: the env's) as :func:`servo_law_for_env` gives them."""
        base = env.unwrapped
        estimator = estimator_for_env(env, estimator)
        gains, hold_load, margin = servo_law_for_env(env, gains, hold_load)
        if load_margin_mm is not None:
            margin = np.asarray(load_margin_mm, dtype=np.float64).reshape(2)
        return cls(base.reference_depth_mm, base.action_scale, gains, estimator, hold_load, tuple(margin))

    def __call__(self, observation: dict) -> np.ndarray:
        first = self.last_estimate is None
        mean, std = self._estimate(observation)
        self.last_estimate = (mean, std)
        if first and self.hold_load:
            self.law.shear_reference_mm = np.asarray(mean[1:3], dtype=np.float64) + self.load_margin_mm
        return self._command(self.law(mean))
