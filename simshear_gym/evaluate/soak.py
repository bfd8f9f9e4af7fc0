"""A fault soak of the real path: ``RealTactileEnv`` driven by the servo controller against the MG400 emulator and a
replayed camera, for thousands of control cycles, with faults injected at random.

``simshear evaluate soak --cycles 10000 --seed 0`` runs :func:`run_soak` on the raw TacTip frames of
``tactip331_raw`` (replayed in a loop, preprocessed as on the robot) and writes ``results/soak.json`` (and the
figure ``results/soak.png``) with the command that produced it. The test suite runs a shorter seeded soak on
synthetic frames.

Every cycle is one ``env.step`` of the servo controller's action (GDNN + Bayesian filter + PI law). **The fault
schedule is decided up front** from the seed (:func:`fault_schedule`): after a random gap, the next kind of a seeded
random permutation of :data:`FAULT_KINDS` (a new permutation each round, so every kind recurs), with random
parameters, at a fixed cycle for a fixed number of cycles, whatever happens during the run; so two runs with the same
seed inject the same faults at the same cycles, and give the same record (:data:`TIMING_KEYS` aside: wall-clock
timings and the stop examples, which quote measured poses and ports). The faults:

* ``dropped_connection``: the emulator closes every connection; ``split_replies``: replies in 2-7 byte TCP
  segments; ``partial_feedback`` / ``corrupt_feedback``: every 2nd-4th feedback packet cut in half / with a wrong
  length field or test value; ``stale_feedback``: no feedback packet for 0.15-0.4 s;
  ``inconsistent_feedback``: every 3rd packet's joints disagree with its pose; ``alarm_mid_motion``: a
  controller alarm (collision, overspeed) while the arm moves; ``slow_replies``: ServoP replies 5-30 ms late
  (ridden through) or 0.4 s late (past the reply timeout); ``camera_stall``: the camera delivers nothing for
  0.6 s; ``frozen_frames``: the camera repeats one frame 5-40 times; ``nan_estimate``: the estimator's reading is
  NaN for 1-3 cycles.

**The controller's box is the soak's workspace.** The soak, like a deployed controller with a workspace guard, scales
back the translation of an action that would take the flange target out of the workspace box (the safety layer's
box; every point of it within ``max_move_mm`` of the start, so that a reset can always move back), so the controller
never asks for a target the safety layer must refuse; and its servo stream is clamped to the stream limits
(``servo_over_limit="clamp"``: the user's choice for a servo stream) instead of being refused. A stop without an
injected fault is then a finding, not the controller running into the box.

Each injected fault ends as a **safe stop** (the episode ended, with a termination the fault can cause
(:data:`FAULT_STOPS`), while it was active or within :data:`GRACE_CYCLES` after) or is **recovered** (ridden
through: the episode went on, every command within the limits; a fault cut short by an unrelated stop counts here
too, and in ``faults_cut_short``). A controller that cannot compute an action (the servo law refuses a NaN
estimate) ends the episode with ``controller_error`` (:meth:`~simshear_gym.real.env.RealTactileEnv.end_episode`),
as ``simshear rollout`` does. After a stop the soak does what an operator would (``ClearError`` + ``Continue``
after an alarm), resets the env (reconnecting if needed) and the controller, and counts the reset as a recovery;
a reset refused while the robot is not ready (a typed error) is retried. Episodes are truncated after
``episode_cycles``.

**Commands outside the limits** are counted independently of the client, from the emulator's records: the motions the
arm executed (:meth:`~simshear_gym.real.mg400_emulator.MG400Emulator.executed_motions`: faster than ``max_speed_*`` or
accelerating faster than ``max_accel_*``), and every motion command it received
(:meth:`~simshear_gym.real.mg400_emulator.MG400Emulator.motion_records`), against the soak's
:class:`~simshear_gym.real.safety.SafetyConfig`: the target's reach, joint limits and workspace box; its step, speed
(step / ``t``) or jump from the last target the robot accepted (what the client commanded); and, for a command the
robot executed, from the target in force when it arrived (what the arm did: after an alarm halted the arm short of its
target, a command is measured from where the arm stopped). Anything raised by ``env.step`` or the controller is
**unhandled**: counted, with its message, and the soak goes on with a reset. All of these must be 0.
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record
from simshear_gym.real.env import ENV_CLIENT, RealEnvConfig

FAULT_KINDS: tuple[str, ...] = ("dropped_connection", "split_replies", "partial_feedback", "corrupt_feedback",
                                "stale_feedback", "inconsistent_feedback", "alarm_mid_motion", "slow_replies",
                                "camera_stall", "frozen_frames", "nan_estimate")
"""Every fault the soak injects."""

GRACE_CYCLES = 3
"""A stop this many cycles after a fault ended still counts as that fault's safe stop (its effects can lag)."""

