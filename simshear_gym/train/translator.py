"""Train the sim-to-real translator: shPix2pix (shear at the bottleneck) or the pix2pix baseline.

``simshear train translator --arch shpix2pix --paired DIR [DIR ...] --out RUN_DIR`` trains on paired sets
(:mod:`simshear_gym.data.paired`). A share of the training rows (``--holdout``) is held out for early stopping
on L1, so the real validation sets stay unseen until ``simshear evaluate translation``. Objective: ``l1_weight *
L1 + gan_weight * least-squares GAN`` (``--gan-weight 0``: L1 alone, as the public shPix2pix code trained), plus
``density_weight *`` the L1 of both images averaged over 8 px squares (``--density-weight``): plain L1 rewards
black where a marker's place is uncertain (its median), which blanks the markers of deep, sheared contacts; the
pooled term asks for the right amount of marker there instead; plus
``pose_weight *`` the pose-consistency loss of a frozen real-image GDNN (``--pose-net``,
:mod:`simshear_gym.train.pose_consistency`) when ``--pose-weight`` is above 0.
Learning rate: constant, or ``--lr-schedule cosine``: ``lr * (1 + cos(pi * p)) / 2`` where ``p`` is the share of
the time budget (``--max-minutes``) used so far, or of the epochs when there is no budget, so a budgeted run ends
at a small learning rate whenever its time runs out.

Run directory: ``config.json``, ``history.json`` (per epoch: wall time, train and holdout L1), tensorboard logs
under ``tb/`` (scalars, image grids sim | generated | real), ``checkpoint.pt`` (written atomically after every
epoch and at the time budget; ``--resume`` continues from it) and ``best.pt`` (the generator with the lowest
holdout L1).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from simshear_gym.data.labels import SHEAR_COLUMNS
from simshear_gym.data.paired import load_paired
from simshear_gym.io import write_json
from simshear_gym.models.translator import (
    ARCHS,
    normalise_shear,
    normalise_sim,
    save_generator,
)
from simshear_gym.models.unet import (
    PatchDiscriminator,
    PatchDiscriminatorConfig,
    UNetConfig,
    UNetGenerator,
)
from simshear_gym.train.pose_consistency import PoseConsistency
from simshear_gym.train.runs import (
    LR_SCHEDULES,
    check_same_settings,
    run_progress,
    save_checkpoint,
    scheduled_lr,
    split_holdout,
)

DENSITY_POOL_PX = 8
"""Square (px at the image size) over which the density loss compares the mean brightness: about two marker
pitches at 128 px."""
_RESUME_FREE = ("epochs", "max_minutes", "patience_epochs")  # settings a resumed run may change


@dataclass(frozen=True)
class TranslatorTrainConfig:
    """Everything a translator training run depends on (saved as ``config.json`` beside its outputs)."""

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
    seed: int = 0
    threads: int = 2
    pose_weight: float = 0.0
    pose_net: str = ""
    pose_variables: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.arch not in ARCHS:
            raise ValueError(f"arch must be one of {ARCHS}, got {self.arch!r}")
        scheduled_lr(self.lr, self.lr_schedule, 0.0)  # validates the schedule
        if self.shear_decoder and self.arch != "shpix2pix":
            raise ValueError("shear_decoder feeds the shear vector: it needs arch 'shpix2pix'")
        if not self.paired_dirs:
            raise ValueError("paired_dirs: give at least one paired set directory")
        if self.epochs < 1 or self.batch_size < 2:
            raise ValueError(f"need epochs >= 1 and batch_size >= 2, got {self.epochs}, {self.batch_size}")
        if not 0.0 < self.holdout < 0.5:
            raise ValueError(f"holdout must be in (0, 0.5), got {self.holdout}")
        if self.lr <= 0 or self.l1_weight < 0 or self.gan_weight < 0 or self.density_weight < 0:
            raise ValueError("lr must be > 0 and the loss weights >= 0")
        if self.pose_weight < 0 or (self.pose_weight > 0) != bool(self.pose_net):
            raise ValueError(f"pose_weight {self.pose_weight} must be >= 0, and above 0 exactly when a pose_net "
                             f"(real-image GDNN) is given, got pose_net {self.pose_net!r}")

    def generator_config(self) -> UNetConfig:
        depth = int(math.log2(self.image_size_px))
        return UNetConfig(image_size_px=self.image_size_px, depth=depth, base_channels=self.base_channels,
                          max_channels=self.max_channels, shear_dim=6 if self.arch == "shpix2pix" else 0,
                          template=self.template, shear_decoder=self.shear_decoder,
                          decoder_scale=self.decoder_scale, flow_px=self.flow_px)

    def lr_at(self, progress: float) -> float:
        """Learning rate after ``progress`` (0..1) of the run."""
        return scheduled_lr(self.lr, self.lr_schedule, progress)


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

    def subset(self, index: np.ndarray) -> "PairedTensors":
        index = torch.as_tensor(index)
        return PairedTensors(self.sim[index], self.shear[index], self.real[index],
                             None if self.pose_labels is None else self.pose_labels[index])

    def batch(self, index: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Model-ready float tensors of the rows ``index``: sim, shear, real, pose labels (or None)."""
        index = torch.as_tensor(index)
        real = self.real[index].unsqueeze(1).to(torch.float32) / 255.0
        labels = None if self.pose_labels is None else self.pose_labels[index]
        return normalise_sim(self.sim[index]), normalise_shear(self.shear[index].numpy()), real, labels


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


