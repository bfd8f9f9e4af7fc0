"""``simshear experiment tracking``: the paper's two-arm tracking experiment on two MG400s (or the rehearsal rig).

::

    simshear experiment tracking --leader 192.168.1.6 --follower 192.168.2.6 --camera 0 --trajectory circle \\
        --controller servo --calibration runs/calibration/arms.json
    simshear experiment tracking --rehearsal --trajectory circle --controller servo

The **leader** holds the plate and moves it along the trajectory of ``SimShearTracking-v0`` (the same paths,
speeds and rotations: :mod:`simshear_gym.envs.trajectories`, the plate's face moved from its start by the
trajectory's offset in the leader's base axes), one ``ServoP`` per control period through its own
:class:`~simshear_gym.real.mg400_client.MG400Client` and safety layer. The **follower** carries the TacTip and runs
the servo controller (or an SB3 policy) through :class:`~simshear_gym.real.env.RealTactileEnv`, on the same clock:
each cycle sends the leader's next target, then the follower's action, then waits for the period and reads the
camera and both arms' feedback.

**The plan's clock** (``trajectory_s``) follows the wall clock but advances at most one servo command's ``t``
(``control_period_s + servo_margin_s``) per cycle: after a late cycle (a busy computer, a slow frame) the leader
goes on along its path from where it stopped instead of jumping ahead, so its next target never asks for more
than the trajectory's own speed, even from rest (the safety layer's stream bounds would refuse the jump, and stop
the run). ``experiment.json`` says how far the plan fell behind the wall clock (``plan_behind_s``) and in how
many cycles (``late_cycles``).

A run, in order: the follower lifts ``retreat_mm`` straight up (MovL) from wherever it is; the leader moves to its
start pose (MovJ); the follower moves to hover ``hover_mm`` above the plate's point ``start_offset_mm`` (through
the calibration) and descends ``approach_step_mm`` per cycle until its GDNN reads a touch (``touch_depth_mm``);
the controller takes over and settles at the reference depth for ``settle_s`` with the leader still; the contact
point is marked and the leader's trajectory starts; after it and ``hold_s`` more, the follower lifts
``retreat_mm`` off the plate.

**Contact error** (the paper's): the distance between the follower's sensor (its fed-back flange pose and the
mount) and the point of the plate it stood on when tracking started, carried with the plate (the leader's
fed-back flange pose, the plate mount and the calibrated base-to-base transform), in the follower's base frame.

**Stops** (both arms: nothing more is sent to either; each stops at its last servo target within ``t``): any
follower termination of ``RealTactileEnv`` (alarm or error mode, stale feedback or a lost connection, a frozen or
lost camera stream, the GDNN's depth below ``min_depth_mm``: contact lost, a refused target); on the leader an
alarm or error mode, stale feedback, a lost connection, joints and pose that disagree (a pose jump), a refused
target, or its fed-back pose farther than ``max_leader_lag_mm`` from the target in force; the sensor more than
``max_lift_mm`` above the plate or off it by the kinematics (contact lost), or the contact error beyond
``max_contact_error_mm`` (the arms drifted apart).

Output in ``--out``: ``log.csv`` (one row per cycle, one clock: both arms' commanded and fed-back poses, the
follower's sensor and its target point, the contact error, the estimate, the action, timings, feedback and frame
ages, and on the rig the true contact error), ``experiment.json`` (the command, settings, calibration, contact
error mean +- std, contact loss, loop rate, compute per cycle, how it ended; on the rig the emulators' audit) and
``experiment.png`` (the paper's figure: the leader's contact point red, the follower's sensor blue).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Self

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.data.labels import SURFACE_DEPTH_MM, wrap_deg
from simshear_gym.envs.trajectories import TRAJECTORIES, Trajectory, TrajectoryConfig
from simshear_gym.io import atomic_write, write_json
from simshear_gym.lab.endpoints import ArmEndpoint
from simshear_gym.lab.frames import (
    LEADER_START_POSE,
    ArmsCalibration,
    BaseToBase,
    PlateMount,
    flange_pose_for_sensor,
    sensor_on_face,
)
from simshear_gym.real.camera import preprocess_config
from simshear_gym.real.env import RealEnvConfig
from simshear_gym.real.mg400_client import wait_at_pose
from simshear_gym.real.rollout import log_vector, write_log_csv
from simshear_gym.real.safety import SafetyConfig
from simshear_gym.robots.mg400.frames import T_base_flange_to_pose, pose_to_T_base_flange
from simshear_gym.transforms import invert, rz_matrix

logger = logging.getLogger(__name__)

POSE_NAMES = ("x_mm", "y_mm", "z_mm", "r_deg")
XYZ = ("x_mm", "y_mm", "z_mm")
STATE_NAMES = ("depth_mm", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
STOPS: tuple[str, ...] = (
    "no_contact", "lost_contact", "arms_apart", "leader_off_path", "leader_robot_error", "leader_lost_connection",
    "leader_feedback_mismatch", "leader_safety_refused", "follower_robot_error", "follower_lost_connection",
    "follower_feedback_mismatch", "follower_safety_refused", "follower_camera_stall", "follower_camera_ended",
    "follower_lost_contact", "follower_controller_error")
"""Every value ``stop`` takes besides ``""`` (finished)."""


class ExperimentError(RuntimeError):
    """An arm is not in a state a run can start from; nothing was moved."""


@dataclass(frozen=True)
class ExperimentConfig:
    """Settings of a two-arm tracking run (see the module docstring for the sequence and the stops).

    Attributes:
        trajectory: one of :data:`~simshear_gym.envs.trajectories.TRAJECTORIES`.
        scale: the path's size factor (1: the env's; smaller for short rehearsals).
        speed_mm_s, rotation_deg: the trajectory's speed and rotation amplitude (the env's defaults).
        real_env: the follower's :class:`~simshear_gym.real.env.RealEnvConfig`, whose control period, servo
            margin, client timeouts and safety both arms share (one cycle: both arms' commands, one camera frame):
            the reference depth (labels' convention: the plate's face at 2.2 mm), image size, preprocessing,
            action scale, mount, estimator noise and frozen-frame limit are the follower's. The run sets its
            client's address, start pose (the hover pose), ``posenet`` and, for an SB3 controller, the
            observation the model was trained on; ``safety.stop_on_lost_contact`` follows ``min_depth_mm``.
        start_offset_mm: where on the plate (face frame x, y) the follower touches, mm.
        hover_mm: the follower starts this far above the plate, mm.
        approach_step_mm: the follower's descent per cycle until the touch, mm.
        touch_depth_mm: the GDNN depth reading that counts as touching (out of contact it reads about 2.1 mm).
        max_approach_mm: give up (``no_contact``) after descending this far past the hover height, mm.
        settle_s: the controller settles at the reference depth for this long before the leader moves, s.
        hold_s: the run goes on this long after the trajectory's end, s.
        min_depth_mm: a GDNN depth reading below this while tracking is contact lost (None: not checked).
        max_lift_mm: the sensor this far above the plate (kinematics) is contact lost, mm.
        max_contact_error_mm: a contact error beyond this: the arms drifted apart, mm.
        max_leader_lag_mm: the leader's fed-back pose farther than this from its target in force, mm.
        retreat_mm: the follower lifts this far before the run and after a finished one, mm.
        rz_feedforward: the follower turns about its sensor axis as the leader's target turns (the servo law
            does not read the turn from the images): the sensor keeps its angle to the plate (the calibration's
            choice; off for the experiment, as in the sim env).
        kinematic_stops: stop on the calibrated kinematics (contact lost, arms apart; off while calibrating,
            when the transform is only a guess).
        plate: the plate on the leader's flange.
        leader_start_pose_mm_deg: the leader's flange at the start (its base frame).
    """

    trajectory: str = "circle"
    scale: float = 1.0
    speed_mm_s: float = 4.0
    rotation_deg: float = TrajectoryConfig().rotation_deg
    real_env: RealEnvConfig = RealEnvConfig(frozen_frame_limit=5)
    start_offset_mm: tuple[float, float] = (0.0, 0.0)
    hover_mm: float = 5.0
    approach_step_mm: float = 0.5
    touch_depth_mm: float = 2.5
    max_approach_mm: float = 4.0
    settle_s: float = 1.5
    hold_s: float = 1.0
    min_depth_mm: float | None = 2.4
    max_lift_mm: float = 1.0
    max_contact_error_mm: float = 10.0
    max_leader_lag_mm: float = 5.0
    retreat_mm: float = 10.0
    kinematic_stops: bool = True
    rz_feedforward: bool = False
    plate: PlateMount = PlateMount()
    leader_start_pose_mm_deg: tuple[float, float, float, float] = LEADER_START_POSE

    def __post_init__(self) -> None:
        self._check_trajectory()
        env = self.real_env
        if not 0.02 <= env.control_period_s:
            raise ValueError(f"ExperimentConfig.real_env.control_period_s must be in [0.02, 1] s, got "
                             f"{env.control_period_s!r}")
        for name in ("hover_mm", "approach_step_mm", "max_approach_mm", "max_lift_mm", "max_contact_error_mm",
                     "max_leader_lag_mm", "retreat_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"ExperimentConfig.{name} must be finite and > 0 mm, got {value!r}")
        for name in ("settle_s", "hold_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"ExperimentConfig.{name} must be finite and >= 0 s, got {value!r}")
        if not SURFACE_DEPTH_MM < self.touch_depth_mm < env.reference_depth_mm:
            raise ValueError(f"ExperimentConfig.touch_depth_mm must lie between the face ({SURFACE_DEPTH_MM} mm) and "
                             f"the reference depth ({env.reference_depth_mm} mm), got {self.touch_depth_mm!r}")
        if self.min_depth_mm is not None and not self.min_depth_mm < env.reference_depth_mm:
            raise ValueError(f"ExperimentConfig.min_depth_mm must be below the reference depth, got "
                             f"{self.min_depth_mm!r}")
        self._check_start_offset(20.0)
        if env.dry_run:
            raise ValueError("ExperimentConfig.real_env.dry_run: a two-arm run needs both arms moving (rehearse on "
                             "the rig instead: --rehearsal)")
        if self.approach_step_mm > env.action_scale.step_mm:
            raise ValueError(f"ExperimentConfig.approach_step_mm ({self.approach_step_mm:g}) must not exceed the "
                             f"action's full scale (real_env.action_scale.step_mm = {env.action_scale.step_mm:g})")

    def _check_trajectory(self) -> None:
        if self.trajectory not in TRAJECTORIES:
            raise ValueError(f"ExperimentConfig.trajectory must be one of {TRAJECTORIES}, got {self.trajectory!r}")
        self.trajectory_config()

    def _check_start_offset(self, margin_mm: float) -> None:
        """``start_offset_mm`` at least ``margin_mm`` inside the face (``plate``) the follower touches."""
        name = type(self).__name__
        offset = tuple(float(v) for v in self.start_offset_mm)
        half = self.plate.half_extents_mm
        if len(offset) != 2 or not (abs(offset[0]) <= half[0] - margin_mm and abs(offset[1]) <= half[1] - margin_mm):
            raise ValueError(f"{name}.start_offset_mm must be (x, y) at least {margin_mm:g} mm inside the face "
                             f"(|x| <= {half[0] - margin_mm:g}, |y| <= {half[1] - margin_mm:g} mm), got "
                             f"{self.start_offset_mm!r}")
        object.__setattr__(self, "start_offset_mm", offset)

    def with_env(self, **changes) -> Self:
        """This config with ``real_env``'s fields ``changes`` replaced."""
        return replace(self, real_env=replace(self.real_env, **changes))

    def trajectory_config(self) -> TrajectoryConfig:
        return TrajectoryConfig(self.trajectory, scale=self.scale, speed_mm_s=self.speed_mm_s,
                                rotation_deg=self.rotation_deg)

    def to_dict(self) -> dict[str, Any]:
        out = {key: list(value) if isinstance(value, tuple) else value for key, value in vars(self).items()}
        out["real_env"] = self.real_env.to_dict()
        out["plate"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(self.plate).items()}
        return out


