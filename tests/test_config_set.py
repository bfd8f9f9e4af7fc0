"""``--set SECTION.KEY=VALUE`` on the commands that read a config TOML: the value read as TOML over the file (the
file untouched), bad forms one error, and a pipeline run records what it was given."""

from __future__ import annotations

import json

import pytest

from simshear_gym.pipelines.config import load_config
from simshear_gym.tables import ConfigError, parse_setting, with_settings
from tests.test_pipeline_check import write_lab


def test_a_setting_is_a_dotted_key_and_a_toml_value():
    assert parse_setting("profiles.smoke.translator.epochs=2") == (("profiles", "smoke", "translator", "epochs"), 2)
    assert parse_setting("a.b=0.5") == (("a", "b"), 0.5)
    assert parse_setting('a.lr_schedule="cosine"') == (("a", "lr_schedule"), "cosine")
    assert parse_setting("a.schedule=cosine") == (("a", "schedule"), "cosine")  # a bare word: a string
    assert parse_setting("a.sizes=[1, 2]") == (("a", "sizes"), [1, 2])
    assert parse_setting("a.flag=true") == (("a", "flag"), True)
    for bad in ("profiles.smoke.epochs", "=2", "a..b=1", "a.b="):
        with pytest.raises(ConfigError, match="expected SECTION.KEY=VALUE"):
            parse_setting(bad)


def test_settings_apply_over_a_copy_and_a_key_through_a_value_is_refused():
    table = {"name": "lab", "profiles": {"smoke": {"translator": {"epochs": 1}}}}
    changed = with_settings(table, ["profiles.smoke.translator.epochs=3", "profiles.quick.posenet.epochs=4"], "f")
    assert changed["profiles"]["smoke"]["translator"]["epochs"] == 3
    assert changed["profiles"]["quick"] == {"posenet": {"epochs": 4}}
    assert table["profiles"]["smoke"]["translator"]["epochs"] == 1  # the file's table is not changed
    with pytest.raises(ConfigError, match=r"f: --set 'name.first=x': name is 'lab', not a table"):
        with_settings(table, ["name.first=x"], "f")


def test_a_config_read_with_settings_names_them_in_its_errors(tmp_path):
    path = write_lab(tmp_path / "data")
    text = path.read_text()
    config = load_config(path, ["profiles.smoke.translator.epochs=2"])
    assert config.profiles["smoke"].translator.setting("epochs") == 2 and config.settings == (
        "profiles.smoke.translator.epochs=2",)
    assert load_config(path).profiles["smoke"].translator.setting("epochs") != 2 and path.read_text() == text
    with pytest.raises(ConfigError, match=r"with --set profiles.smoke.translator.epoch=2.*epoch"):
        load_config(path, ["profiles.smoke.translator.epoch=2"])


def test_pipeline_run_takes_a_setting_and_its_manifest_records_it(tmp_path):
    from simshear_gym import cli

    data = tmp_path / "data"
    path = write_lab(data, rows=30)
    out = tmp_path / "run"
    code = cli.main(["pipeline", "run", str(path), "--profile", "smoke", "--data", str(data), "--out", str(out),
                     "--stages", "adapt", "collect", "translator", "--workers", "1",
                     "--set", "profiles.smoke.translator.epochs=2"])
    assert code == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"] == ["profiles.smoke.translator.epochs=2"]
    translator = next(r for r in manifest["results"] if r["stage"].startswith("translator"))
    record = json.loads((out / translator["folder"] / "stage.json").read_text())
    assert record["metrics"]["epochs"] == 2 and record["metrics"]["stopped_by"] == "epochs"