class TranslatorTrainer:
    """Owns the models, optimisers and run directory of one training run."""

    def __init__(self, config: TranslatorTrainConfig, run_dir: Path, pairs: PairedTensors,
                 pose: PoseConsistency | None = None) -> None:
        if (pose is not None) != (config.pose_weight > 0) or (pose is not None and pairs.pose_labels is None):
            raise ValueError("a pose-consistency run (pose_weight > 0) needs its PoseConsistency and pairs loaded "
                             "with it (load_pairs(..., pose=...)); a run without one takes neither")
        self.config = config
        self.pose = pose
        self.run_dir = Path(run_dir)
        torch.manual_seed(config.seed)
        train_rows, holdout_rows = split_holdout(len(pairs), config.holdout, config.seed)
        self.train_pairs, self.holdout_pairs = pairs.subset(train_rows), pairs.subset(holdout_rows)
        self.generator = UNetGenerator(config.generator_config())
        if config.template:
            self.generator.init_template(self.train_pairs.real.to(torch.float32).mean(0) / 255.0)
        self.discriminator = PatchDiscriminator(PatchDiscriminatorConfig()) if config.gan_weight > 0 else None
        self.opt_g = torch.optim.Adam(self.generator.parameters(), lr=config.lr, betas=(0.5, 0.999))
        self.opt_d = (torch.optim.Adam(self.discriminator.parameters(), lr=config.lr, betas=(0.5, 0.999))
                      if self.discriminator is not None else None)
        self.epoch = 0
        self.step = 0
        self.best_holdout_l1 = float("inf")
        self.epochs_since_best = 0
        self.elapsed_s = 0.0
        self.history: list[dict] = []
        self.batch_rng = np.random.default_rng(config.seed + 1)

    # ------------------------------------------------------------------------------------------- persistence
    def state(self) -> dict:
        return {
            "config": asdict(self.config), "epoch": self.epoch, "step": self.step,
            "best_holdout_l1": self.best_holdout_l1, "epochs_since_best": self.epochs_since_best,
            "elapsed_s": self.elapsed_s, "history": self.history,
            "generator": {"config": asdict(self.generator.config), "state_dict": self.generator.state_dict()},
            "opt_g": self.opt_g.state_dict(),
            "discriminator": self.discriminator.state_dict() if self.discriminator is not None else None,
            "opt_d": self.opt_d.state_dict() if self.opt_d is not None else None,
            "batch_rng": self.batch_rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
        }

    def save_checkpoint(self) -> None:
        save_checkpoint(self.run_dir, self.state(), self.config, self.history)

    def resume(self) -> bool:
        """Continue from ``checkpoint.pt`` if there is one; returns whether it did."""
        path = self.run_dir / "checkpoint.pt"
        if not path.is_file():
            return False
        state = torch.load(path, map_location="cpu", weights_only=False)
        check_same_settings(path, state["config"], self.config, _RESUME_FREE)
        self.generator.load_state_dict(state["generator"]["state_dict"])
        self.opt_g.load_state_dict(state["opt_g"])
        if self.discriminator is not None:
            self.discriminator.load_state_dict(state["discriminator"])
            self.opt_d.load_state_dict(state["opt_d"])
        self.epoch, self.step = state["epoch"], state["step"]
        self.best_holdout_l1, self.epochs_since_best = state["best_holdout_l1"], state["epochs_since_best"]
        self.elapsed_s, self.history = state["elapsed_s"], state["history"]
        self.batch_rng.bit_generator.state = state["batch_rng"]
        torch.set_rng_state(state["torch_rng"])
        return True

    # ---------------------------------------------------------------------------------------------- training
    def holdout_l1(self) -> float:
        self.generator.eval()
        total = 0.0
        with torch.inference_mode():
            for start in range(0, len(self.holdout_pairs), 64):
                sim, shear, real, _ = self.holdout_pairs.batch(
                    np.arange(start, min(start + 64, len(self.holdout_pairs))))
                total += (self.generator(sim, shear if self.generator.config.shear_dim else None) - real
                          ).abs().mean(dim=(1, 2, 3)).sum().item()
        self.generator.train()
        return total / len(self.holdout_pairs)

    def train_step(self, sim: torch.Tensor, shear: torch.Tensor, real: torch.Tensor,
                   pose_labels: torch.Tensor | None = None) -> dict[str, float]:
        config = self.config
        shear_in = shear if self.generator.config.shear_dim else None
        fake = self.generator(sim, shear_in)
        losses = {}
        if self.discriminator is not None:
            self.opt_d.zero_grad(set_to_none=True)
            d_real, d_fake = self.discriminator(sim, real), self.discriminator(sim, fake.detach())
            loss_d = 0.5 * ((d_real - 1) ** 2).mean() + 0.5 * (d_fake ** 2).mean()
            loss_d.backward()
            self.opt_d.step()
            losses["d"] = loss_d.item()
        self.opt_g.zero_grad(set_to_none=True)
        l1 = (fake - real).abs().mean()
        loss = config.l1_weight * l1
        if config.density_weight > 0:
            density = (F.avg_pool2d(fake, DENSITY_POOL_PX) - F.avg_pool2d(real, DENSITY_POOL_PX)).abs().mean()
            loss = loss + config.density_weight * density
            losses["density"] = density.item()
        if self.discriminator is not None:
            gan = ((self.discriminator(sim, fake) - 1) ** 2).mean()
            loss = loss + config.gan_weight * gan
            losses["g_gan"] = gan.item()
        if self.pose is not None:
            pose_loss = self.pose.loss(fake, pose_labels)
            loss = loss + config.pose_weight * pose_loss
            losses["pose"] = pose_loss.item()
        loss.backward()
        self.opt_g.step()
        losses["l1"] = l1.item()
        return losses

    def fit(self, progress: bool = True) -> dict:
        """Train until the epochs, the patience or the time budget run out; returns a summary."""
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm

        config = self.config
        torch.set_num_threads(config.threads)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        write_json(self.run_dir / "config.json", asdict(config))
        writer = SummaryWriter(str(self.run_dir / "tb"))
        budget_s = config.max_minutes * 60.0 if config.max_minutes else float("inf")
        stop_reason = "epochs"
        self.generator.train()
        try:
            while self.epoch < config.epochs:
                started = time.perf_counter() - self.elapsed_s
                order = self.batch_rng.permutation(len(self.train_pairs))
                batches = [order[i:i + config.batch_size] for i in range(0, len(order) - 1, config.batch_size)]
                running = []
                out_of_time = False
                for index in tqdm(batches, desc=f"epoch {self.epoch + 1}/{config.epochs}", disable=not progress,
                                  leave=False):
                    if len(index) < 2:
                        continue
                    self._set_lr(budget_s, len(batches))
                    losses = self.train_step(*self.train_pairs.batch(index))
                    running.append(losses["l1"])
                    self.step += 1
                    if self.step % 20 == 0:
                        for name, value in losses.items():
                            writer.add_scalar(f"train/{name}", value, self.step)
                        writer.add_scalar("train/lr", self.opt_g.param_groups[0]["lr"], self.step)
                    self.elapsed_s = time.perf_counter() - started
                    if self.elapsed_s > budget_s:
                        out_of_time = True
                        break
                self.epoch += 0 if out_of_time else 1
                holdout = self.holdout_l1()
                self.elapsed_s = time.perf_counter() - started
                record = {"epoch": self.epoch, "partial_epoch": out_of_time, "step": self.step,
                          "elapsed_s": round(self.elapsed_s, 1), "train_l1": float(np.mean(running)) if running else None,
                          "holdout_l1": holdout}
                self.history.append(record)
                writer.add_scalar("holdout/l1", holdout, self.step)
                writer.add_scalar("holdout/l1_vs_minutes", holdout, int(self.elapsed_s / 60))
                self._log_images(writer)
                if holdout < self.best_holdout_l1:
                    self.best_holdout_l1, self.epochs_since_best = holdout, 0
                    save_generator(self.run_dir / "best.pt", self.generator, half=False,
                                   card={"holdout_l1": holdout, "epoch": self.epoch, "elapsed_s": self.elapsed_s})
                else:
                    self.epochs_since_best += 1
                self.save_checkpoint()
                if out_of_time:
                    stop_reason = "time budget"
                    break
                if self.epochs_since_best >= config.patience_epochs:
                    stop_reason = "early stopping"
                    break
        finally:
            writer.close()
        return {"epochs": self.epoch, "steps": self.step, "elapsed_s": round(self.elapsed_s, 1),
                "best_holdout_l1": self.best_holdout_l1, "stopped_by": stop_reason}

    def _set_lr(self, budget_s: float, batches_per_epoch: int) -> None:
        config = self.config
        lr = config.lr_at(run_progress(self.elapsed_s, budget_s, self.step, config.epochs * batches_per_epoch))
        for optimiser in (self.opt_g, self.opt_d):
            for group in optimiser.param_groups if optimiser is not None else ():
                group["lr"] = lr

    def _log_images(self, writer) -> None:
        sim, shear, real, _ = self.holdout_pairs.batch(np.arange(min(6, len(self.holdout_pairs))))
        self.generator.eval()
        with torch.inference_mode():
            fake = self.generator(sim, shear if self.generator.config.shear_dim else None)
        self.generator.train()
        grid = torch.cat([torch.cat([(s * 4).clamp(0, 1), f, r], dim=2) for s, f, r in zip(sim, fake, real)], dim=2)
        writer.add_image("holdout/sim_generated_real", grid, self.step)


