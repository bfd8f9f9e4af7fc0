"""U-Net generator of pix2pix, with optional shear conditioning at the bottleneck (shPix2pix).

Tensors: input ``sim`` float (B, 1, H, W) in [0, 1] (the sim depth image, scaled by :data:`SIM_SCALE`), ``shear``
float (B, S) normalised shear vector (see :func:`simshear_gym.models.translator.normalise_shear`); output float
(B, 1, H, W) in [0, 1] (the real TacTip image). H = W = 2**k for any k >= ``depth``.

Architecture: ``depth`` encoder levels (4x4 conv, stride 2; batch norm after the first; LeakyReLU 0.2), the
bottleneck, and mirrored decoder levels (4x4 transposed conv, batch norm, ReLU, dropout on the deepest
levels) that concatenate the encoder's skip features. With ``shear_dim > 0`` the bottleneck is flattened,
concatenated with the shear vector, passed through a fully connected layer and ReLU, and reshaped back
(SimShear's shPix2pix); with ``shear_dim = 0`` it is the plain pix2pix U-Net. Optionally
(``shear_decoder=True``) the shear vector is also stacked as constant planes onto the input of every decoder level,
so the levels that place the markers see it directly instead of only through the 1x1 bottleneck.

Optionally (``template=True``) a learned image of the sensor at rest is stacked onto the input and a learned
per-pixel logit is added to the output. The marker layout is the same in every image, and a U-Net with
mostly-black sim inputs otherwise has to rebuild it from nothing at every pixel; with the template the encoder
sees where the markers are (convolutions alone cannot know position) and the decoder only learns how the image
deviates from the sensor at rest. :meth:`UNetGenerator.init_template` sets both from the mean real training
image and zeroes the last layer, so an untrained generator already outputs the mean image.

Optionally (``flow_px > 0``, with the template) the decoder's feature map at ``flow_px`` pixels square also gives
a displacement field (2 channels, pixels), upsampled bilinearly to the output size, that warps the at-rest logit
before the decoder's own output is added. Shear and deep contacts move the whole marker grid; drawn by
convolutions alone, a marker that moves has to be erased in one place and drawn in another, which an L1-trained
decoder that is unsure of the shift answers with black; the warp moves it instead. The field starts at zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class UNetConfig:
    """Generator settings.

    Attributes:
        image_size_px: H = W of inputs and outputs (a power of two, >= 2**depth).
        depth: number of down-sampling levels; the bottleneck is ``image_size_px / 2**depth`` pixels square.
        base_channels: channels of the first level; doubled per level up to ``max_channels``.
        max_channels: cap on the channels of deep levels.
        shear_dim: length of the shear vector fed at the bottleneck (0 = pix2pix, no shear).
        dropout: dropout probability on the ``dropout_levels`` deepest decoder levels.
        dropout_levels: how many of the deepest decoder levels use dropout.
        template: stack a learned at-rest sensor image onto the input and add a learned logit to the output.
        shear_decoder: also stack the shear vector as constant planes onto every decoder level's input
            (needs ``shear_dim > 0``).
        decoder_scale: decoder levels output this share of their mirrored encoder level's channels (1 = the
            symmetric pix2pix U-Net; 0.5 halves the decoder's cost, where most of the compute is).
        flow_px: size of the displacement field that warps the at-rest template (0 = no warp; needs
            ``template``; a power of two, the size of a decoder level's output before the last).
    """

    image_size_px: int = 128
    depth: int = 7
    base_channels: int = 16
    max_channels: int = 128
    shear_dim: int = 6
    dropout: float = 0.0
    dropout_levels: int = 3
    template: bool = True
    shear_decoder: bool = False
    decoder_scale: float = 1.0
    flow_px: int = 0

    def __post_init__(self) -> None:
        size = self.image_size_px
        if size < 2 or size & (size - 1):
            raise ValueError(f"image_size_px must be a power of two, got {size}")
        if not 1 <= self.depth or size >> self.depth < 1:
            raise ValueError(f"depth {self.depth} needs image_size_px >= 2**depth = {2 ** self.depth}, got {size}")
        if self.base_channels < 1 or self.max_channels < self.base_channels:
            raise ValueError(f"need 1 <= base_channels <= max_channels, got {self.base_channels}, {self.max_channels}")
        if self.shear_dim < 0:
            raise ValueError(f"shear_dim must be >= 0, got {self.shear_dim}")
        if self.shear_decoder and not self.shear_dim:
            raise ValueError("shear_decoder needs shear_dim > 0")
        if not 0.0 < self.decoder_scale <= 1.0:
            raise ValueError(f"decoder_scale must be in (0, 1], got {self.decoder_scale}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if self.flow_px:
            if not self.template:
                raise ValueError("flow_px warps the at-rest template: it needs template=True")
            flow = self.flow_px
            if flow & (flow - 1) or not size >> (self.depth - 1) <= flow <= size // 2:
                raise ValueError(f"flow_px must be a power of two from {size >> (self.depth - 1)} to {size // 2} "
                                 f"(the size of a decoder level's features), got {flow}")

    def channels(self) -> list[int]:
        return [min(self.base_channels * 2 ** level, self.max_channels) for level in range(self.depth)]

    def decoder_channels(self) -> list[int]:
        """Output channels of the decoder level mirroring each encoder level (level 0 outputs the image)."""
        return [1] + [max(1, round(c * self.decoder_scale)) for c in self.channels()[:-1]]

    @property
    def bottleneck_px(self) -> int:
        return self.image_size_px >> self.depth

    @property
    def flow_level(self) -> int:
        """Encoder level whose mirrored decoder level outputs the ``flow_px`` feature map."""
        return (self.image_size_px // self.flow_px).bit_length() - 1


class UNetGenerator(nn.Module):
    """pix2pix U-Net; shPix2pix when ``config.shear_dim > 0`` (see module docstring for shapes)."""

    def __init__(self, config: UNetConfig = UNetConfig()) -> None:
        super().__init__()
        self.config = config
        channels = config.channels()
        in_channels = 2 if config.template else 1
        if config.template:
            self.template = nn.Parameter(torch.zeros(1, 1, config.image_size_px, config.image_size_px))
            self.output_logit = nn.Parameter(torch.zeros(1, 1, config.image_size_px, config.image_size_px))
        self.encoder = nn.ModuleList()
        previous = in_channels
        for level, out in enumerate(channels):
            layers: list[nn.Module] = [nn.Conv2d(previous, out, 4, stride=2, padding=1, bias=level == 0)]
            if level > 0 and level < config.depth - 1:
                layers.append(nn.BatchNorm2d(out))
            layers.append(nn.LeakyReLU(0.2))
            self.encoder.append(nn.Sequential(*layers))
            previous = out
        if config.shear_dim:
            flat = channels[-1] * config.bottleneck_px ** 2
            self.bottleneck = nn.Sequential(nn.Linear(flat + config.shear_dim, flat), nn.ReLU())
        self.decoder = nn.ModuleList()
        decoder_out = config.decoder_channels()
        for level in reversed(range(config.depth)):
            deepest = level == config.depth - 1
            in_ch = (channels[level] if deepest else channels[level] + decoder_out[level + 1]) + (
                config.shear_dim if config.shear_decoder else 0)
            out = decoder_out[level]
            layers = [nn.ConvTranspose2d(in_ch, out, 4, stride=2, padding=1, bias=level == 0)]
            if level > 0:
                layers += [nn.BatchNorm2d(out), nn.ReLU()]
                if config.dropout and config.depth - 1 - level < config.dropout_levels:
                    layers.append(nn.Dropout(config.dropout))
            self.decoder.append(nn.Sequential(*layers))
        if config.flow_px:
            self.flow = nn.Conv2d(decoder_out[config.flow_level], 2, 3, padding=1)
            nn.init.zeros_(self.flow.weight)
            nn.init.zeros_(self.flow.bias)
            size = config.image_size_px
            ramp = (torch.arange(size, dtype=torch.float32) + 0.5) * (2.0 / size) - 1.0
            grid = torch.stack(torch.meshgrid(ramp, ramp, indexing="xy"), dim=-1)  # (H, W, 2): x then y
            self.register_buffer("identity_grid", grid.unsqueeze(0), persistent=False)

    def forward(self, sim: torch.Tensor, shear: torch.Tensor | None = None) -> torch.Tensor:
        config = self.config
        if sim.dim() != 4 or sim.shape[1:] != (1, config.image_size_px, config.image_size_px):
            raise ValueError(
                f"sim must be (B, 1, {config.image_size_px}, {config.image_size_px}), got {tuple(sim.shape)}"
            )
        if config.shear_dim and (shear is None or shear.shape != (sim.shape[0], config.shear_dim)):
            got = None if shear is None else tuple(shear.shape)
            raise ValueError(f"shear must be (B, {config.shear_dim}) for shPix2pix, got {got}")
        return self._run(sim, shear)

    def _run(self, sim: torch.Tensor, shear: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`forward` without its input checks."""
        config = self.config
        x = torch.cat([sim, self.template.expand(sim.shape[0], -1, -1, -1)], dim=1) if config.template else sim
        skips = []
        for layer in self.encoder:
            x = layer(x)
            skips.append(x)
        if config.shear_dim:
            flat = torch.cat([x.flatten(1), shear.to(x.dtype)], dim=1)
            x = self.bottleneck(flat).view_as(x)
        planes = shear.to(x.dtype)[:, :, None, None] if config.shear_decoder else None
        flow = None
        for index, layer in enumerate(self.decoder):
            parts = [x] if index == 0 else [x, skips[-1 - index]]
            if planes is not None:
                parts.append(planes.expand(-1, -1, x.shape[2], x.shape[3]))
            x = layer(torch.cat(parts, dim=1) if len(parts) > 1 else x)
            if config.flow_px and index == config.depth - 1 - config.flow_level:
                flow = self.flow(x)
        if config.flow_px:
            x = x + self._warped_template(flow)
        elif config.template:
            x = x + self.output_logit
        return torch.sigmoid(x)

    def _warped_template(self, flow_px: torch.Tensor) -> torch.Tensor:
        """The at-rest logit sampled at each output pixel displaced by ``flow_px`` (B, 2, h, w), in pixels."""
        size = self.config.image_size_px
        if flow_px.shape[-1] != size:
            flow_px = F.interpolate(flow_px, size=(size, size), mode="bilinear", align_corners=False)
        grid = self.identity_grid + flow_px.permute(0, 2, 3, 1) * (2.0 / size)
        template = self.output_logit.expand(flow_px.shape[0], -1, -1, -1)
        return F.grid_sample(template, grid, mode="bilinear", padding_mode="border", align_corners=False)

    def frozen(self) -> nn.Module:
        """A copy for CPU inference, called as ``copy(sim, shear)`` (``copy(sim)`` without shear): the same
        outputs as :meth:`forward` in eval mode, traced and frozen by TorchScript (batch norm folded into the
        convolutions, weights pre-packed; see :func:`~simshear_gym.models.torchscript.frozen_copy`), with the
        transposed convolutions that oneDNN runs slowly (tiny inputs, one output channel) computed as
        :class:`_ColumnTransposedConv`. Input shapes are not checked."""
        import copy

        from simshear_gym.models.torchscript import Unchecked, frozen_copy

        config = self.config
        example = (torch.zeros(1, 1, config.image_size_px, config.image_size_px),) + (
            (torch.zeros(1, config.shear_dim),) if config.shear_dim else ())
        twin = copy.deepcopy(self).float().eval()
        for index, level in enumerate(twin.decoder):
            upsample = level[0]
            if config.bottleneck_px << index <= _COLUMN_MAX_INPUT_PX or upsample.out_channels == 1:
                level[0] = _ColumnTransposedConv(upsample)
        return frozen_copy(Unchecked(twin), example)

    @torch.no_grad()
    def init_template(self, mean_real: torch.Tensor) -> None:
        """Start from the sensor at rest: ``mean_real`` (H, W) in [0, 1], the mean real training image."""
        if not self.config.template:
            raise ValueError("init_template needs a generator built with template=True")
        mean = mean_real.to(torch.float32).clamp(0.02, 0.98).view_as(self.template)
        self.template.copy_(mean)
        self.output_logit.copy_(torch.log(mean / (1.0 - mean)))
        last = self.decoder[-1][0]
        last.weight.zero_()
        if last.bias is not None:
            last.bias.zero_()


_COLUMN_MAX_INPUT_PX = 4
"""Decoder levels whose input is at most this many pixels square run as :class:`_ColumnTransposedConv`."""


class _ColumnTransposedConv(nn.Module):
    """The same map as a stride-2 ``nn.ConvTranspose2d`` (kernel k, padding p), computed as one matrix product
    (every input pixel's k x k patch of outputs) followed by col2im (``F.fold``, summing overlapping patches).

    Inference only: on a tiny input (the U-Net's deepest levels) or with one output channel (its last level),
    torch's transposed convolution spends most of its time outside the arithmetic; this form took 1.7-3.4x less
    time on those levels at batch 1 on our CPU (the whole surface generator 10-20 % less, side by side), and
    equals it up to float rounding (tests/test_translator.py)."""

    def __init__(self, upsample: nn.ConvTranspose2d) -> None:
        super().__init__()
        in_channels, out_channels, kernel, _ = upsample.weight.shape
        plain = upsample.groups == 1 and upsample.dilation == (1, 1) and not any(upsample.output_padding)
        if upsample.stride != (2, 2) or not plain:
            raise ValueError(f"_ColumnTransposedConv needs a plain stride-2 transposed convolution, got {upsample}")
        self.kernel, self.padding = kernel, upsample.padding[0]
        self.register_buffer("patches", upsample.weight.detach().reshape(in_channels, -1).t().contiguous())
        bias = upsample.bias.detach() if upsample.bias is not None else torch.zeros(out_channels)
        self.register_buffer("bias", bias.view(1, out_channels, 1, 1).clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        height, width = x.shape[2], x.shape[3]
        columns = torch.matmul(self.patches, x.flatten(2))  # (B, out_channels * k * k, H * W)
        size = (2 * height + self.kernel - 2 - 2 * self.padding, 2 * width + self.kernel - 2 - 2 * self.padding)
        return F.fold(columns, size, self.kernel, stride=2, padding=self.padding) + self.bias


@dataclass(frozen=True)
class PatchDiscriminatorConfig:
    """PatchGAN on (condition, image) pairs: 4x4 convs with ``channels``, spectral norm, LeakyReLU."""

    channels: tuple[int, ...] = (32, 64, 128, 256)

    def __post_init__(self) -> None:
        if not self.channels or min(self.channels) < 1:
            raise ValueError(f"channels must be positive, got {self.channels}")


class PatchDiscriminator(nn.Module):
    """Scores overlapping patches of (sim, image) pairs: input two (B, 1, H, W), output (B, 1, h, w) logits."""

    def __init__(self, config: PatchDiscriminatorConfig = PatchDiscriminatorConfig()) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        previous = 2
        for index, out in enumerate(config.channels):
            stride = 2 if index < len(config.channels) - 1 else 1
            layers += [nn.utils.parametrizations.spectral_norm(nn.Conv2d(previous, out, 4, stride, 1)),
                       nn.LeakyReLU(0.2)]
            previous = out
        layers.append(nn.utils.parametrizations.spectral_norm(nn.Conv2d(previous, 1, 4, 1, 1)))
        self.net = nn.Sequential(*layers)

    def forward(self, sim: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([sim, image], dim=1))
