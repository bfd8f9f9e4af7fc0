"""Closed-loop benchmarks of the tactile servo controller: the paper's tracking and co-lift runs.

``simshear evaluate servo`` runs :class:`~simshear_gym.control.servo.ServoController` (tactile image -> GDNN + filter
-> PI law; it never reads ground truth) on every trajectory of ``SimShearTracking-v0`` and every object x
trajectory of ``SimShearCoLift-v0`` (``--tasks colift-heavy``: its heavy objects, ``payload="heavy"``, where the
servo holds the load's shear: ``--hold-load``), in a nominal run and randomised runs (one per seed: the env draws the
trajectory's scale, speed, turn and the start place; co-lift turns the plate only with
``--colift-rotation-deg``), with estimator variants:

- ``shpix2pix``: the env's translated images (``obs_mode="real"``), the shipped GDNN (trained on shPix2pix images);
- ``pix2pix``: the same images, a GDNN trained on pix2pix-generated images (``--posenet-pix2pix``);
- ``sim``: raw sim images (``obs_mode="sim"``), a GDNN trained on raw sim images (``--posenet-sim``);
- ``oracle``: the true depth and shear into the oracle law (the task's floor, not a tactile controller);
- ``policy``, ``ppo``, ``sac``, ``tqc``: an SB3 agent of ``simshear train rl`` (``--policy``, ``--policy-ppo``,
  ``--policy-sac``, ``--policy-tqc``: its ``model.zip``, ``best_model.zip`` or a checkpoint), in the env settings
  it was trained with (its run's ``config.json``: observation, history, image source and size), its observations
  normalised by the run's ``VecNormalize`` statistics and, for a residual policy, its correction added to the
  servo law (:meth:`~simshear_gym.control.policy.SB3Controller.load`); ``ppo``, ``sac``, ``tqc`` check the zip's
  algorithm, so agents compare side by side.

Per run: contact error mean, std and max (mm; the env's ``info["contact_error_mm"]`` every step), steps out of
contact, whether it ended early (``termination``) and, for co-lift, whether the object dropped. Also the control
loop's compute per step (estimator + filter + law) and the whole env step. Writes ``results/servo.json`` (with
the command) and figures like the paper's: leader path (the follower's target point) red, follower sensor blue,
3D, the mean error in the title (``results/servo_<task>.png``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from simshear_gym.control.estimator import EstimatorConfig
from simshear_gym.control.oracle import OracleController
from simshear_gym.control.policy import Controller, SB3Controller, sb3_algorithm
from simshear_gym.control.policy_files import has_policy_files
from simshear_gym.control.servo import SERVO_GAINS, ServoController, with_shear_gains
from simshear_gym.evaluate.closed_loop import POLICY_VARIANTS, TimedEpisode, env_kwargs
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

TRACKING_TRAJECTORIES = ("circle", "tilted_square", "spiral", "loop")
TRACKING_CHOICES = TRACKING_TRAJECTORIES + ("circular_wave", "star")
TASKS = ("tracking", "colift", "colift-heavy")
VARIANTS = ("shpix2pix", "pix2pix", "sim", "oracle", "policy", "ppo", "sac", "tqc")


def make_controller(variant: str, env, posenets: dict[str, str | None], policy: str | None = None,
                    hold_load: bool | None = None, load_margin_mm: tuple[float, float] | None = None,
                    shear_gains: tuple[float, float] | None = None) -> Controller:
    """The controller of a variant, matched to ``env`` (its reference depth, action scale and spaces); ``policy``:
    the SB3 model of a policy variant; ``hold_load``, ``load_margin_mm`` and ``shear_gains`` ((kp, ki) on shear x
    and y): the servo's (None: as the env asks)."""
    if variant == "oracle":
        return OracleController.for_env(env)
    if variant in POLICY_VARIANTS:
        return SB3Controller.for_env(policy, env)
    gains = with_shear_gains(SERVO_GAINS, *shear_gains) if shear_gains is not None else None  # None: the env's
    return ServoController.for_env(env, gains=gains, estimator=EstimatorConfig(posenet=posenets.get(variant)),
                                   hold_load=hold_load, load_margin_mm=load_margin_mm)


