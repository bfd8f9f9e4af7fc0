"""``simshear pipeline env-model``: an env GDNN from its recipe in the sensor config, every step a cached stage."""

import json
import shutil
from pathlib import Path

import pytest

from simshear_gym import cli
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.pipelines.config import EnvModelRecipe, load_config
from simshear_gym.pipelines.env_model import run_recipe
from simshear_gym.tables import ConfigError

TINY = EnvModelRecipe(task="colift", payload="heavy", rows=12, episode_steps=4, oracle_seeds=(1, 2),
                      first_round_seeds=(1,), dagger_seeds=(3,), first_epochs=1,
                      overrides={"epochs": 1, "batch_size": 4, "threads": 1})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("env_model")
    return out, run_recipe(TINY, "colift_heavy", out, command="test")


def test_the_recipe_collects_trains_a_first_gdnn_drives_a_dagger_set_with_it_and_trains_on_all(tiny_run):
    out, manifest = tiny_run
    stages = [result["stage"] for result in manifest["results"]]
    assert stages == ["envset/1", "envset/2", "envposenet/first", "envset/3", "envposenet/final"]
    assert all(result["ran"] for result in manifest["results"])
    dagger = json.loads((out / next(r["folder"] for r in manifest["results"] if r["stage"] == "envset/3")
                         / "set" / "meta.json").read_text())
    assert dagger["config"]["driver"] == "servo" and dagger["config"]["payload"] == "heavy"
    first_weights = out / next(r["folder"] for r in manifest["results"] if r["stage"] == "envposenet/first")
    assert Path(dagger["config"]["posenet"]) == first_weights / "run" / "best.pt"  # the first GDNN drove it
    final_config = json.loads((out / manifest["final_run"] / "config.json").read_text())
    assert len(final_config["paired_dirs"]) == 3 and final_config["source"] == "env"
    model, card = load_posenet(out / manifest["weights"])
    assert model.variables.name == "env" and card["env_model"] == "colift_heavy"
    assert card["recipe"]["dagger_seeds"] == [3]
    assert not Path(manifest["weights"]).is_absolute() and not Path(manifest["final_run"]).is_absolute()


def test_a_rerun_finds_every_stage_cached_and_a_changed_setting_reruns_only_what_depends_on_it(tiny_run, tmp_path):
    out, first = tiny_run
    again = run_recipe(TINY, "colift_heavy", out)
    assert not any(result["ran"] for result in again["results"])
    assert again["final_run"] == first["final_run"]
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    from dataclasses import replace

    changed = run_recipe(replace(TINY, overrides={**TINY.overrides, "epochs": 2}), "colift_heavy", copy)
    ran = {result["stage"]: result["ran"] for result in changed["results"]}
    assert ran == {"envset/1": False, "envset/2": False, "envposenet/first": False, "envset/3": False,
                   "envposenet/final": True}


def test_the_shipped_config_holds_the_heavy_colift_recipe():
    recipe = load_config("configs/tactip331.toml").env_model("colift_heavy")
    assert (recipe.task, recipe.payload) == ("colift", "heavy")
    assert recipe.first_round == (30, 31, 32) and recipe.dagger_seeds == (33,)


@pytest.mark.parametrize(("table", "message"), [
    ("payload = 'medium'", r"env_models\.bad.*payload must be one of \['light', 'heavy'\]"),
    ("task = 'tracking'\npayload = 'heavy'", r"heavy: task colift"),
    ("oracle_seeds = [1, 2]\ndagger_seeds = [2]", r"oracle_seeds and dagger_seeds must all differ"),
    ("oracle_seeds = [1, 2]\nfirst_round_seeds = [5]", r"first_round_seeds must be some of oracle_seeds"),
    ("epochs = 0", r"must be >= 1"),
    ("rows = 'many'", r"env_models\.bad.*rows"),
])
def test_a_bad_recipe_is_one_error_naming_the_file_and_the_table(tmp_path, table, message):
    text = Path("configs/tactip331.toml").read_text() + f"\n[env_models.bad]\n{table}\n"
    path = tmp_path / "lab.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as raised:
        load_config(path)
    assert str(path) in str(raised.value)


def test_an_unknown_model_names_the_ones_the_config_has(tmp_path, capsys):
    assert cli.main(["pipeline", "env-model", "configs/tactip331.toml", "--model", "colift_light",
                     "--out", str(tmp_path)]) == 2
    assert "no [env_models.colift_light] table; it has ['colift', 'colift_heavy']" in capsys.readouterr().err
