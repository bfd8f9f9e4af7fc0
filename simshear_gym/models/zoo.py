"""The model zoo: the one owner of the shipped models' folder, a sensor's ``sensor.json`` and loading a model by name.

The shipped folder, :data:`WEIGHTS_DIR` (``simshear_gym/models/weights``), each file with its card ``<file>.md``:

- translators: ``<arch>_<contact>.pt`` (``<arch>.pt``: both contact types), the envs' ONNX export beside each
  shPix2pix (``<arch>_<contact>.onnx``, :func:`~simshear_gym.models.translator_runtime.onnx_path_for`);
- their distilled students (the envs' ``translator="student"``): ``student/``, named the same;
- GDNNs: ``posenet/<name>.pt`` (``surface``, ``edge``, ``colift``, ...);
- policies: ``policies/<name>/`` (``model.pt``, ``model.json``, ``vecnormalize.json``, ``config.json``, ``model.md``;
  its zoo folder holds ``model.safetensors`` for ``model.pt`` and ``README.md`` for ``model.md``).

A sensor's own models (``simshear pipeline run``) are named by its run folder's ``sensor.json``
(:func:`write_sensor`, :func:`load_sensor`). Torch is imported only by the loaders that need it.

Every shipped model converts to a folder in the Hugging Face Hub layout (``simshear ship zoo --to DIR``: one folder
per name of :func:`shipped_models`; the format: :mod:`~simshear_gym.models.zoo_format`). A model is then named by a
path (a ``.pt`` file, a zoo folder) or by a Hub id (``hf://OWNER/NAME[@REVISION]``, or ``OWNER/NAME`` where no such
path exists), which :func:`model_path` downloads with ``huggingface_hub`` (the ``hub`` extra) into its cache.
"""

from __future__ import annotations

import functools
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from simshear_gym.io import write_json
from simshear_gym.models.translator_runtime import translator_from
from simshear_gym.tables import read_toml

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
STUDENT_DIR = WEIGHTS_DIR / "student"
POSENET_DIR = WEIGHTS_DIR / "posenet"
POLICY_DIR = WEIGHTS_DIR / "policies"
WEIGHTS_SUFFIX = ".pt"
SENSOR_FILE = "sensor.json"
DEFAULT_PIPELINE_RUNS = "runs/pipeline"
"""Where ``simshear pipeline run`` writes a sensor's run folder by default: ``runs/pipeline/<name>``."""


def translator_file(arch: str, contact: str, root: Path = WEIGHTS_DIR) -> Path:
    """Where a translator of ``arch`` and ``contact`` lies (or goes) in a weights folder laid out as the shipped one."""
    return Path(root) / f"{arch}_{contact}{WEIGHTS_SUFFIX}"


def posenet_file(name: str, root: Path = WEIGHTS_DIR) -> Path:
    """Where a GDNN of ``name`` lies (or goes) in a weights folder laid out as the shipped one."""
    return Path(root) / POSENET_DIR.name / f"{name}{WEIGHTS_SUFFIX}"


def shipped_translators(student: bool = False) -> dict[tuple[str, str], Path]:
    """``{(arch, contact): path}`` of the shipped translators (``student``: their students, :data:`STUDENT_DIR`)."""
    from simshear_gym.data.labels import CONTACT_TYPES

    found: dict[tuple[str, str], Path] = {}
    for path in sorted((STUDENT_DIR if student else WEIGHTS_DIR).glob(f"*{WEIGHTS_SUFFIX}")):
        arch, _, contact = path.stem.partition("_")
        for each in ([contact] if contact in CONTACT_TYPES else CONTACT_TYPES if not contact else []):
            found[(arch, each)] = path
    return found


def translator_weights(contact: str, arch: str = "shpix2pix", student: bool = False) -> Path:
    """The shipped translator (or its ``student``) of ``arch`` for ``contact`` (FileNotFoundError naming what ships)."""
    models = shipped_translators(student)
    if (arch, contact) not in models:
        kind = "student " if student else ""
        raise FileNotFoundError(f"no shipped {kind}{arch} translator for {contact!r} contacts in "
                                f"{STUDENT_DIR if student else WEIGHTS_DIR}; shipped: {sorted(models)}")
    return models[(arch, contact)]


def shipped_posenets() -> list[str]:
    """Names of the shipped GDNNs (``posenet/<name>.pt``)."""
    return sorted(path.stem for path in POSENET_DIR.glob(f"*{WEIGHTS_SUFFIX}"))


