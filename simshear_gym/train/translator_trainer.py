"""The translator trainer of ``simshear train translator``: the paired rows in memory, and
:class:`TranslatorTrainer` (generator, optional discriminator, the losses) on the shared epoch loop
(:mod:`simshear_gym.train.loop`). The command, the objective and what the run directory holds:
:mod:`simshear_gym.train.translator`; the run's settings: :mod:`simshear_gym.train.translator_config`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from simshear_gym.data.labels import SHEAR_COLUMNS
from simshear_gym.data.paired import load_paired
from simshear_gym.models.device import cpu_state, resolve_device
from simshear_gym.models.translator import load_generator, normalise_shear, normalise_sim, save_generator
from simshear_gym.models.unet import PatchDiscriminator, PatchDiscriminatorConfig, UNetGenerator
from simshear_gym.train.distributed import Distributed
from simshear_gym.train.loop import EpochTrainer
from simshear_gym.train.pose_consistency import PoseConsistency
from simshear_gym.train.precision import Compiled, MixedPrecision, autocast_dtype, memory_format, use_tf32
from simshear_gym.train.runs import data_on_device, split_holdout
from simshear_gym.train.translator_config import DENSITY_POOL_PX, TranslatorTrainConfig


@dataclass(frozen=True, eq=False)
class PairedTensors:
    """In-memory pairs: sim uint8 (N, H, W), shear float32 (N, 6) sensor frame, real uint8 (N, H, W), and for
    the pose-consistency loss the rows' labels on its GDNN's normalised scale, float32 (N, D), or None."""

    sim: torch.Tensor
    shear: torch.Tensor
    real: torch.Tensor
    pose_labels: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.sim)

    def subset(self, index: np.ndarray) -> PairedTensors:
        index = torch.as_tensor(index)
        return PairedTensors(self.sim[index], self.shear[index], self.real[index],
                             None if self.pose_labels is None else self.pose_labels[index])

    def batch(self, index: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Model-ready float tensors of the rows ``index`` (where the pairs are): sim, shear, real, pose labels (or
        None)."""
        index = torch.as_tensor(index).to(self.sim.device, non_blocking=True)
        real = self.real[index].unsqueeze(1).to(torch.float32) / 255.0
        labels = None if self.pose_labels is None else self.pose_labels[index]
        return normalise_sim(self.sim[index]), self.shear_input(index), real, labels

    def shear_input(self, index: torch.Tensor) -> torch.Tensor:
        """The generator's shear input of the rows ``index`` (normalised here)."""
        return normalise_shear(self.shear[index].numpy())


@dataclass(frozen=True, eq=False)
class DevicePairs(PairedTensors):
    """Training pairs held on the training device (``data_on_device``): sim uint8 (N, H, W), shear float32 (N, 6)
    already normalised (:func:`~simshear_gym.models.translator.normalise_shear`), real uint8 (N, H, W), pose labels
    float32 (N, D) or None. A batch is gathered there by index: the same float tensors
    :meth:`PairedTensors.batch` builds on the CPU, with no copy of images per step."""

    @classmethod
    def of(cls, pairs: PairedTensors, device: torch.device) -> DevicePairs:
        return cls(pairs.sim.to(device), normalise_shear(pairs.shear.numpy()).to(device), pairs.real.to(device),
                   None if pairs.pose_labels is None else pairs.pose_labels.to(device))

    def shear_input(self, index: torch.Tensor) -> torch.Tensor:
        return self.shear[index]


def load_pairs(paired_dirs: tuple[str, ...] | list[str], data: str | None = None,
               pose: PoseConsistency | None = None) -> PairedTensors:
    """Load replayed paired sets (sim render, shear, real image; the labels ``pose`` reads, if given) into memory."""
    sims, shears, reals, labels = [], [], [], []
    for directory in paired_dirs:
        paired, real = load_paired(directory, data)
        if real is None:
            raise ValueError(f"{directory}: a random-contact set has no real images; translators train on replays")
        sims.append(paired.load_images())
        shears.append(paired.targets[list(SHEAR_COLUMNS)].to_numpy(np.float32))
        reals.append(real.load_images())
        if pose is not None:
            labels.append(pose.encoded_labels(paired.targets))
        if sims[-1].shape != reals[-1].shape:
            raise ValueError(f"{directory}: sim images {sims[-1].shape[1:]} and real images "
                             f"{reals[-1].shape[1:]} differ in size")
    return PairedTensors(torch.from_numpy(np.concatenate(sims)), torch.from_numpy(np.concatenate(shears)),
                         torch.from_numpy(np.concatenate(reals)), torch.cat(labels) if pose is not None else None)


