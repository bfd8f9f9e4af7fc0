"""``simshear pipeline compare RUN --reference REF --out JSON``: a finished pipeline run's models against another
run's (another profile, machine or recipe), figure by figure.

Both evaluations are the pipeline's own (``evaluate`` stage: :mod:`simshear_gym.pipelines.evaluation`, on every
dataset's real validation rows). ``RUN`` is a run folder (its ``manifest.json`` names its evaluation); ``REF`` is a
run folder too, or a results record that holds a run's ``evaluation`` (as
``results/ablations/pipeline_full_tactip331_empty_cache.json``). Per dataset: the translators' MAPE and SSIM,
and the GDNNs' MAE per variable with the translated-trained / real-trained ratio, each beside the reference's with
the relative difference (run / reference - 1; above 0: the run is worse). Writes the record with the command, the
run's manifest figures (profile, machine, wall time per stage) and its evaluation.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from simshear_gym.command_line import recorded_command
from simshear_gym.io import write_json


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