def posenet_weights(name: str) -> Path:
    """The shipped GDNN ``name`` (a contact type, ``colift``, ...; FileNotFoundError naming what ships)."""
    path = posenet_file(name)
    if not path.is_file():
        raise FileNotFoundError(f"no shipped posenet for {name!r} contacts in {POSENET_DIR}; "
                                f"shipped: {shipped_posenets()}")
    return path


def shipped_policies() -> list[str]:
    """Names of the shipped policies (``policies/<name>/``)."""
    return sorted(path.name for path in POLICY_DIR.glob("*") if path.is_dir())


def policy_folder(name: str) -> Path:
    """The shipped policy ``name``'s folder, e.g. ``tracking_ppo`` (FileNotFoundError naming what ships)."""
    folder = POLICY_DIR / name
    if not folder.is_dir():
        raise FileNotFoundError(f"no shipped policy {name!r} in {POLICY_DIR}; shipped: {shipped_policies()}")
    return folder


def estimator_file(name: str) -> Path:
    """The shipped file a policy's provenance names: ``translator_<arch>_<contact>`` (a translator) or
    ``posenet_<name>`` (a GDNN); the file need not exist (a shipped model may have been removed since)."""
    if name.startswith("translator_"):
        return WEIGHTS_DIR / f"{name.removeprefix('translator_')}{WEIGHTS_SUFFIX}"
    if name.startswith("posenet_"):
        return posenet_file(name.removeprefix("posenet_"))
    raise ValueError(f"estimator model name must start with 'translator_' or 'posenet_', got {name!r}")


def shipped_models() -> dict[str, tuple[str, Path]]:
    """Every shipped model by the name of its zoo folder: ``{name: (kind, path)}``, kind ``translator``
    (``translator_<arch>_<contact>``; a student: ``translator_student_<stem>``), ``posenet`` (``posenet_<name>``)
    or ``policy`` (``policy_<name>``, its folder)."""
    models: dict[str, tuple[str, Path]] = {}
    for prefix, folder in (("translator_", WEIGHTS_DIR), ("translator_student_", STUDENT_DIR)):
        for path in sorted(folder.glob(f"*{WEIGHTS_SUFFIX}")):
            models[f"{prefix}{path.stem}"] = ("translator", path)
    for name in shipped_posenets():
        models[f"posenet_{name}"] = ("posenet", posenet_file(name))
    for name in shipped_policies():
        models[f"policy_{name}"] = ("policy", POLICY_DIR / name)
    return models


HUB_PREFIX = re.compile(r"hf:/{1,2}")
"""``hf://OWNER/NAME``: a Hugging Face Hub id (one slash: the same spec after ``pathlib.Path`` collapsed ``//``)."""
HUB_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*(@[\w./-]+)?")
FILE_SUFFIXES = (WEIGHTS_SUFFIX, ".onnx", ".zip", ".json", ".safetensors")
"""A missing ``OWNER/NAME`` with one of these suffixes is a mistyped file, never looked up on the Hub."""


def model_path(spec: str | os.PathLike) -> Path:
    """The local path of a model named by ``spec``: a path as it is (a ``.pt`` file, a zoo folder, ...), or a
    Hugging Face Hub id, ``hf://OWNER/NAME[@REVISION]`` (or ``OWNER/NAME[@REVISION]`` where no such path exists),
    downloaded by ``huggingface_hub.snapshot_download`` into its cache: the snapshot's folder.

    Raises:
        ImportError: an ``hf://`` id without huggingface_hub (``pip install 'simshear-gym[hub]'``).
        FileNotFoundError: the Hub gave no such model (the message names the id and the Hub's error).
    """
    text = os.fspath(spec)
    hub = HUB_PREFIX.match(text)
    if not hub and (Path(text).exists() or not HUB_ID.fullmatch(text) or Path(text).suffix in FILE_SUFFIXES):
        return Path(text)
    try:
        from huggingface_hub import snapshot_download
    except ImportError:
        if not hub:
            return Path(text)  # a path that does not exist: its loader says so
        raise ImportError(f"{text!r}: a Hugging Face Hub id needs the huggingface_hub package: "
                          "pip install 'simshear-gym[hub]'") from None
    repo, _, revision = text[hub.end() if hub else 0:].partition("@")
    try:
        return Path(snapshot_download(repo_id=repo, revision=revision or None))
    except Exception as error:  # noqa: BLE001 - the Hub raises its own errors, network errors, ...
        reason = " ".join(str(error).split())[:200]
        raise FileNotFoundError(f"{text!r}: {'no such path, and ' if not hub else ''}no model {repo!r} from the "
                                f"Hugging Face Hub ({type(error).__name__}: {reason})") from None


