"""The ``simshear`` command.

Each sub-command lives in the module that owns the work; this file only routes. A command module exposes
``add_arguments(parser)`` and ``run(args) -> int``, and keeps torch and pybullet out of its module-level imports
(they go inside ``run`` or the engine functions it calls).

The parser is built lazily: every level lists its sub-commands with the help strings of :data:`COMMANDS`, but
only the command that the argument list names gets its options, so ``simshear --help`` and
``simshear evaluate --help`` import no command module and ``simshear evaluate posenet ...`` imports only
:mod:`simshear_gym.evaluate.posenet`.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from collections.abc import Sequence

# (command words, module, one-line help)
COMMANDS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("demo",), "simshear_gym.demo",
     "the default job: the tactile servo controller tracks the four paths in sim on shipped weights, no data "
     "needed (figure: paths and where the error is)"),
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
    (("evaluate", "train-speed"), "simshear_gym.evaluate.train_speed",
     "training step time of the GDNN and translator trainers, default layout against channels_last"),
    (("evaluate", "training-curve"), "simshear_gym.evaluate.training_curve",
     "quality against training time of translator runs"),
    (("mg400-emulator",), "simshear_gym.real.mg400_emulator",
     "run a loopback Dobot MG400 emulator (dashboard, motion, feedback ports) until Ctrl-C"),
    (("train", "posenet"), "simshear_gym.train.posenet",
     "train the pose-and-shear GDNN on real, sim or translated images of paired sets"),
    (("train", "rl"), "simshear_gym.train.rl",
     "train a PPO, SAC or TQC agent on the tracking, co-lift, edge following or pushing env (--preset "
     "tracking-first: a first tracking policy on a 2-core CPU)"),
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
    (("evaluate", "edge-follow"), "simshear_gym.evaluate.edge_follow",
     "edge following on SimShearEdgeFollow-v0: the edge servo (translated images, edge GDNN) once round four outlines"),
    (("evaluate", "push"), "simshear_gym.evaluate.push",
     "pushing on SimShearPush-v0: the push servo (translated images, surface GDNN) with and without its shear term"),
    (("evaluate", "servo6d"), "simshear_gym.evaluate.servo6d",
     "6-DoF servo (Panda) against the 4-DoF MG400 servo on the tilting plate of SimShearTracking6D-v0"),
    (("evaluate", "env-speed"), "simshear_gym.evaluate.env_speed",
     "steps per second of SimShearTracking-v0 (real images), one process and vectorised"),
    (("rollout",), "simshear_gym.real.rollout",
     "run the servo controller or an SB3 policy on the real (or emulated) MG400 with the TacTip, logging every step"),
    (("experiment", "tracking"), "simshear_gym.lab.experiment",
     "the paper's two-arm tracking experiment: a leader MG400 moves the plate, the follower servos on the TacTip"),
    (("experiment", "colift"), "simshear_gym.lab.colift",
     "the paper's co-lift experiment: leader and follower carry an object between plate and horizontal TacTip"),
    (("collect-real",), "simshear_gym.pipelines.collect_real",
     "record a sensor's tap and shear data set with the MG400 from its config's [collect] protocol (or rehearse it)"),
    (("calibrate-arms",), "simshear_gym.lab.calibrate",
     "the leader MG400's base in the follower's frame, by touching the leader's plate (or from a fixture)"),
    (("evaluate", "collect-real"), "simshear_gym.evaluate.collect_real",
     "collect-real rehearsed on an emulated MG400, killed at a random row and rerun: rows, images, limits, row time"),
    (("evaluate", "experiment"), "simshear_gym.evaluate.experiment",
     "the two-arm experiments rehearsed (--tasks tracking colift): contact error, contact loss or drop, loop rate"),
    (("evaluate", "real-cycle"), "simshear_gym.evaluate.real_cycle",
     "compute per control cycle of the real path: preprocess, estimator, filter, servo law, ServoP to the emulator"),
    (("evaluate", "soak"), "simshear_gym.evaluate.soak",
     "fault soak of the real path: the servo controller on the MG400 emulator for 10,000 cycles, faults injected"),
    (("evaluate", "safety-bursts"), "simshear_gym.evaluate.safety_bursts",
     "bursts of individually valid ServoP / MovL on two emulated MG400s: motions faster than the limits"),
    (("pipeline", "check"), "simshear_gym.pipelines.check",
     "validate a sensor's experiment config and its data before anything trains"),
    (("pipeline", "estimate"), "simshear_gym.pipelines.estimate",
     "how long a profile's training takes on this machine, from short probes of its trainers"),
    (("pipeline", "compare"), "simshear_gym.pipelines.evaluation",
     "a finished pipeline run's models against another run's, figure by figure (MAPE, GDNN MAE, ratios)"),
    (("pipeline", "run"), "simshear_gym.pipelines.run",
     "from a sensor's data set to its models: adapt, replay, translators, GDNNs, evaluation (cached stages)"),
    (("pipeline", "sweep"), "simshear_gym.pipelines.sweep",
     "how many real rows the chain needs: translator and GDNNs trained on the first N real rows, per budget"),
    (("pipeline", "env-model"), "simshear_gym.pipelines.env_model",
     "an env GDNN (the co-lift estimator) from its [env_models.<name>] recipe: env sets, one DAgger round, training"),
    (("pipeline", "make-example"), "simshear_gym.pipelines.example_sensor",
     "write the example second lab's data set (configs/example_lab.toml) from the real tactip331 images"),
    (("ship", "translator"), "simshear_gym.ship.translator",
     "ship a translator run as fp16 weights with a check figure"),
    (("ship", "posenet"), "simshear_gym.ship.posenet",
     "ship a posenet run's best GDNN with its model card"),
    (("ship", "onnx"), "simshear_gym.ship.onnx",
     "export shipped translator weights to ONNX (run by onnxruntime in the envs), with a check and a card"),
    (("ship", "policy"), "simshear_gym.ship.policy",
     "ship a simshear train rl policy (model, normalisation, settings) with its model card"),
    (("ship", "run"), "simshear_gym.ship.run",
     "make a finished pipeline run's translators and GDNNs the package's shipped weights, with cards"),
    (("ship", "recheck-posenet"), "simshear_gym.ship.recheck_posenet",
     "measure a shipped GDNN's check figure again (after a new translator) and record it in its file and card"),
    (("ship", "zoo"), "simshear_gym.ship.zoo",
     "every shipped model as a Hugging Face Hub folder (config.json, model.safetensors, README.md), checked"),
)

# Old command words -> the command they name now. Each stays a command of its own (the same module, so the same
# options and output) for one release, so that the command lines recorded in results/ and the cards still run.
ALIASES: dict[tuple[str, ...], tuple[str, ...]] = {
    ("train", "export-translator"): ("ship", "translator"),
    ("train", "export-posenet"): ("ship", "posenet"),
    ("train", "export-onnx"): ("ship", "onnx"),
    ("train", "export-policy"): ("ship", "policy"),
    ("train", "recheck-posenet"): ("ship", "recheck-posenet"),
    ("pipeline", "ship"): ("ship", "run"),
}


def _alias_rows() -> tuple[tuple[tuple[str, ...], str, str], ...]:
    named = {words: (module, help_text) for words, module, help_text in COMMANDS}
    return tuple((old, named[new][0], f"{named[new][1]} (alias of simshear {' '.join(new)}; kept for one release)")
                 for old, new in ALIASES.items())


COMMANDS += _alias_rows()


# the groups of several commands: their one-line help
GROUPS: dict[str, str] = {
    "evaluate": "benchmarks and evaluations, each writing its record under results/",
    "train": "train the translator, the pose-and-shear GDNN and RL agents",
    "pipeline": "a sensor's experiment config: check it, run its cached pipeline (simshear ship run ships its models)",
    "ship": "make a run's translator, GDNN, ONNX export or policy (or a whole pipeline run) shipped weights with "
            "cards; the shipped models as Hugging Face Hub folders",
    "experiment": "the paper's two-arm experiments on two MG400s (or the rehearsal rig)",
}

_LEAVES: dict[tuple[str, ...], str] = {words: module for words, module, _ in COMMANDS}


def _children(prefix: tuple[str, ...]) -> dict[str, str]:
    """The words one level below ``prefix`` with their help, in the order of :data:`COMMANDS`."""
    children: dict[str, str] = {}
    for words, _, help_text in COMMANDS:
        if len(words) > len(prefix) and words[:len(prefix)] == prefix:
            word = words[len(prefix)]
            if word not in children:
                children[word] = help_text if len(words) == len(prefix) + 1 else GROUPS.get(word, f"{word} commands")
    return children


def _fill(parser: argparse.ArgumentParser, prefix: tuple[str, ...], rest: Sequence[str]) -> None:
    """Give ``parser`` (the parser of the words ``prefix``) its options: a command module's, or the sub-commands
    of a group, of which only the one named by ``rest[0]`` is filled in turn."""
    module = _LEAVES.get(prefix)
    if module is not None:
        parser.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(parser)
        return
    subparsers = parser.add_subparsers(dest=f"command_{len(prefix)}" if prefix else "command", required=True,
                                       metavar="COMMAND", title="commands")
    for word, help_text in _children(prefix).items():
        sub = subparsers.add_parser(word, help=help_text, description=help_text)
        if rest and rest[0] == word:
            _fill(sub, prefix + (word,), rest[1:])


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The ``simshear`` parser for the argument list ``argv``: it lists every command, and its leading words
    (``evaluate posenet ...``) choose the one command whose module is imported for its options."""
    parser = argparse.ArgumentParser(prog="simshear",
                                     description="simshear-gym: sim-to-real tactile robotics with shear",
                                     epilog="'simshear COMMAND --help' shows the options of a command.")
    _fill(parser, (), list(argv))
    return parser


