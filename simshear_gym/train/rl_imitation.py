"""The servo law as the policy's starting point (``simshear train rl --bc-steps N``): behaviour cloning before RL.

A policy trained from scratch on co-lift learns to hold the object but not to follow it (docs/experiments.md,
rl_colift_ppo); the servo controller does both. Here PPO's actor starts as a clone of the servo controller:

1. **Teacher**: the servo controller's PI law (gains, load hold and margin as
   :class:`~simshear_gym.control.servo.ServoController` takes them from the env:
   :func:`~simshear_gym.control.servo.servo_law_for_env`) on the
   filter mean that the estimate observation itself carries (:func:`~simshear_gym.contract.filter_mean_from_estimate`):
   the teacher needs nothing the robot lacks. With the ``estimate+action`` observation the teacher is the same law
   in velocity form (:meth:`~simshear_gym.control.pi_law.PILaw.velocity_form`: the last action taken plus the
   change the newest two frames ask for), so that the label is a function of the observation alone: the PI law's
   integral, which a policy on the estimates cannot see, is carried by the action it took.
2. **Rollouts**: ``bc_steps`` env steps in the training envs' settings (envs made in this process, one per
   sub-env, seeds apart from training's). The env executes the teacher's action plus Gaussian noise of std
   ``bc_noise`` (full-scale actions), the label is the clean teacher action, so the clone sees the states a
   slightly wrong policy reaches and how the teacher leaves them.
3. **Normalisation**: the run's ``VecNormalize`` statistics (observations, and PPO's discounted-return scale) are
   updated with the rollouts, so that PPO starts from the same normalised inputs the clone was fitted on.
4. **Fit**: the actor's mean by mean squared error against the teacher's actions, the critic by mean squared error
   against the rollouts' normalised discounted returns (an untrained critic's advantages would pull the clone away
   in PPO's first updates), ``bc_epochs`` passes, Adam; then the policy's log std is set to ``log(bc_noise)``.

The fit's losses before and after, per part, go into the run's ``summary.json`` (``imitation``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from simshear_gym.contract import ESTIMATE_SIZE, filter_mean_from_estimate, servo_hints
from simshear_gym.control.pi_law import PILaw
from simshear_gym.control.servo import servo_law_for_env

SEED_OFFSET = 100_000  # the rollouts' env seeds, apart from training's (seed + rank) and evaluation's


class ServoTeacher:
    """The servo controller's law on an estimate observation (module docstring, 1); one per env stream."""

    def __init__(self, env) -> None:
        base = env.unwrapped
        self.reference_depth_mm = float(base.reference_depth_mm)
        gains, self.hold_load, self.load_margin_mm = servo_law_for_env(env)  # as ServoController.for_env
        self.law = PILaw(self.reference_depth_mm, base.action_scale.as_array(), gains)
        self._first = True

    def reset(self) -> None:
        self.law.reset()
        self._first = True

    def __call__(self, observation: dict) -> np.ndarray:
        mean = filter_mean_from_estimate(observation["estimate"], self.reference_depth_mm)
        first, self._first = self._first, False
        if first and self.hold_load:
            self.law.shear_reference_mm = np.asarray(mean[1:3], dtype=np.float64) + self.load_margin_mm
        if "last_action" in observation:  # the law in velocity form: a function of what the policy sees
            frames = np.asarray(observation["estimate"], dtype=np.float64).reshape(-1, ESTIMATE_SIZE)
            if len(frames) < 2:
                raise ValueError("the teacher's velocity form needs the previous frame: history >= 2")
            # an episode's first step (the history filled with one frame, no action yet): from rest on the target,
            # which makes it the PI law's first step
            previous = (np.array([self.reference_depth_mm, *self.law.shear_reference_mm, 0.0]) if first
                        else filter_mean_from_estimate(frames[:-1].reshape(-1), self.reference_depth_mm))
            return self.law.velocity_form(mean, previous, observation["last_action"])
        return self.law(mean)


class EdgeTeacher:
    """The edge servo's law, proportional only (a function of the observation alone: no integral to carry), on the
    filter mean an edge env's estimate observation carries (:func:`~simshear_gym.control.edge_servo.
    edge_state_from_slots`); one per env stream."""

    def __init__(self, env) -> None:
        from simshear_gym.control.edge_servo import EdgeGains, EdgeLaw

        base = env.unwrapped
        self.reference_depth_mm = float(base.reference_depth_mm)
        self.law = EdgeLaw(self.reference_depth_mm, base.action_scale.as_array(), base.speed_mm_s * base.dt_s,
                           EdgeGains(ki_offset=0.0, ki_depth=0.0))

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        from simshear_gym.control.edge_servo import edge_state_from_slots

        return self.law(edge_state_from_slots(filter_mean_from_estimate(observation["estimate"],
                                                                         self.reference_depth_mm)))


