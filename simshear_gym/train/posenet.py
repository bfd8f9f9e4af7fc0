"""Train the pose-and-shear GDNN (:mod:`simshear_gym.models.gdnn`) on one of four image sources.

``simshear train posenet --source SOURCE --contact surface|edge --paired DIR [DIR ...] --out RUN_DIR`` trains
on the rows of paired sets (:mod:`simshear_gym.data.paired`), labels from their columns (each variable's
``OutputSpec.column``), images from the source:

- ``real``: the real images the paired sets replay (the real-to-real reference);
- ``sim``: the paired sets' own sim renders;
- ``shpix2pix`` / ``pix2pix``: the sim renders (and shear) through the shipped translator of that architecture
  and contact type, generated once at the start (cached on disk per set and generator) and kept in memory; with
  ``--translators W [W ...]`` through each of those generator weights instead, every training row then shown
  through a randomly drawn one each time it is drawn (the holdout through the first), so the network cannot lean
  on one generator's mistakes (a file listed k times is drawn k times as often, loaded and translated once);
- ``env``: sets written by ``simshear collect-env`` (:mod:`simshear_gym.pipelines.env_collect`), the images an env
  emitted (already translated) with its true state; with ``--contact env`` (its variable set).

Images enter the network as uint8 / 255, resized to ``--image-size`` (64 px by default: at 128 px an epoch
costs 20x more on a 2-core CPU for no measured gain in pose error). Loss: beta-NLL
(:func:`simshear_gym.models.gdnn.beta_nll`, ``--beta``, default 0.5; 0 is the plain Gaussian NLL), which keeps the
mean learning where the network is unsure; early stopping and reports use the plain NLL. Augmentation: every
training image is shifted by a random offset of up to ``shift`` (a share of the image size, default 2.5 %) in x
and y, edges repeated; with ``--blur B`` each is then blurred by a Gaussian of std drawn uniformly from [0, B] px
(at the input size), so that the network cannot lean on how sharp the markers are (a generator's images are
softer than the real ones); with ``--erase R`` a black disc of radius up to R (a share of the image size) is then
blanked in each, so that it cannot lean on the dark patches a generator leaves where it cannot place the markers
of a deep, sheared contact. A share of the rows (``--holdout``) is held out for early stopping on the Gaussian
NLL; the real validation set stays unseen until ``simshear evaluate posenet``.

Run directory: ``config.json``, ``history.json`` (per epoch: wall time, train and holdout NLL), tensorboard logs
under ``tb/``, ``checkpoint.pt`` (written atomically after every epoch; ``--resume`` continues from it) and
``best.pt`` (the GDNN with the lowest holdout NLL; :func:`simshear_gym.models.posenet_io.load_posenet`).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from simshear_gym.io import write_json
from simshear_gym.models.gdnn import (
    GDNN,
    GDNNConfig,
    VariableSet,
    beta_nll,
    gaussian_nll,
    variable_set,
)
from simshear_gym.models.gdnn_input import label_matrix, resize_images, to_input
from simshear_gym.models.posenet_io import save_posenet
from simshear_gym.models.translator import ARCHS
from simshear_gym.train.runs import (
    LR_SCHEDULES,
    check_same_settings,
    run_progress,
    save_checkpoint,
    scheduled_lr,
    split_holdout,
)

SOURCES = ("real", "sim", "shpix2pix", "pix2pix", "env")
CONTACTS = ("surface", "edge", "env")
_RESUME_FREE = ("epochs", "max_minutes", "patience_epochs", "threads")


@dataclass(frozen=True)
class PosenetTrainConfig:
    """Everything a posenet training run depends on (saved as ``config.json`` beside its outputs)."""

    source: str = "real"
    contact: str = "surface"
    paired_dirs: tuple[str, ...] = ()
    image_size_px: int = GDNNConfig.image_size_px
    conv_channels: tuple[int, ...] = GDNNConfig.conv_channels
    conv_kernels: tuple[int, ...] = GDNNConfig.conv_kernels
    dense: tuple[int, ...] = GDNNConfig.dense
    dropout: float = GDNNConfig.dropout
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
    seed: int = 0
    threads: int = 2
    translators: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        if self.contact not in CONTACTS:
            raise ValueError(f"contact must be one of {CONTACTS}, got {self.contact!r}")
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
        scheduled_lr(self.lr, self.lr_schedule, 0.0)  # validates the schedule
        self.gdnn_config()  # validates the architecture

    def gdnn_config(self) -> GDNNConfig:
        return GDNNConfig(image_size_px=self.image_size_px, conv_channels=self.conv_channels,
                          conv_kernels=self.conv_kernels, dense=self.dense, dropout=self.dropout,
                          variables=self.contact)


# ------------------------------------------------------------------------------------------------------ data
@dataclass(frozen=True, eq=False)
class LabelledImages:
    """In-memory training rows: images uint8 (N, H, W), or (N, K, H, W) for K renditions of each row (one per
    translator), and labels float32 (N, V) in the variables' units."""

    images: torch.Tensor
    labels: torch.Tensor

    def __post_init__(self) -> None:
        if self.images.dim() not in (3, 4) or self.labels.dim() != 2 or len(self.images) != len(self.labels):
            raise ValueError(f"need images (N, H, W) or (N, K, H, W) and labels (N, V), got "
                             f"{tuple(self.images.shape)} and {tuple(self.labels.shape)}")

    def __len__(self) -> int:
        return len(self.images)

    def subset(self, index: np.ndarray) -> "LabelledImages":
        index = torch.as_tensor(index)
        return LabelledImages(self.images[index], self.labels[index])

    @property
    def first(self) -> torch.Tensor:
        """(N, H, W): each row's first rendition."""
        return self.images if self.images.dim() == 3 else self.images[:, 0]

    def drawn(self, rng: np.random.Generator) -> torch.Tensor:
        """(N, H, W): a randomly drawn rendition of each row (the images themselves when there is one)."""
        if self.images.dim() == 3:
            return self.images
        views = torch.from_numpy(rng.integers(0, self.images.shape[1], len(self)))
        return self.images[torch.arange(len(self)), views]


