"""``simshear pipeline check CONFIG``: validate an experiment config and its data before anything trains.

For each dataset of the config (:mod:`simshear_gym.pipelines.config`): every CSV present with the named columns,
every image present, decodable and of one size, every label finite, every variable declared present varying, both
splits non-empty (:func:`simshear_gym.data.adapter.adapt_dataset`); then a sample of its training rows is replayed
in simulation with the config's sensor, replay geometry and frame, and the share of renders that show any contact
is reported: below ``[check] min_contact_share`` the frame or depth mapping is wrong, and that is an error, never
a silent set of blank images. Last, ``[check] frame_rows`` rows check that the real images change with each label
as the replayed renders do (:mod:`simshear_gym.pipelines.frame_check`): a label the wrong way round, a label on an
axis the stimulus ignores or a wrong mount angle is an error naming the config key behind it. Prints a summary;
``--json PATH`` writes it too.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.data.adapter import adapt_dataset, config_files, summarise_variables
from simshear_gym.data.paths import data_root
from simshear_gym.data.tactile_set import TactileDataError
from simshear_gym.io import write_json
from simshear_gym.pipelines.frame_check import (
    MIN_AGREEMENT,
    MIN_FRAME_ROWS,
    MIN_REAL_R2,
    FrameAgreement,
    check_frame,
    lab_source,
)
from simshear_gym.tables import add_set_argument

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
    frame: dict | None = None  # the frame check's FrameAgreement (None: frame_rows = 0, or too few rows)


def replay_contact_share(config: ExperimentConfig, contact: str, poses: np.ndarray) -> float:
    """Share of ``poses`` (sim frame) whose render shows any contact."""
    from simshear_gym.sim.replay import ReplayScene  # pybullet: here, so that --help stays light

    with ReplayScene(contact, config.sensor, config.replay) as scene:
        touched = [bool(scene.render(pose).any()) for pose in poses]
    return float(np.mean(touched)) if touched else 0.0


UNREPRESENTED = {"move_z": "a slide that changes the depth: the translator's shear input masks z, and the depth is "
                            "the pose's"}
"""Variables the chain has no place for, an error where they vary (not silently dropped)."""


def frame_agreement(config: ExperimentConfig, name: str, train) -> FrameAgreement:
    """The frame check of dataset ``name`` on ``[check] frame_rows`` of its adapted training rows ``train``
    (spread over the split); raises ``TactileDataError`` naming the config key behind the first problem."""
    from simshear_gym.sim.replay import ReplayScene  # pybullet: here, so that --help stays light

    dataset = config.datasets[name]
    rows = np.linspace(0, len(train.targets) - 1, min(config.check.frame_rows, len(train.targets))).round()
    rows = np.unique(rows.astype(int))
    poses = train.targets.iloc[rows][[f"pose_{i}" for i in range(1, 7)]].to_numpy(np.float64)
    with ReplayScene(dataset.contact, config.sensor, config.replay) as scene:
        found = check_frame(poses, train.images[rows], lambda batch: np.stack([scene.render(p) for p in batch]),
                            dataset.contact, shear=dataset.kind == "shear")
    frame = config.frame_for(name)
    frame_key = f"[datasets.{name}.frame]" if name in config.dataset_frames else "[frame]"
    strongest = max(found.variables, key=lambda result: result.real_r2, default=None)
    if strongest is not None and found.agreement < MIN_AGREEMENT and strongest.real_r2 >= MIN_REAL_R2:
        raise TactileDataError(
            f"dataset {name!r}: the real images change with sim {strongest.variable} (it alone explains "
            f"{strongest.real_r2:.0%} of their change) but the replayed renders agree with none of it (agreement "
            f"{found.agreement:.3f}, {found.rows} rows): check the sign and origin of "
            f"{lab_source(dataset, frame, strongest.variable)}, and {frame_key} origin_mm (a set recorded with "
            f"another mount gives its own [datasets.{name}.frame])")
    for result in found.variables:
        source = lab_source(dataset, frame, result.variable)
        if result.verdict == "flipped":
            raise TactileDataError(
                f"dataset {name!r}: the real images change with sim {result.variable} the opposite way to the "
                f"replayed renders (agreement {result.flipped_agreement:.3f} with it flipped against "
                f"{result.agreement:.3f} as configured, {result.flip_t:.1f} standard errors over {found.rows} rows): "
                f"{source} is the wrong way round; check "
                f"its sign (scale = -1) or {frame_key}")
        if result.verdict == "ignored":
            raise TactileDataError(
                f"dataset {name!r}: the real images change with sim {result.variable} (it alone explains "
                f"{result.real_r2:.0%} of their change) but the replayed {dataset.contact} renders do not: {source} "
                f"lands on an axis the stimulus ignores (a set recorded with another mount? give it its own "
                f"[datasets.{name}.frame]) or its unit is off")
    turn = found.best_turn_deg()
    if turn is not None:
        where = (f"{frame_key} mount_rz_deg" if dataset.contact == "edge" else
                 f"which lab tilts {frame_key} axes make sim Rx and Ry (and their signs)")
        raise TactileDataError(
            f"dataset {name!r}: the real images agree better with the sensor turned {turn} deg about its axis "
            f"({found.turns[turn][0]:.3f} against {found.agreement:.3f} as configured, {found.turns[turn][1]:.1f} "
            f"standard errors over {found.rows} rows): check {where} (a set recorded with another mount gives "
            f"its own [datasets.{name}.frame])")
    return found


def check(config: ExperimentConfig, root: Path, max_rows_per_split: int | None = None) -> list[DatasetReport]:
    """Check every dataset (see the module docstring); raises ``TactileDataError`` on the first problem."""
    reports = []
    for name, dataset in config.datasets.items():
        adapted = adapt_dataset(dataset, config.frame_for(name), root, name, max_rows_per_split)
        summaries = summarise_variables(dataset, adapted, name)
        unrepresented = [s.name for s in summaries if s.varies and s.name in UNREPRESENTED]
        if unrepresented:
            raise TactileDataError(
                f"dataset {name!r}: {unrepresented[0]} varies ({UNREPRESENTED[unrepresented[0]]}); neither the "
                f"translators nor the GDNNs represent it, so it would be dropped: hold it fixed (value = 0.0) or "
                f"check which lab variable [frame] maps onto it")
        train = adapted["train"].targets
        count = min(config.check.replay_rows, len(train))
        rows = np.linspace(0, len(train) - 1, count).round().astype(int)
        poses = train.iloc[rows][[f"pose_{i}" for i in range(1, 7)]].to_numpy(np.float64)
        share = replay_contact_share(config, dataset.contact, poses)
        if share < config.check.min_contact_share:
            raise TactileDataError(
                f"dataset {name!r}: only {share:.0%} of {count} replayed training rows make contact in simulation "
                f"(need {config.check.min_contact_share:.0%}): the renders are blank, so the frame or depth mapping "
                f"is wrong (the depth comes from {lab_source(dataset, config.frame_for(name), 'pose_z')}: check its "
                f"sign and [frame] origin_mm; pose z must be the indentation, > [replay] surface_depth_mm = "
                f"{config.replay.surface_depth_mm} mm in contact)")
        checked = config.check.frame_rows and len(adapted["train"].targets) >= MIN_FRAME_ROWS
        frame = asdict(frame_agreement(config, name, adapted["train"])) if checked else None
        reports.append(DatasetReport(name, dataset.contact, dataset.kind,
                                     {s: len(a.image_paths) for s, a in adapted.items()},
                                     adapted["train"].source_size_px, [asdict(s) for s in summaries], count, share,
                                     frame))
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
        if report.frame is None:
            lines.append(f"    frame check: not run ([check] frame_rows = 0, or under {MIN_FRAME_ROWS} training rows)")
        else:
            frame = report.frame
            verdicts = ", ".join(f"{v['variable']} {v['verdict']} ({v['flipped_agreement']:.3f} flipped)"
                                 for v in frame["variables"])
            turns = " / ".join(f"{value:.3f}" for value, _ in frame["turns"].values()) or "-"
            lines.append(f"    frame check ({frame['rows']} rows): agreement {frame['agreement']:.3f}; {verdicts}; "
                         f"turned 90 / 180 / 270 deg {turns}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    add_set_argument(parser)
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--max-rows", type=int, default=None,
                        help="check only the first N rows of each split (default: every row)")
    parser.add_argument("--json", type=Path, default=None, help="also write the summary to this JSON file")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.config import load_config

    start = time.perf_counter()
    config = load_config(args.config, args.settings)
    root = data_root(args.data, holding=config_files(config.datasets.values(), args.config))
    reports = check(config, root, args.max_rows)
    print(format_report(config, reports))
    print(f"ok in {time.perf_counter() - start:.1f} s")
    if args.json is not None:
        write_json(args.json, {"command": recorded_command("simshear pipeline check", add_arguments, args),
                               "config": str(args.config), "sensor": config.name,
                               "datasets": [asdict(report) for report in reports]})
    return 0
