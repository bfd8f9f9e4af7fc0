"""Gymnasium envs. ``import simshear_gym.envs`` registers them (string entry points: nothing heavy is imported
until ``gymnasium.make``):

- ``SimShearTracking-v0`` (:class:`simshear_gym.envs.tracking.SimShearTrackingEnv`), 500 steps per episode;
  ``gymnasium.make_vec`` builds :class:`simshear_gym.envs.vector.SimShearVectorEnv` (sub-envs stepped in worker
  processes, their images translated in batches) unless ``vectorization_mode`` is ``"sync"`` or ``"async"``.
- ``SimShearCoLift-v0`` (:class:`simshear_gym.envs.colift.SimShearCoLiftEnv`), 500 steps per episode; the same
  batched vector env.
- ``SimShearEdgeFollow-v0`` (:class:`simshear_gym.envs.edge_follow.SimShearEdgeFollowEnv`), 1000 steps per
  episode: once round the edge of a flat object; the same batched vector env.
- ``SimShearTracking6D-v0`` (:class:`simshear_gym.envs.tracking6d.SimShearTracking6DEnv`), 500 steps per episode: a
  tilting plate, a 6-DoF (Panda) follower; gymnasium's own vector envs (not in :data:`ENV_IDS`, the envs with the
  batched one).
- ``SimShearPush-v0`` (:class:`simshear_gym.envs.push.SimShearPushEnv`), 800 steps per episode: push an object to a
  target along a straight path (a horizontal TacTip); the same batched vector env.
"""

from gymnasium.envs.registration import register, registry

ENV_IDS: tuple[str, ...] = ("SimShearTracking-v0", "SimShearCoLift-v0", "SimShearEdgeFollow-v0", "SimShearPush-v0")

if "SimShearTracking-v0" not in registry:
    register(
        id="SimShearTracking-v0",
        entry_point="simshear_gym.envs.tracking:SimShearTrackingEnv",
        vector_entry_point="simshear_gym.envs.vector:make_tracking_vector_env",
        max_episode_steps=500,
    )

if "SimShearCoLift-v0" not in registry:
    register(
        id="SimShearCoLift-v0",
        entry_point="simshear_gym.envs.colift:SimShearCoLiftEnv",
        vector_entry_point="simshear_gym.envs.colift:make_colift_vector_env",
        max_episode_steps=500,
    )

if "SimShearTracking6D-v0" not in registry:
    register(
        id="SimShearTracking6D-v0",
        entry_point="simshear_gym.envs.tracking6d:SimShearTracking6DEnv",
        max_episode_steps=500,
    )

if "SimShearEdgeFollow-v0" not in registry:
    register(
        id="SimShearEdgeFollow-v0",
        entry_point="simshear_gym.envs.edge_follow:SimShearEdgeFollowEnv",
        vector_entry_point="simshear_gym.envs.edge_follow:make_edge_follow_vector_env",
        max_episode_steps=1000,
    )

if "SimShearPush-v0" not in registry:
    register(
        id="SimShearPush-v0",
        entry_point="simshear_gym.envs.push:SimShearPushEnv",
        vector_entry_point="simshear_gym.envs.push:make_push_vector_env",
        max_episode_steps=800,
    )
