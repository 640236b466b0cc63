"""A team of arms stepping in time under the paper's controller: state, physics sub-steps, safety.

:class:`Simulation` holds the state of every arm of a :class:`~pan1_env.scenario.Scenario` in
arrays batched over arms that share their number of links and their actuation (an
:class:`ArmGroup`), so one physics sub-step costs a fixed number of numpy calls per group, not per
arm. One physics sub-step (``physics_dt``) is:

1. the cascade terms (M_comb, H_comb), positions and reduced Jacobians of every arm;
2. the reference velocity: the nominal formation law v0 (Eq. 39), or a commanded velocity held
   over the control step;
3. with the safety filter on, its RCBF-QP projection v* (Eq. 61), re-solved every sub-step;
4. the backstepping torque (Eq. 64) with v̇* a backward finite difference over the sub-step;
5. one RK4 step of the cascaded state with that torque held (zero-order hold);
6. the clearance of every end-effector to every obstacle at the new state.

Steps 1, 3–6 run in the compiled kernels of :mod:`pan1_env.kernels` (checked in the tests against
the numpy reference formulas of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety`, :mod:`pan1_env.control`); ``qp_solver="piqp"`` replaces the kernel's exact
QP with qpsolvers + PIQP. Nothing here knows Gymnasium; the CLI's ``reproduce`` and the environments drive it.
Arms are numbered from 0 in team order; padded team arrays use NaN beyond an arm's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .cascade import cascade_terms
from .control import backstepping_torque, nominal_velocity
from .dynamics import ArmBatch
from .formation import edge_errors, edge_length_errors, edge_vectors, formation_gradient
from .safety import QP_SOLVERS, QPStatus, clearance, project_velocity, rcbf_constraints
from .scenario import Scenario

__all__ = ["ArmGroup", "Simulation", "StepRecord", "SubstepRecord"]


@dataclass
class ArmGroup:
    """Arms of one kind (same n, same actuation), stacked for batched computation."""

    arm_ids: np.ndarray  # (A,) indices in team order
    batch: ArmBatch
    obstacle_mask: np.ndarray  # (A, O)
    q: np.ndarray  # (A, n)
    v: np.ndarray  # (A, k)
    v_star_prev: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.batch.n_links

    @property
    def k(self) -> int:
        return self.batch.n_actuated


@dataclass
class StepRecord:
    """What one control step (``substeps`` physics steps with a held command) produced."""

    v_star: np.ndarray  # (N, k_max) v* of the last sub-step (NaN in torque mode)
    tau: np.ndarray  # (N, n_max) full joint torques of the last sub-step
    min_clearance: np.ndarray  # (N,) smallest clearance over the step's sub-steps
    min_barrier: np.ndarray  # (N,) smallest filtered barrier value h seen (inf: no row)
    qp_counts: np.ndarray  # (N, 3) sub-steps per QPStatus
    finite: bool  # False if the state went non-finite (the state is left at its last finite value)


@dataclass
class SubstepRecord:
    """What one physics sub-step produced, in padded team arrays (N, n_max) / (N, k_max)."""

    v_star: np.ndarray
    tau: np.ndarray  # full joint torques (passive entry 0)
    tracking_error: np.ndarray  # (N,) ‖v − v*‖ before the step
    qp_status: np.ndarray  # (N,) QPStatus (NOMINAL when the filter is off)
    min_barrier: np.ndarray  # (N,) smallest filtered h (inf when no row)
    clearance: np.ndarray  # (N,) smallest clearance after the step
    max_edge_error: float  # max_k |‖z_k‖ − d_k| after the step
    passive_momentum: np.ndarray  # (N,) Σ M_1α q̇_α before the step (NaN: fully actuated)


class Simulation:
    """The paper's closed loop for one scenario.

    Args:
        scenario: a validated :class:`~pan1_env.scenario.Scenario`.
        safety_filter: ``True`` filters the reference through the RCBF-QP ("safe" controller);
            ``False`` tracks it directly ("nominal" controller).
        qp_solver: ``"active_set"`` (exact and fast) or ``"piqp"`` (qpsolvers + PIQP).
        physics_dt: overrides the scenario's physics step (seconds).
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        safety_filter: bool = True,
        qp_solver: str = "active_set",
        physics_dt: float | None = None,
    ) -> None:
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"unknown qp_solver {qp_solver!r}; choose one of {QP_SOLVERS}")
        self.scenario = scenario
        self.safety_filter = bool(safety_filter)
        #: RCBF parameters used by the filter (the scenario's unless overridden, e.g. by a shield)
        self.kappa, self.epsilon, self.margin = scenario.kappa, scenario.epsilon, scenario.safety_margin
        self.qp_solver = qp_solver
        self.dt = float(scenario.physics_dt if physics_dt is None else physics_dt)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"physics_dt must be positive, got {physics_dt!r}")
        self.n_arms = scenario.n_arms
        self.n_max = max(a.n_links for a in scenario.arms)
        self.k_max = max(a.n_actuated for a in scenario.arms)
        self.n_links = np.array([a.n_links for a in scenario.arms])
        self.n_actuated = np.array([a.n_actuated for a in scenario.arms])
        self.passive = np.array([a.passive_first_joint for a in scenario.arms])
        self._incidence = scenario.formation.incidence
        self._centers = scenario.obstacles.centers
        self._radii = scenario.obstacles.radii
        mask = scenario.obstacle_mask()
        kinds: dict[tuple[int, bool], list[int]] = {}
        for i, arm in enumerate(scenario.arms):
            kinds.setdefault((arm.n_links, arm.passive_first_joint), []).append(i)
        self.groups: list[ArmGroup] = []
        for (n, _passive), ids in sorted(kinds.items()):
            batch = ArmBatch.stack([scenario.arms[i] for i in ids])
            k = batch.n_actuated
            self.groups.append(
                ArmGroup(
                    arm_ids=np.array(ids),
                    batch=batch,
                    obstacle_mask=mask[ids],
                    q=np.zeros((len(ids), n)),
                    v=np.zeros((len(ids), k)),
                )
            )
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, q0: list[np.ndarray] | None = None) -> None:
        """Put every arm at rest at ``q0`` (default: the scenario's), time 0."""
        q0 = self.scenario.q0 if q0 is None else q0
        if len(q0) != self.n_arms:
            raise ValueError(f"q0 needs one configuration per arm ({self.n_arms}), got {len(q0)}")
        for g in self.groups:
            g.q = np.array([np.asarray(q0[i], dtype=float) for i in g.arm_ids])
            g.v = np.zeros_like(g.v)
            g.v_star_prev = None
        self.time = 0.0
        self.steps = 0
        self._positions = None
        self.min_clearance = self.clearance()  # (N,) running minimum since reset

    def positions(self) -> np.ndarray:
        """End-effector positions of every arm, ``(N, 2)`` (a read-only view, cached per state)."""
        if self._positions is None:
            P = np.empty((self.n_arms, 2))
            for g in self.groups:
                p = np.empty((len(g.arm_ids), 2))
                kernels.group_end_effectors(g.batch.lengths, g.batch.base, g.batch.phi, g.q, p)
                P[g.arm_ids] = p
            P.setflags(write=False)
            self._positions = P
        return self._positions

    def clearance(self) -> np.ndarray:
        """Smallest ‖p_i − o_j‖ − r_j over obstacles for each arm, ``(N,)`` (inf with none)."""
        if len(self._radii) == 0:
            return np.full(self.n_arms, np.inf)
        return clearance(self.positions(), self._centers, self._radii).min(axis=-1)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Padded team arrays ``q (N, n_max)`` and ``q̇ (N, n_max)`` (NaN beyond an arm's n)."""
        q = np.full((self.n_arms, self.n_max), np.nan)
        qd = np.full((self.n_arms, self.n_max), np.nan)
        for g in self.groups:
            terms = cascade_terms(g.batch, g.q, g.v)
            q[g.arm_ids, : g.n] = g.q
            qd[g.arm_ids, : g.n] = terms.qd
        return q, qd

    def passive_momentum(self) -> np.ndarray:
        """Σ_α M_1α q̇_α for every arm, ``(N,)`` (NaN for fully actuated arms)."""
        out = np.full(self.n_arms, np.nan)
        for g in self.groups:
            if g.batch.passive_first_joint:
                t = cascade_terms(g.batch, g.q, g.v)
                out[g.arm_ids] = np.einsum("ab,ab->a", t.M[:, 0, :], t.qd)
        return out

    # --------------------------------------------------------------- stepping
    def substep(self, v_command: np.ndarray | None = None) -> SubstepRecord:
        """Advance one physics step.

        Args:
            v_command: ``None`` to use the nominal formation law, or a padded ``(N, k_max)`` array
                of desired actuated-joint velocities (entries beyond an arm's k are ignored).
        """
        sc = self.scenario
        dt = self.dt
        N = self.n_arms
        P = np.empty((N, 2))
        rec = SubstepRecord(
            v_star=np.full((N, self.k_max), np.nan),
            tau=np.full((N, self.n_max), np.nan),
            tracking_error=np.zeros(N),
            qp_status=np.full(N, int(QPStatus.NOMINAL)),
            min_barrier=np.full(N, np.inf),
            clearance=np.zeros(N),
            max_edge_error=np.nan,
            passive_momentum=np.full(N, np.nan),
        )
        per_group = []
        for g in self.groups:
            A, k = g.v.shape
            p = np.empty((A, 2))
            Jbar = np.empty((A, 2, k))
            Mc = np.empty((A, k, k))
            Hc = np.empty((A, k))
            mom = np.empty(A)
            b = g.batch
            kernels.group_terms(b.lam, b.lengths, b.base, b.phi, b.passive_first_joint, g.q, g.v,
                                p, Jbar, Mc, Hc, mom)
            P[g.arm_ids] = p
            rec.passive_momentum[g.arm_ids] = mom
            per_group.append((p, Jbar, Mc, Hc))

        if v_command is None:
            z = edge_vectors(self._incidence, P)
            e = edge_errors(z, sc.formation.distances)
            e_hat = formation_gradient(self._incidence, z, e)

        for g, (p, Jbar, Mc, Hc) in zip(self.groups, per_group, strict=True):
            A, k = g.v.shape
            if v_command is None:
                v_ref = nominal_velocity(Jbar, e_hat[g.arm_ids], sc.kp)
            else:
                v_ref = np.ascontiguousarray(v_command[g.arm_ids, :k], dtype=float)
            has_prev = g.v_star_prev is not None
            v_prev = g.v_star_prev if has_prev else g.v
            v_star = np.empty((A, k))
            tau_a = np.empty((A, k))
            status = np.empty(A, dtype=np.int64)
            min_h = np.empty(A)
            kernels.group_control(p, Jbar, Mc, Hc, g.v, v_ref, v_prev, has_prev, self.safety_filter,
                                  self._centers, self._radii, g.obstacle_mask, self.kappa, self.epsilon,
                                  self.margin, sc.ke, dt, v_star, tau_a, status, min_h)
            if self.safety_filter and self.qp_solver == "piqp" and g.obstacle_mask.any():
                A_rows, b_rows, _ = rcbf_constraints(p, Jbar, self._centers, self._radii, self.kappa,
                                                     self.epsilon, active=g.obstacle_mask,
                                                     margin=self.margin)
                result = project_velocity(v_ref, A_rows, b_rows, solver="piqp")
                v_star, status = result.v, result.status
                v_dot = (v_star - v_prev) / dt if has_prev else np.zeros_like(v_star)
                tau_a = backstepping_torque(Mc, Hc, g.v, v_star, v_dot, sc.ke)
            rec.v_star[g.arm_ids, :k] = v_star
            rec.tau[g.arm_ids, : g.n] = 0.0
            rec.tau[g.arm_ids, g.n - k : g.n] = tau_a
            rec.tracking_error[g.arm_ids] = np.linalg.norm(g.v - v_star, axis=-1)
            rec.qp_status[g.arm_ids] = status
            rec.min_barrier[g.arm_ids] = min_h
            q_new = np.empty_like(g.q)
            v_new = np.empty_like(g.v)
            kernels.group_rk4(g.batch.lam, g.batch.passive_first_joint, g.q, g.v, tau_a, dt,
                              q_new, v_new)
            g.q, g.v = q_new, v_new
            g.v_star_prev = v_star
        self.time += dt
        self.steps += 1
        self._positions = None
        P = self.positions()
        rec.clearance = self.clearance()
        rec.max_edge_error = float(np.abs(edge_length_errors(
            edge_vectors(self._incidence, P), sc.formation.distances)).max())
        np.minimum(self.min_clearance, rec.clearance, out=self.min_clearance)
        return rec

    def step(self, command: np.ndarray, substeps: int, *, torque: bool = False,
             max_speed: float = np.inf) -> StepRecord:
        """Advance ``substeps`` physics steps holding a per-arm command (the environments' path).

        Args:
            command: padded ``(N, k_max)`` array: desired actuated velocities (rad/s), tracked by
                the backstepping law and, with the safety filter on, projected by the RCBF-QP at
                every sub-step; or, with ``torque=True``, actuated torques (N·m) applied as is.
            substeps: number of physics steps.
            torque: command is a torque.
            max_speed: with ``torque`` and the filter on, the filter also keeps |v_t| ≤ max_speed.
        """
        sc = self.scenario
        N = self.n_arms
        command = np.asarray(command, dtype=float)
        if command.shape != (N, self.k_max):
            raise ValueError(f"command must have shape {(N, self.k_max)}, got {command.shape}")
        rec = StepRecord(
            v_star=np.full((N, self.k_max), np.nan),
            tau=np.full((N, self.n_max), np.nan),
            min_clearance=np.full(N, np.inf),
            min_barrier=np.full(N, np.inf),
            qp_counts=np.zeros((N, 3), dtype=np.int64),
            finite=True,
        )
        for g in self.groups:
            A, k = g.v.shape
            ids = g.arm_ids
            b = g.batch
            has_prev = g.v_star_prev is not None
            v_prev = g.v_star_prev.copy() if has_prev else np.zeros((A, k))
            v_star = np.empty((A, k))
            tau_a = np.empty((A, k))
            min_clear = np.full(A, np.inf)
            min_h = np.full(A, np.inf)
            counts = np.zeros((A, 3), dtype=np.int64)
            q, v = g.q.copy(), g.v.copy()
            ok = kernels.group_advance(
                b.lam, b.lengths, b.base, b.phi, b.passive_first_joint, q, v, v_prev, has_prev,
                np.ascontiguousarray(command[ids, :k]), torque, self.safety_filter, self._centers,
                self._radii, g.obstacle_mask, self.kappa, self.epsilon, self.margin, sc.ke, self.dt,
                int(substeps), float(max_speed), v_star, tau_a, min_clear, min_h, counts)
            g.q, g.v = q, v
            g.v_star_prev = None if torque else v_prev
            rec.finite &= bool(ok)
            rec.v_star[ids, :k] = v_star
            rec.tau[ids, : g.n] = 0.0
            rec.tau[ids, g.n - k : g.n] = tau_a
            rec.min_clearance[ids] = min_clear
            rec.min_barrier[ids] = min_h
            rec.qp_counts[ids] = counts
        self.time += substeps * self.dt
        self.steps += substeps
        self._positions = None
        np.minimum(self.min_clearance, rec.min_clearance, out=self.min_clearance)
        return rec
