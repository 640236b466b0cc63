"""The PettingZoo ``ParallelEnv`` view of the env core (one copy): per-agent dicts, ``state()``, render.

:func:`parallel_env` builds one, :func:`env` gives PettingZoo's AEC view of it, and :data:`raw_env` is
the class. Episodes, rewards, cost and infos are the core's (:mod:`pan1_env.core`); this module only
turns its arrays into dicts keyed by agent.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec

from .config import FormationConfig, config_arguments
from .core import CoreView, FormationCore
from .observation import OBS_BOUND
from .registration import RENDER_FPS, RENDER_MODES
from .scenario import Scenario
from .validation import float_array, forwarded_signature, hints_unknown_keywords

__all__ = ["Pan1ParallelEnv", "parallel_env", "env", "raw_env"]


class Pan1ParallelEnv(CoreView, ParallelEnv):
    """Multi-arm PAn−1 formation with obstacles, as a PettingZoo parallel environment.

    ## Description

    N planar arms (agents ``arm_0`` … ``arm_{N−1}``; the paper numbers from 1) with n links each bring
    their end-effectors into a rigid formation without touching the obstacles. A PA arm's first joint
    is passive; started at rest it follows its active joints (the cascaded model). docs/MODEL.md.

    ## Action Space

    ``Box(-1, 1, (k,), float32)`` per agent, k = n − 1 for a PA arm and n for a fully actuated one (one more
    in circulation mode); clipped. ``action_mode``: ``"velocity"`` (default; tracked by the paper's backstepping
    law at every physics sub-step) or another of :class:`~pan1_env.tasks.FormationTask`'s.

    ## Observation Space

    ``Box(float32)`` per agent, local: own joints, end-effector, graph neighbours and the K nearest
    obstacles (the table: :class:`~pan1_env.observation.ObservationLayout`; :attr:`observation_layout`).
    ``state()`` is global: every arm's q, q̇ (zero-padded) and p, every obstacle's centre and radius (and for a
    moving formation the desired lengths and every arm's feed-forward).
    Arms with different n have different spaces: pad them for parameter sharing
    (``supersuit.pad_observations_v0``, ``supersuit.pad_action_space_v0``).

    ## Rewards, Cost, Infos, Episodes

    The formation task's (:class:`~pan1_env.tasks.FormationTask`) and the env core's (:mod:`pan1_env.core`,
    which lists the infos: ``cost``, ``min_clearance``, ``formation_error``, ``is_success``,
    ``reward_<term>``, the shield's flags): per agent here. Random scenarios draw a new team at every seeded
    ``reset``; truncation after ``max_steps`` or a numerical fault.

    ## Arguments

    :class:`~pan1_env.config.FormationConfig`'s, and ``render_mode`` (``None``, ``"rgb_array"``, ``"human"``).
    :class:`~pan1_env.wrappers.SafetyShield` switches the filter on through :meth:`set_safety_filter`.
    v0: initial release.
    """

    metadata = {"name": "pan1_env_v0", "render_modes": RENDER_MODES, "render_fps": RENDER_FPS,
                "is_parallelizable": True}

    @hints_unknown_keywords
    @config_arguments(FormationConfig)
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", *, render_mode: str | None = None,
                 **arguments: Any) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be None or one of {RENDER_MODES}, got {render_mode!r}")
        self.core = FormationCore(FormationConfig(scenario, **arguments), 1)
        self.render_mode = render_mode
        self.possible_agents = list(self.core.agents)
        self.agents: list[str] = []
        n_links, sizes = self.core.n_links, self.core.action_sizes
        self.observation_spaces = {a: gymnasium.spaces.Box(*self.core.layout.bounds(n), dtype=np.float32)
                                   for a, n in zip(self.possible_agents, n_links, strict=True)}
        self.action_spaces = {a: gymnasium.spaces.Box(-1.0, 1.0, (k,), np.float32)
                              for a, k in zip(self.possible_agents, sizes, strict=True)}
        self.state_space = gymnasium.spaces.Box(-OBS_BOUND, OBS_BOUND, (self.core.state_size,), np.float32)
        self._actions = np.zeros((1, len(n_links), self.core.action_width))
        self._uniform = len(set(sizes)) == 1
        self._renderer = None

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.action_spaces[agent]

    @property
    def np_random(self) -> np.random.Generator:
        return self.core.rngs[0]

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Every arm's joint angles and velocities ``(N, n_max)`` (float64 copies, NaN padding)."""
        q, qd = self.core.engine.joint_state()
        return q[0].copy(), qd[0].copy()

    def end_effectors(self) -> np.ndarray:
        """Every arm's end-effector ``(N, 2)`` (a float64 copy)."""
        return self.core.engine.positions()[0].copy()

    def reset(self, seed: int | None = None, options: dict | None = None):
        self.core.reset(options=options, seeds=None if seed is None else [seed])
        self.agents = list(self.possible_agents)
        mats, infos = self.core.start()
        obs, infos = self._observations(mats), self._infos(infos)
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def step(self, actions: Mapping[str, np.ndarray]):
        if not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        out = self.core.step(self._padded(actions))
        agents = self.agents
        rewards = dict(zip(agents, out.reward[0].tolist(), strict=True))
        terminations = dict.fromkeys(agents, bool(out.terminated[0]))
        truncations = dict.fromkeys(agents, bool(out.truncated[0]))
        obs, infos = self._observations(out.observations), self._infos(out.infos)
        if len(out.ended):
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    def commands(self, actions: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The engine's commands ``(1, N, k_max)`` (rad/s; N·m in torque mode) and efforts ``(N,)`` that
        ``actions`` give from the current state (the residual, gain and circulation modes compose them with the
        paper's law), without stepping."""
        command, effort = self.core.commands(self._padded(actions).copy())
        return command, effort[0]

    def _padded(self, actions: Mapping[str, np.ndarray]) -> np.ndarray:
        """The agents' actions as the core's padded ``(1, N, action_width)`` array, each checked."""
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict keyed by agent, got {type(actions).__name__}")
        if set(actions) != set(self.agents):
            missing, extra = sorted(set(self.agents) - set(actions)), sorted(set(actions) - set(self.agents))
            raise ValueError(f"actions must have one entry per live agent; missing {missing}, unexpected {extra}")
        if self._uniform:  # one conversion for the team when every arm has as many actions
            try:
                batch = np.asarray([actions[a] for a in self.possible_agents], dtype=float)
            except (TypeError, ValueError):
                batch = None  # a bad action: found and named below
            if batch is not None and batch.shape == self._actions.shape[1:]:
                self._actions[0] = batch
                return self._actions
        for i, agent in enumerate(self.possible_agents):
            self._actions[0, i, : self.core.action_sizes[i]] = float_array(f"action for {agent}", actions[agent],
                                                                         self.action_spaces[agent].shape)
        return self._actions

    def state(self) -> np.ndarray:
        return self.core.state()[0]

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        from .render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(human=(self.render_mode == "human"))
        return self._renderer.draw(self)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def _infos(self, infos: dict[str, np.ndarray]) -> dict[str, dict[str, Any]]:
        return dict(zip(self.possible_agents, self.core.agent_infos(infos), strict=True))

    def _observations(self, mats: list[np.ndarray]) -> dict[str, np.ndarray]:
        return dict(zip(self.possible_agents, self.core.copy_observations(mats), strict=True))


def parallel_env(scenario: str | Path | Scenario = "paper_pa3_square", **kwargs: Any) -> Pan1ParallelEnv:
    """The PettingZoo parallel environment (see :class:`Pan1ParallelEnv` for the arguments)."""
    return Pan1ParallelEnv(scenario, **kwargs)


def env(scenario: str | Path | Scenario = "paper_pa3_square", **kwargs: Any):
    """PettingZoo's AEC view of :func:`parallel_env` (``parallel_to_aec`` adds order enforcement)."""
    return parallel_to_aec(parallel_env(scenario, **kwargs))


# help() and notebooks show the constructor's named arguments (Pan1ParallelEnv refuses unknown ones with a hint)
parallel_env.__signature__ = forwarded_signature(parallel_env, Pan1ParallelEnv)  # type: ignore[attr-defined]
env.__signature__ = forwarded_signature(env, Pan1ParallelEnv)  # type: ignore[attr-defined]

raw_env = Pan1ParallelEnv
