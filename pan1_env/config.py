"""The formation envs' arguments, validated once: :class:`FormationConfig`.

Every view of the formation env (PettingZoo parallel and AEC, the Gymnasium env of ``gymnasium.make``,
the vector env, SB3's VecEnv) takes the same arguments; they are checked here, once, and the env core
(:mod:`pan1_env.core`), the task and the engine read them from the config. A config is frozen: a
different setting is a new config, :meth:`FormationConfig.replace` (which resolves the defaults again, where
:func:`dataclasses.replace` would keep the resolved ones).
"""

from __future__ import annotations

import dataclasses
import inspect
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .control import MAX_JOINT_SPEED
from .engine import Physics
from .env_ids import DEFAULT_REACH_STEPS, env_arguments
from .formation import most_neighbours
from .random_scenario import RandomScenarioOptions
from .safety import QP_SOLVERS, FilterParams, filter_parameters
from .scenario import Scenario, load
from .team_draw import draw_teams
from .validation import positive_int, real, refuse_unknown, whole_ratio

__all__ = ["FormationConfig", "ReachConfig", "config_arguments", "ACTION_MODES", "DEFAULT_CONTROL_DT",
           "DEFAULT_GAIN_RANGE", "MAX_KE_DT", "default_physics_dt", "SUCCESS_TOLERANCE", "MODE_SETTINGS"]

ACTION_MODES = ("velocity", "torque", "residual", "gain", "circulation")
DEFAULT_CONTROL_DT = 0.05  # s per env step
DEFAULT_PHYSICS_DT = 0.01  # s per RK4 sub-step: 5 sub-steps per env step, like Gymnasium's MuJoCo tasks
DEFAULT_GAIN_RANGE = 4.0  # action_mode="gain": gains from 1/4 to 4
# action_mode="circulation": the rule's own term at an action of 1, acting within 10 cm of an obstacle (the rule's
# defaults, baselines/circulation.py)
DEFAULT_CIRCULATION = {"circulation_gain": 1.0, "circulation_activation": 0.1}
#: the settings that give an action mode's actions their meaning: recorded with a model trained in the mode, and
#: compared with the env's when it runs there
MODE_SETTINGS = {"gain": ("gain_range",), "circulation": ("gain_range", *DEFAULT_CIRCULATION)}
SUCCESS_TOLERANCE = 0.01  # m: the team is formed when every edge is this close to its length
# Largest K_e · physics_dt accepted. RK4 on the tracker's error, ė = −K_e e, is stable up to 2.78;
# at 1.0 it still shrinks the error by 0.375 a step against the exact e⁻¹ = 0.368.
MAX_KE_DT = 1.0


def default_physics_dt(control_dt: float, ke: float, action_mode: str = "velocity") -> float:
    """The env's default RK4 step: the longest candidate that divides ``control_dt`` and keeps
    K_e·dt ≤ :data:`MAX_KE_DT`.

    Candidates: 10, 5, 2, 1 ms in velocity mode, where the tracker holds speeds near the command;
    2, 1 ms in torque mode, where open-loop torques can spin light links to hundreds of rad/s and a
    10 ms RK4 step diverges. A scenario's ``[simulation]`` table sets the steps of ``pan1-env
    reproduce`` only.
    """
    candidates = (0.002, 0.001) if action_mode == "torque" else (DEFAULT_PHYSICS_DT, 0.005, 0.002, 0.001)
    for dt in candidates:
        ratio = control_dt / dt
        if ke * dt <= MAX_KE_DT and round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-6:  # as whole_ratio
            return dt
    raise ValueError(f"no default physics_dt ({', '.join(f'{dt * 1e3:g} ms' for dt in candidates)}) divides "
                     f"control_dt={control_dt} with K_e·dt ≤ {MAX_KE_DT} (K_e = {ke}); pass physics_dt")


