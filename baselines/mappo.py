"""MAPPO on :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv`: a shared actor on each arm's own observation and
a centralised critic that also reads the team's global state (needs the ``rl`` extra).

The view with ``critic_state=True`` gives every arm the row ``[own padded observation, global state]``.
:class:`LocalActorPolicy` is SB3's ``ActorCriticPolicy`` whose actor network reads only the first
``actor_inputs`` entries and whose critic reads the whole row, so PPO on that view is MAPPO (Yu et al., 2022:
shared parameters, centralised value function, decentralised execution). Acting needs the arm's own
observation alone: :class:`ActorOnly` presents a trained model with that input, the state part left at zero,
which the actor never reads (a test checks it). ``pan1-env train --param-sharing --centralised-critic``
trains it; IPPO is the same run without the flag.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

__all__ = ["LocalActorPolicy", "ActorOnly", "with_critic_entries"]


def with_critic_entries(obs: np.ndarray, width: int) -> np.ndarray:
    """Arm rows ``(…, actor_inputs)`` with ``width`` zeros after them in place of the global state: the input
    of a MAPPO model when only its actor acts, which does not read them."""
    obs = np.asarray(obs, np.float32)
    return np.concatenate([obs, np.zeros((*obs.shape[:-1], width), np.float32)], axis=-1)


class _LocalActorCentralCritic(torch.nn.Module):
    """SB3's ``MlpExtractor`` contract (``forward_actor``, ``forward_critic``, latent sizes) with the actor's
    network on the first ``actor_inputs`` features and the critic's on all of them."""

    def __init__(self, feature_dim: int, actor_inputs: int, net_arch: Any, activation_fn: type[torch.nn.Module],
                 device: torch.device | str) -> None:
        super().__init__()
        local = MlpExtractor(actor_inputs, net_arch, activation_fn, device)
        central = MlpExtractor(feature_dim, net_arch, activation_fn, device)
        self.policy_net, self.value_net = local.policy_net, central.value_net
        self.latent_dim_pi, self.latent_dim_vf = local.latent_dim_pi, central.latent_dim_vf
        self.actor_inputs = actor_inputs

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features[..., : self.actor_inputs])

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(features)


class LocalActorPolicy(ActorCriticPolicy):
    """MAPPO's policy: the actor acts on the first ``actor_inputs`` observation entries (the arm's own), the
    critic values the whole row (with the global state). Other arguments as SB3's ``ActorCriticPolicy``;
    the features extractor must pass the observation through unchanged (the default ``FlattenExtractor``)."""

    def __init__(self, *args: Any, actor_inputs: int, **kwargs: Any) -> None:
        self.actor_inputs = int(actor_inputs)
        super().__init__(*args, **kwargs)
        if self.features_dim < self.actor_inputs:
            raise ValueError(f"actor_inputs={self.actor_inputs} exceeds the observation's {self.features_dim} entries")

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = _LocalActorCentralCritic(self.features_dim, self.actor_inputs, self.net_arch,
                                                      self.activation_fn, self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return super()._get_constructor_parameters() | {"actor_inputs": self.actor_inputs}


class ActorOnly:
    """A MAPPO model as the per-arm policy it is at execution: ``observation_space`` is the arm's own padded
    observation and ``predict`` fills the critic's state entries with zeros, which the actor does not read."""

    def __init__(self, model: Any) -> None:
        self.model, self.action_space = model, model.action_space
        self.actor_inputs = model.policy.actor_inputs
        space = model.observation_space
        self.observation_space = gymnasium.spaces.Box(space.low[: self.actor_inputs], space.high[: self.actor_inputs],
                                                      dtype=np.float32)
        self.critic_inputs = space.shape[0] - self.actor_inputs

    def predict(self, observation: np.ndarray, deterministic: bool = True, **kwargs: Any):
        return self.model.predict(with_critic_entries(observation, self.critic_inputs), deterministic=deterministic,
                                  **kwargs)