FAULT_STOPS: dict[str, tuple[str, ...]] = {
    "dropped_connection": ("lost_connection", "robot_error"),
    "split_replies": ("lost_connection",),
    "partial_feedback": ("lost_connection",),
    "corrupt_feedback": ("lost_connection",),
    "stale_feedback": ("lost_connection",),
    "inconsistent_feedback": ("feedback_mismatch",),
    "alarm_mid_motion": ("robot_error",),
    "slow_replies": ("lost_connection",),
    "camera_stall": ("camera_stall",),
    "frozen_frames": ("camera_stall",),
    "nan_estimate": ("controller_error", "safety_refused"),
}
"""The terminations each fault can cause: a stop of another kind while it is active is not its doing (the
controller reaching the workspace box, say), and is counted as a stop without a fault."""

TIMING_KEYS: tuple[str, ...] = ("wall_s", "cycles_per_s", "stop_examples", "motion_commands_sent",
                                 "servo_commands_sent", "motions_executed")
"""Keys of the soak's record that depend on the wall clock, left out when two runs of one seed are compared: the
timings; the stop examples (they quote measured poses and ports); and how many commands went out, which a command
or two either way at a time-based stop (feedback older than ``max_feedback_age_s`` seconds, a reply later than the
timeout) changes."""

START_POSE_MM_DEG = (300.0, 0.0, 0.0, 0.0)
WORKSPACE_HALF_MM = 25.0  # the soak's box around the start pose: every point of it within max_move_mm of the start
CONTROL_PERIOD_S = 0.02  # the soak's control period, s: five times the robot's rate, for more cycles a minute


def safety_config():
    """The soak's limits: the safe defaults with the workspace narrowed to a box around the start pose, and servo
    targets clamped to the stream limits."""
    from simshear_gym.real.safety import SafetyConfig

    x, y, z, _ = START_POSE_MM_DEG
    half = WORKSPACE_HALF_MM
    return SafetyConfig(x_range_mm=(x - half, x + half), y_range_mm=(y - half, y + half),
                        z_range_mm=(z - half, z + half), servo_over_limit="clamp")


def soak_env() -> RealEnvConfig:
    """The soak's env (``SoakConfig.real_env`` by default): :data:`CONTROL_PERIOD_S`, 64 px images, the start pose,
    :func:`safety_config`'s limits, and a client that waits 0.25 s for a reply, 1 s for a connection and 5 s for
    ``Sync`` (at the emulator's ports, set when the soak starts)."""
    client = replace(ENV_CLIENT, host="127.0.0.1", reply_timeout_s=0.25, connect_timeout_s=1.0, sync_timeout_s=5.0)
    return RealEnvConfig(client=client, control_period_s=CONTROL_PERIOD_S, image_size_px=64,
                         start_pose_mm_deg=START_POSE_MM_DEG, safety=safety_config())


@dataclass(frozen=True)
class SoakConfig:
    """Settings of one soak.

    Attributes:
        cycles: control cycles to run (env steps), at least 10,000 for the record.
        seed: seeds every random choice (fault times, kinds, parameters, frames).
        mean_gap_cycles: mean number of cycles between one fault's end and the next fault.
        episode_cycles: an episode is truncated (reset, not counted as a stop) after this many cycles, once no
            fault is active (short episodes keep the controller's drift on unrelated frames inside the box).
        max_reset_attempts: resets refused in a row before the soak gives up (a stuck robot), counted as unhandled.
        real_env: the env the servo controller drives (:func:`soak_env`): its control period, servo margin
            (generous: a cycle that runs late must not let the arm arrive and stop, or the next command asks it to
            start again from rest), image size, client timeouts, limits and ``posenet`` (the servo controller's
            GDNN; None: the shipped surface one); its client's ports are the emulator's.
    """

    cycles: int = 10_000
    seed: int = 0
    mean_gap_cycles: float = 20.0
    episode_cycles: int = 40
    max_reset_attempts: int = 20
    real_env: RealEnvConfig = field(default_factory=soak_env)

    def __post_init__(self) -> None:
        if self.cycles < 1 or self.episode_cycles < 1 or self.max_reset_attempts < 1:
            raise ValueError(f"SoakConfig needs cycles, episode_cycles, max_reset_attempts >= 1, got {self.cycles}, "
                             f"{self.episode_cycles}, {self.max_reset_attempts}")
        if not (math.isfinite(self.mean_gap_cycles) and self.mean_gap_cycles >= 1.0):
            raise ValueError(f"SoakConfig.mean_gap_cycles must be >= 1, got {self.mean_gap_cycles!r}")

    def to_dict(self) -> dict[str, Any]:
        """The record's settings: the soak's, and ``real_env``'s (without the emulator's ports: a run's own)."""
        env = {key: value for key, value in self.real_env.to_dict().items() if key != "ports"}
        return {f.name: getattr(self, f.name) for f in fields(self)} | {"real_env": env}


