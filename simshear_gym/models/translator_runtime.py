"""Which runtime runs a translator: torch (:class:`~simshear_gym.models.translator.Translator`) or ONNX Runtime
(:class:`OnnxTranslator`), both called the same way.

``translator(sim_uint8, shear_sensor)``: sim uint8 (B, H, W) or (B, 1, H, W), shear (B, 6) in the sensor frame
(mm, deg; ignored by a pix2pix generator) -> uint8 (B, H, W).

An ONNX translator is a generator exported (:mod:`simshear_gym.models.onnx_export`) to ``<weights>.onnx`` beside
its ``<weights>.pt``: the shipped ones by ``simshear ship onnx`` (:mod:`simshear_gym.ship.onnx`), a sensor's own by
``simshear pipeline run`` (:func:`simshear_gym.pipelines.run.stage_onnx`). The graph holds the
whole contract of :class:`~simshear_gym.models.translator.Translator`: it takes the uint8 sim image and the raw
sensor-frame shear, applies ``/ SIM_SCALE`` and ``normalise_shear`` (mask and scale) itself and returns the uint8
image (``floor(255 y + 0.5)`` clamped, as the torch path rounds). Its metadata records the sha256 of the torch
weights it came from, so that ``"auto"`` never runs an ONNX file that is older than the weights beside it, and its
own sha256 lies beside it (``<file>.onnx.sha256``), checked at load: a corrupt file is an error naming it.

Runtimes (:data:`RUNTIMES`): ``"torch"``; ``"onnx"`` (fails with a message naming what is missing);
``"auto"``: ONNX where ``onnxruntime`` is installed and an up-to-date ``.onnx`` lies beside the ``.pt``, else torch.
ONNX Runtime runs on :data:`DEFAULT_THREADS` intra-op thread by default: one core per translator, in the envs'
one-process loop and in each vector-env worker (on a shared 2-core machine, two torch threads took 13-400x longer
per image than one while other jobs held the cores: ``results/env_speed.json``).

The choice of translator, runtime, device and threads (an argument, else an environment variable, which reaches
every process of a vector env, else the default: :func:`choose_translator`, :func:`choose_translator_runtime`,
:func:`choose_translator_device`, :func:`choose_translator_threads`) and the per-process cache of loaded
translators (:func:`translator_from`) live here too.

torch is imported only by the torch path; this module imports neither torch nor onnxruntime at import time.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

import numpy as np

from simshear_gym.io import file_sha256, verify_checksum
from simshear_gym.models.device import DEVICES

RUNTIMES: tuple[str, ...] = ("auto", "torch", "onnx")
DEFAULT_THREADS = 1
ONNX_SUFFIX = ".onnx"
# ONNX graph interface (written by simshear_gym.models.onnx_export, read here)
SIM_INPUT = "sim_uint8"
SHEAR_INPUT = "shear_sensor"
IMAGE_OUTPUT = "image_uint8"
METADATA_KEY = "simshear_translator"  # JSON: arch, source weights name and sha256, generator config, card


def check_runtime(runtime: str) -> str:
    if runtime not in RUNTIMES:
        raise ValueError(f"translator runtime must be one of {RUNTIMES}, got {runtime!r}")
    return runtime


def onnx_path_for(weights: str | os.PathLike) -> Path:
    """The ONNX file that belongs beside a torch weights file: ``x.pt`` -> ``x.onnx``."""
    return Path(weights).with_suffix(ONNX_SUFFIX)


def onnxruntime_available() -> bool:
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def _metadata(session, path) -> dict:
    text = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    if text is None:
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: metadata {METADATA_KEY!r} is not JSON ({error})") from None


def _current_onnx(weights: Path, threads: int) -> OnnxTranslator | Exception:
    """The ONNX translator beside ``weights`` if it was exported from them as they are now, else why not."""
    onnx_path = onnx_path_for(weights)
    if not onnx_path.is_file():
        return FileNotFoundError(f"{onnx_path} not found (export it: simshear ship onnx --weights {weights} "
                                 f"--to {onnx_path})")
    translator = OnnxTranslator(onnx_path, threads=threads)
    if translator.metadata.get("source_sha256") != file_sha256(weights):
        return ValueError(f"{onnx_path} was not exported from {weights} as it is now (its recorded sha256 differs); "
                          f"re-export it: simshear ship onnx --weights {weights} --to {onnx_path}")
    return translator


def load_translator(weights: str | os.PathLike, runtime: str = "auto", threads: int = DEFAULT_THREADS,
                    device: str = "cpu"):
    """A translator from a weights file (or a zoo folder, :mod:`~simshear_gym.models.zoo_format`, run on torch): a
    torch :class:`~simshear_gym.models.translator.Translator`, or an :class:`OnnxTranslator` of the ``.onnx`` beside
    the ``.pt`` (or of ``weights`` itself if it is a ``.onnx``, which only ONNX Runtime runs). ``"auto"`` picks
    ONNX where it can; ``"onnx"`` raises where it cannot (ImportError: onnxruntime missing; FileNotFoundError: no
    ``.onnx``; ValueError: an ``.onnx`` not exported from the ``.pt`` as it is now, or a zoo folder). ``threads``:
    ONNX Runtime's intra-op threads (torch keeps its own setting). ``device``: a torch device name (``"cpu"``,
    ``"cuda"``, ``"cuda:1"``); on a GPU the torch translator runs there ("auto" then means torch: the ONNX path here
    is the CPU's)."""
    check_runtime(runtime)
    weights = Path(weights)
    if not weights.exists():
        raise FileNotFoundError(f"translator weights {weights} not found")
    if weights.is_dir():  # a zoo folder (config.json, model.safetensors): torch weights, no ONNX export beside them
        if runtime == "onnx":
            raise ValueError(f"translator runtime 'onnx' needs a .onnx file (or a .pt with its export beside it); "
                             f"{weights} is a zoo folder of torch weights: use runtime 'torch' or 'auto'")
        runtime = "torch"
    if not str(device).startswith("cpu"):
        if runtime == "onnx" or weights.suffix == ONNX_SUFFIX:
            raise ValueError(f"translator on device {device!r}: ONNX Runtime runs here on the CPU only; give torch "
                             f"weights (.pt) with runtime 'torch' or 'auto', got {weights} with runtime {runtime!r}")
        import torch

        from simshear_gym.models.device import OnDevice
        from simshear_gym.models.translator import Translator, load_generator

        generator, card = load_generator(weights)
        return Translator(OnDevice(generator, torch.device(device)), card, fast=False)
    if weights.suffix == ONNX_SUFFIX:
        if runtime == "torch":
            raise ValueError(f"{weights} is an ONNX file: translator runtime 'torch' needs torch weights (.pt)")
        return OnnxTranslator(weights, threads=threads)
    if runtime != "torch":
        if onnxruntime_available():
            found = _current_onnx(weights, threads)
            if isinstance(found, OnnxTranslator):
                return found
            if runtime == "onnx":
                raise type(found)(f"translator runtime 'onnx': {found}")
        elif runtime == "onnx":
            raise ImportError("translator runtime 'onnx' needs the onnxruntime package: pip install onnxruntime")
    from simshear_gym.models.translator import Translator

    return Translator.load(weights)


def _chosen(value, env: str, default: str, argument: str, choices: tuple[str, ...], note: str = "") -> str:
    """``value`` if given, else ``$env``, else ``default``; unless it is one of ``choices``, a ValueError naming where
    it came from (``argument`` or the variable) and the choices (then ``note``)."""
    chosen = value if value is not None else os.environ.get(env) or default
    if chosen not in choices:
        source = argument if value is not None else f"${env}"
        raise ValueError(f"{source} must be one of {choices}{note}, got {chosen!r}")
    return chosen


TRANSLATOR_RUNTIME_ENV = "SIMSHEAR_TRANSLATOR_RUNTIME"


def choose_translator_runtime(runtime: str | None = None) -> str:
    """The translator runtime to use: ``runtime`` if given, else ``$SIMSHEAR_TRANSLATOR_RUNTIME``, else
    ``"auto"`` (ONNX Runtime where onnxruntime is installed and the ``.onnx`` beside the weights is current, else
    torch). The environment variable reaches every process of a vector env, the envs' own argument-free default."""
    return _chosen(runtime, TRANSLATOR_RUNTIME_ENV, "auto", "translator_runtime", RUNTIMES)


TRANSLATOR_THREADS_ENV = "SIMSHEAR_TRANSLATOR_THREADS"


def choose_translator_threads(threads: int | None = None) -> int:
    """ONNX Runtime's intra-op threads for a translator: ``threads`` if given, else ``$SIMSHEAR_TRANSLATOR_THREADS``,
    else 1 (:data:`DEFAULT_THREADS`: one core per translator, in the one-process loop and in each vector-env
    worker). Two threads translate one env's images about 1.5x faster where the second core is free
    (``results/env_speed.json``); where other work holds the cores they cost more than they gain. The torch runtime
    keeps torch's own setting."""
    chosen = threads if threads is not None else os.environ.get(TRANSLATOR_THREADS_ENV) or DEFAULT_THREADS
    if not str(chosen).isdigit() or int(chosen) < 1 or isinstance(chosen, bool):
        source = "translator threads" if threads is not None else f"${TRANSLATOR_THREADS_ENV}"
        raise ValueError(f"{source} must be a whole number of threads >= 1, got {chosen!r}")
    return int(chosen)


TRANSLATORS: tuple[str, ...] = ("full", "student")
TRANSLATOR_ENV = "SIMSHEAR_TRANSLATOR"


def choose_translator(translator: str | None = None) -> str:
    """Which shipped translator makes the envs' images: ``translator`` if given, else ``$SIMSHEAR_TRANSLATOR``, else
    ``"full"`` (the shipped shPix2pix); ``"student"`` is its distilled student (a smaller generator that learned the
    full one's images: the fast path, :func:`simshear_gym.models.zoo.translator_weights`; see its card for its
    quality on the real validation images). The environment variable reaches every process of a vector env."""
    return _chosen(translator, TRANSLATOR_ENV, "full", "translator", TRANSLATORS)


TRANSLATOR_DEVICE_ENV = "SIMSHEAR_TRANSLATOR_DEVICE"


def choose_translator_device(device: str | None = None) -> str:
    """The torch device the translator runs on: ``device`` if given, else ``$SIMSHEAR_TRANSLATOR_DEVICE``, else
    ``"cpu"`` (the envs' default: one env at batch 1 is fastest on the CPU's ONNX path, and forked vector-env
    workers cannot share a GPU); ``"auto"`` is CUDA where torch finds it; ``"cuda"`` without one is an error
    (:func:`simshear_gym.models.device.resolve_device`). Returns ``"cpu"`` or the CUDA device's name."""
    chosen = _chosen(device, TRANSLATOR_DEVICE_ENV, "cpu", "device", DEVICES, " (where the translator runs)")
    if chosen == "cpu":
        return "cpu"
    from simshear_gym.models.device import resolve_device

    return str(resolve_device(chosen))


@functools.cache
def _cached_translator(weights: str, runtime: str, device: str, threads: int):
    return load_translator(weights, runtime, threads=threads, device=device)


def translator_from(weights: str | os.PathLike, runtime: str | None = None, device: str | None = None,
                    threads: int | None = None):
    """A translator from a weights file on ``runtime`` (:func:`choose_translator_runtime`), ``device``
    (:func:`choose_translator_device`) and ONNX Runtime ``threads`` (:func:`choose_translator_threads`), loaded once
    per process."""
    return _cached_translator(str(weights), choose_translator_runtime(runtime), choose_translator_device(device),
                              choose_translator_threads(threads))


def runtime_of(translator) -> str:
    """``"onnx"`` or ``"torch"``: the runtime a translator of :func:`load_translator` runs on."""
    return getattr(translator, "runtime", "torch")


class OnnxTranslator:
    """A translator exported to ONNX, run by ONNX Runtime on the CPU with ``threads`` intra-op threads (same call,
    inputs and outputs as :class:`~simshear_gym.models.translator.Translator`; the sim images must be uint8)."""

    runtime = "onnx"

    def __init__(self, path: str | os.PathLike, threads: int = DEFAULT_THREADS) -> None:
        try:
            import onnxruntime
        except ImportError:
            raise ImportError("running an ONNX translator needs the onnxruntime package: pip install onnxruntime") \
                from None
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"ONNX translator {self.path} not found")
        if not (isinstance(threads, int) and threads >= 1):
            raise ValueError(f"threads must be an int >= 1, got {threads!r}")
        verify_checksum(self.path)  # a flipped bit in an initializer loads fine and makes black images
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = onnxruntime.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = onnxruntime.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            self._session = onnxruntime.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as error:  # onnxruntime raises its own classes for unreadable or invalid files
            raise ValueError(f"{self.path}: not an ONNX model that onnxruntime can load ({error})") from None
        inputs = {node.name: node for node in self._session.get_inputs()}
        if SIM_INPUT not in inputs or set(inputs) - {SIM_INPUT, SHEAR_INPUT}:
            raise ValueError(f"{self.path}: not a simshear ONNX translator (inputs {sorted(inputs)}, expected "
                             f"{SIM_INPUT!r} and optionally {SHEAR_INPUT!r}; write it with simshear ship onnx)")
        self.shear_conditioned = SHEAR_INPUT in inputs
        size = inputs[SIM_INPUT].shape[-1]
        if not isinstance(size, int):
            raise ValueError(f"{self.path}: the sim input needs a fixed image size, got {inputs[SIM_INPUT].shape}")
        self._size = size
        self.threads = threads
        self.metadata = _metadata(self._session, self.path)
        self.card = self.metadata.get("card", {})

    @property
    def image_size_px(self) -> int:
        return self._size

    def __call__(self, sim_uint8: np.ndarray, shear_sensor: np.ndarray | None = None) -> np.ndarray:
        sim = np.asarray(sim_uint8)
        if sim.ndim == 4 and sim.shape[1] == 1:
            sim = sim[:, 0]
        size = self._size
        if sim.ndim != 3 or sim.shape[1:] != (size, size):
            raise ValueError(f"sim images must be (B, {size}, {size}) or (B, 1, {size}, {size}) uint8 for this "
                             f"translator, got shape {sim.shape}")
        if sim.dtype != np.uint8:
            raise ValueError(f"sim images must be uint8 (the TacTip's depth image), got {sim.dtype}")
        feeds = {SIM_INPUT: np.ascontiguousarray(sim)}
        if self.shear_conditioned:
            if shear_sensor is None:
                raise ValueError("this translator is shear-conditioned (shPix2pix): pass shear_sensor (B, 6)")
            shear = np.ascontiguousarray(shear_sensor, dtype=np.float32)
            if shear.shape != (len(sim), 6):
                raise ValueError(f"shear_sensor must be (B, 6) = ({len(sim)}, 6), got {shear.shape}")
            feeds[SHEAR_INPUT] = shear
        return self._session.run([IMAGE_OUTPUT], feeds)[0]