def _refuse_team_time_steps(options: RandomScenarioOptions) -> None:
    """An env steps at its own ``control_dt`` and ``physics_dt``: the drawn team's own time steps (the options' fields,
    for :func:`pan1_env.random_scenario.random_scenario` outside an env) would be ignored, so other values are
    refused."""
    defaults = RandomScenarioOptions()
    for name in ("control_dt", "physics_dt"):
        if getattr(options, name) != getattr(defaults, name):
            raise ValueError(f"random_options {name}={getattr(options, name)!r}: an env steps at its own {name}; pass "
                             f"{name}= to the env (random_options' time steps are a Scenario's drawn outside an env)")


def physics_of(config: FormationConfig | ReachConfig) -> Physics:
    """A config's :class:`~pan1_env.engine.Physics`: its ``physics_dt``, ``max_joint_speed`` and ``qp_solver``, and
    ``max_torque`` as the bound on the filter's own torques where ``torque_bound`` asks for it (else none)."""
    return Physics(config.physics_dt, config.max_joint_speed, config.max_torque if config.torque_bound else np.inf,
                   config.qp_solver)


def _time_steps(config, put: Callable[[str, Any], None], ke: float, action_mode: str) -> None:
    """A config's ``physics_dt`` (default: :func:`default_physics_dt`), checked against the tracker gain, and
    ``substeps`` (``control_dt`` must be a whole multiple of it)."""
    dt = default_physics_dt(config.control_dt, ke, action_mode) if config.physics_dt is None else config.physics_dt
    put("physics_dt", real("physics_dt", dt, positive=True))
    if ke * config.physics_dt > MAX_KE_DT:
        raise ValueError(f"physics_dt={config.physics_dt} is too long for the tracker gain K_e={ke}: "
                         f"K_e·physics_dt must be ≤ {MAX_KE_DT} for the backstepping loop to stay stable")
    put("substeps", whole_ratio("control_dt", config.control_dt, "physics_dt", config.physics_dt))


