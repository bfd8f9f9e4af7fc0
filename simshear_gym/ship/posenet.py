"""Ship a posenet run: ``simshear train export-posenet --run RUN --contact C --to WEIGHTS.pt --train-command ...``.

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
from collections import Counter
from pathlib import Path

from simshear_gym.command_line import recorded_command


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


def generator_list(translators: list[str]) -> str:
    """``a, b (x3), c``: the generator files of ``--translators`` in order, each once with how often it is listed."""
    counts = Counter(translators)
    return ", ".join(f"`{path}`" + (f" (x{counts[path]})" if counts[path] > 1 else "") for path in counts)


def _commands_line(card: dict, weights: Path) -> str:
    """The card's exact commands: the sets' collection, the training, the export; one recipe command where
    ``simshear pipeline env-model`` made both sets and run (the data paths are then relative to its run folder)."""
    export_args = argparse.Namespace(run="RUN", contact=card["contact"], to=weights)  # RUN: a local path
    export = f"`{recorded_command('simshear train export-posenet', add_arguments, export_args)}`"
    train = card.get("train_command", "")
    if train.startswith("simshear pipeline env-model"):
        return (f"- Exact commands: `{train}` (the recipe's cached stages: the env sets, a first GDNN, the "
                "servo-driven sets it read, this GDNN; the data paths above are relative to its run folder), then "
                + export
                + " with RUN its `envposenet/final/<hash>/run`.")
    collect = card.get("collect_command", "simshear collect --replay-all --out runs/paired")
    return f"- Exact commands: `{collect}`, then `{train}`, then {export}."


def write_card(weights: Path, card: dict, results: dict | None, result_name: str, date: str) -> Path:
    """``<weights>.md``: data, exact commands, metrics, date."""
    config = card.get("train_config", {})
    params = card.get("parameters")
    holdout = f"{100 * config.get('holdout', 0):.0f} % of them held out for early stopping."
    if config.get("source") == "env":
        data_line = (f"- Data: the env sets {config.get('paired_dirs')} of `simshear collect-env` (the images the env "
                     "emitted, translated by the surface shPix2pix shipped when each set was collected, labelled with "
                     f"the env's true state); {holdout}")
    else:
        translated = (f"translated by each of the generators {generator_list(config['translators'])}, a randomly "
                      "drawn one each time a row is drawn, one listed k times drawn k times as often (the holdout "
                      "by the first)" if config.get("translators")
                      else "translated by the shipped shPix2pix of this contact type")
        data_line = (f"- Data: images from source `{config.get('source')}` of the paired sets "
                     f"{config.get('paired_dirs')} (our sim renders of the real tactip331 training rows; `shpix2pix` = "
                     f"{translated}); {holdout} The real validation images were not used in training or selection.")
    lines = [
        f"# Pose-and-shear GDNN, {card['contact']} contacts",
        "",
        f"- File: `{weights.name}` ({weights.stat().st_size / 2**20:.1f} MiB, fp32, {params / 1e6:.2f} M parameters)",
        f"- Date: {date}",
        f"- Architecture: GDNN, {config.get('image_size_px')} px input, conv channels {config.get('conv_channels')} "
        f"kernels {config.get('conv_kernels')}, dense {config.get('dense')}; outputs mean and std per variable "
        f"({', '.join(card.get('variables', []))}).",
        data_line,
        f"- Objective: beta-NLL (beta {config.get('beta')}); Adam lr {config.get('lr')} "
        f"({config.get('lr_schedule', 'constant')}), batch "
        f"{config.get('batch_size')}, shift augmentation {config.get('shift')}, seed {config.get('seed')}, "
        f"{config.get('threads')} CPU thread(s).",
        f"- Training: best holdout NLL {card.get('holdout_nll', float('nan')):.3f} at epoch {card.get('epoch')}, "
        f"{card.get('elapsed_s', 0) / 60:.1f} min on a 2-core CPU.",
        _commands_line(card, weights),
    ]
    section = (results or {}).get("contacts", {}).get(card["contact"], {})
    if result_name in section.get("models", {}):
        figures = section["models"][result_name]
        lines += ["", "## Metrics on the real validation images", "",
                  f"From `{results.get('command')}` (`results/posenet.json`; {figures['rows']} rows of "
                  f"{section.get('set')}; model `{result_name}`), mean NLL {figures['mean_nll']:.3f}, "
                  f"latency at batch 1 {figures.get('latency_batch1', {}).get('median_ms', float('nan')):.2f} ms "
                  "(median, 1 thread):", "",
                  "| variable | MAE | chance MAE | within 1 std | within 2 std |", "|---|---|---|---|---|"]
        for name, row in figures["variables"].items():
            lines.append(f"| {name} ({row['unit']}) | {row['mae']:.3f} | {row['chance_mae']:.3f} | "
                         f"{row['within_1_std']:.2f} | {row['within_2_std']:.2f} |")
        accepted = section.get("acceptance", {}).get("variables", {})
        if accepted:
            lines += ["", "Against the same GDNN trained on the real training images (`real`, the upper bound): "
                      "MAE ratio per variable that one reads (MAE <= 0.5 x chance): "
                      + ", ".join(f"{name} {row['ratio']:.2f}" for name, row in accepted.items()
                                  if row["reference_reads"])
                      + "; not read by `real` either: " + ", ".join(name for name, row in accepted.items()
                                                               if not row["reference_reads"]) + "."]
    check = card.get("check")
    if check and check.get("kind") == "env":
        lines += ["", f"Check figure (tests): MAE on a fresh seeded co-lift set ({check['rows']} rows, "
                      f"`EnvCollectConfig(**{check['collect']})`): "
                      + ", ".join(f"{k} {v:.3f}" for k, v in check["mae"].items())]
    elif check:
        lines += ["", f"Check figure (tests): MAE on the first {check['rows']} rows of the real "
                      f"`{card['contact']}_shear` validation set: "
                      + ", ".join(f"{k} {v:.3f}" for k, v in check["mae"].items())]
    path = weights.with_suffix(".md")
    path.write_text("\n".join(lines) + "\n")
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
