"""``simshear experiment colift``: the paper's co-lift experiment on two MG400s (or the rehearsal rig).

::

    simshear experiment colift --leader 192.168.1.6 --follower 192.168.2.6 --camera 0 --trajectory star \\
        --object prism --calibration runs/calibration/arms.json
    simshear experiment colift --rehearsal --trajectory circular_wave --object egg

The **leader** holds an upright plate (its face 50 mm beyond and 60 mm below the flange, facing the follower: the
co-lift env's bracket) and the **follower** the TacTip lying horizontally (:class:`~simshear_gym.contract.
HorizontalTacTipMount`: axis along its flange's x, 60 mm below it); between them the object, held by friction alone.
The layout is ``SimShearCoLift-v0``'s: the arms face each other 750 mm apart, the leader's flange starts at
(280, 0, 0) mm.

A run is the tracking experiment's loop (:class:`~simshear_gym.lab.experiment.ExperimentRun`: one clock, the
leader's plan clock that advances at most one servo command's ``t`` a cycle, the same stops and log) with the
co-lift's phases:

1. **Grasp**: the follower comes to ``hover_mm`` from the object's face on the grip axis (through the
   calibration: the object rests against the plate's face, on a support, its thickness along the grip axis known:
   :data:`~simshear_gym.lab.colift_layout.OBJECT_FACE_MM`), approaches along the axis ``approach_step_mm`` per
   cycle until the co-lift GDNN reads a touch (``touch_depth_mm``), then the servo controller squeezes to the
   reference depth (3 mm into the dome) for ``settle_s`` with the leader still.
2. **Lift and carry**: the leader lifts the object ``lift_mm`` off its support (a smooth start and stop), moves it
   along the co-lift trajectory (``circular_wave`` or ``star``: the env's paths and speed, translations only),
   and sets it down again (:class:`CoLiftPlan`); the follower runs the co-lift servo controller (the shipped
   ``colift`` GDNN, the env's process noise; the mount cannot turn about its axis, so the action's turn is not
   sent: the paths are translations).
3. **Release**: after ``hold_s`` more, the follower backs off ``retreat_mm`` along the grip axis (MovL).

**Stops**: the tracking experiment's (both arms stop: an alarm or error mode on either arm, stale feedback, a
lost connection, a frozen or lost camera stream, a pose jump, a refused target, the leader off its path, the
GDNN's depth below ``min_depth_mm``: the grip lost, the kinematics' contact lost or the arms apart) plus
``dropped``: on the rig, the object fell (the scene's truth: 20 mm from its place on the plate, or touching
neither gripper); on the hardware a drop shows as the grip lost.

**Contact error**: the follower's sensor against the point of the object's face it stood on when the carry
started, carried with the plate (both arms' fed-back poses through the calibration), as the co-lift env measures
it. Output as the tracking experiment's (``log.csv``, ``experiment.json`` with ``object``, ``dropped`` and on the
rig the object's largest slip on the plate, ``experiment.png``).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.contract import HorizontalTacTipMount
from simshear_gym.data.labels import SURFACE_DEPTH_MM
from simshear_gym.envs.trajectories import COLIFT_TRAJECTORIES
from simshear_gym.lab.colift_layout import (
    COLIFT_LEADER_IN_FOLLOWER_MM_DEG,
    COLIFT_LEADER_START_POSE_MM_DEG,
    OBJECT_NAMES,
    ObjectFace,
)
from simshear_gym.lab.experiment import (
    STOPS,
    ExperimentConfig,
    ExperimentRun,
    LeaderPlan,
    _move_and_wait,
    add_arm_arguments,
    add_loop_arguments,
    run_experiment,
    run_on_rig,
)
from simshear_gym.lab.frames import ArmsCalibration
from simshear_gym.real.env import RealEnvConfig
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange

logger = logging.getLogger(__name__)

SQUEEZE_MM = 3.0  # the co-lift env's light payload: the reference depth 2.2 (the labels' face) + 3 mm
COLIFT_STOPS: tuple[str, ...] = (*STOPS, "dropped")
"""Every value a co-lift run's ``stop`` takes besides ``""`` (finished)."""