@dataclass(frozen=True, eq=False)
class FormationConfig:
    """Every argument of the formation env, validated once (``ValueError`` naming the argument).

    * ``scenario``: a built-in name (``"paper_pa3_square"``, ``"paper_pa_mixed_square"``), a path to a
      TOML file, a :class:`~pan1_env.scenario.Scenario`, ``"random"``, or a registered Gymnasium id
      (``"pan1_env/WholeArmStaticFormation-v0"``, with or without ``pan1_env:``), which stands for its
      scenario and options (``random_options`` given here are merged over the id's, key by key).
    * ``action_mode``: ``"velocity"``, ``"torque"``, ``"residual"``, ``"gain"`` or ``"circulation"``
      (docs/ENVIRONMENTS.md).
    * ``control_dt``: seconds per env step (default 0.05); a whole multiple of ``physics_dt``.
    * ``physics_dt``: RK4 step in seconds. Default: :func:`default_physics_dt` (10 ms in velocity mode,
      2 ms in torque mode, or the next shorter step that divides ``control_dt`` and keeps K_e·dt ≤ 1).
    * ``max_steps``: steps before truncation (default: the scenario's horizon / ``control_dt``).
    * ``terminate_on_collision``, ``terminate_on_success``, ``success_tolerance`` (m, default 0.01).
    * ``success_hold`` (s, default 0): success needs the formation error below ``success_tolerance`` for this
      long without a break (a moving formation's tracking criterion, docs/ENVIRONMENTS.md).
    * ``formation_weight``, ``effort_weight``, ``collision_penalty``, ``success_bonus``,
      ``intervention_penalty``: reward weights (defaults 1, 0, 0, 0, 0).
    * ``residual_gate``, ``blocked_gate``: gates of the residual correction (``action_mode="residual"``
      only; default 0, no gate).
    * ``gain_range``: ``action_mode="gain"`` or ``"circulation"``: gains from 1/``gain_range`` to ``gain_range`` (> 1,
      default 4).
    * ``circulation_gain``, ``circulation_activation``: ``action_mode="circulation"``: the circulation term at an
      action of ±1 (> 0, default 1: the law's speed into an obstacle becomes as fast a turn round it), and how near
      an obstacle (m, > 0, default 0.1) a body point must be for it to act.
    * ``max_joint_speed`` (rad/s, default 2), ``max_torque`` (N·m, default 5): what an action of 1 means.
    * ``torque_bound``: in torque mode behind the filter, keep its torques within ``max_torque`` too, as a
      constraint of its QP (docs/MODEL.md §5d). Default False: the filter reaches its answer in one sub-step
      whatever the torque, as the recorded torque-mode runs did.
    * ``n_obstacle_obs``: K, obstacle slots per observation (default 3).
    * ``random_options``: a :class:`~pan1_env.random_scenario.RandomScenarioOptions` or a dict of its
      fields, for ``scenario="random"``.
    * ``qp_solver``: ``"active_set"`` (exact, compiled, default) or ``"piqp"`` (qpsolvers + PIQP, one copy,
      velocity mode; slow, for cross-checks).
    * ``safety_filter``: the RCBF-QP filter in every physics sub-step: ``False``, ``True`` (the scenario's
      κ, ε, margin) or a :class:`~pan1_env.safety.FilterParams`. Stored resolved (None when off).

    Derived: ``team`` (the scenario, or the random generator's first team, which fixes the spaces),
    ``random`` (a new team every reset), ``substeps`` (physics sub-steps per env step), ``action_scale``.
    """

    scenario: str | Path | Scenario = "paper_pa3_square"
    action_mode: str = "velocity"
    control_dt: float = DEFAULT_CONTROL_DT
    physics_dt: float | None = None
    max_steps: int | None = None
    terminate_on_collision: bool = False
    terminate_on_success: bool = False
    success_tolerance: float = SUCCESS_TOLERANCE
    success_hold: float = 0.0
    formation_weight: float = 1.0
    effort_weight: float = 0.0
    collision_penalty: float = 0.0
    success_bonus: float = 0.0
    residual_gate: float = 0.0
    intervention_penalty: float = 0.0
    blocked_gate: float = 0.0
    gain_range: float = DEFAULT_GAIN_RANGE
    circulation_gain: float = DEFAULT_CIRCULATION["circulation_gain"]
    circulation_activation: float = DEFAULT_CIRCULATION["circulation_activation"]
    max_joint_speed: float = MAX_JOINT_SPEED
    max_torque: float = 5.0
    torque_bound: bool = False
    n_obstacle_obs: int = 3
    random_options: RandomScenarioOptions | Mapping[str, Any] | None = None
    qp_solver: str = "active_set"
    safety_filter: bool | FilterParams | None = False
    team: Scenario = field(init=False, repr=False)
    random: bool = field(init=False, repr=False)
    substeps: int = field(init=False, repr=False)
    arguments: dict = field(init=False, repr=False)  # as given, before defaults were resolved: for replace()

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        put("arguments", {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init})
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        for name in ("control_dt", "success_tolerance", "max_joint_speed", "max_torque"):
            put(name, real(name, getattr(self, name), positive=True))
        if not isinstance(self.torque_bound, (bool, np.bool_)):
            raise ValueError(f"torque_bound must be True or False, got {self.torque_bound!r}")
        if self.torque_bound and self.action_mode != "torque":
            raise ValueError(f"torque_bound=True bounds the filter's torques in action_mode='torque' only, got "
                             f"action_mode={self.action_mode!r}")
        for name in ("formation_weight", "effort_weight", "collision_penalty", "success_bonus",
                     "intervention_penalty", "gain_range"):
            put(name, real(name, getattr(self, name)))
        for name in ("residual_gate", "blocked_gate", "success_hold"):
            put(name, real(name, getattr(self, name), non_negative=True))
        put("terminate_on_collision", bool(self.terminate_on_collision))
        put("terminate_on_success", bool(self.terminate_on_success))
        for name in ("circulation_gain", "circulation_activation"):
            put(name, real(name, getattr(self, name), positive=True))
        if self.gain_range <= 1.0:
            raise ValueError(f"gain_range must be > 1 (gains from 1/gain_range to gain_range), got {self.gain_range}")
        if self.action_mode != "residual" and (self.residual_gate > 0 or self.blocked_gate > 0):
            raise ValueError(f"residual_gate and blocked_gate scale a residual correction: they need "
                             f"action_mode='residual', got action_mode={self.action_mode!r}")
        if self.action_mode != "circulation" and any(getattr(self, k) != v for k, v in DEFAULT_CIRCULATION.items()):
            raise ValueError(f"circulation_gain and circulation_activation shape a circulation action: they need "
                             f"action_mode='circulation', got action_mode={self.action_mode!r}")
        put("n_obstacle_obs", positive_int("n_obstacle_obs", self.n_obstacle_obs, minimum=0))
        if self.qp_solver not in QP_SOLVERS:
            raise ValueError(f"qp_solver must be one of {QP_SOLVERS}, got {self.qp_solver!r}")
        self._resolve_team(put)
        ke = self.team.ke
        _time_steps(self, put, ke, self.action_mode)
        max_steps = int(np.ceil(self.team.horizon / self.control_dt - 1e-9)) if self.max_steps is None \
            else self.max_steps
        put("max_steps", positive_int("max_steps", max_steps))
        if self.success_hold > self.max_steps * self.control_dt:  # legitimate in a short smoke test: warn
            warnings.warn(f"success_hold={self.success_hold:g} s is longer than the episode ({self.max_steps} steps "
                          f"of {self.control_dt:g} s): no episode can succeed", stacklevel=3)
        put("safety_filter", filter_parameters(self.safety_filter, self.team))

    def _resolve_team(self, put) -> None:
        """``scenario`` (an id, a name, a path or a Scenario) and ``random_options`` as the template team."""
        scenario, random_options = self.scenario, self.random_options
        if isinstance(scenario, str):  # a registered id stands for its scenario and options
            scenario, extra = env_arguments(scenario, {"random_options": random_options} if random_options else None)
            random_options = extra.get("random_options", random_options)
        put("random", isinstance(scenario, str) and scenario == "random")
        if self.random:
            if isinstance(random_options, Mapping):
                refuse_unknown("random_options", random_options, RandomScenarioOptions.__dataclass_fields__)
                random_options = RandomScenarioOptions(**random_options)
            elif random_options is not None and not isinstance(random_options, RandomScenarioOptions):
                raise ValueError(f"random_options must be a dict or RandomScenarioOptions, got {random_options!r}")
            random_options = random_options or RandomScenarioOptions()
            _refuse_team_time_steps(random_options)
            # the compiled draw: the reference's team from the same generator, in milliseconds at 256 arms
            team = draw_teams([np.random.default_rng(0)], random_options).scenario(0)
        else:
            if random_options is not None:
                raise ValueError("random_options is only for scenario='random'")
            team = load(scenario)
        put("scenario", scenario)
        put("random_options", random_options)
        put("team", team)

    @classmethod
    def of(cls, scenario: Any = "paper_pa3_square", **kwargs: Any) -> FormationConfig:
        """A config from keyword arguments, with a "did you mean" for an unknown one (``TypeError``)."""
        refuse_unknown("FormationConfig", kwargs, ARGUMENTS, error=TypeError)
        return cls(scenario, **kwargs)

    @property
    def physics(self) -> Physics:
        """The part of the config the engine steps with: :func:`physics_of`."""
        return physics_of(self)

    @property
    def action_scale(self) -> float:
        """Physical units of an action of 1: ``max_joint_speed`` (rad/s), ``max_torque`` (N·m), or 1 for a
        gain or circulation action (the exponent of the gain, the circulation's signed strength)."""
        return {"torque": self.max_torque, "gain": 1.0, "circulation": 1.0}.get(self.action_mode,
                                                                                self.max_joint_speed)

    @property
    def neighbour_slots(self) -> int:
        """D, neighbour slots per observation: for random teams the most neighbours their shape can give an arm
        (a ring: 4 whatever N, so that the observation's size does not depend on the team's; a polygon: N − 1),
        else the largest degree of the scenario's graph."""
        team = self.team
        if self.random:
            return most_neighbours(self.random_options.shape, team.n_arms)
        return int(np.bincount(team.formation.edges.ravel(), minlength=team.n_arms).max())

    @property
    def ring(self) -> bool:
        """Random teams on a ring formation, whose arms list their neighbours in one shared order."""
        return self.random and self.random_options.shape == "ring"

    def replace(self, **changes: Any) -> FormationConfig:
        """This config's arguments with ``changes``, validated and resolved again (a default that depended on
        a changed argument, such as ``physics_dt`` on ``action_mode``, follows it)."""
        return FormationConfig.of(**(self.arguments | changes))


