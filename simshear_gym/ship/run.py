"""``simshear ship run RUN [--to DIR]``: a finished pipeline run's models become the package's shipped weights.

For each contact type of the run (``RUN/manifest.json``): its shPix2pix and pix2pix translators and its GDNN trained
on translated images go where the shipped ones lie in DIR (by default the package's shipped folder; the layout:
:mod:`simshear_gym.models.zoo`). Each file keeps its training record and gains the run's (config, profile, stage
folder, git commit) and a check figure that the tests reproduce (``tests/test_shipped_translator.py``,
``tests/test_shipped_posenet.py``); beside it a card (``.md``): data, settings, the exact commands, the metrics of
the run's evaluation on the real validation rows, date. Each shPix2pix is also exported to the ``.onnx`` the envs
run (``simshear ship onnx``; where the ``export`` extra is missing, the old ``.onnx`` is removed instead).
Nothing is trained: shipping a run twice gives the same files, so the shipped weights are exactly what
``simshear pipeline run CONFIG --profile P`` produced. ``--contacts`` and ``--models`` (translators, posenet) ship a
part of the run.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.models.translator_runtime import onnx_path_for
from simshear_gym.models.zoo import WEIGHTS_DIR, posenet_file, translator_file
from simshear_gym.ship import cards

CHECK_ROWS = {"translator": 16, "posenet": 64}  # rows of the real <contact>_shear val set in the check figures


def read_run(run: Path) -> tuple[dict, dict, dict]:
    """(manifest, evaluation, {stage: record}) of a finished run; a clear error for anything else."""
    path = run / "manifest.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: ship a folder written by `simshear pipeline run`")
    manifest = json.loads(path.read_text())
    if not manifest.get("evaluation") or not (manifest.get("models") or {}).get("posenets"):
        raise ValueError(f"{path}: the run stopped before its evaluate stage (stages {manifest.get('stages')}); "
                         "ship a run of every stage")
    evaluation = json.loads((run / manifest["evaluation"]).read_text())
    records = {record["stage"]: record for record in manifest["results"]}
    return manifest, evaluation, records


MODEL_KINDS = ("translators", "posenet")
"""What ``ship --models`` may name: a contact type's translators (shPix2pix, pix2pix, the ONNX export) and its GDNN."""


def ship(run: Path, to: Path = WEIGHTS_DIR, data: str | None = None, date: str | None = None,
         contacts: tuple[str, ...] | None = None, models: tuple[str, ...] = MODEL_KINDS) -> list[Path]:
    """Write the run's models and cards under ``to`` (see the module docstring), of the contact types in
    ``contacts`` only where given and of the kinds in ``models`` (:data:`MODEL_KINDS`; the others' shipped files
    stay: a GDNN shipped alone reads the images of translators the run did not ship); returns the files written."""
    from simshear_gym.models.posenet_io import load_posenet, save_posenet
    from simshear_gym.models.translator import load_generator, save_generator
    from simshear_gym.ship import posenet, translator

    if not models or set(models) - set(MODEL_KINDS):
        raise ValueError(f"models must name some of {list(MODEL_KINDS)}, got {list(models)}")
    manifest, evaluation, records = read_run(run)
    date = date or datetime.date.today().isoformat()
    made = manifest["models"]["translators"]
    unknown = sorted(set(contacts or ()) - set(made))
    if unknown:
        raise ValueError(f"{run}: no models of contact type(s) {unknown} in this run; it has {sorted(made)}")
    from simshear_gym.pipelines import run as pipeline_run

    run_args = argparse.Namespace(config=manifest["config"], profile=manifest["profile"],
                                  contacts=_restricted_contacts(manifest), out=run)
    ship_args = argparse.Namespace(run=run, contacts=list(contacts) if contacts else None,
                                   models=[kind for kind in MODEL_KINDS if kind in models])
    commands = [recorded_command("simshear pipeline run", pipeline_run.add_arguments, run_args),
                recorded_command("simshear ship run", add_arguments, ship_args)]
    written = []
    for contact, archs in made.items():
        if contacts and contact not in contacts:
            continue
        for arch in ("shpix2pix", "pix2pix") if "translators" in models else ():
            stage = f"translator/{contact}_{arch}"
            dest = translator_file(arch, contact, to)
            generator, card = load_generator(run / archs[arch])
            card = {**card, "pipeline": _provenance(manifest, records[stage]), "train_command": " && ".join(commands)}
            save_generator(dest, generator, card=card)
            card["check"] = translator.check_figure(dest, contact, CHECK_ROWS["translator"], data)
            save_generator(dest, generator, card=card)
            written += [dest, _write(dest, cards.pipeline_translator_card(
                dest, arch, contact, card, _parameters(dest), manifest, evaluation, records[stage],
                _datasets(manifest, contact), commands, date))]
            if arch == "shpix2pix":
                written += _onnx_beside(dest, data)
        if "posenet" not in models:
            continue
        stage = f"posenet/{contact}_shpix2pix"
        dest = posenet_file(contact, to)
        model, card = load_posenet(run / manifest["models"]["posenets"]["models"][contact]["shpix2pix"])
        card = {**card, "contact": contact, "train_command": " && ".join(commands),
                "variables": list(model.variables.names), "parameters": sum(p.numel() for p in model.parameters()),
                "pipeline": _provenance(manifest, records[stage])}
        save_posenet(dest, model, card)
        card["check"] = posenet.check_figure(dest, contact, CHECK_ROWS["posenet"], data)
        save_posenet(dest, model, card)
        written += [dest, _write(dest, cards.pipeline_posenet_card(
            dest, contact, card, manifest, evaluation, records[stage], _datasets(manifest, contact), commands, date))]
    return written