class PushTeacher:
    """The push servo's law without its path-side integral (a function of the observation alone), on the filter
    mean a pushing env's estimate observation carries (:func:`~simshear_gym.control.push_servo.
    push_state_from_slots`) and the observation's ``goal``; one per env stream."""

    def __init__(self, env) -> None:
        from simshear_gym.control.push_servo import PushGains, PushLaw

        base = env.unwrapped
        self.reference_depth_mm = float(base.reference_depth_mm)
        self.law = PushLaw(base.action_scale.as_array(), base.speed_mm_s * base.dt_s, PushGains(ki_side=0.0))

    def reset(self) -> None:
        self.law.reset()

    def __call__(self, observation: dict) -> np.ndarray:
        from simshear_gym.control.push_servo import push_state_from_slots

        if "goal" not in observation:
            raise ValueError(f"the push teacher needs the observation's 'goal' (SimShearPush-v0's), got "
                             f"{sorted(observation)}")
        mean = filter_mean_from_estimate(observation["estimate"], self.reference_depth_mm)
        return self.law(push_state_from_slots(mean), observation["goal"])


TEACHERS = {"servo": ServoTeacher, "edge": EdgeTeacher, "push": PushTeacher}


def teacher_for(env) -> ServoTeacher | EdgeTeacher | PushTeacher:
    """The env's teacher, by its :class:`~simshear_gym.contract.ServoHints` law: the servo law, the edge law or the
    push law."""
    return TEACHERS[servo_hints(env).law](env)


def collect(envs: list, steps: int, noise: float, seed: int, actor=None) -> dict:
    """``steps`` steps over ``envs`` in turn (module docstring, 2), the teacher's action executed (plus noise) or,
    given an ``actor`` (observation -> action), the actor's, the teacher labelling every step either way (DAgger):
    {"observations": {key: (N, ...)}, "actions": (N, 4) teacher labels, "rewards": (N,), "stream": (N,) env index,
    "starts": (N,) bool: first step of an episode}, in step order per env."""
    rng = np.random.default_rng(seed)
    teachers = [teacher_for(env) for env in envs]
    episodes = [0] * len(envs)
    current = []
    for index, (env, teacher) in enumerate(zip(envs, teachers)):
        observation, _ = env.reset(seed=seed + SEED_OFFSET + 1000 * index)
        teacher.reset()
        current.append(observation)
    rows: dict[str, list] = {"observations": [], "actions": [], "rewards": [], "stream": [], "starts": []}
    start = [True] * len(envs)
    while len(rows["actions"]) < steps:
        for index, (env, teacher) in enumerate(zip(envs, teachers)):
            if len(rows["actions"]) >= steps:
                break
            label = teacher(current[index])
            chosen = label if actor is None else np.asarray(actor(current[index]), dtype=np.float64).reshape(4)
            executed = np.clip(chosen + rng.normal(0.0, noise, 4), -1.0, 1.0).astype(np.float32)
            observation, reward, terminated, truncated, _ = env.step(executed)
            rows["observations"].append(current[index])
            rows["actions"].append(label)
            rows["rewards"].append(float(reward))
            rows["stream"].append(index)
            rows["starts"].append(start[index])
            start[index] = False
            if terminated or truncated:
                episodes[index] += 1
                observation, _ = env.reset(seed=seed + SEED_OFFSET + 1000 * index + episodes[index])
                teacher.reset()
                start[index] = True
            current[index] = observation
    keys = rows["observations"][0].keys()
    return {"observations": {key: np.stack([obs[key] for obs in rows["observations"]]) for key in keys},
            "actions": np.stack(rows["actions"]).astype(np.float32),
            "rewards": np.asarray(rows["rewards"], dtype=np.float64),
            "stream": np.asarray(rows["stream"]), "starts": np.asarray(rows["starts"], dtype=bool)}


