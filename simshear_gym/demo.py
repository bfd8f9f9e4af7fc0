"""``simshear demo``: the embedded default job: tactile servoing in simulation on shipped weights, no data needed.

Runs the tactile servo controller (:class:`~simshear_gym.control.servo.ServoController`: the shipped GDNN reads
depth and shear from each tactile image, the Bayesian filter fuses the readings, a PI law moves the follower) on
the four ``SimShearTracking-v0`` trajectories with ``obs_mode="real"`` (the shipped shPix2pix turns every sim
image into a real-looking TacTip image), prints the contact error per trajectory and writes the paper-style
figure (leader path red, follower blue) to ``--out``. The full benchmark with seeds, co-lift and the estimator
variants is ``simshear evaluate servo``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

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
    from simshear_gym.evaluate.servo import figure, run_episode

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
        paths[trajectory] = (target, sensor, result["contact_error_mean_mm"])
        print(f"{trajectory:14s} {result['steps']:5d} {result['contact_error_mean_mm']:13.3f} +- "
              f"{result['contact_error_std_mm']:.3f} {result['contact_error_max_mm']:7.2f} "
              f"{result['steps_out_of_contact']:14d} {result['control_ms_median']:10.2f} "
              f"{result['env_step_ms_median']:11.2f}" + (f"  ended: {result['termination']}"
                                                         if result["termination"] else ""))
    png = args.out / "tracking.png"
    figure(paths, png, "SimShearTracking-v0, tactile servo controller (shipped weights)")
    print(f"wrote {png} ({time.perf_counter() - start:.0f} s)")
    return 0
