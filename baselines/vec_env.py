"""Stable-Baselines3 ``VecEnv`` views of :class:`~pan1_env.vector.Pan1VectorEnv` (the ``rl`` extra): B copies
advance in one compiled call, ``PPO("MlpPolicy", SB3VecEnv("paper_pa3_square", num_envs=64)).learn(100_000)``
(shielded by default); :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv` makes each arm an env of
its own. SB3's conventions hold:
``reset()`` returns observations only (infos in ``reset_infos``), ``seed(s)`` seeds the next reset (every copy
an independent stream spawned from s, as ``Pan1VectorEnv.reset(seed=s)``: not SB3's ``s + b``, which would give
runs with seeds s and s + 1 the same teams in all copies but one), an ended copy is reset in the same step
with its last observation in ``infos[b]["terminal_observation"]`` and ``TimeLimit.truncated`` set on
truncation, and each info carries ``cost``, ``min_clearance``, ``formation_error``, ``is_success`` (and the
shield flags).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from pan1_env.validation import forwards_keywords
from pan1_env.vector import Pan1VectorEnv

__all__ = ["SB3VecEnv"]


class SB3VecEnv(VecEnv):
    """SB3's ``VecEnv`` interface over a :class:`~pan1_env.vector.Pan1VectorEnv` of ``num_envs`` copies built
    from ``scenario`` and ``kwargs`` (``safety_filter``, ``max_steps``, …: ``help()`` lists them), or over an
    existing ``Pan1VectorEnv`` given as ``scenario`` (then leave out ``num_envs`` and ``kwargs``)."""

    @forwards_keywords("pan1_env.vector:Pan1VectorEnv", exclude=("render_mode", "qp_solver"))
    def __init__(self, scenario: Any = "paper_pa3_square", num_envs: int = 1, **kwargs: Any) -> None:
        if isinstance(scenario, Pan1VectorEnv):
            if kwargs or num_envs not in (1, scenario.num_envs):
                raise ValueError("pass either a Pan1VectorEnv or the arguments to build one, not both")
            self.venv = scenario
        else:
            self.venv = Pan1VectorEnv(scenario, num_envs, **kwargs)
        super().__init__(*self._spaces())
        self._actions: np.ndarray | None = None
        self._batch_seed: int | None = None

    @property
    def config(self):
        """The env's settings (:class:`~pan1_env.config.FormationConfig`), as every view gives them."""
        return self.venv.config

    @property
    def dt(self) -> float:
        """Seconds per step (``config.control_dt``)."""
        return self.venv.dt

    def seed(self, seed: int | None = None) -> list[int | None]:
        """Seed the next reset: every copy gets an independent stream spawned from ``seed``
        (:func:`pan1_env.core.copy_generator`); returns that seed once per sub-env."""
        if seed is None:
            seed = int(np.random.randint(0, 2**31 - 1))  # noqa: NPY002 - SB3's own convention for no seed
        self._batch_seed = seed
        return [seed] * self.num_envs

    def _spaces(self) -> tuple[int, gymnasium.Space, gymnasium.Space]:
        return self.venv.num_envs, self.venv.single_observation_space, self.venv.single_action_space

    @property
    def team_envs(self) -> list[range]:
        """The sub-envs of each copy's team (here each copy is one sub-env)."""
        return [range(b, b + 1) for b in range(self.num_envs)]

    def reset(self) -> np.ndarray:
        seed, self._batch_seed = self._batch_seed, None
        obs, infos = self.venv.reset(seed=seed)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = self._split_infos(infos)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        per_env = self._split_infos(infos)
        if dones.any():
            final = infos["final_obs"]
            for b in np.flatnonzero(dones):
                per_env[b]["terminal_observation"] = final[b]
                per_env[b]["TimeLimit.truncated"] = bool(truncated[b] and not terminated[b])
        return obs, rewards.astype(np.float32), dones, per_env

    def close(self) -> None:
        self.venv.close()

    # copies share one engine: attributes and methods are those of the vector env
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError("SB3VecEnv copies share one batched engine; attributes cannot be set per copy")

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        raise AttributeError("SB3VecEnv copies share one batched engine; use .venv to call its methods")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _split_infos(self, infos: dict[str, Any]) -> list[dict[str, Any]]:
        keys = [k for k in infos if not k.startswith("_") and k not in ("final_obs", "final_info")]
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for key in keys:
            values, mask = infos[key], infos.get("_" + key)
            for b in range(self.num_envs):
                if mask is None or mask[b]:
                    v = values[b]
                    out[b][key] = v.item() if isinstance(v, np.generic) else v
        return out
