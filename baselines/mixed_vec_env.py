"""Stable-Baselines3's ``VecEnv`` over teams of several sizes (the ``rl`` extra): :class:`SB3MixedArmVecEnv`, one
:class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv` per team size, side by side, so that one network shared by
the arms learns on all of them at once. It needs a task whose arm observation has the same size for every team
(a ring, ``pan1_env/RandomFormation-v2``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from pan1_env.random_scenario import obstacles_at_size
from pan1_env.validation import positive_int

from .arm_vec_env import SB3ArmVecEnv

__all__ = ["SB3MixedArmVecEnv", "sized_options"]


def sized_options(scenario: Any, options: dict[str, Any], n_arms: int) -> dict[str, int]:
    """The random options that make a team of ``n_arms`` arms of ``scenario``'s task (an id or ``"random"``, with
    ``options`` on top): ``n_arms``, and the obstacles at the task's density, its ``n_obstacles`` per ``n_arms``
    (three per four arms on ``pan1_env/RandomFormation-v2``: 12 for 16 arms, as ``LargeFormation-v0``), rounded
    half up."""
    from pan1_env.random_scenario import RandomScenarioOptions
    from pan1_env.registration import env_arguments

    _, kwargs = env_arguments(scenario, {"random_options": options} if options else None)
    base = RandomScenarioOptions(**kwargs.get("random_options", {}))
    return {"n_arms": n_arms, "n_obstacles": obstacles_at_size(base.n_obstacles, base.n_arms, n_arms)}


class SB3MixedArmVecEnv(VecEnv):
    """``num_envs`` copies of ``scenario`` for each team size of ``team_sizes`` (``random_options`` ``n_arms``, with
    the obstacles at the task's density: :func:`sized_options`), every arm an SB3 env: sub-envs
    ``0 … num_envs·N₀ − 1`` are the arms of the first size's copies (as
    :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv` lays them out), then the next size's, and so on.
    ``seed(s)`` gives every copy of every size its own stream spawned from s (the sizes' copies are numbered one
    after another, :func:`pan1_env.core.copy_generator`). Other arguments as ``SB3ArmVecEnv``.

    Raises:
        ValueError: fewer than one size, a size below 2 or repeated, a global-state critic (its size grows with
            the team), or sizes whose arms see observations of different sizes (the polygon's fan: use a ring).
    """

    def __init__(self, scenario: Any, team_sizes: Sequence[int], num_envs: int = 1, **kwargs: Any) -> None:
        sizes = [positive_int("team_sizes", n, minimum=2) for n in team_sizes]
        if not sizes or len(set(sizes)) != len(sizes):
            raise ValueError(f"team_sizes must be one or more distinct team sizes ≥ 2, got {list(team_sizes)!r}")
        if kwargs.get("critic_state"):
            raise ValueError("critic_state (MAPPO's global state) grows with the team: train mixed team sizes "
                             "without --centralised-critic")
        options = dict(kwargs.pop("random_options", None) or {})
        if "n_arms" in options:
            raise ValueError(f"random_options n_arms={options['n_arms']!r} and team_sizes={sizes} both set the team "
                             "size: give the sizes in team_sizes only")
        if "n_obstacles" in options:
            raise ValueError(f"random_options n_obstacles={options['n_obstacles']!r} with team_sizes: each size gets "
                             "the task's obstacles per arm (sized_options)")
        self.parts = [SB3ArmVecEnv(scenario, num_envs, random_options=options | sized_options(scenario, options, n),
                                   **kwargs) for n in sizes]
        spaces = {(p.observation_space.shape, p.action_space.shape) for p in self.parts}
        if len(spaces) > 1:
            seen = ", ".join(f"{n} arms: {p.observation_space.shape}" for n, p in zip(sizes, self.parts, strict=True))
            raise ValueError(f"one network cannot read these team sizes' arm observations ({seen}): their size "
                             "grows with the team on this task's graph; use a ring (random_options shape='ring', "
                             "as pan1_env/RandomFormation-v2 does)")
        for k, part in enumerate(self.parts):
            part.venv.core.first_copy = k * num_envs
        self.team_sizes, self.local_size = sizes, self.parts[0].local_size
        self._bounds = np.cumsum([0, *(p.num_envs for p in self.parts)])
        first = self.parts[0]
        super().__init__(int(self._bounds[-1]), first.observation_space, first.action_space)

    @property
    def venv(self) -> list:
        """Each size's :class:`~pan1_env.vector.Pan1VectorEnv` (what a checkpoint keeps and restores)."""
        return [p.venv for p in self.parts]

    @venv.setter
    def venv(self, venvs: list) -> None:
        for part, venv in zip(self.parts, venvs, strict=True):
            part.venv = venv

    @property
    def dt(self) -> float:
        """Seconds per step, the same for every team size."""
        return self.parts[0].dt

    @property
    def team_envs(self) -> list[range]:
        """The sub-envs of each copy (its arms), over every size."""
        return [range(first + t.start, first + t.stop) for first, p in zip(self._bounds, self.parts, strict=False)
                for t in p.team_envs]

    def seed(self, seed: int | None = None) -> list[int | None]:
        """Seed the next reset: every copy of every size its own stream spawned from ``seed`` (the sizes' copies
        numbered one after another); returns that seed once per sub-env."""
        seeds = self.parts[0].seed(seed)
        for part in self.parts[1:]:
            part.seed(seeds[0])
        return [seeds[0]] * self.num_envs

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """The next reset's options (the task's reset options), for every size's copies (one dict), or per
        sub-env (a list, as SB3 gives it; a copy takes its first arm's)."""
        for part, lo, hi in zip(self.parts, self._bounds[:-1], self._bounds[1:], strict=True):
            part.set_options(options[lo:hi] if isinstance(options, list) else options)

    def reset(self) -> np.ndarray:
        self._reset_seeds()  # the parts hold the seeds and options this view was given
        self._reset_options()
        obs = [p.reset() for p in self.parts]
        self.reset_infos = [info for p in self.parts for info in p.reset_infos]
        return np.concatenate(obs)

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        for part, lo, hi in zip(self.parts, self._bounds[:-1], self._bounds[1:], strict=True):
            part.step_async(actions[lo:hi])

    def step_wait(self) -> VecEnvStepReturn:
        out = [p.step_wait() for p in self.parts]
        obs, rewards, dones, infos = zip(*out, strict=True)
        return np.concatenate(obs), np.concatenate(rewards), np.concatenate(dones), [i for part in infos for i in part]

    def close(self) -> None:
        for part in self.parts:
            part.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self._part_of(i).venv, attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise AttributeError("SB3MixedArmVecEnv's arms share batched engines; attributes cannot be set per arm")

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        raise AttributeError("SB3MixedArmVecEnv's arms share batched engines; use .parts to call their methods")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _part_of(self, index: int) -> SB3ArmVecEnv:
        return self.parts[int(np.searchsorted(self._bounds, index, side="right")) - 1]
