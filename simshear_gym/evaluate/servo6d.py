"""Closed-loop benchmark of the 6-DoF tactile servo on the tilting plate (``SimShearTracking6D-v0``).

``simshear evaluate servo6d`` runs, on each trajectory (``circle``, ``tilted_square``, ``spiral``, ``loop`` by
default) in a nominal run and one randomised run per seed (the env draws the path's scale, speed, turn, the start
place and each tilt amplitude):

- ``panda_servo6d``: the Panda follower with :class:`~simshear_gym.control.servo6d.Servo6DController` (translated
  images, the shipped ``surface`` GDNN's depth, tilt and shear, Bayesian filter; never ground truth);
- ``mg400_servo``: the baseline: the level MG400 follower with today's
  :class:`~simshear_gym.control.servo.ServoController` (depth and shear only; it cannot tilt).

Per run: contact error mean and max (mm), normal error mean and max (deg; the angle between the sensor's axis
and the plate's normal), steps out of contact, the end (``termination``), and the control loop's compute per step
(estimator + filter + laws, ms, median). Writes ``results/servo_tracking6d.json`` (with the command; ``--name``)
and ``results/servo_tracking6d.png``: per trajectory, the nominal runs' contact and normal errors against time.
Acceptance target of the 6-DoF follower: contact error <= 0.5 mm and normal error <= 2 deg on every trajectory,
no contact loss.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.closed_loop import TimedEpisode
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record

TRAJECTORIES = ("circle", "tilted_square", "spiral", "loop")
ROWS = ("panda_servo6d", "mg400_servo")
TARGET_CONTACT_ERROR_MM = 0.5
TARGET_NORMAL_ERROR_DEG = 2.0


def make_controller(row: str, env, gains=None):
    """The controller of a row, matched to ``env``."""
    if row == "panda_servo6d":
        from simshear_gym.control.servo6d import Servo6DController, Servo6DGains

        return Servo6DController.for_env(env, gains or Servo6DGains())
    from simshear_gym.control.servo import ServoController

    return ServoController.for_env(env)


def run_episode(env, controller, seed: int | None, randomise_seed: bool, max_steps: int | None = None) -> dict:
    """One episode; returns its figures and the per-step errors (``_trace``) for the figure."""
    episode = TimedEpisode(env, controller, seed, max_steps)
    contact, normal = [episode.info["contact_error_mm"]], [episode.info["normal_error_deg"]]
    out_of_contact = 0
    for info in episode:
        contact.append(info["contact_error_mm"])
        normal.append(info["normal_error_deg"])
        out_of_contact += int(not info["in_contact"])
    termination = episode.info.get("termination", "") if episode.terminated else ""
    contact, normal = np.asarray(contact), np.asarray(normal)
    return {
        "seed": seed if randomise_seed else "nominal", "steps": episode.steps,
        "contact_error_mean_mm": float(contact.mean()), "contact_error_max_mm": float(contact.max()),
        "normal_error_mean_deg": float(normal.mean()), "normal_error_max_deg": float(normal.max()),
        "steps_out_of_contact": out_of_contact, "termination": termination,
        "control_ms_median": 1000.0 * float(np.median(episode.control_s)),
        "_trace": (contact, normal),
    }


def summarise(runs: list[dict]) -> dict:
    contact = np.array([r["contact_error_mean_mm"] for r in runs])
    normal = np.array([r["normal_error_mean_deg"] for r in runs])
    losses = int(sum(r["steps_out_of_contact"] > 0 or r["termination"] == "contact_lost" for r in runs))
    return {
        "runs": len(runs), "contact_error_mean_mm": float(contact.mean()),
        "contact_error_mean_std_mm": float(contact.std()),
        "contact_error_max_mm": float(max(r["contact_error_max_mm"] for r in runs)),
        "normal_error_mean_deg": float(normal.mean()), "normal_error_mean_std_deg": float(normal.std()),
        "normal_error_max_deg": float(max(r["normal_error_max_deg"] for r in runs)),
        "contact_losses": losses, "runs_ended_early": int(sum(bool(r["termination"]) for r in runs)),
        "terminations": sorted({r["termination"] for r in runs if r["termination"]}),
        "control_ms_median": float(np.median([r["control_ms_median"] for r in runs])),
        "meets_target": bool(  # every run's mean within the targets, no run losing contact
            contact.max() <= TARGET_CONTACT_ERROR_MM and normal.max() <= TARGET_NORMAL_ERROR_DEG and losses == 0),
    }


def figure(traces: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]], trajectories, path: Path,
           dt_s: float) -> None:
    """Per trajectory (rows): contact error and normal error against time, one line per controller row."""
    plt = pyplot()

    fig, axes = plt.subplots(len(trajectories), 2, figsize=(9.0, 2.2 * len(trajectories)), squeeze=False)
    colours = {"panda_servo6d": "tab:blue", "mg400_servo": "tab:red"}
    for index, trajectory in enumerate(trajectories):
        for row in ROWS:
            if (row, trajectory) not in traces:
                continue
            contact, normal = traces[(row, trajectory)]
            time_s = np.arange(len(contact)) * dt_s
            axes[index, 0].plot(time_s, contact, color=colours[row], lw=0.9, label=row)
            axes[index, 1].plot(time_s, normal, color=colours[row], lw=0.9, label=row)
        axes[index, 0].axhline(TARGET_CONTACT_ERROR_MM, color="k", ls=":", lw=0.8)
        axes[index, 1].axhline(TARGET_NORMAL_ERROR_DEG, color="k", ls=":", lw=0.8)
        axes[index, 0].set_ylabel(f"{trajectory}\ncontact error mm", fontsize=7)
        axes[index, 1].set_ylabel("normal error deg", fontsize=7)
        for axis in axes[index]:
            axis.tick_params(labelsize=6)
            axis.set_ylim(bottom=0.0)
    axes[-1, 0].set_xlabel("time s", fontsize=7)
    axes[-1, 1].set_xlabel("time s", fontsize=7)
    axes[0, 0].legend(fontsize=6)
    fig.suptitle("SimShearTracking6D-v0, nominal runs (dotted: targets 0.5 mm, 2 deg)", fontsize=9)
    save_figure(fig, path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trajectories", nargs="+", default=list(TRAJECTORIES),
                        help="trajectories of SimShearTracking6D-v0 (default circle tilted_square spiral loop; the "
                             "test paths circular_wave and star also run)")
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS,
                        help="panda_servo6d (6-DoF servo on the Panda) and/or mg400_servo (4-DoF baseline)")
    parser.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3],
                        help="seeds of the randomised runs, each besides the nominal run (default 1 2 3; none: the "
                             "nominal runs only)")
    parser.add_argument("--no-nominal", action="store_true", help="skip the nominal run")
    parser.add_argument("--max-steps", type=int, default=None, help="cap per episode (default: the env's 500)")
    parser.add_argument("--tilt-kp", type=float, default=None, help="tilt law kp (default Servo6DGains)")
    parser.add_argument("--tilt-ki", type=float, default=None, help="tilt law ki (default Servo6DGains)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder (default results)")
    parser.add_argument("--name", default="servo_tracking6d", help="file stem (default servo_tracking6d)")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import torch

    import simshear_gym.envs  # noqa: F401  (registers the envs)
    from simshear_gym.control.servo6d import Servo6DGains

    torch.set_num_threads(args.threads)
    gains = Servo6DGains()
    if args.tilt_kp is not None or args.tilt_ki is not None:
        gains = Servo6DGains(planar=gains.planar, tilt_kp=gains.tilt_kp if args.tilt_kp is None else args.tilt_kp,
                             tilt_ki=gains.tilt_ki if args.tilt_ki is None else args.tilt_ki,
                             tilt_process_std_deg=gains.tilt_process_std_deg)
    start = time.perf_counter()
    results: dict = {row: {} for row in args.rows}
    traces: dict = {}
    dt_s = 0.1
    for row in args.rows:
        follower = "panda" if row == "panda_servo6d" else "mg400"
        for trajectory in args.trajectories:
            runs = []
            plan = ([] if args.no_nominal else [(False, [0])]) + [(True, list(args.seeds))]
            for randomise, seeds in plan:
                if not seeds:
                    continue
                env = gym.make("SimShearTracking6D-v0", trajectory=trajectory, follower=follower, obs_mode="real",
                               randomise=randomise)
                dt_s = env.unwrapped.dt_s
                controller = make_controller(row, env, gains)
                for seed in seeds:
                    r = run_episode(env, controller, seed, randomise, args.max_steps)
                    trace = r.pop("_trace")
                    if not randomise:
                        traces[(row, trajectory)] = trace
                    runs.append(r)
                env.close()
            s = results[row][trajectory] = {**summarise(runs), "per_run": runs}
            print(f"{row:14s} {trajectory:14s} contact {s['contact_error_mean_mm']:.3f} mm (max "
                  f"{s['contact_error_max_mm']:.2f}), normal {s['normal_error_mean_deg']:.2f} deg (max "
                  f"{s['normal_error_max_deg']:.1f}), contact losses {s['contact_losses']}, ended early "
                  f"{s['runs_ended_early']} {s['terminations']}, control {s['control_ms_median']:.2f} ms", flush=True)
    png = args.out / f"{args.name}.png"
    figure(traces, args.trajectories, png, dt_s)
    write_record("simshear evaluate servo6d", add_arguments, args, args.out / f"{args.name}.json", {
        "metrics": "contact error = distance (mm) between the follower's sensor and its target point carried with "
                   "the tilting plate, every step; normal error = angle (deg) between the sensor's axis and the "
                   "plate's inward normal, every step; per trajectory the mean over runs of the per-run means (runs: "
                   "nominal + one randomised per seed); contact_losses = runs with any step out of contact; "
                   "control = estimator + filter + laws per step (ms, median of the runs' medians)",
        "target": {"contact_error_mean_mm": TARGET_CONTACT_ERROR_MM, "normal_error_mean_deg": TARGET_NORMAL_ERROR_DEG,
                   "contact_losses": 0, "applies_to": "panda_servo6d, every trajectory"},
        "gains": {"planar_kp": list(gains.planar.kp), "planar_ki": list(gains.planar.ki), "tilt_kp": gains.tilt_kp,
                  "tilt_ki": gains.tilt_ki, "tilt_process_std_deg": gains.tilt_process_std_deg},
        "results": results, "figure": str(png), "seconds": round(time.perf_counter() - start, 1),
    })
    print(f"wrote {args.out / (args.name + '.json')}")
    return 0
