"""The GDNN trainer of ``simshear train posenet``: the training rows of each image source, the augmentations, and
:class:`PosenetTrainer` on the shared epoch loop (:mod:`simshear_gym.train.loop`). The command, the image sources
and what the run directory holds: :mod:`simshear_gym.train.posenet`; the run's settings:
:mod:`simshear_gym.train.posenet_config`.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from simshear_gym.data.labels import SHEAR_COLUMNS
from simshear_gym.data.paired import load_paired
from simshear_gym.data.paths import cache_dir
from simshear_gym.data.tactile_set import read_set
from simshear_gym.io import atomic_write
from simshear_gym.models.device import OnDevice, cpu_state, resolve_device
from simshear_gym.models.gdnn import GDNN, VariableSet, beta_nll, gaussian_nll, variable_set
from simshear_gym.models.gdnn_input import label_matrix, resize_images, to_input
from simshear_gym.models.posenet_io import save_posenet
from simshear_gym.models.translator import ARCHS, Translator, translate_rows
from simshear_gym.models.zoo import load_shipped_translator
from simshear_gym.train.distributed import Distributed
from simshear_gym.train.loop import EpochTrainer
from simshear_gym.train.posenet_config import SOURCES, PosenetTrainConfig
from simshear_gym.train.precision import Compiled, MixedPrecision, autocast_dtype, memory_format, use_tf32
from simshear_gym.train.runs import check_choice, data_on_device, split_holdout


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

    def subset(self, index: np.ndarray) -> LabelledImages:
        index = torch.as_tensor(index).to(self.images.device, non_blocking=True)
        return LabelledImages(self.images[index], self.labels[index])

    def to(self, device: torch.device) -> LabelledImages:
        """The rows on ``device``."""
        return LabelledImages(self.images.to(device), self.labels.to(device))

    @property
    def first(self) -> torch.Tensor:
        """(N, H, W): each row's first rendition."""
        return self.images if self.images.dim() == 3 else self.images[:, 0]

    def drawn(self, rng: np.random.Generator) -> torch.Tensor:
        """(N, H, W): a randomly drawn rendition of each row (the images themselves when there is one)."""
        if self.images.dim() == 3:
            return self.images
        views = torch.from_numpy(rng.integers(0, self.images.shape[1], len(self))).to(self.images.device)
        return self.images[torch.arange(len(self), device=self.images.device), views]


def load_source(source: str, contact: str, paired_dirs: tuple[str, ...] | list[str], data: str | None = None,
                image_size_px: int = 128, batch: int = 64,
                translators: tuple[str, ...] | list[str] = (), variables: str = "",
                device: str = "cpu") -> LabelledImages:
    """Images of ``source`` (see :mod:`simshear_gym.train.posenet`) and labels of the paired sets' rows;
    ``translators``: generator weights to use instead of the shipped one (several give (N, K, H, W) renditions);
    ``variables``: an inline variable set (:func:`~simshear_gym.models.gdnn.variable_set`) instead of the
    contact's; ``device`` (``cpu``, ``cuda``, ``auto``): where the translators run (on a GPU in batches of
    :data:`GPU_TRANSLATION_BATCH`: a GDNN's rows through a pool of generators cost minutes on one CPU thread)."""
    check_choice("source", source, SOURCES)
    variables = variable_set(variables or contact)
    if source == "env":
        return _load_env_sets(paired_dirs, variables, image_size_px)
    translated = source in ARCHS  # the sim renders through translators of that architecture
    if translators and not translated:
        raise ValueError(f"translators are generator weights for a translator source, not {source!r}")
    distinct = list(dict.fromkeys(translators))  # a file listed k times is loaded and translated once, drawn k x
    slots = [distinct.index(path) for path in translators] or [0]  # each listed generator's entry in `chosen`
    chosen = []
    if translated:
        chosen = [Translator.load(path) for path in distinct] or [load_shipped_translator(contact, source)]
        wants_shear = source == "shpix2pix"
        for path, translator in zip(distinct, chosen):
            if bool(translator.generator.config.shear_dim) != wants_shear:
                raise ValueError(f"translator {path}: a {'pix2pix' if wants_shear else 'shpix2pix'} generator, "
                                 f"but --source {source}")
    digests = [weights_digest(translator) for translator in chosen]  # the translation cache's keys
    chosen, batch = on_translation_device(chosen, device, batch)
    images, labels = [], []
    for directory in paired_dirs:
        paired, real = load_paired(directory, data, load_real=source == "real")  # only "real" reads the real set
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


GPU_TRANSLATION_BATCH = 512
"""Rows a generator translates at once on a GPU (a 128 px U-Net of the shipped size takes well under 1 GB)."""