class LeaderPlan:
    """The leader's flange target (its base frame) at a time of the trajectory: the plate's face moved from its
    start by the trajectory's offset (translation in the leader's base axes, turn about the vertical), as
    ``SimShearTracking-v0`` moves it."""

    def __init__(self, trajectory: TrajectoryConfig, start_pose_mm_deg, plate: PlateMount) -> None:
        self.trajectory = Trajectory(trajectory)
        self._T_flange_face = plate.T_flange_face()
        self._T_face_flange = invert(self._T_flange_face)
        self._T_base_face_start = pose_to_T_base_flange(start_pose_mm_deg) @ self._T_flange_face
        self._start_r = float(start_pose_mm_deg[3])

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s

    def flange_target(self, time_s: float) -> np.ndarray:
        dx, dy, dz, dr = self.trajectory.offset_at(time_s)
        T_face = self._T_base_face_start @ rz_matrix(dr)
        T_face[:3, 3] = self._T_base_face_start[:3, 3] + (dx, dy, dz)
        pose = T_base_flange_to_pose(T_face @ self._T_face_flange)
        pose[3] = self._start_r + wrap_deg(pose[3] - self._start_r)
        return pose


# ----------------------------------------------------------------------------------------------------------------
# The run


@dataclass
class _Arms:
    """What a run holds: the leader's client, the follower's env, the controller and its depth reader."""

    leader: Any
    env: Any
    controller: Any
    read_depth: Callable[[np.ndarray], float]