@dataclass(frozen=True)
class CoLiftConfig(ExperimentConfig):
    """Settings of a co-lift run: :class:`~simshear_gym.lab.experiment.ExperimentConfig`'s (the same meaning,
    the face being the object's: ``plate`` is an :class:`ObjectFace`) with the co-lift's defaults, and:

    The co-lift's defaults: the env's path speed (5 mm/s), no turn, and in ``real_env`` the horizontal TacTip
    (:class:`~simshear_gym.contract.HorizontalTacTipMount`), the env's squeeze (reference depth 5.2 mm) and its
    estimator's process noise (1.5 mm); the touch at a co-lift GDNN depth of 2.9 mm (out of contact it reads about
    2.6 mm on the rig's images), the grip lost below 3.0 mm, the kinematic contact loss 2 mm off the object's face
    (a curved object's face is known to about a millimetre), a 2 s squeeze.

    Attributes:
        object_name: the object carried (:data:`OBJECT_NAMES`); sets ``plate`` when that is None.
        lift_mm: the leader lifts the object this far off its support before the trajectory and sets it down
            after it, mm.
        release_s: on the rehearsal rig, the object leaves its support this long before the settle ends (the
            grip takes its weight, and the soft brain's own compliance shows, before the contact point is marked
            and the lift starts), s.
    """

    trajectory: str = "circular_wave"
    object_name: str = "prism"
    speed_mm_s: float = 5.0
    rotation_deg: float = 0.0
    real_env: RealEnvConfig = replace(  # the noise: SimShearCoLiftEnv.servo_hints.process_std_mm
        ExperimentConfig.real_env, reference_depth_mm=SURFACE_DEPTH_MM + SQUEEZE_MM, mount=HorizontalTacTipMount(),
        estimator_process_std_mm=1.5)
    touch_depth_mm: float = 2.9
    min_depth_mm: float | None = 3.0
    max_approach_mm: float = 6.0
    max_lift_mm: float = 2.0
    lift_mm: float = 10.0
    settle_s: float = 2.0
    release_s: float = 1.0
    plate: Any = None
    leader_start_pose_mm_deg: tuple[float, float, float, float] = COLIFT_LEADER_START_POSE_MM_DEG

    def __post_init__(self) -> None:
        if self.object_name not in OBJECT_NAMES:
            raise ValueError(f"CoLiftConfig.object_name must be one of {OBJECT_NAMES}, got {self.object_name!r}")
        if self.plate is None:
            object.__setattr__(self, "plate", ObjectFace(self.object_name))
        if not isinstance(self.plate, ObjectFace) or self.plate.object_name != self.object_name:
            raise ValueError(f"CoLiftConfig.plate must be the ObjectFace of {self.object_name!r} (or None), got "
                             f"{self.plate!r}")
        if not isinstance(self.real_env.mount, HorizontalTacTipMount):
            raise ValueError(f"CoLiftConfig.real_env.mount must be a HorizontalTacTipMount (the co-lift TacTip lies "
                             f"horizontally), got {type(self.real_env.mount).__name__}")
        if not (math.isfinite(self.release_s) and 0.0 <= self.release_s <= self.settle_s):
            raise ValueError(f"CoLiftConfig.release_s must be in [0, settle_s = {self.settle_s!r}] s, got "
                             f"{self.release_s!r}")
        if not (math.isfinite(self.lift_mm) and 0.0 <= self.lift_mm <= 50.0):
            raise ValueError(f"CoLiftConfig.lift_mm must be in [0, 50] mm, got {self.lift_mm!r}")
        super().__post_init__()

    def _check_trajectory(self) -> None:
        if self.trajectory not in COLIFT_TRAJECTORIES:
            raise ValueError(f"CoLiftConfig.trajectory must be one of {COLIFT_TRAJECTORIES}, got "
                             f"{self.trajectory!r}")
        if self.rotation_deg != 0.0:
            raise ValueError(f"CoLiftConfig.rotation_deg must be 0 (the horizontal TacTip cannot turn with the "
                             f"plate: the co-lift paths are translations), got {self.rotation_deg!r}")
        self.trajectory_config()

    def _check_start_offset(self, margin_mm: float) -> None:
        super()._check_start_offset(min(margin_mm, 10.0))  # the objects' faces are 30-50 mm across