ARGUMENTS = tuple(f.name for f in dataclasses.fields(FormationConfig) if f.init)


def config_arguments(config: type) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Decorator for a view's ``__init__(self, scenario, *, own…, **arguments)``: the signature ``help()``, IDEs
    and ``inspect.signature`` show has ``**arguments`` replaced by the config's other arguments (keyword-only,
    with their defaults and types), so that the list of arguments and their defaults is kept once, in the
    config."""

    def decorate(init: Callable[..., None]) -> Callable[..., None]:
        own = inspect.signature(init)
        params = [p for p in own.parameters.values() if p.kind is not p.VAR_KEYWORD]
        taken = {p.name for p in params}
        params += [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=f.type)
                   for f in dataclasses.fields(config) if f.init and f.name not in taken]
        init.__signature__ = own.replace(parameters=params)  # type: ignore[attr-defined]
        return init

    return decorate


@dataclass(frozen=True, eq=False)
class ReachConfig:
    """Every argument of the one-arm reach env (:class:`~pan1_env.reach.PAReachEnv` documents them), validated
    once; ``scenario`` is stored loaded. Derived: ``team`` (a one-arm team: the chosen arm and the scenario's
    obstacles), ``substeps``."""

    scenario: str | Path | Scenario = "paper_pa3_square"
    arm: int = 0
    control_dt: float = DEFAULT_CONTROL_DT
    physics_dt: float | None = None
    max_steps: int = DEFAULT_REACH_STEPS
    max_joint_speed: float = MAX_JOINT_SPEED
    safety_filter: bool | FilterParams | None = True
    goal_tolerance: float = 0.02
    goal_spread: float = np.pi / 2
    goal_clearance: float = 0.05
    terminate_on_success: bool = False
    terminate_on_collision: bool = False
    effort_weight: float = 0.0
    collision_penalty: float = 0.0
    n_obstacle_obs: int = 3
    team: Scenario = field(init=False, repr=False)
    substeps: int = field(init=False, repr=False)

    action_mode = "velocity"
    torque_bound = False  # velocity mode only
    qp_solver = "active_set"
    random = False
    random_options = None

    def __post_init__(self) -> None:
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        scenario = env_arguments(self.scenario)[0] if isinstance(self.scenario, str) else self.scenario
        if isinstance(scenario, str) and scenario == "random":
            raise ValueError(f"the reach env takes an arm of a fixed scenario, not random teams ({self.scenario!r})")
        source = load(scenario)
        put("scenario", source)
        put("arm", positive_int("arm", self.arm, minimum=0))
        if self.arm >= source.n_arms:
            raise ValueError(f"arm must be below the scenario's {source.n_arms} arms, got {self.arm!r}")
        for name in ("control_dt", "max_joint_speed", "goal_tolerance", "goal_spread"):
            put(name, real(name, getattr(self, name), positive=True))
        for name in ("effort_weight", "collision_penalty"):
            put(name, real(name, getattr(self, name)))
        put("goal_clearance", real("goal_clearance", self.goal_clearance, non_negative=True))
        put("terminate_on_success", bool(self.terminate_on_success))
        put("terminate_on_collision", bool(self.terminate_on_collision))
        put("max_steps", positive_int("max_steps", self.max_steps))
        put("n_obstacle_obs", positive_int("n_obstacle_obs", self.n_obstacle_obs, minimum=0))
        _time_steps(self, put, source.ke, self.action_mode)
        # the engine holds a one-arm team: this arm and the scenario's obstacles (the formation is unused)
        put("team", dataclasses.replace(source, arms=(source.arms[self.arm],), q0=(source.q0[self.arm],)))
        put("safety_filter", filter_parameters(self.safety_filter, self.team))

    @property
    def physics(self) -> Physics:
        """The part of the config the engine steps with: :func:`physics_of`."""
        return physics_of(self)

    @property
    def action_scale(self) -> float:
        return self.max_joint_speed
