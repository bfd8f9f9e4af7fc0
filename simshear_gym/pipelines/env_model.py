"""An env GDNN from its recipe in one command: ``simshear pipeline env-model CONFIG --model NAME --out DIR``.

The recipe is the config's ``[env_models.NAME]`` table (:class:`~simshear_gym.pipelines.config.EnvModelRecipe`):
oracle-driven env sets, a first GDNN on some of them, servo-driven sets read by that GDNN (one round of DAgger),
and the GDNN on every set. Each step is a cached stage (:mod:`simshear_gym.pipelines.stages`) under ``DIR``:

- ``envset/<seed>/<hash>/set``: one ``simshear collect-env`` set (its key: the recipe's collection settings, the
  seed, the driver, the sha256 of the translator that makes the env's images and of the driver's GDNN);
- ``envposenet/first/<hash>/run`` and ``envposenet/final/<hash>/run``: ``simshear train posenet --source env``
  runs (their key: the training settings and the sets' stage hashes).

A rerun finds every record and does nothing; a run killed mid-stage resumes that stage (a trainer from its
checkpoint; a set is collected again). ``DIR/manifest.json`` names the final run, its metrics and each stage's
wall time, and ``DIR/<NAME>.pt`` is the final GDNN, the file ``simshear ship posenet --run
DIR/envposenet/final/<hash>/run --contact NAME`` ships with its card.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from simshear_gym.command_line import recorded_command
from simshear_gym.io import write_json
from simshear_gym.models.zoo import load_sensor, translator_weights
from simshear_gym.pipelines.stages import StageResult, StageRunner
from simshear_gym.tables import add_set_argument

if TYPE_CHECKING:  # the config imports the simulation (PyBullet): not for --help
    from simshear_gym.pipelines.config import EnvModelRecipe


def translator_file(recipe: EnvModelRecipe, sensor: str | None) -> Path:
    """The translator weights whose images the recipe's env emits (the shipped surface shPix2pix, or the
    sensor's)."""
    if sensor is not None:
        return Path(load_sensor(sensor).translator("surface"))
    return translator_weights("surface")


def scene_fingerprint(recipe: EnvModelRecipe) -> dict:
    """The physics a co-lift recipe's sets are collected in (its scene settings and objects), so that a change to
    either collects them again; {} for the tracking env."""
    if recipe.task != "colift":
        return {}
    from simshear_gym.sim.colift_scene import FIRM_TIP, CoLiftSceneConfig
    from simshear_gym.sim.objects import HEAVY_OBJECTS, OBJECTS

    scene = asdict(CoLiftSceneConfig(payload=recipe.payload, **(FIRM_TIP if recipe.payload == "heavy" else {})))
    objects = HEAVY_OBJECTS if recipe.payload == "heavy" else OBJECTS
    return {"scene": {k: v for k, v in scene.items() if k not in ("object_name", "mass_kg")},
            "objects": {name: asdict(spec) for name, spec in objects.items()}}


def _sha(path: Path | str) -> str:
    from simshear_gym.io import file_sha256

    return file_sha256(path)[:16]


def collect_step(runner: StageRunner, recipe: EnvModelRecipe, seed: int, sensor: str | None, translator_sha: str,
                 driver_weights: str | None = None) -> StageResult:
    """One env set: oracle-driven, or (``driver_weights``: a GDNN relative to the run folder) servo-driven."""
    from simshear_gym.pipelines.env_collect import EnvCollectConfig, collect

    posenet = str(runner.root / driver_weights) if driver_weights else None
    settings = EnvCollectConfig(task=recipe.task, rows=recipe.rows, episode_steps=recipe.episode_steps, seed=seed,
                                driver="servo" if posenet else "oracle", posenet=posenet, payload=recipe.payload,
                                sensor=sensor)
    key = {"collect": {**asdict(settings), "posenet": _sha(posenet) if posenet else None},
           "translator_sha256": translator_sha, "physics": scene_fingerprint(recipe)}

    def work(folder: Path) -> dict:
        import shutil

        target = folder / "set"
        if target.exists():  # a set cut off mid-collection: collect it again whole
            shutil.rmtree(target)
        rows = collect(settings, target, progress=False)
        return {"outputs": {"set": runner.relative(target)}, "metrics": {"rows": rows}}

    return runner.run(f"envset/{seed}", key, work)