def run_episode(env, controller: Controller, seed: int, max_steps: int | None = None) -> dict:
    """One episode of ``controller`` in a sim env; returns its figures and the paths (target and sensor, world mm)
    for the figure."""
    episode = TimedEpisode(env, controller, seed, max_steps)
    errors, targets, sensors = [episode.info["contact_error_mm"]], [], []
    out_of_contact, dropped, slip_mm = 0, False, 0.0
    for info in episode:
        errors.append(info["contact_error_mm"])
        targets.append(np.asarray(info["target_world_mm"], dtype=np.float64))
        sensors.append(np.asarray(info["sensor_world_mm"], dtype=np.float64))
        out_of_contact += int(not info["in_contact"])
        dropped = dropped or bool(info.get("dropped", False))
        slip_mm = max(slip_mm, float(info.get("object_slip_mm", 0.0)))
    termination = episode.info.get("termination", "") if episode.terminated else ""
    errors = np.asarray(errors)
    return {
        "steps": episode.steps, "contact_error_mean_mm": float(errors.mean()),
        "contact_error_std_mm": float(errors.std()), "contact_error_max_mm": float(errors.max()),
        "steps_out_of_contact": out_of_contact,
        "termination": termination, "dropped": dropped, "object_slip_max_mm": slip_mm,
        "control_ms_median": 1000 * float(np.median(episode.control_s)),
        "env_step_ms_median": 1000 * float(np.median(episode.step_s)),
        "_paths": (np.stack(targets), np.stack(sensors)), "_errors_mm": errors[1:],
    }


def summarise(runs: list[dict]) -> dict:
    means = np.array([r["contact_error_mean_mm"] for r in runs])
    return {
        "seeds": len(runs), "contact_error_mean_mm": float(means.mean()),
        "contact_error_mean_std_mm": float(means.std()),
        "contact_error_max_mm": float(max(r["contact_error_max_mm"] for r in runs)),
        "runs_with_contact_loss": int(sum(r["steps_out_of_contact"] > 0 or r["termination"] == "contact_lost"
                                          for r in runs)),
        "runs_ended_early": int(sum(bool(r["termination"]) for r in runs)),
        "drops": int(sum(r["dropped"] for r in runs)),
        "object_slip_max_mm": float(max(r.get("object_slip_max_mm", 0.0) for r in runs)),
        "control_ms_median": float(np.median([r["control_ms_median"] for r in runs])),
        "env_step_ms_median": float(np.median([r["env_step_ms_median"] for r in runs])),
        "terminations": sorted({r["termination"] for r in runs if r["termination"]}),
    }


def path_panel(axis, target: np.ndarray, sensor: np.ndarray, title: str) -> None:
    """A 3D axis: the target path red, the follower's sensor blue dashed (mm from the target's start, equal scale
    on the three axes)."""
    axis.plot(*(target - target[0]).T, color="tab:red", lw=1.2, label="leader (target)")
    axis.plot(*(sensor - target[0]).T, color="tab:blue", lw=0.8, ls="--", label="follower")
    points = np.concatenate([target, sensor]) - target[0]
    low, high = points.min(axis=0), points.max(axis=0)
    middle, half = (low + high) / 2, max(float((high - low).max()) / 2, 5.0)
    for setter, centre in zip((axis.set_xlim, axis.set_ylim, axis.set_zlim), middle):
        setter(centre - half, centre + half)
    axis.set_box_aspect((1, 1, 1))
    axis.set_title(title, fontsize=8)
    axis.tick_params(labelsize=5)
    axis.set_xlabel("x mm", fontsize=6)
    axis.set_ylabel("y mm", fontsize=6)
    axis.set_zlabel("z mm", fontsize=6)