def on_translation_device(translators: list, device: str, batch: int) -> tuple[list, int]:
    """``translators`` as they run on ``device`` and the batch they translate in: unchanged on the CPU; on a GPU
    each generator moved there (:class:`~simshear_gym.models.device.OnDevice`: CPU arrays in and out) and batches
    of :data:`GPU_TRANSLATION_BATCH`."""
    where = resolve_device(device)
    if where.type == "cpu":
        return translators, batch
    return [Translator(OnDevice(t.generator.float(), where), t.card, fast=False) for t in translators], max(
        batch, GPU_TRANSLATION_BATCH)


def weights_digest(translator) -> str:
    """A hash of a translator's generator weights."""
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
    key = hashlib.sha1(f"{paired.cache_key()}|{weights}|{image_size_px}".encode()).hexdigest()[:16]
    cache_file = cache_dir() / f"translated-{key}.npy"
    if cache_file.exists():
        cached = np.load(cache_file)
        if cached.shape == (len(sim_uint8), image_size_px, image_size_px):
            return cached
    images = resize_images(translate_rows(translator, sim_uint8, shear, batch), image_size_px)
    atomic_write(cache_file, lambda path: np.save(path, images), suffix=".npy")
    return images


def _load_env_sets(directories, variables: VariableSet, image_size_px: int) -> LabelledImages:
    images, labels = [], []
    for directory in directories:
        found = read_set(directory, required_columns=variables.columns)
        if found.meta.get("kind") != "env":
            raise ValueError(f"{directory}: not a set of simshear collect-env (meta.json kind "
                             f"{found.meta.get('kind')!r}, expected 'env')")
        images.append(resize_images(found.load_images(), image_size_px))
        labels.append(label_matrix(found.targets, variables))
    return LabelledImages(torch.from_numpy(np.concatenate(images)), torch.from_numpy(np.concatenate(labels)))


# The augmentations draw their random numbers from a CPU generator (a few per image: the same draws on any
# device, and a state the checkpoint holds) and transform the images where they are (the CPU or the GPU).
def random_shift(images: torch.Tensor, max_share: float, generator: torch.Generator) -> torch.Tensor:
    """Shift each image of (B, 1, H, W) by up to ``max_share`` of its size in x and y, edge pixels repeated."""
    if max_share <= 0:
        return images
    batch = images.shape[0]
    offset = ((torch.rand(batch, 2, generator=generator) * 2 - 1) * (2 * max_share)).to(images.device)  # grid: 2
    theta = torch.zeros(batch, 2, 3, device=images.device)
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
    sigma = (torch.rand(batch, 1, generator=generator) * max_sigma_px).to(images.device)
    offsets = torch.arange(-radius, radius + 1, dtype=torch.float32, device=images.device)
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
    radius = (torch.rand(batch, 1, 1, generator=generator) * max_radius_share).to(images.device)
    centre = (0.25 + 0.5 * torch.rand(batch, 2, 1, 1, generator=generator)).to(images.device)
    y = (torch.arange(height, dtype=torch.float32, device=images.device).view(1, -1, 1) + 0.5) / height
    x = (torch.arange(width, dtype=torch.float32, device=images.device).view(1, 1, -1) + 0.5) / width
    inside = (y - centre[:, 0]) ** 2 + (x - centre[:, 1]) ** 2 < radius ** 2
    return images.masked_fill(inside.unsqueeze(1), 0.0)


