"""Gaussian-density pose-and-shear network (GDNN): a CNN that predicts a Gaussian over pose and shear.

After Lloyd and Lepora's pose-and-shear tactile servoing: a TacTip image goes in, a mean and a standard deviation
per output come out, trained with the Gaussian negative log-likelihood (:func:`gaussian_nll`).

Variables (:data:`VARIABLE_SETS`): one named set per contact type, each variable an :class:`OutputSpec` with its
unit, collection range and whether it is periodic.

Encoding (:meth:`VariableSet.encode`): a non-periodic variable ``v`` with range ``[low, high]`` becomes
``2 (v - low) / (high - low) - 1`` (in [-1, 1] inside the range; values outside are not clipped). A periodic angle
``a`` becomes two encoded components ``(sin a, cos a)``, so the network never sees the jump at +-180 deg. The
encoded dimension D is the number of variables V plus one per periodic variable.

The network predicts an independent Gaussian per *encoded* component, so a periodic angle has a Gaussian over
its sine and one over its cosine. Decoding (:meth:`VariableSet.decode`) gives, per variable, a mean and a std in
the variable's unit:

- non-periodic: ``mean = low + (m + 1) (high - low) / 2``, ``std = s (high - low) / 2``;
- periodic: ``mean = atan2(m_sin, m_cos)`` wrapped to [-180, 180) deg, and the std by first-order propagation
  through atan2: with ``r2 = m_sin^2 + m_cos^2``,
  ``var = (m_cos^2 s_sin^2 + m_sin^2 s_cos^2) / r2^2`` [rad^2], converted to deg and capped at
  ``360 / sqrt(12)`` deg (the std of an angle uniform on the circle) - a short (sin, cos) mean means the network
  cannot tell the angle, and the propagation then diverges.

Why (sin, cos) with two Gaussians rather than an angle mean from atan2 with one scalar std: the loss stays the
plain Gaussian NLL over a D-vector with no special case, and the length of the predicted (sin, cos) mean carries
the angular uncertainty as well as the two stds.

Tensors: input float (B, 1, H, W) in [0, 1] (a uint8 TacTip image / 255), H = W = ``image_size_px``; output
``(mean, std)``, each float (B, D) in normalised units, ``std >= min_std > 0``.

Architecture (:class:`GDNNConfig`): per conv level a ``k x k`` convolution ('same' padding), batch norm, 2x2
max-pool and ELU (the map of ELU then max-pool, ELU being increasing, with the ELU on a quarter of the pixels: a
training step 10-17 % faster on our CPU, ``results/ablations/train_speed_pool_elu_*.json``); flatten; dense
layers with ELU and dropout; a linear mean head and a std head
``std = min_std + softplus(raw)`` (positive, smooth, bounded below so that the NLL cannot collapse).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
UNIFORM_ANGLE_STD_DEG = 360.0 / math.sqrt(12.0)
"""Std of an angle uniform on the circle: the cap on a decoded periodic std."""


@dataclass(frozen=True)
class OutputSpec:
    """One predicted variable.

    Attributes:
        name: variable name with its unit, e.g. ``"z_mm"``.
        unit: ``"mm"`` or ``"deg"``.
        low, high: collection range in ``unit``; it sets the [-1, 1] normalisation of a non-periodic variable.
        periodic: an angle on the circle (unit deg), encoded as (sin, cos); its range must span 360 deg.
        column: the ``targets.csv`` column the label comes from (see :mod:`simshear_gym.data.labels`).
    """

    name: str
    unit: str
    low: float
    high: float
    periodic: bool = False
    column: str = ""

    def __post_init__(self) -> None:
        if self.unit not in ("mm", "deg"):
            raise ValueError(f"OutputSpec {self.name}: unit must be 'mm' or 'deg', got {self.unit!r}")
        if not self.low < self.high:
            raise ValueError(f"OutputSpec {self.name}: need low < high, got {self.low}, {self.high}")
        if self.periodic and (self.unit != "deg" or not math.isclose(self.high - self.low, 360.0)):
            raise ValueError(f"OutputSpec {self.name}: a periodic variable is in deg and spans 360 deg, "
                             f"got {self.unit} [{self.low}, {self.high}]")

    @property
    def encoded_dim(self) -> int:
        return 2 if self.periodic else 1

    @property
    def half_range(self) -> float:
        return 0.5 * (self.high - self.low)

    @property
    def centre(self) -> float:
        return 0.5 * (self.low + self.high)


@dataclass(frozen=True)
class VariableSet:
    """An ordered set of :class:`OutputSpec`, with the label encoding and decoding of the module docstring."""

    name: str
    variables: tuple[OutputSpec, ...]

    def __post_init__(self) -> None:
        if not self.variables:
            raise ValueError(f"VariableSet {self.name}: needs at least one variable")
        names = [v.name for v in self.variables]
        if len(set(names)) != len(names):
            raise ValueError(f"VariableSet {self.name}: duplicate variable names {names}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.variables)

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(v.column for v in self.variables)

    @property
    def periodic(self) -> tuple[bool, ...]:
        return tuple(v.periodic for v in self.variables)

    @property
    def dim(self) -> int:
        """V: the number of variables."""
        return len(self.variables)

    @property
    def encoded_dim(self) -> int:
        """D: the network's output width (one extra per periodic variable)."""
        return sum(v.encoded_dim for v in self.variables)

    def encode(self, values: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Labels (B, V) in the variables' units -> float32 (B, D) normalised targets."""
        values = torch.as_tensor(values, dtype=torch.float32)
        if values.dim() != 2 or values.shape[1] != self.dim:
            raise ValueError(f"values must be (B, {self.dim}) for {self.names}, got {tuple(values.shape)}")
        columns = []
        for index, spec in enumerate(self.variables):
            value = values[:, index]
            if spec.periodic:
                angle = torch.deg2rad(value)
                columns += [torch.sin(angle), torch.cos(angle)]
            else:
                columns.append((value - spec.centre) / spec.half_range)
        return torch.stack(columns, dim=1)

    def decode(self, mean: torch.Tensor, std: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Network output (B, D) mean and std -> (mean (B, V), std (B, V)) in the variables' units (mm, deg)."""
        expected = (mean.shape[0], self.encoded_dim) if mean.dim() == 2 else None
        if expected is None or mean.shape != expected or std.shape != mean.shape:
            raise ValueError(f"mean and std must both be (B, {self.encoded_dim}) for {self.name}, "
                             f"got {tuple(mean.shape)} and {tuple(std.shape)}")
        means, stds = [], []
        column = 0
        for spec in self.variables:
            if spec.periodic:
                m_sin, m_cos = mean[:, column], mean[:, column + 1]
                s_sin, s_cos = std[:, column], std[:, column + 1]
                angle_deg = torch.rad2deg(torch.atan2(m_sin, m_cos))
                means.append(torch.remainder(angle_deg + 180.0, 360.0) - 180.0)
                r2 = (m_sin ** 2 + m_cos ** 2).clamp_min(1e-12)
                var_rad2 = (m_cos ** 2 * s_sin ** 2 + m_sin ** 2 * s_cos ** 2) / r2 ** 2
                stds.append(torch.rad2deg(var_rad2.sqrt()).clamp_max(UNIFORM_ANGLE_STD_DEG))
            else:
                means.append(spec.centre + mean[:, column] * spec.half_range)
                stds.append(std[:, column] * spec.half_range)
            column += spec.encoded_dim
        return torch.stack(means, dim=1), torch.stack(stds, dim=1)


# The sensor-frame shear is the work-frame move (up to 5 mm per axis) rotated by -Rz: up to 5*sqrt(2) mm.
_SHEAR = (
    OutputSpec("shear_x_mm", "mm", -7.5, 7.5, column="shear_sensor_x_mm"),
    OutputSpec("shear_y_mm", "mm", -7.5, 7.5, column="shear_sensor_y_mm"),
    OutputSpec("shear_rz_deg", "deg", -7.5, 7.5, column="shear_sensor_rz_deg"),
)
VARIABLE_SETS: dict[str, VariableSet] = {
    "surface": VariableSet("surface", (
        OutputSpec("z_mm", "mm", 2.0, 5.5, column="pose_3"),
        OutputSpec("rx_deg", "deg", -15.0, 15.0, column="pose_4"),
        OutputSpec("ry_deg", "deg", -15.0, 15.0, column="pose_5"),
    ) + _SHEAR),
    "edge": VariableSet("edge", (
        OutputSpec("y_mm", "mm", -6.0, 6.0, column="pose_2"),
        OutputSpec("z_mm", "mm", 3.0, 5.0, column="pose_3"),
        OutputSpec("edge_angle_deg", "deg", -180.0, 180.0, periodic=True, column="pose_6"),
    ) + _SHEAR),
    "mg400": VariableSet("mg400", (OutputSpec("z_mm", "mm", 2.0, 5.5, column="pose_3"),) + _SHEAR),
    "env": VariableSet("env", (
        OutputSpec("z_mm", "mm", 2.0, 8.0, column="z_mm"),
        OutputSpec("shear_x_mm", "mm", -7.5, 7.5, column="shear_x_mm"),
        OutputSpec("shear_y_mm", "mm", -7.5, 7.5, column="shear_y_mm"),
        OutputSpec("shear_rz_deg", "deg", -7.5, 7.5, column="shear_rz_deg"),
    )),
}
"""The named variable sets: ``surface`` and ``edge`` contacts, ``mg400`` (depth and shear only), and ``env``: an
env's true state as :mod:`simshear_gym.pipelines.env_collect` labels it (depth, shear x, y, shear Rz; the co-lift
env's Rz is the sensor's yaw error)."""


def variable_set(name: str) -> VariableSet:
    """A variable set of :data:`VARIABLE_SETS` by name, or one written inline (a sensor's own, from its data):
    ``"NAME:COLUMN:LOW:HIGH[:periodic],..."``, e.g. ``"z_mm:pose_3:2.0:5.0,rx_deg:pose_4:-15:15"`` (the unit is
    the name's suffix: ``_mm`` or ``_deg``). :func:`variable_spec` writes one."""
    if name in VARIABLE_SETS:
        return VARIABLE_SETS[name]
    if ":" not in name:
        raise ValueError(f"unknown variable set {name!r}; expected one of {sorted(VARIABLE_SETS)} or an inline "
                         "spec NAME:COLUMN:LOW:HIGH[:periodic],...")
    specs = []
    for item in name.split(","):
        parts = item.split(":")
        if len(parts) not in (4, 5) or (len(parts) == 5 and parts[4] != "periodic"):
            raise ValueError(f"variable spec {item!r}: expected NAME:COLUMN:LOW:HIGH[:periodic]")
        unit = parts[0].rpartition("_")[2]
        try:
            low, high = float(parts[2]), float(parts[3])
        except ValueError:
            raise ValueError(f"variable spec {item!r}: LOW and HIGH must be numbers") from None
        specs.append(OutputSpec(parts[0], unit, low, high, periodic=len(parts) == 5, column=parts[1]))
    return VariableSet("inline", tuple(specs))


def variable_spec(variables: VariableSet) -> str:
    """The inline form of a variable set (see :func:`variable_set`)."""
    return ",".join(f"{v.name}:{v.column}:{v.low:g}:{v.high:g}" + (":periodic" if v.periodic else "")
                    for v in variables.variables)


@dataclass(frozen=True)
class GDNNConfig:
    """GDNN settings.

    Attributes:
        image_size_px: H = W of the input; divisible by ``2 ** len(conv_channels)`` (one 2x2 pool per level).
        conv_channels: output channels of the conv levels.
        conv_kernels: odd kernel size per conv level.
        batch_norm: batch norm after each convolution.
        dense: widths of the dense layers after the flatten.
        dropout: dropout probability after each dense layer.
        variables: name of the variable set in :data:`VARIABLE_SETS`.
        min_std: lower bound of the predicted std, in normalised units.
        initial_std: the std the untrained network predicts (normalised units; the std head's bias), with the
            mean head initialised near zero (the range centre): training starts from "centre, +-half a range"
            instead of a random overconfident guess, whose NLL would be in the thousands.
    """

    image_size_px: int = 64
    conv_channels: tuple[int, ...] = (16, 32, 32, 64)
    conv_kernels: tuple[int, ...] = (5, 3, 3, 3)
    batch_norm: bool = True
    dense: tuple[int, ...] = (256,)
    dropout: float = 0.1
    variables: str = "surface"
    min_std: float = 0.01
    initial_std: float = 0.5

    def __post_init__(self) -> None:
        levels = len(self.conv_channels)
        if levels == 0 or len(self.conv_kernels) != levels:
            raise ValueError(f"conv_channels and conv_kernels need the same non-zero length, got "
                             f"{self.conv_channels} and {self.conv_kernels}")
        if min(self.conv_channels) < 1 or (self.dense and min(self.dense) < 1):
            raise ValueError(f"channels and dense widths must be positive, got {self.conv_channels}, {self.dense}")
        if any(k < 1 or k % 2 == 0 for k in self.conv_kernels):
            raise ValueError(f"conv_kernels must be odd and positive, got {self.conv_kernels}")
        if self.image_size_px < 2 ** levels or self.image_size_px % 2 ** levels:
            raise ValueError(f"image_size_px must be a positive multiple of 2**{levels} = {2 ** levels} "
                             f"({levels} pooling levels), got {self.image_size_px}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if not self.min_std > 0.0:
            raise ValueError(f"min_std must be > 0, got {self.min_std}")
        if not self.initial_std > self.min_std:
            raise ValueError(f"initial_std must be > min_std = {self.min_std}, got {self.initial_std}")
        variable_set(self.variables)

    @property
    def variable_set(self) -> VariableSet:
        return variable_set(self.variables)

    @property
    def flat_features(self) -> int:
        """Width of the flattened features after the last pool."""
        return self.conv_channels[-1] * (self.image_size_px >> len(self.conv_channels)) ** 2


class GDNN(nn.Module):
    """Image (B, 1, H, W) in [0, 1] -> (mean (B, D), std (B, D)) in normalised units; see module docstring."""

    def __init__(self, config: GDNNConfig = GDNNConfig()) -> None:
        super().__init__()
        self.config = config
        self.variables = config.variable_set
        layers: list[nn.Module] = []
        previous = 1
        for out, kernel in zip(config.conv_channels, config.conv_kernels):
            layers.append(nn.Conv2d(previous, out, kernel, padding=kernel // 2, bias=not config.batch_norm))
            if config.batch_norm:
                layers.append(nn.BatchNorm2d(out))
            layers += [nn.MaxPool2d(2), nn.ELU()]  # parameter-free: the state dict's keys are those of ELU first
            previous = out
        self.features = nn.Sequential(*layers)
        dense: list[nn.Module] = [nn.Flatten()]
        previous = config.flat_features
        for width in config.dense:
            dense += [nn.Linear(previous, width), nn.ELU(), nn.Dropout(config.dropout)]
            previous = width
        self.dense = nn.Sequential(*dense)
        self.mean_head = nn.Linear(previous, self.variables.encoded_dim)
        self.std_head = nn.Linear(previous, self.variables.encoded_dim)
        with torch.no_grad():
            for head in (self.mean_head, self.std_head):
                head.weight.mul_(0.1)
            self.mean_head.bias.zero_()
            # softplus^-1(initial_std - min_std)
            excess = torch.tensor(config.initial_std - config.min_std)
            self.std_head.bias.fill_(float(excess + torch.log(-torch.expm1(-excess))))

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        size = self.config.image_size_px
        if image.dim() != 4 or image.shape[1:] != (1, size, size):
            raise ValueError(f"image must be (B, 1, {size}, {size}) in [0, 1], got {tuple(image.shape)}")
        return self._run(image)

    def _run(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`forward` without its input check."""
        hidden = self.dense(self.features(image))
        return self.mean_head(hidden), self.config.min_std + F.softplus(self.std_head(hidden))

    def decode(self, mean: torch.Tensor, std: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, std) (B, D) of :meth:`forward` -> per-variable (mean, std) (B, V) in mm / deg."""
        return self.variables.decode(mean, std)

    def frozen(self) -> nn.Module:
        """A copy for CPU inference: the same outputs as :meth:`forward` in eval mode, traced and frozen by
        TorchScript (batch norm folded into the convolutions, weights pre-packed): about 3x faster at batch 1 on
        our 2-core CPU (2 ms instead of 6-7 ms); see :func:`~simshear_gym.models.torchscript.frozen_copy`.
        Input shapes are not checked: give (B, 1, H, W) in [0, 1]."""
        import copy

        from simshear_gym.models.torchscript import Unchecked, frozen_copy

        size = self.config.image_size_px
        return frozen_copy(Unchecked(copy.deepcopy(self).eval()), (torch.zeros(1, 1, size, size),))


def decode(mean: torch.Tensor, std: torch.Tensor,
           variables: str | VariableSet = "surface") -> tuple[torch.Tensor, torch.Tensor]:
    """(mean, std) (B, D) in normalised units -> (mean (B, V), std (B, V)) in mm / deg; see module docstring."""
    chosen = variable_set(variables) if isinstance(variables, str) else variables
    return chosen.decode(mean, std)


def beta_nll(mean: torch.Tensor, std: torch.Tensor, target: torch.Tensor, beta: float = 0.5) -> torch.Tensor:
    """The training loss: the Gaussian NLL with each component weighted by ``std ** (2 beta)`` (not differentiated).

    beta-NLL (Seitzer et al., ICLR 2022, "On the pitfalls of heteroscedastic uncertainty estimation"): with the
    plain NLL (beta = 0) the mean's gradient scales with ``1 / std^2``, so components the network is unsure of
    barely learn and the std inflates to cover them; beta = 1 gives the mean the plain squared-error gradient.
    The optimum of the std is the same for any beta (the weight is constant for the gradient), so the predicted
    std stays a calibrated std. Returns the batch mean of the per-sample weighted sums (a scalar).
    """
    if not mean.shape == std.shape == target.shape or mean.dim() != 2:
        raise ValueError(f"mean, std and target must all be (B, D), got {tuple(mean.shape)}, "
                         f"{tuple(std.shape)}, {tuple(target.shape)}")
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta}")
    per_component = _LOG_SQRT_2PI + torch.log(std) + 0.5 * ((target - mean) / std) ** 2
    if beta:
        per_component = per_component * std.detach() ** (2.0 * beta)
    return per_component.sum(dim=1).mean()


def gaussian_nll(mean: torch.Tensor, std: torch.Tensor, target: torch.Tensor,
                 reduction: str = "mean") -> torch.Tensor:
    """Negative log-likelihood of ``target`` under independent Gaussians, constant included.

    Per sample: ``sum_d [0.5 log(2 pi) + log std_d + (target_d - mean_d)^2 / (2 std_d^2)]`` (nats), the joint NLL
    of the D encoded components. (torch's ``GaussianNLLLoss`` drops the constant and averages over d as well.)

    Args:
        mean, std, target: (B, D); ``std > 0``.
        reduction: ``"mean"`` (average over the batch, a scalar) or ``"none"`` ((B,) per sample).
    """
    if not mean.shape == std.shape == target.shape or mean.dim() != 2:
        raise ValueError(f"mean, std and target must all be (B, D), got {tuple(mean.shape)}, "
                         f"{tuple(std.shape)}, {tuple(target.shape)}")
    if reduction not in ("mean", "none"):
        raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
    per_sample = (_LOG_SQRT_2PI + torch.log(std) + 0.5 * ((target - mean) / std) ** 2).sum(dim=1)
    return per_sample.mean() if reduction == "mean" else per_sample