def braking_margin_mm(safety, servo_time_s: float) -> float:
    """How far inside the workspace box the controller keeps its targets: a servo stream at full speed runs
    ``max_speed * t`` behind its target and needs ``max_speed^2 / (2 max_accel)`` to stop, plus 1 mm; so the
    clamped stream never has to leave the box to slow down."""
    cfg = safety.config
    return cfg.max_speed_mm_s * servo_time_s + cfg.max_speed_mm_s ** 2 / (2.0 * cfg.max_accel_mm_s2) + 1.0


def keep_in_box(action: np.ndarray, commanded_flange: np.ndarray, safety, action_scale, mount,
                margin_mm: float = 0.01) -> np.ndarray:
    """``action`` with its translation scaled back (by bisection) so that the flange target stays inside the
    workspace box of ``safety`` shrunk by ``margin_mm`` (the controller's box: the safety layer's, less the
    :func:`braking_margin_mm`)."""
    from simshear_gym.contract import action_to_move
    from simshear_gym.real.env import move_to_flange_target

    cfg = safety.config

    def inside(candidate: np.ndarray) -> bool:
        target = move_to_flange_target(commanded_flange, action_to_move(candidate, action_scale), mount)
        x_mm, y_mm, z_mm, _ = target
        return all(lower + margin_mm <= value <= upper - margin_mm for value, (lower, upper) in (
            (x_mm, cfg.x_range_mm), (y_mm, cfg.y_range_mm), (z_mm, cfg.z_range_mm),
            (math.hypot(x_mm, y_mm), cfg.radius_range_mm)))

    action = np.asarray(action, dtype=np.float64)
    if not np.all(np.isfinite(action)) or inside(action):
        return action
    low, high = 0.0, 1.0
    for _ in range(30):
        middle = 0.5 * (low + high)
        candidate = action.copy()
        candidate[:3] *= middle
        if inside(candidate):
            low = middle
        else:
            high = middle
    kept = action.copy()
    kept[:3] *= low
    return kept


# ----------------------------------------------------------------------------------------------------------------
# Fault-injecting camera and estimator


class ReplayCamera:
    """Recorded frames, replayed in a loop (a ``FrameSource``), with stalls and frozen frames on demand."""

    name = "replayed camera"

    def __init__(self, frames: list[np.ndarray]) -> None:
        if not frames:
            raise ValueError("ReplayCamera needs at least one frame")
        self._frames = frames
        self._index = 0
        self._lock = threading.Lock()
        self._stall_s = 0.0
        self._frozen_left = 0
        self._frozen: np.ndarray | None = None

    def stall(self, duration_s: float) -> None:
        """The next read waits ``duration_s`` and then fails, as a live camera whose driver stopped delivering."""
        with self._lock:
            self._stall_s = float(duration_s)

    def freeze(self, count: int) -> None:
        """The next ``count`` reads return the same frame (a frozen driver)."""
        with self._lock:
            self._frozen_left = int(count)
            self._frozen = None

    def read(self) -> np.ndarray:
        from simshear_gym.real.camera import CameraError

        with self._lock:
            stall_s, self._stall_s = self._stall_s, 0.0
        if stall_s > 0.0:
            time.sleep(stall_s)
            raise CameraError(f"{self.name}: stalled, no new frame within {stall_s:g} s")
        with self._lock:
            if self._frozen_left > 0:
                self._frozen_left -= 1
                if self._frozen is None:
                    self._frozen = self._frames[self._index % len(self._frames)].copy()
                return self._frozen.copy()
            frame = self._frames[self._index % len(self._frames)]
            self._index += 1
        return frame.copy()

    def close(self) -> None:
        pass


class FaultyEstimator:
    """Wraps a :class:`~simshear_gym.control.estimator.TactileEstimator`: after :meth:`nan` its next readings are
    NaN (a GDNN that returned garbage), otherwise it passes through."""

    def __init__(self, estimator) -> None:
        self._estimator = estimator
        self._nan_left = 0

    def nan(self, count: int) -> None:
        self._nan_left = int(count)

    def __call__(self, tactile: np.ndarray, commanded_move: np.ndarray | None = None):
        mean, std = self._estimator(tactile, commanded_move)
        if self._nan_left > 0:
            self._nan_left -= 1
            return np.full_like(mean, np.nan), std
        return mean, std

    def __getattr__(self, name: str):
        return getattr(self._estimator, name)


