"""``simshear pipeline check CONFIG``: validate an experiment config and its data before anything trains.

For each dataset of the config (:mod:`simshear_gym.pipelines.config`): every CSV present with the named columns,
every image present, decodable and of one size, every label finite, every variable declared present varying, both
splits non-empty (:func:`simshear_gym.data.adapter.adapt_dataset`); then a sample of its training rows is replayed
in simulation with the config's sensor, replay geometry and frame, and the share of renders that show any contact
is reported: below ``[check] min_contact_share`` the frame or depth mapping is wrong, and that is an error, never
a silent set of blank images. Last, ``[check] frame_rows`` rows check that the real images change with each label
as the replayed renders do (the frame check, below): a label the wrong way round, a label on an axis the stimulus
ignores or a wrong mount angle is an error naming the config key behind it. Prints a summary; ``--json PATH``
writes it too.

The frame check. A config's frame, signs and units can be wrong and still put the replayed sensor in contact: a
depth whose sign is flipped, a tilt about the wrong axis, an edge angle counted the other way round, two data sets
recorded with different mounts under one ``[frame]``. The translators and GDNNs then learn a wrong mapping and cost
accuracy downstream, silently. The frame check reads the rows themselves:

1. For a sample of training rows (spread over the split), the real image's *change map* (its absolute difference
   from the rows' median image, blurred, :data:`GRID` x :data:`GRID` cells) and the replayed render of the row's
   labels (:data:`GRID` x :data:`GRID` cells of contact depth).
2. The *agreement* of the two: how much of the change maps' variance a local linear map from the renders explains,
   each cell from the 3 x 3 render cells around it (pooled R^2). A local map can learn how a real sensor's pins
   answer a sim depth (gain, blur), but not move the contact across the image, so it cannot undo a flipped tilt.
3. For each simulation variable that varies in the rows and changes the renders, the same agreement with that
   variable flipped (a depth mirrored within its range, an angle or offset negated). Where the flipped labels
   agree better with the real images than the config's own, the config maps that variable the wrong way round:
   an error naming the lab's label key and the ``[frame]`` axis behind it. "Better" is a paired test over the
   rows (each row's held-out residual under both labellings, :data:`MIN_T` standard errors apart), so that the
   noise of a small or shear-dominated sample does not raise a false alarm.
4. For each variable that varies in the rows, the share of the change maps' variance it explains alone
   (``real_r2``, each cell linear in the variable and its square) and how much the renders change with it: a
   variable that changes the real images but none of the renders (a depth or tilt mapped onto an axis the flat
   surface ignores) is an error too, and so are renders that agree with none of the real images' change while a
   variable explains much of it (a depth whose sign or origin leaves the renders barely touching).
5. The agreement with the sensor turned about its own axis by 90, 180 and 270 deg (a surface's tilt vector turned,
   an edge's angle offset): where a turn agrees better, the mount angle is wrong.

The renders answer a depth over a smaller area than a real dome does, so the agreement cannot judge a variable's
scale finely (a larger depth range always agrees a little better); a unit error gross enough to leave the renders
unchanged shows as ``ignored``, one that takes the sensor out of contact fails the check's contact share first.
On the shipped tactip331 sets every flip and turn agrees worse than the config (``docs/experiments.md``, Frame
check).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.data.adapter import (
    VARIABLES,
    DatasetConfig,
    FrameConfig,
    adapt_dataset,
    summarise_variables,
)
from simshear_gym.data.tactile_set import TactileDataError
from simshear_gym.io import write_json
from simshear_gym.tables import add_set_argument

if TYPE_CHECKING:  # the config imports the simulator (pybullet): in run, so that --help stays light
    from simshear_gym.pipelines.config import ExperimentConfig


# -------------------------------------------------------------------------------------------- the frame check
GRID = 16
"""Cells per side of the change maps and renders compared."""
BLUR_PX = 4.0
"""Blur of the real change map (a 128 px image), so that a pin's move counts in its neighbourhood."""
MIN_AGREEMENT = 0.005
"""The least held-out R^2 a flipped or turned labelling must reach to count as agreeing better: images that carry
no signal (noise) agree with nothing (about 0 or below), whatever the labels."""
MIN_T = 3.0
"""How many standard errors (of the mean per-row difference of held-out residuals) a flipped or turned labelling
must agree better by."""
MIN_FRAME_ROWS = 128
"""The fewest rows the check compares: with fewer, the local maps fitted on half of them show too little of the
renders' agreement to tell a wrong frame from noise (a data set with fewer training rows is not checked)."""
MIN_RENDER_CHANGE = 0.1
"""How much a variable's flip must change the renders (relative to their spread over the rows) to be checked."""
MIN_REAL_R2 = 0.05
"""The share of the real change maps a variable must explain alone to count as changing the real images (noise
images: about 0.01 over 240 rows)."""
RIDGE = 0.1
"""Ridge penalty of the local maps, relative to the renders' mean cell variance: a cell that the contact seldom
reaches (all zero in most rows) is shrunk to the mean, not fitted to the few rows that reach it."""
POSE_VARIABLES = VARIABLES[:6]
_AXIS_NAMES = ("x", "y", "z")