# --------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arch", choices=ARCHS, default="shpix2pix")
    parser.add_argument("--paired", nargs="+", required=True, help="paired set directories (simshear collect)")
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--data", default=None, help="data root of the real images")
    defaults = TranslatorTrainConfig(paired_dirs=("x",))
    parser.add_argument("--lr-schedule", choices=LR_SCHEDULES, default=defaults.lr_schedule,
                        help="cosine: decay to 0 over the time budget (or the epochs)")
    parser.add_argument("--shear-decoder", action="store_true",
                        help="shpix2pix: also feed the shear vector to every decoder level")
    parser.add_argument("--flow", dest="flow_px", type=int, default=defaults.flow_px,
                        help="warp the at-rest template by a displacement field of this many pixels square "
                             "(0 = no warp)")
    for name in ("image_size_px", "base_channels", "max_channels", "decoder_scale", "epochs", "batch_size", "lr", "l1_weight",
                 "density_weight", "gan_weight", "holdout", "patience_epochs", "seed", "threads"):
        value = getattr(defaults, name)
        parser.add_argument(f"--{name.replace('_px', '').replace('_', '-')}", dest=name, type=type(value),
                            default=value, help=f"default {value}")
    parser.add_argument("--max-minutes", type=float, default=None, help="stop after this much training time")
    parser.add_argument("--pose-net", default="", help="pose-consistency loss: a GDNN trained on the real images "
                        "(best.pt of simshear train posenet --source real) of the same contact type")
    parser.add_argument("--pose-weight", type=float, default=0.0,
                        help="weight of the pose-consistency loss (needs --pose-net; default 0: off)")
    parser.add_argument("--pose-variables", nargs="+", default=[], metavar="NAME",
                        help="pose-consistency loss on these of the GDNN's variables only (default: all)")
    parser.add_argument("--no-template", action="store_true", help="no learned at-rest template input")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    parser.add_argument("--export", type=Path, default=None, help="write the best generator (fp16) here")


