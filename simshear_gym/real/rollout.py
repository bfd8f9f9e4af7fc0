"""``simshear rollout``: run the servo controller or a trained SB3 policy on the real (or emulated) MG400.

::

    simshear rollout --robot 192.168.1.6 --camera 0 --controller servo --steps 300 --out runs/rollout/surface
    simshear rollout --robot 127.0.0.1 --camera sim-surface --policy runs/rl/ppo/model.zip --dry-run
    simshear rollout --robot 127.0.0.1 --camera sim-push --task push --steps 300

Controllers: ``--controller servo`` (:class:`~simshear_gym.control.servo.ServoController`: GDNN + Bayesian filter +
PI law, ``--posenet`` weights, default the shipped ``surface`` GDNN), ``--controller edge``
(:class:`~simshear_gym.control.edge_servo.EdgeServoController`: edge following at ``--edge-speed-mm-s``, default
the shipped ``edge`` GDNN), ``--controller push`` (:class:`~simshear_gym.control.push_servo.PushServoController`:
pushing to ``--push-target-mm`` at ``--push-speed-mm-s`` with the horizontal TacTip, the shipped ``surface`` GDNN)
(``--task tracking|edge-follow|push`` picks the same three by task, and checks a ``--controller`` or ``--policy``
against it) or ``--policy MODEL.zip`` (or ``--controller
MODEL.zip``): a Stable-Baselines3 PPO / SAC agent of ``simshear train rl``, loaded with its run folder's
``config.json`` and ``VecNormalize`` statistics (:meth:`~simshear_gym.control.policy.SB3Controller.load`): the
env gives it the observation it was trained on (observation, history, image size; an estimate observation reads
the images with ``--posenet`` / ``--sensor``'s GDNN, default the shipped ``surface`` one, relative to
``--reference-depth-mm``), its observations are normalised as in training and a residual policy's correction is
added to the servo law; a policy of the edge or push task reads its images with that task's estimator (as in
its env), and a pushing policy gets the env's ``goal`` from the measured pose and ``--push-target-mm``
(:class:`~simshear_gym.control.push_servo.PushGoalObservation`). A bare ``.zip`` (no ``config.json``) gets the
``tactile`` observation at ``--image-size``.

Camera (``--camera``): a device index, a video file or an image folder (:class:`~simshear_gym.real.camera.
CameraSource`, preprocessed with ``--preprocess``), or ``sim-surface``: the hardware-in-the-loop camera
(:class:`~simshear_gym.real.hil.SimSurfaceCamera`) rendering the simulated TacTip at the pose the robot's feedback
reports, on a surface moving at ``--surface-velocity`` (use it with ``simshear mg400-emulator``), or ``sim-edge``:
the same over the edge of a still flat object (``--outline``; :class:`~simshear_gym.real.hil_edge.SimEdgeCamera`),
the rehearsal of edge following, or ``sim-push``: the horizontal TacTip against an object it pushes (``--shape``;
:class:`~simshear_gym.real.hil_push.SimPushCamera`), the rehearsal of pushing.

Output in ``--out``: ``steps.csv`` (one row per step: time, measured and commanded TCP and flange poses, action,
the controller's state estimate, timing, robot mode, safety events; with ``sim-surface`` also the simulated ground
truth), ``rollout.json`` (the command, the env's config, how the run ended, timing summary) and
``trajectory.png``. Exit status 0 when every step ran, 1 when a safety condition ended the run early.
"""

from __future__ import annotations

import argparse
import csv
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.contract import ESTIMATE_OBSERVATIONS, HorizontalTacTipMount
from simshear_gym.control.policy import (  # sb3_algorithm is also re-exported for this module's callers
    Controller,
    EstimatingController,
    PolicySettings,
    SB3Controller,
    sb3_algorithm,
)
from simshear_gym.control.policy_files import has_policy_files
from simshear_gym.io import atomic_write, write_json
from simshear_gym.models.zoo import load_sensor

logger = logging.getLogger(__name__)

