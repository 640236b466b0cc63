"""The Gymnasium view of the env core (one copy): one agent controlling every arm (``gymnasium.make``).

Its observation is the concatenation of every agent's observation (agent order ``arm_0``, ``arm_1``, …),
its action the concatenation of every agent's action, its reward the mean of the agents' rewards, and its
infos the team's (:meth:`pan1_env.core.FormationCore.team_infos`): ``cost`` the number of arms that entered an
obstacle in the step, ``min_clearance``, ``formation_error``, ``is_success``, ``reward_<term>`` (averaged over
the arms, as the reward), and with the filter on its report (``shield_intervened``, ``shield_fallback``,
``shield_status``, ``shield_min_barrier``, ``shield_applied`` laid out as the action, ``qp_counts``).
:class:`~pan1_env.vector.Pan1VectorEnv` is the same view for B copies.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from .core import CoreView, FormationCore, team_mean, view_repr
from .registration import RENDER_FPS, RENDER_MODES
from .validation import float_array, forwards_keywords

__all__ = ["CentralizedEnv", "OneCopyGymEnv"]


class OneCopyGymEnv(gymnasium.Env):
    """A Gymnasium env over a one-copy env core (``self.core``): the agents' observations and actions
    concatenated in agent order, the mean of the agents' rewards, the team's infos. Subclasses build the
    core and call :meth:`_flat_spaces`."""

    core: FormationCore

    def __repr__(self) -> str:
        return view_repr(self)

    def __str__(self) -> str:  # Gymnasium's wrappers print the env's str: the filter's switch shows through them
        return f"<{view_repr(self)}>"

    @property
    def num_steps(self) -> int:
        """Steps since the last reset."""
        return int(self.core.steps[0])

    def _flat_spaces(self) -> None:
        self.observation_space = gymnasium.spaces.Box(*self.core.flat_observation_bounds(), dtype=np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (sum(self.core.action_sizes),), np.float32)
        self._needs_reset = True

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.core.reset(options=options, seeds=None if seed is None else [seed])
        super().reset(seed=seed)
        self._needs_reset = False
        mats, infos = self.core.start()
        return self.core.flat_observations(mats)[0], self.core.team_info(infos)

    def step(self, action: np.ndarray):
        if self._needs_reset:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        action = float_array("action", action, self.action_space.shape)
        out = self.core.step(self.core.padded_actions(action[None]))
        self._needs_reset = bool(len(out.ended))
        reward = team_mean(out.reward[0].tolist())  # the arms' mean, as numpy's mean() sums
        return (self.core.flat_observations(out.observations)[0], reward,
                bool(out.terminated[0]), bool(out.truncated[0]), self.core.team_info(out.infos))


class CentralizedEnv(CoreView, OneCopyGymEnv):
    """One agent controlling every arm of a formation scenario (``gymnasium.make("pan1_env/…")``).

    Takes the arguments of :class:`~pan1_env.environment.Pan1ParallelEnv` (``inspect.signature`` and
    ``help()`` list them; :class:`~pan1_env.config.FormationConfig` documents them).
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": RENDER_FPS}

    @forwards_keywords("pan1_env.environment:Pan1ParallelEnv")
    def __init__(self, scenario: Any = "paper_pa3_square", **kwargs: Any) -> None:
        from .environment import Pan1ParallelEnv

        # the parallel view renders and validates render_mode; both views share its core
        self.parallel = Pan1ParallelEnv(scenario, **kwargs)
        self.core: FormationCore = self.parallel.core
        self.render_mode = self.parallel.render_mode
        self.possible_agents = self.core.agents
        self._flat_spaces()
        self._splits = np.cumsum(self.core.action_sizes)[:-1]

    def agent_actions(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """The flat action split into the agents' actions (agent order)."""
        parts = np.split(np.asarray(action, dtype=float), self._splits)
        return dict(zip(self.possible_agents, parts, strict=True))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        out = super().reset(seed=seed, options=options)
        if self.render_mode == "human":
            self.render()
        return out

    def step(self, action: np.ndarray):
        out = super().step(action)
        if self.render_mode == "human":
            self.render()
        return out

    def render(self):
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()