# ----------------------------------------------------------------------------------------------------------------
# The audit


def audit(records, safety) -> tuple[int, list[str]]:
    """Commands the emulator received outside ``safety``'s limits: (count, up to 10 descriptions).

    Each motion command is checked against the target then in force: reach and joint limits, workspace box, and
    for servo commands the step and speed, for queued moves the jump (R and per-joint changes included).
    """
    from simshear_gym.data.labels import wrap_deg
    from simshear_gym.robots.mg400.kinematics import KinematicsError, check_pose_reachable

    cfg = safety.config
    tolerance = 1e-4  # commands carry 6 decimals
    bad: list[str] = []
    accepted: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # the last target the robot accepted

    def step_problems(record, target: np.ndarray, pose, joints, what: str) -> list[str]:
        step_mm = float(np.linalg.norm(target[:3] - np.array(pose[:3])))
        deltas = np.array(record.target_joints) - np.array(joints)
        deltas[3] = wrap_deg(deltas[3])
        step_deg = max([abs(wrap_deg(target[3] - pose[3]))] + [abs(float(d)) for d in deltas])
        max_mm, max_deg = (cfg.max_step_mm, cfg.max_step_deg) if record.servo else (cfg.max_move_mm, cfg.max_move_deg)
        out = []
        if step_mm > max_mm + tolerance:
            out.append(f"step {step_mm:.3f} mm from {what} > {max_mm:g} mm")
        if step_deg > max_deg + tolerance:
            out.append(f"step {step_deg:.3f} deg from {what} > {max_deg:g} deg")
        if record.servo:
            t_s = float(record.duration_s)
            if step_mm / t_s > cfg.max_speed_mm_s + tolerance / t_s:
                out.append(f"speed {step_mm / t_s:.1f} mm/s from {what} > {cfg.max_speed_mm_s:g} mm/s")
            if step_deg / t_s > cfg.max_speed_deg_s + tolerance / t_s:
                out.append(f"speed {step_deg / t_s:.1f} deg/s from {what} > {cfg.max_speed_deg_s:g} deg/s")
        return out

    for record in records:
        problems: list[str] = []
        if accepted is None:
            accepted = (record.in_force_pose, record.in_force_joints)  # where the robot started
        if record.target_pose is None or record.target_joints is None:
            problems.append("target out of reach")
        else:
            target = np.array(record.target_pose)
            try:
                check_pose_reachable(target, cfg.geometry, cfg.limits)
            except KinematicsError as error:
                problems.append(f"beyond the arm's limits ({error})")
            for name, value, (lower, upper) in (("x", target[0], cfg.x_range_mm), ("y", target[1], cfg.y_range_mm),
                                                ("z", target[2], cfg.z_range_mm),
                                                ("radius", math.hypot(target[0], target[1]), cfg.radius_range_mm),
                                                ("r", target[3], cfg.r_range_deg)):
                if not lower - tolerance <= value <= upper + tolerance:
                    problems.append(f"{name} = {value:.3f} outside [{lower:g}, {upper:g}]")
            problems += step_problems(record, target, *accepted, "the last accepted target")
            if record.error_id == 0:
                problems += step_problems(record, target, record.in_force_pose, record.in_force_joints,
                                          "the target in force")
                accepted = (record.target_pose, record.target_joints)
        if problems:
            bad.append(f"{record.command}: {'; '.join(problems)}")
    return len(bad), bad[:10]


# ----------------------------------------------------------------------------------------------------------------
# The soak


@dataclass
class _Fault:
    kind: str
    start_cycle: int
    end_cycle: int
    stopped: str = ""  # the termination it caused, if any


@dataclass
class _Tally:
    injected: Counter = field(default_factory=Counter)
    outcomes: dict[str, Counter] = field(default_factory=dict)
    stops: Counter = field(default_factory=Counter)
    unprovoked_stops: Counter = field(default_factory=Counter)
    stop_examples: dict[str, str] = field(default_factory=dict)
    cut_short: int = 0
    reset_refusals: Counter = field(default_factory=Counter)
    recoveries: int = 0
    truncations: int = 0
    unhandled: list[str] = field(default_factory=list)

    def outcome(self, fault: _Fault) -> None:
        kind = "safe_stop" if fault.stopped else "recovered"
        self.outcomes.setdefault(fault.kind, Counter())[kind] += 1


def _expected_reset_errors() -> tuple[type[BaseException], ...]:
    from simshear_gym.real.camera import CameraError
    from simshear_gym.real.env import RealEnvError
    from simshear_gym.real.mg400_client import (
        FeedbackStaleError,
        MG400ConnectionError,
        MG400Error,
        MG400TimeoutError,
    )
    from simshear_gym.real.safety import SafetyError
    from simshear_gym.robots.mg400.protocol import ProtocolError

    return (RealEnvError, SafetyError, MG400Error, MG400ConnectionError, MG400TimeoutError, FeedbackStaleError,
            CameraError, ProtocolError)


