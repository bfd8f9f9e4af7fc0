"""``simshear ship policy``: a run's policy becomes a shipped folder that the benchmark and the robot load
like the run itself (same settings, same normalisation, same actions), with a card that names its command; and the
trainer's evaluation envs exist in the main process whatever the sub-envs' vectorisation."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from simshear_gym import cli
from simshear_gym.control.env_estimator import env_kwargs
from simshear_gym.control.policy import PolicySettings, SB3Controller, stale_estimator_models
from simshear_gym.models.zoo import POLICY_DIR
from simshear_gym.ship.policy import (
    ENV_MODELS,
    SHIPPED_FILES,
    export,
    source_files,
)
from simshear_gym.train.rl import RLTrainConfig, train

torch.set_num_threads(1)
COMMAND = "simshear train rl --algo ppo --timesteps 32 --out runs/rl/tiny"
EXPORT = "simshear ship policy --run RUN --to policy"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rl") / "tiny"
    train(RLTrainConfig(timesteps=32, observation="estimate", history=2, obs_mode="sim", image_size_px=64,
                        n_steps=16, batch_size=16, n_epochs=2, checkpoint_steps=16, eval_steps=16, eval_max_steps=4),
          folder, progress=False)
    return folder


def test_the_exported_policy_acts_like_the_run_and_carries_its_card(run_dir, tmp_path):
    to = tmp_path / "policies" / "tracking_ppo"
    code = cli.main(["ship", "policy", "--run", str(run_dir), "--to", str(to), "--train-command", COMMAND,
                     "--date", "2026-01-02"])
    assert code == 0
    assert {p.name for p in to.iterdir()} == {"model.pt", "model.json", "vecnormalize.json", "config.json",
                                              "model.md"}  # no pickle
    assert (to / "model.pt").read_bytes() == (run_dir / "best_model.pt").read_bytes()
    assert not list(run_dir.rglob("*.pkl"))  # the trainer writes none either
    config = json.loads((to / "config.json").read_text())
    assert config["provenance"]["train_command"] == COMMAND
    assert set(config["provenance"]["estimator_models_sha256"]) == {"translator_shpix2pix_surface", "posenet_surface"}
    assert PolicySettings.of_model(to / "model.pt") == PolicySettings.of_model(run_dir / "best_model.zip")

    settings = PolicySettings.of_model(to / "model.pt")
    env = gym.make("SimShearTracking-v0", trajectory="circle", **env_kwargs(settings))
    shipped = SB3Controller.for_env(to / "model.pt", env)
    original = SB3Controller.for_env(run_dir / "best_model.zip", env)
    observation, _ = env.reset(seed=0)
    for _ in range(3):
        action = shipped(observation)
        np.testing.assert_array_equal(action, original(observation))
        observation, *_ = env.step(action)
    env.close()

    card = (to / "model.md").read_text()
    assert COMMAND in card and "2026-01-02" in card and "Training evaluation (best model)" in card
    assert str(tmp_path) not in card and str(run_dir) not in card  # no absolute paths


def test_a_policy_whose_estimator_models_were_replaced_warns_on_load(run_dir, tmp_path):
    """A shipped policy records the sha256 of the translator and GDNN that made its observations; once either
    shipped file changes, loading it warns (it sees other observations than in training) and names the model."""
    to = tmp_path / "policy"
    export(run_dir, to, COMMAND, date="2026-01-02")
    assert stale_estimator_models(to / "model.pt") == []
    assert stale_estimator_models(run_dir / "best_model.zip") == []  # a run folder records no provenance
    settings = PolicySettings.of_model(to / "model.pt")
    env = gym.make("SimShearTracking-v0", trajectory="circle", **env_kwargs(settings))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SB3Controller.for_env(to / "model.pt", env)
    config = json.loads((to / "config.json").read_text())
    config["provenance"]["estimator_models_sha256"]["translator_shpix2pix_surface"] = "0" * 64
    (to / "config.json").write_text(json.dumps(config))
    assert stale_estimator_models(to / "model.pt") == ["translator_shpix2pix_surface"]
    with pytest.warns(UserWarning, match=r"translator_shpix2pix_surface.*train it again"):
        SB3Controller.for_env(to / "model.pt", env)
    env.close()


def test_a_run_without_an_evaluated_model_names_what_is_missing(tmp_path, run_dir):
    (tmp_path / "config.json").write_text((run_dir / "config.json").read_text())
    with pytest.raises(FileNotFoundError, match="best_model.zip.*--model final"):
        source_files(tmp_path, "best")
    with pytest.raises(FileNotFoundError, match="not a run of simshear train rl"):
        export(tmp_path / "nothing", tmp_path / "to", COMMAND)


def test_shipped_policies_load_in_their_env():
    """Every folder under models/weights/policies is a complete, pickle-free policy that loads against its own env,
    trained on the observations of the shipped translator and GDNN."""
    folders = sorted(p for p in POLICY_DIR.glob("*") if p.is_dir()) if POLICY_DIR.is_dir() else []
    assert {folder.name for folder in folders} >= {"tracking_ppo", "colift_ppo", "edge_ppo"}
    for folder in folders:
        assert {p.name for p in folder.iterdir()} == set(SHIPPED_FILES), folder  # no pickle
        assert (folder / "model.pt").stat().st_size <= 10 * 2**20, folder
        # a new shipped translator or GDNN ships with the policies retrained on its observations
        assert stale_estimator_models(folder / "model.pt") == [], folder
        settings = PolicySettings.of_model(folder / "model.pt")
        env_id = ENV_MODELS[settings.task][0]
        env = gym.make(env_id, **env_kwargs(settings))
        controller = SB3Controller.for_env(folder / "model.pt", env)
        observation, _ = env.reset(seed=0)
        action = controller(observation)
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
        env.close()


def test_shipped_policies_act_as_their_pickled_originals():
    """The shipped policies were converted from SB3 .zip + vecnormalize.pkl to pickle-free files; on the stored
    observations they give the actions the pickled originals gave (tests/fixtures/policy_actions.json, written
    from the originals before the conversion), to 1e-6."""
    from simshear_gym.control.policy_files import load_normalizer, load_policy

    stored = json.loads((Path(__file__).parent / "fixtures" / "policy_actions.json").read_text())["policies"]
    assert set(stored) == {"tracking_ppo", "colift_ppo"}
    for name, rows in stored.items():
        policy = load_policy(POLICY_DIR / name / "model.pt")
        normalizer = load_normalizer(POLICY_DIR / name / "vecnormalize.json")
        assert len(rows) >= 20
        for row in rows:
            observation = {key: np.asarray(value, np.float32) for key, value in row["observation"].items()}
            action, _ = policy.predict(normalizer.normalize_obs(observation), deterministic=True)
            np.testing.assert_allclose(action, row["action"], rtol=0, atol=1e-6)


def test_a_policy_is_named_by_any_of_its_files():
    """model.pt, model.json and the model.zip they replaced (in recorded commands) name one policy."""
    from simshear_gym.control.policy import sb3_algorithm

    folder = POLICY_DIR / "tracking_ppo"
    assert {sb3_algorithm(folder / name) for name in ("model.pt", "model.json", "model.zip")} == {"ppo"}


def test_the_trainer_registers_the_envs_its_evaluation_makes():
    """With --vec subproc only the workers make training envs; the evaluation envs are made in the main process."""
    code = ("import gymnasium, simshear_gym.train.rl_trainer; "
            "[gymnasium.spec(i) for i in ('SimShearTracking-v0', 'SimShearCoLift-v0')]")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_card_quotes_the_evaluation_of_the_model_it_ships(tmp_path):
    """best_model.zip is the model of the last evaluation that set a new best, and the card quotes that one."""
    from simshear_gym.ship.cards import policy_card

    to = tmp_path / "policy"
    to.mkdir()
    (to / "model.pt").write_bytes(b"0")
    evaluations = [{"timesteps": 100, "wall_s": 6.0, "contact_error_mean_mm": 0.7, "ended_early": 0, "best": True,
                    "episodes": {}},
                   {"timesteps": 200, "wall_s": 12.0, "contact_error_mean_mm": 0.2, "ended_early": 0, "best": True,
                    "episodes": {}},
                   {"timesteps": 300, "wall_s": 18.0, "contact_error_mean_mm": 0.3, "ended_early": 0,
                    "episodes": {}}]
    from dataclasses import asdict

    config = {**asdict(RLTrainConfig(timesteps=300, observation="estimate")), "env_id": "SimShearTracking-v0"}
    provenance = {"train_command": COMMAND, "exported_from": "tiny/best_model.zip", "estimator_models_sha256": {}}
    best = policy_card(config, provenance, to, "best", evaluations, {}, {}, "ppo", EXPORT, "2026-01-02",
                       ENV_MODELS["tracking"])
    assert "At 200 env steps" in best and "0.200 mm" in best and "At 100 env steps" not in best
    final = policy_card(config, provenance, to, "final", evaluations, {}, {}, "ppo", EXPORT, "2026-01-02",
                        ENV_MODELS["tracking"])
    assert "At 300 env steps" in final


def test_the_card_of_a_servo_law_clone_says_so(tmp_path):
    from dataclasses import asdict

    from simshear_gym.ship.cards import policy_card

    to = tmp_path / "policy"
    to.mkdir()
    (to / "model.pt").write_bytes(b"0")
    config = {**asdict(RLTrainConfig(task="colift", timesteps=0, observation="estimate+action", history=2,
                                     bc_steps=100, bc_rounds=2)), "env_id": "SimShearCoLift-v0"}
    provenance = {"train_command": COMMAND, "exported_from": "tiny/model.zip", "estimator_models_sha256": {}}
    imitation = {"noise": 0.1, "epochs": 30, "after": {"actor_mse": 3e-5}, "rounds": [{}, {}], "seconds": 120.0}
    summary = {"timesteps": 0, "seconds": 0.0, "stopped_by": "timesteps", "imitation": imitation}
    card = policy_card(config, provenance, to, "final", [], summary, {}, "ppo", EXPORT, "2026-01-02",
                       ENV_MODELS["colift"])
    assert "Budget: no RL steps" in card and "ran 0 steps" not in card
    assert "DAgger clone of the servo law in velocity form" in card and "2 round(s) of 100 steps" in card
    assert "actor MSE against the teacher 3e-05" in card and "2.0 min" in card
    assert "and the last action (MLP)" in card
