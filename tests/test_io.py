"""simshear_gym.io: results files record paths relative to the repository root, never this machine's."""

from __future__ import annotations

from pathlib import Path

from simshear_gym.io import recorded_path


def test_a_path_under_the_working_directory_is_recorded_relative_to_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    weights = tmp_path / "simshear_gym" / "models" / "weights" / "shpix2pix_edge.pt"
    assert recorded_path(weights) == str(Path("simshear_gym/models/weights/shpix2pix_edge.pt"))
    assert recorded_path("runs/x/best.pt") == str(Path("runs/x/best.pt"))  # relative stays relative


def test_a_path_outside_the_working_directory_is_recorded_without_this_machines_folders(tmp_path, monkeypatch):
    inside = tmp_path / "repo"
    inside.mkdir()
    monkeypatch.chdir(inside)
    assert recorded_path(tmp_path / "elsewhere.pt") == "elsewhere.pt"  # absolute: its name alone
    assert recorded_path("../elsewhere.pt") == str(Path("../elsewhere.pt"))  # relative: as given