SIM_SURFACE_CAMERA = "sim-surface"
SIM_EDGE_CAMERA = "sim-edge"
SIM_PUSH_CAMERA = "sim-push"
SIM_CAMERAS = (SIM_SURFACE_CAMERA, SIM_EDGE_CAMERA, SIM_PUSH_CAMERA)
PUSH_START_POSE_MM_DEG = (340.0, -190.0, 0.0, 90.0)
"""``--controller push``'s default flange start: the horizontal TacTip 60 mm below it pushing along the base's +y,
as ``SimShearPush-v0``'s follower starts."""
PUSH_REFERENCE_DEPTH_MM = 2.6
"""The push law's ``--reference-depth-mm`` default (``SimShearPush-v0``'s: the first touch's depth, labels' z)."""
LAWS = ("servo", "edge", "push")
"""The controllers ``--controller`` names: the servo law (tracking), edge following and pushing."""
TASK_LAWS = {"tracking": "servo", "edge-follow": "edge", "push": "push"}
"""``--task`` -> the law it runs (its ``--controller`` default)."""
POLICY_TASK_LAWS = {"tracking": "servo", "colift": "servo", "edge": "edge", "push": "push"}
"""A policy's task (``simshear train rl --task``) -> the law whose estimator makes its estimate observation."""
STATE_NAMES = ("depth_mm", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
"""The state estimate's columns, unless the controller names its own (``state_names``)."""
POSE_NAMES = ("x_mm", "y_mm", "z_mm", "r_deg")


# ----------------------------------------------------------------------------------------------------------------
# The rollout loop and its log


def log_vector(value, size: int = 4) -> list[float]:
    """A log's ``size`` numbers of ``value`` (flattened), NaN for each when it is None."""
    if value is None:
        return [float("nan")] * size
    return [float(v) for v in np.asarray(value, dtype=np.float64).reshape(-1)[:size]]


def _columns(with_estimate: bool, with_truth: bool, state_names: tuple[str, ...] = STATE_NAMES) -> list[str]:
    columns = ["step", "time_s"]
    columns += [f"tcp_{n}" for n in POSE_NAMES] + [f"tcp_target_{n}" for n in POSE_NAMES]
    columns += [f"flange_{n}" for n in POSE_NAMES] + [f"flange_target_{n}" for n in POSE_NAMES]
    columns += [f"action_{i}" for i in range(4)]
    if with_estimate:
        columns += [f"estimate_{n}" for n in state_names] + [f"estimate_std_{n}" for n in state_names]
    columns += ["policy_ms", "overrun_s", "robot_mode", "feedback_age_s", "camera_frame_age_s", "in_contact",
                "commands_sent", "termination", "safety_event"]
    if with_truth:
        columns += ["truth_contact_error_mm", "truth_penetration_mm", "truth_in_contact"]
    return columns


def _row(step: int, observation: dict, info: dict, action, estimate, policy_ms: float, truth,
         state_names: tuple[str, ...] = STATE_NAMES) -> dict[str, Any]:
    row: dict[str, Any] = {"step": step, "time_s": round(float(info["time_s"]), 4)}
    tcp = observation["tcp_pose"] if "tcp_pose" in observation else info.get("tcp_pose")  # estimate observations
    for prefix, value in (("tcp", tcp), ("tcp_target", info["tcp_target"]),
                          ("flange", info["flange_pose_mm_deg"]), ("flange_target", info["flange_target_mm_deg"])):
        for name, number in zip(POSE_NAMES, log_vector(value)):
            row[f"{prefix}_{name}"] = round(number, 6)  # the precision of the commands sent
    for index, number in enumerate(log_vector(action)):
        row[f"action_{index}"] = round(number, 5)
    if estimate is not None:
        for name, mean, std in zip(state_names, log_vector(estimate[0]), log_vector(estimate[1])):
            row[f"estimate_{name}"] = round(mean, 4)
            row[f"estimate_std_{name}"] = round(std, 4)
    row.update(policy_ms=round(policy_ms, 3), overrun_s=round(float(info["overrun_s"]), 4),
               robot_mode=info["robot_mode"], feedback_age_s=info["feedback_age_s"],
               camera_frame_age_s=info["camera_frame_age_s"], in_contact=info["in_contact"],
               commands_sent=info["commands_sent"], termination=info["termination"],
               safety_event=info.get("safety_event", ""))
    if truth is not None:
        row.update(truth_contact_error_mm=round(truth.contact_error_mm, 4),
                   truth_penetration_mm=round(truth.penetration_mm, 4), truth_in_contact=truth.in_contact)
    return row


def run_rollout(env, controller: Controller, steps: int, out_dir: str | Path, command: str = "") -> dict[str, Any]:
    """Reset ``env`` (a :class:`~simshear_gym.real.env.RealTactileEnv`), run ``controller`` for up to ``steps``
    steps and write ``steps.csv``, ``rollout.json`` and ``trajectory.png`` in ``out_dir``; returns the summary.

    The log carries the controller's state estimate when it keeps one
    (:class:`~simshear_gym.control.policy.EstimatingController`), and names it by its ``name`` (its class name
    without one)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = getattr(controller, "name", type(controller).__name__)
    base = env.unwrapped  # env may be wrapped (a pushing policy's goal): the real env's own parts from it
    observation, info = env.reset()
    controller.reset()
    truth_source = getattr(base.camera, "history", None)
    with_estimate = isinstance(controller, EstimatingController)
    names = tuple(getattr(controller, "state_names", STATE_NAMES))
    rows = [_row(0, observation, info, np.zeros(4), None, 0.0, truth_source[-1] if truth_source else None, names)]
    termination, policy_ms = "", []
    for step in range(1, steps + 1):
        start = time.perf_counter()
        try:
            action = controller(observation)
        except (ValueError, FloatingPointError) as error:  # e.g. a NaN estimate the servo law refuses: a safe stop
            action = None
            policy_ms.append(1000.0 * (time.perf_counter() - start))
            observation, _, terminated, truncated, info = base.end_episode(
                "controller_error", f"the controller could not compute an action, nothing sent: {error}")
        else:
            policy_ms.append(1000.0 * (time.perf_counter() - start))
            observation, _, terminated, truncated, info = env.step(action)
        truth = truth_source[-1] if truth_source else None
        estimate = controller.last_estimate if with_estimate else None
        rows.append(_row(step, observation, info, action, estimate, policy_ms[-1], truth, names))
        if terminated or truncated:
            termination = info["termination"]
            break
    events = list(base.safety_events)
    columns = _columns(with_estimate, truth_source is not None, names)
    write_log_csv(out_dir / "steps.csv", columns, rows)
    figure = plot_trajectory(rows, out_dir / "trajectory.png", title=f"{name}: {termination or 'completed'}")
    overruns = np.array([row["overrun_s"] for row in rows[1:]]) if len(rows) > 1 else np.zeros(0)
    summary: dict[str, Any] = {
        "command": command,
        "controller": name,
        "steps_requested": steps,
        "steps_run": len(rows) - 1,
        "termination": termination,
        "safety_events": events,
        "commands_sent": base.commands_sent,
        "dry_run": base.config.dry_run,
        "policy_ms_median": round(float(np.median(policy_ms)), 3) if policy_ms else None,
        "policy_ms_p95": round(float(np.percentile(policy_ms, 95)), 3) if policy_ms else None,
        "period_overruns": int(np.sum(overruns > 0.0)),
        "max_overrun_s": round(float(overruns.max()), 4) if overruns.size else 0.0,
        "config": base.config.to_dict(),
        "files": {"steps": "steps.csv", "figure": figure.name},
    }
    truth = [row["truth_contact_error_mm"] for row in rows if "truth_contact_error_mm" in row]
    if truth:
        summary["truth_contact_error_mm"] = {"mean": round(float(np.mean(truth)), 4),
                                             "max": round(float(np.max(truth)), 4),
                                             "final": round(float(truth[-1]), 4)}
    progress = getattr(base.camera, "progress_mm", None)
    if progress is not None:  # a simulated edge: how far along it the run went
        summary["truth_progress_mm"] = round(float(progress), 3)
    distance = getattr(base.camera, "target_distance_mm", lambda: None)()
    if distance is not None:  # a simulated push: how far from its target the object ended
        summary["truth_target_distance_mm"] = round(float(distance), 3)
    write_json(out_dir / "rollout.json", summary)
    return summary


def write_log_csv(path: Path, columns: list[str], rows: list[dict]) -> None:
    """``rows`` as a CSV of ``columns`` (None written empty), atomically."""

    def write(tmp: str) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            for row in rows:
                writer.writerow({key: ("" if row.get(key) is None else row.get(key)) for key in columns})

    atomic_write(path, write)


def plot_trajectory(rows: list[dict], path: Path, title: str = "") -> Path:
    """Top view of the TCP path (measured and commanded), the TCP against time and the state estimate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def column(name: str) -> np.ndarray:
        return np.array([float("nan") if row.get(name) is None else row[name] for row in rows], dtype=float)

    time_s = column("time_s")
    has_estimate = any("estimate_depth_mm" in row for row in rows)
    has_truth = "truth_contact_error_mm" in rows[0]
    panels = 2 + int(has_estimate or has_truth)
    figure, axes = plt.subplots(1, panels, figsize=(5.0 * panels, 4.2))
    axes[0].plot(column("tcp_x_mm"), column("tcp_y_mm"), label="measured")
    axes[0].plot(column("tcp_target_x_mm"), column("tcp_target_y_mm"), "--", label="commanded")
    axes[0].plot(column("tcp_x_mm")[:1], column("tcp_y_mm")[:1], "ko", label="start")
    axes[0].set(xlabel="x (mm, base)", ylabel="y (mm, base)", title="TCP path, top view")
    axes[0].axis("equal")
    axes[0].legend(fontsize=8)
    for name, colour in (("x", "C0"), ("y", "C1"), ("z", "C2")):
        values = column(f"tcp_{name}_mm")
        axes[1].plot(time_s, values - values[0], colour, label=f"{name} measured")
        target = column(f"tcp_target_{name}_mm")
        axes[1].plot(time_s, target - values[0], colour, linestyle="--", linewidth=0.8)
    axes[1].set(xlabel="time (s)", ylabel="TCP - start (mm)", title="TCP (dashed: commanded)")
    axes[1].legend(fontsize=8)
    if panels == 3:
        if has_estimate:
            for name, colour in (("shear_x_mm", "C0"), ("shear_y_mm", "C1")):
                axes[2].plot(time_s, column(f"estimate_{name}"), colour, label=f"est. {name}")
            axes[2].plot(time_s, column("estimate_depth_mm") - np.nanmedian(column("estimate_depth_mm")), "C2",
                         label="est. depth - median")
        if has_truth:
            axes[2].plot(time_s, column("truth_contact_error_mm"), "k", label="true contact error")
        axes[2].set(xlabel="time (s)", ylabel="mm", title="state estimate / ground truth")
        axes[2].legend(fontsize=8)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    atomic_write(path, lambda tmp: figure.savefig(tmp, dpi=90, format="png"), suffix=".png")
    plt.close(figure)
    return path


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear rollout``."""
    from simshear_gym.robots.mg400.protocol import (
        DASHBOARD_PORT,
        FEEDBACK_PORT,
        MOTION_PORT,
    )

    parser.add_argument("--robot", required=True, metavar="IP", help="MG400 controller address")
    parser.add_argument("--camera", required=True, metavar="SRC",
                        help=f"camera device index, video file, image folder, '{SIM_SURFACE_CAMERA}' (simulated "
                             f"TacTip on a moving surface at the robot's reported pose), '{SIM_EDGE_CAMERA}' (the "
                             f"same over a still object's edge: the edge following rehearsal) or '{SIM_PUSH_CAMERA}' "
                             "(a horizontal TacTip against an object it pushes: the pushing rehearsal)")
    parser.add_argument("--controller", default=None, metavar="servo|edge|push|MODEL.zip",
                        help="'servo' (GDNN + filter + PI law), 'edge' (edge following: the edge GDNN + filter + the "
                             "edge law), 'push' (pushing to --push-target-mm with a horizontal TacTip: the surface "
                             "GDNN + filter + the push law) or a Stable-Baselines3 PPO/SAC/TQC .zip (as --policy)")
    parser.add_argument("--task", default=None, choices=tuple(TASK_LAWS),
                        help="tracking (the servo law), edge-follow (the edge law) or push (the push law, a "
                             "horizontal TacTip): its controller when neither --controller nor --policy is given, "
                             "else a check that they are of this task")
    parser.add_argument("--policy", default=None, metavar="MODEL.zip",
                        help="a PPO/SAC/TQC agent of simshear train rl (model.zip, best_model.zip or a checkpoint), "
                             "with its run's settings and VecNormalize statistics; instead of --controller")
    parser.add_argument("--steps", type=int, default=200, help="control steps to run (default 200)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default runs/rollout/<date-time>)")
    parser.add_argument("--dry-run", action="store_true", help="check and log motion commands, send none")
    parser.add_argument("--period-s", type=float, default=0.1, help="control period, s (default 0.1)")
    parser.add_argument("--image-size", type=int, default=None, choices=(64, 128),
                        help="tactile observation size (default: the policy's, from its run's config.json, else 128)")
    parser.add_argument("--start-pose", type=float, nargs=4, default=None, metavar=("X", "Y", "Z", "R"),
                        help="flange start pose, mm and deg (default 300 0 0 0; --controller push: "
                             f"{' '.join(f'{v:g}' for v in PUSH_START_POSE_MM_DEG)})")
    parser.add_argument("--max-step-mm", type=float, default=5.0,
                        help="safety: largest translation per command, mm (default 5, the safe default and most)")
    parser.add_argument("--max-step-deg", type=float, default=5.0,
                        help="safety: largest rotation per command, deg (default 5, the safe default and most)")
    parser.add_argument("--unsafe-limits", action="store_true",
                        help="allow --max-step-mm / --max-step-deg looser than the safe defaults (logged as UNSAFE)")
    parser.add_argument("--posenet", default=None, help="GDNN weights for the servo controller (default: shipped)")
    parser.add_argument("--sensor", default=None,
                        help="a sensor's own GDNN for the servo controller: its configs/<name>.toml, the folder of its "
                             "`simshear pipeline run` or that run's sensor.json (instead of --posenet)")
    parser.add_argument("--reference-depth-mm", type=float, default=None,
                        help="depth the controller holds (pushing: the first touch's), labels' convention (default "
                             f"4.0; {PUSH_REFERENCE_DEPTH_MM} with the push law)")
    parser.add_argument("--min-depth-mm", type=float, default=None,
                        help="stop when the GDNN's depth reading falls below this (lost contact); default off")
    parser.add_argument("--preprocess", default="shipped",
                        help="preprocessing JSON, 'shipped' (default), or 'none' when frames are tactile images")
    parser.add_argument("--dashboard-port", type=int, default=DASHBOARD_PORT,
                        help=f"MG400 dashboard TCP port: enable, mode, errors (default {DASHBOARD_PORT})")
    parser.add_argument("--motion-port", type=int, default=MOTION_PORT,
                        help=f"MG400 motion TCP port: MovJ, ServoP (default {MOTION_PORT})")
    parser.add_argument("--feedback-port", type=int, default=FEEDBACK_PORT,
                        help=f"MG400 feedback TCP port: the pose and mode stream (default {FEEDBACK_PORT})")
    parser.add_argument("--surface-velocity", type=float, nargs=3, default=(2.0, 0.0, 0.0), metavar=("VX", "VY", "VZ"),
                        help=f"{SIM_SURFACE_CAMERA} camera: surface velocity in the base frame, mm/s")
    parser.add_argument("--surface-travel-mm", type=float, default=20.0,
                        help=f"{SIM_SURFACE_CAMERA} camera: the surface stops after this travel, mm")
    parser.add_argument("--outline", default="disk",
                        help=f"{SIM_EDGE_CAMERA} camera: the object's outline (disk, rounded_square, clover, wavy)")
    parser.add_argument("--edge-speed-mm-s", type=float, default=5.0,
                        help="edge controller: speed along the edge, mm/s (default 5, as SimShearEdgeFollow-v0)")
    parser.add_argument("--shape", default="cube",
                        help=f"{SIM_PUSH_CAMERA} camera: the pushed object (cube, cylinder, prism)")
    parser.add_argument("--push-target-mm", type=float, nargs=2, default=None, metavar=("X", "Y"),
                        help="push controller: the target, base frame mm (default 150 mm ahead of the object along "
                             "the sensor's axis at the start)")
    parser.add_argument("--push-speed-mm-s", type=float, default=5.0,
                        help="push controller: pushing speed, mm/s (default 5, as SimShearPush-v0)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def _controller_name(args: argparse.Namespace) -> str | None:
    """``--controller``, or ``--task``'s law when neither ``--controller`` nor ``--policy`` is given."""
    if args.controller is None and args.policy is None and args.task is not None:
        return TASK_LAWS[args.task]
    return args.controller


def _policy_path(args: argparse.Namespace, controller: str | None) -> str | None:
    """The SB3 model of ``--policy`` or ``--controller MODEL.zip`` (None for a law's name), checked."""
    if (args.policy is None) == (controller is None):
        raise ValueError("give --controller servo|edge|push|MODEL.zip, --policy MODEL.zip or --task (one of them)")
    if args.policy is not None:
        if not Path(args.policy).is_file() and not has_policy_files(args.policy):
            raise FileNotFoundError(f"--policy {args.policy!r}: no such SB3 .zip file")
        return args.policy
    if controller in LAWS:
        return None
    if not Path(controller).is_file() and not has_policy_files(controller):
        raise FileNotFoundError(f"--controller {controller!r} is neither one of {LAWS} nor an existing SB3 .zip "
                                "file")
    return controller


def _law(controller: str | None, settings: PolicySettings | None, task: str | None) -> str:
    """The law the run is of (:data:`LAWS`): the controller's, or the task a policy was trained on; checked against
    ``--task``."""
    if controller in LAWS:
        law, source = controller, f"--controller {controller}"
    else:
        law = POLICY_TASK_LAWS.get(settings.task, "servo") if settings is not None else "servo"
        source = f"a policy trained on {settings.task}" if settings is not None else "a bare SB3 model (tracking)"
    if task is not None and TASK_LAWS[task] != law:
        raise ValueError(f"--task {task} runs the {TASK_LAWS[task]} law; got {source} (the {law} law)")
    return law


def _load_sb3(path: str, env, flag: str = "--controller") -> SB3Controller:
    """An SB3 model as the env's controller, with errors that name the flags."""
    sb3_algorithm(path)  # not an SB3 model: that error as it is
    try:
        return SB3Controller.for_env(path, env)
    except ValueError as error:  # trained on other spaces
        raise ValueError(f"{flag} {error}; check --image-size") from None


def _sim_camera(args: argparse.Namespace, config, flange_pose):
    """The hardware-in-the-loop camera of ``--camera sim-surface|sim-edge|sim-push`` at the env's start pose and
    mount."""
    if args.camera == SIM_PUSH_CAMERA:
        from simshear_gym.real.hil_push import PushObjectConfig, SimPushCamera

        camera_type, scene = SimPushCamera, PushObjectConfig(shape=args.shape, target_xy_mm=_push_target(args, config),
                                                             reference_depth_mm=config.reference_depth_mm)
    elif args.camera == SIM_EDGE_CAMERA:
        from simshear_gym.real.hil_edge import EdgeObjectConfig, SimEdgeCamera

        camera_type, scene = SimEdgeCamera, EdgeObjectConfig(outline=args.outline,
                                                             reference_depth_mm=config.reference_depth_mm)
    else:
        from simshear_gym.real.hil import MovingSurfaceConfig, SimSurfaceCamera

        camera_type, scene = SimSurfaceCamera, MovingSurfaceConfig(
            velocity_mm_s=tuple(args.surface_velocity), max_travel_mm=args.surface_travel_mm,
            reference_depth_mm=config.reference_depth_mm)
    return camera_type(flange_pose, config.start_pose_mm_deg, scene, config.mount, raw_frame_layout=config.preprocess)


def _law_controller(law: str, args: argparse.Namespace, config, estimator_config):
    """The controller of ``law`` for this run (the one that runs, or whose estimator a policy's estimate
    observation uses): the servo, edge or push controller at the run's depth, speed and target."""
    if law == "edge":
        from simshear_gym.control.edge_servo import EdgeServoController

        return EdgeServoController(config.reference_depth_mm, config.action_scale,
                                   args.edge_speed_mm_s * args.period_s, estimator=estimator_config)
    if law == "push":
        from simshear_gym.control.push_servo import PushServoController, PushTarget

        return PushServoController(config.action_scale, args.push_speed_mm_s * args.period_s,
                                   estimator=estimator_config,
                                   target=PushTarget(_push_target(args, config), config.mount))
    from simshear_gym.control.servo import ServoController

    return ServoController(config.reference_depth_mm, config.action_scale, estimator=estimator_config)


def _push_target(args: argparse.Namespace, config) -> tuple[float, float]:
    """``--push-target-mm``, or 150 mm ahead of the object's centre (25 mm ahead of the apex) at the start."""
    if args.push_target_mm is not None:
        return tuple(float(v) for v in args.push_target_mm)
    from simshear_gym.contract import sensor_axes_xy
    from simshear_gym.real.env import tcp_pose_from_flange

    tcp = tcp_pose_from_flange(config.start_pose_mm_deg, config.mount)
    _, axis = sensor_axes_xy(float(tcp[3]), config.mount)
    target = tcp[:2] + (25.0 + 150.0) * axis
    return float(target[0]), float(target[1])


def run(args: argparse.Namespace) -> int:
    """Run the rollout; 0 when every step ran, 1 when a safety condition stopped it early."""
    import torch

    from simshear_gym.control.env_estimator import reading_estimator
    from simshear_gym.control.estimator import EstimatorConfig
    from simshear_gym.real.camera import preprocess_config as camera_preprocess_config
    from simshear_gym.real.env import EstimatedContact, RealEnvConfig, RealTactileEnv, env_client
    from simshear_gym.real.safety import SafetyConfig, UnsafeSafetyConfig

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    controller_name = _controller_name(args)
    policy = _policy_path(args, controller_name)
    settings = PolicySettings.of_model(policy) if policy else None
    image_size_px = args.image_size or (settings.image_size_px if settings else 128)
    if args.sensor and args.posenet:
        raise ValueError("give --sensor (a sensor's own GDNN) or --posenet (GDNN weights), not both")
    law = _law(controller_name, settings, args.task)
    edge, push = law == "edge", law == "push"
    if (args.camera == SIM_PUSH_CAMERA) != push and args.camera in SIM_CAMERAS:
        raise ValueError(f"--camera {SIM_PUSH_CAMERA} and the push law (--controller push, --task push or a pushing "
                         f"policy) go together (a horizontal TacTip pushing): got --camera {args.camera} with the "
                         f"{law} law")
    if push and args.min_depth_mm is not None:
        raise ValueError("--min-depth-mm stops on a lost surface contact; a push's depth is the object's friction: "
                         "leave --min-depth-mm out with the push law")
    if edge and args.min_depth_mm is not None:
        raise ValueError("--min-depth-mm reads the surface GDNN's depth; the edge controller has none of its own "
                         "yet: leave --min-depth-mm out with the edge law")
    reference_depth_mm = (args.reference_depth_mm if args.reference_depth_mm is not None
                          else PUSH_REFERENCE_DEPTH_MM if push else 4.0)
    posenet = load_sensor(args.sensor).posenet("edge" if edge else "surface") if args.sensor else args.posenet
    out_dir = args.out if args.out is not None else Path("runs/rollout") / time.strftime("%Y%m%d-%H%M%S")
    preprocess_config = camera_preprocess_config(args.preprocess)
    safety_type = UnsafeSafetyConfig if args.unsafe_limits else SafetyConfig
    try:
        safety = safety_type(max_step_mm=args.max_step_mm, max_step_deg=args.max_step_deg,
                             stop_on_lost_contact=args.min_depth_mm is not None)
    except ValueError as error:
        raise ValueError(f"--max-step-mm / --max-step-deg: {error} (the flag --unsafe-limits)") from None
    config = RealEnvConfig(
        client=env_client(args.robot, args.dashboard_port, args.motion_port, args.feedback_port),
        control_period_s=args.period_s, camera_source=str(args.camera),
        preprocess=preprocess_config, image_size_px=image_size_px, start_pose_mm_deg=tuple(
            args.start_pose if args.start_pose is not None else PUSH_START_POSE_MM_DEG if push else (300.0, 0.0, 0.0,
                                                                                                     0.0)),
        observation=settings.observation if settings else "tactile", history=settings.history if settings else 1,
        reference_depth_mm=reference_depth_mm, posenet=posenet, safety=safety, dry_run=args.dry_run,
        **({"mount": HorizontalTacTipMount()} if push else {}),
        # a simulated camera has no noise: equal frames in a row are no sign of a frozen driver
        frozen_frame_limit=None if args.camera in SIM_CAMERAS else RealEnvConfig.frozen_frame_limit)
    estimator_config = EstimatorConfig(posenet=posenet)
    law_controller = _law_controller(law, args, config, estimator_config)
    # a policy of the edge or push task reads its estimate observation with that law's estimator
    policy_estimator = (reading_estimator(law, law_controller)
                        if settings is not None and settings.observation in ESTIMATE_OBSERVATIONS else None)
    if args.camera not in SIM_CAMERAS:
        env = RealTactileEnv(config, estimator=policy_estimator)  # the camera is opened on the first reset
    else:  # the simulated camera renders where the arm's feedback says the flange is
        holder: list[RealTactileEnv] = []
        camera = _sim_camera(args, config, lambda: holder[0].client.measured_pose())
        env = RealTactileEnv(config, camera=camera, estimator=policy_estimator)
        holder.append(env)
    try:
        controller: Controller
        estimator = None
        if policy is None:
            controller = law_controller
            estimator = law_controller.estimator if law == "servo" else None
        else:
            if push:  # the goal the policy saw in sim, from the measured pose and the target
                from simshear_gym.control.push_servo import PushGoalObservation

                env = PushGoalObservation(env, law_controller.target)
            controller = _load_sb3(policy, env, "--policy" if args.policy else "--controller")
        if args.min_depth_mm is not None:
            if estimator is None:
                from simshear_gym.control.estimator import TactileEstimator

                estimator = TactileEstimator(estimator_config)
            env.unwrapped.contact_check = EstimatedContact(estimator, args.min_depth_mm)
        command = recorded_command("simshear rollout", add_arguments, args)
        summary = run_rollout(env, controller, args.steps, out_dir, command=command)
    finally:
        env.close()
    print(f"{summary['steps_run']}/{args.steps} steps, {summary['commands_sent']} commands sent"
          f"{' (dry run)' if args.dry_run else ''}; policy {summary['policy_ms_median']} ms median; "
          f"{'ended: ' + summary['termination'] if summary['termination'] else 'completed'}")
    for event in summary["safety_events"]:
        print(f"  safety: {event}")
    print(f"wrote {out_dir / 'steps.csv'}, {out_dir / 'rollout.json'}, {out_dir / 'trajectory.png'}")
    return 1 if summary["termination"] else 0
