"""Zoo folders (simshear_gym/models/zoo_format.py, ``simshear ship zoo``): every shipped model converts to a folder in
the Hugging Face Hub layout whose model computes what the shipped one does; a folder loads wherever a ``.pt`` does,
and by a Hub id through the zoo; a bad folder is one WeightsFileError naming the file and what was expected."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from simshear_gym.models import zoo
from simshear_gym.models.gdnn import GDNN, GDNNConfig
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.translator import Translator, load_generator, normalise_shear, normalise_sim
from simshear_gym.models.unet import UNetConfig, UNetGenerator
from simshear_gym.models.weights_io import WeightsFileError
from simshear_gym.models.zoo_format import CARD_FILE, CONFIG_FILE, FORMAT, WEIGHTS_FILE, is_zoo_folder, save_folder
from simshear_gym.ship import zoo as ship_zoo


@pytest.fixture(scope="module")
def converted(tmp_path_factory) -> Path:
    """``simshear ship zoo --to DIR`` of every shipped model."""
    folder = tmp_path_factory.mktemp("zoo")
    assert ship_zoo.run(argparse.Namespace(to=folder, models=None)) == 0
    return folder


def test_every_shipped_model_becomes_a_hub_folder(converted):
    models = zoo.shipped_models()
    kinds = {kind for kind, _ in models.values()}
    assert kinds == {"translator", "posenet", "policy"}
    assert {"translator_shpix2pix_surface", "translator_pix2pix_edge", "posenet_surface", "posenet_colift",
            "policy_tracking_ppo"} <= set(models)
    assert sorted(p.name for p in converted.iterdir()) == sorted(models)  # no temporary folder left
    for name, (kind, source) in models.items():
        folder = converted / name
        files = {p.name for p in folder.iterdir()}
        if kind == "policy":
            assert files == {"config.json", "model.json", WEIGHTS_FILE, "vecnormalize.json", CARD_FILE}, name
            assert (folder / CARD_FILE).read_text() == (source / "model.md").read_text()
            continue
        assert files == {CONFIG_FILE, WEIGHTS_FILE, CARD_FILE} and is_zoo_folder(folder), name
        config = json.loads((folder / CONFIG_FILE).read_text())
        assert config["format"] == FORMAT
        assert config["model_class"] == ("UNetGenerator" if kind == "translator" else "GDNN")
        assert (folder / CARD_FILE).read_text() == source.with_suffix(".md").read_text()
        # no larger than the .pt: fp16 translators stay fp16
        assert (folder / WEIGHTS_FILE).stat().st_size <= source.stat().st_size


def _names(kind: str) -> list[str]:
    return [name for name, (each, _) in zoo.shipped_models().items() if each == kind]


@pytest.mark.parametrize("name", _names("translator"))
def test_a_converted_translator_computes_what_the_shipped_one_does(converted, name):
    generator, card = load_generator(zoo.shipped_models()[name][1])
    folder_generator, folder_card = load_generator(converted / name)
    assert folder_card == json.loads(json.dumps(card, default=float))
    rng = np.random.default_rng(0)
    size = generator.config.image_size_px
    sim = rng.integers(0, 120, (2, size, size), dtype=np.uint8)
    shear = rng.uniform(-4, 4, (2, 6)).astype(np.float32)
    with torch.inference_mode():
        arguments = (normalise_sim(sim),) + ((normalise_shear(shear),) if generator.config.shear_dim else ())
        difference = (generator(*arguments) - folder_generator(*arguments)).abs().max().item()
    assert difference <= 1e-6
    np.testing.assert_array_equal(Translator(generator)(sim, shear), Translator(folder_generator)(sim, shear))


@pytest.mark.parametrize("name", _names("posenet"))
def test_a_converted_gdnn_computes_what_the_shipped_one_does(converted, name):
    model, _ = load_posenet(zoo.shipped_models()[name][1])
    folder_model, _ = load_posenet(converted / name)
    size = model.config.image_size_px
    image = torch.rand(3, 1, size, size, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        for ours, theirs in zip(model(image), folder_model(image)):
            assert (ours - theirs).abs().max().item() <= 1e-6


@pytest.mark.parametrize("name", _names("policy"))
def test_a_converted_policy_acts_as_the_shipped_one(converted, name):
    from gymnasium import spaces

    from simshear_gym.control.policy import SB3Controller
    from simshear_gym.control.policy_files import load_policy

    source = zoo.shipped_models()[name][1]
    policy = load_policy(source / "model.pt")
    privileged = getattr(policy.policy, "privileged_keys", ())
    observation_space = spaces.Dict({k: s for k, s in policy.observation_space.spaces.items() if k not in privileged})
    observation_space.seed(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the zoo folder keeps the provenance: no stale-estimator warning
        shipped = SB3Controller.load(source / "model.pt", observation_space, policy.action_space)
        folder = SB3Controller.load(converted / name, observation_space, policy.action_space)
    assert folder.normalizer is not None and folder.settings == shipped.settings
    for _ in range(8):
        observation = observation_space.sample()
        difference = np.abs(shipped(observation) - folder(observation)).max()
        assert difference <= 1e-6


def test_the_envs_loaders_and_evaluations_take_a_folder(converted):
    from simshear_gym.models.translator_runtime import load_translator, translator_from

    folder = converted / "translator_shpix2pix_edge"
    for runtime in ("auto", "torch"):
        assert isinstance(load_translator(folder, runtime), Translator)
    assert isinstance(translator_from(folder, "auto", "cpu", 1), Translator)
    with pytest.raises(ValueError, match="runtime 'onnx' needs a .onnx file.*zoo folder"):
        load_translator(folder, "onnx")
    assert Translator.load(folder).card["contact"] == "edge"


# -- Hub ids, through the zoo only ---------------------------------------------------------------------------------


def test_a_hub_id_is_downloaded_through_the_zoo(converted, monkeypatch):
    hub = pytest.importorskip("huggingface_hub")
    asked = []

    def snapshot_download(repo_id, revision=None, **_):
        asked.append((repo_id, revision))
        return str(converted / repo_id.split("/")[1])

    monkeypatch.setattr(hub, "snapshot_download", snapshot_download)
    assert zoo.model_path("hf://lab/posenet_edge") == converted / "posenet_edge"
    assert zoo.model_path(Path("hf://lab/posenet_edge@v1")) == converted / "posenet_edge"  # Path collapses the //
    assert isinstance(zoo.load_translator("lab/translator_pix2pix_surface"), Translator)  # no such path here
    model, card = zoo.load_posenet("hf://lab/posenet_surface")
    assert model.variables.name == "surface" and card["contact"] == "surface"
    assert asked == [("lab/posenet_edge", None), ("lab/posenet_edge", "v1"), ("lab/translator_pix2pix_surface", None),
                     ("lab/posenet_surface", None)]
    # an existing path, a mistyped file and a path of more than two parts never reach the Hub
    assert zoo.model_path(converted / "posenet_edge") == converted / "posenet_edge"
    assert zoo.model_path("runs/best.pt") == Path("runs/best.pt")
    assert zoo.model_path("runs/posenet/best") == Path("runs/posenet/best")
    assert len(asked) == 4

    def unreachable(repo_id, revision=None, **_):
        raise OSError("no network")

    monkeypatch.setattr(hub, "snapshot_download", unreachable)
    with pytest.raises(FileNotFoundError, match=r"'hf://lab/gone': no model 'lab/gone' from the Hugging Face Hub "
                                                r"\(OSError: no network\)"):
        zoo.model_path("hf://lab/gone")


def test_a_hub_id_without_huggingface_hub_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "huggingface_hub", None)
    with pytest.raises(ImportError, match=r"needs the huggingface_hub package: pip install 'simshear-gym\[hub\]'"):
        zoo.model_path("hf://lab/posenet_edge")
    assert zoo.model_path("lab/posenet_edge") == Path("lab/posenet_edge")  # a missing path: its loader says so


# -- writing and the error contract ---------------------------------------------------------------------------------


def tiny_generator() -> UNetGenerator:
    return UNetGenerator(UNetConfig(image_size_px=32, depth=5, base_channels=4, max_channels=8)).eval()


def tiny_gdnn() -> GDNN:
    return GDNN(GDNNConfig(image_size_px=16, conv_channels=(4,), conv_kernels=(3,), dense=(8,))).eval()


def test_save_folder_round_trips_and_replaces_a_folder_whole(tmp_path):
    folder = tmp_path / "gdnn"
    model = tiny_gdnn()
    save_folder(folder, model, {"note": "first"}, readme="# card\n")
    (folder / "stray.txt").write_text("from before")
    save_folder(folder, model, {"note": "second"})
    assert {p.name for p in folder.iterdir()} == {CONFIG_FILE, WEIGHTS_FILE}
    assert [p.name for p in tmp_path.iterdir()] == ["gdnn"]
    loaded, card = load_posenet(folder)
    assert card == {"note": "second"} and loaded.config == model.config
    image = torch.rand(2, 1, 16, 16)
    with torch.inference_mode():
        assert all(torch.equal(a, b) for a, b in zip(model(image), loaded(image)))
    # fp16 on request, loaded back as fp32
    from safetensors import safe_open

    save_folder(folder, tiny_generator(), half=True)
    with safe_open(folder / WEIGHTS_FILE, "pt") as stored:
        assert stored.get_tensor("template").dtype == torch.float16
    generator, _ = load_generator(folder)
    assert generator.template.dtype == torch.float32


def test_a_failed_write_leaves_the_previous_folder(tmp_path, monkeypatch):
    import safetensors.torch

    folder = tmp_path / "gdnn"
    save_folder(folder, tiny_gdnn(), {"note": "kept"})

    def broken(*_, **__):
        raise RuntimeError("writer failed")

    monkeypatch.setattr(safetensors.torch, "save_file", broken)
    with pytest.raises(RuntimeError, match="writer failed"):
        save_folder(folder, tiny_gdnn(), {"note": "lost"})
    assert load_posenet(folder)[1] == {"note": "kept"}
    assert [p.name for p in tmp_path.iterdir()] == ["gdnn"]


def _gdnn_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "gdnn"
    save_folder(folder, tiny_gdnn())
    return folder


def _flip_a_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-3] ^= 0xFF
    path.write_bytes(bytes(data))


def _drop_checksum(folder: Path) -> None:
    config = json.loads((folder / CONFIG_FILE).read_text())
    del config["weights_sha256"]
    (folder / CONFIG_FILE).write_text(json.dumps(config))


@pytest.mark.parametrize(("damage", "file", "message"), [
    (lambda f: (f / CONFIG_FILE).unlink(), CONFIG_FILE, "missing; expected a zoo folder of a simshear posenet"),
    (lambda f: (f / CONFIG_FILE).write_text("{not json"), CONFIG_FILE, "not valid JSON"),
    (lambda f: (f / CONFIG_FILE).write_text('{"algo": "ppo"}'), CONFIG_FILE, "format None; expected a zoo folder"),
    (lambda f: (f / WEIGHTS_FILE).unlink(), WEIGHTS_FILE, "missing; expected the posenet weights"),
    (lambda f: _flip_a_byte(f / WEIGHTS_FILE), WEIGHTS_FILE, r"sha256 .* differs from the .* recorded in config.json"),
    (lambda f: (_drop_checksum(f), (f / WEIGHTS_FILE).write_bytes(b"garbage")), WEIGHTS_FILE,
     "not a readable safetensors file"),
    (lambda f: (_drop_checksum(f), (f / WEIGHTS_FILE).write_bytes(b"")), WEIGHTS_FILE,
     "not a readable safetensors file"),
])
def test_a_bad_folder_is_one_error_naming_the_file(tmp_path, damage, file, message):
    folder = _gdnn_folder(tmp_path)
    damage(folder)
    with pytest.raises(WeightsFileError, match=message) as caught:
        load_posenet(folder)
    assert str(caught.value).startswith(str(folder / file))


def test_a_folder_of_another_model_is_one_error(tmp_path):
    folder = _gdnn_folder(tmp_path)
    with pytest.raises(WeightsFileError, match=r"config.json: the config of a 'GDNN' model, not a translator "
                                               r"\('UNetGenerator'\)"):
        load_generator(folder)
    # the right class, another architecture's weights
    config = json.loads((folder / CONFIG_FILE).read_text())
    (folder / CONFIG_FILE).write_text(json.dumps({**config, "conv_channels": [8]}))
    with pytest.raises(WeightsFileError, match="not a simshear posenet folder .*another architecture"):
        load_posenet(folder)


def test_a_policy_folder_is_not_a_model_folder(converted):
    with pytest.raises(WeightsFileError, match="policy_edge_ppo/config.json: format None"):
        load_posenet(converted / "policy_edge_ppo")


def test_ship_zoo_converts_the_models_named_and_refuses_others(tmp_path, capsys):
    from simshear_gym import cli

    assert cli.main(["ship", "zoo", "--to", str(tmp_path), "--models", "posenet_edge"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["posenet_edge"]
    assert cli.main(["ship", "zoo", "--to", str(tmp_path), "--models", "posenet_walk"]) == 2
    assert "--models ['posenet_walk']: no such shipped model; shipped: [" in capsys.readouterr().err
