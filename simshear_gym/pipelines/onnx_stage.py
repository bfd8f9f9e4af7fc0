"""The ``onnx`` stage of ``simshear pipeline run``: each of the sensor's translators (the shPix2pix per contact type
that ``sensor.json`` names) exported to ``<weights>.onnx`` beside its ``<weights>.pt``, as ``simshear ship onnx``
exports the shipped ones (:mod:`simshear_gym.models.onnx_export`: the same graph, fp16 storage, the sha256 of the
weights in its metadata), so that an env made with ``sensor=`` runs it on ONNX Runtime (the envs' ``"auto"``
runtime, :mod:`simshear_gym.models.translator_runtime`) like the shipped translators.

The export is checked on the first :data:`CHECK_ROWS` validation rows of each of the contact type's data sets (its
sim renders and shear, as the evaluation feeds them): torch and ONNX Runtime side by side, their MAPE against the
real images, how many pixels differ and by how much, and their batch-1 latency on one thread. The figures are the
stage's metrics (in its ``stage.json`` and the run's manifest) and lie in the ONNX file's metadata.

Each export is a cached stage keyed by the weights' sha256 and the export's settings. Where the ``export`` extra
(onnx, onnxscript) is missing, the stage logs one line saying so and the envs run the sensor's translators on torch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from simshear_gym.models import onnx_export
from simshear_gym.models.translator_runtime import file_sha256, onnx_path_for
from simshear_gym.pipelines.stages import StageRunner

PRECISION = "fp16"  # as the shipped exports (simshear ship onnx's default)
CHECK_ROWS = 64  # validation rows per data set in the check
LATENCY_REPEATS = 100


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
        key = {"weights": relative, "sha256": file_sha256(weights), "precision": PRECISION,
               "opset": onnx_export.OPSET, "check_sets": sets, "check_rows": CHECK_ROWS}

        def work(folder: Path, weights=weights, sets=sets, contact=contact) -> dict:
            to = onnx_path_for(weights)
            model, torch_card, config = onnx_export.export_model(weights, PRECISION)
            check = check_export(model.SerializeToString(), weights, [runner.root / s for s in sets], runner.root)
            record = {"arch": "shpix2pix" if config.shear_dim else "pix2pix", "contact": contact,
                      "source": weights.name, "precision": PRECISION, "pipeline_stage": runner.relative(folder),
                      "config": asdict(config), "card": {"torch_card": torch_card, "check": check}}
            size_bytes = onnx_export.write_export(model, weights, to, record)
            return {"outputs": {"onnx": runner.relative(to)}, "metrics": {**check, "size_bytes": size_bytes}}

        exported[contact] = runner.run(f"onnx/{contact}_shpix2pix", key, work).outputs["onnx"]
    return exported


def check_export(model_bytes: bytes, weights: Path, val_sets: list[Path], root: Path,
                 rows: int = CHECK_ROWS) -> dict:
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
    return {"sets": sets, "latency": both.latency(LATENCY_REPEATS)}