def load_source(source: str, contact: str, paired_dirs: tuple[str, ...] | list[str], data: str | None = None,
                image_size_px: int = 128, batch: int = 64,
                translators: tuple[str, ...] | list[str] = ()) -> LabelledImages:
    """Images of ``source`` (see module docstring) and labels of the paired sets' rows; ``translators``: generator
    weights to use instead of the shipped one (several give (N, K, H, W) renditions)."""
    from simshear_gym.data.labels import SHEAR_COLUMNS
    from simshear_gym.data.paired import load_paired

    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    variables = variable_set(contact)
    if source == "env":
        return _load_env_sets(paired_dirs, variables, image_size_px)
    translated = source in ARCHS  # the sim renders through translators of that architecture
    if translators and not translated:
        raise ValueError(f"translators are generator weights for a translator source, not {source!r}")
    distinct = list(dict.fromkeys(translators))  # a file listed k times is loaded and translated once, drawn k x
    slots = [distinct.index(path) for path in translators] or [0]  # each listed generator's entry in `chosen`
    chosen = []
    if translated:
        from simshear_gym.models.translator import Translator, load_shipped

        chosen = [Translator.load(path) for path in distinct] or [load_shipped(source, contact)]
        wants_shear = source == "shpix2pix"
        for path, translator in zip(distinct, chosen):
            if bool(translator.generator.config.shear_dim) != wants_shear:
                raise ValueError(f"translator {path}: a {'pix2pix' if wants_shear else 'shpix2pix'} generator, "
                                 f"but --source {source}")
    digests = [weights_digest(translator) for translator in chosen]  # the translation cache's keys
    images, labels = [], []
    for directory in paired_dirs:
        paired, real = load_paired(directory, data)
        if paired.meta.get("contact") not in (None, contact):
            raise ValueError(f"{directory}: a {paired.meta['contact']!r} paired set, but --contact {contact}")
        if source == "real":
            if real is None:
                raise ValueError(f"{directory}: a random-contact set has no real images; use --source sim or a "
                                 "translator source, or a replayed set")
            stack = real.load_images()
        else:
            stack = paired.load_images()
            if chosen:
                shear = paired.targets[list(SHEAR_COLUMNS)].to_numpy(np.float32)
                rendered = [translated_rows(translator, digest, paired, stack, shear, image_size_px, batch)
                            for translator, digest in zip(chosen, digests)]
                views = [rendered[slot] for slot in slots]
                stack = views[0] if len(views) == 1 else np.stack(views, axis=1)
        images.append(resize_images(stack, image_size_px))
        labels.append(label_matrix(paired.targets, variables))
    return LabelledImages(torch.from_numpy(np.concatenate(images)), torch.from_numpy(np.concatenate(labels)))