def load_translator(spec: str | os.PathLike):
    """The torch translator (:class:`~simshear_gym.models.translator.Translator`) of a ``.pt`` file, a zoo folder
    or a Hub id (:func:`model_path`)."""
    from simshear_gym.models.translator import Translator

    return Translator.load(model_path(spec))


def load_posenet(spec: str | os.PathLike):
    """(GDNN in eval mode, card) of a ``.pt`` file, a zoo folder or a Hub id (:func:`model_path`)."""
    from simshear_gym.models.posenet_io import load_posenet as load

    return load(model_path(spec))


@functools.cache
def _cached_weights(contact: str, arch: str) -> str:
    return str(translator_weights(contact, arch))


def shipped_translator(contact: str, arch: str = "shpix2pix", runtime: str | None = None,
                       device: str | None = None, threads: int | None = None):
    """The shipped translator for a contact type on the chosen runtime, device and threads
    (:func:`~simshear_gym.models.translator_runtime.translator_from`), loaded once per process."""
    return translator_from(_cached_weights(contact, arch), runtime, device, threads)


def load_shipped_translator(contact: str = "surface", arch: str = "shpix2pix"):
    """The shipped torch translator of ``arch`` for ``contact``
    (a :class:`~simshear_gym.models.translator.Translator`)."""
    return load_translator(translator_weights(contact, arch))


def load_shipped_posenet(name: str = "surface"):
    """(GDNN in eval mode, card) of the shipped GDNN ``name``."""
    return load_posenet(posenet_weights(name))


@dataclass(frozen=True)
class SensorModels:
    """A sensor's own simulated TacTip and models, as ``simshear pipeline run`` exports them (``sensor.json`` in
    its run folder): the TacTip's settings (:class:`~simshear_gym.sim.tactip.TacTipConfig` fields), and per
    contact type the shPix2pix translator and the GDNN trained on its images (absolute paths once loaded)."""

    name: str
    tactip: dict
    translators: dict
    posenets: dict

    def translator(self, contact: str) -> str:
        return self._lookup(self.translators, contact, "translator")

    def posenet(self, contact: str) -> str:
        return self._lookup(self.posenets, contact, "GDNN")

    def _lookup(self, table: dict, contact: str, what: str) -> str:
        if contact not in table:
            raise ValueError(f"sensor {self.name!r} has no {what} for {contact!r} contacts; it has {sorted(table)}")
        return table[contact]


def write_sensor(folder: Path, sensor: str, config: str, profile: str, tactip: dict, translators: dict,
                 posenets: dict, variables, onnx: dict | None = None) -> Path:
    """Write a pipeline run's ``sensor.json`` in ``folder`` (model paths relative to it); returns its path.
    ``onnx``: {contact: the ONNX export beside its translator} (informative: the envs' ``"auto"`` runtime finds an
    export beside the weights by itself, :func:`~simshear_gym.models.translator_runtime.load_translator`)."""
    path = Path(folder) / SENSOR_FILE
    write_json(path, {"sensor": sensor, "config": config, "profile": profile, "tactip": tactip,
                      "translators": translators, "onnx": dict(onnx or {}), "posenets": posenets,
                      "variables": variables})
    return path


def load_sensor(spec: str | os.PathLike) -> SensorModels:
    """A sensor's models from its ``sensor.json``, a pipeline run folder holding one, or its experiment config
    (``configs/<name>.toml``: the run folder ``runs/pipeline/<name>`` that ``simshear pipeline run`` writes by
    default, relative to the working directory)."""
    path = Path(spec)
    if path.suffix == ".toml":
        name = read_toml(path).get("name")
        path = Path(DEFAULT_PIPELINE_RUNS) / str(name)
    if path.is_dir():
        path = path / SENSOR_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no sensor models at {path} (from sensor={str(spec)!r}): run `simshear pipeline "
                                "run CONFIG` first, or pass the sensor.json of a pipeline run folder")
    record = json.loads(path.read_text())
    try:
        folder = path.parent
        return SensorModels(
            name=record["sensor"], tactip=dict(record["tactip"]),
            translators={c: str(folder / p) for c, p in record["translators"].items()},
            posenets={c: str(folder / p) for c, p in record["posenets"].items()})
    except (KeyError, TypeError, AttributeError) as error:
        raise ValueError(f"{path}: not a sensor file of simshear pipeline run ({error!r} missing or "
                         "malformed)") from None
