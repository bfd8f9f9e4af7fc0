"""``simshear pipeline run CONFIG [--profile P] [--stages ...] [--out DIR]``: from a sensor's data set to its models.

Stages, each cached under a content hash of its inputs and settings (:mod:`simshear_gym.pipelines.stages`):

1. ``adapt``: each dataset of the config as canonical tactile sets (train, val) in the simulation's frame
   (:mod:`simshear_gym.data.adapter`);
2. ``collect``: every row replayed in simulation with the config's sensor: paired sets (sim image, shear, real
   image, labels) (:mod:`simshear_gym.sim.collect`);
3. ``translator``: per contact type, a shPix2pix (and a pix2pix baseline) on the paired training sets of that
   contact, with the profile's settings (:mod:`simshear_gym.train.translator_trainer`), and the profile's pool of
   further shPix2pix generators (other seeds, density and pose-consistency losses:
   :class:`~simshear_gym.pipelines.config.PoolGenerator`);
4. ``posenet``: per contact type, a GDNN on the real images (the reference) and one on the translations of the
   sim renders (the one a controller uses), each row through a generator drawn from the shPix2pix and the pool
   (plus the profile's random sim contacts), estimating the variables that vary in the sensor's data (depth,
   tilts, offsets, edge angle; shear where the data has it);
5. ``evaluate``: on every dataset's real validation images: translation MAPE / SSIM against nearest-label
   retrieval (the real training image with the closest labels), the GDNNs' MAE per variable against chance and
   the translated-trained / real-trained ratio; written to ``evaluation.json``.

Once the translators are trained, the ``onnx`` stage (:func:`stage_onnx`) exports each translator of the sensor
(the shPix2pix per contact type that ``sensor.json`` names) to ``<weights>.onnx`` beside its ``<weights>.pt``, as
``simshear ship onnx`` exports the shipped ones (:mod:`simshear_gym.models.onnx_export`: the same graph, fp16
storage, the sha256 of the weights in its metadata), so that an env made with ``sensor=`` runs it on ONNX Runtime
(the envs' ``"auto"`` runtime, :mod:`simshear_gym.models.translator_runtime`) like the shipped translators. The
export is checked on the first :data:`ONNX_CHECK_ROWS` validation rows of each of the contact type's data sets (its sim
renders and shear, as the evaluation feeds them): torch and ONNX Runtime side by side, their MAPE against the real
images, how many pixels differ and by how much, and their batch-1 latency on one thread; the figures are the
stage's metrics and lie in the ONNX file's metadata. Each export is a cached ``onnx/<contact>_shpix2pix`` stage
keyed by the weights' sha256 and the export's settings. Where the ``export`` extra (onnx, onnxscript) is missing,
the stage logs one line saying so and the envs run the sensor's translators on torch.

Stages 3-5 are steps of a graph (:func:`simshear_gym.pipelines.stages.run_steps`), run ``jobs`` at a time in worker
processes: a pose-consistency generator starts once its contact's real-image GDNN is done. The training steps
train on the profile's ``device`` (``--device`` overrides it; ``auto``: CUDA where there is one), which is not
part of their cache keys.

The run folder's ``sensor.json`` names the sensor's TacTip settings, translators and GDNNs: the envs take it
(``gym.make("SimShearTracking-v0", sensor="configs/<name>.toml")``, :func:`simshear_gym.models.zoo.load_sensor`).

SIGTERM or SIGINT stops the run and all its processes (:func:`simshear_gym.pipelines.stages.stop_on_signals`): exit
status 128 + the signal, one ``simshear: error:`` line; the rerun resumes.

The run's manifest (``manifest.json`` in ``--out``): config, profile, package version, git commit, the machine
(:func:`simshear_gym.machine.machine_info`: wall times are that machine's), per stage its folder, whether it ran or
was cached, wall time and metrics.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from simshear_gym.data.adapter import CANONICAL_COLUMNS, adapt_dataset, config_files, resolve, write_canonical
from simshear_gym.data.paths import data_root
from simshear_gym.data.tactile_set import read_set
from simshear_gym.io import file_sha256, write_json
from simshear_gym.machine import machine_info
from simshear_gym.models import onnx_export
from simshear_gym.models.device import DEVICES, check_device_name
from simshear_gym.models.translator_runtime import onnx_path_for
from simshear_gym.models.zoo import DEFAULT_PIPELINE_RUNS, write_sensor
from simshear_gym.pipelines.stages import (
    RunStopped,
    StageResult,
    StageRunner,
    Step,
    end_children,
    file_fingerprint,
    report_epochs,
    run_steps,
    stop_on_signals,
    training_start_line,
)
from simshear_gym.tables import add_set_argument

STAGES: tuple[str, ...] = ("adapt", "collect", "translator", "posenet", "evaluate")
POSE_NAMES = {"pose_x": "x_mm", "pose_y": "y_mm", "pose_z": "z_mm", "pose_rx": "rx_deg", "pose_ry": "ry_deg",
              "pose_rz": "rz_deg"}
SHEAR_SPECS = (("move_x", "shear_x_mm", "shear_sensor_x_mm"), ("move_y", "shear_y_mm", "shear_sensor_y_mm"),
               ("move_rz", "shear_rz_deg", "shear_sensor_rz_deg"))

if TYPE_CHECKING:  # the config imports the simulator (pybullet): in run, so that --help stays light
    from simshear_gym.models.gdnn import VariableSet
    from simshear_gym.pipelines.config import ExperimentConfig

#: profiles that check the plumbing, not the models: a few dozen rows and an epoch or two, so their models sit near
#: chance; their manifest and output say so
PLUMBING_PROFILES = {"smoke": "a plumbing check (a few rows, an epoch or two): it shows that every stage runs; "
                              "its models sit near chance and measure nothing"}


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def stage_adapt(runner: StageRunner, config: ExperimentConfig, root: Path, rows_per_split: int | None) -> dict:
    """{dataset: {split: path of its canonical set}}."""
    sets = {}
    for name, dataset in config.datasets.items():
        key = {"dataset": dataset, "frame": config.frame_for(name), "rows_per_split": rows_per_split,
               "files": file_fingerprint([resolve(data_file.csv, root) for data_file in dataset.files])}

        def work(folder: Path, name=name, dataset=dataset) -> dict:
            adapted = adapt_dataset(dataset, config.frame_for(name), root, name, rows_per_split)
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


def only_contacts(config: ExperimentConfig, contacts: list[str] | None) -> ExperimentConfig:
    """The config restricted to the datasets, pool generators and random contacts of ``contacts`` (None: all);
    the stages of a kept contact type keep their cache keys, so one contact type can be run (and shipped) at a
    time."""
    if not contacts:
        return config
    known = sorted({dataset.contact for dataset in config.datasets.values()})
    unknown = sorted(set(contacts) - set(known))
    if unknown:
        raise ValueError(f"--contacts: {config.path} has no {unknown[0]!r} datasets; its contact types: {known}")
    keep = set(contacts)
    profiles = {name: replace(profile, pool=tuple(g for g in profile.pool if not g.contact or g.contact in keep),
                              posenet=replace(profile.posenet, random_contacts={
                                  c: n for c, n in profile.posenet.random_contacts.items() if c in keep},
                                  random_tap_share={c: share for c, share in profile.posenet.random_tap_share.items()
                                                    if c in keep}))
                for name, profile in config.profiles.items()}
    return replace(config, datasets={name: dataset for name, dataset in config.datasets.items()
                                     if dataset.contact in keep}, profiles=profiles)


def config_and_root(args: argparse.Namespace, contacts: list[str] | None = None) -> tuple[ExperimentConfig, Path]:
    """A pipeline command's experiment config (``args.config`` with its ``--set`` settings, restricted to
    ``contacts``: :func:`only_contacts`) and the data root its paths are relative to (``args.data``)."""
    from simshear_gym.pipelines.config import load_config

    config = only_contacts(load_config(args.config, args.settings), contacts)
    return config, data_root(args.data, holding=config_files(config.datasets.values(), args.config))


def contacts_of(config: ExperimentConfig) -> dict[str, list[str]]:
    """{contact type: its datasets}."""
    out: dict[str, list[str]] = {}
    for name, dataset in config.datasets.items():
        out.setdefault(dataset.contact, []).append(name)
    return out


def variables_for(config: ExperimentConfig, names: list[str], adapted: dict, root: Path) -> str:
    """The inline GDNN variable set of a contact type's datasets: every pose variable that varies in them (an
    angle spanning more than 300 deg as a periodic one), and the sensor-frame shear x, y, Rz where a shear dataset
    moves that way; ranges from the data (written by :func:`~simshear_gym.models.gdnn.variable_spec`)."""
    from simshear_gym.models.gdnn import OutputSpec, VariableSet  # torch: only when a run needs it

    train = {name: read_set(root / adapted[name]["train"]).targets for name in names}
    tables = [table for name in names for table in (train[name], read_set(root / adapted[name]["val"]).targets)]
    targets = pd.concat(tables, ignore_index=True)
    specs = []
    for variable, label in POSE_NAMES.items():
        column = CANONICAL_COLUMNS[variable]
        low, high = float(targets[column].min()), float(targets[column].max())
        if high - low <= 1e-6:
            continue
        unit = label.rpartition("_")[2]
        if unit == "deg" and high - low > 300.0:
            specs.append(OutputSpec(label, unit, -180.0, 180.0, periodic=True, column=column))
        else:
            specs.append(OutputSpec(label, unit, low, high, column=column))
    shear_sets = [name for name in names if config.datasets[name].kind == "shear"]
    if shear_sets:
        moves = pd.concat([train[name] for name in shear_sets])
        for move, label, column in SHEAR_SPECS:
            extent = float(moves[CANONICAL_COLUMNS[move]].abs().max())
            if extent > 1e-6:
                unit = label.rpartition("_")[2]
                reach = extent * (1.5 if unit == "mm" else 1.0)  # x, y rotate into the sensor frame
                specs.append(OutputSpec(label, unit, -reach, reach, column=column))
    return named_set(config.datasets[names[0]].contact, VariableSet("inline", tuple(specs)))


def named_set(contact: str, variables: VariableSet) -> str:
    """The package's named variable set of the contact type (``surface``, ``edge``:
    :data:`~simshear_gym.models.gdnn.VARIABLE_SETS`, the shipped GDNNs' outputs) where the data's ``variables`` (a
    :class:`~simshear_gym.models.gdnn.VariableSet`) are its variables (an edge's Rz as ``edge_angle_deg``), else
    their inline form."""
    from simshear_gym.models.gdnn import VARIABLE_SETS, variable_spec

    named = VARIABLE_SETS.get(contact)
    found = [("edge_angle_deg" if contact == "edge" and v.name == "rz_deg" else v.name, v.column)
             for v in variables.variables]
    if named is not None and found == [(v.name, v.column) for v in named.variables]:
        return contact
    return variable_spec(variables)


# rough relative durations of the training steps, for the schedule's priorities (measured on the 2-core CPU: a
# translator epoch over 10000 pairs about 1.2-2.6 min, a GDNN epoch about 0.4-0.7 min; pose consistency adds the
# reader's passes)
TRANSLATOR_EPOCH_COST = 0.2
POSENET_EPOCH_COST = 0.06
POSE_CONSISTENCY_COST = 1.2


def _translator_settings(stage, contact: str, generator=None) -> dict:
    return {**stage.settings_for(contact), **(generator.replaced() if generator else {})}


def _translator_work(settings: dict, contact: str, names: list[str], arch: str = "shpix2pix") -> dict:
    """A translator step's ``work`` (:class:`~simshear_gym.pipelines.stages.Step`)."""
    return {"trainer": "translator", "contact": contact, "datasets": tuple(names),
            "settings": settings | {"arch": arch}}


def translator_step(config: ExperimentConfig, stage, contact: str, arch: str, train_sets: list[str],
                    generator, runner: StageRunner, done: dict, *, device: str = "auto",
                    reader: str | None = None, start: str | None = None) -> StageResult:
    """A translator of a contact type: its shPix2pix or pix2pix (``generator`` None), or a pool generator
    (:class:`~simshear_gym.pipelines.config.PoolGenerator`; its pose-consistency reader from ``done``: the step
    ``reader``, by default the generator's own; the weights it starts from: the step ``start``'s), trained on
    ``device``."""
    settings = _translator_settings(stage, contact, generator)
    pose_net = ""
    if generator is not None and generator.pose_weight > 0:
        pose_net = done[reader or f"posenet/{contact}_{generator.reader_step}"].outputs["weights"]
        settings |= {"pose_weight": generator.pose_weight, "pose_net": pose_net,
                     "pose_variables": tuple(generator.pose_variables)}
    if start is not None:
        settings |= {"init_weights": done[start].outputs["weights"]}
    key = {"paired": train_sets, "arch": arch, "settings": settings}
    label = generator.name if generator else arch
    name = f"translator/{contact}_{label}"

    def work(folder: Path) -> dict:
        import torch

        from simshear_gym.train.pose_consistency import PoseConsistency
        from simshear_gym.train.translator_config import TranslatorTrainConfig
        from simshear_gym.train.translator_trainer import TranslatorTrainer, export_run, load_pairs

        train_config = TranslatorTrainConfig(arch=arch, paired_dirs=tuple(train_sets),
                                             image_size_px=config.sensor.image_size_px, device=device, **settings)
        torch.set_num_threads(train_config.threads)
        pose = (PoseConsistency(runner.root / pose_net, train_config.pose_variables) if pose_net else None)
        pairs = load_pairs([str(runner.root / d) for d in train_sets], str(runner.root), pose=pose)
        trainer = TranslatorTrainer(train_config, folder / "run", pairs, pose=pose, files_root=runner.root)
        trainer.resume()
        runner.log(training_start_line(name, train_config.epochs, folder / "run" / "tb"))
        report_epochs(trainer, name, runner.log)
        summary = trainer.fit(progress=False)
        path = export_run(folder / "run", folder / f"{label}_{contact}.pt",
                          card={"sensor": config.name, "contact": contact, "arch": arch, "name": label})
        return {"outputs": {"weights": runner.relative(path)}, "metrics": summary}

    return runner.run(name, key, work)


def pool_step(config: ExperimentConfig, stage, contact: str, names: list[str], train_sets: list[str], generator,
              device: str, reader: str | None = None) -> Step:
    """The training step of a pool generator on ``train_sets``; with the pose-consistency loss it needs its reader's
    step (``reader``, by default the generator's own real-image GDNN), with ``start_from`` the step of the
    translator it starts from."""
    needs = ((reader or f"posenet/{contact}_{generator.reader_step}"),) if generator.pose_weight > 0 else ()
    start = (f"translator/{contact}_{generator.start_from}",) if generator.start_from else ()
    settings = _translator_settings(stage, contact, generator)
    return Step(f"translator/{contact}_{generator.name}", partial(
        translator_step, config, stage, contact, "shpix2pix", train_sets, generator, device=device,
        reader=needs[0] if needs else None, start=start[0] if start else None), needs=needs + start,
        cost=TRANSLATOR_EPOCH_COST * settings["epochs"] * (POSE_CONSISTENCY_COST if needs else 1.0),
        work=_translator_work(settings | {"pose_weight": generator.pose_weight}, contact, names))


def arch_step(config: ExperimentConfig, stage, contact: str, arch: str, names: list[str], train_sets: list[str],
              device: str) -> Step:
    """The training step of a contact type's shPix2pix or pix2pix (``arch``) on ``train_sets``."""
    return Step(f"translator/{contact}_{arch}", partial(
        translator_step, config, stage, contact, arch, train_sets, None, device=device),
        cost=TRANSLATOR_EPOCH_COST * stage.epochs_for(contact),
        work=_translator_work(_translator_settings(stage, contact), contact, names, arch))


def gdnn_step(config: ExperimentConfig, stage, contact: str, source: str, names: list[str], train_sets: list[str],
              variables: str, drawn: tuple[tuple[str, int], ...] = (), device: str = "auto", *, name: str = "",
              seed: int | None = None, baseline: bool = False, random_rows: int = 0) -> Step:
    """The training step of a GDNN (:func:`posenet_step`) of a contact type; it needs the translator steps it
    draws from (``drawn``), and is named ``name`` (by default as :func:`posenet_step` names its stage). Its
    ``work`` adds ``random_rows`` random sim contacts to the rows of ``names``. It trains with the stage's settings
    for the contact type; ``seed`` (not None) replaces the stage's seed; ``baseline``: one of the profile's
    comparison GDNNs (trained ``baseline_epochs``)."""
    options = {"device": device, **({"seed": seed} if seed is not None else {})}
    settings = stage.train_settings(contact, baseline) | ({"seed": seed} if seed is not None else {})
    return Step(name or f"posenet/{contact}_{source}{f'_s{seed}' if seed is not None else ''}", partial(
        posenet_step, config, settings, contact, source, train_sets, variables, drawn, **options),
        needs=tuple(step for step, _ in drawn), cost=POSENET_EPOCH_COST * stage.epochs_for(contact, baseline),
        work={"trainer": "posenet", "contact": contact, "datasets": tuple(names), "random_rows": random_rows,
              "settings": settings, "translators": tuple(dict.fromkeys(step for step, _ in drawn))})


def chain_step(config: ExperimentConfig, stage, contact: str, names: list[str], train_sets: list[str],
               random_sets: dict, variables: str, pool, device: str) -> Step:
    """The training step of the GDNN that ships: on the translations of the sim renders of ``train_sets`` (and of
    the contact type's random sim contacts, ``random_sets``), each row through a generator drawn from the contact
    type's shPix2pix and the ``pool`` generators."""
    drawn = ((f"translator/{contact}_shpix2pix", stage.translator_draws_for(contact)),
             *((f"translator/{contact}_{generator.name}", generator.draws) for generator in pool))
    sets = train_sets + ([random_sets[contact]] if contact in random_sets else [])
    return gdnn_step(config, stage, contact, "shpix2pix", names, sets, variables, drawn, device,
                     random_rows=stage.random_contacts.get(contact, 0))


def posenet_step(config: ExperimentConfig, settings: dict, contact: str, source: str, train_sets: list[str],
                 variables: str, translator_steps: tuple[tuple[str, int], ...], runner: StageRunner,
                 done: dict, *, device: str = "auto", seed: int | None = None) -> StageResult:
    """A GDNN of a contact type on the real images (``source`` "real"), on the raw sim renders ("sim") or on
    translations of them (``translator_steps``: the translator steps it draws from, each with its number of
    draws), trained on ``device`` with ``settings`` (its trainer settings, as :func:`gdnn_step` resolves them
    once for the step and its ``work``); ``seed`` (not None: the seed in ``settings``) names the step
    ``<source>_s<seed>`` (a further pose-consistency reader)."""
    used = tuple(path for name, draws in translator_steps for path in [done[name].outputs["weights"]] * draws)
    step_source = f"{source}_s{seed}" if seed is not None else source
    name = f"posenet/{contact}_{step_source}"
    key = {"paired": train_sets, "source": source, "translators": used, "variables": variables,
           "settings": settings}

    def work(folder: Path) -> dict:
        import torch

        from simshear_gym.models.posenet_io import load_posenet, save_posenet
        from simshear_gym.train.posenet_config import PosenetTrainConfig
        from simshear_gym.train.posenet_trainer import PosenetTrainer, load_source

        train_config = PosenetTrainConfig(source=source, contact=contact, paired_dirs=tuple(train_sets),
                                          translators=used, variables=variables, device=device, **settings)
        torch.set_num_threads(train_config.threads)
        data = load_source(source, contact, [str(runner.root / d) for d in train_sets], str(runner.root),
                           train_config.image_size_px, translators=[str(runner.root / t) for t in used],
                           variables=variables, device=device)
        trainer = PosenetTrainer(train_config, folder / "run", data)
        trainer.resume()
        runner.log(training_start_line(name, train_config.epochs, folder / "run" / "tb"))
        report_epochs(trainer, name, runner.log)
        summary = trainer.fit(progress=False)
        model, card = load_posenet(folder / "run" / "best.pt")
        path = folder / f"posenet_{contact}_{step_source}.pt"
        train_record = json.loads((folder / "run" / "config.json").read_text())  # paths relative to the run
        save_posenet(path, model, card={**card, "sensor": config.name, "train_config": train_record})
        return {"outputs": {"weights": runner.relative(path)}, "metrics": summary}

    return runner.run(name, key, work)


def posenet_sources(profile) -> tuple[str, ...]:
    """The GDNNs a profile trains per contact type: the real-image reference, the one on shPix2pix translations
    (it ships) and the profile's baselines."""
    return ("real", "shpix2pix", *profile.posenet.baselines)


def posenet_weights(config: ExperimentConfig, profile, done: dict) -> dict[str, dict[str, str]]:
    """{contact: {source: weights}} of the GDNNs the finished steps ``done`` trained."""
    return {contact: {source: done[f"posenet/{contact}_{source}"].outputs["weights"]
                      for source in posenet_sources(profile)} for contact in contacts_of(config)}


def evaluate_step(config: ExperimentConfig, profile, adapted: dict, paired: dict, variables: dict,
                  runner: StageRunner, done: dict) -> StageResult:
    """Translation and GDNN figures on every dataset's real validation rows (see the module docstring)."""
    translators = {contact: {arch: done[f"translator/{contact}_{arch}"].outputs["weights"]
                             for arch in profile.translator.archs} for contact in contacts_of(config)}
    posenets = {"models": posenet_weights(config, profile, done), "variables": variables}
    key = {"adapted": adapted, "paired": paired, "translators": translators, "posenets": posenets,
           "eval_rows": profile.eval_rows}
    return evaluation_stage(runner, "evaluate", key, config, adapted, paired, translators, posenets,
                            profile.eval_rows)


def evaluation_stage(runner: StageRunner, name: str, key: dict, config: ExperimentConfig, adapted: dict,
                     paired: dict, translators: dict, posenets: dict, eval_rows: int | None) -> StageResult:
    """The stage ``name`` (cached under ``key``) that writes the figures of
    :func:`~simshear_gym.pipelines.evaluation.evaluate_sensor` to its ``evaluation.json``."""

    def work(folder: Path) -> dict:
        from simshear_gym.pipelines.evaluation import evaluate_sensor

        figures = evaluate_sensor(config, runner.root, adapted, paired, translators, posenets, eval_rows)
        write_json(folder / "evaluation.json", figures)
        return {"outputs": {"evaluation": runner.relative(folder / "evaluation.json")}, "metrics": figures["summary"]}

    return runner.run(name, key, work)


def stage_random(runner: StageRunner, config: ExperimentConfig, profile, adapted: dict, workers: int) -> dict:
    """{contact: path of its random-contact set} for the contacts the profile gives ``random_contacts``."""
    from simshear_gym.sim.collect import CollectConfig, random_set  # pybullet: only when the stage runs

    collect_config = CollectConfig(tactip=config.sensor, geometry=config.replay, workers=workers)
    out = {}
    for contact, names in contacts_of(config).items():
        n = profile.posenet.random_contacts.get(contact, 0)
        if not n:
            continue
        ranges = label_ranges(config, names, adapted, runner.root)
        tap_share = float(profile.posenet.random_tap_share.get(contact, 0.0))
        seed = profile.posenet.setting("seed")
        key = {"contact": contact, "n": n, "seed": seed, "ranges": ranges, "tactip": config.sensor,
               "geometry": config.replay, "shear": collect_config.shear}
        if tap_share:  # a set without taps keeps the key it had before there could be any
            key["tap_share"] = tap_share

        def work(folder: Path, contact=contact, n=n, ranges=ranges, tap_share=tap_share) -> dict:
            rows = random_set(contact, n, seed, folder / "set", collect_config, ranges, tap_share)
            return {"outputs": {"set": runner.relative(folder / "set")}, "metrics": {"rows": rows}}

        out[contact] = runner.run(f"collect/random_{contact}", key, work).outputs["set"]
    return out


def label_ranges(config: ExperimentConfig, names: list[str], adapted: dict, root: Path) -> dict:
    """{label column: [low, high]} over a contact type's training rows: the pose columns of every dataset, the
    move columns of its shear datasets; constant columns left out."""
    train = {name: read_set(root / adapted[name]["train"]).targets for name in names}
    ranges = {}
    for variable, column in CANONICAL_COLUMNS.items():
        sets = [name for name in names if variable.startswith("pose") or config.datasets[name].kind == "shear"]
        if not sets:
            continue
        values = pd.concat([train[name][column] for name in sets])
        low, high = float(values.min()), float(values.max())
        if high - low > 1e-6:
            ranges[column] = [low, high]
    return ranges


def training_steps(config: ExperimentConfig, profile, adapted: dict, paired: dict, random_sets: dict,
                   variables: dict, stages: tuple[str, ...], device: str | None = None) -> list[Step]:
    """The translator, GDNN and evaluation steps of the run, with what each needs (:func:`.stages.run_steps`); the
    training steps train on ``device`` (None: the profile's)."""
    device = device or profile.device
    steps = []
    for contact, names in contacts_of(config).items():
        train_sets = [paired[name]["train"] for name in names]
        if "translator" in stages:
            steps += [arch_step(config, profile.translator, contact, arch, names, train_sets, device)
                      for arch in profile.translator.archs]
            steps += [pool_step(config, profile.translator, contact, names, train_sets, generator, device)
                      for generator in profile.pool_for(contact)]
        if "posenet" in stages:
            gdnn = partial(gdnn_step, config, profile.posenet, contact)
            steps.append(gdnn("real", names, train_sets, variables[contact], device=device))
            steps += [gdnn("real", names, train_sets, variables[contact], device=device, seed=reader_seed)
                      for reader_seed in sorted({g.reader_seed for g in profile.pool_for(contact) if g.reader_seed})]
            steps.append(chain_step(config, profile.posenet, contact, names, train_sets, random_sets,
                                    variables[contact], profile.pool_for(contact), device))
            for source in profile.posenet.baselines:
                drawn = ((f"translator/{contact}_pix2pix", 1),) if source == "pix2pix" else ()
                steps.append(gdnn(source, names, train_sets, variables[contact], drawn, device, baseline=True))
    if "evaluate" in stages:
        steps.append(Step("evaluate", partial(evaluate_step, config, profile, adapted, paired, variables),
                          needs=tuple(step.name for step in steps), cost=0.3))
    return steps


ONNX_PRECISION = "fp16"  # as the shipped exports (simshear ship onnx's default)
ONNX_CHECK_ROWS = 64  # validation rows per data set in the check
ONNX_LATENCY_REPEATS = 100


def stage_onnx(runner: StageRunner, translators: dict[str, str], paired: dict, datasets: dict[str, list[str]],
               log: Callable[[str], None] | None = None) -> dict[str, str]:
    """{contact: path of its translator's ONNX export, relative to the run folder} for ``translators`` ({contact:
    weights relative to the run folder}); ``paired``: {dataset: {split: paired set}}, ``datasets``: {contact: its
    datasets}. Empty where the export extra is missing (one line to ``log``, the runner's by default)."""
    missing = onnx_export.missing_export_packages()
    if missing:
        (log or runner.log)(f"[onnx] skipped: exporting the translators to ONNX needs {', '.join(missing)} (pip "
                            "install -e '.[export]'); an env with sensor= runs them on torch")
        return {}
    exported = {}
    for contact, relative in translators.items():
        weights = runner.root / relative
        sets = [paired[name]["val"] for name in datasets[contact]]
        key = {"weights": relative, "sha256": file_sha256(weights), "precision": ONNX_PRECISION,
               "opset": onnx_export.OPSET, "check_sets": sets, "check_rows": ONNX_CHECK_ROWS}

        def work(folder: Path, weights=weights, sets=sets, contact=contact) -> dict:
            to = onnx_path_for(weights)
            model, torch_card, config = onnx_export.export_model(weights, ONNX_PRECISION)
            check = check_export(model.SerializeToString(), weights, [runner.root / s for s in sets], runner.root)
            record = {"arch": "shpix2pix" if config.shear_dim else "pix2pix", "contact": contact,
                      "source": weights.name, "precision": ONNX_PRECISION, "pipeline_stage": runner.relative(folder),
                      "config": asdict(config), "card": {"torch_card": torch_card, "check": check}}
            size_bytes = onnx_export.write_export(model, weights, to, record)
            return {"outputs": {"onnx": runner.relative(to)}, "metrics": {**check, "size_bytes": size_bytes}}

        exported[contact] = runner.run(f"onnx/{contact}_shpix2pix", key, work).outputs["onnx"]
    return exported


def check_export(model_bytes: bytes, weights: Path, val_sets: list[Path], root: Path,
                 rows: int = ONNX_CHECK_ROWS) -> dict:
    """Torch and ONNX Runtime side by side on the first ``rows`` rows of each paired validation set, and their
    batch-1 latency on one thread: {"sets": {set folder name: figures}, "latency": {...}}."""
    from simshear_gym.contract import resize_tactile
    from simshear_gym.data.labels import SHEAR_COLUMNS
    from simshear_gym.data.paired import load_paired
    from simshear_gym.evaluate.metrics import mape

    both = onnx_export.SideBySide(model_bytes, weights)
    size = both.torch_translator.image_size_px
    sets = {}
    for folder in val_sets:
        paired, real_set = load_paired(folder, root)
        sim = resize_tactile(paired.load_images(use_cache=False)[:rows], size)
        shear = paired.targets[list(SHEAR_COLUMNS)].to_numpy(np.float32)[:rows]
        by_torch, by_onnx = both.translate(sim, shear)
        figures = {"rows": len(sim), **onnx_export.difference(by_torch, by_onnx)}
        if real_set is not None:
            real = resize_tactile(real_set.load_images(use_cache=False)[:rows], size)
            figures |= {"mape_torch": float(mape(by_torch, real).mean()),
                        "mape_onnx": float(mape(by_onnx, real).mean())}
        sets[f"{Path(folder).parent.parent.name}_{Path(folder).name}"] = figures
    return {"sets": sets, "latency": both.latency(ONNX_LATENCY_REPEATS)}


def run_pipeline(config: ExperimentConfig, out: Path, root: Path, profile: str, stages: tuple[str, ...],
                 rows_per_split: int | None = None, workers: int = 2, jobs: int | None = None,
                 device: str | None = None) -> dict:
    """Run the stages (each cached; the training steps as a graph, ``jobs`` at a time: :func:`.stages.run_steps`) and
    write ``out/manifest.json``; returns the manifest.

    ``rows_per_split``, ``jobs`` and ``device`` override the profile's (None: the profile's)."""
    missing = [stage for stage in STAGES[:max(STAGES.index(s) for s in stages) + 1] if stage not in stages]
    if missing:
        raise ValueError(f"stages {list(stages)} need the stages before them too: add {missing}")
    profile_settings = config.profile(profile)
    rows_per_split = rows_per_split if rows_per_split is not None else profile_settings.rows_per_split
    jobs = jobs or profile_settings.jobs
    device = check_device_name(device or profile_settings.device)
    out.mkdir(parents=True, exist_ok=True)
    runner = StageRunner(out)
    if profile in PLUMBING_PROFILES:
        runner.log(f"profile {profile}: {PLUMBING_PROFILES[profile]}")
    start, commit = time.perf_counter(), git_commit()  # the code the run starts on (a commit during it is not)
    adapted = stage_adapt(runner, config, root, rows_per_split)
    paired = stage_collect(runner, config, adapted, workers) if "collect" in stages else None
    results = list(runner.results)
    translators = posenets = evaluation = None
    onnx: dict[str, str] = {}
    if "translator" in stages:
        variables = {contact: variables_for(config, names, adapted, runner.root)
                     for contact, names in contacts_of(config).items()}
        random_sets = stage_random(runner, config, profile_settings, adapted, workers) if "posenet" in stages else {}
        results = list(runner.results)
        steps = training_steps(config, profile_settings, adapted, paired, random_sets, variables, stages, device)
        done = run_steps(steps, out, jobs, log=runner.log)
        results += [done[step.name] for step in steps]
        translators = {contact: {name.split("_", 1)[1]: result.outputs["weights"]
                                 for name, result in done.items() if name.startswith(f"translator/{contact}_")}
                       for contact in contacts_of(config)}
        if "posenet" in stages:
            posenets = {"models": posenet_weights(config, profile_settings, done), "variables": variables}
        evaluation = done["evaluate"].record if "evaluate" in stages else None
        exports_from = len(runner.results)
        shipped = {contact: archs["shpix2pix"] for contact, archs in translators.items()}  # sensor.json names them
        onnx = stage_onnx(runner, shipped, paired, contacts_of(config))
        results += runner.results[exports_from:]
        if translators and posenets:
            write_sensor(out, config.name, str(config.path), profile, asdict(config.sensor), translators=shipped,
                         posenets={contact: models["shpix2pix"] for contact, models in posenets["models"].items()},
                         variables=posenets["variables"], onnx=onnx)
    machine = machine_info()  # its packages' versions: the package's own, None where it is not installed
    manifest = {
        "config": str(config.path), "settings": list(config.settings), "sensor": config.name, "profile": profile,
        **({"purpose": PLUMBING_PROFILES[profile]} if profile in PLUMBING_PROFILES else {}), "stages": list(stages),
        "package_version": machine["packages"]["simshear-gym"] or "unknown", "git_commit": commit, "machine": machine,
        "wall_s": round(time.perf_counter() - start, 2),
        "seeds": {"translator": profile_settings.translator.setting("seed"),
                  "posenet": profile_settings.posenet.setting("seed")},
        "jobs": jobs, "device": device, "contacts": sorted(contacts_of(config)),
        "results": [{"stage": r.name, "folder": runner.relative(r.folder), "ran": r.ran,
                     "wall_s": r.record["wall_s"], "metrics": r.record["metrics"]} for r in results],
        "models": {"translators": translators, "posenets": posenets, "onnx": onnx},
        "evaluation": evaluation["outputs"]["evaluation"] if evaluation else None,
    }
    write_json(out / "manifest.json", manifest)
    return manifest


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    add_set_argument(parser)
    parser.add_argument("--profile", default="quick", help="stage settings: smoke (seconds), quick (a laptop, under "
                        "30 min) or full (the shipped recipe)")
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES),
                        help="stages to run (each needs the ones before it; cached ones are reused)")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default runs/pipeline/<sensor>)")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--rows", type=int, default=None, help="first N rows of each split only (default: all)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes of the collect stage")
    parser.add_argument("--jobs", type=int, default=None, help="training steps side by side, each in its own "
                        "process (default: the profile's jobs)")
    parser.add_argument("--device", choices=DEVICES, default=None,
                        help="where the training steps train: auto (CUDA where torch finds it, else the CPU), cpu or "
                             "cuda (default: the profile's device, auto unless the config says otherwise)")
    parser.add_argument("--contacts", nargs="+", default=None, metavar="CONTACT",
                        help="only these contact types' datasets (default: all); their stages keep their cache keys")


def run(args: argparse.Namespace) -> int:
    config, root = config_and_root(args, args.contacts)
    out = args.out or Path(DEFAULT_PIPELINE_RUNS) / config.name
    try:
        with stop_on_signals():
            manifest = run_pipeline(config, out, root, args.profile, tuple(args.stages), args.rows,
                                    args.workers, args.jobs, getattr(args, "device", None))
    except RunStopped as stopped:  # the pools were ended on the way out; anything left is ended here
        end_children()
        print(f"simshear: error: pipeline run {out}: {stopped}", file=sys.stderr)
        return 128 + stopped.signum
    ran = sum(result["ran"] for result in manifest["results"])
    print(f"{config.name}: {len(manifest['results'])} stage steps ({ran} ran, "
          f"{len(manifest['results']) - ran} cached) in {manifest['wall_s']:.1f} s; manifest {out / 'manifest.json'}")
    if "purpose" in manifest:
        print(f"profile {args.profile} is {manifest['purpose']}")
    return 0
