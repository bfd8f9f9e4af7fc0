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

# id, env entry point, vector entry point (None: gymnasium's own vector envs), max_episode_steps
_REGISTRATIONS: tuple[tuple[str, str, str | None, int], ...] = (
    ("SimShearTracking-v0", "tracking:SimShearTrackingEnv", "vector:make_tracking_vector_env", 500),
    ("SimShearCoLift-v0", "colift:SimShearCoLiftEnv", "colift:make_colift_vector_env", 500),
    ("SimShearTracking6D-v0", "tracking6d:SimShearTracking6DEnv", None, 500),
    ("SimShearEdgeFollow-v0", "edge_follow:SimShearEdgeFollowEnv", "edge_follow:make_edge_follow_vector_env", 1000),
    ("SimShearPush-v0", "push:SimShearPushEnv", "push:make_push_vector_env", 800),
)

for _id, _entry, _vector_entry, _max_steps in _REGISTRATIONS:
    if _id not in registry:
        register(id=_id, entry_point=f"simshear_gym.envs.{_entry}", max_episode_steps=_max_steps,
                 vector_entry_point=None if _vector_entry is None else f"simshear_gym.envs.{_vector_entry}")