# -------------------------------------------------------------------------------------------------- training
class PosenetTrainer(EpochTrainer):
    """Owns the model, optimiser and run directory of one posenet training run; :meth:`fit` trains it.

    The rows stay on the CPU, where each batch is drawn and augmented (from the CPU generators the checkpoint
    holds); the batch then moves to ``config.device`` (under torchrun: the process's device, and its share of the
    batch). With ``config.data_on_device`` (by default on a GPU) the training rows live on the device and each
    batch is gathered and augmented there, the same rows and random draws. The model runs in ``channels_last``
    (faster on the CPU too) and on CUDA, with ``config.amp``, in mixed precision, with ``config.tf32`` its float32
    products in TF32; with ``config.compile`` through ``torch.compile`` (one process only)."""

    metric = "nll"  # history: train_nll (the beta-NLL training loss), holdout_nll (the plain Gaussian NLL)
    resume_free = EpochTrainer.resume_free + ("threads",)

    def __init__(self, config: PosenetTrainConfig, run_dir: Path, data: LabelledImages,
                 distributed: Distributed | None = None) -> None:
        super().__init__(config, run_dir, distributed)
        self.device = distributed.device if distributed is not None else resolve_device(config.device)
        self.memory_format = memory_format(self.device)
        self.precision = MixedPrecision(self.device, autocast_dtype(self.device, config.amp))
        use_tf32(self.device, config.tf32)
        torch.manual_seed(config.seed)
        data = LabelledImages(torch.as_tensor(resize_images(data.images.numpy(), config.image_size_px)),
                              data.labels)
        train_rows, holdout_rows = split_holdout(len(data), config.holdout, config.seed)
        self.train_data, self.holdout_data = data.subset(train_rows), data.subset(holdout_rows)
        self.model = GDNN(config.gdnn_config()).to(self.device, memory_format=self.memory_format)
        self.variables = self.model.variables
        self.net = distributed.wrap(self.model) if distributed is not None else self.model  # what trains
        self.forward = Compiled(self.net, config.compile and distributed is None, "the GDNN")
        self.device_data = (self.train_data.to(self.device) if data_on_device(config.data_on_device,
                                                                               self.device.type) else None)
        self.optimiser = torch.optim.Adam(self.model.parameters(), lr=config.lr)
        self.batch_rng = np.random.default_rng(config.seed + 1)
        self.shift_rng = torch.Generator().manual_seed(config.seed + 2)

    # ------------------------------------------------------------------------------------------- persistence
    def trainer_state(self) -> dict:
        return {
            "model": {"config": asdict(self.model.config), "state_dict": cpu_state(self.model)},
            "optimiser": self.optimiser.state_dict(),
            "batch_rng": self.batch_rng.bit_generator.state, "shift_rng": self.shift_rng.get_state(),
            "torch_rng": torch.get_rng_state(),
        }

    def load_trainer_state(self, state: dict) -> None:
        self.model.load_state_dict(state["model"]["state_dict"])
        self.optimiser.load_state_dict(state["optimiser"])
        self.batch_rng.bit_generator.state = state["batch_rng"]
        self.shift_rng.set_state(state["shift_rng"])
        torch.set_rng_state(state["torch_rng"])

    # ---------------------------------------------------------------------------------------------- training
    def holdout_nll(self) -> float:
        """Mean Gaussian NLL (nats per row, over the encoded components) of the held-out rows, unaugmented."""
        self.model.eval()
        total = 0.0
        with torch.inference_mode():
            for start in range(0, len(self.holdout_data), 64):
                part = self.holdout_data.subset(np.arange(start, min(start + 64, len(self.holdout_data))))
                mean, std = self.model(self._on_device(to_input(part.first)))
                total += gaussian_nll(mean.cpu(), std.cpu(), self.variables.encode(part.labels),
                                      reduction="none").sum().item()
        self.model.train()
        return total / len(self.holdout_data)

    def _on_device(self, images: torch.Tensor) -> torch.Tensor:
        """A CPU batch of images (B, 1, H, W) on the model's device and memory format (itself on the CPU)."""
        return images.to(self.device, memory_format=self.memory_format, non_blocking=True)

    def train_step(self, images: torch.Tensor, target: torch.Tensor) -> float:
        """One optimiser step on ``images`` (B, 1, H, W) and encoded ``target`` (B, D), on the CPU or already on the
        device; returns the loss."""
        with self.precision.autocast():
            mean, std = self.forward(self._on_device(images))
        loss = beta_nll(mean.float(), std.float(), target.to(self.device), self.config.beta)
        self.optimiser.zero_grad(set_to_none=True)
        self.precision.backward(loss)
        self.precision.step(self.optimiser)
        self.precision.update()
        return loss.item()

    # -------------------------------------------------------------------------------- the epoch loop's hooks
    def epoch_batches(self) -> list[np.ndarray]:
        order = self.batch_rng.permutation(len(self.train_data))
        size = self.config.batch_size
        return [order[i:i + size] for i in range(0, len(order), size)]  # a last batch of one row counts

    def optimisers(self) -> list[torch.optim.Optimizer]:
        return [self.optimiser]

    def train_mode(self) -> None:
        self.model.train()

    def train_batch(self, index: np.ndarray) -> dict[str, float]:
        """An augmented batch (a drawn rendition, shifted, blurred, erased) and one step on its beta-NLL (under
        torchrun: every process augments the whole batch, so its generators stay in step, and trains on its
        share)."""
        config = self.config
        part = (self.device_data if self.device_data is not None else self.train_data).subset(index)
        images = random_shift(to_input(part.drawn(self.batch_rng)), config.shift, self.shift_rng)
        images = random_blur(images, config.blur_px, self.shift_rng)
        images = random_erase(images, config.erase, self.shift_rng)
        rows = self.local_rows(len(index))
        return {"nll": self.train_step(images[rows], self.variables.encode(part.labels)[rows])}

    holdout_metric = holdout_nll

    def save_best(self, path: Path, card: dict) -> None:
        save_posenet(path, self.model, card={**card, "source": self.config.source, "contact": self.config.contact})