@dataclass(frozen=True)
class ScheduledFault:
    """One fault of the schedule: its kind, the cycle it starts at, how many cycles it stays active, and its
    parameters (``(name, value)`` pairs: packet interval, pause, delay, alarm id, frame count, ...)."""

    kind: str
    start_cycle: int
    cycles: int
    params: tuple[tuple[str, float], ...] = ()

    def param(self, name: str) -> float:
        return dict(self.params)[name]


def _draw_fault(kind: str, rng: np.random.Generator, period_s: float) -> tuple[int, tuple[tuple[str, float], ...]]:
    """(cycles active, parameters) of one fault of ``kind``."""
    cycles = int(rng.integers(3, 25))
    if kind == "dropped_connection":
        return 1, ()
    if kind == "split_replies":
        return cycles, (("bytes", int(rng.integers(2, 8))),)
    if kind in ("partial_feedback", "corrupt_feedback"):
        return cycles, (("every", int(rng.integers(2, 5))),)
    if kind == "stale_feedback":
        pause_s = float(rng.uniform(0.15, 0.4))
        return int(pause_s / period_s) + 1, (("pause_s", pause_s),)
    if kind == "inconsistent_feedback":
        return cycles, (("every", 3),)
    if kind == "alarm_mid_motion":
        return 1, (("alarm", int(rng.choice([112, 48, 50]))),)
    if kind == "slow_replies":
        return cycles, (("delay_s", float(rng.uniform(0.005, 0.03)) if rng.random() < 0.5 else 0.4),)
    if kind == "camera_stall":
        return 1, (("stall_s", 0.6),)
    if kind == "frozen_frames":
        frames = int(rng.integers(5, 41))
        return frames, (("frames", frames),)
    if kind == "nan_estimate":
        readings = int(rng.integers(1, 4))
        return readings, (("readings", readings),)
    raise ValueError(f"unknown fault kind {kind!r}; expected one of {FAULT_KINDS}")


def fault_schedule(config: SoakConfig) -> list[ScheduledFault]:
    """Every fault of a soak, decided from ``config.seed`` before it runs: after a gap (exponential, mean
    ``mean_gap_cycles``) from the previous fault's window, the next kind of a random permutation of
    :data:`FAULT_KINDS` (a new one each round) with its parameters."""
    rng = np.random.default_rng([config.seed, 41])
    schedule: list[ScheduledFault] = []
    order: list[str] = []
    cycle = int(rng.exponential(config.mean_gap_cycles)) + 1
    while cycle < config.cycles:
        if not order:
            order = [str(kind) for kind in rng.permutation(FAULT_KINDS)]
        kind = order.pop()
        cycles, params = _draw_fault(kind, rng, config.real_env.control_period_s)
        schedule.append(ScheduledFault(kind, cycle, cycles, params))
        cycle += cycles + 1 + int(rng.exponential(config.mean_gap_cycles))
    return schedule


class _Injector:
    """Starts and ends faults on the emulator, the camera and the estimator."""

    def __init__(self, emulator, camera: ReplayCamera, estimator: FaultyEstimator) -> None:
        self.emulator, self.camera, self.estimator = emulator, camera, estimator

    def start(self, fault: ScheduledFault) -> None:
        """Inject ``fault`` (its parameters decided by the schedule)."""
        from simshear_gym.real.mg400_emulator import FaultConfig, FeedbackFault

        emulator, kind = self.emulator, fault.kind
        if kind == "dropped_connection":
            emulator.drop_connections()
        elif kind == "split_replies":
            emulator.set_faults(FaultConfig(split_replies_bytes=int(fault.param("bytes")), split_delay_s=0.0005))
        elif kind == "partial_feedback":
            emulator.set_faults(FaultConfig(corrupt_feedback_every=int(fault.param("every")),
                                            feedback_faults=(FeedbackFault.PARTIAL,)))
        elif kind == "corrupt_feedback":
            emulator.set_faults(FaultConfig(corrupt_feedback_every=int(fault.param("every")),
                                            feedback_faults=(FeedbackFault.BAD_LENGTH, FeedbackFault.BAD_TEST_VALUE)))
        elif kind == "stale_feedback":
            emulator.pause_feedback(fault.param("pause_s"))
        elif kind == "inconsistent_feedback":
            emulator.set_faults(FaultConfig(corrupt_feedback_every=int(fault.param("every")),
                                            feedback_faults=(FeedbackFault.INCONSISTENT,)))
        elif kind == "alarm_mid_motion":
            emulator.inject_alarm(int(fault.param("alarm")))
        elif kind == "slow_replies":
            emulator.set_faults(FaultConfig(reply_delay_s=fault.param("delay_s"), slow_commands=("ServoP",)))
        elif kind == "camera_stall":
            self.camera.stall(fault.param("stall_s"))
        elif kind == "frozen_frames":
            self.camera.freeze(int(fault.param("frames")))
        elif kind == "nan_estimate":
            self.estimator.nan(int(fault.param("readings")))
        else:
            raise ValueError(f"unknown fault kind {kind!r}; expected one of {FAULT_KINDS}")

    def end(self) -> None:
        """Undo every fault (the once-only ones are over by themselves)."""
        from simshear_gym.real.mg400_emulator import FaultConfig

        self.emulator.set_faults(FaultConfig())
        self.camera.freeze(0)
        self.camera.stall(0.0)
        self.estimator.nan(0)


