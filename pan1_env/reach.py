"""One PAn−1 arm reaching a goal among obstacles: the single-agent Gymnasium task ``pan1_env/PAReach-v0``.

:class:`PAReachEnv` is the smallest task the engine runs: one arm of a scenario (by default arm 0
of ``paper_pa3_square``, a PA3 arm), the scenario's obstacles, and a goal point for the
end-effector drawn at every reset. It is what a one-arm learner or a controller comparison starts
from, and the peer of Gymnasium's ``Acrobot-v1`` (another underactuated arm) in the benchmark.

It steps the same compiled closed loop as the team environment
(:func:`pan1_env.kernels.group_advance`: RCBF-QP filter, backstepping tracker, RK4), with one arm
and the state held in preallocated arrays, so a step costs a handful of calls. The tests check that
an arm here and the same arm in :class:`~pan1_env.environment.Pan1ParallelEnv`, given the same
commands, follow the same trajectory.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from .compiled import kernel_sizes, kernels
from .dynamics import ArmBatch, end_effector
from .environment import DEFAULT_CONTROL_DT, MAX_KE_DT, default_physics_dt
from .observation import OBS_BOUND, OBSTACLE_FEATURES
from .random_scenario import _passive_path
from .registration import DEFAULT_REACH_STEPS
from .safety import clearance
from .scenario import Scenario, load
from .validation import float_array, hints_unknown_keywords, positive_int, real, whole_ratio

__all__ = ["PAReachEnv"]

_GOAL_DRAWS = 1000  # attempts at a goal clear of the obstacles before giving up


class PAReachEnv(gymnasium.Env):
    """One PAn−1 arm brings its end-effector to a goal without touching an obstacle.

    ## Description

    A planar arm with n links taken from a scenario (``scenario``, ``arm``), the scenario's disk
    obstacles, and a goal point. A PA arm's first joint is passive: started at rest, it keeps zero
    passive momentum, so the passive joint follows the active ones and the end-effector moves
    through the reduced Jacobian J̄ (the paper's cascaded model). The dynamics, tracker and safety
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
    (‖goal − p‖), ``is_success``, ``intervened`` (the filter changed the command in a sub-step) and
    ``fallback`` (its QP was infeasible and the braking fallback ran in a sub-step).

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
    def __init__(self, scenario: str | Path | Scenario = "paper_pa3_square", arm: int = 0, *,
                 control_dt: float = DEFAULT_CONTROL_DT, physics_dt: float | None = None,
                 max_steps: int = DEFAULT_REACH_STEPS, max_joint_speed: float = 2.0,
                 safety_filter: bool = True, goal_tolerance: float = 0.02, goal_spread: float = np.pi / 2,
                 goal_clearance: float = 0.05, terminate_on_success: bool = False,
                 terminate_on_collision: bool = False, effort_weight: float = 0.0,
                 collision_penalty: float = 0.0, n_obstacle_obs: int = 3, render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ValueError(f"PAReachEnv has no render modes; render_mode must be None, got {render_mode!r}")
        self.render_mode = None
        self.scenario = load(scenario)
        self.arm_index = positive_int("arm", arm, minimum=0)
        if self.arm_index >= self.scenario.n_arms:
            raise ValueError(f"arm must be below the scenario's {self.scenario.n_arms} arms, got {arm!r}")
        self.arm = self.scenario.arms[self.arm_index]
        self.control_dt = real("control_dt", control_dt, positive=True)
        if physics_dt is None:
            physics_dt = default_physics_dt(self.control_dt, self.scenario.ke, self.scenario.physics_dt)
        self.physics_dt = real("physics_dt", physics_dt, positive=True)
        if self.scenario.ke * self.physics_dt > MAX_KE_DT:
            raise ValueError(f"physics_dt={physics_dt} is too long for the tracker gain K_e={self.scenario.ke}: "
                             f"K_e·physics_dt must be ≤ {MAX_KE_DT}")
        self.substeps = whole_ratio("control_dt", self.control_dt, "physics_dt", self.physics_dt)
        self.max_steps = positive_int("max_steps", max_steps)
        self.max_joint_speed = real("max_joint_speed", max_joint_speed, positive=True)
        self.safety_filter = bool(safety_filter)
        self.goal_tolerance = real("goal_tolerance", goal_tolerance, positive=True)
        self.goal_spread = real("goal_spread", goal_spread, positive=True)
        self.goal_clearance = real("goal_clearance", goal_clearance, non_negative=True)
        self.terminate_on_success = bool(terminate_on_success)
        self.terminate_on_collision = bool(terminate_on_collision)
        self.effort_weight = real("effort_weight", effort_weight)
        self.collision_penalty = real("collision_penalty", collision_penalty)
        self.n_obstacle_obs = positive_int("n_obstacle_obs", n_obstacle_obs, minimum=0)

        n, k = self.arm.n_links, self.arm.n_actuated
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (k,), np.float32)
        size = 3 * n + 4 + OBSTACLE_FEATURES * self.n_obstacle_obs
        low = np.full(size, -OBS_BOUND, dtype=np.float32)
        high = np.full(size, OBS_BOUND, dtype=np.float32)
        low[: 2 * n], high[: 2 * n] = -1.0, 1.0
        flags = [3 * n + 4 + OBSTACLE_FEATURES * s for s in range(self.n_obstacle_obs)]
        low[flags], high[flags] = 0.0, 1.0
        self.observation_space = gymnasium.spaces.Box(low, high, dtype=np.float32)

        # the one-arm group the kernel steps, and every array it reads or writes, allocated once
        obstacles = self.scenario.obstacles
        self._batch = ArmBatch.stack([self.arm])
        self._centers = np.array(obstacles.centers[None], dtype=float)  # writable copies: the kernel is
        self._radii = np.array(obstacles.radii[None], dtype=float)  # compiled for writable arrays
        self._mask = np.ascontiguousarray(self.scenario.obstacle_mask()[self.arm_index][None])
        self._sizes = kernel_sizes(n, k)
        self._q = np.zeros((1, n))
        self._v = np.zeros((1, k))
        self._v_prev = np.zeros((1, k))
        self._has_prev = np.zeros(1, dtype=bool)
        self._command = np.zeros((1, k))
        self._k_array = np.array([k])
        self._effort = np.zeros(1)
        self._v_star = np.zeros((1, k))
        self._tau = np.zeros((1, k))
        self._qd = np.zeros((1, n))
        self._p = np.zeros((1, 2))
        self._min_clear = np.zeros(1)
        self._min_h = np.zeros(1)
        self._counts = np.zeros((1, 3), dtype=np.int64)
        self._track = np.zeros(1)
        self._finite = np.ones(1, dtype=bool)
        self._goal = np.zeros((1, 2))
        self._base = np.ascontiguousarray(self._batch.base)
        self.num_steps = 0
        self._needs_reset = True

    # ------------------------------------------------------------------- API
    @property
    def goal(self) -> np.ndarray:
        """The current goal point (2,) (a copy)."""
        return self._goal[0].copy()

    @property
    def q(self) -> np.ndarray:
        """The arm's joint angles (n,) (a copy)."""
        return self._q[0].copy()

    @property
    def end_effector(self) -> np.ndarray:
        """The end-effector position (2,) (a copy)."""
        return self._p[0].copy()

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        options = dict(options or {})
        goal = options.pop("goal", None)
        if options:
            raise ValueError(f"unknown reset option {sorted(options)[0]!r}; the only option is 'goal'")
        if goal is not None:  # checked before anything changes
            try:
                point = np.asarray(goal, dtype=float)
            except (TypeError, ValueError):
                point = None
            if point is None or point.shape != (2,) or not np.isfinite(point).all():
                raise ValueError(f"options['goal'] must be 2 finite numbers (x, y), got {goal!r}")
            goal = point
        super().reset(seed=seed)
        q0 = np.asarray(self.scenario.q0[self.arm_index], dtype=float)
        self._q[0] = q0
        self._v[:] = 0.0
        self._v_prev[:] = 0.0
        self._has_prev[:] = False
        self._qd[:] = 0.0
        b = self._batch
        kernels().group_end_effectors(b.lengths, b.base, b.phi, self._q, self._p)
        self._goal[0] = self._draw_goal(q0) if goal is None else goal
        self.num_steps = 0
        self._needs_reset = False
        distance = float(np.hypot(*(self._goal[0] - self._p[0])))
        clear = self._clearance(self._p[0])
        info = {"cost": 0.0, "min_clearance": clear, "distance": distance,
                "is_success": distance < self.goal_tolerance, "intervened": False, "fallback": False}
        return self._observation(), info

    def step(self, action: np.ndarray):
        if self._needs_reset:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        kern = kernels()
        a = float_array("action", action, self.action_space.shape)
        self._command[0] = a
        if kern.scale_command(self._command, self._k_array, self.max_joint_speed, self._effort) >= 0:
            raise ValueError(f"action contains NaN or inf: {a.tolist()}")
        self._min_clear[0] = np.inf
        self._min_h[0] = np.inf
        self._counts[0] = 0
        self._track[0] = 0.0
        self._finite[0] = True
        b, sc = self._batch, self.scenario
        kern.group_advance(*self._sizes, b.lam, b.lengths, b.base, b.phi, b.passive_first_joint, self._q,
                           self._v, self._v_prev, self._has_prev, self._command, False, self.safety_filter,
                           self._centers, self._radii, self._mask, sc.kappa, sc.epsilon, sc.safety_margin, sc.ke,
                           self.physics_dt, self.substeps, self.max_joint_speed, self._v_star, self._tau, self._qd,
                           self._p, self._min_clear, self._min_h, self._counts, self._track, self._finite)
        self.num_steps += 1
        px, py = self._p[0].tolist()
        gx, gy = self._goal[0].tolist()
        distance = ((gx - px) ** 2 + (gy - py) ** 2) ** 0.5
        min_clear = float(self._min_clear[0])
        finite = bool(self._finite[0])
        if not finite:  # the arm stopped at its last finite state: include that state's clearance
            min_clear = min(min_clear, self._clearance(self._p[0]))
        cost = 1.0 if min_clear < 0 else 0.0
        success = distance < self.goal_tolerance
        _, solved, fallback = self._counts[0].tolist()
        reward = -distance - self.effort_weight * float(self._effort[0]) - self.collision_penalty * cost
        terminated = (self.terminate_on_success and success) or (self.terminate_on_collision and cost > 0)
        truncated = self.num_steps >= self.max_steps or not finite
        info = {"cost": cost, "min_clearance": min_clear, "distance": distance, "is_success": success,
                "intervened": solved + fallback > 0, "fallback": fallback > 0}
        if not finite:
            info["fault"] = "non-finite state in the physics step; episode truncated"
        if terminated or truncated:
            self._needs_reset = True
        return self._observation(), reward, terminated, truncated, info

    # ------------------------------------------------------------- internals
    def _observation(self) -> np.ndarray:
        out = np.empty((1, self.observation_space.shape[0]), dtype=np.float32)
        kernels().reach_observations(self._q, self._qd, self._p, self._base, self._goal, self._centers, self._radii,
                                     self.n_obstacle_obs, 1.0 / self.max_joint_speed, OBS_BOUND, out)
        return out[0]

    def _clearance(self, p: np.ndarray) -> float:
        """Smallest clearance ‖p − o_j‖ − r_j of a point to the obstacles (inf with none)."""
        return float(clearance(p, self._centers[0], self._radii[0]).min(initial=np.inf))

    def _draw_goal(self, q0: np.ndarray) -> np.ndarray:
        """An end-effector reachable from ``q0`` at rest, ``goal_clearance`` clear of every obstacle."""
        arm, k = self.arm, self.arm.n_actuated
        for _ in range(_GOAL_DRAWS):
            qa = q0[-k:] + self.np_random.uniform(-self.goal_spread, self.goal_spread, k)
            q = _passive_path(arm, q0, qa)  # zero passive momentum along the straight path
            goal = end_effector(arm, q)
            if self._clearance(goal) >= self.goal_clearance:
                return goal
        raise RuntimeError(f"no goal {self.goal_clearance} m clear of the obstacles in {_GOAL_DRAWS} draws; "
                           "lower goal_clearance")