class CoLiftPlan:
    """The leader's flange target (its base frame) over a co-lift run: lift ``lift_mm`` straight up (a half-cosine
    from rest to rest, its peak speed the trajectory's), the co-lift trajectory as ``SimShearCoLift-v0`` moves the
    plate (:class:`~simshear_gym.lab.experiment.LeaderPlan`), then lower ``lift_mm`` back onto the support."""

    def __init__(self, config: CoLiftConfig) -> None:
        self.name = config.trajectory
        self.carry = LeaderPlan(config.trajectory_config(), config.leader_start_pose_mm_deg, config.plate)
        self.lift_mm = float(config.lift_mm)
        self.lift_s = math.pi * self.lift_mm / (2.0 * config.speed_mm_s)

    @property
    def duration_s(self) -> float:
        return 2.0 * self.lift_s + self.carry.duration_s

    def height_mm(self, time_s: float) -> float:
        """The lift at ``time_s``: 0 on the support, ``lift_mm`` while carrying."""
        if self.lift_s <= 0.0:
            return 0.0
        down_s = self.lift_s + self.carry.duration_s
        if time_s < self.lift_s:
            fraction = max(time_s, 0.0) / self.lift_s
        elif time_s <= down_s:
            return self.lift_mm
        else:
            fraction = max(0.0, 1.0 - (time_s - down_s) / self.lift_s)
        return self.lift_mm * (1.0 - math.cos(math.pi * fraction)) / 2.0

    def flange_target(self, time_s: float) -> np.ndarray:
        target = self.carry.flange_target(min(max(time_s - self.lift_s, 0.0), self.carry.duration_s))
        target[2] += self.height_mm(time_s)
        return target

    def phase(self, time_s: float) -> str:
        if not math.isfinite(time_s):
            return ""
        if time_s < self.lift_s:
            return "lift"
        if time_s <= self.lift_s + self.carry.duration_s:
            return "carry"
        return "lower" if time_s < self.duration_s else "hold"


class CoLiftRun(ExperimentRun):
    """One co-lift run (see the module docstring): the tracking run's loop with the co-lift's plan, action,
    release, drop and summary. ``truth``: the co-lift rig's camera (:class:`~simshear_gym.lab.colift_rig.
    CoLiftCamera`), or None; ``posenet`` None (or empty): the shipped ``colift`` GDNN."""

    config: CoLiftConfig

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if kwargs.get("plan") is None:
            self.plan = CoLiftPlan(self.config)
        if not self.posenet:
            from simshear_gym.models.zoo import posenet_weights

            self.posenet = str(posenet_weights("colift"))

    def _settling(self, left_s: float) -> None:
        """On the rig, the object leaves its support ``release_s`` before the lift (the grip takes its weight)."""
        if self.truth is not None and left_s <= self.config.release_s:
            self.truth.release()

    def _adapt_action(self, action: np.ndarray) -> np.ndarray:
        """The level flange cannot turn a horizontal sensor about its axis: the action's turn is not sent."""
        action = np.asarray(action, dtype=np.float64).copy()
        action[3] = 0.0
        return action

    def _kinematic_stop(self, row: dict[str, Any], leader_target: np.ndarray) -> tuple[str, str] | None:
        if row.get("truth_dropped"):
            return "dropped", (f"the object fell (the rig's scene: {row['truth_object_slip_mm']:.1f} mm from its "
                               "place on the plate, or touching neither gripper)")
        return super()._kinematic_stop(row, leader_target)

    def _log(self, *args, **kwargs) -> dict[str, Any]:
        row = super()._log(*args, **kwargs)
        row["colift_phase"] = self.plan.phase(row["trajectory_s"]) if hasattr(self.plan, "phase") else ""
        if self.truth is not None and self.truth.history:
            truth = self.truth.history[-1]
            row.update(truth_carried=truth.carried, truth_dropped=truth.dropped,
                       truth_object_slip_mm=round(truth.object_slip_mm, 5))
        return row

    def _finish(self, arms) -> None:
        """After a finished run (the object set down): the follower backs off along the grip axis."""
        if self.truth is not None:
            self.truth.set_down()
        time.sleep(self.config.real_env.servo_time_s)  # the last servo targets reached
        client = arms.env.client
        pose, _ = client.measured_state()
        axis = (pose_to_T_base_flange(pose) @ self.config.real_env.mount.T_flange_sensor())[:3, 2]
        target = pose.copy()
        target[:3] -= self.config.retreat_mm * axis
        _move_and_wait(client, target)

    def _summary(self, stop: str, why: str, phase: str, command: str, wall_s: float) -> dict[str, Any]:
        summary = super()._summary(stop, why, phase, command, wall_s)
        summary["object"] = self.config.object_name
        summary["contact_lost"] = stop in ("lost_contact", "follower_lost_contact", "arms_apart", "dropped")
        summary["dropped"] = stop == "dropped" or (stop in ("lost_contact", "follower_lost_contact")
                                                   and phase == "track")
        if self.truth is not None:
            slips = [row.get("truth_object_slip_mm", 0.0) for row in self.rows]
            summary["truth_dropped"] = any(row.get("truth_dropped", False) for row in self.rows)
            summary["truth_object_slip_max_mm"] = round(float(max(slips, default=0.0)), 4)
            summary["dropped"] = summary["dropped"] or summary["truth_dropped"]
        return summary

    def _title(self, summary: dict[str, Any]) -> str:
        return f"{summary['object']}, {super()._title(summary)}"


