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

This module is the command, its flags and ``run``; like the run's settings
(:mod:`simshear_gym.train.posenet_config`) it imports no torch, so ``--help`` stays fast. The training rows,
augmentations and trainer are in :mod:`simshear_gym.train.posenet_trainer`, on the epoch loop of
:mod:`simshear_gym.train.loop`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from simshear_gym.train.flags import config_flags, config_from_args
from simshear_gym.train.posenet_config import CONTACTS, SOURCES, PosenetTrainConfig
from simshear_gym.train.runs import BUDGET_FLAG_HELP, RUN_CHOICES, device_flag_help, train_command
from simshear_gym.train.wandb_sync import FLAG_HELP as WANDB_HELP

FLAG_HELP = {
    "source": "training images: real (the real images the paired sets replay), sim (the sets' own sim renders), "
              "shpix2pix / pix2pix (the sim renders through a translator of that architecture), env (sets of "
              "simshear collect-env, with --contact env)",
    "contact": "contact type, which selects the variables the GDNN estimates; env: an env's state (with --source "
               "env)",
    "paired_dirs": "paired set directories, e.g. runs/paired/surface_shear/csv_train (env sets for --source env)",
    "image_size_px": "input size of the GDNN in px (H = W); every image is resized to it",
    "epochs": "most epochs to train",
    "batch_size": "training rows per step",
    "lr": "Adam learning rate (where the cosine schedule starts)",
    "lr_schedule": "constant, or cosine: decay to 0 over the time budget (or the epochs)",
    "beta": "exponent of the beta-NLL training loss (0: the plain Gaussian NLL)",
    "holdout": "share of the rows held out for early stopping on the Gaussian NLL",
    "patience_epochs": "stop after this many epochs in a row without a lower holdout NLL",
    "shift": "augmentation: shift each training image by up to SHIFT (a share of the image size) in x and y, "
             "edges repeated",
    "blur_px": "augmentation: blur each training image with a Gaussian of std drawn from [0, BLUR] px (at the "
               "input size)",
    "erase": "augmentation: black out a disc of radius up to ERASE (a share of the image size) in each training "
             "image",
    **BUDGET_FLAG_HELP,
    "seed": "seed of the holdout split, the initial weights, the batch order and the augmentations",
    "threads": "torch CPU threads",
    "translators": "generator weights (.pt) to translate with instead of the shipped one; several: each row "
                   "through a randomly drawn one each time",
    "variables": "the variables to estimate, inline (NAME:COLUMN:LOW:HIGH[:periodic],...; a sensor's own, as the "
                 "pipeline writes them) instead of the contact type's set",
    **device_flag_help("GDNN", PosenetTrainConfig.reference_batch),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--data", default=None, help="data root of the real images")
    config_flags(parser, PosenetTrainConfig, FLAG_HELP, flags={"paired_dirs": "--paired", "blur_px": "--blur"},
                 choices={"source": SOURCES, "contact": CONTACTS, **RUN_CHOICES},
                 required=("source", "contact", "paired_dirs"), metavars={"paired_dirs": "DIR",
                                                                          "translators": "WEIGHTS"})
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    parser.add_argument("--wandb", default=None, metavar="PROJECT", help=WANDB_HELP)


def run(args: argparse.Namespace) -> int:
    """Train (under torchrun: data-parallel, rank 0 writing and printing; see
    :mod:`simshear_gym.train.distributed`)."""
    import torch

    from simshear_gym.train.posenet_trainer import PosenetTrainer, load_source

    config = config_from_args(PosenetTrainConfig, args)
    torch.set_num_threads(config.threads)

    def trainer(distributed):
        data = load_source(config.source, config.contact, config.paired_dirs, args.data, config.image_size_px,
                           translators=config.translators, variables=config.variables,
                           device=config.device if distributed is None else "cpu")  # torchrun: each on its CPU
        return PosenetTrainer(config, args.out, data, distributed)

    train_command(args, config, trainer)
    return 0
