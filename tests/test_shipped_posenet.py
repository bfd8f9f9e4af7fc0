"""The shipped GDNNs load and reproduce their recorded check figure on real validation rows."""

import pytest
import torch

from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.zoo import load_shipped_posenet, posenet_weights
from simshear_gym.ship.cards import generator_list
from simshear_gym.ship.posenet import check_figure, env_check_figure

torch.set_num_threads(1)


@pytest.mark.parametrize("contact", ["surface", "edge"])
def test_shipped_posenet_loads_with_card(contact):
    model, card = load_shipped_posenet(contact)
    assert model.variables.name == contact and not model.training
    assert card["contact"] == contact and "train_command" in card and card["train_config"]["source"] == "shpix2pix"
    assert posenet_weights(contact).with_suffix(".md").is_file()
    assert posenet_weights(contact).stat().st_size < 10 * 2 ** 20
    mean, std = model(torch.zeros(2, 1, model.config.image_size_px, model.config.image_size_px))
    assert torch.isfinite(mean).all() and (std > 0).all()


@pytest.mark.data
@pytest.mark.parametrize("contact", ["surface", "edge"])
def test_shipped_posenet_reproduces_its_check_figure(contact, data_root):
    _, card = load_shipped_posenet(contact)
    recorded = card["check"]
    measured = check_figure(posenet_weights(contact), contact, recorded["rows"], str(data_root))
    for name, value in recorded["mae"].items():
        assert measured["mae"][name] == pytest.approx(value, rel=1e-3, abs=1e-4), name


def test_unknown_contact_is_a_clear_error():
    with pytest.raises(FileNotFoundError, match="no shipped posenet for 'cylinder'"):
        posenet_weights("cylinder")


def test_shipped_colift_posenet_is_the_colift_envs_estimator():
    model, card = load_shipped_posenet("colift")
    assert model.variables.name == "env" and card["contact"] == "colift"
    assert card["train_config"]["source"] == "env"
    # its sets' provenance: one `pipeline env-model` command (sets and training), or the hand-run collection commands
    assert card["train_command"].startswith("simshear pipeline env-model") or "collect_command" in card
    assert posenet_weights("colift").with_suffix(".md").is_file()
    assert posenet_weights("colift").stat().st_size < 10 * 2 ** 20


def test_shipped_colift_posenet_reproduces_its_check_figure():
    """The check set is collected afresh from its seed: same physics and translation, so about the same MAE."""
    _, card = load_shipped_posenet("colift")
    recorded = card["check"]
    measured = env_check_figure(posenet_weights("colift"), recorded["collect"])
    assert measured["rows"] == recorded["rows"]
    for name, value in recorded["mae"].items():
        assert measured["mae"][name] == pytest.approx(value, rel=0.05, abs=0.02), name


def test_card_lists_each_generator_once_with_how_often_it_is_drawn():
    assert generator_list(["a.pt", "b.pt", "a.pt", "c.pt", "a.pt", "b.pt"]) == "`a.pt` (x3), `b.pt` (x2), `c.pt`"


@pytest.mark.data
def test_recheck_measures_the_check_again_and_rewrites_the_cards_line(data_root, tmp_path):
    import shutil

    from simshear_gym.ship.recheck_posenet import recheck

    weights = tmp_path / "edge.pt"
    shutil.copy(posenet_weights("edge"), weights)
    shutil.copy(posenet_weights("edge").with_suffix(".md"), weights.with_suffix(".md"))
    _, card = load_shipped_posenet("edge")
    check = recheck(weights, str(data_root), date="2026-01-01")
    for name, value in card["check"]["mae"].items():  # the same images: the same figure
        assert check["mae"][name] == pytest.approx(value, rel=1e-3, abs=1e-4), name
    _, stored = load_posenet(weights)
    assert stored["check"]["measured"] == "2026-01-01"
    text = weights.with_suffix(".md").read_text()
    assert text.count("Check figure (tests):") == 1 and "measured again on 2026-01-01" in text


def test_recheck_of_a_missing_file_is_a_clear_error(tmp_path):
    from simshear_gym.ship.recheck_posenet import recheck

    with pytest.raises(FileNotFoundError, match="not found"):
        recheck(tmp_path / "missing.pt")
