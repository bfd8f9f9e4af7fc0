"""The pipeline's evaluation of a sensor's models on its own **real** validation images (the ``evaluate`` stage of
``simshear pipeline run``), and ``simshear pipeline compare``: one run's evaluation against another's.

- Translation, per dataset: MAPE and SSIM of each translator's images (from the val rows' sim renders and shear)
  against the real images, and of nearest-label retrieval (for each val row, the real training image whose labels
  are closest, every varying label scaled by its range) as the baseline a translator has to beat.
- Pose and shear, per dataset: each GDNN's MAE per variable on the real images against chance (always predicting
  the range centre) and, for the GDNN trained on translated images, its ratio to the real-trained reference
  (``read_by_real``: the variables the reference reads, MAE <= :data:`READ_SHARE` x chance). Variables constant in
  a dataset's validation rows (shear on a tap set) are listed as ``constant``, not scored.

``simshear pipeline compare RUN --reference REF --out JSON``: a finished pipeline run's models against another
run's (another profile, machine or recipe), figure by figure, from both runs' evaluations. ``RUN`` is a run folder
(its ``manifest.json`` names its evaluation); ``REF`` is a run folder too, or a results record that holds a run's
``evaluation`` (as ``results/ablations/pipeline_full_tactip331_empty_cache.json``). Per dataset: the translators'
MAPE and SSIM, and the GDNNs' MAE per variable with the translated-trained / real-trained ratio, each beside the
reference's with the relative difference (run / reference - 1; above 0: the run is worse). Writes the record with
the command, the run's manifest figures (profile, machine, wall time per stage) and its evaluation.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.contract import resize_tactile
from simshear_gym.data.adapter import CANONICAL_COLUMNS
from simshear_gym.data.labels import SHEAR_COLUMNS
from simshear_gym.data.paired import load_paired
from simshear_gym.evaluate.translation import nearest_rows
from simshear_gym.io import write_json

READ_SHARE = 0.5
"""A GDNN reads a variable where its MAE is at most this share of the chance MAE (the acceptance's ratio to the
real-trained GDNN counts on the variables the real-trained one reads)."""


def nearest_label_images(train_targets, train_images: np.ndarray, val_targets) -> np.ndarray:
    """For each val row, the training image whose labels (every varying pose and move column, scaled by its
    range) are closest."""
    columns = [c for c in CANONICAL_COLUMNS.values() if np.ptp(train_targets[c].to_numpy()) > 1e-9]
    scales = np.array([np.ptp(train_targets[c].to_numpy()) for c in columns])
    train = train_targets[columns].to_numpy(np.float64) / scales
    val = val_targets[columns].to_numpy(np.float64) / scales
    return train_images[nearest_rows(train, val)]


def evaluate_sensor(config, root: Path, adapted: dict, paired: dict, translators: dict, posenets: dict,
                    eval_rows: int | None) -> dict:
    """The figures of the module docstring, with a flat ``summary`` for the manifest."""
    from simshear_gym.evaluate.metrics import mape, metrics, ssim  # torch: not for `pipeline compare --help`
    from simshear_gym.models.gdnn_input import label_matrix, predict
    from simshear_gym.models.posenet_io import load_posenet
    from simshear_gym.models.translator import Translator, translate_rows

    translation, pose, summary = {}, {}, {}
    loaded_translators = {contact: {arch: Translator.load(root / path) for arch, path in archs.items()}
                          for contact, archs in translators.items()}
    loaded_posenets = {contact: {source: load_posenet(root / path)[0] for source, path in sources.items()}
                       for contact, sources in posenets["models"].items()}
    for name, dataset in config.datasets.items():
        val_paired, val_real = load_paired(root / paired[name]["val"], root)
        train_paired, train_real = load_paired(root / paired[name]["train"], root)
        rows = slice(0, eval_rows)
        targets = val_paired.targets.iloc[rows].reset_index(drop=True)
        real = val_real.load_images(use_cache=False)[rows]
        sim = val_paired.load_images(use_cache=False)[rows]
        shear = targets[list(SHEAR_COLUMNS)].to_numpy(np.float32)
        entry = {"rows": len(targets)}
        for arch, translator in loaded_translators[dataset.contact].items():
            generated = resize_tactile(translate_rows(translator, sim, shear), real.shape[-1])
            entry[arch] = {"mape": float(mape(generated, real).mean()), "ssim": float(ssim(generated, real).mean())}
        retrieved = nearest_label_images(train_paired.targets, train_real.load_images(use_cache=False),
                                         targets)
        entry["nearest-label retrieval"] = {"mape": float(mape(retrieved, real).mean()),
                                            "ssim": float(ssim(retrieved, real).mean())}
        translation[name] = entry
        for arch in loaded_translators[dataset.contact]:
            summary[f"translation/{name}/{arch}_mape"] = entry[arch]["mape"]
        summary[f"translation/{name}/retrieval_mape"] = entry["nearest-label retrieval"]["mape"]

        readings = {}
        for source, model in loaded_posenets[dataset.contact].items():
            truth = label_matrix(targets, model.variables)
            varying = {spec.name for spec, column in zip(model.variables.variables, truth.T) if np.ptp(column) > 1e-9}
            figures = metrics(*predict(model, real), truth, model.variables)
            readings[source] = {variable: {"mae": per["mae"], "chance_mae": per["chance_mae"],
                                           "mae_over_chance": per["mae"] / max(per["chance_mae"], 1e-12)}
                                for variable, per in figures["variables"].items() if variable in varying}
            readings[source]["mean_nll"] = figures["mean_nll"]
            readings["constant"] = sorted(set(model.variables.names) - varying)  # e.g. shear on a tap set
        reference, candidate = readings.get("real"), readings.get("shpix2pix")
        if reference and candidate:
            readings["ratio_shpix2pix_to_real"] = {
                variable: candidate[variable]["mae"] / max(reference[variable]["mae"], 1e-12)
                for variable in candidate if variable != "mean_nll"}
            readings["read_by_real"] = [variable for variable in reference if variable != "mean_nll"
                                        and reference[variable]["mae_over_chance"] <= READ_SHARE]
        pose[name] = readings
        for variable, per in (candidate or {}).items():
            if variable != "mean_nll":
                summary[f"posenet/{name}/{variable}_mae_over_chance"] = per["mae_over_chance"]
        for variable, ratio in readings.get("ratio_shpix2pix_to_real", {}).items():
            summary[f"posenet/{name}/{variable}_ratio_to_real"] = ratio
    return {"sensor": config.name, "rows_per_dataset": eval_rows, "variables": posenets["variables"],
            "translation": translation, "posenet": pose, "summary": summary}


# ------------------------------------------------------------------------------------------ two runs compared
def load_evaluation(path: Path) -> dict:
    """The pipeline evaluation of a run folder, or the ``evaluation`` object of a results record."""
    if path.is_dir():
        manifest = path / "manifest.json"
        if not manifest.is_file():
            raise FileNotFoundError(f"{path}: no manifest.json (not a pipeline run folder)")
        evaluation = json.loads(manifest.read_text()).get("evaluation")
        if not evaluation:
            raise ValueError(f"{manifest}: the run has no evaluation (run its evaluate stage first)")
        return json.loads((path / evaluation).read_text())
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such run folder or results record")
    record = json.loads(path.read_text())
    if "translation" in record and "posenet" in record:
        return record
    if "evaluation" not in record:
        raise ValueError(f"{path}: neither a pipeline evaluation nor a record with an 'evaluation' object")
    return record["evaluation"]


def _side_by_side(value: float, reference: float | None) -> dict:
    row = {"run": value, "reference": reference}
    if reference is not None:
        row["relative"] = value / reference - 1.0 if reference else None
    return row


def compare(run: dict, reference: dict) -> dict:
    """{"translation": {"<dataset>/<arch>": {mape, ssim}}, "posenet": {"<dataset>/<source>/<variable>": mae},
    "ratio_to_real": {"<dataset>/<variable>": ratio}}, each figure as {run, reference, relative}."""
    out: dict[str, dict] = {"translation": {}, "posenet": {}, "ratio_to_real": {}}
    for dataset, entry in run["translation"].items():
        ref_entry = reference["translation"].get(dataset, {})
        for arch, figures in entry.items():
            if not isinstance(figures, dict):
                continue
            ref = ref_entry.get(arch, {})
            out["translation"][f"{dataset}/{arch}"] = {
                metric: _side_by_side(figures[metric], ref.get(metric)) for metric in ("mape", "ssim")}
    for dataset, readings in run["posenet"].items():
        ref_readings = reference["posenet"].get(dataset, {})
        for source, variables in readings.items():
            if source in ("constant", "read_by_real", "ratio_shpix2pix_to_real"):
                continue
            for variable, figures in variables.items():
                if isinstance(figures, dict):
                    ref = ref_readings.get(source, {}).get(variable, {})
                    out["posenet"][f"{dataset}/{source}/{variable}"] = _side_by_side(figures["mae"], ref.get("mae"))
        for variable, ratio in readings.get("ratio_shpix2pix_to_real", {}).items():
            ref = ref_readings.get("ratio_shpix2pix_to_real", {}).get(variable)
            out["ratio_to_real"][f"{dataset}/{variable}"] = {
                **_side_by_side(ratio, ref), "read_by_real": variable in readings.get("read_by_real", [])}
    return out


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="a finished pipeline run folder")
    parser.add_argument("--reference", type=Path, required=True,
                        help="the run folder or results record (with an 'evaluation') to compare against")
    parser.add_argument("--out", type=Path, required=True, help="the JSON record to write")


def run(args: argparse.Namespace) -> int:
    evaluation = load_evaluation(args.run)
    reference = load_evaluation(args.reference)
    manifest = json.loads((args.run / "manifest.json").read_text())
    figures = compare(evaluation, reference)
    write_json(args.out, {
        "command": recorded_command("simshear pipeline compare", add_arguments, args),
        "run": {"config": manifest["config"], "profile": manifest["profile"], "git_commit": manifest["git_commit"],
                "machine": manifest.get("machine"), "jobs": manifest.get("jobs"), "wall_s": manifest["wall_s"],
                "stages": [{"stage": r["stage"], "ran": r["ran"], "wall_s": r["wall_s"]}
                           for r in manifest["results"]]},
        "reference": str(args.reference), "comparison": figures, "evaluation": evaluation})
    worst = max((row["mape"]["relative"] for row in figures["translation"].values()
                 if row["mape"].get("relative") is not None), default=None)
    print(f"{args.run}: {len(figures['translation'])} translator and {len(figures['posenet'])} GDNN figures against "
          f"{args.reference}" + (f"; translation MAPE at most {worst:+.1%} from the reference" if worst is not None
                                 else "") + f"; wrote {args.out}")
    return 0
