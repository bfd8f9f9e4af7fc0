"""Train the sim-to-real translator: shPix2pix (shear at the bottleneck) or the pix2pix baseline.

``simshear train translator --arch shpix2pix --paired DIR [DIR ...] --out RUN_DIR`` trains on paired sets
(:mod:`simshear_gym.data.paired`). A share of the training rows (``--holdout``) is held out for early stopping
on L1, so the real validation sets stay unseen until ``simshear evaluate translation``. Objective: ``l1_weight *
L1 + gan_weight * least-squares GAN`` (``--gan-weight 0``: L1 alone, as the public shPix2pix code trained), plus
``density_weight *`` the L1 of both images averaged over 8 px squares (``--density-weight``): plain L1 rewards
black where a marker's place is uncertain (its median), which blanks the markers of deep, sheared contacts; the
pooled term asks for the right amount of marker there instead; plus
``pose_weight *`` the pose-consistency loss of a frozen real-image GDNN (``--pose-net``,
:mod:`simshear_gym.train.pose_consistency`) when ``--pose-weight`` is above 0. ``--teacher W.pt`` distils: the
targets are that translator's images of the rows (sim render, shear) instead of the real images, L1 alone, so
that a smaller generator (``--base-channels 8``) learns the shipped one's mapping for the envs' fast path.
``--init-weights W.pt`` fine-tunes: the generator starts from that translator's weights (the same architecture).
Learning rate: constant, or ``--lr-schedule cosine``: ``lr * (1 + cos(pi * p)) / 2`` where ``p`` is the share of
the time budget (``--max-minutes``) used so far, or of the epochs when there is no budget, so a budgeted run ends
at a small learning rate whenever its time runs out.

Run directory: ``config.json``, ``history.json`` (per epoch: wall time, train and holdout L1), tensorboard logs
under ``tb/`` (scalars, image grids sim | generated | real), ``checkpoint.pt`` (written atomically after every
epoch and at the time budget; ``--resume`` continues from it) and ``best.pt`` (the generator with the lowest
holdout L1).

This module is the command, its flags and ``run``; like the run's settings
(:mod:`simshear_gym.train.translator_config`) it imports no torch, so ``--help`` stays fast. The data, losses and
trainer are in :mod:`simshear_gym.train.translator_trainer`, on the epoch loop of :mod:`simshear_gym.train.loop`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from simshear_gym.train.flags import config_flags, config_from_args
from simshear_gym.train.runs import BUDGET_FLAG_HELP, RUN_CHOICES, device_flag_help, train_command
from simshear_gym.train.translator_config import ARCHS, DENSITY_POOL_PX, TranslatorTrainConfig
from simshear_gym.train.wandb_sync import FLAG_HELP as WANDB_HELP

FLAG_HELP = {
    "arch": "generator: shpix2pix (the shear vector at the U-Net bottleneck) or the pix2pix baseline (no shear)",
    "paired_dirs": "paired set directories (simshear collect)",
    "image_size_px": "image size in px (H = W, a power of two); the U-Net has log2(size) levels",
    "base_channels": "channels of the U-Net's first level, doubled per level up to --max-channels",
    "max_channels": "cap on the channels of the deep U-Net levels",
    "template": "no learned at-rest template input",
    "shear_decoder": "shpix2pix: also feed the shear vector to every decoder level",
    "decoder_scale": "decoder levels output this share of their mirrored encoder level's channels (0.5 halves the "
                     "decoder's cost)",
    "flow_px": "warp the at-rest template by a displacement field of this many pixels square (0 = no warp)",
    "epochs": "most epochs to train",
    "batch_size": "training pairs per step",
    "lr": "Adam learning rate of generator and discriminator (where the cosine schedule starts)",
    "lr_schedule": "constant, or cosine: decay to 0 over the time budget (or the epochs)",
    "l1_weight": "weight of the pixel L1 loss",
    "density_weight": f"weight of the L1 of both images averaged over {DENSITY_POOL_PX} px squares (0: off)",
    "gan_weight": "weight of the least-squares GAN loss (0: L1 alone, no discriminator)",
    "holdout": "share of the training rows held out for early stopping on L1",
    "patience_epochs": "stop after this many epochs in a row without a lower holdout L1",
    **BUDGET_FLAG_HELP,
    "seed": "seed of the holdout split, the initial weights and the batch order",
    "threads": "torch CPU threads",
    "pose_net": "pose-consistency loss: a GDNN trained on the real images (best.pt of simshear train posenet "
                "--source real) of the same contact type",
    "pose_weight": "weight of the pose-consistency loss (needs --pose-net; 0: off)",
    "pose_variables": "pose-consistency loss on these of the GDNN's variables only (default: all)",
    "teacher": "distil: learn this translator's images (its .pt weights, same architecture kind) of the paired "
               "rows' sim renders and shear instead of the real images (a smaller, faster student; L1 alone)",
    "init_weights": "fine-tune: start the generator from this translator's weights (its .pt, the same architecture) "
                    "instead of random ones",
    **device_flag_help("generator", TranslatorTrainConfig.reference_batch),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="run directory")
    parser.add_argument("--data", default=None, help="data root of the real images")
    config_flags(parser, TranslatorTrainConfig, FLAG_HELP, flags={"paired_dirs": "--paired"},
                 choices={"arch": ARCHS, **RUN_CHOICES}, required=("paired_dirs",),
                 metavars={"paired_dirs": "DIR", "pose_variables": "NAME"})
    parser.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    parser.add_argument("--export", type=Path, default=None, help="write the best generator (fp16) here")
    parser.add_argument("--wandb", default=None, metavar="PROJECT", help=WANDB_HELP)


def run(args: argparse.Namespace) -> int:
    """Train (under torchrun: data-parallel, rank 0 writing and printing; see
    :mod:`simshear_gym.train.distributed`)."""
    from simshear_gym.train.pose_consistency import PoseConsistency
    from simshear_gym.train.translator_trainer import TranslatorTrainer, export_run, load_pairs

    config = config_from_args(TranslatorTrainConfig, args)

    def trainer(distributed):
        pose = PoseConsistency(config.pose_net, config.pose_variables) if config.pose_weight > 0 else None
        pairs = load_pairs(config.paired_dirs, args.data, pose)
        return TranslatorTrainer(config, args.out, pairs, pose, distributed)

    if train_command(args, config, trainer) is not None and args.export:
        export_run(args.out, args.export)
        print(f"exported {args.export}")
    return 0
