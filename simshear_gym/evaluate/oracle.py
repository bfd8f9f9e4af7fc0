"""The oracle controller on every tracking trajectory: contact error (mm) and contact losses.

``simshear evaluate oracle`` runs :class:`~simshear_gym.control.oracle.OracleController` on
``SimShearTracking-v0`` (``obs_mode="oracle"``: the true depth and shear) for each trajectory: one episode on the
nominal trajectory and ``--seeds`` episodes with the training randomisation (scale, speed, rotation, start
place), and writes ``results/oracle.json`` with the mean +- std and max of the per-step contact error, the steps
out of contact and the episodes that ended early. The goal is a mean error <= 0.5 mm on every trajectory; the
paper's real-robot numbers (estimated pose and shear, not an oracle) are listed for scale.

``--tasks colift`` (or ``--tasks tracking colift``) runs the same on ``SimShearCoLift-v0`` for every object and
co-lift trajectory and writes ``results/oracle_colift.json``; its goal: a mean error <= 1.0 mm and no drop.
"""

from __future__ import annotations

import argparse
import functools
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.closed_loop import TimedEpisode
from simshear_gym.evaluate.records import write_record

GOAL_MEAN_MM = 0.5
COLIFT_GOAL_MEAN_MM = 1.0
TASKS: tuple[str, ...] = ("tracking", "colift")
PAPER_REAL_ROBOT_MM = {  # SimShear (CoRL 2025), tracking with the real MG400s: mean +- std contact error
    "circle": (0.97, 0.53), "tilted_square": (0.89, 0.40), "spiral": (1.06, 0.53), "loop": (1.60, 1.02)}


def run_episode(trajectory: str, seed: int, randomise: bool, obs_mode: str = "oracle",
                env_id: str = "SimShearTracking-v0", **env_kwargs) -> dict:
    """One full episode with the oracle; returns the per-step errors and how the episode ended."""
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401  (registers the envs)
    from simshear_gym.control.oracle import OracleController

    env = gym.make(env_id, trajectory=trajectory, obs_mode=obs_mode, randomise=randomise, **env_kwargs)
    controller = OracleController.for_env(env)
    episode = TimedEpisode(env, controller, seed)
    errors, out_of_contact, slip_mm = [], 0, 0.0
    for info in episode:
        errors.append(info["contact_error_mm"])
        slip_mm = max(slip_mm, info.get("object_slip_mm", 0.0))  # co-lift: the object's drift on the plate
        out_of_contact += int(not info["in_contact"])
    termination = episode.info["termination"]
    env.close()
    return {"errors_mm": np.asarray(errors), "steps_out_of_contact": out_of_contact, "termination": termination,
            "max_object_slip_mm": slip_mm}


def summarise(episodes: list[dict]) -> dict:
    errors = np.concatenate([episode["errors_mm"] for episode in episodes])
    return {
        "episodes": len(episodes), "steps": int(errors.size),
        "mean_mm": round(float(errors.mean()), 4), "std_mm": round(float(errors.std()), 4),
        "max_mm": round(float(errors.max()), 4),
        "contact_losses_steps": int(sum(episode["steps_out_of_contact"] for episode in episodes)),
        "episodes_ended_early": int(sum(bool(episode["termination"]) for episode in episodes)),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=int, default=5, help="randomised episodes per trajectory")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory")
    parser.add_argument("--tasks", nargs="+", choices=TASKS, default=["tracking"],
                        help="envs to run: tracking (SimShearTracking-v0, results/oracle.json) and/or colift "
                             "(SimShearCoLift-v0 over every object, results/oracle_colift.json)")


def run(args: argparse.Namespace) -> int:
    if args.seeds < 0:
        raise ValueError(f"--seeds must be >= 0, got {args.seeds}")
    status = 0
    if "tracking" in args.tasks:
        status |= run_tracking(args)
    if "colift" in args.tasks:
        status |= run_colift(args)
    return status