def weights_digest(translator) -> str:
    """A hash of a translator's generator weights."""
    import hashlib

    digest = hashlib.sha1()
    for name, tensor in translator.generator.state_dict().items():
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().numpy().tobytes())
    return digest.hexdigest()


def translated_rows(translator, weights: str, paired, sim_uint8: np.ndarray, shear: np.ndarray, image_size_px: int,
                    batch: int = 64) -> np.ndarray:
    """uint8 (N, size, size): a paired set's sim renders through ``translator`` (its :func:`weights_digest`
    ``weights``), resized; cached on disk (keyed by the set's files and the weights), since translating a set
    through several generators costs minutes on a CPU."""
    import hashlib

    from simshear_gym.data.paths import cache_dir
    from simshear_gym.io import atomic_write

    key = hashlib.sha1(f"{paired.cache_key()}|{weights}|{image_size_px}".encode()).hexdigest()[:16]
    cache_file = cache_dir() / f"translated-{key}.npy"
    if cache_file.exists():
        cached = np.load(cache_file)
        if cached.shape == (len(sim_uint8), image_size_px, image_size_px):
            return cached
    images = resize_images(np.concatenate([translator(sim_uint8[i:i + batch], shear[i:i + batch])
                                           for i in range(0, len(sim_uint8), batch)]), image_size_px)
    atomic_write(cache_file, lambda path: np.save(path, images), suffix=".npy")
    return images


def _load_env_sets(directories, variables: VariableSet, image_size_px: int) -> LabelledImages:
    from simshear_gym.data.tactile_set import read_set

    images, labels = [], []
    for directory in directories:
        found = read_set(directory, required_columns=variables.columns)
        if found.meta.get("kind") != "env":
            raise ValueError(f"{directory}: not a set of simshear collect-env (meta.json kind "
                             f"{found.meta.get('kind')!r}, expected 'env')")
        images.append(resize_images(found.load_images(), image_size_px))
        labels.append(label_matrix(found.targets, variables))
    return LabelledImages(torch.from_numpy(np.concatenate(images)), torch.from_numpy(np.concatenate(labels)))


def random_shift(images: torch.Tensor, max_share: float, generator: torch.Generator) -> torch.Tensor:
    """Shift each image of (B, 1, H, W) by up to ``max_share`` of its size in x and y, edge pixels repeated."""
    if max_share <= 0:
        return images
    batch = images.shape[0]
    offset = (torch.rand(batch, 2, generator=generator) * 2 - 1) * (2 * max_share)  # grid units span 2
    theta = torch.zeros(batch, 2, 3)
    theta[:, 0, 0] = theta[:, 1, 1] = 1.0
    theta[:, :, 2] = offset
    grid = F.affine_grid(theta, list(images.shape), align_corners=False)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)


def random_blur(images: torch.Tensor, max_sigma_px: float, generator: torch.Generator) -> torch.Tensor:
    """Blur each image of (B, 1, H, W) with a Gaussian of std drawn uniformly from [0, ``max_sigma_px``] px,
    edge pixels repeated; std 0 leaves an image unchanged."""
    if max_sigma_px <= 0:
        return images
    batch = images.shape[0]
    radius = int(np.ceil(3 * max_sigma_px))
    sigma = torch.rand(batch, 1, generator=generator) * max_sigma_px
    offsets = torch.arange(-radius, radius + 1, dtype=torch.float32)
    weights = torch.where(sigma > 0, torch.exp(-0.5 * (offsets / sigma.clamp_min(1e-6)) ** 2),
                          (offsets == 0).to(torch.float32).expand(batch, -1))
    weights = weights / weights.sum(dim=1, keepdim=True)
    padded = F.pad(images.transpose(0, 1), (radius, radius, radius, radius), mode="replicate")  # (1, B, H', W')
    rows = F.conv2d(padded, weights.view(batch, 1, 1, -1), groups=batch)
    both = F.conv2d(rows, weights.view(batch, 1, -1, 1), groups=batch)
    return both.transpose(0, 1)


def random_erase(images: torch.Tensor, max_radius_share: float, generator: torch.Generator) -> torch.Tensor:
    """Black out one disc in each image of (B, 1, H, W): radius uniform in [0, ``max_radius_share``] of the image
    size, centre uniform over the middle half of the image (where contacts are)."""
    if max_radius_share <= 0:
        return images
    batch, _, height, width = images.shape
    radius = torch.rand(batch, 1, 1, generator=generator) * max_radius_share
    centre = 0.25 + 0.5 * torch.rand(batch, 2, 1, 1, generator=generator)
    y = (torch.arange(height, dtype=torch.float32).view(1, -1, 1) + 0.5) / height
    x = (torch.arange(width, dtype=torch.float32).view(1, 1, -1) + 0.5) / width
    inside = (y - centre[:, 0]) ** 2 + (x - centre[:, 1]) ** 2 < radius ** 2
    return images.masked_fill(inside.unsqueeze(1), 0.0)


