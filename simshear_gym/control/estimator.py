"""Tactile state estimator: GDNN reading of one tactile image, fused over time by the Bayesian filter.

The follower never sees ground truth: each step it reads the image with a GDNN
(:mod:`simshear_gym.models.gdnn`) and fuses the reading with its belief, predicted forward by the move it commanded
(:mod:`simshear_gym.models.bayes_filter`). State (the layout of the envs' ``true_pose_shear``)::

    (depth mm, shear x mm, shear y mm, shear Rz deg)        sensor frame; depth in the labels' convention

Motion model, per step: the follower's commanded move ``(dx, dy, dz mm, dRz deg)`` in the sensor frame changes the
state by ``(+dz, +dx, +dy, +dRz)`` (shear is the sensor's displacement from where it touched the contact). What the
follower does not command, the leader's motion of the contact, is the process noise: ``process_std`` per step
should cover the contact's travel in one step (about 0.4 mm at 4 mm/s and 10 Hz).

The GDNN may predict more variables than the state (a ``surface`` network also gives the tilt Rx, Ry); the
estimator takes the four it needs by name. Variables a network cannot read (its std near the range's) still enter
with their large std, so the filter then follows the commanded motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

STATE_VARIABLES = ("z_mm", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
"""The estimated state, in order (GDNN variable names): depth, shear x, shear y, shear Rz."""
UNREAD_STD = 100.0
"""The std (mm, deg) reported for a state variable the GDNN does not read (its mean is 0)."""
DEFAULT_PROCESS_STD_MM = 0.4
"""Process noise when neither the config nor the env gives one: the tracking contact's 4 mm/s at 10 Hz."""


@dataclass(frozen=True)
class EstimatorConfig:
    """Estimator settings.

    Attributes:
        posenet: a GDNN weights file (``best.pt`` of ``simshear train posenet``); None: the shipped ``surface`` one.
        process_std_mm: per-step std of the contact's unknown motion, for depth and shear x, y (mm); None:
            :data:`DEFAULT_PROCESS_STD_MM` (``ServoController.for_env`` takes the env's
            ``servo_hints.process_std_mm`` where it gives one).
        process_std_deg: the same for shear Rz (deg).
        filtered: fuse over time with the Bayesian filter; False: the raw GDNN reading each step.
        threads: torch threads for the GDNN (None: leave torch's setting).
    """

    posenet: str | None = None
    process_std_mm: float | None = None
    process_std_deg: float = 0.8
    filtered: bool = True
    threads: int | None = None

    def __post_init__(self) -> None:
        if not ((self.process_std_mm is None or self.process_std_mm > 0) and self.process_std_deg > 0):
            raise ValueError(f"process stds must be > 0, got {self.process_std_mm} mm, {self.process_std_deg} deg")


