"""The Gymnasium vector environment: B copies of a scenario on one engine.

:class:`Pan1VectorEnv` is an adapter over :class:`~pan1_env.engine.Engine` with B copies (one
kernel call per arm kind for all copies) and the formation task (:class:`~pan1_env.tasks.FormationTask`),
the same two the parallel env runs on with B = 1. It is the vectorised form of
:class:`~pan1_env.registration.CentralizedEnv` (the ``gymnasium.make`` view): the same flat
observation, action, reward, cost and time steps, with the safety filter on by default.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .compiled import kernels
from .engine import PARALLEL_THRESHOLD, Engine, FilterParams
from .random_scenario import random_scenario
from .scenario import Scenario
from .tasks import FormationTask
from .validation import float_array, forwards_keywords, positive_int

__all__ = ["Pan1VectorEnv", "PARALLEL_THRESHOLD"]


class Pan1VectorEnv(VectorEnv):
    """``num_envs`` independent copies of a pan1-env scenario as one Gymnasium ``VectorEnv``.

    ## Description

    Each copy is the centralised single-agent view of :class:`~pan1_env.environment.Pan1ParallelEnv`
    (what ``gymnasium.make("pan1_env/PaperPA3Square-v0")`` gives); all copies step together in
    batched compiled code, so the cost per arm falls as ``num_envs`` grows.

    ## Action Space

    ``Box(-1, 1, (num_envs, Σ k_i), float32)``: row b is copy b's concatenated per-arm actions
    (agent order), meant as in the parallel env (``action_mode`` velocity, torque, residual or gain). Values are
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
    (``reset(seed=s)`` seeds copy b with ``s + b``; a list of seeds gives one per copy).

    ## Episode End

    Per copy, as the parallel env (truncation after ``max_steps``, on a numerical fault, or the
    optional terminations). A copy that ends is reset in the same call
    (``metadata["autoreset_mode"] = AutoresetMode.SAME_STEP``): the returned observation is the
    new episode's first, and ``infos["final_obs"]`` / ``infos["final_info"]`` (with the masks
    ``infos["_final_obs"]``, ``infos["_final_info"]``) hold the ended episode's last ones.

    ## Infos

    Arrays over copies (each with Gymnasium's ``_key`` mask): ``cost`` (number of arms that entered
    an obstacle in the step), ``min_clearance`` (m), ``formation_error`` (m), ``is_success``, and with
    the safety filter ``shield_intervened`` and ``shield_fallback``; after a step the reward's terms
    ``reward_formation`` (and ``reward_effort``, ``reward_collision`` when their weights are not
    zero), averaged over the agents like the reward; ``fault`` (strings, masked) for a copy truncated
    by a non-finite state.

    ## Arguments

    * ``scenario``: as the parallel env (a built-in name, a TOML path, a Scenario or ``"random"``).
    * ``num_envs``: B, the number of copies.
    * ``safety_filter``: the paper's RCBF-QP safety filter at every physics sub-step: ``True``
      (default; the same filter as :class:`~pan1_env.wrappers.SafetyShield`, the scenario's κ, ε and
      margin), ``False``, or a :class:`~pan1_env.engine.FilterParams`. (``shield=`` is its
      deprecated name.)
    * ``threads``: ``"auto"`` (numba's thread pool from :data:`PARALLEL_THRESHOLD` arms of a kind
      on), ``True`` or ``False``. The serial and multi-threaded kernels run the same compiled code,
      4 arms at once; an arm's result does not depend on the others, and the two agree bit for bit
      (tests/test_kernels.py, tests/test_vector.py).
    * every other keyword of :class:`~pan1_env.environment.Pan1ParallelEnv` except ``render_mode``
      and ``qp_solver`` (the batched engine uses the exact compiled QP).

    ## Version History

    * v0: initial release.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    @forwards_keywords("pan1_env.environment:Pan1ParallelEnv", exclude=("render_mode", "qp_solver", "safety_filter"))
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", num_envs: int = 1, *,
                 safety_filter: bool | FilterParams = True, threads: bool | str = "auto",
                 shield: bool | None = None, **kwargs: Any) -> None:
        from .environment import Pan1ParallelEnv

        for bad in ("render_mode", "qp_solver"):
            if bad in kwargs:
                raise TypeError(f"Pan1VectorEnv does not take {bad!r} (no rendering; the exact compiled QP only)")
        if shield is not None:
            warnings.warn("Pan1VectorEnv(shield=...) is deprecated; use safety_filter=...", DeprecationWarning,
                          stacklevel=3)
            safety_filter = bool(shield)
        self.num_envs = positive_int("num_envs", num_envs)
        # one parallel env validates the arguments and fixes spaces, layout and time steps
        self.template = t = Pan1ParallelEnv(scenario, safety_filter=safety_filter, **kwargs)
        self._random = t._random
        self.engine = Engine(t.scenario, self.num_envs, physics_dt=t.physics_dt, safety_filter=t.safety_filter or False,
                             max_speed=t.max_joint_speed, threads=threads)
        self.task = FormationTask.of_env(t, self.num_envs)
        self.agents = list(t.possible_agents)
        obs_spaces = [t.observation_space(a) for a in self.agents]
        act_sizes = t.n_actuated
        self.single_observation_space = gymnasium.spaces.Box(
            np.concatenate([s.low for s in obs_spaces]), np.concatenate([s.high for s in obs_spaces]),
            dtype=np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (sum(act_sizes),), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        N, k_max = len(act_sizes), max(act_sizes)
        # where each action column goes in the padded (N, k_max) command of a copy
        self._columns = np.concatenate([i * k_max + np.arange(k) for i, k in enumerate(act_sizes)])
        self._k_rows = np.tile(np.asarray(act_sizes), self.num_envs)
        self._command = np.zeros((self.num_envs, N, k_max))
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._needs_reset = True
        self.render_mode = None

    @property
    def safety_filter(self) -> FilterParams | None:
        """The safety filter's parameters, or None when it is off."""
        return self.engine.filter

    @property
    def shield(self) -> bool:
        """Deprecated: ``safety_filter is not None``."""
        warnings.warn("Pan1VectorEnv.shield is deprecated; use safety_filter", DeprecationWarning, stacklevel=2)
        return self.engine.filter is not None

    @property
    def threads(self) -> bool | str:
        return self.engine.threads

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset every copy. ``seed``: an int (copy b gets ``seed + b``) or one seed (or None) per copy."""
        B = self.num_envs
        if seed is not None:
            seeds = [seed + b for b in range(B)] if isinstance(seed, (int, np.integer)) else list(seed)
            if len(seeds) != B:
                raise ValueError(f"reset(seed=...) needs an int or {B} seeds, got {len(seeds)}")
            for b, s in enumerate(seeds):
                if s is not None:
                    self._rngs[b] = np.random.default_rng(s)
        self._reset_copies(np.arange(B))
        self._needs_reset = False
        err, mats = self.task.observe(self.engine)
        out = self.task.evaluate(None, err, np.zeros((B, self.engine.n_arms)), self.engine.clearance())
        return self.task.flat(mats), self._infos(out, None)

    def step(self, actions: np.ndarray):
        if self._needs_reset:
            raise RuntimeError("step() called before reset(); call reset()")
        a = float_array("actions", actions, self.action_space.shape)
        B, t = self.num_envs, self.template
        command = self._command
        command.reshape(B, -1)[:, self._columns] = a
        effort = np.empty(B * self.engine.n_arms)
        bad = kernels().scale_command(command.reshape(len(effort), -1), self._k_rows, t.action_scale, effort)
        if bad >= 0:
            raise ValueError(f"actions for copy {bad // self.engine.n_arms} contain NaN or inf")
        self.task.compose(t.action_mode, command, self.engine)
        rec = self.engine.step(command, t.substeps, torque=t.action_mode == "torque")
        self._steps += 1
        err, mats = self.task.observe(self.engine)
        obs = self.task.flat(mats)
        out = self.task.evaluate(rec, err, effort.reshape(B, -1),
                                 command=None if t.action_mode == "torque" else command)
        finite = rec.finite.all(axis=1)
        truncated = (self._steps >= t.max_steps) | ~finite
        infos = self._infos(out, rec)
        if not finite.all():
            infos["fault"] = np.where(finite, "", "non-finite state in the physics step; episode truncated")
            infos["_fault"] = ~finite
        done = out.terminated | truncated
        if done.any():
            which = np.flatnonzero(done)
            final_obs = np.full(B, None, dtype=object)
            for b in which:
                final_obs[b] = obs[b].copy()
            final_info = dict(infos)
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
            self._reset_copies(which)
            obs[which] = self.task.flat(self.task.observe(self.engine)[1])[which]
        return obs, out.reward.mean(axis=1), out.terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # ------------------------------------------------------------- internals
    def _reset_copies(self, which: np.ndarray) -> None:
        """Put the copies ``which`` (indices) at their start, at rest (new teams when random)."""
        for b in which:
            if self._random:
                team = random_scenario(self._rngs[b], self.template.random_options)
                self.engine.load_team(int(b), team)
                self.task.load_team(int(b), team)
            self._steps[b] = 0
        self.task.blocked[which] = 0.0  # no filter change yet in a new episode
        self.engine.reset(which)

    def _infos(self, out, rec) -> dict[str, Any]:
        everywhere = np.ones(self.num_envs, dtype=bool)
        infos = {"cost": out.cost.sum(axis=1), "min_clearance": out.measures["min_clearance"].min(axis=1),
                 "formation_error": out.measures["formation_error"], "is_success": out.success}
        if rec is not None:  # the reward's terms, averaged over the agents as the reward is
            for name, value in out.terms.items():
                infos[f"reward_{name}"] = np.broadcast_to(value, out.cost.shape).mean(axis=1)
        if self.engine.filter is not None:
            infos["shield_intervened"] = rec.intervened.any(axis=1) if rec is not None else ~everywhere
            infos["shield_fallback"] = rec.fallback.any(axis=1) if rec is not None else ~everywhere
        for key in list(infos):
            infos["_" + key] = everywhere
        return infos