def _wait_for_clean_feedback(emulator, packets: int = 3, timeout_s: float = 2.0) -> None:
    """Wait until the emulator sends feedback again and ``packets`` more packets went out (so that none of an
    ended fault is the newest), before a reset."""
    deadline_s = time.monotonic() + timeout_s
    while emulator.feedback_paused and time.monotonic() < deadline_s:
        time.sleep(0.005)
    sent = emulator.feedback_packets_sent
    while emulator.feedback_packets_sent < sent + packets and time.monotonic() < deadline_s:
        time.sleep(0.002)


def synthetic_frames(count: int = 12, seed: int = 0) -> list[np.ndarray]:
    """Camera-like 640x480 frames (bright pins on a dark membrane, shifted), for a soak without the data set."""
    import cv2

    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(count):
        frame = np.full((480, 640, 3), 30, np.uint8)
        dx, dy = (int(v) for v in rng.integers(-4, 5, 2))
        for y in range(40, 470, 24):
            for x in range(95, 520, 24):
                cv2.circle(frame, (x + dx, y + dy), 6, (230, 230, 230), -1)
        frame += rng.integers(0, 3, frame.shape, dtype=np.uint8)  # sensor noise: no two frames alike
        frames.append(frame)
    return frames


def run_soak(config: SoakConfig, frames: list[np.ndarray]) -> dict[str, Any]:
    """Run the soak (see the module docstring) and return its counts."""
    import torch

    from simshear_gym.control.estimator import EstimatorConfig
    from simshear_gym.control.servo import ServoController
    from simshear_gym.real.env import RealTactileEnv
    from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator

    torch.manual_seed(config.seed)
    schedule = fault_schedule(config)
    emulator = MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                            joint_speed_deg_s=400.0, linear_speed_mm_s=1000.0)).start()
    camera = ReplayCamera(frames)
    env_config = replace(config.real_env, client=replace(
        config.real_env.client, dashboard_port=emulator.dashboard_port, motion_port=emulator.motion_port,
        feedback_port=emulator.feedback_port))
    env = RealTactileEnv(env_config, camera=camera)
    controller = ServoController(env_config.reference_depth_mm, env_config.action_scale, estimator=EstimatorConfig(
        posenet=env_config.posenet, process_std_mm=env_config.estimator_process_std_mm))
    estimator = FaultyEstimator(controller.estimator)
    controller.estimator = estimator
    injector = _Injector(emulator, camera, estimator)
    margin_mm = braking_margin_mm(env.safety, env_config.servo_time_s)
    expected = _expected_reset_errors()
    tally = _Tally()
    fault: _Fault | None = None
    ended: list[_Fault] = []  # faults over, within their grace cycles, whose outcome is open
    next_fault = 0  # index into the schedule
    cycle, episode_cycle, observation, commanded = 0, 0, None, np.array(START_POSE_MM_DEG)
    needs_reset, last_termination, refused_in_a_row = True, "", 0
    started = time.monotonic()
    try:
        while cycle < config.cycles:
            if needs_reset:
                if fault is not None:  # a fault does not outlive the episode it stopped
                    injector.end()
                    ended.append(fault)
                    fault = None
                _wait_for_clean_feedback(emulator)  # the operator waits for the robot to be readable again
                try:
                    if last_termination == "robot_error" or emulator.alarms:
                        env.client.clear_error()  # the operator's part: clear the cause, ClearError, Continue
                        env.client.continue_()
                    observation, reset_info = env.reset()
                    commanded = np.asarray(reset_info["flange_target_mm_deg"], dtype=np.float64)
                except expected as error:
                    tally.reset_refusals[type(error).__name__] += 1
                    refused_in_a_row += 1
                    if refused_in_a_row >= config.max_reset_attempts:
                        tally.unhandled.append(f"reset refused {refused_in_a_row} times in a row: {error}")
                        break
                    time.sleep(0.05)
                    continue
                controller.reset()
                if last_termination:
                    tally.recoveries += 1
                needs_reset, last_termination, refused_in_a_row, episode_cycle = False, "", 0, 0
            if fault is None and next_fault < len(schedule) and cycle >= schedule[next_fault].start_cycle:
                scheduled = schedule[next_fault]
                next_fault += 1
                tally.injected[scheduled.kind] += 1
                fault = _Fault(scheduled.kind, cycle, cycle + scheduled.cycles)
                injector.start(scheduled)
            try:
                try:
                    action = controller(observation)
                except (ValueError, FloatingPointError) as error:  # as simshear rollout: a safe stop, nothing sent
                    observation, _, terminated, _, info = env.end_episode(
                        "controller_error", f"the controller could not compute an action, nothing sent: {error}")
                else:
                    action = keep_in_box(action, commanded, env.safety, env.action_scale, env.config.mount,
                                         margin_mm)
                    observation, _, terminated, _, info = env.step(action)
                    commanded = np.asarray(info["flange_target_mm_deg"], dtype=np.float64)
            except Exception as error:  # noqa: BLE001 - the soak counts what the env failed to handle
                tally.unhandled.append(f"cycle {cycle}: {type(error).__name__}: {error}")
                terminated, info = True, {"termination": "unhandled"}
            cycle += 1
            episode_cycle += 1
            if terminated:
                termination = info["termination"]
                tally.stops[termination] += 1
                tally.stop_examples.setdefault(termination, str(info.get("safety_event", ""))[:300])
                candidates = ([fault] if fault is not None else []) + ended[::-1]
                culprit = next((f for f in candidates if not f.stopped and termination in FAULT_STOPS[f.kind]), None)
                if culprit is not None:
                    culprit.stopped = termination
                else:
                    tally.unprovoked_stops[termination] += 1
                    if fault is not None:
                        tally.cut_short += 1
                needs_reset, last_termination = True, termination
            elif episode_cycle >= config.episode_cycles and fault is None:
                tally.truncations += 1
                needs_reset = True
            if fault is not None and (cycle >= fault.end_cycle or fault.stopped):
                injector.end()
                ended.append(fault)
                fault = None
            while ended and (ended[0].stopped or cycle - ended[0].end_cycle > GRACE_CYCLES):
                tally.outcome(ended.pop(0))
        if fault is not None:
            ended.append(fault)
        for leftover in ended:
            tally.outcome(leftover)
    finally:
        env.close()
        emulator.stop()
    wall_s = time.monotonic() - started
    from simshear_gym.evaluate.safety_bursts import audit_motions

    records = emulator.motion_records()
    outside, examples = audit(records, env.safety)
    executed = audit_motions(emulator.executed_motions(), env.safety.config)
    outcomes = {kind: dict(tally.outcomes.get(kind, Counter())) for kind in FAULT_KINDS}
    accounted = sum(sum(counts.values()) for counts in outcomes.values())
    return {
        "cycles": cycle,
        "wall_s": round(wall_s, 1),
        "cycles_per_s": round(cycle / wall_s, 1) if wall_s > 0 else None,
        "faults_injected": {kind: int(tally.injected[kind]) for kind in FAULT_KINDS},
        "faults_total": int(sum(tally.injected.values())),
        "fault_outcomes": outcomes,
        "faults_unaccounted": int(sum(tally.injected.values())) - accounted,
        "safe_stops": dict(sorted(tally.stops.items())),
        "safe_stops_total": int(sum(tally.stops.values())),
        "stops_without_a_fault": dict(sorted(tally.unprovoked_stops.items())),
        "stops_without_a_fault_share": (round(sum(tally.unprovoked_stops.values()) / sum(tally.stops.values()), 4)
                                        if tally.stops else 0.0),
        "faults_cut_short": tally.cut_short,
        "stop_examples": dict(sorted(tally.stop_examples.items())),
        "recoveries": tally.recoveries,
        "reset_refusals": dict(sorted(tally.reset_refusals.items())),
        "episodes_truncated": tally.truncations,
        "motion_commands_sent": len(records),
        "servo_commands_sent": sum(1 for r in records if r.servo),
        "commands_outside_limits": outside,
        "commands_outside_limits_examples": examples,
        "motions_executed": executed["motions_executed"],
        "motions_faster_than_the_limit": executed["motions_faster_than_the_limit"],
        "motions_faster_examples": executed["motions_faster_examples"],
        "motions_accelerating_faster_than_the_limit": executed["motions_accelerating_faster_than_the_limit"],
        "motions_accelerating_faster_examples": executed["motions_accelerating_faster_examples"],
        "fault_schedule": [[f.kind, f.start_cycle, f.cycles, dict(f.params)] for f in schedule],
        "unhandled_exceptions": len(tally.unhandled),
        "unhandled_examples": tally.unhandled[:10],
        "config": config.to_dict(),
    }


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear evaluate soak``."""
    parser.add_argument("--cycles", type=int, default=SoakConfig.cycles,
                        help="control cycles to run (default %(default)d)")
    parser.add_argument("--seed", type=int, default=SoakConfig.seed,
                        help="seed of every random choice (default %(default)d)")
    parser.add_argument("--period-s", type=float, default=CONTROL_PERIOD_S,
                        help="control period, s (default %(default)g)")
    parser.add_argument("--mean-gap", type=float, default=SoakConfig.mean_gap_cycles,
                        help="mean cycles between one fault's end and the next (default %(default)g)")
    parser.add_argument("--data", default=None,
                        help="data root holding tactip331_raw/ (the replayed frames; default SIMSHEAR_DATA or "
                             "../shared/data)")
    parser.add_argument("--synthetic-frames", action="store_true",
                        help="replay synthetic camera-like frames instead of tactip331_raw (no data needed)")
    parser.add_argument("--posenet", default=None, help="GDNN weights (default: the shipped surface GDNN)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results directory for soak.json and soak.png (default results)")


def _figure(result: dict[str, Any], path: Path) -> None:
    """Each fault kind's outcomes (safe stop, ridden through) and the stops without a fault, as bars."""
    plt = pyplot()

    kinds = list(FAULT_KINDS)
    stops = [result["fault_outcomes"][kind].get("safe_stop", 0) for kind in kinds]
    recovered = [result["fault_outcomes"][kind].get("recovered", 0) for kind in kinds]
    unprovoked = sum(result["stops_without_a_fault"].values())
    fig, ax = plt.subplots(figsize=(9.5, 3.8))
    positions = np.arange(len(kinds) + 1)
    ax.bar(positions[:-1], stops, color="tab:orange", label="safe stop")
    ax.bar(positions[:-1], recovered, bottom=stops, color="tab:green", label="ridden through")
    ax.bar(positions[-1], unprovoked, color="tab:red", label="stop without a fault")
    ax.set_xticks(positions, [kind.replace("_", " ") for kind in kinds] + ["no fault"], rotation=35, ha="right",
                  fontsize=8)
    ax.set_ylabel("count")
    ax.set_title(f"Fault soak: {result['cycles']} cycles, {result['faults_total']} faults; motions faster than the "
                 f"limits {result['motions_faster_than_the_limit']}, commands outside "
                 f"{result['commands_outside_limits']}", fontsize=9)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    """Run the soak, write ``soak.json`` and ``soak.png``; 0 when nothing went outside the limits and nothing was
    unhandled."""
    import logging

    import torch

    from simshear_gym.data.paths import data_root
    from simshear_gym.evaluate.real_cycle import load_raw_frames

    torch.set_num_threads(args.threads)
    logging.getLogger("simshear_gym.real").setLevel(logging.CRITICAL)  # thousands of expected stops: counted instead
    config = SoakConfig(cycles=args.cycles, seed=args.seed, mean_gap_cycles=args.mean_gap,
                        real_env=replace(soak_env(), control_period_s=args.period_s, posenet=args.posenet))
    frames = synthetic_frames(seed=args.seed) if args.synthetic_frames else load_raw_frames(data_root(args.data))
    result = run_soak(config, frames)
    payload = {"frames": ("synthetic camera-like frames" if args.synthetic_frames
                          else f"{len(frames)} raw 640x480 frames of tactip331_raw, replayed in a loop"),
               **result}
    _figure(result, args.out / "soak.png")
    path = write_record("simshear evaluate soak", add_arguments, args, args.out / "soak.json", payload)
    unprovoked = sum(result["stops_without_a_fault"].values())
    print(f"{result['cycles']} cycles in {result['wall_s']} s; {result['faults_total']} faults injected, "
          f"{result['safe_stops_total']} safe stops ({unprovoked} without a fault), {result['recoveries']} "
          f"recoveries; commands outside the limits {result['commands_outside_limits']}, motions faster than the "
          f"limits {result['motions_faster_than_the_limit']}, unhandled {result['unhandled_exceptions']}, faults "
          f"unaccounted {result['faults_unaccounted']}")
    print(f"wrote {path} and {args.out / 'soak.png'}")
    clean = (result["commands_outside_limits"] == 0 and result["unhandled_exceptions"] == 0
             and result["motions_faster_than_the_limit"] == 0)
    return 0 if clean and result["faults_unaccounted"] == 0 else 1