# -------------------------------------------------------------------------------------------------- training
class PosenetTrainer:
    """Owns the model, optimiser and run directory of one posenet training run."""

    def __init__(self, config: PosenetTrainConfig, run_dir: Path, data: LabelledImages) -> None:
        self.config = config
        self.run_dir = Path(run_dir)
        torch.manual_seed(config.seed)
        data = LabelledImages(torch.as_tensor(resize_images(data.images.numpy(), config.image_size_px)),
                              data.labels)
        train_rows, holdout_rows = split_holdout(len(data), config.holdout, config.seed)
        self.train_data, self.holdout_data = data.subset(train_rows), data.subset(holdout_rows)
        self.model = GDNN(config.gdnn_config())
        self.variables = self.model.variables
        self.optimiser = torch.optim.Adam(self.model.parameters(), lr=config.lr)
        self.epoch = 0
        self.step = 0
        self.best_holdout_nll = float("inf")
        self.epochs_since_best = 0
        self.elapsed_s = 0.0
        self.history: list[dict] = []
        self.batch_rng = np.random.default_rng(config.seed + 1)
        self.shift_rng = torch.Generator().manual_seed(config.seed + 2)

    # ------------------------------------------------------------------------------------------- persistence
    def state(self) -> dict:
        return {
            "config": asdict(self.config), "epoch": self.epoch, "step": self.step,
            "best_holdout_nll": self.best_holdout_nll, "epochs_since_best": self.epochs_since_best,
            "elapsed_s": self.elapsed_s, "history": self.history,
            "model": {"config": asdict(self.model.config), "state_dict": self.model.state_dict()},
            "optimiser": self.optimiser.state_dict(),
            "batch_rng": self.batch_rng.bit_generator.state, "shift_rng": self.shift_rng.get_state(),
            "torch_rng": torch.get_rng_state(),
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
        self.model.load_state_dict(state["model"]["state_dict"])
        self.optimiser.load_state_dict(state["optimiser"])
        self.epoch, self.step = state["epoch"], state["step"]
        self.best_holdout_nll, self.epochs_since_best = state["best_holdout_nll"], state["epochs_since_best"]
        self.elapsed_s, self.history = state["elapsed_s"], state["history"]
        self.batch_rng.bit_generator.state = state["batch_rng"]
        self.shift_rng.set_state(state["shift_rng"])
        torch.set_rng_state(state["torch_rng"])
        return True

    # ---------------------------------------------------------------------------------------------- training
    def holdout_nll(self) -> float:
        """Mean Gaussian NLL (nats per row, over the encoded components) of the held-out rows, unaugmented."""
        self.model.eval()
        total = 0.0
        with torch.inference_mode():
            for start in range(0, len(self.holdout_data), 64):
                part = self.holdout_data.subset(np.arange(start, min(start + 64, len(self.holdout_data))))
                mean, std = self.model(to_input(part.first))
                total += gaussian_nll(mean, std, self.variables.encode(part.labels), reduction="none").sum().item()
        self.model.train()
        return total / len(self.holdout_data)

    def train_step(self, images: torch.Tensor, target: torch.Tensor) -> float:
        mean, std = self.model(images)
        loss = beta_nll(mean, std, target, self.config.beta)
        self.optimiser.zero_grad(set_to_none=True)
        loss.backward()
        self.optimiser.step()
        return loss.item()

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
        self.model.train()
        try:
            while self.epoch < config.epochs:
                started = time.perf_counter() - self.elapsed_s
                order = self.batch_rng.permutation(len(self.train_data))
                batches = [order[i:i + config.batch_size] for i in range(0, len(order), config.batch_size)]
                running = []
                out_of_time = False
                for index in tqdm(batches, desc=f"epoch {self.epoch + 1}/{config.epochs}", disable=not progress,
                                  leave=False):
                    if len(index) < 2:  # batch norm needs two rows
                        continue
                    progress = run_progress(self.elapsed_s, budget_s, self.step, config.epochs * len(batches))
                    for group in self.optimiser.param_groups:
                        group["lr"] = scheduled_lr(config.lr, config.lr_schedule, progress)
                    part = self.train_data.subset(index)
                    images = random_shift(to_input(part.drawn(self.batch_rng)), config.shift, self.shift_rng)
                    images = random_blur(images, config.blur_px, self.shift_rng)
                    images = random_erase(images, config.erase, self.shift_rng)
                    running.append(self.train_step(images, self.variables.encode(part.labels)))
                    self.step += 1
                    if self.step % 20 == 0:
                        writer.add_scalar("train/nll", running[-1], self.step)
                    self.elapsed_s = time.perf_counter() - started
                    if self.elapsed_s > budget_s:
                        out_of_time = True
                        break
                self.epoch += 0 if out_of_time else 1
                holdout = self.holdout_nll()
                self.elapsed_s = time.perf_counter() - started
                record = {"epoch": self.epoch, "partial_epoch": out_of_time, "step": self.step,
                          "elapsed_s": round(self.elapsed_s, 1),
                          "train_nll": float(np.mean(running)) if running else None, "holdout_nll": holdout}
                self.history.append(record)
                writer.add_scalar("holdout/nll", holdout, self.step)
                if holdout < self.best_holdout_nll:
                    self.best_holdout_nll, self.epochs_since_best = holdout, 0
                    save_posenet(self.run_dir / "best.pt", self.model,
                                 card={"holdout_nll": holdout, "epoch": self.epoch, "elapsed_s": self.elapsed_s,
                                       "source": config.source, "contact": config.contact})
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
                "best_holdout_nll": self.best_holdout_nll, "stopped_by": stop_reason}


