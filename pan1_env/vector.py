"""The Gymnasium vector view of the env core: B copies of a scenario stepped together.

:class:`Pan1VectorEnv` reshapes a :class:`~pan1_env.core.FormationCore` of B copies (one kernel call per
arm kind for all copies) into Gymnasium's ``VectorEnv``: the flat observation, action, reward and infos
of :class:`~pan1_env.centralized.CentralizedEnv` (the ``gymnasium.make`` view), batched, with the safety
filter on by default and same-step autoreset.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .config import FormationConfig
from .core import CoreView, FormationCore
from .engine import PARALLEL_THRESHOLD
from .safety import FilterParams
from .scenario import Scenario
from .validation import float_array, forwards_keywords

__all__ = ["Pan1VectorEnv", "PARALLEL_THRESHOLD"]


class Pan1VectorEnv(CoreView, VectorEnv):
    """``num_envs`` independent copies of a pan1-env scenario as one Gymnasium ``VectorEnv``.

    ## Description

    Each copy is the centralised single-agent view of :class:`~pan1_env.environment.Pan1ParallelEnv`
    (what ``gymnasium.make("pan1_env/PaperPA3Square-v0")`` gives); all copies step together in
    batched compiled code, so the cost per arm falls as ``num_envs`` grows.

    ## Action Space

    ``Box(-1, 1, (num_envs, Σ k_i), float32)`` (Σ (k_i + 1) in circulation mode): row b is copy b's concatenated
    per-arm actions (agent order), meant as in the parallel env (``action_mode``). Values are
    clipped to [−1, 1]; a wrong shape, NaN/inf or a non-numeric batch (a dict, a string) raises
    ``ValueError``.

    ## Observation Space

    ``Box(..., (num_envs, Σ obs_i), float32)``: row b is the concatenation of copy b's local agent
    observations (layout in :class:`~pan1_env.environment.Pan1ParallelEnv`).

    ## Rewards

    Per copy, the mean of its agents' rewards (the parallel env's reward terms and weights).

    ## Starting State

    As the parallel env: the scenario's configuration at rest, or for ``scenario="random"`` a new
    team drawn per copy at every reset of that copy from the copy's own generator
    (``reset(seed=s)`` gives every copy an independent stream spawned from s,
    :func:`pan1_env.core.copy_generator`; a list of seeds gives copy b the team a one-copy env draws with
    ``reset(seed=seeds[b])``).

    ## Episode End

    Per copy, as the parallel env (truncation after ``max_steps``, on a numerical fault, or the
    optional terminations). A copy that ends is reset in the same call
    (``metadata["autoreset_mode"] = AutoresetMode.SAME_STEP``): the returned observation is the
    new episode's first, and ``infos["final_obs"]`` / ``infos["final_info"]`` (with the masks
    ``infos["_final_obs"]``, ``infos["_final_info"]``) hold the ended episode's last ones.

    ## Infos

    Arrays over copies, each with Gymnasium's ``_key`` mask: the team infos of
    :class:`~pan1_env.centralized.CentralizedEnv` (:meth:`pan1_env.core.FormationCore.team_infos`): ``cost`` (number of
    arms that entered an obstacle in the step), ``min_clearance`` (m), ``formation_error`` (m),
    ``is_success``, ``reward_<term>`` (averaged over the agents like the reward), with the safety filter
    its report (``shield_intervened``, ``shield_fallback``, ``shield_status``, ``shield_min_barrier``,
    ``shield_applied`` laid out as the action, ``qp_counts``); ``fault`` (strings, masked) for a copy
    truncated by a non-finite state.

    ## Arguments

    * ``scenario``: as the parallel env (a built-in name, a TOML path, a Scenario, ``"random"`` or an id).
    * ``num_envs``: B, the number of copies.
    * ``safety_filter``: the paper's RCBF-QP safety filter at every physics sub-step: ``True``
      (default; the same filter as :class:`~pan1_env.wrappers.SafetyShield`, the scenario's κ, ε and
      margin), ``False``, or a :class:`~pan1_env.safety.FilterParams`.
    * ``threads``: ``"auto"`` (numba's thread pool from :data:`PARALLEL_THRESHOLD` arms of a kind
      on), ``True`` or ``False``; the serial and multi-threaded kernels agree bit for bit.
    * every other keyword of :class:`~pan1_env.config.FormationConfig` except ``qp_solver`` (the batched
      engine uses the exact compiled QP).

    ## Version History

    * v0: initial release.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    @forwards_keywords("pan1_env.environment:Pan1ParallelEnv", exclude=("render_mode", "qp_solver", "safety_filter"))
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", num_envs: int = 1, *,
                 safety_filter: bool | FilterParams = True, threads: bool | str = "auto", **kwargs: Any) -> None:
        for bad in ("render_mode", "qp_solver"):
            if bad in kwargs:
                raise TypeError(f"Pan1VectorEnv does not take {bad!r} (no rendering; the exact compiled QP only)")
        config = FormationConfig(scenario, safety_filter=safety_filter, **kwargs)
        self.core = FormationCore(config, num_envs, threads=threads)
        self.num_envs = self.core.copies
        self.agents = list(self.core.agents)
        self.single_observation_space = gymnasium.spaces.Box(*self.core.flat_observation_bounds(), dtype=np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (sum(self.core.action_sizes),), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._needs_reset = True
        self.render_mode = None

    @property
    def threads(self) -> bool | str:
        return self.core.engine.threads

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset every copy. ``seed``: an int (independent streams spawned from it, one per copy) or one seed (or
        None) per copy (copy b then meets the team of a one-copy env reset with ``seeds[b]``)."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            seed = list(seed)
        self.core.reset(options=options, seeds=seed)
        self._needs_reset = False
        mats, infos = self.core.start()
        return self.core.flat_observations(mats), _masked(self.core.team_infos(infos))

    def step(self, actions: np.ndarray):
        if self._needs_reset:
            raise RuntimeError("step() called before reset(); call reset()")
        a = float_array("actions", actions, self.action_space.shape)
        out = self.core.step(self.core.padded_actions(a), autoreset=True)
        obs = self.core.flat_observations(out.observations)
        infos = _masked(self.core.team_infos(out.infos))
        if "fault" in infos:
            infos["_fault"] = out.infos["fault"] != ""
        if len(out.ended):
            done = np.zeros(self.num_envs, dtype=bool)
            done[out.ended] = True
            final = self.core.flat_observations(out.final_observations)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for b in out.ended:
                final_obs[b] = final[b]
            final_info = dict(infos)
            infos["final_obs"], infos["_final_obs"] = final_obs, done
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
        return obs, out.reward.mean(axis=1), out.terminated, out.truncated, infos


def _masked(infos: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Gymnasium's vector infos: every key with its ``_key`` mask (every copy has every key)."""
    for key in list(infos):
        infos["_" + key] = np.ones(len(infos[key]), dtype=bool)
    return infos
