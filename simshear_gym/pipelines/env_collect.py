"""Labelled tactile images from a SimShear env, for training a task's own estimator.

``simshear collect-env --task colift --rows 12000 --out DIR`` runs the task's env with ``obs_mode="oracle_real"``
and keeps, every step, the image the env emits (translated by the shipped shPix2pix, as a controller sees it)
with the env's true state: depth (label convention), shear x, y (mm) and shear Rz (deg; for co-lift the sensor's
yaw error), the variables of :data:`~simshear_gym.models.gdnn.VARIABLE_SETS` ``"env"``.

Which states: by default (``driver="oracle"``) the follower is driven by the oracle's law
(:class:`~simshear_gym.control.oracle.OracleController`) scaled by a gain that wanders between ``gain_min`` and 1
(a slow sine with a random phase per episode), plus Gaussian action noise, so the follower lags, overshoots and
loses its place the way a learned controller does, not only the oracle's near-zero errors. With
``driver="servo"`` the image-based :class:`~simshear_gym.control.servo.ServoController` (``posenet``: its GDNN)
drives, plus the noise on the components it steers (it does not steer the yaw, where noise would random-walk the
sensor far from any state the controller visits): the states that controller visits, labelled with the truth (one
round of DAgger: train on oracle-driven sets, collect where the trained estimator takes the follower, train again
on both). Episodes run over the task's objects and trajectories in turn, with the env's randomisation of scale,
speed and start; an episode that ends early (a drop, a limit) is followed by the next.

Output: a set directory (``images/image_N.png`` 128 px, ``targets.csv``, ``meta.json``) like the data's own sets;
``targets.csv`` columns: ``sensor_image``, ``episode``, ``step``, ``object_name``, ``trajectory``, the four
variables (``z_mm``, ``shear_x_mm``, ``shear_y_mm``, ``shear_rz_deg``) and ``contact_error_mm``.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

TASKS = ("tracking", "colift")
DRIVERS = ("oracle", "servo")
STATE_COLUMNS = ("z_mm", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
"""The env's ``true_pose_shear``, in order, as label columns."""


@dataclass(frozen=True)
class EnvCollectConfig:
    """What to collect.

    Attributes:
        task: ``tracking`` (SimShearTracking-v0 over its trajectories) or ``colift`` (SimShearCoLift-v0 over its
            objects and trajectories).
        rows: images to keep.
        episode_steps: steps per episode at most.
        gain_min: the oracle law's gain wanders between this and 1.
        gain_period_steps: period of the gain's wander.
        noise: std of the Gaussian noise added to the action (action units, full scale 1).
        seed: seeds episodes, gains and noise.
        driver: ``oracle`` (the oracle law with the wandering gain) or ``servo`` (the servo controller).
        posenet: the servo driver's GDNN weights (None: the shipped one the controller picks).
        payload: co-lift only: ``light`` (the paper's objects) or ``heavy`` (``SimShearCoLift-v0``'s
            ``payload="heavy"``). A heavy set's shear labels are the skin's deflection (``info["shear_sensor_mm_deg"]``,
            what the image shows and the translator is given, the held load's shear included), not the shear over
            the face as carried by the plate that the oracle sees: the two differ by the load's steady deflection,
            which an image cannot tell apart from a lag without knowing the mass.
        sensor: a sensor's models instead of the shipped ones (the env's ``sensor``: a ``sensor.json`` of
            ``simshear pipeline run`` or its folder); None: the shipped translator.
    """

    task: str = "colift"
    rows: int = 12000
    episode_steps: int = 200
    gain_min: float = 0.3
    gain_period_steps: float = 60.0
    noise: float = 0.3
    seed: int = 0
    driver: str = "oracle"
    posenet: str | None = None
    payload: str = "light"
    sensor: str | None = None

    def __post_init__(self) -> None:
        if self.driver not in DRIVERS:
            raise ValueError(f"driver must be one of {DRIVERS}, got {self.driver!r}")
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        if self.payload not in ("light", "heavy") or (self.payload == "heavy" and self.task != "colift"):
            raise ValueError(f"payload must be 'light' or 'heavy' (heavy: task colift), got {self.payload!r} for "
                             f"task {self.task!r}")
        if self.rows < 1 or self.episode_steps < 1:
            raise ValueError(f"rows and episode_steps must be >= 1, got {self.rows}, {self.episode_steps}")
        if not 0.0 <= self.gain_min <= 1.0 or self.gain_period_steps <= 0 or self.noise < 0:
            raise ValueError(f"need 0 <= gain_min <= 1, gain_period_steps > 0, noise >= 0; got {self.gain_min}, "
                             f"{self.gain_period_steps}, {self.noise}")

    def episodes(self) -> list[dict]:
        """The env settings of the episodes, in the order they run (repeated as long as rows are needed)."""
        if self.task == "colift":
            from simshear_gym.envs.colift import COLIFT_TRAJECTORIES, OBJECT_NAMES

            return [{"object_name": name, "trajectory": path, "payload": self.payload} for path in COLIFT_TRAJECTORIES
                    for name in OBJECT_NAMES]
        from simshear_gym.envs.trajectories import TRAJECTORIES

        return [{"trajectory": path} for path in TRAJECTORIES]