class _Contact:
    """The env's contact check: not armed during the approach (True), then the GDNN depth >= ``min_depth_mm``.
    It sees every frame's image whatever the policy observes, and keeps the last (the approach reads it)."""

    def __init__(self, read_depth: Callable[[np.ndarray], float], min_depth_mm: float | None) -> None:
        self.read_depth = read_depth
        self.min_depth_mm = min_depth_mm
        self.armed = False
        self.last_tactile: np.ndarray | None = None

    def __call__(self, observation: dict[str, np.ndarray]) -> bool:
        self.last_tactile = observation["tactile"]
        if not self.armed or self.min_depth_mm is None:
            return True
        return self.read_depth(observation["tactile"]) >= self.min_depth_mm


def follower_hover_pose(config: ExperimentConfig, calibration: BaseToBase) -> np.ndarray:
    """The follower flange pose with its sensor ``hover_mm`` above the plate's ``start_offset_mm`` (leader at its
    start pose), through the calibration."""
    T_face = config.plate.T_follower_face(config.leader_start_pose_mm_deg, calibration.T_follower_leader())
    T_sensor = sensor_on_face(T_face, *config.start_offset_mm, SURFACE_DEPTH_MM - config.hover_mm)
    return flange_pose_for_sensor(T_sensor, config.real_env.mount.T_flange_sensor())


def _at(endpoint: ArmEndpoint, real_env: RealEnvConfig) -> RealEnvConfig:
    """``real_env`` with its client at ``endpoint`` (its timeouts kept)."""
    return replace(real_env, client=replace(real_env.client, **asdict(endpoint)))


def _client(endpoint: ArmEndpoint, real_env: RealEnvConfig):
    """An arm's client at ``endpoint``: ``real_env``'s client and safety limits."""
    from simshear_gym.real.mg400_client import MG400Client
    from simshear_gym.real.safety import SafetyLayer

    return MG400Client(_at(endpoint, real_env).client_config(), SafetyLayer(real_env.safety))


def _ready(client, what: str) -> None:
    """Refuse an arm in error mode; enable a disabled one."""
    from simshear_gym.robots.mg400.protocol import RobotMode

    mode = client.robot_mode()
    if mode == RobotMode.ERROR:
        alarms = list(client.get_error_id().all_ids)
        raise ExperimentError(f"the {what} MG400 at {client.config.host} is in error mode (alarms {alarms}): clear "
                              "the cause, send ClearError() and Continue(), then start again")
    if mode in (RobotMode.DISABLED, RobotMode.POWER_OFF):
        client.enable_robot()


def _move_and_wait(client, pose: np.ndarray, linear: bool = True) -> None:
    """MovL (MovJ: not ``linear``) to ``pose`` from the measured pose, then wait until the fed-back pose is
    ``pose`` and no queued move runs."""
    client.reset_reference()
    (client.mov_l if linear else client.mov_j)(*pose)
    client.sync()
    reached = wait_at_pose(client, pose, 0.5, 5.0, 0.005)
    if reached is not None:
        raise ExperimentError(f"the MG400 at {client.config.host} stopped at {reached.round(3).tolist()} "
                              f"instead of {pose.round(3).tolist()}")


def _lift(client, retreat_mm: float, safety: SafetyConfig) -> None:
    """MovL straight up by ``retreat_mm`` (kept inside the workspace's z range) and wait for it."""
    pose, _ = client.measured_state()
    target = pose.copy()
    target[2] = min(pose[2] + retreat_mm, safety.z_range_mm[1])
    _move_and_wait(client, target)


def prepare_arms(leader_endpoint: ArmEndpoint, follower_endpoint: ArmEndpoint, config: ExperimentConfig):
    """Connect the leader (returned, connected and enabled, at its start pose) after lifting the follower
    ``retreat_mm`` straight up through a short-lived client of its own. Raises :class:`ExperimentError` when an
    arm is in error mode (nothing moved)."""
    follower = _client(follower_endpoint, config.real_env)
    leader = _client(leader_endpoint, config.real_env)
    try:
        follower.connect()
        leader.connect()
        _ready(follower, "follower")
        _ready(leader, "leader")
        follower.wait_feedback(2.0)
        leader.wait_feedback(2.0)
        _lift(follower, config.retreat_mm, config.real_env.safety)
    finally:
        follower.close()
    try:
        _move_and_wait(leader, np.array(config.leader_start_pose_mm_deg), linear=False)
    except BaseException:
        leader.close()
        raise
    return leader


def _leader_stop(leader, error: BaseException | None) -> tuple[str, str] | None:
    """(stop, why) for a leader command that failed or a leader status that must stop."""
    from simshear_gym.real.mg400_client import (
        FeedbackStaleError,
        MG400ConnectionError,
        MG400Error,
        MG400TimeoutError,
    )
    from simshear_gym.real.safety import FeedbackMismatchError, SafetyError, StopReason
    from simshear_gym.robots.mg400.protocol import ProtocolError

    if error is not None:
        if isinstance(error, FeedbackMismatchError):
            return "leader_feedback_mismatch", str(error)
        if isinstance(error, SafetyError):
            return "leader_safety_refused", f"leader target refused, not sent: {error}"
        if isinstance(error, MG400Error):
            return "leader_robot_error", str(error)
        if isinstance(error, (MG400ConnectionError, MG400TimeoutError, ProtocolError, FeedbackStaleError, OSError)):
            return "leader_lost_connection", str(error)
        raise error
    mismatch = leader.feedback_mismatch
    if mismatch is not None:
        return "leader_feedback_mismatch", f"leader feedback: {mismatch}"
    decision = leader.safety.check_status(leader.status_snapshot())
    if decision.stop:
        stop = {StopReason.ROBOT_ERROR_MODE: "leader_robot_error"}.get(decision.reason, "leader_lost_connection")
        return stop, "leader: " + "; ".join(decision.reasons)
    return None