def run(args: argparse.Namespace) -> int:
    config = TranslatorTrainConfig(
        arch=args.arch, paired_dirs=tuple(str(d) for d in args.paired), image_size_px=args.image_size_px,
        base_channels=args.base_channels, max_channels=args.max_channels, template=not args.no_template,
        shear_decoder=args.shear_decoder, decoder_scale=args.decoder_scale, flow_px=args.flow_px,
        epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
        lr_schedule=args.lr_schedule, l1_weight=args.l1_weight, density_weight=args.density_weight,
        gan_weight=args.gan_weight, holdout=args.holdout, patience_epochs=args.patience_epochs,
        max_minutes=args.max_minutes, seed=args.seed, threads=args.threads, pose_weight=args.pose_weight,
        pose_net=args.pose_net, pose_variables=tuple(args.pose_variables),
    )
    pose = PoseConsistency(config.pose_net, config.pose_variables) if config.pose_weight > 0 else None
    pairs = load_pairs(config.paired_dirs, args.data, pose)
    trainer = TranslatorTrainer(config, args.out, pairs, pose)
    if args.resume and trainer.resume():
        print(f"resumed from {args.out / 'checkpoint.pt'} at epoch {trainer.epoch}")
    elif (args.out / "checkpoint.pt").exists():
        raise ValueError(f"{args.out / 'checkpoint.pt'} exists: pass --resume to continue it or use a new --out")
    summary = trainer.fit()
    print(json.dumps(summary))
    if args.export:
        export_run(args.out, args.export)
        print(f"exported {args.export}")
    return 0


def export_run(run_dir: Path, path: Path, card: dict | None = None) -> Path:
    """Ship a run's best generator as fp16 weights, with its training config and ``card`` in the file."""
    from simshear_gym.models.translator import load_generator

    generator, best = load_generator(Path(run_dir) / "best.pt")
    config = json.loads((Path(run_dir) / "config.json").read_text())
    return save_generator(path, generator, card={"best": best, "train_config": config, **(card or {})})
