"""One home per training knob: the trainers' configs own the knobs and their defaults; the pipeline's stages, pool
generators and env-model recipes override them; what every profile of the shipped configs trains stays pinned
(``tests/fixtures/pipeline_knobs.json``, written by the code before the knobs moved); ``configs/README.md``
documents exactly the keys the dataclasses read."""

from __future__ import annotations

import ast
import dataclasses
import importlib
import json
import re
from pathlib import Path

import pytest

from simshear_gym.pipelines import config as pipeline_config
from simshear_gym.pipelines.config import (
    POSENET_SET_BY_PIPELINE,
    TRANSLATOR_SET_BY_PIPELINE,
    EnvModelRecipe,
    PoolGenerator,
    PosenetStage,
    Profile,
    TranslatorStage,
    knob_names,
    load_config,
    trainer_defaults,
)
from simshear_gym.pipelines.stages import StageResult
from simshear_gym.train.posenet_config import PosenetTrainConfig
from simshear_gym.train.translator_config import TranslatorTrainConfig

ROOT = Path(__file__).resolve().parents[1]
PINNED = json.loads((ROOT / "tests" / "fixtures" / "pipeline_knobs.json").read_text())


class _KeyRunner:
    """A stage runner that records each stage's cache key and runs nothing."""

    root = Path("/nowhere")

    def __init__(self) -> None:
        self.keys: dict[str, dict] = {}

    def run(self, name, key, work):
        self.keys[name] = key
        return StageResult(name, Path("/nowhere"), {"outputs": {"weights": f"w/{name}.pt", "run": "run"},
                                                    "hash": name}, ran=False)


class _Done(dict):
    def __missing__(self, name):
        return StageResult(name, Path("/nowhere"), {"outputs": {"weights": f"w/{name}.pt"}}, ran=False)


def _settings_of_steps(config, profile: str) -> dict:
    from simshear_gym.pipelines.estimate import planned_steps

    found = {}
    for step in planned_steps(config, profile):
        runner = _KeyRunner()
        step.action(runner, _Done())
        (key,) = runner.keys.values()
        found[step.name] = json.loads(json.dumps(key["settings"]))
    return found


@pytest.mark.parametrize("name", sorted(name for name in PINNED if ":env_models." not in name))
def test_every_profile_of_the_shipped_configs_trains_what_it_trained(name):
    """The settings each training step passes its trainer (and keys its cache by) are those before the knobs
    moved: same epochs, rate, schedule, patience... for every step of every profile."""
    file, profile = name.split(":")
    assert _settings_of_steps(load_config(ROOT / "configs" / file), profile) == PINNED[name]


@pytest.mark.parametrize("name", sorted(name for name in PINNED if ":env_models." in name))
def test_every_env_model_recipe_trains_what_it_trained(name):
    from simshear_gym.pipelines.env_model import train_step

    file, model = name.split(":env_models.")
    recipe = load_config(ROOT / "configs" / file).env_model(model)
    runner = _KeyRunner()
    sets = [StageResult(f"envset/{s}", Path("/x"), {"outputs": {"set": f"{s}"}, "hash": f"{s}"}, False)
            for s in recipe.oracle_seeds]
    train_step(runner, recipe, "first", sets, recipe.first_epochs, "cpu")
    train_step(runner, recipe, "final", sets, recipe.train_settings()["epochs"], "cpu")
    assert {stage: json.loads(json.dumps(key["settings"])) for stage, key in runner.keys.items()} == PINNED[name]


def test_the_shipped_recipe_reads_from_the_toml_alone():
    """What ``full`` of configs/tactip331.toml trains is the trainers' defaults and its own tables: neither the
    built-in ``full`` nor the pipeline's epoch budget adds a knob it does not name."""
    table = pipeline_config.read_toml(ROOT / "configs" / "tactip331.toml")["profiles"]["full"]
    profile = load_config(ROOT / "configs" / "tactip331.toml").profile("full")
    for stage, trainer, settings in (("translator", TranslatorTrainConfig, profile.translator.settings_for),
                                     ("posenet", PosenetTrainConfig, profile.posenet.train_settings)):
        own = {item.name for item in dataclasses.fields(type(getattr(profile, stage)))}
        written = {**trainer_defaults(trainer), **{k: v for k, v in table[stage].items() if k not in own}}
        for contact in ("surface", "edge"):
            resolved = settings(contact)
            epochs = table[stage].get("contact_epochs", {}).get(contact, written["epochs"])
            assert resolved == {knob: written[knob] for knob in resolved} | {"epochs": epochs}
    assert {"jobs": profile.jobs, "rows_per_split": profile.rows_per_split} == {"jobs": table["jobs"],
                                                                                  "rows_per_split": None}


MIRRORS = ((TranslatorStage, TranslatorTrainConfig), (PoolGenerator, TranslatorTrainConfig),
           (PosenetStage, PosenetTrainConfig), (EnvModelRecipe, PosenetTrainConfig))


def _defaults(cls) -> dict:
    out = {}
    for item in dataclasses.fields(cls):
        if item.default is not dataclasses.MISSING:
            out[item.name] = item.default
        elif item.default_factory is not dataclasses.MISSING:
            out[item.name] = item.default_factory()
    return out


