"""``simshear pipeline compare``: a run's evaluation against another's, figure by figure."""

from __future__ import annotations

import json

import pytest

from simshear_gym.cli import main
from simshear_gym.pipelines.evaluation import compare, load_evaluation


def _evaluation(mape: float, z_mae: float, real_z_mae: float) -> dict:
    return {"translation": {"tap": {"rows": 10, "shpix2pix": {"mape": mape, "ssim": 0.9},
                                    "nearest-label retrieval": {"mape": 0.2, "ssim": 0.5}}},
            "posenet": {"tap": {"real": {"z_mm": {"mae": real_z_mae}, "mean_nll": -1.0},
                                "shpix2pix": {"z_mm": {"mae": z_mae}, "mean_nll": -2.0},
                                "constant": ["shear_x_mm"], "read_by_real": ["z_mm"],
                                "ratio_shpix2pix_to_real": {"z_mm": z_mae / real_z_mae}}}}


def test_each_figure_stands_beside_the_reference_with_its_relative_difference():
    figures = compare(_evaluation(0.11, 0.12, 0.1), _evaluation(0.10, 0.10, 0.1))
    assert figures["translation"]["tap/shpix2pix"]["mape"] == pytest.approx(
        {"run": 0.11, "reference": 0.10, "relative": 0.1})
    assert figures["translation"]["tap/nearest-label retrieval"]["mape"]["relative"] == pytest.approx(0.0)
    assert figures["posenet"]["tap/shpix2pix/z_mm"]["relative"] == pytest.approx(0.2)
    assert set(figures["posenet"]) == {"tap/real/z_mm", "tap/shpix2pix/z_mm"}  # no nll, no lists
    ratio = figures["ratio_to_real"]["tap/z_mm"]
    assert ratio["run"] == pytest.approx(1.2) and ratio["reference"] == pytest.approx(1.0) and ratio["read_by_real"]


def test_a_figure_the_reference_lacks_has_no_relative_difference():
    reference = _evaluation(0.1, 0.1, 0.1)
    del reference["translation"]["tap"]["shpix2pix"]
    row = compare(_evaluation(0.1, 0.1, 0.1), reference)["translation"]["tap/shpix2pix"]["mape"]
    assert row == {"run": 0.1, "reference": None}


def test_the_command_writes_the_record_from_a_run_folder_and_a_results_record(tmp_path, monkeypatch):
    run = tmp_path / "run"
    (run / "evaluate").mkdir(parents=True)
    (run / "evaluate" / "evaluation.json").write_text(json.dumps(_evaluation(0.11, 0.12, 0.1)))
    (run / "manifest.json").write_text(json.dumps({
        "config": "configs/lab.toml", "profile": "quick", "git_commit": "abc", "machine": {"cpus": 2}, "jobs": 2,
        "wall_s": 60.0, "evaluation": "evaluate/evaluation.json",
        "results": [{"stage": "evaluate", "ran": True, "wall_s": 5.0, "metrics": {}}]}))
    record = tmp_path / "full.json"
    record.write_text(json.dumps({"command": "...", "evaluation": _evaluation(0.10, 0.10, 0.1)}))
    monkeypatch.chdir(tmp_path)
    assert main(["pipeline", "compare", "run", "--reference", "full.json", "--out", "out.json"]) == 0
    written = json.loads((tmp_path / "out.json").read_text())
    assert written["command"] == "simshear pipeline compare run --reference full.json --out out.json"
    assert written["run"]["profile"] == "quick" and written["run"]["stages"][0]["stage"] == "evaluate"
    assert written["comparison"]["translation"]["tap/shpix2pix"]["mape"]["relative"] == pytest.approx(0.1)
    assert load_evaluation(tmp_path / "run") == written["evaluation"]


def test_a_folder_without_a_manifest_or_a_record_without_an_evaluation_is_one_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no manifest.json"):
        load_evaluation(tmp_path)
    (tmp_path / "other.json").write_text(json.dumps({"command": "x"}))
    with pytest.raises(ValueError, match="'evaluation' object"):
        load_evaluation(tmp_path / "other.json")