def command_parser(words: Sequence[str]) -> argparse.ArgumentParser:
    """The parser of one command of :data:`COMMANDS` (its module is imported), e.g. ``("evaluate", "posenet")``."""
    words = tuple(words)
    if words not in _LEAVES:
        raise ValueError(f"no simshear command {' '.join(words)!r}")
    parser = build_parser(words)
    for word in words:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[word]
    return parser


# Errors that say what was wrong with the input or the setup (a file, a column, a host, a camera), raised by the
# library with a message that names it: the CLI prints them as one line. Besides ValueError and OSError (missing
# files, refused connections, timeouts), these, looked up only when their module is loaded (so that this module
# imports none of them):
INPUT_ERRORS: tuple[tuple[str, str], ...] = (
    ("simshear_gym.real.camera", "CameraError"),
    ("simshear_gym.real.safety", "SafetyError"),
    ("simshear_gym.real.env", "RealEnvError"),
    ("simshear_gym.real.mg400_client", "MG400Error"),
    ("simshear_gym.real.mg400_client", "FeedbackStaleError"),
    ("simshear_gym.lab.experiment", "ExperimentError"),
    ("simshear_gym.lab.calibrate", "CalibrationError"),
    ("simshear_gym.lab.collect_real", "CollectError"),
    ("simshear_gym.sim.parallel", "ExecutorError"),
    ("simshear_gym.pipelines.stages", "StageStopped"),
)


