"""``simshear calibrate-arms``: where the leader's base stands in the follower's frame.

::

    simshear calibrate-arms --leader 192.168.1.6 --follower 192.168.2.6 --camera 0 --guess 600 0 0 180 \\
        --out runs/calibration/arms.json
    simshear calibrate-arms --fixture 690 0 0 180 --out runs/calibration/arms.json
    simshear calibrate-arms --rehearsal --rig-leader-base 600 0 0 180 --guess 592 6 2 176

**By touch** (default): the follower's TacTip touches the leader's plate and holds its point of the plate while
the leader carries it through a set of poses. It is the tracking run's machinery
(:class:`~simshear_gym.lab.experiment.ExperimentRun`): the follower hovers above the plate where the ``--guess``
(a tape-measure estimate, within about 10 mm and 5 deg) puts it, descends until its GDNN reads the touch, and the
servo controller keeps the point (shear back to zero; the follower turns with the leader's turns, so the sensor
keeps its angle to the plate) while the leader moves from pose to pose
(:class:`WaypointPlan`: translations along and across, a lift and turns about the flange axis) and dwells at each.
At the end of every dwell, the follower's sensor position ``p_i`` (fed-back flange pose and mount), the leader's
fed-back flange pose ``F_i`` and the GDNN's depth ``d_i`` are averaged over ``average_s``. The fit
(:func:`fit_base_to_base`, nonlinear least squares) finds the transform ``T`` (x, y, z, rz: both bases stand level)
and the touched point ``(qx, qy)`` on the plate's face that best explain ``p_i = T F_i T_flange_face (qx, qy,
-(d_i - 2.2))``: the turns tell where the point sits from the flange axis, the translations turn the leader's
axes onto the follower's. Its RMS residual is reported; the kinematic stop conditions of the tracking run are off
(the transform is only a guess yet), the image's contact check and every other stop stay on.

**From a fixture** (``--fixture X Y Z RZ``): the arms stand on a fixture whose drawing gives the leader base in
the follower's frame; the file records it with residual 0.

The file (:class:`~simshear_gym.lab.frames.ArmsCalibration`, JSON) is what ``simshear experiment --calibration``
reads.
"""

from __future__ import annotations

import argparse
import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.data.labels import SURFACE_DEPTH_MM
from simshear_gym.io import write_json
from simshear_gym.lab.endpoints import ArmEndpoint
from simshear_gym.lab.frames import ArmsCalibration, BaseToBase, PlateMount
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange

logger = logging.getLogger(__name__)

DEFAULT_WAYPOINTS_MM_DEG: tuple[tuple[float, float, float, float], ...] = (
    (0.0, 0.0, 0.0, 0.0), (-40.0, 0.0, 0.0, 0.0), (-40.0, 40.0, 0.0, 30.0), (0.0, 40.0, 10.0, 0.0),
    (0.0, -40.0, 0.0, -30.0), (-40.0, -40.0, 0.0, 30.0), (0.0, 0.0, 0.0, -30.0), (0.0, 0.0, 0.0, 0.0))
"""The leader's calibration poses: offsets (dx, dy, dz mm, dR deg) from its start pose, its base frame (x only
away from its base's side where the follower stands, so that a follower as close as 600 mm stays in reach)."""


