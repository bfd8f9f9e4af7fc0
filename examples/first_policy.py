"""A first tracking policy with Stable-Baselines3 on ``gym.make`` (docs/first_policy.md): PPO on the servo
controller's estimate and the last action, started as a DAgger clone of the servo law, then trained by PPO.

Budget: 36,000 env steps of cloning (6 rounds of 6,000) and 25,000 PPO steps, all on the CPU with one torch thread;
the wall time and the errors it gave are in docs/first_policy.md. Run: ``python examples/first_policy.py``.
"""

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import simshear_gym.envs  # noqa: F401  (registers SimShearTracking-v0)
from simshear_gym.control.env_estimator import env_estimator
from simshear_gym.train.rl_imitation import clone_servo_law

SETTINGS = dict(observation="estimate+action", history=2, image_size_px=64, estimator=env_estimator)


def main(clone_steps=6000, rounds=6, ppo_steps=25_000, max_steps=None, seed=0):
    torch.set_num_threads(1)
    train = {**SETTINGS, "trajectory": "random", "randomise": True}  # a random path, scale, speed and start per reset
    venv = VecNormalize(make_vec_env("SimShearTracking-v0", n_envs=4, seed=seed, env_kwargs=train),
                        norm_obs_keys=["estimate", "last_action"], gamma=0.98)  # the estimate is already scaled
    model = PPO("MultiInputPolicy", venv, n_steps=512, batch_size=256, gamma=0.98, learning_rate=1e-4,
                policy_kwargs={"net_arch": [128, 128]}, seed=seed, device="cpu")
    clone_servo_law(model, venv, [gym.make("SimShearTracking-v0", **train) for _ in range(4)], clone_steps, rounds,
                    seed=seed, gamma=0.98, batch_size=256)
    model.learn(ppo_steps)
    venv.training = False  # the evaluation reads the statistics, never updates them
    errors = {}
    for name in ("circle", "tilted_square", "spiral", "loop"):
        env = gym.make("SimShearTracking-v0", trajectory=name, max_episode_steps=max_steps, **SETTINGS)
        observation, info = env.reset(seed=0)
        steps, done = [], False
        while not done:
            action, _ = model.predict(venv.normalize_obs(observation), deterministic=True)
            observation, _, ended, truncated, info = env.step(action)
            steps.append(info["contact_error_mm"])
            done = ended or truncated
        errors[name] = float(np.mean(steps))
        print(f"{name}: mean contact error {errors[name]:.3f} mm over {len(steps)} steps"
              + (f", ended early: {info['termination']}" if ended else ""))
    return model, venv, errors


if __name__ == "__main__":
    main()
