"""Quality against training time of translator runs: holdout L1 (= MAPE on held-out training pairs) per epoch.

``simshear evaluate training-curve --run NAME=RUN_DIR ...`` reads each run's ``history.json`` and writes
``results/translator_training.json`` and ``results/translator_training.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", action="append", required=True, metavar="NAME=RUN_DIR",
                        help="a translator run directory (its history.json) and the curve's name; repeat for several")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory (default results)")
    parser.add_argument("--name", default="translator_training",
                        help="base name of the json and png written (default translator_training)")


def run(args: argparse.Namespace) -> int:
    plt = pyplot()

    curves = {}
    for spec in args.run:
        name, _, directory = spec.partition("=")
        history_file = Path(directory) / "history.json"
        if not history_file.is_file():
            raise FileNotFoundError(f"{history_file}: missing; expected a translator run directory")
        history = json.loads(history_file.read_text())
        curves[name] = {"config": history["config"],
                        "points": [{"minutes": round(e["elapsed_s"] / 60, 2), "epoch": e["epoch"],
                                    "holdout_mape": round(e["holdout_l1"], 5)} for e in history["epochs"]]}
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for name, curve in curves.items():
        ax.plot([p["minutes"] for p in curve["points"]], [p["holdout_mape"] for p in curve["points"]],
                marker="o", ms=3, label=name)
    ax.set_xlabel("training time on this CPU [min]")
    ax.set_ylabel("holdout MAPE")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    png = args.out / f"{args.name}.png"
    save_figure(fig, png, dpi=120)
    write_record("simshear evaluate training-curve", add_arguments, args, args.out / f"{args.name}.json", {
        "note": "holdout = a share of the paired training rows kept out of training (never the real val sets)",
        "runs": curves, "figure": str(png)})
    for name, curve in curves.items():
        last = curve["points"][-1]
        print(f"{name}: {len(curve['points'])} points, last {last['minutes']} min -> "
              f"holdout MAPE {last['holdout_mape']}")
    print(f"wrote {args.out / (args.name + '.json')} and {png}")
    return 0
