"""Zoo folders: a model as a folder in the Hugging Face Hub layout, with no pickle in it.

A folder holds

- ``config.json``: ``"format"`` (:data:`FORMAT`), ``"model_class"`` (the class it rebuilds: ``UNetGenerator`` for a
  translator, ``GDNN``), the fields of the model's frozen config dataclass, ``"weights_sha256"`` (the sha256 of
  ``model.safetensors``, checked at load) and ``"card"`` (the free-form table of the ``.pt`` format);
- ``model.safetensors``: the state dict (safetensors holds tensors only: nothing in it runs; fp16 weights stay fp16
  and load as fp32, as in the ``.pt`` format);
- ``README.md``: the Markdown model card.

:func:`save_folder` writes one from a live model and :func:`convert_file` from a ``.pt`` weights file of
:mod:`~simshear_gym.models.weights_io` (its tensors bit for bit), both atomically (a temporary folder, then renamed);
:func:`load_any` loads a folder or a ``.pt`` file alike. A bad folder (config.json missing, not JSON, of another
format or model class; model.safetensors missing, unreadable, or not the sha256 recorded; weights of another
architecture) is one :class:`~simshear_gym.models.weights_io.WeightsFileError` naming the file and what was expected.
safetensors is imported only when a folder is read or written. Hub ids: :func:`simshear_gym.models.zoo.model_path`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from torch import nn

from simshear_gym.io import atomic_folder, file_sha256, write_json
from simshear_gym.models.weights_io import WeightsFileError, load_model, read_weights, rebuild

FORMAT = "simshear-zoo/1"
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
CARD_FILE = "README.md"
RESERVED = ("format", "model_class", "weights_sha256", "card")
"""The keys of ``config.json`` that are not config fields."""


def is_zoo_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder holding ``config.json`` and ``model.safetensors``."""
    path = Path(path)
    return path.is_dir() and (path / CONFIG_FILE).is_file() and (path / WEIGHTS_FILE).is_file()


def write_safetensors(path: Path, state: dict) -> None:
    """A state dict as a safetensors file (copies of its tensors on the CPU: safetensors refuses tensors that share
    memory, and a state dict may name one parameter twice)."""
    from safetensors.torch import save_file

    save_file({key: value.detach().cpu().clone().contiguous() for key, value in state.items()}, path,
              metadata={"format": "pt"})


def write_folder(folder: str | os.PathLike, model_class: str, config: dict, state: dict, card: dict | None = None,
                 readme: str | None = None) -> Path:
    """Write a zoo folder from a model class name, its config fields and its state dict, atomically."""
    clash = sorted(set(config) & set(RESERVED))
    if clash:
        raise ValueError(f"{model_class} config fields {clash} clash with the keys of {CONFIG_FILE} {RESERVED}")

    def write(tmp: Path) -> None:
        write_safetensors(tmp / WEIGHTS_FILE, state)
        write_json(tmp / CONFIG_FILE, {"format": FORMAT, "model_class": model_class, **config,
                                       "weights_sha256": file_sha256(tmp / WEIGHTS_FILE), "card": card or {}})
        if readme is not None:
            (tmp / CARD_FILE).write_text(readme)

    return atomic_folder(folder, write)


def save_folder(folder: str | os.PathLike, model: nn.Module, card: dict | None = None, readme: str | None = None,
                half: bool = False) -> Path:
    """Write a model (``model.config``: its frozen config dataclass; fp16 weights if ``half``), its ``card`` table
    and its Markdown card ``readme`` as a zoo folder, atomically."""
    state = {k: (v.half() if half and v.is_floating_point() else v) for k, v in model.state_dict().items()}
    return write_folder(folder, type(model).__name__, asdict(model.config), state, card, readme)


