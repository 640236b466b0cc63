"""A policy that drives every end-effector straight at its nearest obstacle (for testing shields).

From agent i's observation it reads the nearest obstacle's offset o − p_i and its joint angles,
and commands the actuated velocities (or torques) along J̄_iᵀ (o − p_i), scaled so the largest
entry is ±1: the steepest way for the arm to move its end-effector towards the obstacle. Without
an obstacle in its observation it sends zeros.
"""

from __future__ import annotations

import numpy as np

from pan1_env.cascade import reduced_jacobian

from .reference import decode_observation

__all__ = ["AdversarialPolicy"]


class AdversarialPolicy:
    """Every arm heads for its nearest obstacle at full action (velocity or torque mode).

    ``env`` is the parallel env, wrapped or not; only its public ``possible_agents``, ``scenario``
    and ``observation_layout`` are read.
    """

    def __init__(self, env) -> None:
        self.env = env

    def act(self, agent: str, obs: np.ndarray) -> np.ndarray:
        env = self.env
        i = env.possible_agents.index(agent)
        arm = env.scenario.arms[i]
        d = decode_observation(obs, env.observation_layout, arm.n_links)
        obstacles = d["obstacles"]
        if obstacles.size == 0 or obstacles[0, 0] < 0.5:
            return np.zeros(arm.n_actuated, np.float32)
        toward = obstacles[0, 1:3]
        a = reduced_jacobian(arm, d["q"]).T @ toward
        peak = np.max(np.abs(a))
        return (a / peak if peak > 0 else a).astype(np.float32)

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {agent: self.act(agent, obs) for agent, obs in observations.items()}
