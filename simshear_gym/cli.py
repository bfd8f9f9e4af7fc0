"""The ``simshear`` command.

Each sub-command lives in the module that owns the work; this file only routes. A command module exposes
``add_arguments(parser)`` and ``run(args) -> int``; it imports heavy dependencies (torch, pybullet) inside
``run`` so that building the parser stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# (command words, module, one-line help)
COMMANDS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("demo",), "simshear_gym.demo", "the default job: simulated TacTip contacts with shear, no data needed"),
    (("collect",), "simshear_gym.pipelines.collect", "render paired (sim image, shear, real image) sets"),
    (("collect-env",), "simshear_gym.pipelines.env_collect",
     "labelled translated images from a SimShear env (its own estimator's training set)"),
    (("evaluate", "render"), "simshear_gym.evaluate.render_agreement",
     "compare our sim renders with the published Tactile Gym sim images"),
    (("evaluate", "collect-speed"), "simshear_gym.evaluate.collect_speed",
     "benchmark paired tuples per second of the collection"),
    (("train", "translator"), "simshear_gym.train.translator",
     "train the shPix2pix or pix2pix sim-to-real translator on paired sets"),
    (("evaluate", "translation"), "simshear_gym.evaluate.translation",
     "MAPE / SSIM of translators on the real validation images, with reference rows"),
    (("evaluate", "translator-speed"), "simshear_gym.evaluate.translator_speed",
     "translator latency per image at batch 1 and 32"),
    (("evaluate", "training-curve"), "simshear_gym.evaluate.training_curve",
     "quality against training time of translator runs"),
    (("mg400-emulator",), "simshear_gym.real.mg400_emulator",
     "run a loopback Dobot MG400 emulator (dashboard, motion, feedback ports) until Ctrl-C"),
    (("train", "export-translator"), "simshear_gym.pipelines.export_translator",
     "ship a translator run as fp16 weights with a check figure"),
    (("train", "posenet"), "simshear_gym.train.posenet",
     "train the pose-and-shear GDNN on real, sim or translated images of paired sets"),
    (("train", "export-posenet"), "simshear_gym.pipelines.export_posenet",
     "ship a posenet run's best GDNN with its model card"),
    (("train", "rl"), "simshear_gym.train.rl",
     "train a PPO or SAC agent on SimShearTracking-v0 (translated images, randomised trajectories)"),
    (("evaluate", "posenet"), "simshear_gym.evaluate.posenet",
     "pose-and-shear GDNN errors on the real validation images, against chance"),
    (("evaluate", "filter"), "simshear_gym.evaluate.posenet_filter",
     "the Bayesian filter against raw GDNN readings on simulated, translated contact sequences"),
    (("evaluate", "camera"), "simshear_gym.evaluate.camera_calibration",
     "calibrate the TacTip camera preprocessing on raw frames against the published processed images"),
    (("evaluate", "oracle"), "simshear_gym.evaluate.oracle",
     "contact error of the oracle controller on every tracking trajectory (--tasks colift: every co-lift run)"),
    (("evaluate", "servo"), "simshear_gym.evaluate.servo",
     "closed-loop tracking and co-lift benchmarks of the tactile servo controller"),
    (("evaluate", "env-speed"), "simshear_gym.evaluate.env_speed",
     "steps per second of SimShearTracking-v0 (real images), one process and vectorised"),
    (("rollout",), "simshear_gym.real.rollout",
     "run the servo controller or an SB3 policy on the real (or emulated) MG400 with the TacTip, logging every step"),
    (("evaluate", "real-cycle"), "simshear_gym.evaluate.real_cycle",
     "compute per control cycle of the real path: preprocess, estimator, filter, servo law, ServoP to the emulator"),
)


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="simshear", description="simshear-gym: sim-to-real tactile robotics with shear")
    groups: dict[tuple[str, ...], argparse._SubParsersAction] = {(): parser.add_subparsers(dest="command", required=True)}
    for words, module, help_text in COMMANDS:
        for depth in range(1, len(words)):
            prefix = words[:depth]
            if prefix not in groups:
                sub = groups[words[: depth - 1]].add_parser(words[depth - 1], help=f"{words[depth - 1]} commands")
                groups[prefix] = sub.add_subparsers(dest=f"command_{depth}", required=True)
        sub = groups[words[:-1]].add_parser(words[-1], help=help_text, description=help_text)
        sub.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except (ValueError, FileNotFoundError) as error:  # library errors carry their own explanation
        print(f"simshear: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
