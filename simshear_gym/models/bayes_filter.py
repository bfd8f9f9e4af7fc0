"""Discriminative Bayesian filter in Kalman form, for smoothing the GDNN's pose-and-shear Gaussians over time.

The discriminative Kalman filter (DKF; Burkhart, Brandman, Franco, Hochberg and Harrison, Neural Computation
2020) with the robot's own commanded motion as the motion model. All quantities are in the variables' units
(mm, deg); V <= 6 variables; every covariance may be a full matrix.

State belief ``N(m, S)``. Motion model, driven by the commanded relative move ``u`` of the robot:

    z_t = A z_{t-1} + B u_t + w_t,    w_t ~ N(0, G),   G = diag(process_std^2)

Prediction:

    m- = A m + B u,    M = A S A' + G

Observation: the network is *discriminative*: it returns ``p(z_t | x_t) ~ N(f, Q)`` for an image ``x_t``, not a
likelihood ``p(x_t | z_t)``. It was trained on labels spread as ``p(z) ~ N(m0, S0)`` (the stationary prior), so
by Bayes ``p(x_t | z_t) ∝ N(z_t; f, Q) / N(z_t; m0, S0)`` and the posterior is

    p(z_t | x_1..t) ∝ N(z_t; f, Q) N(z_t; m-, M) / N(z_t; m0, S0)

a product of Gaussians; in information form

    S_t^-1 = M^-1 + Q^-1 - S0^-1
    m_t    = S_t (M^-1 m- + Q^-1 f - S0^-1 m0)

which with ``m0 = 0`` and ``m- = A m_{t-1}`` is the published DKF update. This module uses the equivalent
innovation form (expand ``M^-1 m- = S_t^-1 m- - (Q^-1 - S0^-1) m-``):

    m_t = m- + S_t [Q^-1 (f (-) m-) - S0^-1 (m0 (-) m-)]

where ``(-)`` is subtraction, wrapped to [-180, 180) deg on periodic variables, so an angle innovation across
+-180 deg is the short way round; ``m_t`` and ``m-`` are wrapped too.

Robust fallback: when ``Q^-1 - S0^-1`` is not positive definite the network claims to know less than the prior
in some direction, which no Gaussian posterior can; dividing out the prior would then *increase* the
uncertainty over the prediction. The update then ignores the prior and is the plain Kalman update with
observation ``f``, noise ``Q`` and H = I:

    S_t^-1 = M^-1 + Q^-1,    m_t = m- + S_t Q^-1 (f (-) m-)

(:attr:`DiscriminativeKalmanFilter.used_fallback` says which one ran.) Requiring ``Q^-1 - S0^-1 > 0`` is stricter
than requiring the bracket ``M^-1 + Q^-1 - S0^-1 > 0``, which it implies. With an infinite prior
(``prior_std = inf``, ``S0^-1 = 0``) the filter is the plain Kalman filter throughout; a periodic variable with a
uniform prior on the circle has ``S0^-1 = 0`` too (:meth:`BayesFilterConfig.from_output_specs`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from simshear_gym.data.labels import wrap_deg

_Matrix = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class BayesFilterConfig:
    """Filter settings; V = ``len(process_std)`` variables.

    Attributes:
        process_std: (V,) std of the motion-model noise per step, in each variable's unit (mm, deg).
        prior_std: (V,) std of the stationary prior S0 (the spread of the training labels); ``inf`` = no prior
            (plain Kalman for that variable). None: all ``inf``.
        prior_mean: (V,) mean m0 of the stationary prior. None: zeros.
        periodic: (V,) True for an angle in deg on the circle (wrapped to [-180, 180)). None: none periodic.
        transition: A, (V, V). None: identity.
        control: B, (V, C) mapping the commanded move (C,) into the state. None: identity (C = V).
        names: optional variable names, for error messages.
    """

    process_std: tuple[float, ...]
    prior_std: tuple[float, ...] | None = None
    prior_mean: tuple[float, ...] | None = None
    periodic: tuple[bool, ...] | None = None
    transition: _Matrix | None = None
    control: _Matrix | None = None
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        dim = len(self.process_std)
        if not 1 <= dim <= 6:
            raise ValueError(f"process_std needs 1 to 6 variables, got {dim}")
        if any(not (math.isfinite(s) and s >= 0.0) for s in self.process_std):
            raise ValueError(f"process_std must be finite and >= 0, got {self.process_std}")
        for field in ("prior_std", "prior_mean", "periodic", "names"):
            value = getattr(self, field)
            if value is not None and len(value) != dim:
                raise ValueError(f"{field} must have {dim} entries (one per variable), got {len(value)}")
        if self.prior_std is not None and any(not s > 0.0 for s in self.prior_std):
            raise ValueError(f"prior_std must be > 0 (inf for no prior), got {self.prior_std}")
        if self.prior_mean is not None and not all(math.isfinite(m) for m in self.prior_mean):
            raise ValueError(f"prior_mean must be finite, got {self.prior_mean}")
        if self.transition is not None and self.A.shape != (dim, dim):
            raise ValueError(f"transition A must be ({dim}, {dim}), got {self.A.shape}")
        if self.control is not None and (self.B.ndim != 2 or self.B.shape[0] != dim):
            raise ValueError(f"control B must be ({dim}, C), got {self.B.shape}")

    @property
    def dim(self) -> int:
        return len(self.process_std)

    @property
    def A(self) -> np.ndarray:
        return np.eye(self.dim) if self.transition is None else np.array(self.transition, dtype=np.float64)

    @property
    def B(self) -> np.ndarray:
        return np.eye(self.dim) if self.control is None else np.array(self.control, dtype=np.float64)

    @property
    def G(self) -> np.ndarray:
        """Process noise covariance (V, V)."""
        return np.diag(np.square(np.array(self.process_std, dtype=np.float64)))

    @property
    def prior_precision(self) -> np.ndarray:
        """S0^-1 (V, V); zero where the prior std is infinite."""
        std = np.full(self.dim, np.inf) if self.prior_std is None else np.array(self.prior_std, dtype=np.float64)
        return np.diag(1.0 / np.square(std))

    @property
    def m0(self) -> np.ndarray:
        return np.zeros(self.dim) if self.prior_mean is None else np.array(self.prior_mean, dtype=np.float64)

    @property
    def periodic_mask(self) -> np.ndarray:
        return np.zeros(self.dim, bool) if self.periodic is None else np.array(self.periodic, dtype=bool)

    @classmethod
    def from_output_specs(cls, specs: Sequence, process_std: Sequence[float], **overrides) -> BayesFilterConfig:
        """Config for GDNN variables (:class:`simshear_gym.models.gdnn.OutputSpec`: ``low, high, periodic``).

        The prior is the labels' collection range taken as uniform: mean at the centre, std
        ``(high - low) / sqrt(12)``; a periodic angle is uniform on the circle, so it gets no prior (``inf``).
        """
        settings = dict(
            process_std=tuple(float(s) for s in process_std),
            prior_std=tuple(math.inf if s.periodic else (s.high - s.low) / math.sqrt(12.0) for s in specs),
            prior_mean=tuple(0.0 if s.periodic else 0.5 * (s.low + s.high) for s in specs),
            periodic=tuple(bool(s.periodic) for s in specs),
            names=tuple(getattr(s, "name", f"var{i}") for i, s in enumerate(specs)),
        )
        settings.update(overrides)
        return cls(**settings)


class DiscriminativeKalmanFilter:
    """The filter of the module docstring. Call :meth:`reset` first, then :meth:`predict` / :meth:`update`."""

    def __init__(self, config: BayesFilterConfig) -> None:
        self.config = config
        self._A, self._B, self._G = config.A, config.B, config.G
        self._prior_precision, self._m0 = config.prior_precision, config.m0
        self._periodic = config.periodic_mask
        self._mean: np.ndarray | None = None
        self._cov: np.ndarray | None = None
        self.used_fallback = False
        """Whether the last :meth:`update` fell back to the plain Kalman update."""

    @property
    def mean(self) -> np.ndarray:
        """(V,) current mean, in the variables' units."""
        return self._state()[0].copy()

    @property
    def cov(self) -> np.ndarray:
        """(V, V) current covariance."""
        return self._state()[1].copy()

    @property
    def std(self) -> np.ndarray:
        """(V,) current marginal stds."""
        return np.sqrt(np.diag(self._state()[1]))

    def reset(self, mean: Sequence[float] | np.ndarray, cov: np.ndarray) -> None:
        """Start from belief ``N(mean, cov)``: mean (V,), cov (V, V) symmetric positive definite."""
        dim = self.config.dim
        mean = np.asarray(mean, dtype=np.float64)
        cov = np.asarray(cov, dtype=np.float64)
        if mean.shape != (dim,):
            raise ValueError(f"mean must be ({dim},), got {mean.shape}")
        if cov.shape != (dim, dim):
            raise ValueError(f"cov must be ({dim}, {dim}) (for stds use np.diag(std ** 2)), got {cov.shape}")
        if not _is_positive_definite(cov):
            raise ValueError("cov must be symmetric positive definite")
        self._mean = self._wrap(mean.copy())
        self._cov = 0.5 * (cov + cov.T)
        self.used_fallback = False

    def predict(self, commanded_delta: Sequence[float] | np.ndarray | None = None) -> None:
        """Motion step: ``m- = A m + B u``, ``M = A S A' + G``; ``u`` (C,) the commanded move (None: no move)."""
        mean, cov = self._state()
        predicted = self._A @ mean
        if commanded_delta is not None:
            u = np.asarray(commanded_delta, dtype=np.float64)
            if u.shape != (self._B.shape[1],):
                raise ValueError(f"commanded_delta must be ({self._B.shape[1]},), got {u.shape}")
            predicted = predicted + self._B @ u
        cov = self._A @ cov @ self._A.T + self._G
        self._mean, self._cov = self._wrap(predicted), 0.5 * (cov + cov.T)

    def update(self, measurement_mean: Sequence[float] | np.ndarray,
               measurement_std: Sequence[float] | np.ndarray | None = None, *,
               measurement_cov: np.ndarray | None = None) -> None:
        """Fuse the network's Gaussian ``N(f, Q)``: ``f`` (V,), and either stds (V,) or a full ``Q`` (V, V)."""
        mean, cov = self._state()
        dim = self.config.dim
        f = np.asarray(measurement_mean, dtype=np.float64)
        if f.shape != (dim,):
            raise ValueError(f"measurement_mean must be ({dim},), got {f.shape}")
        if (measurement_std is None) == (measurement_cov is None):
            raise ValueError("give exactly one of measurement_std (V,) and measurement_cov (V, V)")
        if measurement_std is not None:
            std = np.asarray(measurement_std, dtype=np.float64)
            if std.shape != (dim,) or not np.all(std > 0.0):
                raise ValueError(f"measurement_std must be ({dim},) and > 0, got {std}")
            q_precision = np.diag(1.0 / std ** 2)
        else:
            q = np.asarray(measurement_cov, dtype=np.float64)
            if q.shape != (dim, dim) or not _is_positive_definite(q):
                raise ValueError(f"measurement_cov must be ({dim}, {dim}) symmetric positive definite")
            q_precision = np.linalg.inv(0.5 * (q + q.T))
            q_precision = 0.5 * (q_precision + q_precision.T)
        m_precision = np.linalg.inv(cov)
        m_precision = 0.5 * (m_precision + m_precision.T)
        self.used_fallback = not _is_positive_definite(q_precision - self._prior_precision)
        prior_precision = np.zeros_like(q_precision) if self.used_fallback else self._prior_precision
        posterior = np.linalg.inv(m_precision + q_precision - prior_precision)
        posterior = 0.5 * (posterior + posterior.T)
        innovation = self._wrap(f - mean)
        prior_offset = self._wrap(self._m0 - mean)
        updated = mean + posterior @ (q_precision @ innovation - prior_precision @ prior_offset)
        self._mean, self._cov = self._wrap(updated), posterior

    def step(self, commanded_delta: Sequence[float] | np.ndarray | None,
             measurement_mean: Sequence[float] | np.ndarray,
             measurement_std: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`predict` then :meth:`update`; returns the new (mean (V,), std (V,))."""
        self.predict(commanded_delta)
        self.update(measurement_mean, measurement_std)
        return self.mean, self.std

    def _state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._mean is None or self._cov is None:
            raise RuntimeError("call reset(mean, cov) before predict/update")
        return self._mean, self._cov

    def _wrap(self, values: np.ndarray) -> np.ndarray:
        if self._periodic.any():
            values = values.copy()
            values[self._periodic] = wrap_deg(values[self._periodic])
        return values


def _is_positive_definite(matrix: np.ndarray) -> bool:
    if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(matrix).max()))):
        return False
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        return False
    return True