def figure(paths: dict[str, tuple[np.ndarray, np.ndarray, float]], path: Path, title: str) -> None:
    """One 3D panel per run: target path red, follower blue, mean error in the title."""
    plt = pyplot()

    names = list(paths)
    columns = min(4, len(names))
    rows = -(-len(names) // columns)
    fig = plt.figure(figsize=(3.2 * columns, 3.0 * rows))
    for index, name in enumerate(names):
        target, sensor, error = paths[name]
        path_panel(fig.add_subplot(rows, columns, index + 1, projection="3d"), target, sensor,
                   f"{name}\nerror {error:.2f} mm")
    fig.axes[0].legend(fontsize=6, loc="upper left")
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tasks", nargs="+", default=["tracking", "colift"], choices=TASKS,
                        help="benchmarks to run: SimShearTracking-v0, SimShearCoLift-v0 (the light objects) and/or "
                             "colift-heavy (SimShearCoLift-v0 with payload='heavy': 0.5-2 kg; default tracking and "
                             "colift)")
    parser.add_argument("--trajectories", nargs="+", default=list(TRACKING_TRAJECTORIES),
                        choices=TRACKING_CHOICES,
                        help="tracking trajectories (default the four trained ones; circular_wave and star: the "
                             "held-out test paths)")
    parser.add_argument("--objects", nargs="+", default=None, help="co-lift objects (default all)")
    parser.add_argument("--colift-trajectories", nargs="+", default=None, help="co-lift trajectories (default all)")
    parser.add_argument("--colift-rotation-deg", type=float, default=0.0,
                        help="the co-lift plate's turn about the vertical along the path (default 0: the paper's "
                             "translations; see SimShearCoLiftEnv's rotation_deg)")
    parser.add_argument("--variants", nargs="+", default=["shpix2pix"], choices=VARIANTS,
                        help="controllers to compare: shpix2pix (translated images, shipped GDNN), pix2pix and sim "
                             "(need --posenet-pix2pix / --posenet-sim), oracle (true depth and shear), policy, ppo, "
                             "sac, tqc (agents of simshear train rl: need --policy / --policy-ppo / --policy-sac / "
                             "--policy-tqc); "
                             "default shpix2pix")
    parser.add_argument("--hold-load", choices=("env", "on", "off"), default="env",
                        help="the servo holds the shear of its first image (a carried load's) instead of zero: env "
                             "(as the env asks: on for colift-heavy), on, off (the light-object law: an ablation)")
    parser.add_argument("--load-margin-mm", type=float, nargs=2, default=None, metavar=("X", "Y"),
                        help="shear (mm, sensor frame) the servo adds to a held load's (default: as the env asks: "
                             "0 -0.4 on colift-heavy, where sensor +y is down)")
    parser.add_argument("--shear-gains", type=float, nargs=2, default=None, metavar=("KP", "KI"),
                        help="the servo's gains on shear x and y (default: the env's where it holds a load, "
                             "kp 1 ki 0.5 on colift-heavy; else 0.6 0.2)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2],
                        help="seeds of the randomised runs (trajectory scale, speed, rotation, start place), each "
                             "besides the nominal run")
    parser.add_argument("--posenet-shpix2pix", default=None, help="GDNN for the shpix2pix variant (default shipped)")
    parser.add_argument("--posenet-pix2pix", default=None, help="GDNN trained on pix2pix images")
    parser.add_argument("--posenet-sim", default=None, help="GDNN trained on raw sim images")
    parser.add_argument("--policy", default=None,
                        help="policy of simshear train rl for the policy variant: its model.pt (or the .zip it was "
                             "saved beside; its run folder's config.json and vecnormalize.json are loaded with it)")
    parser.add_argument("--policy-ppo", default=None, help="PPO model .zip of simshear train rl for the ppo variant")
    parser.add_argument("--policy-sac", default=None, help="SAC model .zip of simshear train rl for the sac variant")
    parser.add_argument("--policy-tqc", default=None, help="TQC model .zip of simshear train rl for the tqc variant")
    parser.add_argument("--max-steps", type=int, default=None, help="cap per episode (default: the env's limit)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="output folder for <name>.json and the figures (default results)")
    parser.add_argument("--name", default="servo",
                        help="file name stem: <name>.json and <name>_<task>_<variant>.png (default servo)")


def check_args(args: argparse.Namespace) -> tuple[dict[str, str | None], dict[str, str | None]]:
    """The options' checks that need neither torch nor PyBullet (run before either is imported); returns the GDNN
    of each estimator variant and the model of each policy variant, as given."""
    posenets = {"shpix2pix": args.posenet_shpix2pix, "pix2pix": args.posenet_pix2pix, "sim": args.posenet_sim}
    policies = {"policy": args.policy, "ppo": args.policy_ppo, "sac": args.policy_sac, "tqc": args.policy_tqc}
    if args.threads < 1 or (args.max_steps is not None and args.max_steps < 1):
        raise ValueError(f"--threads and --max-steps must be >= 1, got {args.threads}, {args.max_steps}")
    for variant in args.variants:
        if variant in ("pix2pix", "sim") and not posenets[variant]:
            raise ValueError(f"--variants {variant} needs --posenet-{variant} (a GDNN trained on {variant} images)")
        if variant in POLICY_VARIANTS:
            flag = "--policy" if variant == "policy" else f"--policy-{variant}"
            if not policies[variant]:
                raise ValueError(f"--variants {variant} needs {flag} MODEL.zip (from simshear train rl)")
            if not Path(policies[variant]).is_file() and not has_policy_files(policies[variant]):
                raise FileNotFoundError(f"{flag} {policies[variant]!r}: no such model file")
            algorithm = sb3_algorithm(policies[variant])
            if variant != "policy" and algorithm != variant:
                raise ValueError(f"{flag} {policies[variant]} is a {algorithm.upper()} model, not {variant.upper()}")
    return posenets, policies


def run(args: argparse.Namespace) -> int:
    posenets, policies = check_args(args)
    import gymnasium as gym
    import torch

    import simshear_gym.envs  # noqa: F401  (registers the envs)

    torch.set_num_threads(args.threads)
    settings: list[tuple[str, str, dict]] = []
    if "tracking" in args.tasks:
        settings += [("tracking", trajectory, {"trajectory": trajectory}) for trajectory in args.trajectories]
    from simshear_gym.envs.colift import COLIFT_TRAJECTORIES, OBJECT_NAMES

    for task, payload in (("colift", "light"), ("colift-heavy", "heavy")):
        if task not in args.tasks:
            continue
        for trajectory in args.colift_trajectories or COLIFT_TRAJECTORIES:
            for name in args.objects or OBJECT_NAMES:
                settings.append((task, f"{name}_{trajectory}", {"trajectory": trajectory, "object_name": name,
                                                                "rotation_deg": args.colift_rotation_deg,
                                                                "payload": payload}))
    env_ids = {"tracking": "SimShearTracking-v0", "colift": "SimShearCoLift-v0", "colift-heavy": "SimShearCoLift-v0"}
    hold_load = {"env": None, "on": True, "off": False}[args.hold_load]
    start = time.perf_counter()
    results: dict = {}
    paths: dict[tuple[str, str], dict] = {}
    for variant in args.variants:
        results[variant] = {}
        obs_mode = {"sim": "sim", "oracle": "oracle"}.get(variant, "real")  # a policy: its run's (env_kwargs)
        for task, label, kwargs in settings:
            runs = []
            for randomise, seeds in ((False, ["nominal"]), (True, args.seeds)):
                env = gym.make(env_ids[task], randomise=randomise,
                               **env_kwargs(variant, policies.get(variant), obs_mode), **kwargs)
                controller = make_controller(variant, env, posenets, policies.get(variant), hold_load,
                                             args.load_margin_mm, args.shear_gains)
                for seed in seeds:
                    r = run_episode(env, controller, 0 if seed == "nominal" else seed, args.max_steps)
                    target, sensor = r.pop("_paths")
                    r.pop("_errors_mm")
                    r["seed"] = seed
                    paths.setdefault((task, variant), {})[f"{label} {seed}"] = (
                        target, sensor, r["contact_error_mean_mm"])
                    runs.append(r)
                env.close()
            results[variant][f"{task}/{label}"] = {**summarise(runs), "runs": runs}
            s = results[variant][f"{task}/{label}"]
            print(f"{variant:9s} {task}/{label:22s} error {s['contact_error_mean_mm']:.3f} +- "
                  f"{s['contact_error_mean_std_mm']:.3f} mm (max {s['contact_error_max_mm']:.2f}), "
                  f"contact losses {s['runs_with_contact_loss']}, drops {s['drops']} (slip max "
                  f"{s['object_slip_max_mm']:.2f} mm), ended early "
                  f"{s['runs_ended_early']} {s['terminations']}, control {s['control_ms_median']:.2f} ms, "
                  f"env step {s['env_step_ms_median']:.2f} ms")
    figures = []
    for (task, variant), runs in paths.items():
        first = "nominal"
        first_seed = {name: value for name, value in runs.items() if name.endswith(first)}
        png = args.out / f"{args.name}_{task}_{variant}.png"
        figure(first_seed, png, f"{task}, {variant} estimator (nominal runs)")
        figures.append(str(png))
    write_record("simshear evaluate servo", add_arguments, args, args.out / f"{args.name}.json", {
        "metrics": "contact error = distance (mm) between the follower's sensor and its target point on the "
                   "leader's face, every step; mean +- std over seeds of the per-run means; control = estimator + "
                   "filter + law per step (ms, median); env step = one env.step including rendering/translation; "
                   "object slip max = the co-lift object's largest drift from its place on the plate (mm)",
        "translator_runtime": _translator_runtime(), "translator_threads": _translator_threads(),
        "results": results, "figures": figures, "seconds": round(time.perf_counter() - start, 1),
        "machine": machine_info(),
    })
    print(f"wrote {args.out / (args.name + '.json')}")
    return 0


def _translator_threads() -> int:
    """ONNX Runtime's intra-op threads of the envs' translators (``$SIMSHEAR_TRANSLATOR_THREADS``, default 1)."""
    from simshear_gym.models.translator_runtime import choose_translator_threads

    return choose_translator_threads()


def _translator_runtime() -> str:
    """The runtime the envs' shipped surface translator ran on in this process (``"onnx"`` or ``"torch"``)."""
    from simshear_gym.models.translator_runtime import runtime_of
    from simshear_gym.models.zoo import shipped_translator

    return runtime_of(shipped_translator("surface"))