def run_colift_rehearsal(config: CoLiftConfig, out_dir: str | Path, controller: str = "servo",
                         calibration: ArmsCalibration | None = None, posenet: str | None = None, command: str = "",
                         rig_config=None, on_cycle=None, rig=None, **rig_changes) -> dict[str, Any]:
    """One co-lift run on a fresh co-lift rig (default: laid out as ``config`` has it, with ``rig_changes``) or on
    ``rig``, started, with the shipped ``colift`` GDNN unless ``posenet`` (:class:`CoLiftRun`); the summary of
    :func:`~simshear_gym.lab.experiment.run_on_rig` (``rows`` included)."""
    from simshear_gym.lab.colift_rig import CoLiftRig, CoLiftRigConfig

    if rig is not None:
        return run_on_rig(rig, config, out_dir, controller, calibration, posenet, command, on_cycle,
                          experiment=CoLiftRun)
    rig_config = rig_config if rig_config is not None else CoLiftRigConfig.for_run(config, **rig_changes)
    if rig_config.object_name != config.object_name:
        raise ValueError(f"the rig holds {rig_config.object_name!r}, the run expects {config.object_name!r}")
    with CoLiftRig(rig_config) as started:
        return run_on_rig(started, config, out_dir, controller, calibration, posenet, command, on_cycle,
                          experiment=CoLiftRun)


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear experiment colift``."""
    add_arm_arguments(parser, "holds the plate", "the horizontal TacTip",
                      "the co-lift scene's object between them, the rig camera", COLIFT_LEADER_IN_FOLLOWER_MM_DEG,
                      "the co-lift scene's")
    parser.add_argument("--trajectory", default=CoLiftConfig.trajectory, choices=COLIFT_TRAJECTORIES,
                        help="the leader's path")
    parser.add_argument("--object", default=CoLiftConfig.object_name, choices=OBJECT_NAMES, help="the object carried")
    parser.add_argument("--speed-mm-s", type=float, default=CoLiftConfig.speed_mm_s,
                        help="the leader's speed along its path, mm/s")
    parser.add_argument("--lift-mm", type=float, default=CoLiftConfig.lift_mm,
                        help="lift off the support before the path, mm")
    add_loop_arguments(parser, "co-lift", "runs/colift")


def run(args: argparse.Namespace) -> int:
    """Run the co-lift experiment; 0 when it completed, 1 when a stop ended it early."""
    def config(**env) -> CoLiftConfig:
        return CoLiftConfig(trajectory=args.trajectory, object_name=args.object, speed_mm_s=args.speed_mm_s,
                            lift_mm=args.lift_mm).with_env(**env)

    return run_experiment(args, recorded_command("simshear experiment colift", add_arguments, args), config,
                          CoLiftRun, run_colift_rehearsal, "runs/colift",
                          "{trajectory} with the {object}: {tracking_cycles} cycles at {loop_rate_hz} Hz, contact "
                          "error {contact_error_mean_mm} +- {contact_error_std_mm} mm, dropped: {dropped}, compute "
                          "{compute_ms_median} ms median")


__all__ = ["COLIFT_STOPS", "OBJECT_NAMES", "CoLiftConfig", "CoLiftPlan", "CoLiftRun", "ObjectFace",
           "run_colift_rehearsal"]
