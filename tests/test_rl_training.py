"""``simshear train rl`` beyond the basics (tests/test_rl.py): estimate observations with a history, residual RL,
VecNormalize saved and loaded with the policy, evaluation during training as tensorboard scalars, resume, worker
processes, the wall-clock budget, co-lift, and the servo benchmark's ppo / sac variants. Tiny budgets only."""

from __future__ import annotations

import json
from argparse import ArgumentParser
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from simshear_gym.contract import filter_mean_from_estimate
from simshear_gym.control.env_estimator import env_kwargs
from simshear_gym.control.policy import PolicySettings, SB3Controller, vecnormalize_path
from simshear_gym.train.rl import RLTrainConfig, latest_checkpoint, train
from simshear_gym.train.rl_trainer import WallClockBudget
from tests.clocks import TickClock

torch.set_num_threads(1)


def tiny(**overrides) -> RLTrainConfig:
    settings = dict(algo="ppo", timesteps=32, observation="estimate", history=2, obs_mode="sim", image_size_px=64,
                    n_steps=16, batch_size=16, n_epochs=2, checkpoint_steps=16, eval_steps=16, eval_max_steps=4)
    settings.update(overrides)
    return RLTrainConfig(**settings)


def scalars(run_dir: Path) -> set[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags: set[str] = set()
    for events in (run_dir / "tb").rglob("events.out.tfevents.*"):
        accumulator = EventAccumulator(str(events))
        accumulator.Reload()
        tags |= set(accumulator.Tags()["scalars"])
    return tags


def test_residual_estimate_policy_trains_evaluates_resumes_and_loads_with_its_normalisation(tmp_path):
    run_dir = tmp_path / "ppo"
    summary = train(tiny(residual_bound=0.2), run_dir, progress=False)
    assert summary["timesteps"] >= 32 and summary["stopped_by"] == "timesteps"
    for name in ("model.zip", "model.pt", "model.json", "vecnormalize.json", "best_model.zip", "best_model.pt",
                 "best_model.json", "best_model_vecnormalize.json", "config.json", "evaluations.json",
                 "learning_curve.png", "checkpoints/rl_model_16_steps.pt",
                 "checkpoints/rl_model_vecnormalize_16_steps.json"):
        assert (run_dir / name).is_file(), name
    assert not list(run_dir.rglob("*.pkl"))  # no pickle written
    evaluations = json.loads((run_dir / "evaluations.json").read_text())["evaluations"]
    assert [e["timesteps"] for e in evaluations] == [16, 32]
    assert set(evaluations[-1]["episodes"]) == {"circle", "tilted_square", "spiral", "loop"}
    assert all(0 < e["steps"] <= 4 for e in evaluations[-1]["episodes"].values())
    assert {"eval/contact_error_mm_mean", "eval/contact_error_mm/circle", "eval/ended_early"} <= scalars(run_dir)

    settings = PolicySettings.of_model(run_dir / "model.zip")
    assert (settings.observation, settings.history, settings.obs_mode, settings.image_size_px) == (
        "estimate", 2, "sim", 64)
    assert settings.residual.bound == 0.2 and settings.residual.kp == (0.6, 0.6, 0.5, 0.0)
    checkpoint = latest_checkpoint(run_dir)
    assert vecnormalize_path(checkpoint).name == "rl_model_vecnormalize_32_steps.json"
    assert PolicySettings.of_model(checkpoint) == settings

    env = gym.make("SimShearTracking-v0", trajectory="circle", **env_kwargs(settings))
    try:
        controller = SB3Controller.for_env(run_dir / "model.zip", env)
        assert controller.normalizer is not None and controller.residual is not None
        obs, _ = env.reset(seed=0)
        controller.reset()
        # the residual policy's action is the servo law's within the bound
        law = controller.residual.law
        law.reset()
        state = filter_mean_from_estimate(obs["estimate"], 4.0)
        servo_action = law(state)
        law.reset()
        action = controller(obs)
        assert np.all(np.abs(action - servo_action) <= 0.2 + 1e-6)
        for _ in range(3):
            obs, *_ = env.step(controller(obs))
    finally:
        env.close()

    resumed = train(tiny(residual_bound=0.2, timesteps=48), run_dir, resume=True, progress=False)
    assert resumed["timesteps"] >= 48 and resumed["resumed_from"].endswith("rl_model_32_steps.zip")
    with pytest.raises(ValueError, match="different settings"):
        train(tiny(residual_bound=0.2, timesteps=64, history=3), run_dir, resume=True, progress=False)


def test_subproc_workers_with_the_wall_clock_budget(tmp_path, monkeypatch):
    monkeypatch.setattr(WallClockBudget, "clock", TickClock(1 / 16))  # 3 s: the 48th step's reading
    summary = train(tiny(n_envs=2, vec="subproc", timesteps=10_000, minutes=0.05, eval_steps=0, n_steps=8,
                         batch_size=16), tmp_path / "sub", progress=False)
    assert summary["stopped_by"] == "minutes" and summary["timesteps"] == 48 * 2
    assert (tmp_path / "sub" / "model.pt").is_file() and (tmp_path / "sub" / "vecnormalize.json").is_file()


def test_colift_sac_trains_on_the_objects(tmp_path):
    from simshear_gym.train.rl_trainer import env_settings, evaluation_settings

    config = tiny(algo="sac", task="colift", timesteps=12, batch_size=4, eval_steps=0, history=1)
    assert [env_settings(config, rank)["object_name"] for rank in range(5)] == [
        "prism", "egg", "brain", "ducky", "prism"]
    assert set(evaluation_settings(config)) == {"prism", "egg", "brain", "ducky"}
    summary = train(config, tmp_path / "sac", progress=False)
    assert summary["task"] == "colift" and summary["timesteps"] >= 12
    assert PolicySettings.of_model(tmp_path / "sac" / "model.zip").task == "colift"


def test_servo_benchmark_runs_ppo_and_checks_the_algorithm(tmp_path):
    run_dir = tmp_path / "ppo"
    train(tiny(eval_steps=0, timesteps=16), run_dir, progress=False)
    from simshear_gym.evaluate import servo

    def args(*words: str):
        parser = ArgumentParser()
        servo.add_arguments(parser)
        return parser.parse_args(["--tasks", "tracking", "--trajectories", "circle", "--seeds", "1", "--max-steps",
                                  "3", "--out", str(tmp_path / "results"), *words])

    assert servo.run(args("--variants", "ppo", "--policy-ppo", str(run_dir / "model.zip"))) == 0
    result = json.loads((tmp_path / "results" / "servo.json").read_text())
    assert "--policy-ppo" in result["command"]
    assert result["results"]["ppo"]["tracking/circle"]["seeds"] == 2
    with pytest.raises(ValueError, match="is a PPO model, not SAC"):
        servo.run(args("--variants", "sac", "--policy-sac", str(run_dir / "model.zip")))
    with pytest.raises(ValueError, match="needs --policy-ppo"):
        servo.run(args("--variants", "ppo"))


def test_bad_training_settings_name_the_flag():
    with pytest.raises(ValueError, match="--residual-bound needs --observation one of .*'estimate'"):
        tiny(observation="tactile", residual_bound=0.3)
    with pytest.raises(ValueError, match="vec must be one of"):
        tiny(vec="threads")
    with pytest.raises(ValueError, match="minutes must be > 0"):
        tiny(minutes=0.0)
    with pytest.raises(ValueError, match="task must be one of"):
        tiny(task="stacking")


def test_tqc_from_sb3_contrib_trains_and_loads(tmp_path):
    pytest.importorskip("sb3_contrib")
    from simshear_gym.control.policy import sb3_algorithm

    run_dir = tmp_path / "tqc"
    summary = train(tiny(algo="tqc", timesteps=12, batch_size=4, eval_steps=0, history=1), run_dir, progress=False)
    assert summary["algo"] == "tqc" and sb3_algorithm(run_dir / "model.zip") == "tqc"
    settings = PolicySettings.of_model(run_dir / "model.zip")
    env = gym.make("SimShearTracking-v0", **env_kwargs(settings))
    try:
        controller = SB3Controller.for_env(run_dir / "model.zip", env)
        assert controller.name.startswith("tqc:")
        obs, _ = env.reset(seed=0)
        action = controller(obs)
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
    finally:
        env.close()


def test_asymmetric_critic_sees_the_true_state_and_the_actor_does_not(tmp_path):
    run_dir = tmp_path / "asym"
    summary = train(tiny(asymmetric_critic=True, timesteps=32, eval_steps=32), run_dir, progress=False)
    assert summary["last_evaluation"]["ended_early"] >= 0  # evaluated as deployed: no true state in its env
    settings = PolicySettings.of_model(run_dir / "model.zip")
    env = gym.make("SimShearTracking-v0", trajectory="circle", **env_kwargs(settings))
    try:
        assert "true_pose_shear" not in env.observation_space.spaces
        controller = SB3Controller.for_env(run_dir / "model.zip", env)
        policy = controller.model.policy
        assert policy.privileged_keys == ("true_pose_shear",) and set(controller.privileged) == {"true_pose_shear"}
        obs, _ = env.reset(seed=0)
        action = controller(obs)
        assert action.shape == (4,)
        # the actor ignores the true state; the critic reads it
        batch = {key: torch.as_tensor(value[None]) for key, value in obs.items()}
        values, actions = [], []
        for truth in (np.zeros(4), np.array([3.0, 2.0, -2.0, 1.0])):
            batch["true_pose_shear"] = torch.as_tensor(truth[None], dtype=torch.float32)
            with torch.no_grad():
                actions.append(policy.get_distribution(batch).distribution.mean.numpy())
                values.append(policy.predict_values(batch).numpy())
        np.testing.assert_array_equal(actions[0], actions[1])
        assert not np.allclose(values[0], values[1])
    finally:
        env.close()
    with pytest.raises(ValueError, match="asymmetric-critic is PPO's"):
        tiny(algo="sac", asymmetric_critic=True)


def test_discounted_returns_restart_at_each_episode_and_run_per_env():
    from simshear_gym.train.rl_imitation import discounted_returns

    rewards = np.array([1.0, 1.0, 1.0, 2.0, 2.0])
    stream = np.array([0, 1, 0, 1, 0])  # env 0: steps 0, 2, 4 (a new episode at 4); env 1: steps 1, 3
    starts = np.array([True, True, False, False, True])
    future, running = discounted_returns(rewards, stream, starts, gamma=0.5)
    np.testing.assert_allclose(future, [1.5, 2.0, 1.0, 2.0, 2.0])
    np.testing.assert_allclose(running, [1.0, 1.0, 1.5, 2.5, 2.0])


def test_the_teacher_is_the_servo_law_on_the_observations_estimate():
    from simshear_gym.control.policy import ResidualServo, ResidualSettings
    from simshear_gym.control.servo import SERVO_GAINS
    from simshear_gym.train.rl_imitation import ServoTeacher
    from simshear_gym.train.rl_trainer import make_env

    env = make_env(tiny())
    teacher = ServoTeacher(env)
    base = env.unwrapped
    law = ResidualServo(ResidualSettings(bound=0.5, kp=SERVO_GAINS.kp, ki=SERVO_GAINS.ki), base.reference_depth_mm,
                        base.action_scale)
    observation, _ = env.reset(seed=3)
    for _ in range(4):
        action = teacher(observation)
        np.testing.assert_allclose(action, law(observation, np.zeros(4)), atol=1e-6)
        observation, *_ = env.step(action)
    env.close()


def test_with_the_last_action_the_teacher_is_the_servo_law_in_velocity_form():
    """On ``estimate+action`` the label is a function of the observation alone; executed, it gives the servo law's
    own actions (its integral carried by the last action) while nothing clips."""
    from simshear_gym.contract import filter_mean_from_estimate
    from simshear_gym.control.pi_law import PILaw
    from simshear_gym.control.servo import SERVO_GAINS
    from simshear_gym.train.rl_imitation import ServoTeacher
    from simshear_gym.train.rl_trainer import make_env

    env = make_env(tiny(observation="estimate+action", history=2))
    teacher = ServoTeacher(env)
    base = env.unwrapped
    law = PILaw(base.reference_depth_mm, base.action_scale.as_array(), SERVO_GAINS)
    observation, _ = env.reset(seed=3)
    unclipped = np.ones(4, dtype=bool)  # a clip ends the agreement of that variable: its carried integral differs
    compared = 0
    for step in range(6):
        action = teacher(observation)
        expected = law(filter_mean_from_estimate(observation["estimate"], base.reference_depth_mm))
        unclipped &= np.abs(expected) < 1.0
        np.testing.assert_allclose(action[unclipped], expected[unclipped], atol=1e-5)
        compared += int(unclipped.sum())
        if step:  # past the first step the label is a function of the observation: a fresh teacher agrees
            again = ServoTeacher(env)
            again._first = False
            np.testing.assert_allclose(again(observation), action, atol=1e-6)
        observation, *_ = env.step(action)
    env.close()
    assert compared >= 12  # most of the variables agreed over most of the steps


def test_the_servo_law_is_cloned_into_the_policy_before_rl(tmp_path):
    summary = train(tiny(bc_steps=48, bc_rounds=2, bc_epochs=60, bc_noise=0.2, eval_steps=0), tmp_path / "bc",
                    progress=False)
    imitation = summary["imitation"]
    first, dagger = imitation["rounds"]
    assert imitation["steps"] == 96 and imitation["noise"] == 0.2
    assert (first["actor"], dagger["actor"]) == ("servo law", "policy") and dagger["steps"] == 96
    assert first["after"]["actor_mse"] < 0.25 * first["before"]["actor_mse"]
    assert first["after"]["critic_mse"] < first["before"]["critic_mse"]
    assert dagger["after"]["actor_mse"] < dagger["before"]["actor_mse"]
    assert json.loads((tmp_path / "bc" / "imitation.json").read_text()) == imitation
    assert summary["timesteps"] >= 32 and (tmp_path / "bc" / "model.zip").is_file()
    with pytest.raises(ValueError, match="--bc-steps clones the servo law .* needs --algo ppo"):
        tiny(bc_steps=10, algo="sac")
    with pytest.raises(ValueError, match="--bc-steps .* --observation one of .*'estimate'"):
        tiny(bc_steps=10, observation="tactile", history=1)
    with pytest.raises(ValueError, match="velocity form .* needs --history >= 2, got 1"):
        tiny(bc_steps=10, observation="estimate+action", history=1)
    with pytest.raises(ValueError, match="bc_noise in"):
        tiny(bc_noise=0.0)
    with pytest.raises(ValueError, match="bc_rounds and bc_epochs >= 1"):
        tiny(bc_rounds=0)
