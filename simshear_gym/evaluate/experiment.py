"""``simshear evaluate experiment --tasks tracking colift``: the paper's two-arm experiments, rehearsed.

**tracking**: for each of the tracking env's trajectories (``circle``, ``tilted_square``, ``spiral``, ``loop``: the
paths, speed 4 mm/s and rotations of ``SimShearTracking-v0``), one full run of ``simshear experiment tracking
--rehearsal`` (:func:`~simshear_gym.lab.experiment.run_tracking_rehearsal`) with the shipped models (the shipped
shPix2pix makes the rig camera's images, the shipped surface GDNN reads them; the servo controller) on a fresh
rehearsal rig: two loopback MG400 emulators and the rig camera, the leader's base where the sim scene has it, the
calibration exact (the rig's own layout; ``simshear calibrate-arms`` has its own test).

**colift**: for each co-lift trajectory (``circular_wave``, ``star``: ``SimShearCoLift-v0``'s paths at 5 mm/s) and
each object (``prism``, ``egg``, ``brain``, ``ducky``), one full run of ``simshear experiment colift --rehearsal``
(:func:`~simshear_gym.lab.colift.run_colift_rehearsal`: grasp, lift, carry, set down, release) on a fresh co-lift
rig (the co-lift scene's object physics between the two emulated arms; the shipped co-lift GDNN, the co-lift
servo controller). Recorded besides the tracking's figures: drops (the stop, and the rig's truth) and the object's
largest slip on the plate.

Recorded per run: the contact error as the paper measures it (the calibrated kinematics of both arms' fed-back
poses; mean, std and max over the run's tracking cycles) and the rig's true one, contact loss (cycles with the
sensor above or off the face, and whether a stop ended the run), the loop rate (tracking cycles over their
duration, one clock), the compute per cycle (the controller: GDNN, filter, law; median and p95, ms), period
overruns, late cycles, and the emulators' audit (commands outside the safe limits in their own records). Every run's
log, figure and record go to ``--runs`` (default ``runs/experiment_<task>``); ``results/experiment_<task>.json``
(with the command) and ``results/experiment_<task>.png`` (the paper's figure: leader red, follower blue, error mean
+- std per run).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.io import write_json
from simshear_gym.machine import machine_info

TASKS = ("tracking", "colift")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.envs.trajectories import COLIFT_TRAJECTORIES, TRAJECTORIES
    from simshear_gym.lab.colift import OBJECT_NAMES

    parser.add_argument("--tasks", nargs="+", default=["tracking"], choices=TASKS,
                        help="which experiments (default tracking)")
    parser.add_argument("--trajectories", nargs="+", default=list(TRAJECTORIES), choices=TRAJECTORIES,
                        help="tracking: the leader's paths (default all four)")
    parser.add_argument("--speed-mm-s", type=float, default=4.0, help="tracking: the leader's speed (default 4)")
    parser.add_argument("--colift-trajectories", nargs="+", default=list(COLIFT_TRAJECTORIES),
                        choices=COLIFT_TRAJECTORIES, help="colift: the leader's paths (default both)")
    parser.add_argument("--objects", nargs="+", default=list(OBJECT_NAMES), choices=OBJECT_NAMES,
                        help="colift: the objects carried (default all four)")
    parser.add_argument("--colift-speed-mm-s", type=float, default=5.0,
                        help="colift: the leader's speed (default 5, the co-lift env's)")
    parser.add_argument("--max-feedback-age-s", type=float, default=1.0,
                        help="the rehearsal's feedback and camera-frame age limit, s (default 1.0: the emulators, "
                             "the render and the networks share the process)")
    parser.add_argument("--runs", type=Path, default=None,
                        help="each run's log, figure and record go under here (default runs/experiment_<task>)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="where the records and figures go")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


KEYS = ("completed", "stop", "stop_reason", "trajectory_duration_s", "tracking_cycles", "contact_error_mean_mm",
        "contact_error_std_mm", "contact_error_max_mm", "truth_contact_error_mean_mm", "truth_contact_error_std_mm",
        "truth_contact_error_max_mm", "cycles_out_of_contact", "truth_cycles_out_of_contact", "contact_lost",
        "loop_rate_hz", "compute_ms_median", "compute_ms_p95", "period_overruns", "late_cycles", "plan_behind_s",
        "commands_outside_limits", "wall_s")
COLIFT_KEYS = ("dropped", "truth_dropped", "truth_object_slip_max_mm")


def plot(runs: dict, path: Path, title: str = "two-arm tracking, rehearsed", columns: int = 4) -> Path:
    import csv

    from simshear_gym.lab.experiment import draw_run

    plt = pyplot()
    columns = min(columns, len(runs))
    lines = -(-len(runs) // columns)
    figure = plt.figure(figsize=(4.2 * columns, 4.4 * lines))
    for index, (name, run) in enumerate(runs.items()):
        with open(Path(run["run_dir"]) / "log.csv") as handle:
            rows = [{key: (value if key in ("phase", "colift_phase") else float(value)
                           if value not in ("", "True", "False") else value)
                     for key, value in row.items()} for row in csv.DictReader(handle)]
        mean, std = run["contact_error_mean_mm"], run["contact_error_std_mm"]
        label = f"{name}: {mean:.2f} +- {std:.2f} mm" if mean is not None else f"{name}: no tracking"
        if run.get("dropped"):
            label += " (dropped)"
        draw_run(figure.add_subplot(lines, columns, index + 1, projection="3d"), rows, label)
    figure.suptitle(f"{title} (leader's contact point red, follower's sensor blue; follower's base frame, mm)",
                    fontsize=10)
    save_figure(figure, path, dpi=90)
    return path


def _tracking(args: argparse.Namespace, command: str) -> dict:
    from simshear_gym.lab.experiment import ExperimentConfig, rehearsal_safety, run_tracking_rehearsal

    runs_dir = args.runs if args.runs is not None else Path("runs/experiment_tracking")
    runs: dict[str, dict] = {}
    for name in args.trajectories:
        run_dir = runs_dir / name
        config = ExperimentConfig(trajectory=name, speed_mm_s=args.speed_mm_s).with_env(
            safety=rehearsal_safety(args.max_feedback_age_s, args.max_feedback_age_s))
        summary = run_tracking_rehearsal(config, run_dir, command=f"{command}  # run {name}")
        runs[name] = {"run_dir": str(run_dir), **{key: summary.get(key) for key in KEYS}}
        print(f"{name}: contact error {summary['contact_error_mean_mm']} +- {summary['contact_error_std_mm']} mm "
              f"(truth {summary['truth_contact_error_mean_mm']}), {summary['cycles_out_of_contact']} cycles out of "
              f"contact, {summary['loop_rate_hz']} Hz, compute {summary['compute_ms_median']} ms; "
              f"{'completed' if summary['completed'] else 'stopped: ' + summary['stop']}")
    return {
        "runs": runs,
        "setup": {"rig": "two loopback MG400 emulators, rig camera (sim render + shear + shipped shPix2pix, "
                         "640x480 frame, real preprocessing), leader base at (690, 0, 0, 180) in the follower's "
                         "frame", "controller": "servo (shipped surface GDNN + filter + PI law)",
                  "control_period_s": 0.1, "speed_mm_s": args.speed_mm_s,
                  "goal": "mean contact error <= 0.5 mm, no contact loss (the paper's real robot: 0.89-1.60 mm)"},
        "title": "two-arm tracking, rehearsed", "columns": 4,
    }


def _colift(args: argparse.Namespace, command: str) -> dict:
    from simshear_gym.lab.colift import CoLiftConfig, run_colift_rehearsal
    from simshear_gym.lab.experiment import rehearsal_safety

    runs_dir = args.runs if args.runs is not None else Path("runs/experiment_colift")
    runs: dict[str, dict] = {}
    for trajectory in args.colift_trajectories:
        for name in args.objects:
            key = f"{name}_{trajectory}"
            run_dir = runs_dir / key
            config = CoLiftConfig(trajectory=trajectory, object_name=name, speed_mm_s=args.colift_speed_mm_s).with_env(
                safety=rehearsal_safety(args.max_feedback_age_s, args.max_feedback_age_s))
            summary = run_colift_rehearsal(config, run_dir, command=f"{command}  # run {key}")
            summary.pop("rows")
            runs[key] = {"run_dir": str(run_dir), **{k: summary.get(k) for k in KEYS + COLIFT_KEYS}}
            print(f"{key}: contact error {summary['contact_error_mean_mm']} +- {summary['contact_error_std_mm']} mm "
                  f"(truth {summary['truth_contact_error_mean_mm']}), dropped {summary['dropped']}, slip max "
                  f"{summary['truth_object_slip_max_mm']} mm, {summary['loop_rate_hz']} Hz, compute "
                  f"{summary['compute_ms_median']} ms; "
                  f"{'completed' if summary['completed'] else 'stopped: ' + summary['stop']}")
    return {
        "runs": runs,
        "setup": {"rig": "two loopback MG400 emulators in the co-lift layout (leader base at (750, 0, 0, 180) in the "
                         "follower's frame, upright plate, horizontal TacTip), the co-lift scene's object physics "
                         "stepped on the emulators' poses, rig camera (sim render of the object in the dome + the "
                         "skin's shear + shipped shPix2pix, 640x480 frame, real preprocessing)",
                  "controller": "servo (shipped colift GDNN + filter, process noise 1.5 mm + PI law; no turn)",
                  "sequence": "approach along the grip axis to the touch, squeeze to 3 mm (2 s; the object leaves "
                              "its support 1 s before the lift), lift 10 mm, the trajectory, set down, hold 1 s, "
                              "back off 10 mm along the grip axis",
                  "control_period_s": 0.1, "speed_mm_s": args.colift_speed_mm_s,
                  "goal": "mean contact error <= 1.0 mm each, no drop, 0 commands outside the safety limits"},
        "title": "co-lift, rehearsed", "columns": 4,
    }


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(args.threads)
    command = recorded_command("simshear evaluate experiment", add_arguments, args)
    ok = True
    for task in args.tasks:
        started = time.monotonic()
        result = {"tracking": _tracking, "colift": _colift}[task](args, command)
        runs = result["runs"]
        figure = plot(runs, args.out / f"experiment_{task}.png", result["title"], result["columns"])
        payload = {
            "command": command,
            "machine": machine_info(),
            "metrics": ("contact error = the follower's sensor against the contact point the leader carries, from "
                        "both arms' fed-back poses through the calibration (the paper's), per tracking cycle; truth = "
                        "the rig's simulation; loop rate = tracking cycles per second on one clock; compute = "
                        "controller (GDNN + filter + PI law) per cycle; commands outside limits = the emulators' own "
                        "records checked against the safe defaults"),
            "setup": result["setup"],
            "runs": runs,
            "figure": str(figure),
            "seconds": round(time.monotonic() - started, 1),
        }
        path = write_json(args.out / f"experiment_{task}.json", payload)
        print(f"wrote {path} and {figure}")
        ok = ok and all(run["completed"] for run in runs.values())
    return 0 if ok else 1
