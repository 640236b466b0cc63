"""The env core: B copies × N arms of the formation task, the one owner of an episode.

:class:`FormationCore` runs an :class:`~pan1_env.engine.Engine` and a
:class:`~pan1_env.tasks.FormationTask` built from one :class:`~pan1_env.config.FormationConfig`. It owns
everything an episode is: seeding, reset (new random teams, task state, the clock), turning actions into
commands, the step, the episode clock, truncation, numerical faults, autoreset and the infos. Every view
(the PettingZoo parallel env, the Gymnasium env, the vector env, SB3's VecEnv) only reshapes what it
returns; B = 1 is a batch of one.

Infos (:meth:`FormationCore.infos`) are flat arrays, the same keys after a reset and after a step:

* per arm ``(B, N)``: ``cost`` (1.0 where the arm's protected bodies entered an obstacle after a
  sub-step), ``min_clearance`` (m), ``reward_<term>`` (the reward's weighted terms, which sum to it:
  ``formation``, and ``effort``, ``collision``, ``success``, ``intervention`` when their weights are not
  zero; 0 at a reset; ``(B, 1)`` for a term every arm shares, such as ``formation``), and with the safety
  filter on its report of the step: ``shield_intervened`` (the QP changed the command at some sub-step),
  ``shield_fallback`` (its QP was infeasible and the fallback ran), ``shield_status`` (the worst QP status
  over the sub-steps, 0 nominal, 1 solved, 2 fallback: :class:`~pan1_env.safety.QPStatus`),
  ``shield_min_barrier`` (the smallest barrier value the filter saw; inf with none), ``shield_applied
  (B, N, k_max)`` float32 (the command applied at the last sub-step, one entry per actuated joint: the filtered
  velocity v*/``max_joint_speed``, or the torque/``max_torque``; 0 in the padding and for a lost joint) and
  ``qp_counts (B, N, 3)`` (sub-steps per QP status); on a team whose arms may lose an actuator
  (``Scenario.fault_times``), ``actuator_lost`` (the arm's first joint has lost its drive: the action entry of
  that joint, the first, or in circulation mode the second, is ignored);
* per copy ``(B,)``: ``formation_error`` (m, largest edge-length error), ``is_success``, and ``fault`` (a
  message, "" for the copies without one) only in a step where some copy's state went non-finite.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium.utils.seeding import np_random

from .compiled import kernels
from .config import FormationConfig, ReachConfig
from .engine import Engine
from .observation import OBS_BOUND, ObservationLayout
from .step_record import StepRecord
from .tasks import FormationTask, ReachTask
from .team_draw import draw_teams
from .validation import positive_int

__all__ = ["FormationCore", "CoreStep", "copy_generator", "CoreView", "per_arm", "FAULT",
           "view_repr", "team_mean"]

FAULT = "non-finite state in the physics step; episode truncated"
TASKS = {FormationConfig: FormationTask, ReachConfig: ReachTask}


@dataclass
class CoreStep:
    """A step of every copy: observations (one ``(B, A, size)`` float32 array per layout group), ``reward
    (B, N)``, ``terminated``, ``truncated`` ``(B,)``, the infos, and with autoreset the copies that ended
    (``ended``, indices) with their last observations and infos (``final_observations``, ``final_infos``)
    and, if asked for, global state (``final_state``); the observations are then the new episodes' first."""

    observations: list[np.ndarray]
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    infos: dict[str, np.ndarray]
    ended: np.ndarray
    final_observations: list[np.ndarray] | None = None
    final_infos: dict[str, np.ndarray] | None = None
    final_state: np.ndarray | None = None


