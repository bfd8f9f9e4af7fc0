"""A translator's generator as the ONNX graph the envs run (:class:`~simshear_gym.models.translator_runtime.
OnnxTranslator`): built, compared with torch and written beside its weights.

The graph is the generator in eval mode with the translator's whole input/output contract inside it (uint8 sim image
and raw sensor-frame shear in, uint8 image out), exported by torch's dynamo exporter (batch norm folded into the
convolutions), with a dynamic batch size. ``precision="fp16"`` stores the weights in fp16 with a cast to fp32 that
ONNX Runtime folds when it loads the graph: half the file, the same fp32 arithmetic. The file's metadata records
the sha256 of the weights it came from (the envs' ``"auto"`` runtime runs only a current export) and its own sha256
lies beside it (``<file>.onnx.sha256``).

Two callers, one graph: ``simshear ship onnx`` (:mod:`simshear_gym.ship.onnx`, the shipped translators, checked on
the tactip331 real validation sets) and ``simshear pipeline run`` (:func:`simshear_gym.pipelines.run.stage_onnx`, a
sensor's own translators, checked on its paired validation sets).

Building needs the ``export`` extra (``pip install -e ".[export]"``: onnx, onnxscript); comparing and running need
onnxruntime. Nothing here is imported at module import but numpy.
"""

from __future__ import annotations

import importlib.util
import json
import os
import time
from pathlib import Path

import numpy as np

EXPORT_PACKAGES = ("onnx", "onnxscript")
PRECISIONS = ("fp32", "fp16")
OPSET = 20


def missing_export_packages() -> list[str]:
    """The packages of the ``export`` extra that are not installed (none: exports can be built)."""
    return [name for name in EXPORT_PACKAGES if importlib.util.find_spec(name) is None]


def _contract_module(generator):
    """The generator with the translator's input and output conversions, as one torch module to export."""
    import torch

    from simshear_gym.models.translator import SHEAR_INPUT_MASK, SHEAR_SCALE, SIM_SCALE

    class TranslatorGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.generator = generator
            self.register_buffer("shear_factor", torch.from_numpy(SHEAR_INPUT_MASK / SHEAR_SCALE))

        def forward(self, sim_uint8, shear_sensor=None):
            sim = sim_uint8.unsqueeze(1).to(torch.float32) / SIM_SCALE
            shear = shear_sensor * self.shear_factor if shear_sensor is not None else None
            image = self.generator._run(sim, shear)[:, 0]
            return torch.floor(image * 255.0 + 0.5).clamp(0.0, 255.0).to(torch.uint8)

    return TranslatorGraph().eval()


def export_model(weights: Path, precision: str = "fp32"):
    """(ONNX ModelProto without metadata, the torch generator's card, its config) of a translator weights file."""
    missing = missing_export_packages()
    if missing:
        raise ImportError(f"exporting to ONNX needs {', '.join(missing)} (the export extra): "
                          f"pip install -e '.[export]'  (or pip install {' '.join(missing)})")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    import warnings

    import torch

    from simshear_gym.models.translator import load_generator
    from simshear_gym.models.translator_runtime import IMAGE_OUTPUT, SHEAR_INPUT, SIM_INPUT

    generator, card = load_generator(weights)
    generator = generator.float().eval()
    config = generator.config
    module = _contract_module(generator)
    size = config.image_size_px
    batch = torch.export.Dim("batch", min=1, max=4096)
    example: tuple = (torch.zeros(2, size, size, dtype=torch.uint8),)
    names, shapes = [SIM_INPUT], {"sim_uint8": {0: batch}}
    if config.shear_dim:
        example += (torch.zeros(2, config.shear_dim),)
        names.append(SHEAR_INPUT)
        shapes["shear_sensor"] = {0: batch}
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(module, example, input_names=names, output_names=[IMAGE_OUTPUT],
                                    dynamic_shapes=shapes, dynamo=True, opset_version=OPSET, optimize=True,
                                    verbose=False)
    model = program.model_proto
    if precision == "fp16":
        _store_half(model)
    import onnx

    onnx.checker.check_model(model)
    return model, card, config