# --------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", choices=SOURCES, required=True,
                        help="training images: the real ones, our sim renders, or sim through a shipped translator")
    parser.add_argument("--contact", choices=CONTACTS, required=True,
                        help="contact type (selects the variables); env: an env's state (with --source env)")
    parser.add_argument("--paired", nargs="+", required=True,
                        help="paired set directories, e.g. runs/paired/surface_shear/csv_train (env sets for "
                             "--source env)")
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--data", default=None, help="data root of the real images")
    defaults = PosenetTrainConfig(paired_dirs=("x",))
    for name in ("image_size_px", "epochs", "batch_size", "lr", "beta", "holdout", "patience_epochs", "shift", "seed",
                 "threads"):
        value = getattr(defaults, name)
        parser.add_argument(f"--{name.replace('_px', '').replace('_', '-')}", dest=name, type=type(value),
                            default=value, help=f"default {value}")
    parser.add_argument("--blur", dest="blur_px", type=float, default=defaults.blur_px,
                        help="augmentation: blur each training image with a Gaussian of std drawn from [0, BLUR] px "
                             f"(at the input size); default {defaults.blur_px}")
    parser.add_argument("--erase", type=float, default=defaults.erase,
                        help="augmentation: black out a disc of radius up to ERASE (a share of the image size) in each "
                             f"training image; default {defaults.erase}")
    parser.add_argument("--max-minutes", type=float, default=None, help="stop after this much training time")
    parser.add_argument("--lr-schedule", choices=LR_SCHEDULES, default=defaults.lr_schedule,
                        help="cosine: decay to 0 over the time budget (or the epochs)")
    parser.add_argument("--translators", nargs="+", default=(),
                        help="generator weights (.pt) to translate with instead of the shipped one; several: each "
                             "row through a randomly drawn one each time")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")


def run(args: argparse.Namespace) -> int:
    config = PosenetTrainConfig(
        source=args.source, contact=args.contact, paired_dirs=tuple(str(d) for d in args.paired),
        image_size_px=args.image_size_px, epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
        lr_schedule=args.lr_schedule, beta=args.beta,
        holdout=args.holdout, patience_epochs=args.patience_epochs, shift=args.shift,
        blur_px=args.blur_px, erase=args.erase, max_minutes=args.max_minutes, seed=args.seed, threads=args.threads,
        translators=tuple(str(path) for path in args.translators),
    )
    if (args.out / "checkpoint.pt").exists() and not args.resume:
        raise ValueError(f"{args.out / 'checkpoint.pt'} exists: pass --resume to continue it or use a new --out")
    torch.set_num_threads(config.threads)
    data = load_source(config.source, config.contact, config.paired_dirs, args.data, config.image_size_px,
                       translators=config.translators)
    trainer = PosenetTrainer(config, args.out, data)
    if args.resume and trainer.resume():
        print(f"resumed from {args.out / 'checkpoint.pt'} at epoch {trainer.epoch}")
    summary = trainer.fit()
    print(json.dumps(summary))
    return 0