def convert_file(weights: str | os.PathLike, folder: str | os.PathLike, model_class: str, what: str,
                 readme: str | None = None) -> Path:
    """A ``.pt`` weights file (:func:`~simshear_gym.models.weights_io.save_model`; its sha256 checked) as a zoo
    folder: the same config, card and tensors (their dtypes kept)."""
    payload = read_weights(weights, what)
    try:
        config, state, card = dict(payload["config"]), dict(payload["state_dict"]), payload.get("card", {})
    except (KeyError, TypeError, ValueError) as error:
        raise WeightsFileError(f"{weights}: not a simshear {what} file ({error!r} missing)") from None
    return write_folder(folder, model_class, config, state, card if isinstance(card, dict) else {}, readme)


def read_config(folder: Path, what: str, model_class: str) -> dict:
    """A zoo folder's ``config.json``, checked for its format and model class."""
    path = folder / CONFIG_FILE
    expected = (f"expected a zoo folder of a simshear {what} ({CONFIG_FILE} of format {FORMAT!r} with model_class "
                f"{model_class!r}, and {WEIGHTS_FILE})")
    if not path.is_file():
        raise WeightsFileError(f"{path}: missing; {expected}")
    try:
        table = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise WeightsFileError(f"{path}: not valid JSON ({error}); {expected}") from None
    if not isinstance(table, dict) or table.get("format") != FORMAT:
        found = table.get("format") if isinstance(table, dict) else type(table).__name__
        raise WeightsFileError(f"{path}: format {found!r}; {expected}")
    if table.get("model_class") != model_class:
        raise WeightsFileError(f"{path}: the config of a {table.get('model_class')!r} model, not a {what} "
                               f"({model_class!r}); {expected}")
    return table


def load_folder(folder: str | os.PathLike, build: Callable[[dict], nn.Module], what: str,
                model_class: str) -> tuple[nn.Module, dict]:
    """Rebuild a model from a zoo folder in eval mode; returns it with its card table. ``build`` makes the model
    from the config fields (lists as tuples).

    Raises:
        FileNotFoundError: no such folder.
        WeightsFileError: see the module docstring.
    """
    from safetensors.torch import load_file

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{what} folder {folder} not found")
    table = read_config(folder, what, model_class)
    weights = folder / WEIGHTS_FILE
    expected = f"expected the {what} weights that {CONFIG_FILE} describes (safetensors of its state dict)"
    if not weights.is_file():
        raise WeightsFileError(f"{weights}: missing; {expected}")
    recorded, actual = table.get("weights_sha256"), file_sha256(weights)
    if recorded is not None and actual != recorded:
        raise WeightsFileError(f"{weights}: sha256 {actual[:12]}... differs from the "
                               f"{str(recorded)[:12]}... recorded in {CONFIG_FILE}: the file is corrupt (a flipped "
                               "bit, a truncated copy) or was replaced; " + expected)
    try:
        state = load_file(weights, device="cpu")
    except Exception as error:  # noqa: BLE001 - safetensors raises its own SafetensorError, OSError, ...
        reason = " ".join(str(error).split())[:200]
        raise WeightsFileError(f"{weights}: not a readable safetensors file ({type(error).__name__}: {reason}); "
                               f"{expected}") from None
    config = {k: v for k, v in table.items() if k not in RESERVED}
    failure = f"{folder}: not a simshear {what} folder ({CONFIG_FILE} and {WEIGHTS_FILE} of another architecture?"
    model = rebuild({"config": config, "state_dict": state}, build, failure)
    card = table.get("card", {})
    return model, card if isinstance(card, dict) else {}


def load_any(path: str | os.PathLike, build: Callable[[dict], nn.Module], what: str, model_class: str,
             checkpoint_entry: str | None = None) -> tuple[nn.Module, dict]:
    """A model from a zoo folder (:func:`load_folder`) or a ``.pt`` weights file
    (:func:`~simshear_gym.models.weights_io.load_model`, with its ``checkpoint_entry``), in eval mode, with its card."""
    if Path(path).is_dir():
        return load_folder(path, build, what, model_class)
    return load_model(path, build, what, checkpoint_entry)