def collect(config: EnvCollectConfig, out_dir: Path, progress: bool = True) -> int:
    """Write a set of ``config.rows`` labelled env images to ``out_dir``; returns the rows written."""
    import gymnasium as gym
    import pandas as pd
    from tqdm import tqdm

    import simshear_gym.envs  # noqa: F401  (registers the env ids)
    from simshear_gym.control.estimator import EstimatorConfig
    from simshear_gym.control.oracle import OracleController
    from simshear_gym.control.servo import SERVO_GAINS, ServoController
    from simshear_gym.data.tactile_set import image_name, write_image, write_targets

    env_id = "SimShearCoLift-v0" if config.task == "colift" else "SimShearTracking-v0"
    out_dir = Path(out_dir)
    images_dir = out_dir / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(config.seed)
    rows: list[dict] = []
    envs: dict[tuple, tuple[gym.Env, object]] = {}  # env and its controller, made once per setting
    settings = config.episodes()
    started = time.perf_counter()
    bar = tqdm(total=config.rows, disable=not progress, desc=f"collect {config.task}")
    episode = 0
    try:
        while len(rows) < config.rows:
            setting = settings[episode % len(settings)]
            key = tuple(sorted(setting.items()))
            if key not in envs:
                env = gym.make(env_id, obs_mode="oracle_real", randomise=True, **setting,
                               **({"sensor": config.sensor} if config.sensor else {}))
                # the DAgger driver: the servo law as the shipped env GDNNs' recipes ran it (default gains, the
                # grasp's shear held without a margin), whatever the env asks of the servo since
                envs[key] = env, (ServoController.for_env(env, SERVO_GAINS, EstimatorConfig(posenet=config.posenet),
                                                          load_margin_mm=(0.0, 0.0))
                                  if config.driver == "servo" else OracleController.for_env(env))
            env, controller = envs[key]
            steered = controller.law.gains.controlled  # noise there only: an unsteered yaw would random-walk
            observation, _ = env.reset(seed=int(rng.integers(2 ** 31)))
            controller.reset()
            phase = rng.uniform(0.0, 2.0 * math.pi)
            for step in range(config.episode_steps):
                gain = 1.0 if config.driver == "servo" else config.gain_min + (1.0 - config.gain_min) * 0.5 * (
                    1.0 + math.sin(phase + 2.0 * math.pi * step / config.gain_period_steps))
                action = gain * controller(observation) + rng.normal(0.0, config.noise, 4) * steered
                observation, _, terminated, truncated, info = env.step(np.clip(action, -1, 1).astype(np.float32))
                name = image_name(len(rows))
                write_image(images_dir, name, observation["tactile"][0])
                state = dict(zip(STATE_COLUMNS, observation["true_pose_shear"].astype(float)))
                if config.payload == "heavy":  # what the image shows: the skin's deflection, the load's included
                    state["shear_x_mm"], state["shear_y_mm"] = (float(v) for v in info["shear_sensor_mm_deg"][:2])
                rows.append({"sensor_image": name, "episode": episode, "step": step,
                             "object_name": setting.get("object_name", ""), "trajectory": setting["trajectory"],
                             **state, "contact_error_mm": float(info["contact_error_mm"])})
                bar.update(1)
                if terminated or truncated or len(rows) >= config.rows:
                    break
            episode += 1
    finally:
        bar.close()
        for env, _ in envs.values():
            env.close()
    meta = {"kind": "env", "env_id": env_id, "obs_mode": "oracle_real", "variables": "env",
            "config": asdict(config), "episodes": episode, "seconds": round(time.perf_counter() - started, 1)}
    write_targets(out_dir, pd.DataFrame(rows), meta)
    return len(rows)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = EnvCollectConfig()
    parser.add_argument("--task", choices=TASKS, default=defaults.task,
                        help="tracking (SimShearTracking-v0 over its trajectories) or colift (SimShearCoLift-v0 over "
                             f"its objects and trajectories); default {defaults.task}")
    parser.add_argument("--out", type=Path, required=True, help="set directory to write")
    parser.add_argument("--driver", choices=DRIVERS, default=defaults.driver,
                        help="who moves the follower: the oracle law (wandering gain) or the servo controller")
    parser.add_argument("--posenet", default=None, help="GDNN of the servo driver (default: shipped)")
    parser.add_argument("--payload", choices=("light", "heavy"), default="light",
                        help="co-lift objects: light (30 g, soft TacTip) or heavy (0.5-2 kg, firm TacTip; shear "
                             "labels are the skin's deflection, the load's included)")
    helps = {"rows": "images to keep", "episode_steps": "steps per episode at most",
             "gain_min": "the oracle law's gain wanders between this and 1",
             "gain_period_steps": "period of the gain's wander, in steps",
             "noise": "std of the Gaussian noise added to the action (action units, full scale 1)",
             "seed": "seeds episodes, gains and noise"}
    for name, text in helps.items():
        value = getattr(defaults, name)
        parser.add_argument(f"--{name.replace('_', '-')}", type=type(value), default=value,
                            help=f"{text} (default {value})")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (translation)")


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(args.threads)
    config = EnvCollectConfig(task=args.task, rows=args.rows, episode_steps=args.episode_steps,
                              gain_min=args.gain_min, gain_period_steps=args.gain_period_steps, noise=args.noise,
                              seed=args.seed, driver=args.driver, posenet=args.posenet, payload=args.payload)
    if (Path(args.out) / "targets.csv").exists():
        raise ValueError(f"{args.out}/targets.csv exists: choose a new --out")
    started = time.perf_counter()
    rows = collect(config, args.out)
    print(f"wrote {rows} rows to {args.out} in {time.perf_counter() - started:.0f} s")
    return 0
