"""``simshear demo``: the embedded default job: tactile servoing in simulation on shipped weights, no data needed.

Runs the tactile servo controller (:class:`~simshear_gym.control.servo.ServoController`: the shipped GDNN reads
depth and shear from each tactile image, the Bayesian filter fuses the readings, a PI law moves the follower) on
the four ``SimShearTracking-v0`` trajectories with ``obs_mode="real"`` (the shipped shPix2pix turns every sim
image into a real-looking TacTip image), prints the contact error per trajectory and writes a figure to ``--out``
(``tracking.png``), one column per trajectory: the paper-style 3-D paths (leader red, follower blue; a fraction of a
millimetre apart, so they lie on top of each other), the leader's path seen from above coloured by the contact error
at each step (where along the path the error is), and the error over time. The full benchmark with seeds, co-lift
and the estimator variants is ``simshear evaluate servo``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.figures import pyplot, save_figure

TRAJECTORIES = ("circle", "tilted_square", "spiral", "loop")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory")
    parser.add_argument("--trajectories", nargs="+", default=list(TRAJECTORIES), choices=TRAJECTORIES,
                        help="SimShearTracking-v0 trajectories to follow, one episode each (default all four)")
    parser.add_argument("--max-steps", type=int, default=None, help="cap per episode (default: the whole path)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym
    import torch

    import simshear_gym.envs  # noqa: F401  (registers the envs)
    from simshear_gym.control.servo import ServoController
    from simshear_gym.evaluate.servo import run_episode

    torch.set_num_threads(args.threads)
    print("Tactile servoing on SimShearTracking-v0: shPix2pix images -> shipped GDNN + filter -> PI law")
    print(f"{'trajectory':14s} {'steps':>5s} {'error mm (mean +- std)':>23s} {'max mm':>7s} {'out of contact':>14s} "
          f"{'control ms':>10s} {'env step ms':>11s}")
    paths = {}
    start = time.perf_counter()
    for trajectory in args.trajectories:
        env = gym.make("SimShearTracking-v0", trajectory=trajectory, obs_mode="real")
        controller = ServoController.for_env(env)
        result = run_episode(env, controller, seed=0, max_steps=args.max_steps)
        env.close()
        target, sensor = result.pop("_paths")
        paths[trajectory] = (target, sensor, result.pop("_errors_mm"))
        period_s = 1.0 / env.unwrapped.control_rate_hz
        print(f"{trajectory:14s} {result['steps']:5d} {result['contact_error_mean_mm']:13.3f} +- "
              f"{result['contact_error_std_mm']:.3f} {result['contact_error_max_mm']:7.2f} "
              f"{result['steps_out_of_contact']:14d} {result['control_ms_median']:10.2f} "
              f"{result['env_step_ms_median']:11.2f}" + (f"  ended: {result['termination']}"
                                                         if result["termination"] else ""))
    png = args.out / "tracking.png"
    figure(paths, png, "SimShearTracking-v0, tactile servo controller (shipped weights)", period_s)
    print(f"wrote {png} ({time.perf_counter() - start:.0f} s)")
    return 0


def figure(runs: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path, title: str,
           period_s: float) -> None:
    """One column per run (name -> (target (T, 3), sensor (T, 3) world mm, contact error (T,) mm per step)): the
    3-D paths, the target path from above (x, y mm from its start) coloured by the error on one scale for all
    runs, and the error against time (steps of ``period_s``) with its mean."""
    from simshear_gym.evaluate.servo import path_panel

    plt = pyplot()

    names = list(runs)
    top = max(float(np.max(errors)) for _, _, errors in runs.values())
    fig = plt.figure(figsize=(3.6 * len(names), 8.8))
    grid = fig.add_gridspec(3, len(names), height_ratios=(1.2, 1.0, 0.7), wspace=0.4, hspace=0.35)
    for column, name in enumerate(names):
        target, sensor, errors = runs[name]
        path_panel(fig.add_subplot(grid[0, column], projection="3d"), target, sensor,
                   f"{name}\nerror {errors.mean():.2f} mm (max {errors.max():.2f})")
        above = fig.add_subplot(grid[1, column])
        xy = target[:, :2] - target[0, :2]
        above.plot(*xy.T, color="0.8", lw=0.6, zorder=1)
        dots = above.scatter(*xy.T, c=errors, s=6, cmap="viridis", vmin=0.0, vmax=top, zorder=2)
        above.set_aspect("equal", adjustable="datalim")
        above.set_title("error along the path (from above)", fontsize=7)
        above.set_xlabel("x mm", fontsize=6)
        above.set_ylabel("y mm", fontsize=6)
        above.tick_params(labelsize=5)
        over_time = fig.add_subplot(grid[2, column])
        seconds = period_s * np.arange(1, len(errors) + 1)
        over_time.plot(seconds, errors, color="tab:blue", lw=0.8)
        over_time.axhline(errors.mean(), color="k", lw=0.6, ls=":", label=f"mean {errors.mean():.2f} mm")
        over_time.set_ylim(0.0, top * 1.05)
        over_time.set_xlabel("time s", fontsize=6)
        over_time.set_ylabel("contact error mm", fontsize=6)
        over_time.tick_params(labelsize=5)
        over_time.legend(fontsize=5, loc="upper right")
    fig.axes[0].legend(fontsize=6, loc="upper left")
    fig.colorbar(dots, ax=[axis for axis in fig.axes if axis.get_title().startswith("error along")],
                 label="contact error mm", shrink=0.8)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path, tight=False)
