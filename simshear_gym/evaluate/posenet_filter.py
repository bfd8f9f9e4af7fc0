"""The Bayesian filter on simulated contact sequences: filtered against unfiltered GDNN estimates, and the lag.

``simshear evaluate filter --model surface=PATH --model edge=PATH`` builds, per contact type and speed, a sequence
of contacts (:func:`contact_sequence`): the sensor slides and rotates over the stimulus while its depth and tilt
(surface) or its offset, depth and angle to the edge (edge) change smoothly. Each step is labelled exactly like a
row of the real sets (a ``pose`` and a ``move`` since touching; :mod:`simshear_gym.data.labels`), rendered by our
sim (:class:`simshear_gym.sim.replay.ReplayScene`), given its shear by the shear tracker
(:func:`simshear_gym.sim.shear.replay_shear`), and translated by the shipped shPix2pix of that contact type: the
images a follower sees in the envs. The GDNN reads each image; the discriminative Kalman filter
(:mod:`simshear_gym.models.bayes_filter`) fuses the readings with the motion model driven by the commanded motion,
here the change of the labels between steps (the robot knows its own move exactly; what it does not know is where
the contact is).

Per variable it reports the MAE of the raw GDNN means and of the filtered means (mm / deg), the reduction, and
lags: the shift k in 0..``max_lag`` steps that minimises ``MAE(estimate[t], truth[t - k])`` (0 = no lag).
``filter_lag_steps`` is the lag of the filter's dynamics alone: the filter fed the exact labels with the network's
stds, so no reading error can hide or mimic a lag. ``filtered_lag_steps`` is the same on the real readings; where the
motion per step is smaller than the estimate's error it only says that no shift explains the error better. Writes
``results/posenet_filter.json`` (with the command) and ``results/posenet_filter.png`` (truth, raw, filtered over
time).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simshear_gym.data.labels import CONTACT_TYPES
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.model_specs import parse_contact_paths
from simshear_gym.evaluate.records import write_record
from simshear_gym.io import recorded_path


@dataclass(frozen=True)
class SequenceConfig:
    """One simulated contact sequence: a full cycle of smooth motion in ``steps`` steps.

    Attributes:
        contact: ``surface`` | ``edge``.
        steps: steps per cycle; fewer steps = faster motion (largest per-step move: about
            ``2 pi slide_mm / steps`` mm).
        slide_mm: amplitude of the slide (the move since touching) in x and y, mm (the data's moves span +-5).
        twist_deg: amplitude of the rotation about the sensor axis since touching, deg.
    """

    contact: str = "surface"
    steps: int = 200
    slide_mm: float = 4.0
    twist_deg: float = 4.0

    def __post_init__(self) -> None:
        if self.contact not in CONTACT_TYPES:
            raise ValueError(f"contact must be one of {CONTACT_TYPES}, got {self.contact!r}")
        if self.steps < 8:
            raise ValueError(f"steps must be >= 8, got {self.steps}")
        if not (0 <= self.slide_mm <= 5 and 0 <= self.twist_deg <= 5):
            raise ValueError(f"slide_mm and twist_deg must be in [0, 5] (the data's range), got {self.slide_mm}, "
                             f"{self.twist_deg}")


@dataclass(frozen=True)
class FilterSettings:
    """Filter settings.

    Attributes:
        process_std_mm: motion-model noise (the commanded move's error per step) of variables in mm.
        process_std_deg: the same for variables in deg.
        divide_prior: divide the training labels' spread (uniform over the collection range, as a Gaussian) out
            of every reading, the discriminative Kalman update; False: the plain Kalman update (infinite prior).
            Default False: our motion model is a random walk driven by the commanded move, which has no stationary
            distribution for the prior to stand for, and dividing the same prior out at every step makes the
            estimate drift away from the range centre (measured: a 1-step lag on exact readings).
    """

    process_std_mm: float = 0.05
    process_std_deg: float = 0.3
    divide_prior: bool = False


def contact_sequence(config: SequenceConfig) -> tuple[np.ndarray, np.ndarray]:
    """(poses (T, 6), moves (T, 6)) in the labels' convention (x, y, z mm, Rx, Ry, Rz deg); move 0 at touch."""
    phase = 2.0 * math.pi * np.arange(config.steps) / config.steps
    poses = np.zeros((config.steps, 6))
    moves = np.zeros((config.steps, 6))
    moves[:, 0] = config.slide_mm * np.sin(phase)  # a figure of eight, from the touch point
    moves[:, 1] = config.slide_mm * np.sin(2.0 * phase)
    moves[:, 5] = config.twist_deg * np.sin(3.0 * phase)
    if config.contact == "surface":
        poses[:, 2] = 4.0 + 1.2 * np.sin(2.0 * phase)  # depth 2.8..5.2 mm (data 2.5..5.5)
        poses[:, 3] = 10.0 * np.sin(phase)  # tilt within +-10 deg (data +-15)
        poses[:, 4] = 10.0 * np.sin(phase + 1.0)
    else:
        poses[:, 1] = 4.0 * np.sin(phase)  # offset across the edge (data +-6)
        poses[:, 2] = 4.0 + 0.7 * np.sin(2.0 * phase)  # depth 3.3..4.7 (data 3..5)
        poses[:, 5] = np.remainder(120.0 + 120.0 * phase / (2.0 * math.pi) + 180.0, 360.0) - 180.0  # crosses 180
    return poses, moves


def sequence_images(config: SequenceConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(poses, shear (T, 6) sensor frame, translated uint8 images (T, H, W)) of a sequence."""
    from simshear_gym.models.translator import translate_rows
    from simshear_gym.models.zoo import load_shipped_translator
    from simshear_gym.sim.replay import ReplayScene
    from simshear_gym.sim.shear import ShearTrackerConfig, replay_shear

    poses, moves = contact_sequence(config)
    with ReplayScene(config.contact) as scene:
        sim = np.stack([scene.render(pose) for pose in poses])
    shear = replay_shear(poses, moves, ShearTrackerConfig())
    translator = load_shipped_translator(config.contact)
    images = translate_rows(translator, sim, shear, 32)
    return poses, shear, images


def run_filter(mean: np.ndarray, std: np.ndarray, truth: np.ndarray, variables,
               settings: FilterSettings = FilterSettings()) -> tuple[np.ndarray, np.ndarray]:
    """Filter GDNN readings (T, V) over a sequence; the commanded move is the change of ``truth``.

    Returns (filtered means (T, V), filtered stds (T, V)). Starts from the first reading.
    """
    from simshear_gym.data.labels import wrap_deg
    from simshear_gym.models.bayes_filter import (
        BayesFilterConfig,
        DiscriminativeKalmanFilter,
    )

    specs = variables.variables
    process = [settings.process_std_mm if spec.unit == "mm" else settings.process_std_deg for spec in specs]
    overrides = {} if settings.divide_prior else {"prior_std": tuple(math.inf for _ in specs)}
    kalman = DiscriminativeKalmanFilter(BayesFilterConfig.from_output_specs(specs, process, **overrides))
    periodic = np.array([spec.periodic for spec in specs])
    kalman.reset(mean[0], np.diag(std[0] ** 2))
    means, stds = [kalman.mean], [kalman.std]
    for t in range(1, len(mean)):
        delta = truth[t] - truth[t - 1]
        delta[periodic] = wrap_deg(delta[periodic])
        filtered_mean, filtered_std = kalman.step(delta, mean[t], std[t])
        means.append(filtered_mean)
        stds.append(filtered_std)
    return np.stack(means), np.stack(stds)


def lag_steps(estimate: np.ndarray, truth: np.ndarray, periodic: bool, max_lag: int) -> int:
    """The k in 0..max_lag minimising mean |estimate[t] - truth[t - k]| over the common steps."""
    from simshear_gym.data.labels import wrap_deg

    costs = []
    for k in range(max_lag + 1):
        error = estimate[k:] - truth[:len(truth) - k]
        costs.append(np.abs(wrap_deg(error) if periodic else error).mean())
    return int(np.argmin(costs))


def evaluate_sequence(model_path: Path, config: SequenceConfig, settings: FilterSettings, max_lag: int = 5) -> dict:
    from simshear_gym.evaluate.metrics import errors, pose_shear_labels
    from simshear_gym.models.gdnn_input import predict
    from simshear_gym.models.posenet_io import load_posenet

    model, _ = load_posenet(model_path)
    variables = model.variables
    if variables.name != config.contact:
        raise ValueError(f"{model_path}: predicts the {variables.name!r} variables, not {config.contact!r}")
    poses, shear, images = sequence_images(config)
    truth = pose_shear_labels(poses, shear, variables)
    mean_encoded, std_encoded = predict(model, images)
    raw_mean, raw_std = (t.numpy().astype(np.float64) for t in variables.decode(mean_encoded, std_encoded))
    filtered_mean, filtered_std = run_filter(raw_mean, raw_std, truth, variables, settings)
    exact_filtered, _ = run_filter(truth.astype(np.float64), raw_std, truth, variables, settings)
    raw_error = np.abs(errors(raw_mean, truth, variables))
    filtered_error = np.abs(errors(filtered_mean, truth, variables))
    step_change = np.abs(errors(truth[1:], truth[:-1], variables))
    per_variable = {}
    for i, spec in enumerate(variables.variables):
        raw, filtered = float(raw_error[:, i].mean()), float(filtered_error[:, i].mean())
        per_variable[spec.name] = {
            "unit": spec.unit, "raw_mae": raw, "filtered_mae": filtered,
            "reduction": 1.0 - filtered / raw if raw > 0 else 0.0,
            "raw_lag_steps": lag_steps(raw_mean[:, i], truth[:, i], spec.periodic, max_lag),
            "filtered_lag_steps": lag_steps(filtered_mean[:, i], truth[:, i], spec.periodic, max_lag),
            "filter_lag_steps": lag_steps(exact_filtered[:, i], truth[:, i], spec.periodic, max_lag),
            "max_change_per_step": float(step_change[:, i].max()),
        }
    return {"steps": config.steps, "slide_mm": config.slide_mm, "twist_deg": config.twist_deg,
            "variables": per_variable,
            "_series": (variables, truth, raw_mean, filtered_mean)}


def figure(series: dict, path: Path) -> None:
    """One row per (contact, speed), one panel per variable: truth, raw and filtered over the steps."""
    plt = pyplot()

    keys = list(series)
    columns = max(variables.dim for variables, *_ in series.values())
    fig, axes = plt.subplots(len(keys), columns, figsize=(2.4 * columns, 2.0 * len(keys)), squeeze=False)
    for r, key in enumerate(keys):
        variables, truth, raw, filtered = series[key]
        for c, spec in enumerate(variables.variables):
            axis = axes[r, c]
            axis.plot(raw[:, c], ".", ms=2, color="0.6", label="GDNN")
            axis.plot(filtered[:, c], "-", lw=1, color="tab:blue", label="filtered")
            axis.plot(truth[:, c], "-", lw=1, color="tab:red", label="true")
            axis.set_title(f"{key}: {spec.name}" if c == 0 else spec.name, fontsize=7)
            axis.tick_params(labelsize=6)
        axes[r, 0].legend(fontsize=5)
    save_figure(fig, path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", action="append", required=True, metavar="CONTACT=PATH",
                        help="a posenet weights file per contact type, e.g. surface=runs/pn/surface_shpix2pix/best.pt;"
                             " CONTACT=shipped for the shipped one")
    parser.add_argument("--steps", type=int, nargs="+", default=[200, 50],
                        help="steps per motion cycle, one sequence each (fewer = faster), default 200 50")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory (default results)")
    parser.add_argument("--name", default="posenet_filter",
                        help="base name of the json and png written (default posenet_filter)")


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(args.threads)
    models = parse_contact_paths(args.model, "--model")
    for contact, path in list(models.items()):
        if str(path) == "shipped":
            from simshear_gym.models.zoo import posenet_weights

            models[contact] = posenet_weights(contact)
    start = time.perf_counter()
    settings = FilterSettings()
    results, series = {}, {}
    for contact, path in models.items():
        for steps in args.steps:
            key = f"{contact}_{steps}steps"
            result = evaluate_sequence(path, SequenceConfig(contact=contact, steps=steps), settings)
            series[key] = result.pop("_series")
            results[key] = {"model": recorded_path(path), **result}
            print(f"{key}:")
            for name, figures in result["variables"].items():
                print(f"  {name:16s} MAE raw {figures['raw_mae']:7.3f} filtered {figures['filtered_mae']:7.3f} "
                      f"({100 * figures['reduction']:+5.1f} %), filter lag {figures['filter_lag_steps']} steps, "
                      f"max change/step {figures['max_change_per_step']:.3f}")
    png = args.out / f"{args.name}.png"
    figure(series, png)
    write_record("simshear evaluate filter", add_arguments, args, args.out / f"{args.name}.json", {
        "sequences": "our sim renders of a sliding, rotating contact with changing depth/tilt (surface) or "
                     "offset/depth/angle (edge), shear from the tracker, translated by the shipped shPix2pix",
        "filter": {"process_std_mm": settings.process_std_mm, "process_std_deg": settings.process_std_deg,
                   "divide_prior": settings.divide_prior,
                   "motion_model": "commanded move = change of the labels between steps"},
        "metrics": "MAE in mm/deg of GDNN means (raw) and filtered means; reduction = 1 - filtered/raw; "
                   "lag = shift in steps minimising the MAE against the truth",
        "results": results, "figure": str(png), "seconds": round(time.perf_counter() - start, 1),
    })
    print(f"wrote {args.out / (args.name + '.json')} and {png}")
    return 0
