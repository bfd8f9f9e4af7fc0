"""Closed-loop edge following: ``simshear evaluate edge-follow``.

Runs a controller once round the edge of each outline of ``SimShearEdgeFollow-v0`` (``disk``, ``rounded_square``,
``clover``, ``wavy``): a nominal run (40 mm object, start at the outline's first point, on the edge, sensor
unturned) and one randomised run per seed (the env draws the size, 32, 40 or 48 mm, the start point, an offset of up
to 2 mm and the sensor's turn). Variants:

- ``servo``: :class:`~simshear_gym.control.edge_servo.EdgeServoController` on the env's translated images
  (``obs_mode="real"``, the shipped edge shPix2pix) read by the shipped edge GDNN (``--posenet`` for another);
  it never sees ground truth;
- ``oracle``: the same law on the true offset, depth and angle (the law's floor, not a tactile controller);
- ``policy`` / ``ppo`` / ``sac`` / ``tqc``: an SB3 agent of ``simshear train rl`` (``--policy``), in the settings
  it was trained with.

Per run, every step: the apex's offset from the edge (mm: its distance from the outline in the top face's plane),
the depth error (labels' z against the reference, mm), whether the lap was completed (``termination == "lap"``)
and how far round it got. Writes ``results/<name>.json`` (with the command) and a figure: per outline, the outline
and each variant's path seen from above (nominal runs), and the offset along the way.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.closed_loop import POLICY_VARIANTS, TimedEpisode, check_policy, env_kwargs
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

ENV_ID = "SimShearEdgeFollow-v0"
VARIANTS = ("servo", "oracle", "policy", "ppo", "sac", "tqc")
GOAL_OFFSET_MM = 0.5  # issue 43: mean offset from the edge per contour
GOAL_DEPTH_MM = 0.3  # and depth error


def make_controller(variant: str, env, posenet: str | None, policy: str | None):
    from simshear_gym.control.edge_servo import EdgeOracleController, EdgeServoController
    from simshear_gym.control.estimator import EstimatorConfig

    if variant == "oracle":
        return EdgeOracleController.for_env(env)
    if variant in POLICY_VARIANTS:
        from simshear_gym.control.policy import SB3Controller

        return SB3Controller.for_env(policy, env)
    return EdgeServoController.for_env(env, estimator=EstimatorConfig(posenet=posenet))


def run_episode(env, controller, seed: int, max_steps: int | None = None) -> dict:
    """One episode; its figures, and the sensor's path (world mm) and offsets for the figure."""
    episode = TimedEpisode(env, controller, seed, max_steps)
    reference = env.unwrapped.reference_depth_mm
    offsets, depth_errors, path = [], [], [np.asarray(episode.info["sensor_world_mm"], dtype=np.float64)]
    progress = [0.0]
    out_of_contact = 0
    for info in episode:
        offsets.append(float(info["edge_offset_mm"]))
        depth_errors.append(float(info["depth_mm"]) - reference)
        path.append(np.asarray(info["sensor_world_mm"], dtype=np.float64))
        progress.append(float(info["progress_mm"]))
        out_of_contact += int(not info["in_contact"])
    info = episode.info
    termination = (info.get("termination", "") if episode.terminated
                   else ("time_limit" if episode.truncated else "max_steps"))
    offsets, depth_errors = np.abs(offsets), np.abs(depth_errors)
    return {
        "steps": episode.steps, "lap_completed": termination == "lap", "termination": termination,
        "perimeter_mm": float(info["perimeter_mm"]), "progress_mm": float(info["progress_mm"]),
        "offset_mean_mm": float(offsets.mean()), "offset_max_mm": float(offsets.max()),
        "depth_error_mean_mm": float(depth_errors.mean()), "depth_error_max_mm": float(depth_errors.max()),
        "steps_out_of_contact": out_of_contact,
        "control_ms_median": 1000 * float(np.median(episode.control_s)),
        "env_step_ms_median": 1000 * float(np.median(episode.step_s)),
        "_path": np.stack(path), "_progress": np.asarray(progress[1:]), "_offsets": offsets,
    }


def summarise(runs: list[dict]) -> dict:
    offsets = np.array([r["offset_mean_mm"] for r in runs])
    depths = np.array([r["depth_error_mean_mm"] for r in runs])
    return {
        "runs": len(runs), "laps_completed": int(sum(r["lap_completed"] for r in runs)),
        "offset_mean_mm": float(offsets.mean()), "offset_mean_worst_run_mm": float(offsets.max()),
        "offset_max_mm": float(max(r["offset_max_mm"] for r in runs)),
        "depth_error_mean_mm": float(depths.mean()), "depth_error_mean_worst_run_mm": float(depths.max()),
        "depth_error_max_mm": float(max(r["depth_error_max_mm"] for r in runs)),
        "terminations": sorted({r["termination"] for r in runs if r["termination"] != "lap"}),
        "control_ms_median": float(np.median([r["control_ms_median"] for r in runs])),
        "env_step_ms_median": float(np.median([r["env_step_ms_median"] for r in runs])),
    }


