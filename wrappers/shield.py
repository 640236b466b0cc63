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

With ``sensing_radius=s`` (m) an end-effector scenario is filtered through the whole-arm rows with the
end-effector as the body: an obstacle gets a row only within s (plus what the gap can close in a
sub-step), so the robust term of far obstacles cannot hold an arm still (the paper's filter, the
default, keeps a row for every obstacle in reach; docs/LEARNING_STUDIES.md measures the difference).

With ``tracking_bound=δ̄`` the filter uses the tightened barrier h − Γ(δ̄), Γ(δ̄) = ε δ̄² / (4 κ)
(docs/MODEL.md §5): as long as the tracking error stays below δ̄ the arm stays in the *original* set
h ≥ 0, not only in the inflated one h ≥ −Γ(δ̄).
"""

from __future__ import annotations

import gymnasium
from pettingzoo.utils.wrappers import BaseParallelWrapper

from pan1_env.safety import FilterParams

__all__ = ["SafetyShield", "GymSafetyShield", "shield_parameters"]


def shield_parameters(scenario, kappa: float | None, epsilon: float | None, margin: float | None,
                      tracking_bound: float | None, sensing_radius: float | None = None, *,
                      barrier: str | None = None, decay: float | None = None,
                      gate: float | None = None) -> FilterParams:
    """Validated filter parameters: κ, ε (default: the scenario's), the barrier margin (explicit,
    or Γ(δ̄) from ``tracking_bound``; default: the scenario's), the sensing radius (default: none), the
    barrier, λ of the tunable ε(h̃) and the activation gate (default: the scenario's). :meth:`FilterParams.of` owns the
    rules; errors name the argument after ``SafetyShield:``."""
    return FilterParams.of(scenario, kappa, epsilon, margin, tracking_bound, sensing_radius, owner="SafetyShield",
                           barrier=barrier, decay=decay, gate=gate)


def _switch_on(core, owner: str, params: FilterParams | None, kappa, epsilon, margin, tracking_bound, sensing_radius,
               barrier, decay, gate) -> None:
    """Switch the filter on through the env's public :meth:`set_safety_filter`: ``params`` as they are, or the
    scenario's settings with the loose ones replaced (not both)."""
    if core.safety_filter is not None:
        raise ValueError("this env is already shielded; wrap it once")
    if params is None:
        params = shield_parameters(core.scenario, kappa, epsilon, margin, tracking_bound, sensing_radius,
                                   barrier=barrier, decay=decay, gate=gate)
    elif not isinstance(params, FilterParams):
        raise TypeError(f"{owner}: params must be a pan1_env.safety.FilterParams, got {type(params).__name__}")
    elif any(v is not None for v in (kappa, epsilon, margin, tracking_bound, sensing_radius, barrier, decay, gate)):
        raise ValueError(f"{owner}: give params or the settings one by one (kappa=…, barrier=…), not both: "
                         "FilterParams.of(env.unwrapped.scenario, …) builds params from the scenario's")
    core.set_safety_filter(params)


class SafetyShield(BaseParallelWrapper):
    """Shield a :class:`~pan1_env.environment.Pan1ParallelEnv` (or a wrapper of one).

    The filter runs inside the env's physics sub-steps, so wrapping switches it on in the wrapped
    env itself (a reference to the unwrapped env steps shielded too); an env is shielded once.

    Args:
        env: the parallel env.
        kappa, epsilon: RCBF parameters κ and ε (default: the scenario's).
        margin: subtract this from every barrier (m² for the squared barrier, m for the distance one;
            default: the scenario's, 0 for the paper's).
        tracking_bound: δ̄; sets ``margin = Γ(δ̄)`` (the tightened set that keeps h ≥ 0).
        sensing_radius: the whole-arm filter's range (m; default: none).
        barrier: ``"squared"`` (the paper's) or ``"distance"``; decay: λ ≥ 0 of ε(h̃) = ε e^{λ h̃}
            (docs/MODEL.md §5a; default: the scenario's, the paper's "squared" and 0).
        gate: width (m) of the smooth activation past the sensing range (0: a hard range; default: the
            scenario's); needs whole-arm bodies or ``sensing_radius``, and the env's speed bound.
        params: a whole :class:`~pan1_env.safety.FilterParams` instead of the settings above (one object to
            sweep a filter's design with, e.g. ``FilterParams.of(scenario, barrier="distance", decay=50)``).
    """

    def __init__(self, env, kappa: float | None = None, epsilon: float | None = None,
                 margin: float | None = None, tracking_bound: float | None = None,
                 sensing_radius: float | None = None, *, barrier: str | None = None,
                 decay: float | None = None, gate: float | None = None, params: FilterParams | None = None) -> None:
        super().__init__(env)
        core = env.unwrapped
        if not hasattr(core, "set_safety_filter"):
            raise TypeError(f"SafetyShield wraps a pan1_env parallel env, got {type(core).__name__}")
        _switch_on(core, "SafetyShield", params, kappa, epsilon, margin, tracking_bound, sensing_radius, barrier,
                   decay, gate)


class GymSafetyShield(gymnasium.Wrapper):
    """Shield the Gymnasium view (:class:`~pan1_env.registration.CentralizedEnv`).

    The infos' ``shield_*`` keys report the filter over the team. Arguments as :class:`SafetyShield`.
    """

    def __init__(self, env: gymnasium.Env, kappa: float | None = None, epsilon: float | None = None,
                 margin: float | None = None, tracking_bound: float | None = None,
                 sensing_radius: float | None = None, *, barrier: str | None = None,
                 decay: float | None = None, gate: float | None = None, params: FilterParams | None = None) -> None:
        super().__init__(env)
        inner = env.unwrapped
        if not hasattr(inner, "parallel"):
            hint = " (PAReachEnv has the filter built in: safety_filter=True)" if hasattr(inner, "arm_index") else ""
            raise TypeError(f"GymSafetyShield wraps a pan1_env team Gymnasium env, got {type(inner).__name__}{hint}")
        _switch_on(inner.parallel, "GymSafetyShield", params, kappa, epsilon, margin, tracking_bound, sensing_radius,
                   barrier, decay, gate)
