"""The data-collection protocol of a sensor's ``[collect]`` table: which contacts to record, and the arm's path
for each.

A row is a contact in the simulation's labels (work frame, :mod:`simshear_gym.data.labels`: x, y in the stimulus
plane, z into the stimulus, so a pose's z is the indentation, the stimulus's face at ``surface_depth_mm``; angles
in degrees; the move: the sensor touched at pose - move and slid, in contact, to pose). :func:`draw_rows` draws the
rows from the protocol's seed, the same for the robot (``simshear collect-real``) and the simulation
(``simshear collect --protocol``), so a lab can compare its real set with the simulated one row by row.

Per row the follower (a downward TacTip on an MG400: x, y, z and the turn about the vertical only) goes: from the
hover point above the row's touch, down to pose - move, slides to pose (a shear row; a tap row has no move), settles,
the camera averages ``frames_per_capture`` frames, and the arm lifts and travels to the next row's hover point in
one move. :func:`row_waypoints` gives the flange poses (robot base frame) through the work frame's place in the base
frame (``work_origin_base_mm``: the stimulus point the sensor touches at pose x = y = 0, at the face's height;
``work_rz_deg``: the work x axis turned about the base's vertical) and the sensor's mount. :func:`row_time_s` is the
robot time of a row from trapezoidal speed profiles at the protocol's speed and acceleration.

Settings that the arm cannot do, or the safety layer would refuse, are errors before the arm moves
(:meth:`CollectProtocol.check_reach`): a tilt (the MG400 cannot tilt its tool), a waypoint outside the arm's reach
or the safety layer's workspace, a hover point below the stimulus's face, a slide or a move longer than one queued
move may jump, a speed above the safety layer's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pandas as pd

from simshear_gym.contract import TacTipMount
from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS, SURFACE_DEPTH_MM
from simshear_gym.robots.mg400.frames import T_base_flange_to_pose
from simshear_gym.robots.mg400.kinematics import KinematicsError, check_pose_reachable
from simshear_gym.transforms import invert, pose_to_matrix

VARIABLES = ("pose_x", "pose_y", "pose_z", "pose_rx", "pose_ry", "pose_rz",
             "move_x", "move_y", "move_z", "move_rx", "move_ry", "move_rz")
"""The twelve label variables, in the order of ``pose_1..6``, ``move_1..6``."""
LEVEL_ONLY = ("pose_rx", "pose_ry", "move_z", "move_rx", "move_ry")
"""Variables a level 4-axis arm cannot vary (its tool never tilts; a slide keeps its depth)."""


@dataclass(frozen=True)
class CollectProtocol:
    """The ``[collect]`` table of a sensor's config (units in the names; ranges in the labels' work frame).

    Attributes:
        stimulus: ``surface`` or ``edge`` (the edge along work x at the replay's ``edge_y_mm``).
        work_origin_base_mm: where the work frame's origin lies in the robot's base frame (x, y of the stimulus
            point touched at pose x = y = 0; z of the stimulus's face, refined by the touch-off).
        work_rz_deg: the work frame's x axis, turned about the base's vertical (an edge's direction), deg.
        ranges: variable (:data:`VARIABLES`) -> ``[low, high]``, drawn uniformly; variables not named stay 0
            (``pose_z``: the indentation, in the labels' convention, so it must lie past ``surface_depth_mm``).
        rows: rows to record; seed: the rows' generator.
        tap_share: share of rows recorded as taps (no move), the others as shear rows.
        hover_mm: height of the hover points above the stimulus's face.
        speed_mm_s, acceleration_mm_s2: the arm's queued moves (trapezoidal profiles).
        settle_s: wait after the last move of a row, before the capture.
        frames_per_capture: camera frames averaged per row; frame_period_s: the camera's frame period.
        surface_depth_mm: the labels' depth of the stimulus's face (the config's ``[replay] surface_depth_mm``).
        mount: the TacTip on the flange.
    """

    stimulus: Literal["surface", "edge"]
    work_origin_base_mm: tuple[float, float, float]
    work_rz_deg: float = 0.0
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    rows: int = 500
    seed: int = 0
    tap_share: float = 0.5
    hover_mm: float = 3.0
    speed_mm_s: float = 50.0
    acceleration_mm_s2: float = 800.0
    settle_s: float = 0.1
    frames_per_capture: int = 1
    frame_period_s: float = 1.0 / 30.0
    surface_depth_mm: float = SURFACE_DEPTH_MM
    mount: TacTipMount = TacTipMount()

    def __post_init__(self) -> None:
        if self.stimulus not in ("surface", "edge"):
            raise ValueError(f"stimulus must be 'surface' or 'edge', got {self.stimulus!r}")
        unknown = sorted(set(self.ranges) - set(VARIABLES))
        if unknown:
            raise ValueError(f"ranges: unknown variable {unknown[0]!r}; expected one of {list(VARIABLES)}")
        for name, (low, high) in self.ranges.items():
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(f"ranges.{name} = [{low}, {high}]: expected finite low <= high")
        tilted = [name for name in LEVEL_ONLY if name in self.ranges and self.ranges[name] != (0.0, 0.0)]
        if tilted:
            raise ValueError(f"ranges.{tilted[0]}: the MG400 cannot tilt its tool or change depth while sliding; "
                             f"it can vary {[v for v in VARIABLES if v not in LEVEL_ONLY]}")
        depth = self.ranges.get("pose_z")
        if depth is None or depth[0] <= self.surface_depth_mm:
            raise ValueError(f"ranges.pose_z = {list(depth) if depth else None}: the indentation must lie past the "
                             f"stimulus's face (surface_depth_mm = {self.surface_depth_mm} mm), e.g. "
                             f"[{self.surface_depth_mm + 0.5:g}, {self.surface_depth_mm + 3.0:g}]")
        if self.rows < 1:
            raise ValueError(f"rows must be >= 1, got {self.rows!r}")
        if not 0.0 <= self.tap_share <= 1.0:
            raise ValueError(f"tap_share must be in [0, 1], got {self.tap_share!r}")
        if self.hover_mm <= 0:
            raise ValueError(f"hover_mm = {self.hover_mm!r}: the hover points must lie above the stimulus's face "
                             "(> 0 mm)")
        for name in ("speed_mm_s", "acceleration_mm_s2", "frame_period_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.settle_s < 0 or self.frames_per_capture < 1:
            raise ValueError(f"settle_s must be >= 0 and frames_per_capture >= 1, got {self.settle_s!r}, "
                             f"{self.frames_per_capture!r}")

    # ------------------------------------------------------------------------------------------------ rows
    def draw_rows(self) -> pd.DataFrame:
        """The protocol's rows (``pose_1..6``, ``move_1..6``, ``kind``: tap | shear), drawn from its seed and
        visited in order of the sensor's turn Rz (an edge's angle over +-180 deg would otherwise turn the sensor
        half a turn between rows)."""
        rng = np.random.default_rng(self.seed)
        values = np.zeros((self.rows, len(VARIABLES)))
        for index, name in enumerate(VARIABLES):
            low, high = self.ranges.get(name, (0.0, 0.0))
            values[:, index] = rng.uniform(low, high, self.rows)
        taps = rng.random(self.rows) < self.tap_share
        values[taps, 6:] = 0.0
        order = np.argsort(values[:, 5], kind="stable")  # by the sensor's turn: no row turns it far from the last
        table = pd.DataFrame(values[order], columns=list(POSE_COLUMNS + MOVE_COLUMNS))
        table["kind"] = np.where(taps[order], "tap", "shear")
        return table

    # --------------------------------------------------------------------------------------------- the path
    def T_base_work(self, touch_z_base_mm: float | None = None) -> np.ndarray:
        """The work frame in the base frame: origin at ``work_origin_base_mm`` (its z: the face's height, or the
        touch-off's ``touch_z_base_mm``) moved up by ``surface_depth_mm`` (so a pose's z is the indentation past
        the face's depth), x turned by ``work_rz_deg``, z pointing down into the stimulus."""
        x, y, z = self.work_origin_base_mm
        z = z if touch_z_base_mm is None else touch_z_base_mm
        return pose_to_matrix(np.array([x, y, z + self.surface_depth_mm, 180.0, 0.0, self.work_rz_deg]))

    def flange_pose(self, pose_work: np.ndarray, T_base_work: np.ndarray) -> np.ndarray:
        """The level flange pose ``(x, y, z mm, r deg)`` that puts the sensor at ``pose_work`` (x, y, z mm, Rx,
        Ry, Rz deg in the work frame)."""
        T_base_sensor = T_base_work @ pose_to_matrix(np.asarray(pose_work, dtype=np.float64))
        return T_base_flange_to_pose(T_base_sensor @ invert(self.mount.T_flange_sensor()))

    def row_waypoints(self, row: pd.Series, T_base_work: np.ndarray) -> dict[str, np.ndarray]:
        """A row's flange poses: ``hover`` (above pose - move), ``touch`` (pose - move), ``pose`` (after the
        slide; the touch itself for a tap row)."""
        pose = row[list(POSE_COLUMNS)].to_numpy(np.float64)
        move = row[list(MOVE_COLUMNS)].to_numpy(np.float64)
        touch = pose - move
        hover = touch.copy()
        hover[2] = self.surface_depth_mm - self.hover_mm
        return {name: self.flange_pose(point, T_base_work) for name, point in
                (("hover", hover), ("touch", touch), ("pose", pose))}

    def move_time_s(self, distance_mm: float) -> float:
        """A queued move's time over ``distance_mm`` with a trapezoidal (or triangular) speed profile."""
        v, a = self.speed_mm_s, self.acceleration_mm_s2
        if distance_mm <= 0:
            return 0.0
        if distance_mm >= v * v / a:
            return distance_mm / v + v / a
        return 2.0 * math.sqrt(distance_mm / a)

    def row_time_s(self, waypoints: dict[str, np.ndarray], next_hover: np.ndarray | None) -> float:
        """Robot time of a row: down, slide, settle, capture, then lift and travel to ``next_hover`` (or back up
        to its own hover point) in one move. Turns about the vertical ride along with the moves."""
        def distance(a: np.ndarray, b: np.ndarray) -> float:
            return float(np.linalg.norm(a[:3] - b[:3]))

        end = waypoints["hover"] if next_hover is None else next_hover
        return (self.move_time_s(distance(waypoints["hover"], waypoints["touch"]))
                + self.move_time_s(distance(waypoints["touch"], waypoints["pose"]))
                + self.settle_s + self.frames_per_capture * self.frame_period_s
                + self.move_time_s(distance(waypoints["pose"], end)))

    def plan(self, touch_z_base_mm: float | None = None) -> tuple[pd.DataFrame, list[dict[str, np.ndarray]],
                                                                   np.ndarray]:
        """(rows, their waypoints, each row's robot time s)."""
        rows = self.draw_rows()
        T_base_work = self.T_base_work(touch_z_base_mm)
        waypoints = [self.row_waypoints(row, T_base_work) for _, row in rows.iterrows()]
        times = np.array([self.row_time_s(points, waypoints[i + 1]["hover"] if i + 1 < len(waypoints) else None)
                          for i, points in enumerate(waypoints)])
        return rows, waypoints, times

    def check_reach(self, waypoints: list[dict[str, np.ndarray]], inside, max_move_mm: float,
                    max_move_deg: float, max_speed_mm_s: float) -> None:
        """Raise ``ValueError`` naming the first row and waypoint the arm cannot reach (kinematics), that
        ``inside`` (flange pose -> bool: the safety layer's workspace) refuses, a move longer than ``max_move_mm``,
        or a move into or along the contact turning more than ``max_move_deg`` (in the air,
        :func:`~simshear_gym.lab.collect_real.move_to` splits a turn); and if the protocol's speed exceeds
        ``max_speed_mm_s``."""
        if self.speed_mm_s > max_speed_mm_s:
            raise ValueError(f"speed_mm_s = {self.speed_mm_s:g} exceeds the safety layer's {max_speed_mm_s:g} mm/s")
        previous = None
        for index, points in enumerate(waypoints):
            for name in ("hover", "touch", "pose"):
                point = points[name]
                try:
                    check_pose_reachable(point)
                except KinematicsError as error:
                    raise ValueError(f"row {index}: the {name} point {np.round(point, 2).tolist()} is out of the "
                                     f"arm's reach ({error}); move work_origin_base_mm or narrow the ranges") from None
                if not inside(point):
                    raise ValueError(f"row {index}: the {name} point {np.round(point, 2).tolist()} lies outside "
                                     "the safety layer's workspace; move work_origin_base_mm or narrow the ranges")
                if previous is not None and np.linalg.norm(point[:3] - previous[:3]) > max_move_mm:
                    raise ValueError(f"row {index}: the move to its {name} point is "
                                     f"{np.linalg.norm(point[:3] - previous[:3]):.1f} mm, over the {max_move_mm:g} mm "
                                     "one queued move may jump; narrow the ranges or lower hover_mm")
                turn_deg = abs((point[3] - previous[3] + 180.0) % 360.0 - 180.0) if previous is not None else 0.0
                if turn_deg > max_move_deg and name != "hover":  # in the air a turn is split into several moves
                    raise ValueError(f"row {index}: the move to its {name} point turns the flange {turn_deg:.1f} "
                                     f"deg, over the {max_move_deg:g} deg one queued move may turn")
                previous = point
