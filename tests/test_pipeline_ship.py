"""``simshear ship run``: a finished run's translators and GDNNs become weights with cards and check figures
(the shipped weights are what a pipeline run produced); an unfinished run is refused with a clear error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simshear_gym.models.onnx_export import missing_export_packages
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.translator import Translator
from simshear_gym.models.translator_runtime import load_translator, runtime_of
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.run import STAGES, run_pipeline
from simshear_gym.ship import posenet as ship_posenet
from simshear_gym.ship import translator as ship_translator
from simshear_gym.ship.run import read_run, ship

ROOT = Path(__file__).resolve().parents[1]


def test_an_unfinished_run_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="manifest.json not found"):
        read_run(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"stages": ["adapt", "collect"], "evaluation": None,
                                                        "models": {"translators": None, "posenets": None}}))
    with pytest.raises(ValueError, match="stopped before its evaluate stage"):
        read_run(tmp_path)


@pytest.mark.data
@pytest.mark.slow
def test_ship_writes_the_runs_models_with_cards_and_check_figures(data_root, tmp_path):
    config = load_config(ROOT / "configs" / "tactip331.toml")
    run = tmp_path / "run"
    manifest = run_pipeline(config, run, data_root, "smoke", STAGES, rows_per_split=24, workers=1)
    to = tmp_path / "weights"
    written = ship(run, to, str(data_root), date="2026-01-01")
    exported = not missing_export_packages()
    assert sorted(p.relative_to(to).as_posix() for p in written) == sorted(
        [f"{stem}.{ext}" for stem in ("shpix2pix_surface", "pix2pix_surface", "posenet/surface", "shpix2pix_edge",
                                      "pix2pix_edge", "posenet/edge") for ext in ("pt", "md")]
        + [f"shpix2pix_{contact}.{ext}" for contact in ("surface", "edge") for ext in ("onnx", "onnx.md")
           if exported])
    if exported:  # the envs' auto runtime takes the new .onnx: it was exported from the new .pt
        assert runtime_of(load_translator(to / "shpix2pix_edge.pt", "auto")) == "onnx"
    translator = Translator.load(to / "shpix2pix_edge.pt")
    assert translator.card["pipeline"]["profile"] == "smoke"
    assert translator.card["pipeline"]["stage"] == next(r["folder"] for r in manifest["results"]
                                                        if r["stage"] == "translator/edge_shpix2pix")
    check = translator.card["check"]
    assert ship_translator.check_figure(to / "shpix2pix_edge.pt", "edge", check["rows"],
                                        str(data_root))["mape"] == pytest.approx(check["mape"], abs=1e-6)
    model, card = load_posenet(to / "posenet" / "surface.pt")
    assert model.variables.name == "surface" and card["train_config"]["source"] == "shpix2pix"
    measured = ship_posenet.check_figure(to / "posenet" / "surface.pt", "surface", card["check"]["rows"],
                                         str(data_root))
    assert measured["mae"] == pytest.approx(card["check"]["mae"], rel=1e-5)
    text = (to / "posenet" / "surface.md").read_text()
    assert f"simshear pipeline run {config.path} --profile smoke --out {run}" in text
    assert "## Metrics on the real `surface_shear` validation rows (24)" in text
    # one contact type's models only: the other's shipped files are not touched
    edge_only = ship(run, tmp_path / "edge_only", str(data_root), date="2026-01-01", contacts=("edge",))
    assert {p.name.split(".")[0] for p in edge_only} == {"shpix2pix_edge", "pix2pix_edge", "edge"}
    card = (tmp_path / "edge_only" / "posenet" / "edge.md").read_text()
    assert f"simshear ship run {run} --contacts edge" in card
    gdnn_only = ship(run, tmp_path / "gdnn_only", str(data_root), date="2026-01-01", contacts=("surface",),
                     models=("posenet",))
    assert [p.relative_to(tmp_path / "gdnn_only").as_posix() for p in gdnn_only] == ["posenet/surface.pt",
                                                                                       "posenet/surface.md"]
    assert "--contacts surface --models posenet" in (tmp_path / "gdnn_only" / "posenet" / "surface.md").read_text()
    with pytest.raises(ValueError, match="models must name some of"):
        ship(run, tmp_path / "none", str(data_root), models=("policies",))
    with pytest.raises(ValueError, match=r"no models of contact type\(s\) \['wall'\]"):
        ship(run, tmp_path / "none", str(data_root), contacts=("wall",))


def test_ship_writes_into_the_package_weights_folder_by_default():
    import argparse
    import inspect

    from simshear_gym.models import zoo
    from simshear_gym.ship import run as ship_module

    parser = argparse.ArgumentParser()
    ship_module.add_arguments(parser)
    assert parser.parse_args(["RUN"]).to == zoo.WEIGHTS_DIR
    assert inspect.signature(ship_module.ship).parameters["to"].default == zoo.WEIGHTS_DIR