def _store_half(model, min_elements: int = 64) -> None:
    """Float32 initializers of at least ``min_elements`` stored as float16, each behind a Cast to float32 (ONNX
    Runtime folds the casts when it loads the graph, so the arithmetic stays fp32)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    graph = model.graph
    casts = []
    for index, tensor in enumerate(list(graph.initializer)):
        if tensor.data_type != TensorProto.FLOAT or int(np.prod(tensor.dims)) < min_elements:
            continue
        name = tensor.name
        half = numpy_helper.from_array(numpy_helper.to_array(tensor).astype(np.float16), f"{name}__fp16")
        graph.initializer[index].CopyFrom(half)  # replaces ``tensor`` in place
        casts.append(helper.make_node("Cast", [half.name], [name], to=TensorProto.FLOAT, name=f"{name}__to_fp32"))
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    onnx.checker.check_model(model)


class SideBySide:
    """A weights file's torch translator and an ONNX graph of it (bytes, not yet written) on ONNX Runtime, called
    alike: ``translate(sim_uint8, shear_sensor) -> (by_torch, by_onnx)`` uint8 (B, H, W)."""

    def __init__(self, model_bytes: bytes, weights: Path, threads: int = 1) -> None:
        import onnxruntime

        from simshear_gym.models.translator import Translator
        from simshear_gym.models.translator_runtime import SHEAR_INPUT

        self.torch_translator = Translator.load(weights)
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self._session = onnxruntime.InferenceSession(model_bytes, options, providers=["CPUExecutionProvider"])
        self._shear_input = any(node.name == SHEAR_INPUT for node in self._session.get_inputs())

    def onnx(self, sim_uint8: np.ndarray, shear_sensor: np.ndarray) -> np.ndarray:
        from simshear_gym.models.translator_runtime import IMAGE_OUTPUT, SHEAR_INPUT, SIM_INPUT

        feeds = {SIM_INPUT: np.ascontiguousarray(sim_uint8),
                 **({SHEAR_INPUT: np.asarray(shear_sensor, dtype=np.float32)} if self._shear_input else {})}
        return self._session.run([IMAGE_OUTPUT], feeds)[0]

    def translate(self, sim_uint8: np.ndarray, shear_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.torch_translator(sim_uint8, shear_sensor), self.onnx(sim_uint8, shear_sensor)

    def latency(self, repeats: int = 200) -> dict:
        """Median batch-1 latency (ms) of both on one thread (torch's setting restored after), with the load
        average before."""
        import torch

        rng = np.random.default_rng(0)
        size = self.torch_translator.image_size_px
        sim1 = rng.integers(0, 60, (1, size, size), dtype=np.uint8)
        shear1 = rng.uniform(-5, 5, (1, 6)).astype(np.float32)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            load = round(os.getloadavg()[0], 2)
            return {"torch_ms_batch1": _median_ms(lambda: self.torch_translator(sim1, shear1), repeats),
                    "onnx_ms_batch1": _median_ms(lambda: self.onnx(sim1, shear1), repeats),
                    "threads": 1, "load_average_before": load}
        finally:
            torch.set_num_threads(threads)


def difference(by_torch: np.ndarray, by_onnx: np.ndarray) -> dict:
    """How far the ONNX images lie from torch's: the share of pixels that differ and the largest difference."""
    diff = np.abs(by_torch.astype(np.int16) - by_onnx.astype(np.int16))
    return {"pixels_differing": float((diff > 0).mean()), "max_abs_difference_grey": int(diff.max())}


def _median_ms(call, repeats: int) -> float:
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return round(1000.0 * float(np.median(times)), 3)


def write_export(model, weights: Path, to: Path, record: dict) -> int:
    """Write ``model`` to ``to`` atomically with ``record`` (JSON) as its metadata, plus the sha256 of ``weights``
    (``source_sha256``, what the envs' ``"auto"`` runtime checks) and its own checksum file; returns its size in
    bytes."""
    import onnx

    from simshear_gym.io import atomic_write, write_checksum
    from simshear_gym.models.translator_runtime import METADATA_KEY, file_sha256

    record = {**record, "source_sha256": file_sha256(weights), "opset": OPSET}
    onnx.helper.set_model_props(model, {METADATA_KEY: json.dumps(record, default=float)})
    atomic_write(to, lambda tmp: onnx.save_model(model, tmp))
    write_checksum(to)  # checked when the file is loaded
    return to.stat().st_size
