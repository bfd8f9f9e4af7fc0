"""``simshear pipeline run``: stages cached under a content hash (a rerun does nothing), an interrupted stage rerun
in its own folder, new settings in a new folder; a manifest per run."""

from __future__ import annotations

import json
import shutil

from simshear_gym.data.tactile_set import read_set
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.run import run_pipeline
from tests.test_pipeline_check import write_lab


def test_rerun_is_cached_and_an_interrupted_stage_reruns_in_its_folder(tmp_path):
    data = tmp_path / "data"
    config = load_config(write_lab(data))
    out = tmp_path / "run"
    first = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in first["results"]] == [True, True]
    paired = read_set(out / first["results"][1]["folder"] / "train")
    assert len(paired) == 8 and paired.meta["tactip"]["dome_radius_mm"] == config.sensor.dome_radius_mm
    assert paired.images_dir.is_dir()

    second = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in second["results"]] == [False, False]
    assert [r["folder"] for r in second["results"]] == [r["folder"] for r in first["results"]]

    collect_folder = out / first["results"][1]["folder"]
    (collect_folder / "stage.json").unlink()  # killed before the record: the stage runs again, same folder
    shutil.rmtree(collect_folder / "val")
    third = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in third["results"]] == [False, True]
    record = json.loads((collect_folder / "stage.json").read_text())
    assert record["resumed"] and record["metrics"] == {"train": 8, "val": 4}

    fewer = run_pipeline(config, out, data, "smoke", ("adapt",), rows_per_split=3, workers=1)
    assert fewer["results"][0]["ran"] and fewer["results"][0]["folder"] != first["results"][0]["folder"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sensor"] == "lab" and manifest["git_commit"] and manifest["profile"] == "smoke"
