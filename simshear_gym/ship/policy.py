"""Ship a policy of ``simshear train rl``: ``simshear ship policy --run RUN --to DIR --train-command ...``.

A shipped policy is a folder, the layout :meth:`~simshear_gym.control.policy.SB3Controller.load` reads, with no
pickle in it: ``model.pt`` and ``model.json`` (the policy's pickle-free files,
:mod:`~simshear_gym.control.policy_files`: its network's state dict, and what rebuilds it with the sha256 of the
``.pt``; the run's ``best_model`` by default, ``--model final``: its ``model``), ``vecnormalize.json`` (that model's
VecNormalize statistics), ``config.json`` (the run's settings, so the benchmark and the robot rebuild the observation
it was trained on, plus the sha256 of the translator and GDNN that made its observations at export) and the card
``model.md``: the exact command, the budget and the seed, the run's own evaluations and, with ``--results``, the
figures of ``simshear evaluate servo`` on it.

A run of an older simshear has only SB3's ``.zip`` and a pickled ``vecnormalize.pkl``: ``--trust-pickle`` converts
them (by unpickling: only for runs you made yourself), and ``--convert DIR --trust-pickle`` converts a shipped
folder of that kind in place, keeping its settings and card.

``simshear evaluate servo --variants ppo --policy-ppo DIR/model.pt`` and ``simshear rollout --policy
DIR/model.pt`` load it like a run folder.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.io import atomic_write, recorded_path, write_json
from simshear_gym.models.zoo import estimator_file
from simshear_gym.ship.cards import converted_card, policy_card

SHIPPED_FILES = ("model.pt", "model.json", "vecnormalize.json", "config.json", "model.md")
"""The files of a shipped policy."""
PICKLES = ("model.zip", "vecnormalize.pkl")
"""The pickle-bearing files of older shipped policies (removed by a conversion)."""
MODEL_CHOICES = ("best", "final")
ENV_MODELS = {"tracking": ("SimShearTracking-v0", "surface"), "colift": ("SimShearCoLift-v0", "colift"),
              "edge": ("SimShearEdgeFollow-v0", "edge"), "push": ("SimShearPush-v0", "surface")}
"""task -> (env id, the shipped GDNN its estimate observation reads; the translator is of the same contact: edge
for the edge GDNN, surface otherwise)."""


def source_files(run: Path, model: str) -> tuple[Path, Path | None]:
    """The model of a run (``best``: ``best_model``, ``final``: ``model``; its SB3 ``.zip`` path, whose pickle-free
    files lie beside it) and its VecNormalize statistics (``.json``; an older run's ``.pkl``; None for a run without
    normalisation).

    Raises:
        FileNotFoundError: the run lacks that model or its ``config.json``.
    """
    from simshear_gym.control.policy import RUN_CONFIG, vecnormalize_path
    from simshear_gym.control.policy_files import has_policy_files

    if model not in MODEL_CHOICES:
        raise ValueError(f"model must be one of {MODEL_CHOICES}, got {model!r}")
    if not (run / RUN_CONFIG).is_file():
        raise FileNotFoundError(f"{run} is not a run of simshear train rl: no {RUN_CONFIG}")
    zip_path = run / ("best_model.zip" if model == "best" else "model.zip")
    if not zip_path.is_file() and not has_policy_files(zip_path):
        hint = " (the run never evaluated: pass --model final, or train with --eval-steps)" if model == "best" else ""
        raise FileNotFoundError(f"no {zip_path.name} in {run}{hint}")
    config = json.loads((run / RUN_CONFIG).read_text())
    stats = vecnormalize_path(zip_path) or vecnormalize_path(zip_path, ".pkl")
    if config.get("normalize", True) and stats is None:
        raise FileNotFoundError(f"{zip_path} was trained with VecNormalize but its statistics are missing in {run}")
    return zip_path, stats


def write_policy_files(zip_path: Path, stats: Path | None, to: Path, trust_pickle: bool = False) -> None:
    """``to/model.pt``, ``to/model.json`` and ``to/vecnormalize.json`` from a model and its statistics: copied
    where they are pickle-free, else (``trust_pickle``) converted by loading the SB3 ``.zip`` / ``.pkl``.

    Raises:
        PolicyFileError: a pickle to convert without ``trust_pickle``.
    """
    from simshear_gym.control.policy import load_normalizer, sb3_algorithm, sb3_class
    from simshear_gym.control.policy_files import (
        PolicyFileError,
        has_policy_files,
        load_policy,
        policy_files,
        save_normalizer,
        save_policy,
    )

    if has_policy_files(zip_path):
        load_policy(zip_path)  # whole and loadable (its sha256 checked) before it ships
        for source, target in zip(policy_files(zip_path), policy_files(to / "model.pt")):
            atomic_write(target, lambda tmp, source=source: shutil.copyfile(source, tmp))
        # the description names its weights file: model.pt now
        description = json.loads((to / "model.json").read_text())
        write_json(to / "model.json", {**description, "weights": "model.pt"})
    elif not trust_pickle:
        raise PolicyFileError(f"{zip_path}: a Stable-Baselines3 .zip without pickle-free policy files (a run of an "
                              "older version); converting it unpickles it, which runs whatever code it carries: "
                              "pass --trust-pickle if you made this run yourself")
    else:
        save_policy(sb3_class(sb3_algorithm(zip_path)).load(zip_path, device="cpu"), to / "model.pt")
    if stats is None:
        (to / "vecnormalize.json").unlink(missing_ok=True)
    elif stats.suffix == ".json":
        atomic_write(to / "vecnormalize.json", lambda tmp: shutil.copyfile(stats, tmp))
    else:
        save_normalizer(load_normalizer(stats, trust_pickle), to / "vecnormalize.json")
    for name in PICKLES:
        (to / name).unlink(missing_ok=True)


def convert_shipped(folder: Path, trust_pickle: bool = False) -> Path:
    """Convert a shipped policy of an older version (``model.zip``, ``vecnormalize.pkl``) in place to the
    pickle-free files, keeping its ``config.json`` and card (whose file list is updated); returns the card.

    Raises:
        FileNotFoundError: not a shipped policy folder with a ``model.zip``.
        PolicyFileError: without ``trust_pickle``.
    """
    folder = Path(folder)
    if not (folder / "model.zip").is_file() or not (folder / "model.md").is_file():
        raise FileNotFoundError(f"{folder}: not an older shipped policy (expected model.zip and model.md)")
    stats = folder / "vecnormalize.pkl"
    write_policy_files(folder / "model.zip", stats if stats.is_file() else None, folder, trust_pickle)
    command = recorded_command("simshear ship policy", add_arguments,
                               argparse.Namespace(convert=recorded_path(folder), trust_pickle=True))
    card = converted_card((folder / "model.md").read_text(), folder, command)
    atomic_write(folder / "model.md", lambda tmp: Path(tmp).write_text(card), suffix=".md")
    return folder / "model.md"


def model_hashes(task: str) -> dict[str, str]:
    """sha256 of the shipped translator and GDNN that make a task's estimate observation now."""
    from simshear_gym.models.translator_runtime import file_sha256

    posenet = ENV_MODELS[task][1]
    contact = "edge" if posenet == "edge" else "surface"
    names = (f"translator_shpix2pix_{contact}", f"posenet_{posenet}")
    return {name: file_sha256(estimator_file(name)) for name in names}


