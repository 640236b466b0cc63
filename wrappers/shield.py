"""The safety shield: the paper's RCBF-QP filter between any policy and the arms.

:class:`SafetyShield` wraps the PettingZoo parallel env, :class:`GymSafetyShield` the Gymnasium
view. Whatever a policy sends, each arm moves with the RCBF-QP projection of it (Eq. 56–61; the
rows and the QP are those of :mod:`pan1_env.safety`, run in the engine's kernels), re-evaluated at
**every physics sub-step**, so safety holds between control steps:

* velocity mode: the desired velocity is projected and the projection tracked by the backstepping
  law (the paper's controller);
* torque mode: the velocity the torque would produce after one sub-step is projected; if the
  projection differs, the arm is driven to it in one sub-step instead of applying the torque.

In both modes the QP also bounds every filtered speed, |v_t| ≤ ``max_joint_speed`` (the actions'
own limit), so a nearly degenerate row cannot ask for a huge velocity; a problem that these bounds
make infeasible brakes. The shield's torques are not limited to ``max_torque``: keeping the arm out
of obstacles takes precedence, and ``applied`` (in units of ``max_torque`` in torque mode) can then
exceed 1. ``intervened`` counts speed limiting as an intervention too.

Obstacles beyond an arm's reach (farther from its base than its reach plus their radius) cannot be
hit and are left out of its QP. If the QP is infeasible the fallback is braking (v* = 0: no barrier
of a still obstacle decreases). A scenario with whole-arm safety (``bodies = "links"``, ``inter_arm``
or moving obstacles) protects every link from the obstacles where they are at each sub-step and from
the other arms' capsules, and its fallback drops the robust term, then violates the rows least
(docs/SCENARIOS.md, "Whole-arm safety"). The env's infos report the filter's work in every step, as flat
numbers that TorchRL's and RLlib's PettingZoo wrappers take as they are: ``shield_intervened`` (the QP
changed the action at some sub-step), ``shield_fallback`` (the QP was infeasible and the fallback was
used), ``shield_status`` (the worst QP status over the sub-steps: 0 nominal, 1 solved, 2 fallback),
``shield_min_barrier`` (the smallest barrier value h = ‖p − o‖² − r² the filter saw, h = ‖p − o‖ − r with
``barrier="distance"``; with whole-arm safety the smallest of its pairs in sensing range, against the
capsules inflated by the skin; inf when there is none), ``shield_applied`` (the action actually applied
at the last sub-step, in the action's normalised units; in residual mode the whole filtered velocity
v*/``max_joint_speed``, reference included) and ``qp_counts`` (sub-steps per status). The Gymnasium
view gathers them over the arms (:meth:`~pan1_env.core.FormationCore.team_infos`).

With ``params=FilterParams.of(scenario, sensing_radius=s)`` (m) an end-effector scenario is filtered
through the whole-arm rows with the end-effector as the body: an obstacle gets a row only within s (plus
what the gap can close in a sub-step), so the robust term of far obstacles cannot hold an arm still (the
paper's filter, the default, keeps a row for every obstacle in reach; docs/LEARNING_STUDIES.md measures
the difference).

With ``FilterParams.of(scenario, tracking_bound=δ̄)`` the filter uses the tightened barrier h − Γ(δ̄), Γ(δ̄) = ε δ̄² / (4 κ)
(docs/MODEL.md §5): as long as the tracking error stays below δ̄ the arm stays in the *original* set
h ≥ 0, not only in the inflated one h ≥ −Γ(δ̄).
"""

from __future__ import annotations

import gymnasium
from pettingzoo.utils.wrappers import BaseParallelWrapper

from pan1_env.safety import FilterParams

__all__ = ["SafetyShield", "GymSafetyShield"]


def _switch_on(core, owner: str, params: FilterParams | None, loose: dict) -> None:
    """Switch the filter on through the env's public :meth:`set_safety_filter`: ``params``, or the scenario's own
    filter (``scenario.filter``) if None. Settings given one by one (``kappa=…``) are refused with the one way in."""
    if loose:
        given = ", ".join(f"{key}={value!r}" for key, value in loose.items())
        raise TypeError(f"{owner} takes the filter's settings as one FilterParams: {owner}(env, "
                        f"params=FilterParams.of(env.unwrapped.scenario, {given})), not one by one")
    if core.safety_filter is not None:
        raise ValueError("this env is already shielded; wrap it once")
    if params is not None and not isinstance(params, FilterParams):
        raise TypeError(f"{owner}: params must be a pan1_env.safety.FilterParams, got {type(params).__name__}")
    core.set_safety_filter(True if params is None else params)  # True: the scenario's own


class SafetyShield(BaseParallelWrapper):
    """Shield a :class:`~pan1_env.environment.Pan1ParallelEnv` (or a wrapper of one).

    The filter runs inside the env's physics sub-steps, so wrapping switches it on in the wrapped
    env itself (a reference to the unwrapped env steps shielded too); an env is shielded once.

    Args:
        env: the parallel env.
        params: the filter (:class:`~pan1_env.safety.FilterParams`); None: the scenario's own
            (``env.unwrapped.scenario.filter``). ``FilterParams.of(scenario, …)`` changes some of the scenario's
            settings (κ, ε, the margin or ``tracking_bound``, the barrier, …), e.g.
            ``SafetyShield(env, params=FilterParams.of(env.unwrapped.scenario, barrier="distance", decay=50))``.
    """

    def __init__(self, env, params: FilterParams | None = None, **settings) -> None:
        super().__init__(env)
        core = env.unwrapped
        if not hasattr(core, "set_safety_filter"):
            raise TypeError(f"SafetyShield wraps a pan1_env parallel env, got {type(core).__name__}")
        _switch_on(core, "SafetyShield", params, settings)


class GymSafetyShield(gymnasium.Wrapper):
    """Shield the Gymnasium view (:class:`~pan1_env.registration.CentralizedEnv`).

    The infos' ``shield_*`` keys report the filter over the team. Arguments as :class:`SafetyShield`.
    """

    def __init__(self, env: gymnasium.Env, params: FilterParams | None = None, **settings) -> None:
        super().__init__(env)
        inner = env.unwrapped
        if not hasattr(inner, "parallel"):
            hint = " (PAReachEnv has the filter built in: safety_filter=True)" if hasattr(inner, "arm_index") else ""
            raise TypeError(f"GymSafetyShield wraps a pan1_env team Gymnasium env, got {type(inner).__name__}{hint}")
        _switch_on(inner.parallel, "GymSafetyShield", params, settings)