class ExperimentRun:
    """One two-arm tracking run (see the module docstring); :meth:`run` returns the summary.

    Args:
        leader_endpoint, follower_endpoint: where the arms' controllers listen.
        camera: the follower's TacTip camera (a :class:`~simshear_gym.real.camera.FrameSource`); the run closes it.
        calibration: the leader's base in the follower's frame.
        controller: ``"servo"`` or an SB3 model's ``.zip``.
        config: the run's settings.
        posenet: GDNN weights of the servo controller and the contact check (None: the shipped ``surface``).
        truth: the rehearsal rig's camera (its ground truth is logged), or None.
        plan: the leader's plan (``flange_target(time_s)``, ``duration_s``; default the config's trajectory,
            :class:`LeaderPlan`); the calibration passes its waypoints.
        on_cycle: called with every logged row (a rehearsal's fault injection).
    """

    def __init__(self, leader_endpoint: ArmEndpoint, follower_endpoint: ArmEndpoint, camera, calibration:
                 ArmsCalibration, controller: str = "servo", config: ExperimentConfig = ExperimentConfig(),
                 posenet: str | None = None, truth=None, plan=None,
                 on_cycle: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.leader_endpoint = leader_endpoint
        self.follower_endpoint = follower_endpoint
        self.camera = camera
        self.calibration = calibration
        self.controller_spec = controller
        self.config = config
        self.posenet = posenet
        self.truth = truth
        self.plan = plan if plan is not None else LeaderPlan(config.trajectory_config(),
                                                             config.leader_start_pose_mm_deg, config.plate)
        self.on_cycle = on_cycle
        self._T_follower_leader = calibration.leader_in_follower.T_follower_leader()
        self._T_flange_sensor = config.real_env.mount.T_flange_sensor()
        self.rows: list[dict[str, Any]] = []
        self.late_cycles = 0  # tracking cycles whose plan clock advanced less than the wall clock
        self.plan_behind_s = 0.0  # how far the plan's clock fell behind the wall clock, s

    # -- building ------------------------------------------------------------------------------------------------

    def _build(self, leader) -> _Arms:
        from simshear_gym.control.estimator import EstimatorConfig, TactileEstimator
        from simshear_gym.real.env import RealTactileEnv

        cfg = self.config
        observed = {}
        if self.controller_spec != "servo":
            from simshear_gym.control.policy import PolicySettings

            policy = PolicySettings.of_model(self.controller_spec)  # the observation it was trained on
            observed = dict(image_size_px=policy.image_size_px, observation=policy.observation, history=policy.history)
        env_config = self.env_config = replace(
            _at(self.follower_endpoint, cfg.real_env), posenet=self.posenet,
            start_pose_mm_deg=tuple(follower_hover_pose(cfg, self.calibration.leader_in_follower)),
            safety=replace(cfg.real_env.safety, stop_on_lost_contact=cfg.min_depth_mm is not None), **observed)
        estimator = TactileEstimator(EstimatorConfig(posenet=self.posenet))

        def read_depth(tactile: np.ndarray) -> float:
            return float(estimator.read(tactile)[0][0])

        contact = _Contact(read_depth, cfg.min_depth_mm)
        env = RealTactileEnv(env_config, camera=self.camera, contact_check=contact)
        if self.controller_spec == "servo":
            from simshear_gym.control.servo import ServoController

            controller = ServoController(env_config.reference_depth_mm, env_config.action_scale,
                                         estimator=EstimatorConfig(posenet=self.posenet,
                                                                   process_std_mm=env_config.estimator_process_std_mm))
        else:
            from simshear_gym.control.policy import SB3Controller

            controller = SB3Controller.for_env(self.controller_spec, env)
        return _Arms(leader, env, controller, read_depth)

    # -- geometry ------------------------------------------------------------------------------------------------

    def _face(self, leader_pose) -> np.ndarray:
        return self.config.plate.T_follower_face(leader_pose, self._T_follower_leader)

    def _sensor(self, follower_pose) -> np.ndarray:
        return (pose_to_T_base_flange(follower_pose) @ self._T_flange_sensor)[:3, 3]

    # -- the run -------------------------------------------------------------------------------------------------

    def run(self, out_dir: str | Path, command: str = "") -> dict[str, Any]:
        """Run, write ``log.csv``, ``experiment.json`` and ``experiment.png`` in ``out_dir``; the summary."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        cfg = self.config
        started = time.monotonic()
        leader = arms = None
        stop, why, phase = "", "", "approach"
        try:
            leader = prepare_arms(self.leader_endpoint, self.follower_endpoint, cfg)
            arms = self._build(leader)
            observation, info = arms.env.reset()
            stop, why, phase = self._loop(arms, observation, info)
            if stop == "":
                self._finish(arms)
        finally:
            if arms is not None:
                arms.env.close()
            else:
                self.camera.close()
            if leader is not None:
                leader.close()
        summary = self._summary(stop, why, phase, command, time.monotonic() - started)
        columns = list(dict.fromkeys(key for row in self.rows for key in row))  # each row's new keys, in order
        write_log_csv(out_dir / "log.csv", columns, self.rows)
        plot_run(self.rows, out_dir / "experiment.png", title=self._title(summary))
        write_json(out_dir / "experiment.json", summary)
        return summary

    def _loop(self, arms: _Arms, observation, info) -> tuple[str, str, str]:
        """Approach, settle and track; (stop, why, phase at the stop)."""
        cfg = self.config
        env, leader, controller = arms.env, arms.leader, arms.controller
        hold = np.array(cfg.leader_start_pose_mm_deg)
        t0 = time.monotonic()
        descended_mm = 0.0
        phase = "approach"
        settle_until = None
        plan_s, plan_wall_s = 0.0, math.nan  # the plan's clock and the wall time it last advanced at
        leader_target = hold.copy()
        previous_target_r = float(hold[3])
        q_face: np.ndarray | None = None
        cycle = 0
        while True:
            now = time.monotonic()
            if phase == "track":
                advance_s = now - plan_wall_s
                if advance_s > cfg.real_env.servo_time_s:
                    self.late_cycles += 1
                    self.plan_behind_s += advance_s - cfg.real_env.servo_time_s
                    advance_s = cfg.real_env.servo_time_s
                plan_s, plan_wall_s = plan_s + advance_s, now
                trajectory_s = plan_s
                leader_target = self.plan.flange_target(trajectory_s)
                if trajectory_s > self.plan.duration_s + cfg.hold_s:
                    return "", "", phase
            else:
                trajectory_s = math.nan
            leader_error = None
            try:
                leader.servo_p(*leader_target, t_s=cfg.real_env.servo_time_s)
            except Exception as error:  # noqa: BLE001 - classified below; anything unknown is re-raised there
                leader_error = error
            leader_stop = _leader_stop(leader, leader_error) if leader_error is not None else None
            if leader_stop is not None:
                self._log(cycle, now - t0, phase, trajectory_s, leader, leader_target, info, None, None, q_face,
                          0.0, leader_stop)
                return (*leader_stop, phase)
            compute_start = time.perf_counter()
            estimate = None
            if phase == "approach":
                depth = arms.read_depth(env.contact_check.last_tactile)
                estimate = (np.array([depth, math.nan, math.nan, math.nan]), np.full(4, math.nan))
                if depth >= cfg.touch_depth_mm:
                    phase, settle_until = "settle", now + cfg.settle_s
                    controller.reset()
                    env.contact_check.armed = True
                elif descended_mm >= cfg.hover_mm + cfg.max_approach_mm:
                    self._log(cycle, now - t0, phase, trajectory_s, leader, leader_target, info, None, estimate,
                              q_face, 0.0, ("no_contact", ""))
                    return ("no_contact", f"no touch read after descending {descended_mm:.1f} mm (the GDNN reads "
                            f"{depth:.2f} mm < touch_depth_mm = {cfg.touch_depth_mm:g})", phase)
                else:
                    action = np.array([0.0, 0.0, cfg.approach_step_mm / cfg.real_env.action_scale.step_mm, 0.0])
                    descended_mm += cfg.approach_step_mm
            if phase != "approach":
                try:
                    action = controller(observation)
                except (ValueError, FloatingPointError) as error:
                    action = None
                    controller_error = error
                estimate = getattr(controller, "last_estimate", None)
                if action is not None:
                    action = self._adapt_action(action)
            if action is not None and phase == "track" and cfg.rz_feedforward:
                turn_deg = wrap_deg(float(leader_target[3]) - previous_target_r)  # about the vertical, up
                action = np.asarray(action, dtype=np.float64).copy()
                # the action's dRz turns about the sensor's axis, which points down
                action[3] = float(np.clip(action[3] - turn_deg / cfg.real_env.action_scale.step_deg, -1.0, 1.0))
            previous_target_r = float(leader_target[3])
            compute_ms = 1000.0 * (time.perf_counter() - compute_start)
            if action is None:
                observation, _, terminated, _, info = env.end_episode(
                    "controller_error", f"the controller could not compute an action, nothing sent: "
                    f"{controller_error}")
            else:
                observation, _, terminated, _, info = env.step(action)
            if phase == "settle" and not terminated:
                self._settling(settle_until - time.monotonic())
            if phase == "settle" and time.monotonic() >= settle_until and not terminated:
                phase, plan_wall_s = "track", time.monotonic()
                leader_pose = self._leader_feedback(leader)
                if leader_pose is not None and info["flange_pose_mm_deg"] is not None:
                    sensor = self._sensor(info["flange_pose_mm_deg"])
                    q_face = (invert(self._face(leader_pose)) @ np.append(sensor, 1.0))[:3]
                if self.truth is not None:  # at the fed-back pose marked above (the leader holds still)
                    self.truth.mark_target(info["flange_pose_mm_deg"])
            stop = None
            if terminated:
                stop = (f"follower_{info['termination']}", info.get("safety_event", ""))
            else:
                stop = _leader_stop(leader, None)
            row = self._log(cycle, time.monotonic() - t0, phase, trajectory_s, leader, leader_target, info, action,
                            estimate, q_face, compute_ms, stop)
            if stop is None and phase != "approach" and self.config.kinematic_stops:
                stop = self._kinematic_stop(row, leader_target)
                if stop is not None:
                    row["stop"], row["stop_reason"] = stop
            if self.on_cycle is not None:
                self.on_cycle(row)
            if stop is not None:
                return (*stop, phase)
            cycle += 1

    def _settling(self, left_s: float) -> None:
        """Called every settle cycle with the settle's time left, s (nothing to do on the plate)."""

    def _adapt_action(self, action: np.ndarray) -> np.ndarray:
        """The controller's action as the follower's mount can carry it out (all of it, on the plate)."""
        return action

    def _leader_feedback(self, leader) -> np.ndarray | None:
        from simshear_gym.real.mg400_client import FeedbackStaleError

        try:
            return np.asarray(leader.latest_feedback(math.inf).tool_vector_actual, dtype=np.float64)
        except FeedbackStaleError:
            return None

    def _kinematic_stop(self, row: dict[str, Any], leader_target: np.ndarray) -> tuple[str, str] | None:
        cfg = self.config
        lag = row["leader_lag_mm"]
        if math.isfinite(lag) and lag > cfg.max_leader_lag_mm:
            return "leader_off_path", (f"the leader's fed-back pose is {lag:.2f} mm from its target in force "
                                       f"(max_leader_lag_mm = {cfg.max_leader_lag_mm:g})")
        lift = row["sensor_above_face_mm"]
        if math.isfinite(lift) and (lift > cfg.max_lift_mm or not row["on_face"]):
            return "lost_contact", (f"the sensor is {lift:.2f} mm above the plate{'' if row['on_face'] else ', off it'}"
                                    f" (max_lift_mm = {cfg.max_lift_mm:g}), by the arms' kinematics")
        error = row["contact_error_mm"]
        if math.isfinite(error) and error > cfg.max_contact_error_mm:
            return "arms_apart", (f"contact error {error:.2f} mm > max_contact_error_mm = "
                                  f"{cfg.max_contact_error_mm:g}: the arms drifted apart")
        return None

    def _log(self, cycle: int, time_s: float, phase: str, trajectory_s: float, leader, leader_target, info,
             action, estimate, q_face, compute_ms: float, stop) -> dict[str, Any]:
        leader_pose = self._leader_feedback(leader)
        follower_pose = info.get("flange_pose_mm_deg")
        row: dict[str, Any] = {"cycle": cycle, "time_s": round(time_s, 4), "phase": phase,
                               "trajectory_s": round(trajectory_s, 4)}
        for prefix, value in (("leader_target", leader_target), ("leader", leader_pose),
                              ("follower_target", info.get("flange_target_mm_deg")), ("follower", follower_pose)):
            for name, number in zip(POSE_NAMES, log_vector(value)):
                row[f"{prefix}_{name}"] = round(number, 6)
        sensor = target = None
        lift = error = math.nan
        on_face = True
        if follower_pose is not None:
            sensor = self._sensor(follower_pose)
        if leader_pose is not None and sensor is not None:
            T_face = self._face(leader_pose)
            in_face = (invert(T_face) @ np.append(sensor, 1.0))[:3]
            lift = float(in_face[2])
            half = self.config.plate.half_extents_mm
            on_face = bool(abs(in_face[0]) <= half[0] and abs(in_face[1]) <= half[1])
            if q_face is not None:
                target = (T_face @ np.append(q_face, 1.0))[:3]
                error = float(np.linalg.norm(sensor - target))
        for prefix, value in (("sensor", sensor), ("target", target)):
            for name, number in zip(XYZ, log_vector(value, 3)):
                row[f"{prefix}_{name}"] = round(number, 5)
        lag = math.nan
        if leader_pose is not None:
            lag = float(np.linalg.norm(np.asarray(leader_pose[:3]) - np.asarray(leader_target[:3])))
        row.update(contact_error_mm=round(error, 5), sensor_above_face_mm=round(lift, 5), on_face=on_face,
                   leader_lag_mm=round(lag, 5))
        mean, std = (None, None) if estimate is None else estimate
        for name, m, s in zip(STATE_NAMES, log_vector(mean), log_vector(std)):
            row[f"estimate_{name}"] = round(m, 4)
            row[f"estimate_std_{name}"] = round(s, 4)
        for index, number in enumerate(log_vector(action)):
            row[f"action_{index}"] = round(number, 5)
        snapshot = leader.status_snapshot()
        row.update(compute_ms=round(compute_ms, 3), overrun_s=round(float(info.get("overrun_s", 0.0)), 4),
                   leader_feedback_age_s=snapshot.feedback_age_s, follower_feedback_age_s=info.get("feedback_age_s"),
                   camera_frame_age_s=info.get("camera_frame_age_s"), follower_in_contact=info.get("in_contact"),
                   stop="" if stop is None else stop[0], stop_reason="" if stop is None else stop[1])
        if self.truth is not None and self.truth.history:
            truth = self.truth.history[-1]
            row.update(truth_contact_error_mm=round(truth.contact_error_mm, 5),
                       truth_penetration_mm=round(truth.penetration_mm, 5), truth_in_contact=truth.in_contact)
        self.rows.append(row)
        return row

    def _finish(self, arms: _Arms) -> None:
        """After a finished run: the follower lifts off the plate (the leader stays)."""
        client = arms.env.client
        time.sleep(self.config.real_env.servo_time_s)  # the last servo target reached
        _lift(client, self.config.retreat_mm, self.config.real_env.safety)

    def _summary(self, stop: str, why: str, phase: str, command: str, wall_s: float) -> dict[str, Any]:
        cfg = self.config
        tracking = [row for row in self.rows if row["phase"] == "track"]
        errors = np.array([row["contact_error_mm"] for row in tracking], dtype=float)
        errors = errors[np.isfinite(errors)]
        compute = np.array([row["compute_ms"] for row in self.rows if row["phase"] != "approach"], dtype=float)
        times = np.array([row["time_s"] for row in tracking], dtype=float)
        loop_hz = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else None
        out_of_contact = sum(1 for row in tracking if row["sensor_above_face_mm"] > 0.0 or not row["on_face"])
        summary: dict[str, Any] = {
            "command": command,
            "trajectory": getattr(self.plan, "name", cfg.trajectory),
            "controller": self.controller_spec,
            "leader": str(self.leader_endpoint),
            "follower": str(self.follower_endpoint),
            "calibration": self.calibration.to_dict(),
            "config": cfg.to_dict() | {"real_env": self.env_config.to_dict()},  # the follower's env as built
            "stop": stop,
            "stop_reason": why,
            "stop_phase": phase if stop else "",
            "completed": stop == "",
            "trajectory_duration_s": round(self.plan.duration_s, 3),
            "tracking_cycles": len(tracking),
            "cycles": len(self.rows),
            "contact_error_mean_mm": _stat(errors, np.mean),
            "contact_error_std_mm": _stat(errors, np.std),
            "contact_error_max_mm": _stat(errors, np.max),
            "cycles_out_of_contact": out_of_contact,
            "contact_lost": stop in ("lost_contact", "follower_lost_contact", "arms_apart"),
            "loop_rate_hz": None if loop_hz is None else round(float(loop_hz), 3),
            "compute_ms_median": _stat(compute, np.median, 3),
            "compute_ms_p95": _stat(compute, lambda a: np.percentile(a, 95), 3),
            "period_overruns": sum(1 for row in self.rows if row["overrun_s"] > 0.0),
            "late_cycles": self.late_cycles,
            "plan_behind_s": round(self.plan_behind_s, 3),
            "wall_s": round(wall_s, 2),
        }
        if self.truth is not None:
            truth = np.array([row.get("truth_contact_error_mm", math.nan) for row in tracking], dtype=float)
            truth = truth[np.isfinite(truth)]
            summary.update(truth_contact_error_mean_mm=_stat(truth, np.mean),
                           truth_contact_error_std_mm=_stat(truth, np.std),
                           truth_contact_error_max_mm=_stat(truth, np.max),
                           truth_cycles_out_of_contact=sum(1 for row in tracking
                                                           if row.get("truth_in_contact") is False))
        return summary

    def _title(self, summary: dict[str, Any]) -> str:
        mean, std = summary["contact_error_mean_mm"], summary["contact_error_std_mm"]
        error = "no tracking" if mean is None else f"contact error {mean:.2f} +- {std:.2f} mm"
        return f"{summary['trajectory']} ({summary['controller']}): {error}; {summary['stop'] or 'completed'}"


def _stat(values: np.ndarray, function, digits: int = 4) -> float | None:
    return round(float(function(values)), digits) if len(values) else None


def _span(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.max() - finite.min()) if len(finite) else 0.0


def draw_run(axes, rows: list[dict[str, Any]], title: str = "") -> None:
    """The paper's figure on 3-D ``axes``: the leader's contact point (red) and the follower's sensor (blue) in
    the follower's base frame, while tracking."""
    tracking = [row for row in rows if row["phase"] == "track"]

    def column(name: str) -> np.ndarray:
        return np.array([row[name] for row in tracking], dtype=float)

    if tracking:
        axes.plot(column("target_x_mm"), column("target_y_mm"), column("target_z_mm"), color="red", label="leader")
        axes.plot(column("sensor_x_mm"), column("sensor_y_mm"), column("sensor_z_mm"), color="blue",
                  label="follower", linewidth=0.9)
        # one scale on all three axes, so that a flat path looks flat (and the follower's z wobble true to size)
        centres = [float(np.nanmean(column(f"target_{n}"))) for n in XYZ]
        half = max(max(_span(column(f"target_{n}")) for n in XYZ), 1.0) / 2.0 + 2.0
        axes.set(xlim=(centres[0] - half, centres[0] + half), ylim=(centres[1] - half, centres[1] + half),
                 zlim=(centres[2] - half, centres[2] + half))
        axes.view_init(elev=35.0, azim=-130.0)
    axes.set(xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
    axes.legend(fontsize=8)
    if title:
        axes.set_title(title, fontsize=9)


def plot_run(rows: list[dict[str, Any]], path: Path, title: str = "") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure(figsize=(10.0, 4.4))
    draw_run(figure.add_subplot(1, 2, 1, projection="3d"), rows, "follower's base frame")
    axes = figure.add_subplot(1, 2, 2)
    tracking = [row for row in rows if row["phase"] == "track"]
    time_s = np.array([row["trajectory_s"] for row in tracking], dtype=float)
    axes.plot(time_s, [row["contact_error_mm"] for row in tracking], "k", label="contact error (calibrated)")
    if tracking and "truth_contact_error_mm" in tracking[0]:
        axes.plot(time_s, [row["truth_contact_error_mm"] for row in tracking], "g--", linewidth=0.8,
                  label="rig truth")
    axes.set(xlabel="trajectory time (s)", ylabel="mm", title="contact error")
    axes.legend(fontsize=8)
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    atomic_write(path, lambda tmp: figure.savefig(tmp, dpi=90, format="png"), suffix=".png")
    plt.close(figure)
    return path


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arm_arguments(parser: argparse.ArgumentParser, leader_holds: str = "moves the plate",
                      sensor: str = "carries the TacTip", rig: str = "the rig camera",
                      rig_leader_base: tuple[float, ...] = BaseToBase().as_tuple(), scene: str = "the sim scene's",
                      ) -> None:
    """The options every two-arm experiment takes: the arms, the camera, the calibration and the rehearsal rig."""
    parser.add_argument("--leader", default=None, metavar="HOST[:PORTS]",
                        help=f"the leader MG400 ({leader_holds}): HOST or HOST:DASHBOARD,MOTION,FEEDBACK")
    parser.add_argument("--follower", default=None, metavar="HOST[:PORTS]",
                        help=f"the follower MG400 ({sensor}): HOST or HOST:DASHBOARD,MOTION,FEEDBACK")
    parser.add_argument("--camera", default=None, metavar="SRC", help="the TacTip camera: device index or video file")
    parser.add_argument("--calibration", default=None, metavar="FILE",
                        help="the arms' calibration (simshear calibrate-arms); with --rehearsal default: the rig's "
                             "true layout")
    parser.add_argument("--rehearsal", action="store_true",
                        help=f"start the rehearsal rig (two loopback emulators and {rig}) and run on it")
    parser.add_argument("--rig-leader-base", type=float, nargs=4, default=list(rig_leader_base),
                        metavar=("X", "Y", "Z", "RZ"),
                        help="--rehearsal: where the rig's leader base truly stands in the follower's frame (mm, "
                             f"deg; default {scene})")


def add_loop_arguments(parser: argparse.ArgumentParser, gdnn: str = "surface", out: str = "runs/experiment") -> None:
    """The options of every two-arm experiment's loop: the controller, the period, the limits, the output."""
    parser.add_argument("--controller", default="servo", metavar="servo|MODEL.zip",
                        help="'servo' (GDNN + filter + PI law) or an SB3 model of simshear train rl")
    parser.add_argument("--posenet", default=None, help=f"GDNN weights (default: the shipped {gdnn} GDNN)")
    parser.add_argument("--period-s", type=float, default=ExperimentConfig.real_env.control_period_s,
                        help="control period, s (default %(default)g: 10 Hz)")
    parser.add_argument("--max-feedback-age-s", type=float, default=None,
                        help="feedback (and camera frames) older than this stop both arms (default 0.1 and the "
                             "camera's 0.5; 1.0 with --rehearsal: the emulators share this process)")
    parser.add_argument("--preprocess", default="shipped",
                        help="camera preprocessing JSON, 'shipped' (default) or 'none' (tactile images)")
    parser.add_argument("--out", type=Path, default=None, help=f"output folder (default {out}/<time>)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear experiment tracking``."""
    add_arm_arguments(parser)
    parser.add_argument("--trajectory", default=ExperimentConfig.trajectory, choices=TRAJECTORIES,
                        help="the leader's path")
    parser.add_argument("--speed-mm-s", type=float, default=ExperimentConfig.speed_mm_s,
                        help="the leader's speed along its path, mm/s")
    parser.add_argument("--reference-depth-mm", type=float, default=ExperimentConfig.real_env.reference_depth_mm,
                        help="depth to hold (default %(default).1f)")
    add_loop_arguments(parser)


def rehearsal_safety(max_feedback_age_s: float = 1.0, max_camera_frame_age_s: float = 1.0) -> SafetyConfig:
    """The safe defaults with the feedback and camera-frame ages the rehearsal allows: two emulators, the render
    and the networks share one process (on a loaded 2-core machine a 0.5 s stall is the machine's, not the link's
    or the camera's; the stale-feedback and camera faults have their own tests). The rig's camera renders on read
    and has no frame age (:func:`~simshear_gym.real.camera.renders_on_read`): ``max_camera_frame_age_s`` binds a
    real camera only."""
    return SafetyConfig(max_feedback_age_s=max_feedback_age_s, max_camera_frame_age_s=max_camera_frame_age_s)


def run_on_rig(rig, config: ExperimentConfig, out_dir: str | Path, controller: str = "servo",
               calibration: ArmsCalibration | None = None, posenet: str | None = None, command: str = "",
               on_cycle: Callable[[dict[str, Any]], None] | None = None, plan=None,
               experiment: type[ExperimentRun] | None = None) -> dict[str, Any]:
    """One run on a started rehearsal rig (:class:`~simshear_gym.lab.rig.RehearsalRig`) with a fresh rig camera
    (calibration default: the rig's true layout); the summary gains the emulators' audit (``audit``: every
    command either emulator has received so far that the safe defaults refuse, per arm) and is written again.
    ``experiment``: the run's class (default :class:`ExperimentRun`; co-lift's subclass)."""
    calibration = calibration if calibration is not None else ArmsCalibration(rig.config.leader_in_follower,
                                                                              "fixture", command="rig truth")
    camera = rig.new_camera()
    experiment = experiment if experiment is not None else ExperimentRun
    run_ = experiment(rig.leader_endpoint, rig.follower_endpoint, camera, calibration, controller, config,
                      posenet, truth=camera, plan=plan, on_cycle=on_cycle)
    summary = run_.run(out_dir, command)
    summary["audit"] = rig.audit(SafetyConfig())
    summary["commands_outside_limits"] = sum(len(lines) for lines in summary["audit"].values())
    summary["leader_true_in_follower"] = list(rig.config.leader_in_follower.as_tuple())
    write_json(Path(out_dir) / "experiment.json", summary)
    summary["rows"] = run_.rows
    return summary


def run_tracking_rehearsal(config: ExperimentConfig, out_dir: str | Path, controller: str = "servo",
                           calibration: ArmsCalibration | None = None, posenet: str | None = None,
                           command: str = "", rig_config=None, **rig_changes) -> dict[str, Any]:
    """One tracking run on a fresh rehearsal rig (:func:`run_on_rig`; default: laid out as ``config`` has it, with
    ``rig_changes``)."""
    from simshear_gym.lab.rig import RehearsalRig, RigConfig

    rig_config = rig_config if rig_config is not None else RigConfig.for_run(config, **rig_changes)
    with RehearsalRig(rig_config) as rig:
        summary = run_on_rig(rig, config, out_dir, controller, calibration, posenet, command)
    summary.pop("rows")
    return summary


def report_run(summary: dict[str, Any], out_dir: Path, headline: str) -> int:
    """Print a two-arm run's result (``headline``; completed or why it stopped; the emulators' audit where the
    summary has one; the files written to ``out_dir``); 0 when it completed, 1 when a stop ended it early."""
    print(f"{headline}; "
          f"{'completed' if summary['completed'] else 'stopped: ' + summary['stop'] + ': ' + summary['stop_reason']}")
    if "commands_outside_limits" in summary:
        print(f"emulators' audit: {summary['commands_outside_limits']} commands outside the safety limits")
    print(f"wrote {out_dir / 'log.csv'}, {out_dir / 'experiment.json'}, {out_dir / 'experiment.png'}")
    return 0 if summary["completed"] else 1


def arms_safety(args: argparse.Namespace) -> SafetyConfig:
    """Both arms' limits: the safe defaults, or :func:`rehearsal_safety` with ``--max-feedback-age-s`` (default 1 s
    with ``--rehearsal``)."""
    age = args.max_feedback_age_s if args.max_feedback_age_s is not None else (1.0 if args.rehearsal else None)
    return SafetyConfig() if age is None else rehearsal_safety(age, max(age, SafetyConfig.max_camera_frame_age_s))


def run_experiment(args: argparse.Namespace, command: str, make_config: Callable[..., ExperimentConfig],
                   experiment: type[ExperimentRun], rehearse, out: str, headline: str) -> int:
    """A two-arm experiment command's ``run`` (``command``: its recorded command line); 0 when it completed, 1 when
    a stop ended it early.

    It checks the arms, camera and calibration given (or ``--rehearsal``) and the controller, sets logging and
    torch's threads; builds the run's config, ``make_config(**env)`` (``env``: the follower env's control period,
    both arms' limits, :func:`arms_safety`, and the camera preprocessing); runs on a fresh rehearsal rig
    (``rehearse``, as :func:`run_tracking_rehearsal`, the rig's leader base from ``--rig-leader-base``) or on the
    arms (an ``experiment``: both endpoints parsed before the camera opens) into ``--out`` (default
    ``out/<time>``); and reports with :func:`report_run`, ``headline`` filled in from the summary."""
    import torch

    if args.rehearsal and (args.leader or args.follower or args.camera):
        raise ValueError("--rehearsal starts its own arms and camera: leave out --leader, --follower and --camera")
    if not args.rehearsal and not (args.leader and args.follower and args.camera is not None and args.calibration):
        raise ValueError("give --leader, --follower, --camera and --calibration (or --rehearsal)")
    if args.controller != "servo" and not Path(args.controller).is_file():
        raise FileNotFoundError(f"--controller {args.controller!r} is neither 'servo' nor an existing SB3 .zip file")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    config = make_config(control_period_s=args.period_s, safety=arms_safety(args),
                         preprocess=preprocess_config(args.preprocess))
    out_dir = args.out if args.out is not None else Path(out) / time.strftime("%Y%m%d-%H%M%S")
    calibration = ArmsCalibration.load(args.calibration) if args.calibration else None
    if args.rehearsal:
        summary = rehearse(config, out_dir, args.controller, calibration, args.posenet, command,
                           leader_in_follower=BaseToBase(*args.rig_leader_base))
        summary.pop("rows", None)
    else:
        from simshear_gym.real.camera import CameraSource

        leader, follower = ArmEndpoint.parse(args.leader, "--leader"), ArmEndpoint.parse(args.follower, "--follower")
        summary = experiment(leader, follower, CameraSource(args.camera), calibration, args.controller, config,
                             args.posenet).run(out_dir, command)
    return report_run(summary, out_dir, headline.format(**summary))


def run(args: argparse.Namespace) -> int:
    """Run the experiment; 0 when it completed, 1 when a stop ended it early."""
    def config(**env) -> ExperimentConfig:
        return ExperimentConfig(trajectory=args.trajectory, speed_mm_s=args.speed_mm_s).with_env(
            reference_depth_mm=args.reference_depth_mm, **env)

    return run_experiment(args, recorded_command("simshear experiment tracking", add_arguments, args), config,
                          ExperimentRun, run_tracking_rehearsal, "runs/experiment",
                          "{trajectory}: {tracking_cycles} tracking cycles at {loop_rate_hz} Hz, contact error "
                          "{contact_error_mean_mm} +- {contact_error_std_mm} mm, compute {compute_ms_median} ms median")


__all__ = ["STOPS", "BaseToBase", "ExperimentConfig", "ExperimentError", "ExperimentRun", "LeaderPlan",
           "follower_hover_pose", "prepare_arms", "report_run", "run_on_rig", "run_tracking_rehearsal"]