def _restricted_contacts(manifest: dict) -> list[str] | None:
    """The run's contact types where it was restricted to some of its config's, else None."""
    from simshear_gym.pipelines.config import load_config

    contacts = manifest.get("contacts")
    if not contacts:
        return None
    try:
        every = {dataset.contact for dataset in load_config(manifest["config"]).datasets.values()}
    except (OSError, ValueError):  # the config moved: name the contacts anyway
        every = set()
    return None if set(contacts) == every else list(contacts)


def _onnx_beside(weights: Path, data: str | None) -> list[Path]:
    """The envs' ONNX translator beside newly shipped shPix2pix weights: exported from them where the export extra
    is installed; else the old ``.onnx`` (and card) are removed (the envs' ``auto`` runtime would skip them anyway:
    their recorded sha256 no longer matches) and the command to export them is printed."""
    from simshear_gym.models.onnx_export import missing_export_packages
    from simshear_gym.ship import onnx as ship_onnx

    onnx_path = onnx_path_for(weights)
    if missing_export_packages():
        for stale in (onnx_path, onnx_path.with_name(onnx_path.name + ".md")):
            stale.unlink(missing_ok=True)
        print(f"note: {onnx_path} not written (the export extra is not installed); the envs run the torch "
              f"translator until: pip install -e '.[export]' && simshear ship onnx --weights {weights}")
        return []
    exported = ship_onnx.export(weights, onnx_path, translation_results=None, data=data)
    return [exported["onnx"], exported["card"]]


def _provenance(manifest: dict, record: dict) -> dict:
    return {"config": manifest["config"], "profile": manifest["profile"], "stage": record["folder"],
            "git_commit": manifest["git_commit"], "package_version": manifest["package_version"]}


def _write(weights: Path, text: str) -> Path:
    from simshear_gym.io import atomic_write

    return atomic_write(weights.with_suffix(".md"), lambda tmp: Path(tmp).write_text(text))


def _datasets(manifest: dict, contact: str) -> list[str]:
    """The run's datasets of a contact type (from its config)."""
    from simshear_gym.pipelines.config import load_config

    return [name for name, dataset in load_config(manifest["config"]).datasets.items() if dataset.contact == contact]


def _parameters(weights: Path) -> int:
    from simshear_gym.models.weights_io import read_weights

    payload = read_weights(weights, "model")  # weights_only, its sha256 checked, one clear error
    return sum(value.numel() for value in payload["state_dict"].values())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="a finished run folder of `simshear pipeline run` (its manifest.json)")
    parser.add_argument("--to", type=Path, default=WEIGHTS_DIR,
                        help="weights folder (default: the package's shipped models)")
    parser.add_argument("--data", default=None,
                        help="data root of the check figures (default: $SIMSHEAR_DATA, else ../shared/data)")
    parser.add_argument("--contacts", nargs="+", default=None, metavar="CONTACT",
                        help="ship only these contact types' models (default: every one the run made)")
    parser.add_argument("--models", nargs="+", default=list(MODEL_KINDS), choices=MODEL_KINDS,
                        help="ship only these kinds: translators (shPix2pix, pix2pix, ONNX) and/or posenet (the GDNN "
                             "on translated images); default both")


def run(args: argparse.Namespace) -> int:
    for path in ship(args.run, args.to, args.data, contacts=tuple(args.contacts) if args.contacts else None,
                     models=tuple(args.models)):
        print(f"wrote {path}")
    return 0
