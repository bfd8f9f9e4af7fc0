"""``simshear ship recheck-posenet W.pt``: measure a shipped GDNN's check figure again and record it.

A GDNN's check figure (``tests/test_shipped_posenet.py`` reproduces it) is its MAE on a fixed set of images. For the
co-lift GDNN that set is collected afresh from the co-lift env, whose images come from the shipped surface
shPix2pix: when that translator is replaced (``simshear ship run``), the same GDNN sees other images and its
check figure moves. This command measures it again with the translator shipped now, stores it in the weights file
(``check``, with the sha256 of the translator that made the images) and rewrites the card's check line, saying when
and why. The network itself is not touched.
"""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.ship.cards import recheck_line, with_check_line


def recheck(weights: Path, data: str | None = None, date: str | None = None) -> dict:
    """Measure ``weights``' check figure again (same set as recorded), store it and update its card; returns it."""
    from simshear_gym.models.posenet_io import load_posenet, save_posenet
    from simshear_gym.models.translator_runtime import file_sha256
    from simshear_gym.models.zoo import shipped_translators
    from simshear_gym.ship.posenet import check_figure, env_check_figure

    weights = Path(weights)
    if not weights.is_file():
        raise FileNotFoundError(f"GDNN weights {weights} not found")
    model, card = load_posenet(weights)
    old = card.get("check")
    if not old:
        raise ValueError(f"{weights}: its card holds no check figure to measure again (export it with "
                         "simshear ship posenet)")
    if old.get("kind") == "env":
        check = env_check_figure(weights, old["collect"])
        translator = shipped_translators()[("shpix2pix", "surface")]
        check["translator_sha256"] = file_sha256(translator)
    else:
        check = check_figure(weights, card["contact"], old["rows"], data)
    date = date or datetime.date.today().isoformat()
    check["measured"] = date
    save_posenet(weights, model, {**card, "check": check})
    md = weights.with_suffix(".md")
    if md.is_file():
        command = recorded_command("simshear ship recheck-posenet", add_arguments, argparse.Namespace(weights=weights))
        md.write_text(with_check_line(md.read_text(), recheck_line(check, card["contact"], old, command)))
    return check


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("weights", type=Path,
                        help="shipped GDNN weights (simshear_gym.models.zoo.posenet_weights(NAME))")
    parser.add_argument("--data", default=None,
                        help="data root of a real-data check (default: $SIMSHEAR_DATA, else ../shared/data)")


def run(args: argparse.Namespace) -> int:
    check = recheck(args.weights, args.data)
    print(f"{args.weights}: check MAE " + ", ".join(f"{k} {v:.3f}" for k, v in check["mae"].items()))
    return 0