class TactileEstimator:
    """Image -> (mean (4,), std (4,)) of :data:`STATE_VARIABLES`; call :meth:`reset` at each episode start.

    Subclasses estimate another state (``state_variables``) with their own filter and motion model
    (:meth:`_make_filter`, :meth:`_state_delta`), e.g. the 6-DoF servo's :class:`~simshear_gym.control.servo6d.
    TiltEstimator`; the GDNN reading and the filter's use are this class's.
    """

    state_variables: tuple[str, ...] = STATE_VARIABLES
    """The estimated state, in order (GDNN variable names)."""

    def __init__(self, config: EstimatorConfig = EstimatorConfig()) -> None:
        import torch

        from simshear_gym.models.posenet_io import load_posenet
        from simshear_gym.models.zoo import posenet_weights

        if config.threads:
            torch.set_num_threads(config.threads)
        self.config = config
        path = Path(config.posenet) if config.posenet else posenet_weights("surface")
        self.model, self.card = load_posenet(path)
        names = self.model.variables.names
        self._check_variables(path, names)
        self.unread = tuple(name for name in self.state_variables if name not in names)
        """State variables this GDNN does not read (a sensor recorded without shear): reported as 0 with
        :data:`UNREAD_STD`, so the servo law leaves them alone."""
        self._present = [i for i, name in enumerate(self.state_variables) if name in names]
        self._index = [names.index(self.state_variables[i]) for i in self._present]
        process_mm = DEFAULT_PROCESS_STD_MM if config.process_std_mm is None else config.process_std_mm
        self._filter = self._make_filter(process_mm)
        self._size = self.model.config.image_size_px
        self._inference = self.model.frozen()
        self._started = False

    def _check_variables(self, path: Path, names: tuple[str, ...]) -> None:
        if "z_mm" not in names:
            raise ValueError(f"{path}: the GDNN predicts {names}; the estimator needs at least the depth z_mm")

    def _make_filter(self, process_mm: float):
        """The Bayesian filter over :attr:`state_variables` (ranges from the GDNN's output specs)."""
        from simshear_gym.models.bayes_filter import BayesFilterConfig, DiscriminativeKalmanFilter
        from simshear_gym.models.gdnn import OutputSpec

        names = self.model.variables.names
        specs = [self.model.variables.variables[names.index(name)] if name in names
                 else OutputSpec(name, name.rpartition("_")[2], -7.5, 7.5) for name in STATE_VARIABLES]
        process = (process_mm,) * 3 + (self.config.process_std_deg,)
        return DiscriminativeKalmanFilter(BayesFilterConfig.from_output_specs(
            specs, process, prior_std=(math.inf,) * 4))

    @staticmethod
    def _state_delta(commanded_move: np.ndarray) -> np.ndarray:
        """The state change of a commanded move (dx, dy, dz mm, dRz deg): (+dz, +dx, +dy, +dRz)."""
        dx, dy, dz, drz = np.asarray(commanded_move, dtype=np.float64)
        return np.array([dz, dx, dy, drz])

    def reset(self) -> None:
        """Forget the belief: the next reading starts it afresh."""
        self._started = False

    def read(self, tactile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The GDNN's reading of one image, uint8 (H, W) or (1, H, W): (mean, std) of the state."""
        import torch

        from simshear_gym.models.gdnn_input import resize_images, to_input

        image = np.asarray(tactile)
        if image.ndim == 3 and image.shape[0] == 1:
            image = image[0]
        if image.ndim != 2 or image.dtype != np.uint8:
            raise ValueError(f"tactile must be a uint8 (H, W) or (1, H, W) image, got {image.dtype} {image.shape}")
        image = resize_images(image, self._size)
        with torch.inference_mode():
            mean, std = self._inference(to_input(torch.from_numpy(image)[None]))
            mean, std = self.model.decode(mean, std)
        size = len(self.state_variables)
        state_mean, state_std = np.zeros(size), np.full(size, UNREAD_STD)
        state_mean[self._present] = mean[0, self._index].numpy()
        state_std[self._present] = std[0, self._index].numpy()
        return state_mean, state_std

    def __call__(self, tactile: np.ndarray, commanded_move: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Fuse one image; ``commanded_move`` (dx, dy, dz mm, dRz deg; a subclass's own move) is the move sent since
        the last image.

        Returns the state estimate (mean, std).
        """
        reading_mean, reading_std = self.read(tactile)
        if not self.config.filtered:
            return reading_mean, reading_std
        if not self._started:
            self._filter.reset(reading_mean, np.diag(reading_std ** 2))
            self._started = True
            return self._filter.mean, self._filter.std
        delta = None if commanded_move is None else self._state_delta(commanded_move)
        return self._filter.step(delta, reading_mean, reading_std)


class SlotEstimates:
    """Mixin before a :class:`TactileEstimator` subclass (``class E(SlotEstimates, SomeEstimator)``): its filter
    state and the GDNN's reading of the last image (``last_reading``) in the four slots of the policies' ``estimate``
    observation (:func:`~simshear_gym.contract.estimate_features`), through ``slots(mean, std)``, at one GDNN pass
    per image. The edge and push estimators' (their states are not the tracking's four variables)."""

    last_reading: tuple[np.ndarray, np.ndarray] | None = None

    @staticmethod
    def slots(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def read(self, tactile: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reading = super().read(tactile)
        self.last_reading = self.slots(*reading)
        return reading

    def __call__(self, tactile: np.ndarray, commanded_move: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        return self.slots(*super().__call__(tactile, commanded_move))
