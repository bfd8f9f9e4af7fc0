"""The settings of a ``simshear train translator`` run (:mod:`simshear_gym.train.translator`), saved as its
``config.json``. Torch-free, so that the command builds its parser without torch."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from simshear_gym.train.runs import check_choice, check_run_knobs, run_lr

if TYPE_CHECKING:
    from simshear_gym.models.unet import UNetConfig

ARCHS = ("shpix2pix", "pix2pix")
"""Generator architectures: :data:`simshear_gym.models.translator.ARCHS`, written out here so that the command
needs no torch (``tests/test_train_loop.py`` checks that they agree)."""
DENSITY_POOL_PX = 8
"""Square (px at the image size) over which the density loss compares the mean brightness: about two marker
pitches at 128 px."""


@dataclass(frozen=True)
class TranslatorTrainConfig:
    """Everything a translator training run depends on (saved as ``config.json`` beside its outputs).

    The GPU knobs: ``lr_scaling`` (``none``, ``linear``, ``sqrt``) scales ``lr`` from :attr:`reference_batch`, the
    batch it was tuned at, to ``batch_size``, and ``warmup_epochs`` ramps the rate up linearly over that many
    epochs (:func:`~simshear_gym.train.runs.run_lr`); ``data_on_device`` (``auto``, ``on``, ``off``) keeps the
    training pairs on the training device, batches gathered there (``auto``: on a GPU); ``compile`` runs the
    generator through ``torch.compile`` (the eager generator, with one warning, where it cannot compile);
    ``tf32``: on CUDA, float32 matrix products and convolutions in TF32 (:mod:`simshear_gym.train.precision`).
    ``init_weights``: the generator starts from this translator's weights (its ``.pt``, the same architecture)
    instead of random ones: a fine-tuning run (its holdout split and batch order are still ``seed``'s)."""

    reference_batch: ClassVar[int] = 16
    """The batch size ``lr`` was tuned at (the default ``batch_size``): what ``lr_scaling`` scales from."""

    arch: str = "shpix2pix"
    paired_dirs: tuple[str, ...] = ()
    image_size_px: int = 128
    base_channels: int = 16
    max_channels: int = 128
    template: bool = True
    shear_decoder: bool = False
    decoder_scale: float = 1.0
    flow_px: int = 0
    epochs: int = 100
    batch_size: int = 16
    lr: float = 1e-3
    lr_schedule: str = "constant"
    l1_weight: float = 100.0
    density_weight: float = 0.0
    gan_weight: float = 0.0
    holdout: float = 0.05
    patience_epochs: int = 8
    max_minutes: float | None = None
    cap_minutes: float | None = None
    seed: int = 0
    threads: int = 2
    pose_weight: float = 0.0
    pose_net: str = ""
    pose_variables: tuple[str, ...] = ()
    teacher: str = ""
    init_weights: str = ""
    device: str = "auto"
    amp: bool = True
    lr_scaling: str = "none"
    warmup_epochs: float = 0.0
    data_on_device: str = "auto"
    compile: bool = False
    tf32: bool = True

    def __post_init__(self) -> None:
        check_choice("arch", self.arch, ARCHS)
        check_run_knobs(self)
        if self.shear_decoder and self.arch != "shpix2pix":
            raise ValueError("shear_decoder feeds the shear vector: it needs arch 'shpix2pix'")
        if not self.paired_dirs:
            raise ValueError("paired_dirs: give at least one paired set directory")
        if self.flow_px and (self.flow_px < 2 or self.flow_px & (self.flow_px - 1)):
            raise ValueError(f"flow_px must be a power of two >= 2 (a decoder level's size) or 0 (no warp), "
                             f"got {self.flow_px!r}")
        if self.epochs < 1 or self.batch_size < 2:
            raise ValueError(f"need epochs >= 1 and batch_size >= 2, got {self.epochs}, {self.batch_size}")
        if not 0.0 < self.holdout < 0.5:
            raise ValueError(f"holdout must be in (0, 0.5), got {self.holdout}")
        if self.lr <= 0 or self.l1_weight < 0 or self.gan_weight < 0 or self.density_weight < 0:
            raise ValueError("lr must be > 0 and the loss weights >= 0")
        if self.teacher and (self.pose_weight > 0 or self.density_weight > 0 or self.gan_weight > 0):
            raise ValueError("a distilled generator (teacher) learns the teacher's images with L1 alone: it takes no "
                             f"pose, density or GAN loss, got pose_weight {self.pose_weight}, density_weight "
                             f"{self.density_weight}, gan_weight {self.gan_weight}")
        if self.init_weights and self.teacher:
            raise ValueError("a distilled generator (teacher) starts from random weights: give init_weights or "
                             f"teacher, not both (got {self.init_weights!r}, {self.teacher!r})")
        if self.pose_weight < 0 or (self.pose_weight > 0) != bool(self.pose_net):
            raise ValueError(f"pose_weight {self.pose_weight} must be >= 0, and above 0 exactly when a pose_net "
                             f"(real-image GDNN) is given, got pose_net {self.pose_net!r}")

    def generator_config(self) -> UNetConfig:
        """The generator's :class:`~simshear_gym.models.unet.UNetConfig` (imports torch)."""
        from simshear_gym.models.unet import UNetConfig

        depth = int(math.log2(self.image_size_px))
        return UNetConfig(image_size_px=self.image_size_px, depth=depth, base_channels=self.base_channels,
                          max_channels=self.max_channels, shear_dim=6 if self.arch == "shpix2pix" else 0,
                          template=self.template, shear_decoder=self.shear_decoder,
                          decoder_scale=self.decoder_scale, flow_px=self.flow_px)

    def lr_at(self, progress: float) -> float:
        """Learning rate after ``progress`` (0..1) of the run (scaled to the batch and warmed up as asked)."""
        return run_lr(self, progress)