def train_step(runner: StageRunner, recipe: EnvModelRecipe, name: str, sets: list[StageResult],
               epochs: int, device: str) -> StageResult:
    """A GDNN on env sets (``simshear train posenet --source env --contact env``), ``epochs`` epochs."""
    from simshear_gym.train.posenet_config import PosenetTrainConfig

    set_dirs = tuple(result.outputs["set"] for result in sets)
    settings = recipe.train_settings(epochs)
    key = {"sets": [result.record["hash"] for result in sets], "settings": settings}

    def work(folder: Path) -> dict:
        import torch

        from simshear_gym.train.posenet_trainer import PosenetTrainer, load_source

        config = PosenetTrainConfig(source="env", contact="env", paired_dirs=set_dirs, device=device, **settings)
        torch.set_num_threads(config.threads)
        data = load_source("env", "env", [str(runner.root / d) for d in set_dirs], str(runner.root),
                           config.image_size_px)
        trainer = PosenetTrainer(config, folder / "run", data)
        trainer.resume()
        summary = trainer.fit(progress=False)
        return {"outputs": {"run": runner.relative(folder / "run"),
                            "weights": runner.relative(folder / "run" / "best.pt")}, "metrics": summary}

    return runner.run(f"envposenet/{name}", key, work)


def run_recipe(recipe: EnvModelRecipe, name: str, out: Path, sensor: str | None = None, device: str = "cpu",
               command: str = "") -> dict:
    """Run (or find cached) every step of ``recipe`` under ``out``; write ``out/manifest.json`` and
    ``out/<name>.pt`` (the final GDNN); returns the manifest."""
    from simshear_gym.models.posenet_io import load_posenet, save_posenet

    out.mkdir(parents=True, exist_ok=True)
    runner = StageRunner(out)
    start = time.perf_counter()
    translator_sha = _sha(translator_file(recipe, sensor))
    oracle = {seed: collect_step(runner, recipe, seed, sensor, translator_sha) for seed in recipe.oracle_seeds}
    sets = list(oracle.values())
    if recipe.dagger_seeds:
        first = train_step(runner, recipe, "first", [oracle[seed] for seed in recipe.first_round],
                           recipe.first_epochs, device)
        sets += [collect_step(runner, recipe, seed, sensor, translator_sha, first.outputs["weights"])
                 for seed in recipe.dagger_seeds]
    final = train_step(runner, recipe, "final", sets, recipe.train_settings()["epochs"], device)
    model, card = load_posenet(out / final.outputs["weights"])
    weights = out / f"{name}.pt"
    recipe_record = recipe.record()
    save_posenet(weights, model, card={**card, "env_model": name, "recipe": recipe_record})
    manifest = {
        "command": command, "model": name, "recipe": recipe_record, "sensor": sensor or "shipped",
        "translator_sha256": translator_sha, "device": device, "wall_s": round(time.perf_counter() - start, 2),
        "final_run": final.outputs["run"], "weights": runner.relative(weights),
        "results": [{"stage": r.name, "folder": runner.relative(r.folder), "ran": r.ran, "wall_s": r.record["wall_s"],
                     "metrics": r.record["metrics"]} for r in runner.results],
    }
    write_json(out / "manifest.json", manifest)
    return manifest


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.models.device import DEVICES

    parser.add_argument("config", type=Path, help="the sensor's experiment config (configs/<name>.toml)")
    add_set_argument(parser)
    parser.add_argument("--model", required=True, help="the recipe: the config's [env_models.<MODEL>] table")
    parser.add_argument("--out", type=Path, default=None,
                        help="run folder (default runs/env_models/<config name>/<MODEL>); a rerun reuses its stages")
    parser.add_argument("--sensor", default=None,
                        help="the env's models: a pipeline run's sensor.json or folder (default: the shipped ones)")
    parser.add_argument("--device", choices=DEVICES, default="cpu", help="where the GDNNs train (default cpu)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.config import load_config

    config = load_config(args.config, args.settings)
    recipe = config.env_model(args.model)
    out = args.out or Path("runs") / "env_models" / config.name / args.model
    command = recorded_command("simshear pipeline env-model", add_arguments, args)
    manifest = run_recipe(recipe, args.model, out, args.sensor, args.device, command)
    final = next(r for r in manifest["results"] if r["stage"] == "envposenet/final")
    print(f"{args.model}: {out / manifest['weights']} (final run {out / manifest['final_run']}; best holdout NLL "
          f"{final['metrics'].get('best_holdout_nll')}) in {manifest['wall_s']:.0f} s")
    return 0