class FormationCore:
    """B copies of a scenario's team and a task, stepped together (see the module docstring).

    Args:
        config: the env's arguments, validated: a :class:`~pan1_env.config.FormationConfig` (the formation
            task) or a :class:`~pan1_env.config.ReachConfig` (the one-arm reach task).
        copies: B.
        threads: the engine's ``threads`` (``"auto"``, ``True`` or ``False``).
    """

    #: the padded observation is the one layout group's array (set per core; False: the general path)
    _padded_is_the_group = False
    #: where these copies start in a larger batch seeded with one int (several cores trained as one, as the mixed
    #: team sizes of pan1_env.baselines.mixed_vec_env are), so that every copy's stream is its own
    first_copy: int = 0

    def __init__(self, config: FormationConfig | ReachConfig, copies: int = 1, *, threads: bool | str = "auto") -> None:
        self.config = c = config
        self.copies = B = positive_int("num_envs", copies)
        team = c.team
        self.engine = Engine(team, B, c.physics, threads=threads)
        self.set_safety_filter(c.safety_filter or False)  # refused here, as later, where the solver cannot do it
        self.task = TASKS[type(c)](c, B)
        self.layout: ObservationLayout | None = getattr(self.task, "layout", None)
        self.agents = [f"arm_{i}" for i in range(team.n_arms)]
        self.n_links = [a.n_links for a in team.arms]
        self.n_actuated = [a.n_actuated for a in team.arms]
        #: each arm's action entries: one per actuated joint, and in circulation mode one more, its circulation
        self.action_sizes = [k + (c.action_mode == "circulation") for k in self.n_actuated]
        self.rngs = [np.random.default_rng() for _ in range(B)]
        self.steps = np.zeros(B, dtype=np.int64)
        self.record: StepRecord | None = None
        self._k_rows = np.tile(np.asarray(self.action_sizes), B)
        # the flat team layout's columns in the padded (N, k_max) command (the filter's report) and in the padded
        # (N, action_width) actions (the team views' flat action)
        k_max = max(self.n_actuated)
        self._columns = np.concatenate([i * k_max + np.arange(k) for i, k in enumerate(self.n_actuated)])
        width = max(self.action_sizes)
        self._action_columns = np.concatenate([i * width + np.arange(k) for i, k in enumerate(self.action_sizes)])
        self._command = np.zeros((B, team.n_arms, width))
        # each arm's actuated joints among the torque record's n_max columns (its last k), and its padding
        k = np.asarray(self.n_actuated)[:, None]
        slot = np.minimum(np.arange(k_max), k - 1)
        self._actuated_joints = (np.asarray(self.n_links)[:, None] - k + slot)[None]
        self._padding = np.arange(k_max) >= k
        self._slots = _command_slots(team.n_arms, k_max)
        self._uniform_actions = len(set(self.n_actuated)) == 1
        self._team_plans: dict[tuple[str, ...], list] = {}  # team_info's reading of each key, per key set
        # (layout group, row in the group) of each agent's observation, in agent order
        groups = [ids for _, ids in self.layout.groups] if self.layout is not None else [np.arange(1)]
        order = sorted((i, g, r) for g, ids in enumerate(groups) for r, i in enumerate(ids.tolist()))
        self._observation_rows = [(g, r) for _, g, r in order]
        self._observation_sizes = [len(self.task.bounds(i)[0]) for i in range(team.n_arms)]  # agent order
        self._padded_is_the_group = len(groups) == 1 and groups[0].tolist() == list(range(team.n_arms))

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_team_plans"] = {}  # functions made on the fly do not pickle; they are made again on use
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if "_slots" not in state:  # pickled by a build before the filter's report was compiled
            self._slots = _command_slots(self.engine.n_arms, self.engine.k_max)
        if "_action_columns" not in state:  # pickled before circulation actions: the actions are the command's width
            self.action_sizes, self._action_columns = list(self.n_actuated), self._columns

    def set_safety_filter(self, safety_filter) -> None:
        """Switch the engine's filter (``False``, ``True`` or a :class:`~pan1_env.safety.FilterParams`), after
        its QP solver has checked that it can filter this env (PIQP: one copy, velocity mode)."""
        check = getattr(self.engine.qp, "check", None)
        if safety_filter is not False and check is not None:
            check(self.copies, torque=self.config.action_mode == "torque")
        self.engine.set_safety_filter(safety_filter)

    @property
    def k_max(self) -> int:
        """The most actuated joints of an arm: the width of the engine's command and of the filter's report."""
        return self.engine.k_max

    @property
    def action_width(self) -> int:
        """The most action entries of an arm (:attr:`action_sizes`): the width of the padded actions."""
        return len(self._command[0, 0])

    @property
    def state_size(self) -> int:
        """Size of :meth:`state`: q, q̇ (padded to the largest n) and p of every arm, centre and radius of every
        obstacle, and for a moving formation the desired lengths and every arm's feed-forward."""
        return (len(self.agents) * (2 * max(self.n_links) + 2) + 3 * self.engine.radii.shape[1]
                + self.task.target_size)

    def state(self) -> np.ndarray:
        """Every copy's global state ``(B, state_size)`` float32, for centralised critics: every arm's q and q̇
        (zeros beyond its links) and end-effector, then every obstacle's centre (where it is now) and radius, then
        for a moving formation (the target moves: a critic needs it) the desired lengths now and every arm's
        feed-forward ṗ_ff."""
        engine, B, N = self.engine, self.copies, len(self.agents)
        out = np.empty((B, self.state_size), dtype=np.float32)
        arms = N * (2 * engine.n_max + 2)
        out[:, :arms] = 0.0  # the padding beyond an arm's links
        for kind in engine.kinds:  # each arm's q, q̇ (NaN read 0: a non-finite arm's), p, clipped
            kernels().kind_state(kind.q, kind.qd, kind.p, kind.stepped, kind.ids, kind.A, engine.n_max, OBS_BOUND, out)
        kernels().obstacle_state(engine.centers, engine.radii, arms, OBS_BOUND, out)
        if self.task.target_size:
            out[:, arms + 3 * engine.radii.shape[1]:] = np.clip(self.task.target_state(engine), -OBS_BOUND, OBS_BOUND)
        return out

    def copy_observations(self, mats: list[np.ndarray], b: int = 0) -> list[np.ndarray]:
        """Copy b's observation of every agent, in agent order (views of ``mats``): what a one-copy view returns."""
        return [mats[group][b, row] for group, row in self._observation_rows]

    def per_agent(self, mats: list[np.ndarray]) -> list[np.ndarray]:
        """The observations of :meth:`observe` (one array per layout group) as one ``(B, size_i)`` array per
        agent, in agent order (views of ``mats``)."""
        return [mats[group][:, row] for group, row in self._observation_rows]

    def padded_observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``(N, size)`` of :meth:`padded_observations`: each arm's own, zeros on its padding."""
        bounds = [self.task.bounds(i) for i in range(len(self.agents))]
        size = max(len(lo) for lo, _ in bounds)
        low, high = np.zeros((len(bounds), size), np.float32), np.zeros((len(bounds), size), np.float32)
        for i, (lo, hi) in enumerate(bounds):
            low[i, : len(lo)], high[i, : len(hi)] = lo, hi
        return low, high

    def padded_observations(self, mats: list[np.ndarray]) -> np.ndarray:
        """Every arm's observation zero-padded at its end to the largest arm's size, ``(B, N, size)`` float32:
        the shared-network views' layout (one row per arm, in agent order)."""
        if self._padded_is_the_group:  # one layout group, in agent order: its array is the padded layout
            return mats[0]
        size = max(mat.shape[-1] for mat in mats)
        out = np.zeros((self.copies, len(self.agents), size), np.float32)
        for (_, ids), mat in zip(self.layout.groups, mats, strict=True):
            out[:, ids, : mat.shape[-1]] = mat
        return out

    def padded_from_flat(self, flat: np.ndarray) -> np.ndarray:
        """The team views' flat observations ``(B', Σ size)`` (any number of rows) in :meth:`padded_observations`'
        layout, ``(B', N, size)``: to run a network shared by the arms on a team view."""
        flat = np.asarray(flat, dtype=np.float32)
        sizes = self._observation_sizes
        out = np.zeros((len(flat), len(sizes), max(sizes)), np.float32)
        for i, part in enumerate(np.split(flat, np.cumsum(sizes)[:-1], axis=1)):
            out[:, i, : part.shape[1]] = part
        return out

    def flat_actions(self, padded: np.ndarray) -> np.ndarray:
        """Padded actions ``(B', N, action_width)`` (any number of rows; each arm's first :attr:`action_sizes`
        entries count) as the team views' flat actions ``(B', Σ sizes)``: the inverse of :meth:`padded_actions`."""
        return np.asarray(padded).reshape(-1, len(self.agents) * self.action_width)[:, self._action_columns]

    def flat_observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the team views' flat observation: the agents' observations concatenated in agent order."""
        bounds = [self.task.bounds(i) for i in range(len(self.agents))]
        return np.concatenate([lo for lo, _ in bounds]), np.concatenate([hi for _, hi in bounds])

    def flat_observations(self, mats: list[np.ndarray]) -> np.ndarray:
        """The agents' observations concatenated in agent order, ``(B, Σ size)``."""
        return self.task.flat(mats)

    def padded_actions(self, flat: np.ndarray) -> np.ndarray:
        """A flat team action ``(B, Σ sizes)`` (agent order) as the padded ``(B, N, action_width)`` array
        :meth:`step` takes (a scratch array of the core's, overwritten by the next call)."""
        if self._uniform_actions:  # every arm has as many actions: the padded array is the flat one reshaped
            self._command.reshape(self.copies, -1)[:] = flat
        else:
            self._command.reshape(self.copies, -1)[:, self._action_columns] = flat
        return self._command

    def seed(self, seeds: int | list[int | None]) -> None:
        """Fresh generators. One int ``s``: every copy gets an independent stream spawned from ``s``
        (:func:`copy_generator`, copy b's number ``first_copy + b``), so runs with different seeds share no copy's
        teams, and no copy's stream is the stream of a one-copy env's ``reset(seed=...)`` (the held-out evaluation
        teams). A list: copy b gets Gymnasium's ``np_random(seeds[b])``, the team a one-copy env draws with that
        seed (``None``: keep the copy's generator). A seed is a non-negative int (``gymnasium.error.Error``
        otherwise)."""
        if isinstance(seeds, (int, np.integer)):
            np_random(int(seeds))  # Gymnasium's check of the seed, before anything changes
            self.rngs = [copy_generator(int(seeds), self.first_copy + b) for b in range(self.copies)]
            return
        if len(seeds) != self.copies:
            raise ValueError(f"reset(seed=...) needs an int or {self.copies} seeds, got {len(seeds)}")
        fresh = {b: np_random(s)[0] for b, s in enumerate(seeds) if s is not None}  # all checked, then set
        for b, rng in fresh.items():
            self.rngs[b] = rng

    def reset(self, which: np.ndarray | None = None, options: dict | None = None,
              seeds: int | list[int | None] | None = None) -> None:
        """Start a new episode in the copies ``which`` (default: all): with ``seeds`` (as :meth:`seed`) fresh
        generators first, then a new team from the copy's generator for random scenarios, every arm at
        rest at its start, the task's state (``options``: the task's reset options) and the clock at zero. A
        bad option or seed changes nothing."""
        which = np.arange(self.copies) if which is None else np.asarray(which, dtype=np.int64)
        options = self.task.reset_options(options)
        if seeds is not None:
            self.seed(seeds)
        if self.config.random and len(which):
            draws = draw_teams([self.rngs[b] for b in which.tolist()], self.config.random_options)
            self.engine.load_teams(which, draws)
            self.task.load_teams(which, draws)
        self.steps[which] = 0
        self.engine.reset(which)
        self.task.reset(which, self.rngs, self.engine, options)
        self.record = None

    def observe(self) -> list[np.ndarray]:
        """Every agent's observation, one float32 array ``(B, A, size)`` per layout group."""
        return self.task.observe(self.engine)[1]

    def start(self, copies: np.ndarray | None = None) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
        """The observations (as :meth:`observe`) and infos of the state just reset (no step yet): the same
        infos keys a step gives. With ``copies`` (indices) those copies' rows only, in their order, at a cost
        that grows with their number (a partial reset's)."""
        state, mats = self.task.observe(self.engine, copies)
        n = self.copies if copies is None else len(copies)
        out = self.task.evaluate(None, self.engine, state, np.zeros((n, len(self.agents))), copies=copies)
        return mats, self._infos(out, None, copies)

    def commands(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The engine's commands ``(B, N, k_max)`` from actions ``(B, N, action_width)`` at the current state (clip to
        [−1, 1], scale, compose with the paper's law in residual, gain and circulation modes; in place in the
        actions' array but in circulation mode, whose actions are one entry wider) and each arm's effort
        ‖clip(a)‖²/size ``(B, N)``. ``ValueError`` for NaN or inf, before anything changes."""
        effort = np.empty(len(self._k_rows))
        flat = actions.reshape(len(effort), -1)
        bad = kernels().scale_command(flat, self._k_rows, self.config.action_scale, effort)
        if bad >= 0:
            b, i = divmod(bad, len(self.agents))
            where = f"action for {self.agents[i]}" + (f" of copy {b}" if self.copies > 1 else "")
            raise ValueError(f"{where} contains NaN or inf: {flat[bad, : self.action_sizes[i]].tolist()}")
        command = self.task.compose(self.config.action_mode, actions, self.engine)
        return command, effort.reshape(self.copies, -1)

    def step(self, actions: np.ndarray, *, autoreset: bool = False, final_state: bool = False) -> CoreStep:
        """One env step of every copy. ``actions (B, N, action_width)``: each arm's actions in [−1, 1] (clipped),
        padding ignored; the array is used as scratch. With ``autoreset`` the copies that end start a new
        episode in the same call (the returned observations are the new episodes' first), and with
        ``final_state`` the step also keeps every copy's :meth:`state` from before that reset (a centralised
        critic's input at an episode's end; it costs about 6 % of a step at B = 1024, so only on request)."""
        c, engine = self.config, self.engine
        torque = c.action_mode == "torque"
        command, effort = self.commands(actions)
        rec = engine.step(command, c.substeps, torque=torque)
        self.record = rec
        self.steps += 1
        state, mats = self.task.observe(engine)
        out = self.task.evaluate(rec, engine, state, effort, command=None if torque else command)
        truncated = self.steps >= c.max_steps
        infos = self._infos(out, rec)
        if not rec.all_finite:  # a numerical fault truncates its copies
            finite = rec.finite.all(axis=1)
            truncated |= ~finite
            infos["fault"] = np.where(finite, "", FAULT)
        ended = (out.terminated | truncated).nonzero()[0]
        result = CoreStep(mats, out.reward, out.terminated, truncated, infos, ended)
        if autoreset and len(result.ended):
            result.final_observations = mats  # observe() builds new arrays: the next call does not touch these
            result.final_infos = infos
            if final_state:
                result.final_state = self.state()
            self.reset(result.ended)
            self.record = rec
            result.observations = self._observe_after_reset(mats, result.ended)
        return result

    def _observe_after_reset(self, mats: list[np.ndarray], ended: np.ndarray) -> list[np.ndarray]:
        """The observations after the copies ``ended`` were reset: theirs anew, the others' those of the step
        (``mats``, kept unchanged as the ended copies' last observations)."""
        if len(ended) == self.copies:
            return self.observe()
        fresh = self.task.observe(self.engine, ended)[1]
        return [_with_rows(mat, ended, rows) for mat, rows in zip(mats, fresh, strict=True)]

    def start_among(self, mats: list[np.ndarray], infos: dict[str, np.ndarray],
                    copies: np.ndarray) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
        """Every copy's observations and infos after the copies ``copies`` were reset: theirs as :meth:`start`
        gives them (computed for them alone), the others' rows of ``mats`` and ``infos`` (what they were given
        last; their state has not moved since). Infos keys that a start does not give are left out."""
        fresh_mats, fresh_infos = self.start(copies)
        return ([_with_rows(mat, copies, rows) for mat, rows in zip(mats, fresh_mats, strict=True)],
                {key: _with_rows(value, copies, fresh_infos[key]) for key, value in infos.items()
                 if key in fresh_infos})

    def agent_infos(self, infos: dict[str, np.ndarray], b: int = 0) -> list[dict[str, Any]]:
        """Copy b's infos per agent, in agent order: per-arm values at the agent's index (``shield_applied``
        the agent's own k_i entries), team values as they are (Python scalars; arrays for ``qp_counts`` and
        ``shield_applied``)."""
        keys = tuple(infos)
        plan = self._team_plans.get(("agents", keys))
        if plan is None:
            plan = self._team_plans[("agents", keys)] = [self._agent_rule(key) for key in keys]
        columns = [gather(infos[key], b) for key, gather in zip(keys, plan, strict=True)]  # each in agent order
        return [dict(zip(keys, values, strict=True)) for values in zip(*columns, strict=True)]

    def _agent_rule(self, key: str):
        """How :meth:`agent_infos` reads ``key`` of copy b as one value per agent (a function of the info's array and
        b), chosen once per key."""
        n = len(self.agents)
        if key == "shield_applied":
            return lambda v, b: [row[:k] for row, k in zip(v[b], self.n_actuated, strict=True)]
        if key == "qp_counts":
            return lambda v, b: list(v[b])
        if _team_rule(key) is None:  # a team value
            return lambda v, b: (v.item(b),) * n
        # per arm, or one value every arm shares
        return lambda v, b: v[b].tolist() if v.shape[1] == n else v[b].tolist() * n

    def team_infos(self, infos: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The infos per copy ``(B,)``, as the team views give them: ``cost`` the number of arms that entered
        an obstacle (``actuator_lost``: that have lost an actuator), ``min_clearance`` and ``shield_min_barrier``
        the smallest, ``reward_<term>`` the mean over arms (as the team reward is), ``shield_intervened``/
        ``_fallback`` any arm's, ``shield_status`` the worst, ``shield_applied (B, Σ k_i)`` one entry per actuated
        joint in agent order (the flat team action's layout but in circulation mode); per-copy keys as they are."""
        out: dict[str, np.ndarray] = {}
        for key, value in infos.items():
            rule = _team_rule(key)
            if rule == "flat":
                out[key] = value.reshape(self.copies, -1)[:, self._columns]
            elif rule is None:
                out[key] = value
            else:
                out[key] = _over_arms(rule, value)
        return out

    def team_info(self, infos: dict[str, np.ndarray], b: int = 0) -> dict[str, Any]:
        """Copy b's :meth:`team_infos` as Python values, for a one-copy view: the same numbers, without a
        numpy reduction per key where a Python one on a handful of arms is cheaper."""
        plan = self._team_plans.get(tuple(infos))
        if plan is None:
            plan = self._team_plans[tuple(infos)] = [(key, self._one_copy_rule(key, value)) for key, value in
                                                     infos.items()]
        return {key: gather(infos[key], b) for key, gather in plan}

    def _one_copy_rule(self, key: str, value: np.ndarray):
        """How :meth:`team_info` reads ``key`` of copy b (a function of the info's array and b), chosen once
        per key: the keys and their shapes stay the same from step to step."""
        rule = _team_rule(key)
        if rule is None:
            return np.ndarray.item  # value.item(b): a per-copy number, without an intermediate scalar
        if rule == "flat":
            if self._uniform_actions:
                return lambda v, b: v[b].reshape(-1)
            return lambda v, b: v[b].reshape(-1)[self._columns]
        if value.shape[1] == 1:  # one arm, or a term every arm shares: its own value
            return (lambda v, b: v[b, 0]) if value.ndim == 3 else (lambda v, b: v.item(b, 0))
        if key == "qp_counts":
            return lambda v, b: v[b].sum(axis=0)
        return lambda v, b: _gather(rule, v[b].tolist())

    def _shield_infos(self, rec: StepRecord | None, shape: tuple[int, int]) -> dict[str, np.ndarray]:
        """The filter's report of the step (the module docstring lists it)."""
        if rec is None:
            zero = np.zeros(shape, dtype=bool)
            return {"shield_intervened": zero, "shield_fallback": zero.copy(),
                    "shield_status": np.zeros(shape, dtype=np.int64), "shield_min_barrier": np.full(shape, np.inf),
                    "shield_applied": np.zeros((*shape, self.k_max), dtype=np.float32),
                    "qp_counts": np.zeros((*shape, 3), dtype=np.int64)}
        c = self.config
        if c.action_mode == "torque":  # the arm's actuated joints' torques in units of the bound
            source, columns, unit = rec.tau, self._actuated_joints[0], c.max_torque
        else:  # velocity, residual and gain modes: the filtered velocity in units of the largest speed
            source, columns, unit = rec.v_star, self._slots, c.max_joint_speed
        intervened, fallback = np.empty(shape, dtype=bool), np.empty(shape, dtype=bool)
        status, applied = np.empty(shape, dtype=np.int64), np.empty((*shape, self.k_max), dtype=np.float32)
        # the padding (NaN in the record) and a lost joint's entry read 0
        kernels().shield_report(rec.qp_counts, source, columns, self._padding, self.engine.faulted, 1.0 / unit,
                                intervened, fallback, status, applied)
        return {"shield_intervened": intervened, "shield_fallback": fallback, "shield_status": status,
                "shield_min_barrier": rec.min_barrier, "shield_applied": applied, "qp_counts": rec.qp_counts}

    def _infos(self, out, rec: StepRecord | None, copies: np.ndarray | None = None) -> dict[str, np.ndarray]:
        shape = out.cost.shape
        infos: dict[str, Any] = {"cost": out.cost, "min_clearance": out.measures["min_clearance"]}
        for name, value in out.terms.items():  # (B, N), or (B, 1) for a term every arm shares
            if np.ndim(value) < 2:  # a number for every copy and arm (the intervention term before any command)
                value = np.full((shape[0], 1), float(value))
            infos[f"reward_{name}"] = value if rec is not None else np.zeros_like(value, dtype=float)
        if self.engine.filter is not None:
            infos.update(self._shield_infos(rec, shape))
        if self.engine.faults:
            infos["actuator_lost"] = self.engine.faulted.copy() if copies is None else self.engine.faulted[copies]
        infos.update((key, value) for key, value in out.measures.items() if key != "min_clearance")
        infos["is_success"] = out.success
        return infos


# How the team views gather an info over the arms (an array reduction's name), None for a per-copy info:
# costs, QP counts and lost actuators add up, clearances and barriers take the smallest, a flag is any arm's,
# the status the worst, the applied commands are laid out as the team's flat action, a reward term is averaged
# as the team reward is.
_TEAM_RULES = {"cost": "sum", "qp_counts": "sum", "min_clearance": "min", "shield_min_barrier": "min",
               "shield_intervened": "any", "shield_fallback": "any", "shield_status": "max", "shield_applied": "flat",
               "actuator_lost": "sum"}


def _with_rows(array: np.ndarray, copies: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """A copy of ``array`` (every copy's) with the rows of ``copies`` replaced by ``rows`` (theirs, in their
    order)."""
    out = array.copy()
    out[copies] = rows
    return out


def _over_arms(rule: str, value: np.ndarray) -> np.ndarray:
    """numpy's ``value.<rule>(axis=1)``, bit for bit: in one compiled pass (kernels/outcome.py) for the core's own
    infos (float64, int64 and bool arrays of fewer than 8 arms: numpy sums pairwise from 8; int64 counts of any
    width), else numpy's own, as for a smallest value that is NaN or any other dtype."""
    if value.ndim == 3 and rule == "sum" and value.dtype == np.int64:
        out = np.empty((len(value), value.shape[2]), dtype=np.int64)
        kernels().arms_sum_columns(value, out)
        return out
    if value.ndim != 2 or value.shape[1] >= 8 or value.dtype not in _EXACT_DTYPES[rule]:
        return getattr(value, rule)(axis=1)
    dtype = np.float64 if rule == "mean" else (np.int_ if value.dtype == bool and rule == "sum" else value.dtype)
    out = np.empty(len(value), dtype=dtype)
    if rule == "min":
        return out if kernels().arms_min(value, out) else value.min(axis=1)
    getattr(kernels(), "arms_" + rule)(value, out)
    return out


# the dtypes each compiled reduction gives numpy's answer for (a float32 sum, say, numpy adds in float32; a float
# maximum would have to carry numpy's NaN rule, and the only maximum the core takes is of the integer status)
_EXACT_DTYPES = {"sum": (np.float64, np.int64, np.bool_), "mean": (np.float64,), "min": (np.float64, np.int64),
                 "max": (np.int64,), "any": (np.bool_,)}


def copy_generator(seed: int, copy: int) -> np.random.Generator:
    """Copy ``copy``'s generator in a batch seeded with the one int ``seed``: the stream numpy spawns as child
    ``copy`` of ``SeedSequence(seed)``. Children of different seeds, or of one seed, are independent streams,
    and none is a one-copy env's ``np_random(s)`` (a sequence with no spawn key): training copies never draw
    the held-out teams."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(copy,))))


def _team_rule(key: str) -> str | None:
    return _TEAM_RULES.get(key, "mean" if key.startswith("reward_") else None)


def per_arm(key: str) -> bool:
    """Whether an info of the core is per arm (``(B, N, …)``, or ``(B, 1)`` for a reward term every arm
    shares) rather than per copy (``(B,)``)."""
    return _team_rule(key) is not None


def _command_slots(arms: int, k_max: int) -> np.ndarray:
    """Each arm's command slots ``(N, k_max)``: where the filter's report reads an arm's v* in the record."""
    return np.tile(np.arange(k_max), (arms, 1))


def team_mean(row: list[float]) -> float:
    """The mean of a few arms' values, equal to numpy's (:func:`_gather`'s ``mean``)."""
    return _gather("mean", row)


def _numpy_sum(row: list) -> Any:
    """numpy's sum of a row: one value after another from 0 below 8 values (Python's ``sum`` compensates the
    rounding of floats from 3.12 on, so it is not used), pairwise from 8."""
    if len(row) >= 8:
        return float(np.add.reduce(row))
    total = 0
    for value in row:
        total += value
    return total


def _gather(rule: str, row: list) -> Any:
    """``rule`` over a few arms' Python values, equal to numpy's reduction of them (:func:`_numpy_sum`)."""
    if rule == "mean":
        return _numpy_sum(row) / len(row)
    if rule == "sum":
        return _numpy_sum(row)
    if rule == "min":  # NaN wins, as in numpy (a copy whose state went non-finite)
        return float("nan") if any(x != x for x in row) else min(row)
    return max(row) if rule == "max" else any(row)


class CoreView:
    """What every view of a :class:`FormationCore` (``self.core``) exposes besides its own API: the config
    (``env.config.max_steps``: every argument, validated, defaults resolved), the step's length ``env.dt``, the
    engine, task and layout, and the safety filter's switch."""

    core: FormationCore

    def __repr__(self) -> str:
        return view_repr(self)

    @property
    def config(self) -> FormationConfig | ReachConfig:
        return self.core.config

    @property
    def engine(self) -> Engine:
        return self.core.engine

    @property
    def task(self) -> FormationTask:
        return self.core.task

    @property
    def observation_layout(self) -> ObservationLayout:
        """Where each part of an agent's observation lies (:class:`~pan1_env.observation.ObservationLayout`)."""
        return self.core.layout

    @property
    def scenario(self):
        """Copy 0's team (for random scenarios, the team of its current episode)."""
        return self.core.engine.teams[0]

    @property
    def teams(self) -> list:
        """Every copy's team, in copy order (for random scenarios, the team of its current episode)."""
        return list(self.core.engine.teams)

    @property
    def n_links(self) -> list[int]:
        return self.core.n_links

    @property
    def n_actuated(self) -> list[int]:
        return self.core.n_actuated

    @property
    def obstacle_centers_now(self) -> np.ndarray:
        """Where every copy's obstacles are now, ``(B, O, 2)`` m (a copy: moving obstacles move each sub-step)."""
        return self.core.engine.centers.copy()

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step (the config's ``control_dt``), as Gymnasium's MuJoCo envs name it."""
        return self.core.config.control_dt

    @property
    def num_steps(self) -> int:
        """Steps since copy 0's reset."""
        return int(self.core.steps[0])

    @property
    def safety_filter(self):
        """The safety filter's parameters, or None when it is off."""
        return self.core.engine.filter

    def set_safety_filter(self, safety_filter) -> None:
        """Switch the RCBF-QP filter on (``True``: the scenario's κ, ε, margin; or a
        :class:`~pan1_env.safety.FilterParams`) or off (``False``), from the next physics sub-step.
        :class:`~pan1_env.wrappers.SafetyShield` calls this."""
        self.core.set_safety_filter(safety_filter)

    @property
    def last_step(self) -> StepRecord | None:
        """The engine's record of the last step (arrays ``(B, N, …)``); None after a reset."""
        return self.core.record

    @property
    def action_scale(self) -> float:
        return self.core.config.action_scale


def view_repr(view: Any) -> str:
    """A view's repr: its class, its scenario as given, copies, arms, whether the safety filter is on and the
    action mode. Views differ in the filter's default (off in the parallel, Gymnasium team and TorchRL envs; on in
    the vector, SB3 and reach envs and the BenchMARL task), so the repr says it."""
    c = view.core
    scenario = getattr(c.config, "arguments", {}).get("scenario", c.config.scenario)
    scenario = getattr(scenario, "name", scenario)  # a Scenario object by its name
    return (f"{type(view).__name__}({str(scenario)!r}, copies={c.copies}, arms={len(c.agents)}, "
            f"safety_filter={'on' if c.engine.filter is not None else 'off'}, "
            f"action_mode={getattr(c.config, 'action_mode', 'velocity')!r})")
