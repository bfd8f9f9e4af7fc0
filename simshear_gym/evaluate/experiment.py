"""``simshear evaluate experiment --tasks tracking``: the paper's two-arm tracking experiment, rehearsed.

For each of the tracking env's trajectories (``circle``, ``tilted_square``, ``spiral``, ``loop``: the paths, speed
4 mm/s and rotations of ``SimShearTracking-v0``), one full run of ``simshear experiment tracking --rehearsal``
(:func:`~simshear_gym.lab.experiment.run_tracking_rehearsal`) with the shipped models (the shipped shPix2pix makes
the rig camera's images, the shipped surface GDNN reads them; the servo controller) on a fresh rehearsal rig: two
loopback MG400 emulators and the rig camera, the leader's base where the sim scene has it, the calibration exact
(the rig's own layout; ``simshear calibrate-arms`` has its own test).

Recorded per trajectory: the contact error as the paper measures it (the calibrated kinematics of both arms' fed-back
poses; mean, std and max over the run's tracking cycles) and the rig's true one, contact loss (cycles with the
sensor above or off the plate, and whether a stop ended the run), the loop rate (tracking cycles over their
duration, one clock), the compute per cycle (the controller: GDNN, filter, law; median and p95, ms), period
overruns, and the emulators' audit (commands outside the safe limits in their own records). Every run's log,
figure and record go to ``--runs``; ``results/experiment_tracking.json`` (with the command) and
``results/experiment_tracking.png`` (the paper's figure: leader red, follower blue, error mean +- std per run).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from simshear_gym.io import write_json
from simshear_gym.machine import machine_info

TASKS = ("tracking",)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.envs.trajectories import TRAJECTORIES

    parser.add_argument("--tasks", nargs="+", default=["tracking"], choices=TASKS,
                        help="which experiment (tracking; co-lift is not built yet)")
    parser.add_argument("--trajectories", nargs="+", default=list(TRAJECTORIES), choices=TRAJECTORIES,
                        help="the leader's paths (default all four)")
    parser.add_argument("--speed-mm-s", type=float, default=4.0, help="the leader's speed (default 4, the env's)")
    parser.add_argument("--max-feedback-age-s", type=float, default=1.0,
                        help="the rehearsal's feedback and camera-frame age limit, s (default 1.0: the emulators, "
                             "the render and the networks share the process)")
    parser.add_argument("--runs", type=Path, default=Path("runs/experiment_tracking"),
                        help="each run's log, figure and record go here")
    parser.add_argument("--out", type=Path, default=Path("results"), help="where the record and figure go")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def command_line(args: argparse.Namespace) -> str:
    return (f"simshear evaluate experiment --tasks {' '.join(args.tasks)} --trajectories "
            f"{' '.join(args.trajectories)} --speed-mm-s {args.speed_mm_s:g} --max-feedback-age-s "
            f"{args.max_feedback_age_s:g} --runs {args.runs} --out {args.out} --threads {args.threads}")


KEYS = ("completed", "stop", "stop_reason", "trajectory_duration_s", "tracking_cycles", "contact_error_mean_mm",
        "contact_error_std_mm", "contact_error_max_mm", "truth_contact_error_mean_mm", "truth_contact_error_std_mm",
        "truth_contact_error_max_mm", "cycles_out_of_contact", "truth_cycles_out_of_contact", "contact_lost",
        "loop_rate_hz", "compute_ms_median", "compute_ms_p95", "period_overruns", "late_cycles", "plan_behind_s",
        "commands_outside_limits", "wall_s")


def plot(runs: dict, path: Path) -> Path:
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simshear_gym.io import atomic_write
    from simshear_gym.lab.experiment import draw_run

    figure = plt.figure(figsize=(4.2 * len(runs), 4.4))
    for index, (name, run) in enumerate(runs.items()):
        with open(Path(run["run_dir"]) / "log.csv") as handle:
            rows = [{key: (value if key == "phase" else float(value) if value not in ("", "True", "False") else value)
                     for key, value in row.items()} for row in csv.DictReader(handle)]
        mean, std = run["contact_error_mean_mm"], run["contact_error_std_mm"]
        title = f"{name}: {mean:.2f} +- {std:.2f} mm" if mean is not None else f"{name}: no tracking"
        draw_run(figure.add_subplot(1, len(runs), index + 1, projection="3d"), rows, title)
    figure.suptitle("two-arm tracking, rehearsed (leader's contact point red, follower's sensor blue; follower's "
                    "base frame, mm)", fontsize=10)
    figure.tight_layout()
    atomic_write(path, lambda tmp: figure.savefig(tmp, dpi=90, format="png"), suffix=".png")
    plt.close(figure)
    return path


def run(args: argparse.Namespace) -> int:
    import torch

    from simshear_gym.lab.experiment import ExperimentConfig, rehearsal_safety, run_tracking_rehearsal

    torch.set_num_threads(args.threads)
    command = command_line(args)
    started = time.monotonic()
    runs: dict[str, dict] = {}
    for name in args.trajectories:
        run_dir = args.runs / name
        config = ExperimentConfig(trajectory=name, speed_mm_s=args.speed_mm_s,
                                  safety=rehearsal_safety(args.max_feedback_age_s, args.max_feedback_age_s))
        summary = run_tracking_rehearsal(config, run_dir, command=f"{command}  # run {name}")
        runs[name] = {"run_dir": str(run_dir), **{key: summary.get(key) for key in KEYS}}
        print(f"{name}: contact error {summary['contact_error_mean_mm']} +- {summary['contact_error_std_mm']} mm "
              f"(truth {summary['truth_contact_error_mean_mm']}), {summary['cycles_out_of_contact']} cycles out of "
              f"contact, {summary['loop_rate_hz']} Hz, compute {summary['compute_ms_median']} ms; "
              f"{'completed' if summary['completed'] else 'stopped: ' + summary['stop']}")
    args.out.mkdir(parents=True, exist_ok=True)
    figure = plot(runs, args.out / "experiment_tracking.png")
    payload = {
        "command": command,
        "machine": machine_info(),
        "metrics": ("contact error = the follower's sensor against the contact point the leader carries, from both "
                    "arms' fed-back poses through the calibration (the paper's), per tracking cycle; truth = the "
                    "rig's simulation; loop rate = tracking cycles per second on one clock; compute = controller "
                    "(GDNN + filter + PI law) per cycle; commands outside limits = the emulators' own records "
                    "checked against the safe defaults"),
        "setup": {"rig": "two loopback MG400 emulators, rig camera (sim render + shear + shipped shPix2pix, "
                         "640x480 frame, real preprocessing), leader base at (690, 0, 0, 180) in the follower's "
                         "frame", "controller": "servo (shipped surface GDNN + filter + PI law)",
                  "control_period_s": 0.1, "speed_mm_s": args.speed_mm_s,
                  "goal": "mean contact error <= 0.5 mm, no contact loss (the paper's real robot: 0.89-1.60 mm)"},
        "runs": runs,
        "figure": str(figure),
        "seconds": round(time.monotonic() - started, 1),
    }
    path = write_json(args.out / "experiment_tracking.json", payload)
    print(f"wrote {path} and {figure}")
    return 0 if all(run["completed"] for run in runs.values()) else 1
