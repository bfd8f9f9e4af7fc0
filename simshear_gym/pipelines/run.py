"""``simshear pipeline run CONFIG [--profile P] [--stages ...] [--out DIR]``: from a sensor's data set to its models.

Stages, each cached under a content hash of its inputs and settings (:mod:`simshear_gym.pipelines.stages`):

1. ``adapt``: each dataset of the config as canonical tactile sets (train, val) in the simulation's frame
   (:mod:`simshear_gym.data.adapter`);
2. ``collect``: every row replayed in simulation with the config's sensor: paired sets (sim image, shear, real
   image, labels) (:mod:`simshear_gym.sim.collect`).

The run's manifest (``manifest.json`` in ``--out``): config, profile, package version, git commit, per stage its
folder, whether it ran or was cached, wall time and metrics.
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING

from simshear_gym.data.adapter import adapt_dataset, write_canonical
from simshear_gym.data.paths import data_root
from simshear_gym.io import write_json
from simshear_gym.pipelines.stages import StageRunner, file_fingerprint

STAGES: tuple[str, ...] = ("adapt", "collect")

if TYPE_CHECKING:  # the config imports the simulator (pybullet): in run, so that --help stays light
    from simshear_gym.pipelines.config import ExperimentConfig


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _dataset_files(config: ExperimentConfig, name: str, root: Path) -> list[Path]:
    from simshear_gym.data.adapter import resolve

    return [resolve(data_file.csv, root) for data_file in config.datasets[name].files]


def stage_adapt(runner: StageRunner, config: ExperimentConfig, root: Path, rows_per_split: int | None) -> dict:
    """{dataset: {split: path of its canonical set}}."""
    sets = {}
    for name, dataset in config.datasets.items():
        key = {"dataset": dataset, "frame": config.frame, "rows_per_split": rows_per_split,
               "files": file_fingerprint(_dataset_files(config, name, root))}

        def work(folder: Path, name=name, dataset=dataset) -> dict:
            adapted = adapt_dataset(dataset, config.frame, root, name, rows_per_split)
            outputs = {}
            for split, part in adapted.items():
                meta = {"sensor": config.name, "dataset": name, "contact": dataset.contact, "kind": dataset.kind,
                        "split": split, "source_image_px": list(part.source_size_px)}
                outputs[split] = runner.relative(write_canonical(part, folder / split, meta))
            return {"outputs": outputs, "metrics": {split: len(part.image_paths) for split, part in adapted.items()}}

        sets[name] = runner.run(f"adapt/{name}", key, work).outputs
    return sets


def stage_collect(runner: StageRunner, config: ExperimentConfig, adapted: dict, workers: int) -> dict:
    """{dataset: {split: path of its paired set}}."""
    from simshear_gym.sim.collect import CollectConfig, replay_set  # pybullet: only when the stage runs

    collect_config = CollectConfig(tactip=config.sensor, geometry=config.replay, workers=workers)
    paired = {}
    for name, splits in adapted.items():
        contact = config.datasets[name].contact
        key = {"sets": splits, "contact": contact, "tactip": config.sensor, "geometry": config.replay,
               "shear": collect_config.shear}

        def work(folder: Path, splits=splits, contact=contact) -> dict:
            outputs, rows = {}, {}
            for split, relative in splits.items():
                out = folder / split
                rows[split] = replay_set(runner.root / relative, out, collect_config, runner.root, contact)
                outputs[split] = runner.relative(out)
            return {"outputs": outputs, "metrics": rows}

        paired[name] = runner.run(f"collect/{name}", key, work).outputs
    return paired


def run_pipeline(config: ExperimentConfig, out: Path, root: Path, profile: str, stages: tuple[str, ...],
                 rows_per_split: int | None, workers: int = 2) -> dict:
    """Run the stages in order (each cached) and write ``out/manifest.json``; returns the manifest."""
    out.mkdir(parents=True, exist_ok=True)
    runner = StageRunner(out)
    start = time.perf_counter()
    adapted = stage_adapt(runner, config, root, rows_per_split)
    if "collect" in stages:
        stage_collect(runner, config, adapted, workers)
    manifest = {
        "config": str(config.path), "sensor": config.name, "profile": profile, "stages": list(stages),
        "package_version": _version(), "git_commit": git_commit(),
        "wall_s": round(time.perf_counter() - start, 2),
        "results": [{"stage": r.name, "folder": runner.relative(r.folder), "ran": r.ran,
                     "wall_s": r.record["wall_s"], "metrics": r.record["metrics"]} for r in runner.results],
    }
    write_json(out / "manifest.json", manifest)
    return manifest


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("simshear-gym")
    except PackageNotFoundError:
        return "unknown"


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    parser.add_argument("--profile", default="quick", help="stage settings: smoke (seconds), quick (a laptop, under "
                        "30 min) or full (the shipped recipe)")
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES),
                        help="stages to run (each needs the ones before it; cached ones are reused)")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/pipeline/<sensor>)")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--rows", type=int, default=None, help="first N rows of each split only (default: all)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes of the collect stage")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.config import load_config

    config = load_config(args.config)
    out = args.out or Path("runs") / "pipeline" / config.name
    manifest = run_pipeline(config, out, data_root(args.data), args.profile, tuple(args.stages), args.rows,
                            args.workers)
    ran = sum(result["ran"] for result in manifest["results"])
    print(f"{config.name}: {len(manifest['results'])} stage steps ({ran} ran, "
          f"{len(manifest['results']) - ran} cached) in {manifest['wall_s']:.1f} s; manifest {out / 'manifest.json'}")
    return 0
