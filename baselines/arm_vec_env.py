"""Stable-Baselines3's ``VecEnv`` with one env per arm (the ``rl`` extra): :class:`SB3ArmVecEnv`, the B copies ×
N arms of the batched engine as B·N SB3 envs, for one network shared by the arms (IPPO, MAPPO). SB3's
conventions and the seeding are :class:`~pan1_env.baselines.vec_env.SB3VecEnv`'s.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from pan1_env.core import per_arm
from pan1_env.observation import OBS_BOUND
from pan1_env.validation import float_array, forwards_keywords

from .vec_env import SB3VecEnv

__all__ = ["SB3ArmVecEnv"]


class SB3ArmVecEnv(SB3VecEnv):
    """The B copies × N arms of a :class:`~pan1_env.vector.Pan1VectorEnv` as B·N SB3 envs, for one network
    shared by the arms, each acting on its own observation (IPPO when trained with PPO). Sub-env ``b·N + i``
    is arm i of copy b: its observation is the arm's, zero-padded to the largest arm's (``local_size``), its
    action the largest arm's size (the arm applies its own first entries, ``core.action_sizes``), its reward
    and info (``cost``, ``min_clearance``, shield flags) its own beside its copy's ``formation_error`` and
    ``is_success``. A
    copy's arms start and end together; ``seed(s)`` seeds the copies as :class:`SB3VecEnv` does.
    ``critic_state=True`` appends the copy's global state (:meth:`~pan1_env.core.FormationCore.state`) to
    each row, for MAPPO's critic (:class:`~pan1_env.baselines.mappo.LocalActorPolicy`'s actor reads only
    the first ``local_size`` entries). Other arguments as :class:`SB3VecEnv`; ``num_envs`` counts copies.
    """

    @forwards_keywords("pan1_env.vector:Pan1VectorEnv", exclude=("render_mode", "qp_solver"))
    def __init__(self, scenario: Any = "paper_pa3_square", num_envs: int = 1, *, critic_state: bool = False,
                 **kwargs: Any) -> None:
        self.critic_state = bool(critic_state)
        super().__init__(scenario, num_envs, **kwargs)

    def _spaces(self) -> tuple[int, gymnasium.Space, gymnasium.Space]:
        core = self.venv.core
        low, high = core.padded_observation_bounds()
        self._arms, self.local_size = len(core.agents), low.shape[1]
        low, high = low.min(axis=0), high.max(axis=0)
        if self.critic_state:
            bound = np.full(core.state_size, OBS_BOUND, np.float32)
            low, high = np.concatenate([low, -bound]), np.concatenate([high, bound])
        observation = gymnasium.spaces.Box(low, high, dtype=np.float32)
        action = gymnasium.spaces.Box(-1.0, 1.0, (core.action_width,), np.float32)
        return self.venv.num_envs * self._arms, observation, action

    @property
    def team_envs(self) -> list[range]:
        """The sub-envs of each copy's team: its arms."""
        N = self._arms
        return [range(b * N, (b + 1) * N) for b in range(self.num_envs // N)]

    def reset(self) -> np.ndarray:
        core, seed = self.venv.core, self._batch_seed
        self._batch_seed = None
        core.reset(seeds=seed, options=self._options[0] or None)
        self._reset_seeds()
        self._reset_options()
        mats, infos = core.start()
        self.reset_infos = self._arm_infos(infos)
        return self._arm_rows(mats)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        core, N = self.venv.core, self._arms
        width = core.action_width
        actions = float_array("actions", self._actions, (self.num_envs, width)).reshape(-1, N, width)
        self._actions = None
        out = core.step(actions.astype(np.float64), autoreset=True, final_state=self.critic_state)
        infos = self._arm_infos(out.infos)
        if len(out.ended):
            final = self._arm_rows(out.final_observations, out.final_state).reshape(core.copies, N, -1)
            for b in out.ended.tolist():
                truncated = bool(out.truncated[b] and not out.terminated[b])
                for i in range(N):
                    infos[b * N + i]["terminal_observation"] = final[b, i]
                    infos[b * N + i]["TimeLimit.truncated"] = truncated
        dones = np.repeat(out.terminated | out.truncated, N)
        return self._arm_rows(out.observations), out.reward.reshape(-1).astype(np.float32), dones, infos

    def arm_observations(self, flat: np.ndarray) -> np.ndarray:
        """The team views' flat observations ``(B', Σ obs_i)`` (any number of rows) as each arm's own padded
        observation, ``(B'·N, local_size)``: to run a model trained here on :class:`~pan1_env.vector.Pan1VectorEnv`."""
        return self.venv.core.padded_from_flat(flat).reshape(-1, self.local_size)

    def team_actions(self, arm_actions: np.ndarray) -> np.ndarray:
        """This view's actions ``(B'·N, action_width)`` as the team views' flat actions ``(B', Σ sizes)``."""
        return self.venv.core.flat_actions(arm_actions)

    def _arm_rows(self, mats: list[np.ndarray], state: np.ndarray | None = None) -> np.ndarray:
        """One row per sub-env; with ``critic_state`` its copy's global state (``state``, or the core's now)."""
        core = self.venv.core
        obs = core.padded_observations(mats)
        if self.critic_state:
            state = core.state() if state is None else state
            state = np.broadcast_to(state[:, None], (*obs.shape[:2], state.shape[1]))
            obs = np.concatenate([obs, state], axis=-1)
        return obs.reshape(-1, obs.shape[-1])

    def _arm_infos(self, infos: dict[str, np.ndarray]) -> list[dict[str, Any]]:
        """One dict per arm of the scalar infos: the arm's own, and its copy's repeated for each arm."""
        N, columns = self._arms, {}
        for key, value in infos.items():
            if per_arm(key) and value.ndim == 2:
                columns[key] = np.broadcast_to(value, (len(value), N)).reshape(-1).tolist()
            elif not per_arm(key) and value.ndim == 1:
                columns[key] = np.repeat(value, N).tolist()
        keys = list(columns)
        return [dict(zip(keys, row, strict=True)) for row in zip(*columns.values(), strict=True)]
