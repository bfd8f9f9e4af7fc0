"""Files that would run code when loaded are refused, and nothing in them runs (issue 41, item 2).

Each crafted file carries a payload whose unpickling creates a marker file (``open(marker, "w")``, the harmless
stand-in for any code): a policy ``.zip`` of Stable-Baselines3, a ``vecnormalize.pkl`` beside a pickle-free policy,
a policy ``.pt`` whose description vouches for it, and a trainer's ``checkpoint.pt``. The loaders refuse each with
one error naming the file, and the marker never appears. The pickle-free policy files round-trip an agent exactly.
"""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

from simshear_gym import cli
from simshear_gym.control.policy import SB3Controller, sb3_algorithm
from simshear_gym.control.policy_files import (
    PolicyFileError,
    file_sha256,
    load_normalizer,
    load_policy,
    save_normalizer,
    save_policy,
)
from simshear_gym.train.loop import CheckpointError, load_checkpoint

torch.set_num_threads(1)


class Payload:
    """Unpickling it opens (creates) ``marker``: were a loader to unpickle it, the marker would show."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


class TinyEnv(gym.Env):
    """A Dict observation like the envs' estimate observation, four actions in [-1, 1]."""

    observation_space = spaces.Dict({"estimate": spaces.Box(-4.0, 4.0, (6,), np.float32)})
    action_space = spaces.Box(-1.0, 1.0, (4,), np.float32)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return {"estimate": self.np_random.normal(size=6).astype(np.float32)}, {}

    def step(self, action):
        return {"estimate": self.np_random.normal(size=6).astype(np.float32)}, 0.0, False, False, {}


@pytest.fixture(scope="module")
def agent():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([TinyEnv]), norm_obs_keys=["estimate"])
    model = PPO("MultiInputPolicy", venv, n_steps=16, batch_size=16, n_epochs=1, seed=0, device="cpu",
                policy_kwargs={"net_arch": [8, 8]})
    model.learn(32)
    venv.training = False
    return model, venv


def policy_folder(folder: Path, agent) -> Path:
    """A run folder with the agent's pickle-free files and its run settings."""
    model, venv = agent
    folder.mkdir(parents=True, exist_ok=True)
    save_policy(model, folder / "model.pt")
    save_normalizer(venv, folder / "vecnormalize.json")
    (folder / "config.json").write_text(json.dumps({"observation": "estimate", "history": 1, "obs_mode": "sim",
                                                    "image_size_px": 64, "task": "tracking"}))
    return folder


def load(path: Path, **kwargs) -> SB3Controller:
    return SB3Controller.load(path, TinyEnv.observation_space, TinyEnv.action_space, **kwargs)


def test_the_pickle_free_files_act_as_the_agent_did(agent, tmp_path):
    model, venv = agent
    folder = policy_folder(tmp_path / "run", agent)
    controller = load(folder / "model.pt")
    assert sb3_algorithm(folder / "model.pt") == "ppo" and controller.name.startswith("ppo:")
    rng = np.random.default_rng(0)
    for _ in range(20):
        observation = {"estimate": rng.normal(0, 3, 6).astype(np.float32)}
        expected, _ = model.predict(venv.normalize_obs(observation), deterministic=True)
        np.testing.assert_array_equal(controller(observation), np.asarray(expected, np.float32))
    stats = load_normalizer(folder / "vecnormalize.json")
    np.testing.assert_array_equal(stats.obs_rms["estimate"][0], venv.obs_rms["estimate"].mean)
    text = (folder / "model.json").read_text() + (folder / "vecnormalize.json").read_text()
    assert ":serialized:" not in text and "__reduce__" not in text  # nothing but data


