"""A policy that drives every end-effector straight at its nearest obstacle (for testing shields).

From agent i's observation it reads the nearest obstacle's offset o − p_i and its joint angles,
and commands the actuated velocities (or torques) along J̄_iᵀ (o − p_i), scaled so the largest
entry is ±1: the steepest way for the arm to move its end-effector towards the obstacle. Without
an obstacle in its observation it sends zeros. :class:`VectorAdversary` is the same rule on the
batched observations of a :class:`~pan1_env.vector.Pan1VectorEnv`, one call for every copy.
"""

from __future__ import annotations

import numpy as np

from pan1_env.cascade import reduced_jacobian
from pan1_env.dynamics import ArmBatch
from pan1_env.observation import OBSTACLE_FEATURES

from .reference import decode_observation

__all__ = ["AdversarialPolicy", "VectorAdversary"]


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
        return _toward(reduced_jacobian(arm, d["q"]), obstacles[0, 1:3], np.bool_(True)).astype(np.float32)

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {agent: self.act(agent, obs) for agent, obs in observations.items()}


def _toward(Jbar: np.ndarray, toward: np.ndarray, present: np.ndarray) -> np.ndarray:
    """J̄ᵀ (o − p) scaled so its largest entry is ±1; zeros where no obstacle is observed."""
    a = np.einsum("...jk,...j->...k", Jbar, toward)
    peak = np.max(np.abs(a), axis=-1, keepdims=True)
    return np.where(present[..., None] & (peak > 0), a / np.where(peak > 0, peak, 1.0), 0.0)


class VectorAdversary:
    """:class:`AdversarialPolicy` for a :class:`~pan1_env.vector.Pan1VectorEnv`: every arm of every copy
    heads for its nearest obstacle at full action, computed for all copies at once.

    It reads each copy's current team (random teams change at every reset), so it is bound to the vector
    env it acts on: pass it to :func:`pan1_env.baselines.evaluation.evaluate`, which calls :meth:`attach`
    with the env it builds, or call ``attach(venv)`` yourself. Then ``policy(obs)`` takes the
    ``(num_envs, Σ obs_i)`` observations and returns ``(num_envs, Σ k_i)`` actions.
    """

    def __init__(self) -> None:
        self.venv = None
        self._teams: list = []
        self._arms: list[ArmBatch] = []

    def attach(self, venv) -> VectorAdversary:
        self.venv = venv
        self._teams = []
        return self

    def _arm_batches(self) -> list[ArmBatch]:
        teams = self.venv.unwrapped.teams
        if len(teams) != len(self._teams) or any(a is not b for a, b in zip(teams, self._teams, strict=True)):
            self._arms = [ArmBatch.stack([team.arms[i] for team in teams]) for i in range(len(teams[0].arms))]
            self._teams = teams  # held, so a new team can never be taken for the one it replaced
        return self._arms

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self.venv is None:
            raise RuntimeError("VectorAdversary: attach(venv) first (evaluate() does it for the env it builds)")
        layout = self.venv.unwrapped.observation_layout
        obs = np.asarray(obs, dtype=float)
        expected = (self.venv.num_envs, *self.venv.single_observation_space.shape)
        if obs.shape != expected:
            raise ValueError(f"VectorAdversary: observations of shape {obs.shape}; the attached env gives {expected}")
        actions, start = [], 0
        for arms in self._arm_batches():
            n = arms.n_links
            seg = {name: slice(start + part.start, start + part.stop) for name, part in layout.segments(n).items()}
            start += layout.size(n)
            if layout.n_obstacle_obs == 0:  # no obstacle in sight: zeros, as AdversarialPolicy
                actions.append(np.zeros((len(obs), arms.n_actuated)))
                continue
            q = np.arctan2(obs[:, seg["sin_q"]], obs[:, seg["cos_q"]])
            nearest = obs[:, seg["obstacles"]].reshape(len(obs), -1, OBSTACLE_FEATURES)[:, 0]
            actions.append(_toward(reduced_jacobian(arms, q), nearest[:, 1:3], nearest[:, 0] >= 0.5))
        return np.concatenate(actions, axis=1).astype(np.float32)
