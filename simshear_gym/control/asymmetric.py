"""An asymmetric actor-critic policy for SB3's PPO: the critic sees the true contact state, the actor only what the
robot sees.

In training the env gives the privileged keys too (``true_pose_shear`` of the oracle modes, normalised by
VecNormalize); :class:`AsymmetricActorCriticPolicy` gives actor and critic separate feature extractors and the
actor's zeroes the privileged keys, so the action never depends on them. At deployment the env has no such keys:
:class:`~simshear_gym.control.policy.SB3Controller` fills them with zeros (what the actor reads anyway).

Imports torch and Stable-Baselines3: import it only to train or load such a policy (SB3's load does, by the class's
name).
"""

from __future__ import annotations

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import CombinedExtractor

PRIVILEGED_KEYS: tuple[str, ...] = ("true_pose_shear",)
"""The keys only the critic sees: the env's true (depth, shear x, y, Rz) in its oracle modes."""


class MaskedCombinedExtractor(CombinedExtractor):
    """SB3's ``CombinedExtractor`` (every key flattened or through a CNN, concatenated) with ``masked_keys`` zeroed:
    the same feature size with or without them, their content never reaching the output."""

    def __init__(self, observation_space: spaces.Dict, masked_keys: tuple[str, ...] = (), **kwargs) -> None:
        super().__init__(observation_space, **kwargs)
        unknown = sorted(set(masked_keys) - set(observation_space.spaces))
        if unknown:
            raise ValueError(f"masked_keys {unknown} are not keys of the observation "
                             f"{sorted(observation_space.spaces)}")
        self.masked_keys = tuple(masked_keys)

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        seen = {key: torch.zeros_like(value) if key in self.masked_keys else value
                for key, value in observations.items()}
        return super().forward(seen)


class AsymmetricActorCriticPolicy(MultiInputActorCriticPolicy):
    """``MultiInputPolicy`` whose actor is blind to ``privileged_keys`` and whose critic sees everything (separate
    feature extractors). ``policy_kwargs={"privileged_keys": ...}`` (default :data:`PRIVILEGED_KEYS`)."""

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.Space, lr_schedule,
                 privileged_keys: tuple[str, ...] = PRIVILEGED_KEYS, **kwargs) -> None:
        self.privileged_keys = tuple(privileged_keys)
        self._extractors_made = 0
        kwargs["share_features_extractor"] = False
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def make_features_extractor(self) -> MaskedCombinedExtractor:
        # ActorCriticPolicy makes the actor's extractor first, then the critic's
        masked = self.privileged_keys if self._extractors_made == 0 else ()
        self._extractors_made += 1
        return MaskedCombinedExtractor(self.observation_space, masked, **self.features_extractor_kwargs)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "privileged_keys": self.privileged_keys}


__all__ = ["PRIVILEGED_KEYS", "AsymmetricActorCriticPolicy", "MaskedCombinedExtractor"]
