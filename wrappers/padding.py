"""Every arm of a mixed team on the largest arm's spaces, for one shared network.

A team may mix arms of different link counts and actuated joints, so their spaces differ; libraries that
stack the agents of a group into one tensor (TorchRL's ``PettingZooWrapper``, a shared RLlib policy) need
one shape. :class:`PadToLargestArm` gives each arm the largest observation, zero-padded at its end, and the
largest action, of which the arm applies its own first entries (the rest is ignored). Its infos' per-arm
arrays (``shield_applied``) are padded to the action's size the same way.
"""

from __future__ import annotations

import gymnasium
import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper

__all__ = ["PadToLargestArm"]


class PadToLargestArm(BaseParallelWrapper):
    """Pad a parallel env's arms to the largest arm's spaces (see the module docstring). An env whose arms
    already share their spaces passes through unchanged."""

    def __init__(self, env) -> None:
        super().__init__(env)
        obs = {a: env.observation_space(a) for a in env.possible_agents}
        act = {a: env.action_space(a) for a in env.possible_agents}
        self._obs_size = {a: space.shape[0] for a, space in obs.items()}
        self._act_size = {a: space.shape[0] for a, space in act.items()}
        n_obs, n_act = max(self._obs_size.values()), max(self._act_size.values())
        # the union of the arms' bounds, an arm's padding (0) included where it has one
        low = np.min([np.pad(space.low, (0, n_obs - space.shape[0])) for space in obs.values()], axis=0)
        high = np.max([np.pad(space.high, (0, n_obs - space.shape[0])) for space in obs.values()], axis=0)
        self._obs_space = gymnasium.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self._act_space = gymnasium.spaces.Box(-1.0, 1.0, shape=(n_act,), dtype=np.float32)

    @property
    def observation_spaces(self) -> dict:
        return dict.fromkeys(self.possible_agents, self._obs_space)

    @property
    def action_spaces(self) -> dict:
        return dict.fromkeys(self.possible_agents, self._act_space)

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self._act_space

    def reset(self, seed=None, options=None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return self._observations(observations), self._infos(infos)

    def step(self, actions):
        own = {a: np.asarray(u)[: self._act_size[a]] for a, u in actions.items()}
        observations, rewards, terminated, truncated, infos = self.env.step(own)
        return self._observations(observations), rewards, terminated, truncated, self._infos(infos)

    def _observations(self, observations: dict) -> dict:
        n = self._obs_space.shape[0]
        return {a: np.pad(np.asarray(o, dtype=np.float32), (0, n - len(o))) for a, o in observations.items()}

    def _infos(self, infos: dict) -> dict:
        n = self._act_space.shape[0]
        for info in infos.values():
            if "shield_applied" in info:
                applied = info["shield_applied"]
                info["shield_applied"] = np.pad(applied, (0, n - len(applied)))
        return infos