def export(run: Path, to: Path, train_command: str, model: str = "best", results: Path | None = None,
           variant: str = "ppo", date: str | None = None, trust_pickle: bool = False) -> Path:
    """Write a run's policy into ``to`` as pickle-free files (:func:`write_policy_files`; ``trust_pickle``: convert
    an older run's pickles) and its card; returns the card's path."""
    run, to = Path(run), Path(to)
    zip_path, stats = source_files(run, model)
    config = json.loads((run / "config.json").read_text())
    to.mkdir(parents=True, exist_ok=True)
    write_policy_files(zip_path, stats, to, trust_pickle)
    provenance = {"train_command": train_command, "exported_from": f"{run.name}/{zip_path.name}",
                  "estimator_models_sha256": model_hashes(config["task"])}
    write_json(to / "config.json", {**config, "provenance": provenance})
    evaluations = _read_json(run / "evaluations.json").get("evaluations", [])
    summary = _read_json(run / "summary.json")
    servo = _read_json(results) if results is not None else {}
    card = policy_card(config, provenance, to, model, evaluations, summary, servo, variant,
                       _export_command(to, model, results, variant), date or datetime.date.today().isoformat(),
                       ENV_MODELS[config["task"]])
    atomic_write(to / "model.md", lambda tmp: Path(tmp).write_text(card), suffix=".md")
    return to / "model.md"


def _read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text()) if Path(path).is_file() else {}


def _export_command(to: Path, model: str, results: Path | None, variant: str) -> str:
    """The export's command line, its run folder ``RUN`` (a local path) and its train command left out."""
    args = argparse.Namespace(run="RUN", to=recorded_path(to), model=model,
                              results=recorded_path(results) if results else None, variant=variant)
    return recorded_command("simshear ship policy", add_arguments, args)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", type=Path, default=None, help="run folder of simshear train rl")
    parser.add_argument("--to", type=Path, default=None,
                        help="the policy's folder (a shipped one: simshear_gym.models.zoo.POLICY_DIR / NAME)")
    parser.add_argument("--model", choices=MODEL_CHOICES, default="best",
                        help="best: the run's best evaluated model (best_model), final: its last (model)")
    parser.add_argument("--train-command", default=None, help="the exact simshear train rl command of the run")
    parser.add_argument("--results", type=Path, default=None,
                        help="a results/*.json of simshear evaluate servo on this policy, quoted in the card")
    parser.add_argument("--variant", default="ppo", help="the policy's variant name in --results (ppo, sac, ...)")
    parser.add_argument("--date", default=None, help="the card's date (default today)")
    parser.add_argument("--convert", type=Path, default=None, metavar="DIR",
                        help="instead of exporting a run: convert a shipped policy folder of an older version "
                             "(model.zip, vecnormalize.pkl) in place to pickle-free files (needs --trust-pickle)")
    parser.add_argument("--trust-pickle", action="store_true",
                        help="convert SB3 .zip / vecnormalize.pkl files of an older version by unpickling them. A "
                             "pickle runs whatever code it carries when loaded (a crafted policy file is a program): "
                             "only for files you made yourself, never for policies from e-mail or shared drives")


def run(args: argparse.Namespace) -> int:
    if args.convert is not None:
        card = convert_shipped(args.convert, args.trust_pickle)
        print(f"converted {args.convert} to pickle-free files ({', '.join(SHIPPED_FILES)}); card {card}")
        return 0
    missing = [flag for flag, value in (("--run", args.run), ("--to", args.to),
                                        ("--train-command", args.train_command)) if value is None]
    if missing:
        raise ValueError(f"ship policy needs {' and '.join(missing)} (or --convert DIR)")
    card = export(args.run, args.to, args.train_command, args.model, args.results, args.variant, args.date,
                  args.trust_pickle)
    print(f"wrote {args.to / 'model.pt'} and {card}")
    return 0