def run_colift(args: argparse.Namespace) -> int:
    from simshear_gym.envs.colift import COLIFT_TRAJECTORIES, OBJECT_NAMES

    rows: dict = {}
    start = time.perf_counter()
    for object_name in OBJECT_NAMES:
        for trajectory in COLIFT_TRAJECTORIES:
            run_one = functools.partial(run_episode, trajectory, env_id="SimShearCoLift-v0", object_name=object_name)
            nominal = [run_one(0, randomise=False)]
            randomised = [run_one(seed, randomise=True) for seed in range(args.seeds)]
            episodes = nominal + randomised
            row = {"nominal": summarise(nominal), "all": summarise(episodes)}
            if randomised:
                row["randomised"] = summarise(randomised)
            row["drops"] = sum(episode["termination"] == "dropped" for episode in episodes)
            row["max_object_slip_mm"] = round(max(episode["max_object_slip_mm"] for episode in episodes), 3)
            row["goal_met"] = row["all"]["mean_mm"] <= COLIFT_GOAL_MEAN_MM and row["all"]["episodes_ended_early"] == 0
            rows[f"{object_name}/{trajectory}"] = row
            summary = row["all"]
            print(f"{object_name:6s} {trajectory:14s} {summary['episodes']} episodes: contact error "
                  f"{summary['mean_mm']:.3f} +- {summary['std_mm']:.3f} mm (max {summary['max_mm']:.3f}), "
                  f"{row['drops']} drops, object slip <= {row['max_object_slip_mm']:.2f} mm, "
                  f"{summary['episodes_ended_early']} episodes ended early")
    payload = {
        "env": "SimShearCoLift-v0, obs_mode='oracle', 500 steps at 10 Hz, 30 g objects; nominal trajectory (seed 0) "
               "plus seeds 0.. with randomise=True (scale, speed x0.7-1.3, leader start +-10 mm; no turn of the plate)",
        "controller": "simshear_gym.control.oracle.OracleController (PI, kp=1, ki=0.5 per variable)",
        "goal_mean_mm": COLIFT_GOAL_MEAN_MM, "goal": "mean contact error <= 1.0 mm and no episode ended early",
        "all_goals_met": all(row["goal_met"] for row in rows.values()),
        "seconds": round(time.perf_counter() - start, 1), "objects_trajectories": rows,
    }
    write_record("simshear evaluate oracle", add_arguments, args, args.out / "oracle_colift.json", payload)
    print(f"wrote {args.out / 'oracle_colift.json'}")
    return 0 if payload["all_goals_met"] else 1


def run_tracking(args: argparse.Namespace) -> int:
    from simshear_gym.envs.trajectories import TRAJECTORIES

    rows = {}
    start = time.perf_counter()
    for trajectory in TRAJECTORIES:
        nominal = [run_episode(trajectory, 0, randomise=False)]
        randomised = [run_episode(trajectory, seed, randomise=True) for seed in range(args.seeds)]
        row = {"nominal": summarise(nominal), "all": summarise(nominal + randomised)}
        if randomised:
            row["randomised"] = summarise(randomised)
        row["paper_real_robot_mean_std_mm"] = PAPER_REAL_ROBOT_MM[trajectory]
        row["goal_met"] = row["all"]["mean_mm"] <= GOAL_MEAN_MM
        rows[trajectory] = row
        summary = row["all"]
        print(f"{trajectory:14s} {summary['episodes']} episodes: contact error {summary['mean_mm']:.3f} +- "
              f"{summary['std_mm']:.3f} mm (max {summary['max_mm']:.3f}), contact lost on "
              f"{summary['contact_losses_steps']} steps, {summary['episodes_ended_early']} episodes ended early")
    payload = {
        "env": "SimShearTracking-v0, obs_mode='oracle', 500 steps at 10 Hz; nominal trajectory (seed 0) plus "
               "seeds 0.. with randomise=True (scale, speed x0.7-1.3, rotation, start place +-10 mm)",
        "controller": "simshear_gym.control.oracle.OracleController (PI, kp=1, ki=0.5 per variable)",
        "goal_mean_mm": GOAL_MEAN_MM, "all_goals_met": all(row["goal_met"] for row in rows.values()),
        "seconds": round(time.perf_counter() - start, 1), "trajectories": rows,
    }
    write_record("simshear evaluate oracle", add_arguments, args, args.out / "oracle.json", payload)
    print(f"wrote {args.out / 'oracle.json'}")
    return 0 if payload["all_goals_met"] else 1
