"""Ship a translator run: ``simshear ship translator --run RUN --contact C --to WEIGHTS.pt``.

Writes the run's best generator as fp16 weights and records a check figure in the file: the MAPE of the
exported model on the first ``--check-rows`` rows of the real ``<contact>_shear`` validation set, which the tests
reproduce (``tests/test_shipped_translator.py``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from simshear_gym.command_line import recorded_command


def check_figure(weights: Path, contact: str, rows: int, data: str | None = None) -> dict:
    from simshear_gym.data.paths import data_root, real_set_dir
    from simshear_gym.data.tactile_set import read_set
    from simshear_gym.evaluate.metrics import mape
    from simshear_gym.models.translator import Translator
    from simshear_gym.sim.replay import render_poses
    from simshear_gym.sim.shear import ShearTrackerConfig, replay_shear

    val = read_set(real_set_dir(data_root(data), contact, "shear", "val"))
    poses, moves = val.poses()[:rows], val.moves()[:rows]
    generated = Translator.load(weights)(render_poses(contact, poses), replay_shear(poses, moves, ShearTrackerConfig()))
    return {"kind": "shear", "rows": rows, "mape": float(mape(generated, val.load_images()[:rows]).mean())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", type=Path, required=True, help="translator run directory (best.pt, config.json)")
    parser.add_argument("--contact", choices=("surface", "edge"), required=True,
                        help="contact type of the run; its real <contact>_shear val set gives the check figure")
    parser.add_argument("--to", type=Path, required=True, help="weights file to write")
    parser.add_argument("--train-command", required=True, help="the exact command that trained the run")
    parser.add_argument("--check-rows", type=int, default=16,
                        help="rows of the real <contact>_shear val set in the check figure's MAPE (default 16)")
    parser.add_argument("--data", default=None,
                        help="data root holding tactip331/ (default: $SIMSHEAR_DATA, else ../shared/data)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.models.translator import load_generator, save_generator
    from simshear_gym.models.weights_io import read_weights
    from simshear_gym.train.translator_trainer import export_run

    export_run(args.run, args.to, card={"train_command": args.train_command, "contact": args.contact})
    check = check_figure(args.to, args.contact, args.check_rows, args.data)
    generator, card = load_generator(args.to)
    save_generator(args.to, generator, card={**card, "check": check})
    read_weights(args.to, "translator")  # readable as written (weights_only, its sha256 checked)
    print(f"exported {args.to} ({args.to.stat().st_size / 2**20:.1f} MiB); check: {check}")
    print("command:", recorded_command("simshear ship translator", add_arguments, args))
    return 0