@pytest.mark.parametrize(("config", "trainer"), MIRRORS, ids=lambda cls: cls.__name__)
def test_a_stage_holds_no_copy_of_a_trainer_knob(config, trainer):
    """A stage, pool generator or recipe has its own fields and ``overrides``: no field of the trainer's config,
    so no second default for a knob."""
    mirrored = sorted(set(_defaults(config)) & set(_defaults(trainer)))
    assert mirrored == []


def test_the_trainers_default_models_are_the_models_defaults():
    """The architecture knobs a trainer config writes out (torch-free) default to the model configs' defaults."""
    from simshear_gym.models.gdnn import GDNNConfig
    from simshear_gym.models.unet import UNetConfig

    assert TranslatorTrainConfig(paired_dirs=("set",)).generator_config() == UNetConfig()
    assert PosenetTrainConfig(paired_dirs=("set",)).gdnn_config() == GDNNConfig()
    conflicts = [(name, value, _defaults(UNetConfig)[name]) for name, value in _defaults(TranslatorTrainConfig).items()
                 if name in _defaults(UNetConfig) and value != _defaults(UNetConfig)[name]]
    assert conflicts == []


def test_the_real_env_holds_a_client_config_not_copies_of_its_fields():
    from simshear_gym.real.env import ENV_CLIENT, RealEnvConfig
    from simshear_gym.real.mg400_client import MG400ClientConfig

    assert sorted(set(_defaults(RealEnvConfig)) & set(_defaults(MG400ClientConfig))) == []
    assert RealEnvConfig().client == ENV_CLIENT
    named = {name: value for name, value in vars(ENV_CLIENT).items() if value != _defaults(MG400ClientConfig)[name]}
    assert named == {"reply_timeout_s": 1.0, "sync_timeout_s": 30.0}  # the control loop's, named in ENV_CLIENT


def test_an_unknown_or_pipeline_owned_knob_is_one_error_naming_file_table_key_and_the_valid_keys(tmp_path):
    from simshear_gym.tables import ConfigError

    text = (ROOT / "configs" / "tactip331.toml").read_text()
    path = tmp_path / "lab.toml"
    path.write_text(text.replace("[profiles.quick.translator]\n", "[profiles.quick.translator]\nepoch = 3\n"))
    with pytest.raises(ConfigError, match=r"lab\.toml: \[profiles\.quick\.translator\] unknown key 'epoch'; "
                                          r"expected one of \['archs', 'contact_epochs'\] or a TranslatorTrainConfig "
                                          r"knob of \[.*'epochs'.*\]") as raised:
        load_config(path)
    assert "pose_weight" not in str(raised.value).split("knob of")[1]  # pool generators only
    path.write_text(text.replace("[profiles.quick.posenet]\n", "[profiles.quick.posenet]\nvariables = 'edge'\n"))
    with pytest.raises(ConfigError, match=r"\[profiles\.quick\.posenet\] 'variables' is set by the pipeline"):
        load_config(path)
    path.write_text(text.replace("first_epochs = 10\n", "first_epochs = 10\nlr = 'fast'\n", 1))
    with pytest.raises(ConfigError, match=r"env_models\.colift\.lr = 'fast'; expected a number"):
        load_config(path)


README_CHECKED = {
    Profile: None, TranslatorStage: None, PosenetStage: None, PoolGenerator: None, EnvModelRecipe: None,
    pipeline_config.CheckConfig: None,
    TranslatorTrainConfig: TRANSLATOR_SET_BY_PIPELINE, PosenetTrainConfig: POSENET_SET_BY_PIPELINE,
}


def _readme_tables() -> dict[type, dict[str, str]]:
    """{dataclass named in a heading: {key in its table's first column: the default column}}."""
    tables: dict[type, dict[str, str]] = {}
    current = None
    for line in (ROOT / "configs" / "README.md").read_text().splitlines():
        if line.startswith("#"):
            found = re.search(r"`(simshear_gym(?:\.\w+)+)\.(\w+)`\)?\s*$", line)
            current = getattr(importlib.import_module(found[1]), found[2]) if found else None
            if current is not None:
                tables.setdefault(current, {})
        elif current is not None and line.startswith("| `"):
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            keys = re.findall(r"`([^`]+)`", cells[0])
            for key in keys:
                tables[current][key] = cells[1] if len(keys) == 1 and len(cells) > 2 else ""
    return tables


def _literal(text: str):
    text = text.strip("`")
    words = {"none": None, "true": True, "false": False}
    return words[text] if text in words else ast.literal_eval(text)


def _plain(value):
    return list(value) if isinstance(value, tuple) else dict(value) if isinstance(value, dict) else value


def test_the_config_readme_documents_exactly_the_keys_and_defaults_the_dataclasses_read():
    tables = _readme_tables()
    for cls, set_by_pipeline in README_CHECKED.items():
        assert cls in tables, f"configs/README.md has no table headed `{cls.__module__}.{cls.__name__}`"
        expected = (set(knob_names(cls, set_by_pipeline)) if set_by_pipeline is not None
                    else {item.name for item in dataclasses.fields(cls)} - {"overrides"})
        assert set(tables[cls]) == expected, cls.__name__
        defaults = _defaults(cls)
        for key, cell in tables[cls].items():
            if cell and cell != "(required)" and key in defaults:
                assert _literal(cell) == _plain(defaults[key]), (cls.__name__, key, cell)
