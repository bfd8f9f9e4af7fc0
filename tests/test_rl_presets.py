"""``simshear train rl --preset NAME``: named settings under the flags given beside them; the first-policy example
(``examples/first_policy.py``) runs as written on a tiny budget."""

import importlib.util
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np
import pytest

from simshear_gym.cli import command_parser
from simshear_gym.train.rl import config_of
from simshear_gym.train.rl_config import PRESETS, RLTrainConfig

ROOT = Path(__file__).resolve().parents[1]


def parsed(*flags: str) -> RLTrainConfig:
    return config_of(command_parser(("train", "rl")).parse_args(["--out", "unused", *flags]))


def test_without_a_preset_the_flags_and_the_defaults_make_the_config():
    assert parsed() == RLTrainConfig()
    assert parsed("--n-steps", "128", "--no-normalize", "--net-arch", "32", "32") == RLTrainConfig(
        n_steps=128, normalize=False, net_arch=(32, 32))


def test_a_preset_fills_what_no_flag_gives_and_every_flag_given_wins():
    preset = PRESETS["tracking-first"]
    config = parsed("--preset", "tracking-first")
    assert {name: getattr(config, name) for name in preset} == preset
    others = {f.name for f in fields(RLTrainConfig)} - set(preset)
    assert {name: getattr(config, name) for name in others} == {n: v for n, v in asdict(RLTrainConfig()).items()
                                                               if n in others}
    # a flag wins even when it gives the dataclass default (3e-4) that the preset changes
    changed = parsed("--preset", "tracking-first", "--learning-rate", "0.0003", "--timesteps", "0", "--task", "colift")
    assert (changed.learning_rate, changed.timesteps, changed.task) == (3e-4, 0, "colift")
    assert changed.bc_steps == preset["bc_steps"]


def test_the_tracking_first_preset_is_the_documented_recipe():
    config = parsed("--preset", "tracking-first")
    assert (config.algo, config.task, config.observation, config.history) == ("ppo", "tracking", "estimate+action", 2)
    assert config.bc_steps * config.bc_rounds + config.timesteps <= 200_000  # a budget for a 2-core CPU
    recipe = (ROOT / "docs" / "first_policy.md").read_text()
    assert "simshear train rl --preset tracking-first --out runs/rl/first_policy" in recipe
    assert f"{config.bc_steps * config.bc_rounds:,} env steps" in recipe and f"{config.timesteps:,} PPO steps" in recipe


def test_an_unknown_preset_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        command_parser(("train", "rl")).parse_args(["--out", "x", "--preset", "no-such"])
    assert "invalid choice: 'no-such'" in capsys.readouterr().err


@pytest.mark.slow
def test_the_first_policy_example_runs_as_written_on_a_tiny_budget():
    spec = importlib.util.spec_from_file_location("first_policy", ROOT / "examples" / "first_policy.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    model, venv, errors = example.main(clone_steps=40, rounds=2, ppo_steps=1, max_steps=5)
    assert list(errors) == ["circle", "tilted_square", "spiral", "loop"]
    assert all(np.isfinite(value) and value >= 0 for value in errors.values())
    assert model.num_timesteps >= 1 and not venv.training
    assert set(venv.obs_rms) == {"estimate", "last_action"}  # the clone's rollouts updated the statistics
    assert venv.obs_rms["estimate"].count > 80
