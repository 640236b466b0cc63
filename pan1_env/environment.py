"""The PettingZoo ``ParallelEnv``: spaces, local observations, rewards, cost, infos, seeding, render.

See :class:`Pan1ParallelEnv` for the full description. :func:`parallel_env` builds one,
:func:`env` gives PettingZoo's AEC view of it, and :data:`raw_env` is the class itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec

from .compiled import kernels
from .engine import Engine, FilterParams, StepRecord, filter_parameters
from .observation import OBS_BOUND, ObservationLayout
from .random_scenario import RandomScenarioOptions, random_scenario
from .registration import RENDER_FPS, RENDER_MODES
from .safety import QP_SOLVERS
from .scenario import Scenario, load
from .tasks import DEFAULT_GAIN_RANGE, FormationTask
from .validation import float_array, forwarded_signature, hints_unknown_keywords, positive_int, real, whole_ratio

__all__ = ["Pan1ParallelEnv", "parallel_env", "env", "raw_env", "ACTION_MODES"]

ACTION_MODES = ("velocity", "torque", "residual", "gain")
# Largest K_e · physics_dt accepted. RK4 on the tracker's error, ė = −K_e e, is stable up to 2.78;
# at 1.0 it still shrinks the error by 0.375 a step against the exact e⁻¹ = 0.368.
MAX_KE_DT = 1.0
DEFAULT_CONTROL_DT = 0.05  # s per env step
DEFAULT_PHYSICS_DT = 0.01  # s per RK4 sub-step: 5 sub-steps per env step, like Gymnasium's MuJoCo tasks


class Pan1ParallelEnv(ParallelEnv):
    """Multi-arm PAn−1 formation with obstacles, as a PettingZoo parallel environment.

    ## Description

    N planar arms (agents ``arm_0`` … ``arm_{N−1}``, numbered from 0; the paper numbers from 1)
    with n links each. A PA arm's first joint is passive (no motor), the others are actuated; a
    fully actuated arm drives every joint. The arms must bring their end-effectors into a rigid
    formation (distances d_k on the edges of an infinitesimally rigid graph) without any
    end-effector entering a disk obstacle. The dynamics are the paper's (no gravity, RK4 with a
    ``physics_dt`` step); a PA arm started at rest keeps zero passive momentum, so its passive joint
    follows its active ones (the cascaded model).

    ## Action Space

    ``Box(-1, 1, (k,), float32)`` per agent, k = n − 1 for a PA arm and n for a fully actuated one.
    Values outside [−1, 1] are clipped; NaN/inf, a wrong shape or a non-numeric action (a dict, a
    string) raise ``ValueError``.

    * ``action_mode="velocity"`` (default): the desired active-joint velocity
      v = a · ``max_joint_speed`` (rad/s), held for the control step and tracked inside the env by
      the paper's backstepping law (Eq. 64) at every physics sub-step.
    * ``action_mode="torque"``: the active-joint torque τ_a = a · ``max_torque`` (N·m), held.
    * ``action_mode="residual"``: a correction to the paper's distributed law (Eq. 39),
      v = clip(v_0 + a · ``max_joint_speed``, ±``max_joint_speed``), tracked as in velocity mode;
      v_0 = −K_P J̄ᵀ ê computed from the true state at the step's start and scaled down as a whole
      to ``max_joint_speed`` (as :class:`pan1_env.baselines.ReferencePolicy` does). The zero action
      is the reference controller (behind the safety filter, the paper's safe controller); the
      effort term penalises the correction only. With ``residual_gate=g`` (m, > 0) arm i's
      correction is scaled by min(1, (e_i/g)²), e_i the largest length error of its edges, so it
      vanishes at the formation and the formed shape stays an equilibrium. With ``blocked_gate=c``
      (> 0) it is also scaled by min(1, b_i/c), b_i how much the safety filter changed the arm's
      previous command (the intervention term's measure, 0 at a reset): the correction acts only
      where the filter holds the paper's law back.
    * ``action_mode="gain"``: a re-weighting of the paper's law: joint j's term of v_0 is multiplied
      by ``gain_range`` ** a_j (default 4, so gains from 1/4 to 4) before the vector is scaled down
      as a whole to ``max_joint_speed``. The zero action is the reference controller; any action
      keeps the command from ever ascending V (a positive diagonal re-weighting of −K_P J̄ᵀ ê, before
      the filter and with the velocity tracked exactly) and the formed shape an equilibrium: unlike a
      residual, a gain cannot point against the law. The effort term penalises the log-gains a.

    ## Observation Space

    ``Box(-inf, inf, (3n + 2 + 4D + 5K,), float32)`` per agent (``+ 2K`` with moving obstacles), *local* to
    the agent:

    | slice | content |
    |---|---|
    | ``[0, n)`` | cos q (own joint angles) |
    | ``[n, 2n)`` | sin q |
    | ``[2n, 3n)`` | q̇ / ``max_joint_speed`` |
    | ``[3n, 3n+2)`` | own end-effector relative to own base, p − p0 (m) |
    | next ``4D`` | D neighbour slots ``[present, dx, dy, err]`` |
    | next ``5K`` | K obstacle slots ``[present, dx, dy, r, h]`` |
    | last ``2K`` | only with moving obstacles: the same slots' obstacle velocities ``[vx, vy]`` (m/s) |

    D is the formation graph's largest degree (N − 1 for random scenarios); for neighbour j,
    (dx, dy) = p_j − p_i and err = ‖p_j − p_i‖ − d_ij (m). The K obstacles are the nearest by
    clearance; for obstacle o, (dx, dy) = o − p_i, r its radius and h = ‖p_i − o‖² − r² the barrier
    value. Absent slots are zeros. Entries other than cos, sin and flags are clipped to ±1e6.

    Neighbours appear in the order of the formation's edges. This is everything the paper's
    distributed controller needs besides the arm's own parameters (see
    :class:`pan1_env.baselines.ReferencePolicy`). ``state()`` returns the global state: for every
    arm q and q̇ (padded with zeros to the largest n) and p, then every obstacle's centre (where it is
    now) and radius.

    Arms with different n have different spaces. For parameter sharing pad them to one size, e.g.
    with SuperSuit: ``supersuit.pad_observations_v0(env)`` and ``supersuit.pad_action_space_v0(env)``.

    ## Rewards

    Every agent receives the shared formation term plus its own optional terms:
    ``r_i = −formation_weight · mean_k |‖z_k‖ − d_k| − effort_weight · ‖a_i‖² / k
    − collision_penalty · cost_i + success_bonus · success
    − intervention_penalty · ‖(v_i − v*_i) / max_joint_speed‖² / k`` (the mean edge-length error in
    metres, the squared normalised action, the cost below, 1 in a step that ends with every edge
    within ``success_tolerance``, and how much the safety filter changed the arm's commanded
    velocity v_i at the step's last sub-step; velocity and residual modes). Defaults: 1, 0, 0, 0, 0.
    The last two are shaping for learners: the formation term alone rewards the last centimetre
    little, and the intervention term tells a policy at once when the filter holds its arm back.

    ## Cost

    ``infos[agent]["cost"]`` is 1.0 in a step where that arm's end-effector was inside an obstacle
    (clearance < 0) after any physics sub-step, else 0.0 (the safety-gymnasium convention).

    ## Infos

    Per agent: ``cost``, ``min_clearance`` (m, smallest over the step's sub-steps and obstacles),
    ``formation_error`` (m, max over edges of |‖z_k‖ − d_k|), ``is_success`` (formation error below
    ``success_tolerance``), ``reward_terms`` (the reward's weighted terms, which sum to it:
    ``formation``, and ``effort`` and ``collision`` when their weights are not zero; after a step),
    ``qp_counts`` when a safety filter is on, and ``fault`` (a string) if the episode was truncated by a
    numerical fault.

    ## Starting State

    The paper scenarios start at rest at the paper's configurations. ``scenario="random"`` draws a
    new team (parameters, bases, starting configurations at rest, obstacles, formation placement)
    on every ``reset`` from the seeded generator, each start collision-free, regular and with the
    formation reachable (:mod:`pan1_env.random_scenario`); the team's structure (links and passive
    joints per arm) is fixed by ``random_options``.

    ## Episode End

    Truncation after ``max_steps`` steps (default: the scenario's horizon / ``control_dt``: 2000
    steps of 0.05 s for the paper scenarios, enough for the reference controller to form the
    square) or when the state becomes non-finite (``infos[agent]["fault"]``). Termination (all
    agents at once) on a collision with ``terminate_on_collision=True`` and on success with
    ``terminate_on_success=True``; both default to False.

    ## Arguments

    * ``scenario``: a built-in name (``"paper_pa3_square"``, ``"paper_pa_mixed_square"``), a path
      to a TOML file, a :class:`~pan1_env.scenario.Scenario`, or ``"random"``.
    * ``action_mode``: ``"velocity"``, ``"torque"``, ``"residual"`` or ``"gain"``.
    * ``control_dt``: seconds per env step (default 0.05); a whole multiple of ``physics_dt``.
    * ``physics_dt``: RK4 step in seconds. Default in velocity mode 0.01 (5 sub-steps per control
      step, as in Gymnasium's MuJoCo tasks), in torque mode 0.002 (open-loop torques can spin the
      light links to hundreds of rad/s); or the next shorter of 5, 2, 1 ms that divides
      ``control_dt`` and keeps K_e·``physics_dt`` ≤ 1 for the scenario's tracker gain (else
      ValueError: pass ``physics_dt``). The env's time steps come from these two arguments only;
      the scenario's ``[simulation]`` table sets those of ``pan1-env reproduce`` (the paper's runs
      use 1 ms: pass ``physics_dt=scenario.physics_dt`` to match). The safety filter is re-solved
      at every sub-step either way.
    * ``max_steps``: steps before truncation.
    * ``render_mode``: ``None``, ``"rgb_array"`` or ``"human"``.
    * ``terminate_on_collision``, ``terminate_on_success``, ``success_tolerance`` (m, default 0.01).
    * ``formation_weight``, ``effort_weight``, ``collision_penalty``, ``success_bonus``,
      ``intervention_penalty``: reward weights.
    * ``residual_gate``, ``blocked_gate``: see ``action_mode="residual"`` (default 0: no gate; other
      modes refuse them).
    * ``gain_range``: see ``action_mode="gain"`` (> 1, default 4).
    * ``max_joint_speed`` (rad/s, default 2.0), ``max_torque`` (N·m, default 5.0): action scales.
    * ``n_obstacle_obs``: K, obstacle slots per observation (default: 3).
    * ``random_options``: a :class:`~pan1_env.random_scenario.RandomScenarioOptions` or a dict of
      its fields, for ``scenario="random"``.
    * ``qp_solver``: the safety filter's QP solver when shielded: ``"active_set"`` (exact, compiled,
      default) or ``"piqp"`` (qpsolvers + PIQP, velocity mode only; much slower).
    * ``safety_filter``: the paper's RCBF-QP filter inside every physics sub-step: ``False``
      (default), ``True`` (the scenario's κ, ε, margin) or a :class:`~pan1_env.engine.FilterParams`.
      :class:`~pan1_env.wrappers.SafetyShield` switches it on through :meth:`set_safety_filter` and
      adds per-agent reports; :attr:`last_step` is the engine's record of the last step.

    ## Version History

    * v0: initial release.
    """

    metadata = {
        "name": "pan1_env_v0",
        "render_modes": RENDER_MODES,
        "render_fps": RENDER_FPS,
        "is_parallelizable": True,
    }

    @hints_unknown_keywords
    def __init__(
        self,
        scenario: str | Path | Scenario = "paper_pa3_square",
        *,
        action_mode: str = "velocity",
        control_dt: float = DEFAULT_CONTROL_DT,
        physics_dt: float | None = None,
        max_steps: int | None = None,
        render_mode: str | None = None,
        terminate_on_collision: bool = False,
        terminate_on_success: bool = False,
        success_tolerance: float = 0.01,
        formation_weight: float = 1.0,
        effort_weight: float = 0.0,
        collision_penalty: float = 0.0,
        success_bonus: float = 0.0,
        residual_gate: float = 0.0,
        intervention_penalty: float = 0.0,
        blocked_gate: float = 0.0,
        gain_range: float = DEFAULT_GAIN_RANGE,
        max_joint_speed: float = 2.0,
        max_torque: float = 5.0,
        n_obstacle_obs: int = 3,
        random_options: RandomScenarioOptions | Mapping[str, Any] | None = None,
        qp_solver: str = "active_set",
        safety_filter: bool | FilterParams = False,
    ) -> None:
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        control_dt = real("control_dt", control_dt, positive=True)
        success_tolerance = real("success_tolerance", success_tolerance, positive=True)
        max_joint_speed = real("max_joint_speed", max_joint_speed, positive=True)
        max_torque = real("max_torque", max_torque, positive=True)
        formation_weight = real("formation_weight", formation_weight)
        effort_weight = real("effort_weight", effort_weight)
        collision_penalty = real("collision_penalty", collision_penalty)
        success_bonus = real("success_bonus", success_bonus)
        residual_gate = real("residual_gate", residual_gate, non_negative=True)
        intervention_penalty = real("intervention_penalty", intervention_penalty)
        blocked_gate = real("blocked_gate", blocked_gate, non_negative=True)
        gain_range = real("gain_range", gain_range)
        if gain_range <= 1.0:
            raise ValueError(f"gain_range must be > 1 (gains from 1/gain_range to gain_range), got {gain_range}")
        if action_mode != "residual" and (residual_gate > 0 or blocked_gate > 0):
            raise ValueError(f"residual_gate and blocked_gate scale a residual correction: they need "
                             f"action_mode='residual', got action_mode={action_mode!r}")
        n_obstacle_obs = positive_int("n_obstacle_obs", n_obstacle_obs, minimum=0)
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"qp_solver must be one of {QP_SOLVERS}, got {qp_solver!r}")

        self._random = isinstance(scenario, str) and scenario == "random"
        if self._random:
            if isinstance(random_options, Mapping):
                unknown = sorted(set(random_options) - set(RandomScenarioOptions.__dataclass_fields__))
                if unknown:
                    raise ValueError(f"random_options: unknown option {unknown[0]!r}; options are "
                                     f"{sorted(RandomScenarioOptions.__dataclass_fields__)}")
                random_options = RandomScenarioOptions(**random_options)
            elif random_options is not None and not isinstance(random_options, RandomScenarioOptions):
                raise ValueError(f"random_options must be a dict or RandomScenarioOptions, got {random_options!r}")
            self.random_options = random_options or RandomScenarioOptions()
            template = random_scenario(np.random.default_rng(0), self.random_options)
        else:
            if random_options is not None:
                raise ValueError("random_options is only for scenario='random'")
            template = load(scenario)
        if physics_dt is None:
            physics_dt = default_physics_dt(control_dt, template.ke, action_mode)
        physics_dt = real("physics_dt", physics_dt, positive=True)
        if template.ke * physics_dt > MAX_KE_DT:
            raise ValueError(f"physics_dt={physics_dt} is too long for the tracker gain K_e={template.ke}: "
                             f"K_e·physics_dt must be ≤ {MAX_KE_DT} for the backstepping loop to stay stable")
        self.substeps = whole_ratio("control_dt", control_dt, "physics_dt", physics_dt)
        self.physics_dt = physics_dt
        self.control_dt = control_dt
        if max_steps is None:
            max_steps = int(np.ceil(template.horizon / self.control_dt - 1e-9))
        self.max_steps = positive_int("max_steps", max_steps)
        self.qp_solver = qp_solver
        self.action_mode = action_mode
        self._torque_mode = action_mode == "torque"
        # an action of 1 in physical units; a gain action is an exponent, used as it is
        scales = {"torque": max_torque, "gain": 1.0}
        self._action_scale = float(scales.get(action_mode, max_joint_speed))
        self.render_mode = render_mode
        self.terminate_on_collision = bool(terminate_on_collision)
        self.terminate_on_success = bool(terminate_on_success)
        self.success_tolerance = float(success_tolerance)
        self.formation_weight = float(formation_weight)
        self.effort_weight = float(effort_weight)
        self.collision_penalty = float(collision_penalty)
        self.success_bonus = float(success_bonus)
        self.residual_gate = float(residual_gate)
        self.intervention_penalty = float(intervention_penalty)
        self.blocked_gate = float(blocked_gate)
        self.gain_range = float(gain_range)
        self.max_joint_speed = float(max_joint_speed)
        self.max_torque = float(max_torque)
        self.n_obstacle_obs = int(n_obstacle_obs)

        self.possible_agents = [f"arm_{i}" for i in range(template.n_arms)]
        self.agents: list[str] = []
        self.n_links = [a.n_links for a in template.arms]
        self.n_actuated = [a.n_actuated for a in template.arms]
        self._k_array = np.array(self.n_actuated)
        self._command_shape = (1, template.n_arms, max(self.n_actuated))
        self._uniform_k = len(set(self.n_actuated)) == 1
        degrees = np.bincount(template.formation.edges.ravel(), minlength=template.n_arms)
        slots = template.n_arms - 1 if self._random else int(degrees.max())
        self._layout = ObservationLayout.from_scenario(template, slots, self.n_obstacle_obs)
        self.observation_spaces = {
            agent: gymnasium.spaces.Box(*self._layout.bounds(self.n_links[i]), dtype=np.float32)
            for i, agent in enumerate(self.possible_agents)
        }
        self.action_spaces = {
            agent: gymnasium.spaces.Box(-1.0, 1.0, (self.n_actuated[i],), np.float32)
            for i, agent in enumerate(self.possible_agents)
        }
        state_size = template.n_arms * (2 * max(self.n_links) + 2) + 3 * len(template.obstacles)
        self.state_space = gymnasium.spaces.Box(-OBS_BOUND, OBS_BOUND, (state_size,), np.float32)
        self.engine = Engine(template, 1, physics_dt=physics_dt, safety_filter=safety_filter,
                             max_speed=self.max_joint_speed, qp_solver=qp_solver)
        self.scenario = template
        self.task = FormationTask.of_env(self, 1)
        self._record: StepRecord | None = None
        # (agent, layout group, row in the group) in agent order: where each observation comes from
        rows = sorted((i, g, r) for g, (_, ids) in enumerate(self._layout.groups) for r, i in enumerate(ids.tolist()))
        self._observation_rows = [(self.possible_agents[i], g, r) for i, g, r in rows]
        self.np_random, self.np_random_seed = gymnasium.utils.seeding.np_random(None)
        self._renderer = None
        self._needs_reset = True

    # ----------------------------------------------------------------- spaces
    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        return self.action_spaces[agent]

    @property
    def observation_layout(self) -> ObservationLayout:
        """The agents' observation layout (read-only; fixed by the team's structure): its
        :meth:`~pan1_env.observation.ObservationLayout.segments` say where each part of an agent's
        observation lies, ``slots`` is D and ``n_obstacle_obs`` K. Public, so wrappers forward it
        (:func:`pan1_env.baselines.decode_observation` reads observations with it)."""
        return self._layout

    # ---------------------------------------------------------- safety filter
    @property
    def safety_filter(self) -> FilterParams | None:
        """The safety filter's parameters, or None when it is off."""
        return self.engine.filter

    def set_safety_filter(self, safety_filter: bool | FilterParams) -> None:
        """Switch the RCBF-QP filter on (``True``: the scenario's κ, ε, margin; or a
        :class:`~pan1_env.engine.FilterParams`) or off (``False``), from the next physics sub-step.
        :class:`~pan1_env.wrappers.SafetyShield` calls this."""
        if self.qp_solver == "piqp" and self.action_mode == "torque" and safety_filter is not False:
            raise ValueError("the torque-mode filter needs qp_solver='active_set'")
        self.engine.set_safety_filter(filter_parameters(safety_filter, self.scenario))

    @property
    def last_step(self) -> StepRecord | None:
        """The engine's record of the last step (arrays ``(1, N, …)``: one copy; None after a reset)."""
        return self._record

    @property
    def action_scale(self) -> float:
        """Physical units of an action of 1: ``max_joint_speed`` (rad/s), ``max_torque`` (N·m), or 1
        (``action_mode="gain"``: the action is the exponent of the gain)."""
        return self._action_scale

    # ------------------------------------------------------------------ state
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Every arm's joint angles and velocities ``(N, n_max)`` (float64 copies, NaN padding)."""
        q, qd = self.engine.joint_state()
        return q[0].copy(), qd[0].copy()

    def end_effectors(self) -> np.ndarray:
        """Every arm's end-effector ``(N, 2)`` (a float64 copy)."""
        return self.engine.positions()[0].copy()

    @property
    def sim(self):
        """Removed in 0.2 (it was never documented): a clear error instead of an unknown attribute."""
        raise AttributeError("Pan1ParallelEnv.sim was removed: use env.joint_state(), env.end_effectors(), "
                             "env.last_step or env.engine (B = 1 copy of the team)")

    # ------------------------------------------------------------------- API
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.np_random, self.np_random_seed = gymnasium.utils.seeding.np_random(seed)
        if self._random:
            self.scenario = random_scenario(self.np_random, self.random_options)
            self.engine.load_team(0, self.scenario)
            self.task.load_team(0, self.scenario)
        self.engine.reset()
        self.agents = list(self.possible_agents)
        self.num_steps = 0
        self._needs_reset = False
        self._record = None
        err, obs = self._observations()
        max_err = float(np.max(np.abs(err)))
        clear = self.engine.clearance()[0]
        infos = {agent: self._info(0.0, clear[i], max_err) for i, agent in enumerate(self.agents)}
        if self.render_mode == "human":
            self.render()
        return obs, infos

    def step(self, actions: Mapping[str, np.ndarray]):
        if self._needs_reset or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        command, effort = self._command(actions)
        rec = self.engine.step(command, self.substeps, torque=self._torque_mode)
        self.num_steps += 1
        err, obs = self._observations()
        out = self.task.evaluate(rec, err, effort[None], command=None if self._torque_mode else command)
        self._record = rec
        max_err = float(out.measures["formation_error"][0])
        success = bool(out.success[0])
        fault = None if rec.all_finite else "non-finite state in the physics step; episode truncated"
        terminated = bool(out.terminated[0])
        truncated = self.num_steps >= self.max_steps or fault is not None
        rewards = dict(zip(self.possible_agents, out.reward[0].tolist(), strict=True))
        infos = {}  # every arm is live in a step (agents leave together), so team index = position
        filtered = self.engine.filter is not None
        n_agents = len(self.possible_agents)  # per-agent rows of the terms (a shared term has one column)
        terms = {name: row if len(row) == n_agents else row * n_agents
                 for name, row in ((name, value[0].tolist()) for name, value in out.terms.items())}
        for i, (agent, cost, clear) in enumerate(zip(self.possible_agents, out.cost[0].tolist(),
                                                     rec.min_clearance[0].tolist(), strict=True)):
            info = {"cost": cost, "min_clearance": clear, "formation_error": max_err, "is_success": success,
                    "reward_terms": {name: value[i] for name, value in terms.items()}}
            if filtered:
                info["qp_counts"] = rec.qp_counts[0, i]
            if fault:
                info["fault"] = fault
            infos[agent] = info
        terminations = dict.fromkeys(self.agents, terminated)
        truncations = dict.fromkeys(self.agents, truncated)
        if terminated or truncated:
            self.agents = []
            self._needs_reset = True
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        q, qd = self.engine.joint_state(pad=0.0)
        q, qd, P = np.nan_to_num(q[0], nan=0.0), np.nan_to_num(qd[0], nan=0.0), self.engine.positions()[0]
        parts = [np.concatenate([q[i], qd[i], P[i]]) for i in range(self.scenario.n_arms)]
        obs = self.scenario.obstacles  # centres where they are now (moving obstacles)
        parts.append(np.concatenate([self.engine.centers[0], obs.radii[:, None]], axis=1).ravel())
        return np.clip(np.concatenate(parts), -OBS_BOUND, OBS_BOUND).astype(np.float32)

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

    # ------------------------------------------------------------- internals
    def _command(self, actions: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The padded physical command ``(N, k_max)`` and each agent's effort ‖clip(a)‖² / k."""
        if type(actions) is not dict and not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict keyed by agent, got {type(actions).__name__}")
        if len(actions) != len(self.agents) or set(actions) != set(self.agents):
            missing = sorted(set(self.agents) - set(actions))
            extra = sorted(set(actions) - set(self.agents))
            raise ValueError(f"actions must have one entry per live agent; missing {missing}, unexpected {extra}")
        command = None
        if self._uniform_k:  # one array call when every agent has the same action size
            try:
                command = np.array([[actions[a] for a in self.possible_agents]], dtype=float)
            except (ValueError, TypeError):
                command = None
            if command is not None and command.shape != self._command_shape:
                command = None
        if command is None:  # mixed sizes, or a bad action: per agent, with a specific error
            command = np.zeros(self._command_shape)
            for i, agent in enumerate(self.possible_agents):
                command[0, i, : self.n_actuated[i]] = float_array(f"action for {agent}", actions[agent],
                                                                  (self.n_actuated[i],))
        effort = np.empty(command.shape[1])
        bad = kernels().scale_command(command[0], self._k_array, self._action_scale, effort)  # clip, effort, scale
        if bad >= 0:
            agent = self.possible_agents[bad]
            raise ValueError(f"action for {agent} contains NaN or inf: {np.asarray(actions[agent]).tolist()}")
        self.task.compose(self.action_mode, command, self.engine)
        return command, effort

    def _info(self, cost: float, min_clearance: float, max_err: float) -> dict[str, Any]:
        return {
            "cost": float(cost),
            "min_clearance": float(min_clearance),
            "formation_error": max_err,
            "is_success": bool(max_err < self.success_tolerance),
        }

    def _observations(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The edges' length errors ‖z_k‖ − d_k ``(1, E)`` and every live agent's observation."""
        err, mats = self.task.observe(self.engine)
        out = {agent: mats[group][0, row] for agent, group, row in self._observation_rows}
        if len(out) != len(self.agents):
            out = {a: out[a] for a in self.agents}
        return err, out


def default_physics_dt(control_dt: float, ke: float, action_mode: str = "velocity") -> float:
    """The env's default RK4 step: the longest candidate that divides ``control_dt`` and keeps
    K_e·dt ≤ :data:`MAX_KE_DT`.

    Candidates: 10, 5, 2, 1 ms in velocity mode, where the tracker holds speeds near the command;
    2, 1 ms in torque mode, where open-loop torques can spin light links to hundreds of rad/s and a
    10 ms RK4 step diverges. The envs' time steps come from their arguments only; a scenario's
    ``[simulation]`` table sets the steps of ``pan1-env reproduce`` (docs/ARCHITECTURE.md).
    """
    candidates = (0.002, 0.001) if action_mode == "torque" else (DEFAULT_PHYSICS_DT, 0.005, 0.002, 0.001)
    for dt in candidates:
        ratio = control_dt / dt
        if ke * dt <= MAX_KE_DT and round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-6:  # as whole_ratio
            return dt
    raise ValueError(f"no default physics_dt ({', '.join(f'{dt * 1e3:g} ms' for dt in candidates)}) divides "
                     f"control_dt={control_dt} with K_e·dt ≤ {MAX_KE_DT} (K_e = {ke}); pass physics_dt")


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