def teacher_targets(pairs: PairedTensors, teacher: str | Path, arch: str, batch: int = 64) -> PairedTensors:
    """``pairs`` with the real images replaced by a teacher translator's uint8 images of the same rows (sim
    render and shear, through the translator's contract as the envs run it), for distillation. The teacher must
    be of the student's architecture kind (shPix2pix or pix2pix) and image size."""
    from simshear_gym.models.translator import Translator, translate_rows

    teacher = Path(teacher)
    if not teacher.is_file():
        raise FileNotFoundError(f"teacher translator {teacher} not found (expected a .pt of simshear ship "
                                f"translator)")
    generator, card = load_generator(teacher)
    teacher_arch = "shpix2pix" if generator.config.shear_dim else "pix2pix"
    if teacher_arch != arch or generator.config.image_size_px != pairs.sim.shape[-1]:
        raise ValueError(f"teacher {teacher} is a {teacher_arch} of {generator.config.image_size_px} px; the student "
                         f"is a {arch} of {pairs.sim.shape[-1]} px: they must agree")
    translator = Translator(generator.float().eval(), card)
    images = translate_rows(translator, pairs.sim.numpy(), pairs.shear.numpy(), batch)
    return PairedTensors(pairs.sim, pairs.shear, torch.from_numpy(images), pairs.pose_labels)


def start_from(generator: UNetGenerator, weights: str | Path) -> None:
    """Load a translator's generator weights (``weights``, its ``.pt``) into ``generator``, which must be the same
    architecture: the start of a fine-tuning run (``init_weights``)."""
    start, _ = load_generator(weights)
    if start.config != generator.config:
        differ = {name: (value, getattr(start.config, name)) for name, value in asdict(generator.config).items()
                  if getattr(start.config, name) != value}
        raise ValueError(f"init_weights {weights}: its generator is not the architecture this run trains "
                         f"(this run, the file: {differ})")
    generator.load_state_dict(start.state_dict())