@dataclass(frozen=True)
class WaypointPlan:
    """The leader's flange through ``waypoints`` (offsets from ``start``) at ``speed_mm_s`` / ``turn_deg_s``,
    dwelling ``dwell_s`` at each (the first dwell at the start)."""

    start: tuple[float, float, float, float]
    waypoints: tuple[tuple[float, float, float, float], ...] = DEFAULT_WAYPOINTS_MM_DEG
    speed_mm_s: float = 5.0
    turn_deg_s: float = 3.0
    dwell_s: float = 3.0
    name: str = "calibration"

    def __post_init__(self) -> None:
        if len(self.waypoints) < 4:
            raise ValueError(f"WaypointPlan needs at least 4 waypoints (turns and moves), got {len(self.waypoints)}")
        for name in ("speed_mm_s", "turn_deg_s", "dwell_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"WaypointPlan.{name} must be finite and > 0, got {value!r}")

    def _segments(self) -> list[tuple[float, float, np.ndarray, np.ndarray]]:
        """(start time, end of motion, from, to) per waypoint; the dwell follows the motion."""
        out, time_s = [], 0.0
        previous = np.array(self.waypoints[0], dtype=float)
        for index, waypoint in enumerate(self.waypoints):
            target = np.array(waypoint, dtype=float)
            move_s = 0.0 if index == 0 else max(np.linalg.norm(target[:3] - previous[:3]) / self.speed_mm_s,
                                                abs(target[3] - previous[3]) / self.turn_deg_s)
            out.append((time_s, time_s + move_s, previous, target))
            time_s += move_s + self.dwell_s
            previous = target
        return out

    @property
    def duration_s(self) -> float:
        start, moved, _, _ = self._segments()[-1]
        return moved + self.dwell_s

    def dwell_windows(self, average_s: float) -> list[tuple[float, float]]:
        """(from, to) trajectory times of the last ``average_s`` of each dwell."""
        return [(moved + self.dwell_s - average_s, moved + self.dwell_s) for _, moved, _, _ in self._segments()]

    def flange_target(self, time_s: float) -> np.ndarray:
        for start_s, moved_s, source, target in reversed(self._segments()):
            if time_s >= start_s:
                fraction = 1.0 if moved_s <= start_s else min(max((time_s - start_s) / (moved_s - start_s), 0.0), 1.0)
                return np.array(self.start) + source + fraction * (target - source)
        return np.array(self.start) + np.array(self.waypoints[0])


@dataclass(frozen=True)
class TouchSample:
    """One dwell's averages: the follower's sensor (its base frame, mm), the leader's flange pose (its base frame)
    and the GDNN's depth (labels' convention, mm)."""

    sensor_mm: np.ndarray
    leader_flange_mm_deg: np.ndarray
    depth_mm: float
    cycles: int


def samples_from_rows(rows: list[dict[str, Any]], plan: WaypointPlan, average_s: float) -> list[TouchSample]:
    """Average each dwell's last ``average_s`` of a run's log rows into a :class:`TouchSample`."""
    tracking = [row for row in rows if row["phase"] == "track"]
    samples = []
    for start_s, end_s in plan.dwell_windows(average_s):
        window = [row for row in tracking if start_s <= row["trajectory_s"] <= end_s]
        if not window:
            continue
        sensor = np.mean([[row[f"sensor_{n}"] for n in ("x_mm", "y_mm", "z_mm")] for row in window], axis=0)
        leader = np.mean([[row[f"leader_{n}"] for n in ("x_mm", "y_mm", "z_mm", "r_deg")] for row in window], axis=0)
        depth = float(np.mean([row["estimate_depth_mm"] for row in window]))
        samples.append(TouchSample(sensor, leader, depth, len(window)))
    return samples


def fit_base_to_base(samples: list[TouchSample], plate: PlateMount, guess: BaseToBase
                     ) -> tuple[BaseToBase, np.ndarray, float]:
    """(the leader base in the follower's frame, the touched point (qx, qy) on the face, RMS residual mm)."""
    from scipy.optimize import least_squares

    if len(samples) < 4:
        raise ValueError(f"the calibration fit needs at least 4 dwell samples, got {len(samples)} (did the run "
                         "stop early?)")
    T_flange_face = plate.T_flange_face()
    faces = [pose_to_T_base_flange(s.leader_flange_mm_deg) @ T_flange_face for s in samples]
    points = np.array([s.sensor_mm for s in samples])
    depths = np.array([s.depth_mm for s in samples])

    def residuals(theta: np.ndarray) -> np.ndarray:
        T = BaseToBase(theta[0], theta[1], theta[2], math.degrees(theta[3])).T_follower_leader()
        out = []
        for T_face, point, depth in zip(faces, points, depths):
            q = np.array([theta[4], theta[5], -(depth - SURFACE_DEPTH_MM), 1.0])
            out.append((T @ T_face @ q)[:3] - point)
        return np.concatenate(out)

    x0 = np.array([guess.x_mm, guess.y_mm, guess.z_mm, math.radians(guess.rz_deg), 0.0, 0.0])
    result = least_squares(residuals, x0, x_scale=np.array([10.0, 10.0, 10.0, 0.1, 10.0, 10.0]))
    theta = result.x
    rms = float(np.sqrt(np.mean(result.fun.reshape(-1, 3) ** 2 * 3.0)))
    return BaseToBase(theta[0], theta[1], theta[2], math.degrees(theta[3])), theta[4:6].copy(), rms


def calibrate_by_touch(leader: ArmEndpoint, follower: ArmEndpoint, camera, guess: BaseToBase, out_dir: str | Path,
                       config=None, plan: WaypointPlan | None = None, average_s: float = 1.5,
                       posenet: str | None = None, truth=None, command: str = "") -> tuple[ArmsCalibration,
                                                                                          dict[str, Any]]:
    """Run the touch calibration (module docstring); (the calibration, the run's summary with the fit's
    samples). ``config``: an :class:`~simshear_gym.lab.experiment.ExperimentConfig` (its kinematic stops are
    turned off here)."""
    from simshear_gym.lab.experiment import ExperimentConfig, ExperimentRun

    config = replace(config if config is not None else ExperimentConfig(), kinematic_stops=False, hold_s=0.0,
                     rz_feedforward=True)
    plan = plan if plan is not None else WaypointPlan(tuple(config.leader_start_pose_mm_deg))
    if average_s >= plan.dwell_s:
        raise ValueError(f"average_s ({average_s:g} s) must be shorter than the dwell ({plan.dwell_s:g} s)")
    run = ExperimentRun(leader, follower, camera, ArmsCalibration(guess, "fixture", command="guess"), "servo",
                        config, posenet, truth=truth, plan=plan)
    summary = run.run(out_dir, command)
    if not summary["completed"]:
        raise CalibrationError(f"the calibration run stopped ({summary['stop']}: {summary['stop_reason']}); "
                               f"nothing written. The log is in {Path(out_dir) / 'log.csv'}")
    samples = samples_from_rows(run.rows, plan, average_s)
    fitted, point, rms = fit_base_to_base(samples, config.plate, guess)
    calibration = ArmsCalibration(fitted, "touch", round(rms, 4), len(samples), command)
    summary["fit"] = {"leader_in_follower": list(fitted.as_tuple()), "touched_point_face_mm": point.tolist(),
                      "residual_rms_mm": rms, "samples": [
                          {"sensor_mm": s.sensor_mm.tolist(), "leader_flange_mm_deg": s.leader_flange_mm_deg.tolist(),
                           "depth_mm": s.depth_mm, "cycles": s.cycles} for s in samples]}
    return calibration, summary


class CalibrationError(RuntimeError):
    """The calibration run did not finish; nothing was written."""


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear calibrate-arms``."""
    parser.add_argument("--leader", default=None, metavar="HOST[:PORTS]", help="the leader MG400 (holds the plate)")
    parser.add_argument("--follower", default=None, metavar="HOST[:PORTS]", help="the follower MG400 (the TacTip)")
    parser.add_argument("--camera", default=None, metavar="SRC", help="the TacTip camera: device index or video file")
    parser.add_argument("--guess", type=float, nargs=4, default=None, metavar=("X", "Y", "Z", "RZ"),
                        help="the leader base in the follower's frame, measured roughly (mm, deg): where to touch")
    parser.add_argument("--fixture", type=float, nargs=4, default=None, metavar=("X", "Y", "Z", "RZ"),
                        help="write this transform from a fixture's drawing instead of touching (mm, deg)")
    parser.add_argument("--rehearsal", action="store_true",
                        help="calibrate on the rehearsal rig (two loopback emulators and the rig camera)")
    parser.add_argument("--rig-leader-base", type=float, nargs=4, default=list(BaseToBase().as_tuple()),
                        metavar=("X", "Y", "Z", "RZ"),
                        help="--rehearsal: where the rig's leader base truly stands (default the sim scene's)")
    parser.add_argument("--average-s", type=float, default=1.5, help="averaging window at each dwell, s")
    parser.add_argument("--max-feedback-age-s", type=float, default=None,
                        help="feedback (and camera frames) older than this stop both arms (default 0.1 and the "
                             "camera's 0.5; 1.0 with --rehearsal)")
    parser.add_argument("--posenet", default=None, help="GDNN weights (default: the shipped surface GDNN)")
    parser.add_argument("--out", type=Path, default=Path("runs/calibration/arms.json"),
                        help="the calibration file to write (default runs/calibration/arms.json); the run's log "
                             "goes beside it, in <name>_run/")


def run(args: argparse.Namespace) -> int:
    """Write the calibration file; 0 on success."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    command = recorded_command("simshear calibrate-arms", add_arguments, args)
    if args.fixture is not None:
        if args.guess is not None or args.rehearsal:
            raise ValueError("--fixture writes the fixture's transform: leave out --guess and --rehearsal")
        calibration = ArmsCalibration(BaseToBase(*args.fixture), "fixture", 0.0, 0, command)
        calibration.save(args.out)
        print(f"wrote {args.out}: leader base at {calibration.leader_in_follower.as_tuple()} (fixture)")
        return 0
    if args.guess is None:
        raise ValueError("give --guess X Y Z RZ (a rough measure of the leader base in the follower's frame) to "
                         "calibrate by touch, or --fixture X Y Z RZ")
    import torch

    from simshear_gym.lab.experiment import ExperimentConfig, arms_safety

    torch.set_num_threads(1)
    guess = BaseToBase(*args.guess)
    config = ExperimentConfig(hover_mm=8.0, max_approach_mm=10.0).with_env(safety=arms_safety(args))
    run_dir = args.out.parent / f"{args.out.stem}_run"
    if args.rehearsal:
        if args.leader or args.follower or args.camera:
            raise ValueError("--rehearsal starts its own arms and camera: leave out --leader, --follower and --camera")
        from simshear_gym.lab.rig import RehearsalRig, RigConfig

        rig_config = RigConfig(leader_in_follower=BaseToBase(*args.rig_leader_base))
        with RehearsalRig(rig_config) as rig:
            camera = rig.new_camera()
            calibration, summary = calibrate_by_touch(rig.leader_endpoint, rig.follower_endpoint, camera, guess,
                                                      run_dir, config, average_s=args.average_s,
                                                      posenet=args.posenet, truth=camera, command=command)
            truth = rig_config.leader_in_follower
            distance, turn = calibration.leader_in_follower.difference(truth)
            summary["fit"].update(rig_truth=list(truth.as_tuple()), error_mm=distance, error_deg=turn)
    else:
        if not (args.leader and args.follower and args.camera is not None):
            raise ValueError("give --leader, --follower and --camera (or --rehearsal, or --fixture)")
        from simshear_gym.real.camera import CameraSource

        calibration, summary = calibrate_by_touch(ArmEndpoint.parse(args.leader, "--leader"),
                                                  ArmEndpoint.parse(args.follower, "--follower"),
                                                  CameraSource(args.camera), guess, run_dir, config,
                                                  average_s=args.average_s, posenet=args.posenet, command=command)
    write_json(run_dir / "experiment.json", summary)
    calibration.save(args.out)
    fit = summary["fit"]
    print(f"wrote {args.out}: leader base at ({', '.join(f'{v:.3f}' for v in fit['leader_in_follower'])}) mm/deg, "
          f"residual {fit['residual_rms_mm']:.3f} mm RMS over {calibration.points} poses")
    if "rig_truth" in fit:
        print(f"rig truth {fit['rig_truth']}: off by {fit['error_mm']:.3f} mm and {fit['error_deg']:.3f} deg")
    return 0


__all__ = ["DEFAULT_WAYPOINTS_MM_DEG", "CalibrationError", "TouchSample", "WaypointPlan", "calibrate_by_touch",
           "fit_base_to_base", "samples_from_rows"]