def is_input_error(error: BaseException) -> bool:
    """Whether ``error`` reports bad input or an unusable setup (one ``simshear: error:`` line), not a bug."""
    if isinstance(error, (ValueError, OSError)):
        return True
    for module_name, class_name in INPUT_ERRORS:
        module = sys.modules.get(module_name)
        error_type = getattr(module, class_name, None) if module is not None else None
        if error_type is not None and isinstance(error, error_type):
            return True
    return False


def error_line(error: BaseException) -> str:
    """The one line the CLI prints for ``error``."""
    text = "; ".join(line.strip() for line in str(error).splitlines() if line.strip())
    return f"simshear: error: {text or type(error).__name__}"


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(argv).parse_args(argv)
    module = importlib.import_module(args._module)
    from simshear_gym.pipelines.stages import RunStopped, end_children, stop_on_signals

    try:
        # SIGTERM (a scheduler, kill) and SIGINT become RunStopped: every command's finally blocks run (an arm's
        # client closes, logs are written) and the worker processes it started end with it
        with stop_on_signals():
            return int(module.run(args) or 0)
    except RunStopped as stopped:
        ended = end_children()
        print(f"simshear: stopped by {signal.Signals(stopped.signum).name}"
              + (f"; {ended} worker process{'es' if ended != 1 else ''} ended" if ended else ""), file=sys.stderr)
        return 128 + stopped.signum
    except Exception as error:  # library errors carry their own explanation; anything else is a bug: traceback
        if not is_input_error(error):
            raise
        print(error_line(error), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