class TranslatorTrainer(EpochTrainer):
    """Owns the models, optimisers and run directory of one training run; :meth:`fit` trains it.

    The pairs stay on the CPU and each batch moves to ``config.device`` (under torchrun: the process's device, and
    its share of the batch), or with ``config.data_on_device`` (by default on a GPU) the training pairs live on the
    device (:class:`DevicePairs`) and each batch is gathered there, the same rows in the same order. The networks
    run in ``channels_last`` (faster on the CPU too) and on CUDA, with ``config.amp``, their forward passes in
    mixed precision (the losses in float32), with ``config.tf32`` their float32 products in TF32; with
    ``config.compile`` the generator runs through ``torch.compile`` (one process only). A fine-tuning run's start
    (``config.init_weights``) is read relative to ``files_root`` (the pipeline's run folder; None: the working
    directory)."""

    metric = "l1"  # history: train_l1, holdout_l1 (mean absolute pixel error, images in [0, 1])

    def __init__(self, config: TranslatorTrainConfig, run_dir: Path, pairs: PairedTensors,
                 pose: PoseConsistency | None = None, distributed: Distributed | None = None,
                 files_root: Path | None = None) -> None:
        if (pose is not None) != (config.pose_weight > 0) or (pose is not None and pairs.pose_labels is None):
            raise ValueError("a pose-consistency run (pose_weight > 0) needs its PoseConsistency and pairs loaded "
                             "with it (load_pairs(..., pose=...)); a run without one takes neither")
        super().__init__(config, run_dir, distributed)
        self.device = distributed.device if distributed is not None else resolve_device(config.device)
        self.memory_format = memory_format(self.device)
        self.precision = MixedPrecision(self.device, autocast_dtype(self.device, config.amp))
        use_tf32(self.device, config.tf32)
        self.pose = pose.to(self.device) if pose is not None else None
        torch.manual_seed(config.seed)
        if config.teacher:  # distillation: the teacher's images are the targets (and the holdout's)
            pairs = teacher_targets(pairs, config.teacher, config.arch)
        train_rows, holdout_rows = split_holdout(len(pairs), config.holdout, config.seed)
        self.train_pairs, self.holdout_pairs = pairs.subset(train_rows), pairs.subset(holdout_rows)
        self.generator = UNetGenerator(config.generator_config())
        if config.init_weights:
            start_from(self.generator, Path(files_root or ".") / config.init_weights)
        elif config.template:
            self.generator.init_template(self.train_pairs.real.to(torch.float32).mean(0) / 255.0)
        self.discriminator = PatchDiscriminator(PatchDiscriminatorConfig()) if config.gan_weight > 0 else None
        self.generator.to(self.device, memory_format=self.memory_format)
        if self.discriminator is not None:
            self.discriminator.to(self.device, memory_format=self.memory_format)
        # what trains: the networks, or under torchrun their DistributedDataParallel wrappers (the checkpoint is
        # written from the networks themselves: no "module." prefix)
        self.net_g = distributed.wrap(self.generator) if distributed is not None else self.generator
        self.net_d = (distributed.wrap(self.discriminator) if distributed is not None and self.discriminator
                      is not None else self.discriminator)
        self.forward_g = Compiled(self.net_g, config.compile and distributed is None, "the generator")
        self.device_pairs = (DevicePairs.of(self.train_pairs, self.device)
                             if data_on_device(config.data_on_device, self.device.type) else None)
        self.opt_g = torch.optim.Adam(self.generator.parameters(), lr=config.lr, betas=(0.5, 0.999))
        self.opt_d = (torch.optim.Adam(self.discriminator.parameters(), lr=config.lr, betas=(0.5, 0.999))
                      if self.discriminator is not None else None)
        self.batch_rng = np.random.default_rng(config.seed + 1)

    # ------------------------------------------------------------------------------------------- persistence
    def trainer_state(self) -> dict:
        return {
            "generator": {"config": asdict(self.generator.config), "state_dict": cpu_state(self.generator)},
            "opt_g": self.opt_g.state_dict(),
            "discriminator": cpu_state(self.discriminator) if self.discriminator is not None else None,
            "opt_d": self.opt_d.state_dict() if self.opt_d is not None else None,
            "batch_rng": self.batch_rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
        }

    def load_trainer_state(self, state: dict) -> None:
        self.generator.load_state_dict(state["generator"]["state_dict"])
        self.opt_g.load_state_dict(state["opt_g"])
        if self.discriminator is not None:
            self.discriminator.load_state_dict(state["discriminator"])
            self.opt_d.load_state_dict(state["opt_d"])
        self.batch_rng.bit_generator.state = state["batch_rng"]
        torch.set_rng_state(state["torch_rng"])

    # ---------------------------------------------------------------------------------------------- training
    def _on_device(self, sim: torch.Tensor, shear: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """A CPU batch's sim images (B, 1, H, W) and shear (B, 6) on the device: the generator's inputs (the
        shear None for a pix2pix generator)."""
        sim = sim.to(self.device, memory_format=self.memory_format, non_blocking=True)
        return sim, shear.to(self.device, non_blocking=True) if self.generator.config.shear_dim else None

    def holdout_l1(self) -> float:
        """Mean absolute error (images in [0, 1]) of the generated held-out images against the real ones (the
        teacher's, when distilling)."""
        self.generator.eval()
        total = 0.0
        with torch.inference_mode():
            for start in range(0, len(self.holdout_pairs), 64):
                sim, shear, real, _ = self.holdout_pairs.batch(
                    np.arange(start, min(start + 64, len(self.holdout_pairs))))
                total += (self.generator(*self._on_device(sim, shear)) - real.to(self.device)
                          ).abs().mean(dim=(1, 2, 3)).sum().item()
        self.generator.train()
        return total / len(self.holdout_pairs)

    def train_step(self, sim: torch.Tensor, shear: torch.Tensor, real: torch.Tensor,
                   pose_labels: torch.Tensor | None = None) -> dict[str, float]:
        """One step of the discriminator (if any) and the generator on a batch (on the CPU or already on the
        device); returns the losses."""
        config = self.config
        precision = self.precision
        sim, shear_in = self._on_device(sim, shear)
        real = real.to(self.device, memory_format=self.memory_format, non_blocking=True)
        with precision.autocast():
            fake = self.forward_g(sim, shear_in)
        fake = fake.float()  # the losses in float32
        losses = {}
        if self.discriminator is not None:
            self.opt_d.zero_grad(set_to_none=True)
            with precision.autocast():
                d_real, d_fake = self.net_d(sim, real), self.net_d(sim, fake.detach())
            loss_d = 0.5 * ((d_real.float() - 1) ** 2).mean() + 0.5 * (d_fake.float() ** 2).mean()
            precision.backward(loss_d)
            precision.step(self.opt_d)
            losses["d"] = loss_d.item()
        self.opt_g.zero_grad(set_to_none=True)
        l1 = (fake - real).abs().mean()
        loss = config.l1_weight * l1
        if config.density_weight > 0:
            density = (F.avg_pool2d(fake, DENSITY_POOL_PX) - F.avg_pool2d(real, DENSITY_POOL_PX)).abs().mean()
            loss = loss + config.density_weight * density
            losses["density"] = density.item()
        if self.discriminator is not None:
            # the discriminator itself, not its DDP wrapper: its own gradients from this pass are zeroed before its
            # next step, so there is nothing to average (the generator's flow back through `fake`)
            with precision.autocast():
                judged = self.discriminator(sim, fake)
            gan = ((judged.float() - 1) ** 2).mean()
            loss = loss + config.gan_weight * gan
            losses["g_gan"] = gan.item()
        if self.pose is not None:
            pose_loss = self.pose.loss(fake, pose_labels.to(self.device))
            loss = loss + config.pose_weight * pose_loss
            losses["pose"] = pose_loss.item()
        precision.backward(loss)
        precision.step(self.opt_g)
        precision.update()
        losses["l1"] = l1.item()
        return losses

    # -------------------------------------------------------------------------------- the epoch loop's hooks
    def epoch_batches(self) -> list[np.ndarray]:
        order = self.batch_rng.permutation(len(self.train_pairs))
        size = self.config.batch_size
        return [order[i:i + size] for i in range(0, len(order) - 1, size)]  # no last batch of one row

    def optimisers(self) -> list[torch.optim.Optimizer]:
        return [self.opt_g] + ([self.opt_d] if self.opt_d is not None else [])

    def train_mode(self) -> None:
        self.generator.train()

    def train_batch(self, index: np.ndarray) -> dict[str, float]:
        rows = self.device_pairs if self.device_pairs is not None else self.train_pairs
        return self.train_step(*rows.batch(index[self.local_rows(len(index))]))

    holdout_metric = holdout_l1

    def save_best(self, path: Path, card: dict) -> None:
        save_generator(path, self.generator, half=False, card=card)

    def log_epoch(self, writer) -> None:
        """An image grid of six held-out rows: sim (brightened) | generated | real."""
        sim, shear, real, _ = self.holdout_pairs.batch(np.arange(min(6, len(self.holdout_pairs))))
        self.generator.eval()
        with torch.inference_mode():
            fake = self.generator(*self._on_device(sim, shear)).cpu()
        self.generator.train()
        grid = torch.cat([torch.cat([(s * 4).clamp(0, 1), f, r], dim=2) for s, f, r in zip(sim, fake, real)], dim=2)
        writer.add_image("holdout/sim_generated_real", grid, self.step)


def export_run(run_dir: Path, path: Path, card: dict | None = None) -> Path:
    """Ship a run's best generator as fp16 weights, with its training config and ``card`` in the file."""
    generator, best = load_generator(Path(run_dir) / "best.pt")
    config = json.loads((Path(run_dir) / "config.json").read_text())
    return save_generator(path, generator, card={"best": best, "train_config": config, **(card or {})})