@dataclass(frozen=True)
class Fit:
    """How well renders explain the real change maps: the pooled held-out R^2 and each row's held-out squared
    residual (summed over cells), for paired comparisons of two labellings."""

    r2: float
    row_residuals: np.ndarray

    def beaten_by(self, other: Fit) -> float:
        """How many standard errors ``other`` fits the rows better by (the mean per-row residual difference over
        its standard error; positive: ``other`` fits better)."""
        difference = self.row_residuals - other.row_residuals
        error = float(difference.std(ddof=1)) / np.sqrt(len(difference)) + 1e-12
        return float(difference.mean()) / error


@dataclass(frozen=True)
class VariableAgreement:
    """One simulation variable's check: the agreement of the real change maps with the config's renders and with
    the renders of the variable flipped (``flip_t``: standard errors by which the flip fits better), how much the
    renders change when it flips (relative to their spread), how much of the real change maps it explains alone;
    ``verdict``: ``ok``, ``flipped``, ``ignored`` (changes the real images but not the renders) or ``unchecked``
    (changes neither much)."""

    variable: str
    agreement: float
    flipped_agreement: float
    flip_t: float
    render_change: float
    real_r2: float
    verdict: str


def change_maps(images: np.ndarray) -> np.ndarray:
    """(N, S, S) uint8 real images -> (N, GRID, GRID) blurred absolute differences from their median image."""
    values = images.astype(np.float32) / 255.0
    median = np.median(values, axis=0)
    sigma = BLUR_PX * values.shape[-1] / 128.0
    return np.stack([_cells(cv2.GaussianBlur(np.abs(image - median), (0, 0), sigma)) for image in values])


def _cells(image: np.ndarray) -> np.ndarray:
    return cv2.resize(np.asarray(image, np.float32), (GRID, GRID), interpolation=cv2.INTER_AREA)


def render_cells(renders: np.ndarray) -> np.ndarray:
    """(N, S, S) renders -> (N, GRID, GRID) cell means."""
    return np.stack([_cells(render) for render in renders])


def local_fit(render_maps: np.ndarray, real_maps: np.ndarray) -> Fit:
    """Each real cell predicted from the 3 x 3 render cells around it by a ridge fit (:data:`RIDGE`) on the other
    half of the rows (two folds: even and odd rows): the :class:`Fit` of the held-out predictions."""
    rows = len(real_maps)
    folds = (np.arange(rows) % 2 == 0, np.arange(rows) % 2 == 1)
    renders = render_maps.astype(np.float64)
    ridge = RIDGE * (rows / 2) * float(renders.var(axis=0).mean() + 1e-12)
    row_residuals = np.zeros(rows)
    total = 0.0
    for i in range(GRID):
        for j in range(GRID):
            around = renders[:, max(i - 1, 0):i + 2, max(j - 1, 0):j + 2].reshape(rows, -1)
            target = real_maps[:, i, j].astype(np.float64)
            for fit, held in (folds, folds[::-1]):
                x_mean, y_mean = around[fit].mean(axis=0), target[fit].mean()
                x, y = around[fit] - x_mean, target[fit] - y_mean
                weights = np.linalg.solve(x.T @ x + ridge * np.eye(x.shape[1]), x.T @ y)
                predicted = (around[held] - x_mean) @ weights + y_mean
                row_residuals[held] += (target[held] - predicted) ** 2
                total += float(np.sum((target[held] - y_mean) ** 2))
    return Fit(1.0 - float(row_residuals.sum()) / total if total > 0 else 0.0, row_residuals)


def explained_by(values: np.ndarray, real_maps: np.ndarray) -> float:
    """Pooled R^2 of every real cell from one variable (intercept, value, value^2)."""
    scaled = (values - values.mean()) / (values.std() + 1e-12)
    design = np.column_stack([np.ones(len(values)), scaled, scaled ** 2])
    target = real_maps.reshape(len(values), -1).astype(np.float64)
    coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
    total = float(np.sum((target - target.mean(axis=0)) ** 2))
    return 1.0 - float(np.sum((target - design @ coefficients) ** 2)) / total if total > 0 else 0.0


def flipped(poses: np.ndarray, index: int) -> np.ndarray:
    """``poses`` (N, 6: x, y, z mm, Rx, Ry, Rz deg) with variable ``index`` the wrong way round: a depth mirrored
    within its range (a depth sign error with the origin fitted to the contact), anything else negated."""
    out = poses.copy()
    if index == 2:
        out[:, 2] = poses[:, 2].max() + poses[:, 2].min() - poses[:, 2]
    else:
        out[:, index] = -poses[:, index]
        if index >= 3:
            out[:, index] = (out[:, index] + 180.0) % 360.0 - 180.0
    return out


def turned(poses: np.ndarray, contact: str, turn_deg: float) -> np.ndarray:
    """``poses`` as a sensor mounted ``turn_deg`` further about its own axis would record them: a surface's tilt
    vector (Rx, Ry) turned, an edge's angle (Rz) offset."""
    out = poses.copy()
    if contact == "edge":
        out[:, 5] = (poses[:, 5] + turn_deg + 180.0) % 360.0 - 180.0
    else:
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        out[:, 3], out[:, 4] = c * poses[:, 3] - s * poses[:, 4], s * poses[:, 3] + c * poses[:, 4]
    return out