def discounted_returns(rewards: np.ndarray, stream: np.ndarray, starts: np.ndarray, gamma: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(the return from each step to its episode's end or the rollout's, the running discounted sum up to each step
    as ``VecNormalize`` accumulates it to scale rewards), per step."""
    future = np.zeros(len(rewards))
    running = np.zeros(len(rewards))
    for index in np.unique(stream):
        rows = np.flatnonzero(stream == index)
        total = 0.0
        for row in rows:  # forwards: the running sum, reset at each episode start
            total = (0.0 if starts[row] else total * gamma) + rewards[row]
            running[row] = total
        total = 0.0
        for position in range(len(rows) - 1, -1, -1):  # backwards: the return to go
            row = rows[position]
            ends_here = position + 1 < len(rows) and starts[rows[position + 1]]
            total = rewards[row] + (0.0 if ends_here else gamma * total)
            future[row] = total
    return future, running


def merge(parts: list[dict]) -> dict:
    """Rollouts of several :func:`collect` calls as one (their env streams kept apart)."""
    offset, streams = 0, []
    for part in parts:
        streams.append(part["stream"] + offset)
        offset += int(part["stream"].max()) + 1
    return {"observations": {key: np.concatenate([part["observations"][key] for part in parts])
                             for key in parts[0]["observations"]},
            "actions": np.concatenate([part["actions"] for part in parts]),
            "rewards": np.concatenate([part["rewards"] for part in parts]),
            "stream": np.concatenate(streams), "starts": np.concatenate([part["starts"] for part in parts])}


def update_normalisation(vec_normalize, rollouts: dict, gamma: float) -> None:
    """The run's ``VecNormalize`` statistics updated with new rollouts (observations; the discounted-return scale
    of PPO's rewards)."""
    if vec_normalize is None:
        return
    for key, statistics in vec_normalize.obs_rms.items():
        statistics.update(rollouts["observations"][key])
    if vec_normalize.norm_reward:
        _, running = discounted_returns(rollouts["rewards"], rollouts["stream"], rollouts["starts"], gamma)
        vec_normalize.ret_rms.update(running)


def policy_actor(model, vec_normalize):
    """observation -> the policy's deterministic action, through the run's normalisation."""
    def act(observation: dict) -> np.ndarray:
        batch = {key: np.asarray(value)[None] for key, value in observation.items()}
        if vec_normalize is not None:
            batch = vec_normalize.normalize_obs(batch)
        action, _ = model.policy.predict(batch, deterministic=True)
        return np.asarray(action).reshape(4)

    return act


def imitate(model, vec_normalize, rollouts: dict, epochs: int, noise: float, batch_size: int = 256,
            learning_rate: float = 1e-3, seed: int = 0, gamma: float = 0.99) -> dict:
    """Fit ``model.policy`` (an SB3 actor-critic) to the rollouts (module docstring, 4), through the run's
    normalisation as it stands (:func:`update_normalisation` first); returns the losses."""
    import torch

    observations = rollouts["observations"]
    future, _ = discounted_returns(rollouts["rewards"], rollouts["stream"], rollouts["starts"], gamma)
    reward_scale = 1.0
    if vec_normalize is not None:
        if vec_normalize.norm_reward:
            reward_scale = float(np.sqrt(vec_normalize.ret_rms.var + vec_normalize.epsilon))
        observations = vec_normalize.normalize_obs(observations)
    policy = model.policy
    tensors, _ = policy.obs_to_tensor(observations)
    actions = torch.as_tensor(rollouts["actions"], device=policy.device)
    values = torch.as_tensor(future / reward_scale, dtype=torch.float32, device=policy.device)
    optimiser = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)

    def losses(rows) -> tuple:
        batch = {key: value[rows] for key, value in tensors.items()}
        mean = policy.get_distribution(batch).distribution.mean
        return (torch.mean((mean - actions[rows]) ** 2),
                torch.mean((policy.predict_values(batch).flatten() - values[rows]) ** 2))

    def evaluate() -> dict:
        with torch.no_grad():
            actor, critic = losses(torch.arange(len(actions)))
        return {"actor_mse": float(actor), "critic_mse": float(critic)}

    before = evaluate()
    policy.set_training_mode(True)
    for _ in range(epochs):
        order = torch.randperm(len(actions), generator=generator)
        for first in range(0, len(order), batch_size):
            actor, critic = losses(order[first:first + batch_size])
            optimiser.zero_grad()
            (actor + critic).backward()
            optimiser.step()
    policy.set_training_mode(False)
    with torch.no_grad():
        policy.log_std.fill_(math.log(noise))
    after = evaluate()
    return {"steps": len(actions), "epochs": epochs, "noise": noise, "before": before, "after": after}


def clone_servo_law(model, vec_normalize, envs: list, steps: int, rounds: int = 1, epochs: int = 30,
                    noise: float = 0.1, seed: int = 0, gamma: float = 0.99, batch_size: int = 64) -> dict:
    """Clone the servo law into ``model`` (an SB3 PPO on an estimate observation; ``vec_normalize``: its
    ``VecNormalize`` or None): ``steps`` steps of the law acting in ``envs`` (``gym.make``'d with the training
    envs' settings, one per stream), then ``rounds`` - 1 rounds of DAgger (the clone acts, the law labels, all
    rounds' steps refitted); steps 1-4 of the module docstring. Returns the fits' records (``seconds``: wall time).
    ``simshear train rl --bc-steps`` calls it; ``examples/first_policy.py`` too."""
    if steps < 1 or rounds < 1:
        raise ValueError(f"clone_servo_law needs steps and rounds >= 1, got {steps}, {rounds}")
    started = time.perf_counter()
    records, parts = [], []
    for round_index in range(rounds):
        actor = None if round_index == 0 else policy_actor(model, vec_normalize)
        part = collect(envs, steps, noise, seed + round_index, actor=actor)
        update_normalisation(vec_normalize, part, gamma)
        parts.append(part)
        record = imitate(model, vec_normalize, merge(parts), epochs, noise, batch_size=batch_size, seed=seed,
                         gamma=gamma)
        records.append({**record, "round": round_index, "actor": "servo law" if actor is None else "policy",
                        "new_steps": len(part["actions"]),
                        "episodes_ended": max(0, int(part["starts"].sum()) - len(envs))})
    return {"steps": sum(len(part["actions"]) for part in parts), "epochs": epochs, "noise": noise,
            "before": records[0]["before"], "after": records[-1]["after"], "rounds": records,
            "seconds": round(time.perf_counter() - started, 1)}
