"""One PAn−1 arm reaching a goal among obstacles: the single-agent Gymnasium task ``pan1_env/PAReach-v0``.

:class:`PAReachEnv` is the smallest task the engine runs: one arm of a scenario (by default arm 0
of ``paper_pa3_square``, a PA3 arm), the scenario's obstacles, and a goal point for the
end-effector drawn at every reset. It is what a one-arm learner or a controller comparison starts
from, and the peer of Gymnasium's ``Acrobot-v1`` (another underactuated arm) in the benchmark.

It is a view of the env core (:class:`~pan1_env.core.FormationCore`, one copy) running the same engine
as the team environment (RCBF-QP filter, backstepping tracker, RK4) with one arm, and the reach task
(:class:`~pan1_env.tasks.ReachTask`). The tests check that an arm here and the same arm in
:class:`~pan1_env.environment.Pan1ParallelEnv`, given the same commands, follow the same trajectory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .centralized import OneCopyGymEnv
from .config import ReachConfig, config_arguments
from .core import FormationCore
from .safety import FilterParams
from .scenario import Scenario
from .validation import hints_unknown_keywords

__all__ = ["PAReachEnv"]


class PAReachEnv(OneCopyGymEnv):
    """One PAn−1 arm brings its end-effector to a goal without touching an obstacle.

    ## Description

    A planar arm with n links taken from a scenario (``scenario``, ``arm``), the scenario's disk
    obstacles, and a goal point. A PA arm's first joint is passive: started at rest and frictionless, it
    keeps zero passive momentum, so the passive joint follows the active ones and the end-effector moves
    through the reduced Jacobian J̄ (the paper's cascaded model; with ``passive_damping`` > 0 the momentum
    leaves zero and the drawn goal is the frictionless arm's). The dynamics, tracker and safety
    filter are the team environment's (:class:`~pan1_env.environment.Pan1ParallelEnv`).

    ## Action Space

    ``Box(-1, 1, (k,), float32)``, k = n − 1 for a PA arm (n when fully actuated): the desired
    active-joint velocity v = a · ``max_joint_speed`` (rad/s), held for the control step and
    tracked by the paper's backstepping law (Eq. 64) at every physics sub-step. Values outside
    [−1, 1] are clipped; NaN/inf, a wrong shape or a non-numeric action (a dict, a string) raise
    ``ValueError``.

    With ``safety_filter=True`` (default) every sub-step first projects the command through the
    paper's RCBF-QP (Eq. 61) with the scenario's κ, ε and margin, and bounds the filtered speeds by
    ``max_joint_speed``: the end-effector stays outside every obstacle the arm's filter sees (all but
    those out of its reach, with the scenario's ``ignore_unreachable_obstacles``), whatever the
    action, up to the RK4 sub-step's discretisation.

    ## Observation Space

    ``Box(float32)`` of size 3n + 4 + 5K (K = ``n_obstacle_obs``)::

        [cos q (n), sin q (n), q̇ / max_joint_speed (n), p − base (2), goal − p (2),
         K obstacle slots (present, dx, dy, r, h)]

    p is the end-effector; the obstacle slots hold the K obstacles nearest to p by clearance
    (dx, dy from p to the centre, radius r, barrier h = ‖p − o‖² − r²), zeros when absent. Entries
    other than cos/sin and the presence flags are clipped to ±1e6.

    ## Rewards

    ``−‖goal − p‖ − effort_weight · ‖a‖²/k − collision_penalty · cost`` per step, where
    ``cost`` (also ``info["cost"]``) is 1.0 when the end-effector was inside an obstacle after any
    sub-step of the step and 0.0 otherwise.

    ## Starting State

    The arm at rest at the scenario's initial angles. The goal is the end-effector of a
    configuration reached from the start at rest (the actuated joints moved in a straight line by
    up to ±``goal_spread`` rad each, the passive joint by zero momentum), drawn from the env's
    seeded generator and redrawn until it is at least ``goal_clearance`` m clear of every obstacle.
    ``reset(options={"goal": (x, y)})`` sets the goal instead.

    ## Episode End

    Terminated when the end-effector is within ``goal_tolerance`` of the goal and
    ``terminate_on_success`` is set, or on a collision with ``terminate_on_collision``; truncated
    after ``max_steps`` steps, or at once if the state goes non-finite (``info["fault"]`` says so;
    the arm is left at its last finite state).

    ## Info

    ``cost``, ``min_clearance`` (smallest ‖p − o‖ − r over the step's sub-steps), ``distance``
    (‖goal − p‖), ``is_success``, with the filter on ``shield_intervened`` (the filter changed the command
    in a sub-step), ``shield_fallback`` (its QP was infeasible and the braking fallback ran),
    ``shield_status`` (0 nominal, 1 solved, 2 fallback), ``shield_min_barrier``, ``shield_applied`` (the
    action applied, v*/``max_joint_speed``) and ``qp_counts``; ``reward_<term>``: the reward's terms
    (``reward_distance``, and ``reward_effort`` and ``reward_collision`` when their weights are not zero),
    which sum to it (0 after a reset).

    ## Arguments

    * ``scenario``: a built-in scenario name, a TOML path or a :class:`~pan1_env.scenario.Scenario`
      (default ``"paper_pa3_square"``); ``arm``: which of its arms (default 0).
    * ``control_dt`` (0.05 s), ``physics_dt`` (default: the team env's, 10 ms here).
    * ``max_steps`` (200), ``max_joint_speed`` (2 rad/s), ``safety_filter`` (True).
    * ``goal_tolerance`` (0.02 m), ``goal_spread`` (π/2 rad), ``goal_clearance`` (0.05 m).
    * ``terminate_on_success`` (False), ``terminate_on_collision`` (False),
      ``effort_weight`` (0), ``collision_penalty`` (0), ``n_obstacle_obs`` (3).

    ## Version History

    * v0: first version.
    """

    metadata = {"render_modes": []}

    @hints_unknown_keywords
    @config_arguments(ReachConfig)
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", arm: int = 0, *,
                 render_mode: str | None = None, **arguments: Any) -> None:
        if render_mode is not None:
            raise ValueError(f"PAReachEnv has no render modes; render_mode must be None, got {render_mode!r}")
        self.core = FormationCore(ReachConfig(scenario, arm, **arguments), 1)
        self.config = self.core.config
        self.arm_index = self.config.arm
        self.render_mode = None
        self.engine = self.core.engine
        self.scenario = self.config.scenario
        self.task = self.core.task
        self.arm = self.config.team.arms[0]
        self._flat_spaces()

    @property
    def safety_filter(self) -> FilterParams | None:
        """The safety filter's parameters, or None when it is off."""
        return self.engine.filter

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step (the config's ``control_dt``)."""
        return self.config.control_dt

    @property
    def goal(self) -> np.ndarray:
        """The current goal point (2,) (a copy)."""
        return self.core.task.goal[0].copy()

    @property
    def q(self) -> np.ndarray:
        """The arm's joint angles (n,) (a copy)."""
        return self.engine.kinds[0].q[0].copy()

    @property
    def end_effector(self) -> np.ndarray:
        """The end-effector position (2,) (a copy)."""
        return self.engine.kinds[0].p[0].copy()
