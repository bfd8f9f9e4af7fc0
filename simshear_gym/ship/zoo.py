"""Every shipped model as a folder in the Hugging Face Hub layout: ``simshear ship zoo --to DIR``.

One folder per model of :func:`~simshear_gym.models.zoo.shipped_models` (``translator_<arch>_<contact>``,
``posenet_<name>``, ``policy_<name>``), each ready to upload as a Hub repository and loadable by path (or, once
uploaded, by its Hub id: :func:`~simshear_gym.models.zoo.model_path`):

- a translator or GDNN: ``config.json``, ``model.safetensors`` and ``README.md``
  (:mod:`~simshear_gym.models.zoo_format`; the ``.pt``'s tensors bit for bit, fp16 translators stay fp16);
- a policy: its folder with ``model.safetensors`` for ``model.pt`` (``model.json`` naming it, with its sha256) and
  ``README.md`` for ``model.md``; ``config.json`` (its run's settings) and ``vecnormalize.json`` as they are.

Each converted model is loaded back and its state dict compared with the shipped one's, tensor by tensor (equal, or
the command fails naming it). The shipped ``.pt`` files stay as they are.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

POLICY_CARD = "model.md"


def _weights_kinds() -> dict:
    """kind -> (model class name, loader of a ``.pt`` file or a zoo folder)."""
    from simshear_gym.models.gdnn import GDNN
    from simshear_gym.models.posenet_io import load_posenet
    from simshear_gym.models.translator import load_generator
    from simshear_gym.models.unet import UNetGenerator

    return {"translator": (UNetGenerator.__name__, load_generator), "posenet": (GDNN.__name__, load_posenet)}


def _same_tensors(source: dict, converted: dict, where: Path) -> None:
    import torch

    differ = sorted(key for key in source.keys() | converted.keys()
                    if key not in source or key not in converted or source[key].dtype != converted[key].dtype
                    or not torch.equal(source[key], converted[key]))
    if differ:
        raise ValueError(f"{where}: the converted weights differ from the shipped ones in {differ[:5]}")


def convert_weights(kind: str, source: Path, target: Path) -> Path:
    """A shipped translator or GDNN ``.pt`` (with its card ``<file>.md``) as a zoo folder, checked."""
    from simshear_gym.models.zoo_format import convert_file

    model_class, load = _weights_kinds()[kind]
    card = source.with_suffix(".md")
    convert_file(source, target, model_class, kind, card.read_text() if card.is_file() else None)
    shipped, converted = load(source)[0], load(target)[0]
    _same_tensors(shipped.state_dict(), converted.state_dict(), target)
    return target


def convert_policy(source: Path, target: Path) -> Path:
    """A shipped policy folder as a zoo folder (``model.safetensors``, ``README.md``), checked."""
    from simshear_gym.control.policy_files import (
        FOLDER_MODEL,
        SAFETENSORS_SUFFIX,
        PolicyFileError,
        load_weights,
        policy_files,
        read_description,
    )
    from simshear_gym.io import atomic_folder, file_sha256, write_json
    from simshear_gym.models.zoo_format import write_safetensors

    description_path, weights = policy_files(source / FOLDER_MODEL)
    description = read_description(description_path)
    if file_sha256(weights) != description.get("weights_sha256"):
        raise PolicyFileError(f"{weights}: its sha256 differs from the one recorded in {description_path.name}")
    state = load_weights(weights, "policy")
    safetensors_name = Path(FOLDER_MODEL).with_suffix(SAFETENSORS_SUFFIX).name

    def write(tmp: Path) -> None:
        for item in sorted(source.iterdir()):
            if item.is_file() and item.name not in (weights.name, description_path.name, POLICY_CARD):
                shutil.copyfile(item, tmp / item.name)
        write_safetensors(tmp / safetensors_name, state)
        write_json(tmp / description_path.name, {**description, "weights": safetensors_name,
                                                  "weights_sha256": file_sha256(tmp / safetensors_name)})
        if (source / POLICY_CARD).is_file():
            shutil.copyfile(source / POLICY_CARD, tmp / "README.md")

    atomic_folder(target, write)
    _same_tensors(state, load_weights(policy_files(target)[1], "policy"), target)
    return target


def convert(kind: str, source: Path, target: Path) -> Path:
    """One shipped model of ``kind`` (``translator``, ``posenet``, ``policy``) as a zoo folder ``target``."""
    return convert_policy(source, target) if kind == "policy" else convert_weights(kind, source, target)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--to", type=Path, required=True,
                        help="folder to write the model folders into, one per shipped model (translator_<arch>_"
                             "<contact>, posenet_<name>, policy_<name>); a folder of that name there is replaced")
    parser.add_argument("--models", nargs="+", default=None, metavar="NAME",
                        help="only these models, by folder name (default: every shipped model)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.models.zoo import shipped_models

    models = shipped_models()
    chosen = args.models or list(models)
    unknown = sorted(set(chosen) - set(models))
    if unknown:
        raise ValueError(f"--models {unknown}: no such shipped model; shipped: {sorted(models)}")
    for name in chosen:
        kind, source = models[name]
        folder = convert(kind, source, args.to / name)
        size = sum(item.stat().st_size for item in folder.iterdir()) / 2**20
        print(f"{name}: {folder} ({kind}, {size:.2f} MiB)")
    print(f"wrote {len(chosen)} model folders under {args.to}")
    return 0
