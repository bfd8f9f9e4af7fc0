"""The settings of a ``simshear train posenet`` run (:mod:`simshear_gym.train.posenet`), saved as its
``config.json``. Torch-free, so that the command builds its parser without torch."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from simshear_gym.train.runs import check_choice, check_run_knobs

if TYPE_CHECKING:
    from simshear_gym.models.gdnn import GDNNConfig

SOURCES = ("real", "sim", "shpix2pix", "pix2pix", "env")
CONTACTS = ("surface", "edge", "env")


@dataclass(frozen=True)
class PosenetTrainConfig:
    """Everything a posenet training run depends on (saved as ``config.json`` beside its outputs).

    The architecture fields default to :class:`simshear_gym.models.gdnn.GDNNConfig`'s defaults (written out here so
    that the command needs no torch; ``tests/test_train_loop.py`` checks that they agree). The GPU knobs
    (``lr_scaling``, ``warmup_epochs``, ``data_on_device``, ``compile``, ``tf32``) are those of
    :class:`~simshear_gym.train.translator_config.TranslatorTrainConfig`, the GDNN in place of the generator (with
    ``data_on_device`` the augmentations run on the device too, their random draws from the run's CPU generators).
    """

    reference_batch: ClassVar[int] = 64
    """The batch size ``lr`` was tuned at (the default ``batch_size``): what ``lr_scaling`` scales from."""

    source: str = "real"
    contact: str = "surface"
    paired_dirs: tuple[str, ...] = ()
    image_size_px: int = 64
    conv_channels: tuple[int, ...] = (16, 32, 32, 64)
    conv_kernels: tuple[int, ...] = (5, 3, 3, 3)
    dense: tuple[int, ...] = (256,)
    dropout: float = 0.1
    beta: float = 0.5
    shift: float = 0.025
    blur_px: float = 0.0
    erase: float = 0.0
    epochs: int = 50
    batch_size: int = 64
    lr: float = 1e-3
    lr_schedule: str = "constant"
    holdout: float = 0.1
    patience_epochs: int = 8
    max_minutes: float | None = None
    cap_minutes: float | None = None
    seed: int = 0
    threads: int = 2
    translators: tuple[str, ...] = ()
    variables: str = ""
    device: str = "auto"
    amp: bool = True
    lr_scaling: str = "none"
    warmup_epochs: float = 0.0
    data_on_device: str = "auto"
    compile: bool = False
    tf32: bool = True

    def __post_init__(self) -> None:
        check_choice("source", self.source, SOURCES)
        check_choice("contact", self.contact, CONTACTS)
        if (self.source == "env") != (self.contact == "env"):
            raise ValueError(f"source 'env' (sets of simshear collect-env) goes with contact 'env' and only with it, "
                             f"got source {self.source!r}, contact {self.contact!r}")
        if not self.paired_dirs:
            raise ValueError("paired_dirs: give at least one paired set directory")
        if self.epochs < 1 or self.batch_size < 2:
            raise ValueError(f"need epochs >= 1 and batch_size >= 2, got {self.epochs}, {self.batch_size}")
        if not 0.0 < self.holdout < 0.5:
            raise ValueError(f"holdout must be in (0, 0.5), got {self.holdout}")
        if not 0.0 <= self.shift < 0.5:
            raise ValueError(f"shift must be in [0, 0.5) of the image size, got {self.shift}")
        if not 0.0 <= self.blur_px <= 4.0:
            raise ValueError(f"blur_px must be in [0, 4] px (a Gaussian std at the input size), got {self.blur_px}")
        if not 0.0 <= self.erase < 0.5:
            raise ValueError(f"erase must be in [0, 0.5) of the image size (a disc radius), got {self.erase}")
        if not 0.0 <= self.beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1], got {self.beta}")
        if self.lr <= 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        check_run_knobs(self)
        self.gdnn_config()  # validates the architecture

    def gdnn_config(self) -> GDNNConfig:
        """The network's :class:`~simshear_gym.models.gdnn.GDNNConfig` (imports torch)."""
        from simshear_gym.models.gdnn import GDNNConfig

        return GDNNConfig(image_size_px=self.image_size_px, conv_channels=self.conv_channels,
                          conv_kernels=self.conv_kernels, dense=self.dense, dropout=self.dropout,
                          variables=self.variables or self.contact)
