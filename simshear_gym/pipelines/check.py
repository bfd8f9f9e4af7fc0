"""``simshear pipeline check CONFIG``: validate an experiment config and its data before anything trains.

For each dataset of the config (:mod:`simshear_gym.pipelines.config`): every CSV present with the named columns,
every image present, decodable and of one size, every label finite, every variable declared present varying, both
splits non-empty (:func:`simshear_gym.data.adapter.adapt_dataset`); then a sample of its training rows is replayed
in simulation with the config's sensor, replay geometry and frame, and the share of renders that show any contact
is reported: below ``[check] min_contact_share`` the frame or depth mapping is wrong, and that is an error, never
a silent set of blank images. Prints a summary; ``--json PATH`` writes it too.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from simshear_gym.data.adapter import adapt_dataset, config_files, summarise_variables
from simshear_gym.data.paths import data_root
from simshear_gym.data.tactile_set import TactileDataError
from simshear_gym.io import write_json

if TYPE_CHECKING:  # the config imports the simulator (pybullet): in run, so that --help stays light
    from simshear_gym.pipelines.config import ExperimentConfig


@dataclass(frozen=True)
class DatasetReport:
    name: str
    contact: str
    kind: str
    rows: dict
    source_image_px: tuple[int, int]
    variables: list
    replayed_rows: int
    contact_share: float


def replay_contact_share(config: ExperimentConfig, contact: str, poses: np.ndarray) -> float:
    """Share of ``poses`` (sim frame) whose render shows any contact."""
    from simshear_gym.sim.replay import ReplayScene  # pybullet: here, so that --help stays light

    with ReplayScene(contact, config.sensor, config.replay) as scene:
        touched = [bool(scene.render(pose).any()) for pose in poses]
    return float(np.mean(touched)) if touched else 0.0


def check(config: ExperimentConfig, root: Path, max_rows_per_split: int | None = None) -> list[DatasetReport]:
    """Check every dataset (see the module docstring); raises ``TactileDataError`` on the first problem."""
    reports = []
    for name, dataset in config.datasets.items():
        adapted = adapt_dataset(dataset, config.frame, root, name, max_rows_per_split)
        summaries = summarise_variables(dataset, adapted, name)
        train = adapted["train"].targets
        count = min(config.check.replay_rows, len(train))
        rows = np.linspace(0, len(train) - 1, count).round().astype(int)
        poses = train.iloc[rows][[f"pose_{i}" for i in range(1, 7)]].to_numpy(np.float64)
        share = replay_contact_share(config, dataset.contact, poses)
        report = DatasetReport(name, dataset.contact, dataset.kind, {s: len(a.image_paths) for s, a in adapted.items()},
                               adapted["train"].source_size_px, [asdict(s) for s in summaries], count, share)
        if share < config.check.min_contact_share:
            raise TactileDataError(
                f"dataset {name!r}: only {share:.0%} of {count} replayed training rows make contact in simulation "
                f"(need {config.check.min_contact_share:.0%}): the renders are blank, so the frame or depth mapping "
                f"is wrong (check [frame] axes / origin_mm and the sign of the depth column; pose z must be the "
                f"indentation, > [replay] surface_depth_mm = {config.replay.surface_depth_mm} mm in contact)")
        reports.append(report)
    return reports


def format_report(config: ExperimentConfig, reports: list[DatasetReport]) -> str:
    lines = [f"config {config.path}: sensor {config.name!r}, {len(reports)} datasets"]
    for report in reports:
        lines.append(f"  {report.name}: {report.contact} {report.kind}, rows train {report.rows['train']} "
                     f"val {report.rows['val']}, images {report.source_image_px[0]}x{report.source_image_px[1]} px, "
                     f"replay contact {report.contact_share:.0%} of {report.replayed_rows}")
        varying = [f"{v['name']} [{v['low']:.3g}, {v['high']:.3g}]" for v in report.variables if v["varies"]]
        constant = [v["name"] for v in report.variables if not v["varies"]]
        lines.append(f"    varying: {', '.join(varying) or 'none'}")
        lines.append(f"    constant: {', '.join(constant) or 'none'}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--max-rows", type=int, default=None,
                        help="check only the first N rows of each split (default: every row)")
    parser.add_argument("--json", type=Path, default=None, help="also write the summary to this JSON file")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.config import load_config

    start = time.perf_counter()
    config = load_config(args.config)
    root = data_root(args.data, holding=config_files(config.datasets.values(), args.config))
    reports = check(config, root, args.max_rows)
    print(format_report(config, reports))
    print(f"ok in {time.perf_counter() - start:.1f} s")
    if args.json is not None:
        write_json(args.json, {"config": str(args.config), "sensor": config.name,
                               "datasets": [asdict(report) for report in reports]})
    return 0