def figure(panels: dict[str, dict[str, tuple]], outlines_world: dict[str, np.ndarray], path: Path,
           title: str) -> None:
    """Per outline (columns): the outline (black) and each variant's nominal path from above; below, each
    variant's offset from the edge along the way."""
    plt = pyplot()

    names = list(panels)
    fig, axes = plt.subplots(2, len(names), figsize=(3.3 * len(names), 6.0), squeeze=False,
                             gridspec_kw={"height_ratios": [3, 1.4]})
    for column, name in enumerate(names):
        top, bottom = axes[0, column], axes[1, column]
        outline = outlines_world[name]
        top.plot(*np.vstack([outline, outline[:1]]).T, color="black", lw=1.0, label="edge")
        for variant, (sensor, progress, offsets, result) in panels[name].items():
            top.plot(sensor[:, 0], sensor[:, 1], lw=0.8, ls="--",
                     label=f"{variant}: {result['offset_mean_mm']:.2f} mm")
            bottom.plot(progress, offsets, lw=0.7, label=variant)
        top.set_aspect("equal")
        top.set_title(name, fontsize=9)
        top.legend(fontsize=6, loc="lower left")
        top.tick_params(labelsize=6)
        top.set_xlabel("world x mm", fontsize=7)
        top.set_ylabel("world y mm", fontsize=7)
        bottom.set_xlabel("along the edge, mm", fontsize=7)
        bottom.set_ylabel("|offset| mm", fontsize=7)
        bottom.tick_params(labelsize=6)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.sim.contours import OUTLINES

    parser.add_argument("--outlines", nargs="+", default=list(OUTLINES), choices=OUTLINES,
                        help="objects' outlines (default all four)")
    parser.add_argument("--variants", nargs="+", default=["servo", "oracle"], choices=VARIANTS,
                        help="controllers: servo (translated images, shipped edge GDNN), oracle (true state into the "
                             "same law), policy / ppo / sac / tqc (an agent of simshear train rl: --policy); "
                             "default servo oracle")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3],
                        help="seeds of the randomised runs (size, start point, offset, turn), besides the nominal run")
    parser.add_argument("--posenet", default=None, help="edge GDNN of the servo variant (default the shipped one)")
    parser.add_argument("--policy", default=None, help="the agent's model.zip (or model.pt) for a policy variant")
    parser.add_argument("--max-steps", type=int, default=None, help="cap per episode (default: the env's limit)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder (default results)")
    parser.add_argument("--name", default="edge_follow", help="file name stem (default edge_follow)")


def check_args(args: argparse.Namespace) -> None:
    if args.threads < 1 or (args.max_steps is not None and args.max_steps < 1):
        raise ValueError(f"--threads and --max-steps must be >= 1, got {args.threads}, {args.max_steps}")
    check_policy(args.variants, args.policy)


def run(args: argparse.Namespace) -> int:
    check_args(args)
    import gymnasium as gym
    import torch

    import simshear_gym.envs  # noqa: F401  (registers the envs)
    from simshear_gym.envs.edge_follow import T_WORLD_OBJECT

    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    results: dict = {}
    panels: dict[str, dict[str, tuple]] = {}
    outlines_world: dict[str, np.ndarray] = {}
    for variant in args.variants:
        results[variant] = {}
        obs_mode = "oracle" if variant == "oracle" else "real"
        for outline in args.outlines:
            runs = []
            for randomise, seeds in ((False, ["nominal"]), (True, args.seeds)):
                env = gym.make(ENV_ID, outline=outline, randomise=randomise,
                               **env_kwargs(variant, args.policy, obs_mode))
                controller = make_controller(variant, env, args.posenet, args.policy)
                for seed in seeds:
                    r = run_episode(env, controller, 0 if seed == "nominal" else seed, args.max_steps)
                    sensor, progress, offsets = r.pop("_path"), r.pop("_progress"), r.pop("_offsets")
                    r["seed"] = seed
                    if seed == "nominal":
                        panels.setdefault(outline, {})[variant] = (sensor, progress, offsets, r)
                        points = env.unwrapped.contour.points_mm
                        outlines_world[outline] = points @ T_WORLD_OBJECT[:2, :2].T + T_WORLD_OBJECT[:2, 3]
                    runs.append(r)
                env.close()
            s = results[variant][outline] = {**summarise(runs), "per_run": runs}
            print(f"{variant:7s} {outline:15s} laps {s['laps_completed']}/{s['runs']}, "
                  f"offset {s['offset_mean_mm']:.3f} mm (worst run {s['offset_mean_worst_run_mm']:.3f}, "
                  f"max {s['offset_max_mm']:.2f}), depth error {s['depth_error_mean_mm']:.3f} mm "
                  f"(worst run {s['depth_error_mean_worst_run_mm']:.3f}), {s['terminations'] or 'no early end'}, "
                  f"control {s['control_ms_median']:.2f} ms, env step {s['env_step_ms_median']:.2f} ms")
    png = args.out / f"{args.name}.png"
    figure(panels, outlines_world, png, f"{ENV_ID}: once round the edge (nominal runs)")
    goals = {variant: {"offset_mean_mm_max": GOAL_OFFSET_MM, "depth_error_mean_mm_max": GOAL_DEPTH_MM,
                       "met": all(s["laps_completed"] == s["runs"]
                                  and s["offset_mean_worst_run_mm"] <= GOAL_OFFSET_MM
                                  and s["depth_error_mean_worst_run_mm"] <= GOAL_DEPTH_MM
                                  for s in results[variant].values())}
             for variant in args.variants}
    write_record("simshear evaluate edge-follow", add_arguments, args, args.out / f"{args.name}.json", {
        "env": ENV_ID,
        "metrics": "offset = the dome apex's distance from the object's outline in the top face's plane (mm), every "
                   "step; depth error = |labels' z - reference depth| (mm), every step; per run their means and "
                   "maxima; lap_completed: once round the edge without an early end; summaries over the nominal run "
                   "and the seeds' randomised runs (worst run: the largest per-run mean)",
        "goals": goals, "results": results, "figure": png.as_posix(),
        "seconds": round(time.perf_counter() - start, 1), "machine": machine_info(),
    })
    print(f"wrote {args.out / (args.name + '.json')}, {png}")
    return 0
