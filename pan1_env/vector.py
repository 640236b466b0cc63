"""The Gymnasium vector environment: B copies of a scenario stepped in one batched call per arm kind.

:class:`Pan1VectorEnv` holds the state of every arm of every copy in arrays batched over
``B × (arms of one kind)`` and advances them all with one call of the compiled closed-loop kernel
(:func:`pan1_env.kernels.group_advance`, or its multi-threaded twin for large batches) per arm
kind, then builds every observation with one compiled call per kind; turning actions into
commands and the arms' results into per-copy costs, rewards and flags is compiled too
(:mod:`pan1_env.vector_kernels`). It is the vectorised form of
:class:`~pan1_env.registration.CentralizedEnv` (the ``gymnasium.make`` view): the same flat
observation, action, reward, cost and time steps, with the safety filter on by default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .dynamics import ArmBatch
from .random_scenario import random_scenario
from .safety import clearance
from .scenario import Scenario
from .validation import float_array, forwards_keywords, positive_int

__all__ = ["Pan1VectorEnv", "PARALLEL_THRESHOLD"]

PARALLEL_THRESHOLD = 256  # arms of one kind from which the kernel runs on numba's thread pool


class Pan1VectorEnv(VectorEnv):
    """``num_envs`` independent copies of a pan1-env scenario as one Gymnasium ``VectorEnv``.

    ## Description

    Each copy is the centralised single-agent view of :class:`~pan1_env.environment.Pan1ParallelEnv`
    (what ``gymnasium.make("pan1_env/PaperPA3Square-v0")`` gives); all copies step together in
    batched compiled code, so the cost per arm falls as ``num_envs`` grows.

    ## Action Space

    ``Box(-1, 1, (num_envs, Σ k_i), float32)``: row b is copy b's concatenated per-arm actions
    (agent order), scaled as in the parallel env (``action_mode`` velocity or torque). Values are
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
    the safety filter ``shield_intervened`` and ``shield_fallback``; ``fault`` (strings, masked) for a
    copy truncated by a non-finite state.

    ## Arguments

    * ``scenario``: as the parallel env (a built-in name, a TOML path, a Scenario or ``"random"``).
    * ``num_envs``: B, the number of copies.
    * ``shield``: run the paper's RCBF-QP safety filter at every physics sub-step (default True;
      the same filter as :class:`~pan1_env.wrappers.SafetyShield` with the scenario's κ, ε, margin).
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

    @forwards_keywords("pan1_env.environment:Pan1ParallelEnv", exclude=("render_mode", "qp_solver"))
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", num_envs: int = 1, *,
                 shield: bool = True, threads: bool | str = "auto", **kwargs: Any) -> None:
        from .environment import Pan1ParallelEnv

        for bad in ("render_mode", "qp_solver"):
            if bad in kwargs:
                raise TypeError(f"Pan1VectorEnv does not take {bad!r} (no rendering; the exact compiled QP only)")
        if threads not in ("auto", True, False):
            raise ValueError(f"threads must be 'auto', True or False, got {threads!r}")
        self.num_envs = positive_int("num_envs", num_envs)
        self.threads = threads
        # one parallel env validates the arguments and fixes spaces, layout and time steps
        self.template = Pan1ParallelEnv(scenario, **kwargs)
        if shield:
            from pan1_env.wrappers.shield import _switch_on

            _switch_on(self.template, None, None, None, None)
        t = self.template
        self.shield = bool(shield)
        self._random = t._random
        self.agents = list(t.possible_agents)
        obs_spaces = [t.observation_space(a) for a in self.agents]
        act_sizes = [t.action_space(a).shape[0] for a in self.agents]
        self.single_observation_space = gymnasium.spaces.Box(
            np.concatenate([s.low for s in obs_spaces]), np.concatenate([s.high for s in obs_spaces]),
            dtype=np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (sum(act_sizes),), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._act_offsets = np.concatenate([[0], np.cumsum(act_sizes)])
        self._obs_offsets = np.concatenate([[0], np.cumsum([s.shape[0] for s in obs_spaces])])
        self._scale = t.max_joint_speed if t.action_mode == "velocity" else t.max_torque
        self._torque = t.action_mode == "torque"
        # effort = Σ_i ‖a_i‖² / k_i: one weight per action column
        self._effort_weights = np.concatenate([np.full(k, 1.0 / max(k, 1)) for k in act_sizes])
        self._build_batches(t.scenario)
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._needs_reset = True
        self.render_mode = None

    # ------------------------------------------------------------------ set-up
    def _build_batches(self, sc: Scenario) -> None:
        """Arrays over B copies of ``sc``: one kernel group per arm kind, arms ordered copy-major."""
        B, t = self.num_envs, self.template
        self._groups = []
        for g in t.sim.groups:
            A = len(g.arm_ids)
            rep = lambda x: np.ascontiguousarray(np.tile(x, (B,) + (1,) * (x.ndim - 1)))  # noqa: E731
            b = g.batch
            cols = np.array([np.arange(self._act_offsets[i], self._act_offsets[i] + g.k) for i in g.arm_ids],
                            dtype=np.int64).reshape(A, g.k)
            self._groups.append({
                "ids": np.ascontiguousarray(g.arm_ids, dtype=np.int64), "n": g.n, "k": g.k, "sizes": g.sizes, "A": A,
                "passive": b.passive_first_joint, "cols": cols,
                "lam": rep(b.lam), "lengths": rep(b.lengths), "base": rep(b.base), "phi": rep(b.phi),
                "centers": rep(g.centers), "radii": rep(g.radii), "mask": rep(g.obstacle_mask),
                "q0": rep(np.array([sc.q0[i] for i in g.arm_ids])),
                "q": np.zeros((B * A, g.n)), "v": np.zeros((B * A, g.k)), "v_prev": np.zeros((B * A, g.k)),
                "has_prev": np.zeros(B * A, dtype=bool), "qd": np.zeros((B * A, g.n)), "p": np.zeros((B * A, 2)),
                "v_star": np.zeros((B * A, g.k)), "tau": np.zeros((B * A, g.k)),
                "finite": np.ones(B * A, dtype=bool), "counts": np.zeros((B * A, 3), dtype=np.int64),
                # per-step scratch: commands and the kernel's running extremes
                "command": np.zeros((B * A, g.k)), "clear": np.zeros(B * A), "min_h": np.zeros(B * A),
                "track": np.zeros(B * A),
            })
        N, n_max = sc.n_arms, max(a.n_links for a in sc.arms)
        self._n_arms, self._n_max = N, n_max
        # one arm kind in team order: the state arrays reshaped are the observation's inputs
        self._team_order = len(self._groups) == 1 and list(self._groups[0]["ids"]) == list(range(N))
        self._bases = np.tile(np.array([a.base for a in sc.arms])[None], (B, 1, 1))
        self._centers = np.tile(sc.obstacles.centers[None], (B, 1, 1))
        self._radii = np.tile(sc.obstacles.radii[None], (B, 1))
        self._edges = np.ascontiguousarray(sc.formation.edges, dtype=np.int64)
        self._distances = np.tile(sc.formation.distances[None], (B, 1))
        self._sim_params = (sc.kappa, sc.epsilon, sc.safety_margin, sc.ke)
        if self.shield and t.shield_params:
            p = t.shield_params
            self._sim_params = (p["kappa"], p["epsilon"], p["margin"], sc.ke)

    def _load_team(self, b: int, sc: Scenario) -> None:
        """Write a (random) team's parameters, obstacles and formation into copy b's slots."""
        mask = sc.obstacle_mask()
        for g in self._groups:
            sl = slice(b * g["A"], (b + 1) * g["A"])
            arms = [sc.arms[i] for i in g["ids"]]
            batch = ArmBatch.stack(arms)
            g["lam"][sl], g["lengths"][sl], g["base"][sl], g["phi"][sl] = (batch.lam, batch.lengths, batch.base,
                                                                            batch.phi)
            g["centers"][sl] = sc.obstacles.centers[None]
            g["radii"][sl] = sc.obstacles.radii[None]
            g["mask"][sl] = mask[g["ids"]]
            g["q0"][sl] = np.array([sc.q0[i] for i in g["ids"]])
        self._bases[b] = np.array([a.base for a in sc.arms])
        self._centers[b] = sc.obstacles.centers
        self._radii[b] = sc.obstacles.radii
        self._distances[b] = sc.formation.distances

    def _reset_copies(self, which: np.ndarray) -> None:
        """Put the copies ``which`` (indices) at their start, at rest (new teams when random)."""
        for b in which:
            if self._random:
                self._load_team(int(b), random_scenario(self._rngs[b], self.template.random_options))
            self._steps[b] = 0
        for g in self._groups:
            A = g["A"]
            rows = (np.asarray(which)[:, None] * A + np.arange(A)[None]).ravel()
            g["q"][rows] = g["q0"][rows]
            g["v"][rows] = 0.0
            g["v_prev"][rows] = 0.0
            g["has_prev"][rows] = False
            g["qd"][rows] = 0.0
        self._refresh_positions()

    def _refresh_positions(self) -> None:
        from .kernels import group_end_effectors

        for g in self._groups:
            group_end_effectors(g["lengths"], g["base"], g["phi"], g["q"], g["p"])

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
        err, obs = self._observations()
        info = self._infos(np.zeros(B), self._clearance(), np.abs(err).max(axis=1), None)
        return obs, info

    def step(self, actions: np.ndarray):
        from . import kernels, vector_kernels

        if self._needs_reset:
            raise RuntimeError("step() called before reset(); call reset()")
        a = np.ascontiguousarray(float_array("actions", actions, self.action_space.shape))
        if not np.isfinite(a).all():
            bad = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
            raise ValueError(f"actions for copy {bad} contain NaN or inf")
        t = self.template
        B = self.num_envs
        kappa, eps, margin, ke = self._sim_params
        min_clear = np.full((B, self._n_arms), np.inf)
        intervened = np.zeros(B, dtype=bool)
        fallback = np.zeros(B, dtype=bool)
        finite = np.ones(B, dtype=bool)
        for g in self._groups:
            A = g["A"]
            command = g["command"]
            vector_kernels.gather_commands(a, g["cols"], self._scale, command)
            clear = g["clear"]
            clear.fill(np.inf)
            g["min_h"].fill(np.inf)
            g["track"].fill(0.0)
            g["counts"].fill(0)
            args = (*g["sizes"], g["lam"], g["lengths"], g["base"], g["phi"], g["passive"], g["q"], g["v"],
                    g["v_prev"], g["has_prev"], command, self._torque, self.shield, g["centers"], g["radii"],
                    g["mask"], kappa, eps, margin, ke, t.physics_dt, t.substeps,
                    t.max_joint_speed if self.shield else np.inf, g["v_star"], g["tau"], g["qd"], g["p"], clear,
                    g["min_h"], g["counts"], g["track"], g["finite"])
            chunks = self._chunks(B * A)
            if chunks:
                kernels.group_advance_parallel(*args, chunks)
            else:
                kernels.group_advance(*args)
            if self._torque:
                g["has_prev"].fill(False)
            vector_kernels.gather_arm_results(g["ids"], clear, g["counts"], g["finite"], min_clear, intervened,
                                              fallback, finite)
        self._steps += 1
        err, obs = self._observations()
        cost, clearance, formation_error = np.empty(B), np.empty(B), np.empty(B)
        success, reward = np.empty(B, dtype=bool), np.empty(B)
        vector_kernels.team_rewards(min_clear, err, a, self._effort_weights, t.formation_weight, t.effort_weight,
                                    t.collision_penalty, t.success_tolerance, cost, clearance, formation_error,
                                    success, reward)
        terminated = np.zeros(B, dtype=bool)
        if t.terminate_on_collision:
            terminated |= cost > 0
        if t.terminate_on_success:
            terminated |= success
        truncated = (self._steps >= t.max_steps) | ~finite
        infos = self._infos(cost, clearance, formation_error, (intervened, fallback), success)
        if not finite.all():
            infos["fault"] = np.where(finite, "", "non-finite state in the physics step; episode truncated")
            infos["_fault"] = ~finite
        done = terminated | truncated
        if done.any():
            which = np.flatnonzero(done)
            final_obs = np.full(B, None, dtype=object)
            for b in which:
                final_obs[b] = obs[b].copy()
            final_info = {key: value for key, value in infos.items()}
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
            self._reset_copies(which)
            obs[which] = self._observations()[1][which]
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # ------------------------------------------------------------- internals
    def _positions(self) -> np.ndarray:
        P = np.empty((self.num_envs, self._n_arms, 2))
        for g in self._groups:
            P[:, g["ids"]] = g["p"].reshape(self.num_envs, g["A"], 2)
        return P

    def _clearance(self) -> np.ndarray:
        if self._radii.shape[1] == 0:
            return np.full(self.num_envs, np.inf)
        return clearance(self._positions(), self._centers[:, None], self._radii[:, None]).min(axis=(1, 2))

    def _chunks(self, arms: int) -> int:
        """0 if a compiled call over ``arms`` arms runs on one thread, else the number of chunks it is split
        into on numba's thread pool (the ``threads`` argument; "auto" from :data:`PARALLEL_THRESHOLD`)."""
        if not (self.threads is True or (self.threads == "auto" and arms >= PARALLEL_THRESHOLD)):
            return 0
        from numba import get_num_threads

        return 4 * get_num_threads()

    def _observations(self) -> tuple[np.ndarray, np.ndarray]:
        """The edge-length errors ``(B, E)`` and the observations ``(B, Σ obs_i)`` of the current state."""
        B, N = self.num_envs, self._n_arms
        if self._team_order:
            q, qd, P = (self._groups[0][key].reshape(B, N, -1) for key in ("q", "qd", "p"))
        else:
            P = self._positions()
            q = np.zeros((B, N, self._n_max))
            qd = np.zeros((B, N, self._n_max))
            for g in self._groups:
                q[:, g["ids"], : g["n"]] = g["q"].reshape(B, g["A"], g["n"])
                qd[:, g["ids"], : g["n"]] = g["qd"].reshape(B, g["A"], g["n"])
        err, mats = self.template._layout.build_with_errors(q, qd, P, self._bases, self._edges, self._distances,
                                                            self._centers, self._radii, self.template.max_joint_speed,
                                                            self._chunks(B * N))
        if len(mats) == 1 and len(self._groups[0]["ids"]) == N:
            return err, mats[0].reshape(B, -1)
        out = np.empty((B, self._obs_offsets[-1]), dtype=np.float32)
        for (_, ids), mat in zip(self.template._layout.groups, mats, strict=True):
            for r, i in enumerate(ids):
                out[:, self._obs_offsets[i] : self._obs_offsets[i + 1]] = mat[:, r]
        return err, out

    def _infos(self, cost, min_clearance, formation_error, shield, success=None) -> dict[str, Any]:
        B = self.num_envs
        everywhere = np.ones(B, dtype=bool)
        if success is None:
            success = formation_error < self.template.success_tolerance
        infos = {"cost": np.asarray(cost, dtype=float), "min_clearance": min_clearance,
                 "formation_error": formation_error, "is_success": success}
        if shield is not None and self.shield:
            infos["shield_intervened"], infos["shield_fallback"] = shield
        for key in list(infos):
            infos["_" + key] = everywhere
        return infos
