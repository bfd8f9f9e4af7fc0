"""RL training: a tiny PPO run end to end, resume, the servo benchmark's policy variant, bad settings."""

from argparse import ArgumentParser

import pytest
import torch

from simshear_gym.train.rl import RLTrainConfig, latest_checkpoint, train

torch.set_num_threads(1)


def tiny(**overrides):
    settings = dict(algo="ppo", timesteps=32, obs_mode="sim", image_size_px=64, n_steps=16, batch_size=16,
                    checkpoint_steps=16)
    settings.update(overrides)
    return RLTrainConfig(**settings)


def test_tiny_ppo_trains_resumes_and_runs_in_the_benchmark(tmp_path):
    run_dir = tmp_path / "ppo"
    summary = train(tiny(), run_dir, progress=False)
    assert summary["timesteps"] >= 32 and (run_dir / "model.zip").is_file()
    assert latest_checkpoint(run_dir).name.startswith("rl_model_")
    assert any((run_dir / "tb").rglob("events.out.tfevents.*"))
    with pytest.raises(ValueError, match="--resume"):
        train(tiny(), run_dir, progress=False)
    resumed = train(tiny(timesteps=64), run_dir, resume=True, progress=False)
    assert resumed["timesteps"] >= 64 and resumed["resumed_from"]
    with pytest.raises(ValueError, match="different settings"):
        train(tiny(timesteps=96, learning_rate=1e-3), run_dir, resume=True, progress=False)

    from simshear_gym.evaluate import servo

    out = tmp_path / "results"
    parser = ArgumentParser()
    servo.add_arguments(parser)
    args = parser.parse_args(["--tasks", "tracking", "--trajectories", "circle", "--variants", "policy", "--seeds", "1",
                              "--policy", str(run_dir / "model.zip"), "--max-steps", "5", "--out", str(out)])
    assert servo.run(args) == 0
    import json

    result = json.loads((out / "servo.json").read_text())["results"]["policy"]["tracking/circle"]
    assert result["seeds"] == 2 and all(run["steps"] <= 5 for run in result["runs"])


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="a policy never sees ground truth"):
        tiny(obs_mode="oracle")
    with pytest.raises(ValueError, match="algo"):
        tiny(algo="dqn")


def test_tiny_sac_trains_and_saves(tmp_path):
    summary = train(tiny(algo="sac", timesteps=24, batch_size=8), tmp_path / "sac", progress=False)
    assert summary["algo"] == "sac" and summary["timesteps"] >= 24 and (tmp_path / "sac" / "model.zip").is_file()
    from simshear_gym.real.rollout import sb3_algorithm

    assert sb3_algorithm(tmp_path / "sac" / "model.zip") == "sac"
