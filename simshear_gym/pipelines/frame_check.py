"""Do a data set's real images change with each label the way the replayed simulation renders do?

A config's frame, signs and units can be wrong and still put the replayed sensor in contact: a depth whose sign is
flipped, a tilt about the wrong axis, an edge angle counted the other way round, two data sets recorded with
different mounts under one ``[frame]``. The translators and GDNNs then learn a wrong mapping and cost accuracy
downstream, silently. This check reads the rows themselves:

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

from dataclasses import dataclass

import cv2
import numpy as np

from simshear_gym.data.adapter import VARIABLES, DatasetConfig, FrameConfig

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