@dataclass(frozen=True)
class FrameAgreement:
    """The check of one data set: the agreement of its real change maps with the config's renders, each varying
    variable's :class:`VariableAgreement`, and the agreement with the sensor turned about its axis by 90, 180 and
    270 deg (``turns``: {deg: [agreement, standard errors by which it fits better]}; a wrong mount angle)."""

    rows: int
    agreement: float
    variables: tuple[VariableAgreement, ...]
    turns: dict[int, tuple[float, float]]

    def best_turn_deg(self) -> int | None:
        """The turn that fits the real images better than the config (:data:`MIN_T`, :data:`MIN_AGREEMENT`; the
        best one), or None."""
        better = {turn: value for turn, (value, t) in self.turns.items() if t > MIN_T and value >= MIN_AGREEMENT}
        return max(better, key=better.get) if better else None


def check_frame(poses: np.ndarray, images: np.ndarray, render, contact: str, shear: bool = False) -> FrameAgreement:
    """The :class:`FrameAgreement` of a data set's rows (see the module docstring).

    ``poses``: (N, 6) rows in the simulation's frame; ``images``: their (N, S, S) real images; ``render``: (M, 6)
    poses -> (M, S', S') renders; ``contact``: ``surface`` or ``edge``. A variable is ``flipped`` where its flip
    fits the real images better than the config (by :data:`MIN_T` standard errors, to at least
    :data:`MIN_AGREEMENT`); ``ignored`` where it explains :data:`MIN_REAL_R2` of the real change maps alone but its
    flip changes the renders by less than :data:`MIN_RENDER_CHANGE` of their spread; except, in a ``shear`` set, the
    sensor's turn Rz (it turns the shear into the sensor's frame, which the shear-free renders cannot show)."""
    real_maps = change_maps(images)
    base_renders = render_cells(render(poses))
    base = local_fit(base_renders, real_maps)
    spread = float(np.linalg.norm(base_renders - base_renders.mean(axis=0))) + 1e-12
    results = []
    for index, variable in enumerate(POSE_VARIABLES):
        values = poses[:, index]
        if np.ptp(values) <= 1e-6:
            continue
        flip_renders = render_cells(render(flipped(poses, index)))
        change = float(np.linalg.norm(flip_renders - base_renders)) / spread
        real_r2 = explained_by(values, real_maps)
        if change < MIN_RENDER_CHANGE:
            flip, t = base.r2, 0.0
            shear_turn = shear and variable == "pose_rz"
            verdict = "ignored" if real_r2 >= MIN_REAL_R2 and not shear_turn else "unchecked"
        else:
            fit = local_fit(flip_renders, real_maps)
            flip, t = fit.r2, base.beaten_by(fit)
            verdict = "flipped" if t > MIN_T and flip >= MIN_AGREEMENT else "ok"
        results.append(VariableAgreement(variable, round(base.r2, 4), round(flip, 4), round(t, 2), round(change, 4),
                                         round(real_r2, 4), verdict))
    turns = {}
    if np.ptp(poses[:, 5:] if contact == "edge" else poses[:, 3:5], axis=0).max() > 1e-6:
        for turn in (90, 180, 270):
            fit = local_fit(render_cells(render(turned(poses, contact, turn))), real_maps)
            turns[turn] = (round(fit.r2, 4), round(base.beaten_by(fit), 2))
    return FrameAgreement(len(poses), round(base.r2, 4), tuple(results), turns)


def lab_source(dataset: DatasetConfig, frame: FrameConfig, variable: str) -> str:
    """The config keys a simulation pose variable comes from: its lab label (through ``[frame] axes``)."""
    index = POSE_VARIABLES.index(variable)
    axis = index % 3
    lab_axis = frame.axes[axis]
    lab_name = f"pose_{'r' if index >= 3 else ''}{lab_axis.lstrip('+-')}"
    source = dataset.labels.get(lab_name)
    described = (f"labels.{lab_name} (column {source.column!r}, scale {source.scale:g})"
                 if source is not None and source.column is not None else f"labels.{lab_name}")
    turn = (f", turned by [frame] mount_rz_deg = {frame.mount_rz_deg:g}"
            if frame.mount_rz_deg and index in (0, 1, 5) else "")
    return f"{described} through [frame] axes[{axis}] = {lab_axis!r} (sim {_AXIS_NAMES[axis]}){turn}"


# ----------------------------------------------------------------------------------------------- the datasets
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
    from simshear_gym.pipelines.run import config_and_root

    start = time.perf_counter()
    config, root = config_and_root(args)
    reports = check(config, root, args.max_rows)
    print(format_report(config, reports))
    print(f"ok in {time.perf_counter() - start:.1f} s")
    if args.json is not None:
        write_json(args.json, {"command": recorded_command("simshear pipeline check", add_arguments, args),
                               "config": str(args.config), "sensor": config.name,
                               "datasets": [asdict(report) for report in reports]})
    return 0