def test_a_crafted_policy_zip_is_refused_and_runs_nothing(tmp_path, capsys):
    """An SB3 .zip whose pickled entry runs code: refused by the controller, the benchmark and the export."""
    marker = tmp_path / "ran"
    payload = base64.b64encode(pickle.dumps(Payload(marker))).decode()
    data = {"observation_space": {":type:": "<class 'gymnasium.spaces.dict.Dict'>", ":serialized:": payload},
            "clip_range": {":serialized:": payload}, "policy_class": {":serialized:": payload}}
    run = tmp_path / "run"
    run.mkdir()
    with zipfile.ZipFile(run / "model.zip", "w") as archive:
        archive.writestr("data", json.dumps(data))
        archive.writestr("policy.pth", pickle.dumps(Payload(marker)))
    (run / "config.json").write_text(json.dumps({"observation": "estimate", "task": "tracking", "normalize": False}))

    assert sb3_algorithm(run / "model.zip") == "ppo"  # its JSON alone is read
    with pytest.raises(PolicyFileError, match=r"model\.zip.*refused"):
        load(run / "model.zip")
    code = cli.main(["evaluate", "servo", "--tasks", "tracking", "--trajectories", "circle", "--variants", "ppo",
                     "--seeds", "1", "--policy-ppo", str(run / "model.zip"), "--out", str(tmp_path / "results")])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("simshear: error:")]
    assert code == 2 and len(lines) == 1 and "model.zip" in lines[0] and "refused" in lines[0]
    code = cli.main(["ship", "policy", "--run", str(run), "--to", str(tmp_path / "shipped"), "--model",
                     "final", "--train-command", "x"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("simshear: error:")]
    assert code == 2 and len(lines) == 1 and "--trust-pickle" in lines[0]
    assert not marker.exists()
    assert not (tmp_path / "results").exists() and not (tmp_path / "shipped" / "model.pt").exists()


def test_a_crafted_vecnormalize_pkl_is_refused_and_runs_nothing(agent, tmp_path, capsys):
    marker = tmp_path / "ran"
    folder = policy_folder(tmp_path / "run", agent)
    (folder / "vecnormalize.json").unlink()
    (folder / "vecnormalize.pkl").write_bytes(pickle.dumps(Payload(marker)))
    with pytest.raises(PolicyFileError, match=r"vecnormalize\.pkl: a pickle.*refused"):
        load(folder / "model.pt")
    (folder / "best_model.pt").write_bytes((folder / "model.pt").read_bytes())
    (folder / "best_model.json").write_text((folder / "model.json").read_text())
    code = cli.main(["ship", "policy", "--run", str(folder), "--to", str(tmp_path / "shipped"),
                     "--train-command", "x"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("simshear: error:")]
    assert code == 2 and len(lines) == 1 and "vecnormalize.pkl" in lines[0]
    assert not marker.exists()


def test_a_crafted_policy_pt_is_refused_even_when_its_description_vouches_for_it(agent, tmp_path):
    marker = tmp_path / "ran"
    folder = policy_folder(tmp_path / "run", agent)
    torch.save({"weight": Payload(marker)}, folder / "model.pt")
    description = json.loads((folder / "model.json").read_text())
    description["weights_sha256"] = file_sha256(folder / "model.pt")
    (folder / "model.json").write_text(json.dumps(description))
    with pytest.raises(PolicyFileError, match=r"model\.pt: not a policy weights file of tensors"):
        load_policy(folder / "model.pt")
    description["policy_class"] = "builtins.eval"  # a class outside the allowlist is not even imported
    (folder / "model.json").write_text(json.dumps(description))
    with pytest.raises(PolicyFileError, match=r"class 'builtins.eval' is not one a policy file may name"):
        load_policy(folder / "model.pt")
    assert not marker.exists()


def test_a_bit_flipped_policy_pt_is_named_by_its_checksum(agent, tmp_path):
    folder = policy_folder(tmp_path / "run", agent)
    data = bytearray((folder / "model.pt").read_bytes())
    data[len(data) // 2] ^= 0x10
    (folder / "model.pt").write_bytes(bytes(data))
    with pytest.raises(PolicyFileError, match=r"model\.pt: sha256 .* differs .* a corrupt or replaced"):
        load(folder / "model.pt")


def test_a_crafted_checkpoint_is_refused_and_runs_nothing(tmp_path):
    from tests.test_train_loop import FakeConfig, FakeTrainer

    marker = tmp_path / "ran"
    run = tmp_path / "run"
    trainer = FakeTrainer(FakeConfig(epochs=2), run)
    trainer.fit(progress=False)
    assert FakeTrainer(FakeConfig(epochs=3), run).resume()  # its own checkpoint (numpy generator state) loads
    state = load_checkpoint(run / "checkpoint.pt")
    torch.save({**state, "rng": Payload(marker)}, run / "checkpoint.pt")
    with pytest.raises(CheckpointError, match=r"checkpoint\.pt: cannot be resumed from.*without running code"):
        FakeTrainer(FakeConfig(epochs=3), run).resume()
    assert not marker.exists()
    (run / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(CheckpointError, match=r"checkpoint\.pt: cannot be resumed from"):
        FakeTrainer(FakeConfig(epochs=3), run).resume()


def test_an_older_shipped_policy_converts_in_place_only_when_trusted(agent, tmp_path, capsys):
    """`ship policy --convert DIR` turns an older shipped folder (SB3 .zip + .pkl) into the pickle-free files,
    only with --trust-pickle; the converted policy acts as the agent did and its card lists the new files."""
    from simshear_gym.ship.policy import SHIPPED_FILES

    model, venv = agent
    folder = tmp_path / "policy"
    folder.mkdir()
    model.save(folder / "model.zip")
    venv.save(str(folder / "vecnormalize.pkl"))
    (folder / "config.json").write_text(json.dumps({"observation": "estimate", "task": "tracking"}))
    (folder / "model.md").write_text("# PPO policy\n\n- Files: `model.zip`, `vecnormalize.pkl`\n- Date: 2026-01-02\n")
    with pytest.raises(PolicyFileError, match="unpickles"):
        load(folder / "model.zip")
    code = cli.main(["ship", "policy", "--convert", str(folder)])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("simshear: error:")]
    assert code == 2 and len(lines) == 1 and "--trust-pickle" in lines[0]
    assert cli.main(["ship", "policy", "--convert", str(folder), "--trust-pickle"]) == 0
    assert {p.name for p in folder.iterdir()} == set(SHIPPED_FILES)
    card = (folder / "model.md").read_text()
    assert "`model.pt`" in card and "Converted to pickle-free files" in card and "- Date: 2026-01-02" in card
    controller = load(folder / "model.zip")  # the name a recorded command used still loads it, pickle-free
    rng = np.random.default_rng(1)
    for _ in range(10):
        observation = {"estimate": rng.normal(0, 3, 6).astype(np.float32)}
        expected, _ = model.predict(venv.normalize_obs(observation), deterministic=True)
        np.testing.assert_array_equal(controller(observation), np.asarray(expected, np.float32))
