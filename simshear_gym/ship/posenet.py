"""Ship a posenet run: ``simshear ship posenet --run RUN --contact C --to WEIGHTS.pt --train-command ...``.

Copies the run's best GDNN into a weights file with a card (training command, run config, best holdout NLL, and a
check figure: the per-variable MAE on the first ``--check-rows`` rows of the real ``<contact>_shear`` validation
set, which ``tests/test_shipped_posenet.py`` reproduces), and writes the Markdown model card beside it from the
``simshear evaluate posenet`` results of that run (``--results``, the model named ``--result-name``).

``--contact colift``: a GDNN of the ``env`` variables trained on co-lift env sets (``simshear collect-env``); its
check figure is the MAE on a small seeded co-lift set collected afresh (:func:`env_check_figure`), since no real
images of that task exist.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.ship.cards import posenet_card


def check_figure(weights: Path, contact: str, rows: int, data: str | None = None) -> dict:
    """Per-variable MAE (mm / deg) of a weights file on the first ``rows`` real validation rows."""
    import numpy as np

    from simshear_gym.data.paths import data_root, real_set_dir
    from simshear_gym.data.tactile_set import read_set
    from simshear_gym.evaluate.metrics import errors, truth_labels
    from simshear_gym.models.gdnn_input import predict
    from simshear_gym.models.posenet_io import load_posenet

    model, _ = load_posenet(weights)
    val = read_set(real_set_dir(data_root(data), contact, "shear", "val"))
    truth = truth_labels(val, model.variables)[:rows]
    mean, std = model.variables.decode(*predict(model, val.load_images()[:rows]))
    mae = np.abs(errors(mean.numpy(), truth, model.variables)).mean(axis=0)
    return {"kind": "shear", "rows": rows, "mae": {name: float(v) for name, v in zip(model.variables.names, mae)}}


ENV_CHECK = {"task": "colift", "rows": 48, "episode_steps": 12, "seed": 12345}
"""The seeded co-lift set of an env GDNN's check figure (oracle-driven, collected afresh by the check)."""
ENV_CHECKS = {"colift": ENV_CHECK, "colift_heavy": {**ENV_CHECK, "payload": "heavy"}}
"""The check set of each env GDNN (``--contact``): the light and the heavy co-lift."""


def env_check_figure(weights: Path, settings: dict = ENV_CHECK) -> dict:
    """Per-variable MAE of an ``env`` GDNN on a small seeded co-lift set collected into a temporary directory."""
    import tempfile

    import numpy as np

    from simshear_gym.data.tactile_set import read_set
    from simshear_gym.evaluate.metrics import errors
    from simshear_gym.models.gdnn_input import label_matrix, predict
    from simshear_gym.models.posenet_io import load_posenet
    from simshear_gym.pipelines.env_collect import EnvCollectConfig, collect

    model, _ = load_posenet(weights)
    with tempfile.TemporaryDirectory() as directory:
        collect(EnvCollectConfig(**settings), Path(directory), progress=False)
        found = read_set(directory, required_columns=model.variables.columns)
        truth = label_matrix(found.targets, model.variables)
        images = found.load_images(use_cache=False)
    mean, _ = model.variables.decode(*predict(model, images))
    mae = np.abs(errors(mean.numpy(), truth, model.variables)).mean(axis=0)
    return {"kind": "env", "collect": dict(settings), "rows": len(truth),
            "mae": {name: float(v) for name, v in zip(model.variables.names, mae)}}


def write_card(weights: Path, card: dict, results: dict | None, result_name: str, date: str) -> Path:
    """``<weights>.md`` (:func:`~simshear_gym.ship.cards.posenet_card`): data, exact commands, metrics, date."""
    export_args = argparse.Namespace(run="RUN", contact=card["contact"], to=weights)  # RUN: a local path
    export_command = recorded_command("simshear ship posenet", add_arguments, export_args)
    path = weights.with_suffix(".md")
    path.write_text(posenet_card(weights, card, results, result_name, date, export_command))
    return path


# --contact -> the GDNN's variable set
_VARIABLES = {"surface": "surface", "edge": "edge", "colift": "env", "colift_heavy": "env"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", type=Path, required=True, help="posenet run directory (best.pt, config.json)")
    parser.add_argument("--contact", choices=tuple(_VARIABLES), required=True,
                        help="surface | edge (real-data GDNNs), colift or colift_heavy (env GDNNs of the co-lift env, "
                             "payload light or heavy)")
    parser.add_argument("--to", type=Path, required=True, help="weights file to write")
    parser.add_argument("--train-command", required=True, help="the exact command that trained the run")
    parser.add_argument("--results", type=Path, default=None, help="results json of simshear evaluate posenet")
    parser.add_argument("--result-name", default="shpix2pix", help="the model's name in --results")
    parser.add_argument("--check-rows", type=int, default=64,
                        help="rows of the real <contact>_shear val set in the check figure's MAE (default 64; "
                             "colift checks on its own seeded env set)")
    parser.add_argument("--data", default=None,
                        help="data root holding tactip331/ (default: $SIMSHEAR_DATA, else ../shared/data)")
    parser.add_argument("--collect-command", default=None,
                        help="the exact command(s) that made the training sets (default: simshear collect)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.models.posenet_io import load_posenet, save_posenet

    model, best_card = load_posenet(args.run / "best.pt")
    if model.variables.name != _VARIABLES[args.contact]:
        raise ValueError(f"{args.run / 'best.pt'}: predicts the {model.variables.name!r} variables, not "
                         f"{_VARIABLES[args.contact]!r} (--contact {args.contact})")
    config = json.loads((args.run / "config.json").read_text())
    card = {**best_card, "contact": args.contact, "train_command": args.train_command, "train_config": config,
            "variables": list(model.variables.names), "parameters": sum(p.numel() for p in model.parameters())}
    if args.collect_command:
        card["collect_command"] = args.collect_command
    args.to.parent.mkdir(parents=True, exist_ok=True)
    save_posenet(args.to, model, card)
    card["check"] = (env_check_figure(args.to, ENV_CHECKS[args.contact]) if args.contact in ENV_CHECKS else
                     check_figure(args.to, args.contact, args.check_rows, args.data))
    save_posenet(args.to, model, card)
    results = json.loads(args.results.read_text()) if args.results else None
    md = write_card(args.to, card, results, args.result_name, datetime.date.today().isoformat())
    print(f"exported {args.to} ({args.to.stat().st_size / 2**20:.2f} MiB) and {md}; check: {card['check']}")
    return 0
