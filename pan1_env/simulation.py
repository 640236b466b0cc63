"""A team of arms stepping in time under the paper's controller: state, physics sub-steps, safety.

:class:`Simulation` holds the state of every arm of a :class:`~pan1_env.scenario.Scenario` in
arrays batched over arms that share their number of links and their actuation (an
:class:`ArmGroup`), so a step costs a fixed number of calls per group, not per arm.

:meth:`Simulation.step` holds a command for a number of physics sub-steps (``physics_dt`` each).
At every sub-step, for every arm:

1. with the safety filter on, the command (a desired velocity, or in torque mode the velocity the
   torque would produce after one sub-step) is projected by the RCBF-QP (Eq. 61), re-solved at the
   current state;
2. in velocity mode the result v* is tracked by the backstepping torque (Eq. 64) with v̇* a backward
   finite difference over the sub-step (the paper, Remark 5);
3. one RK4 step of the cascaded state with that torque held (zero-order hold);
4. the clearance of the end-effector to every obstacle at the new state.

The paper's controller is :meth:`nominal_velocity` (Eq. 39) as the command, recomputed every
control step: with ``control_dt = physics_dt`` (the paper scenarios) that is every sub-step.

The sub-steps run in the compiled kernel :func:`pan1_env.kernels.group_advance` (checked in the
tests against the numpy reference formulas of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety` and :mod:`pan1_env.control`). With ``qp_solver="piqp"`` the filter's QP
is solved by qpsolvers + PIQP instead, one sub-step at a time. Nothing here knows Gymnasium; the
CLI's ``reproduce`` and the environments drive it. Arms are numbered from 0 in team order; padded
team arrays use NaN beyond an arm's size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import kernels
from .control import nominal_velocity
from .dynamics import ArmBatch
from .formation import edge_errors, edge_vectors, formation_gradient
from .safety import QP_SOLVERS, clearance, project_velocity, rcbf_constraints
from .scenario import Scenario

__all__ = ["ArmGroup", "Simulation", "StepRecord"]


@dataclass
class ArmGroup:
    """Arms of one kind (same n, same actuation), stacked for batched computation."""

    arm_ids: np.ndarray  # (A,) indices in team order
    batch: ArmBatch
    centers: np.ndarray  # (A, O, 2) the team's obstacles, seen by every arm of the group
    radii: np.ndarray  # (A, O)
    obstacle_mask: np.ndarray  # (A, O) obstacles in each arm's filter
    q: np.ndarray  # (A, n); this and the other state arrays are updated in place, never replaced
    v: np.ndarray  # (A, k)
    v_star_prev: np.ndarray  # (A, k) v* of the last velocity-mode sub-step (valid where has_prev)
    has_prev: np.ndarray  # (A,) bool
    qd: np.ndarray  # (A, n) q̇ at the current state
    p: np.ndarray  # (A, 2) end-effector at the current state
    whole_team: bool = False  # the group is the whole team in team order (no gather/scatter needed)
    sizes: tuple = field(init=False)  # kernel_sizes(n, k): the kernel's compile-time sizes

    def __post_init__(self) -> None:
        self.sizes = kernels.kernel_sizes(self.q.shape[1], self.v.shape[1])

    @property
    def n(self) -> int:
        return self.batch.n_links

    @property
    def k(self) -> int:
        return self.batch.n_actuated


@dataclass
class StepRecord:
    """What one :meth:`Simulation.step` (sub-steps with a held command) produced, per arm."""

    v_star: np.ndarray  # (N, k_max) v* of the last sub-step (NaN in unfiltered torque mode)
    tau: np.ndarray  # (N, n_max) full joint torques of the last sub-step (passive entry 0)
    min_clearance: np.ndarray  # (N,) smallest clearance after any of the sub-steps
    min_barrier: np.ndarray  # (N,) smallest filtered barrier value h seen (inf: no row)
    qp_counts: np.ndarray  # (N, 3) sub-steps per QPStatus (all NOMINAL when the filter is off)
    max_tracking_error: np.ndarray  # (N,) largest ‖v − v*‖ at the start of a sub-step
    finite: bool  # False if a state went non-finite (that arm is left at its last finite state)


class Simulation:
    """The paper's closed loop for one scenario.

    Args:
        scenario: a validated :class:`~pan1_env.scenario.Scenario`.
        safety_filter: ``True`` filters every command through the RCBF-QP ("safe" controller);
            ``False`` tracks it directly ("nominal" controller).
        qp_solver: ``"active_set"`` (exact, compiled) or ``"piqp"`` (qpsolvers + PIQP).
        physics_dt: overrides the scenario's physics step (seconds).
    """

    def __init__(self, scenario: Scenario, *, safety_filter: bool = True, qp_solver: str = "active_set",
                 physics_dt: float | None = None) -> None:
        if qp_solver not in QP_SOLVERS:
            raise ValueError(f"unknown qp_solver {qp_solver!r}; choose one of {QP_SOLVERS}")
        self.scenario = scenario
        self.safety_filter = bool(safety_filter)
        self.qp_solver = qp_solver
        #: RCBF parameters used by the filter (the scenario's unless overridden, e.g. by a shield)
        self.kappa, self.epsilon, self.margin = scenario.kappa, scenario.epsilon, scenario.safety_margin
        self.dt = float(scenario.physics_dt if physics_dt is None else physics_dt)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"physics_dt must be positive, got {physics_dt!r}")
        self.n_arms = scenario.n_arms
        self.n_max = max(a.n_links for a in scenario.arms)
        self.k_max = max(a.n_actuated for a in scenario.arms)
        self._incidence = scenario.formation.incidence
        self._centers = np.ascontiguousarray(scenario.obstacles.centers)
        self._radii = np.ascontiguousarray(scenario.obstacles.radii)
        mask = scenario.obstacle_mask()
        kinds: dict[tuple[int, bool], list[int]] = {}
        for i, arm in enumerate(scenario.arms):
            kinds.setdefault((arm.n_links, arm.passive_first_joint), []).append(i)
        N = self.n_arms
        self._record_template = StepRecord(  # a StepRecord's initial values
            v_star=np.full((N, self.k_max), np.nan), tau=np.full((N, self.n_max), np.nan),
            min_clearance=np.full(N, np.inf), min_barrier=np.full(N, np.inf),
            qp_counts=np.zeros((N, 3), dtype=np.int64), max_tracking_error=np.zeros(N), finite=True)
        self.groups: list[ArmGroup] = []  # (the template's τ is 0 at every passive joint, NaN where unset)
        for (n, _passive), ids in sorted(kinds.items()):
            batch = ArmBatch.stack([scenario.arms[i] for i in ids])
            A, k = len(ids), batch.n_actuated
            self.groups.append(ArmGroup(
                arm_ids=np.array(ids), batch=batch,
                # writable copies (a one-arm broadcast would stay a read-only view, another kernel type)
                centers=np.broadcast_to(self._centers, (A, *self._centers.shape)).copy(),
                radii=np.broadcast_to(self._radii, (A, len(self._radii))).copy(),
                obstacle_mask=np.ascontiguousarray(mask[ids]), q=np.zeros((A, n)), v=np.zeros((A, k)),
                v_star_prev=np.zeros((A, k)), has_prev=np.zeros(A, dtype=bool), qd=np.zeros((A, n)),
                p=np.zeros((A, 2)), whole_team=(A == self.n_arms)))
            if _passive:
                self._record_template.tau[ids, 0] = 0.0
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, q0: list[np.ndarray] | None = None) -> None:
        """Put every arm at rest at ``q0`` (default: the scenario's), time 0."""
        q0 = self.scenario.q0 if q0 is None else q0
        if len(q0) != self.n_arms:
            raise ValueError(f"q0 needs one configuration per arm ({self.n_arms}), got {len(q0)}")
        for g in self.groups:
            rows = [np.asarray(q0[i], dtype=float) for i in g.arm_ids]
            for i, row in zip(g.arm_ids, rows, strict=True):
                if row.shape != (g.n,) or not np.all(np.isfinite(row)):
                    raise ValueError(f"q0[{i}] must be {g.n} finite joint angles, got {row.tolist()}")
            # in place: a group's state arrays live as long as the Simulation (views of them stay valid)
            g.q[...] = rows
            g.v[...] = 0.0
            g.v_star_prev[...] = 0.0
            g.has_prev[...] = False
            g.qd[...] = 0.0
            kernels.group_end_effectors(g.batch.lengths, g.batch.base, g.batch.phi, g.q, g.p)
        self.time = 0.0
        self.steps = 0
        self._positions = None
        self._terms_cache: dict = {}
        self.min_clearance = self.clearance()  # (N,) running minimum since reset

    def positions(self) -> np.ndarray:
        """End-effector positions of every arm, ``(N, 2)`` (a read-only view, cached per state)."""
        if self._positions is None:
            if len(self.groups) == 1 and self.groups[0].whole_team:
                P = self.groups[0].p.copy()
            else:
                P = np.empty((self.n_arms, 2))
                for g in self.groups:
                    P[g.arm_ids] = g.p
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
            q[g.arm_ids, : g.n] = g.q
            qd[g.arm_ids, : g.n] = g.qd
        return q, qd

    def _group_terms(self, g: ArmGroup):
        """Positions, J̄ and passive momentum of a group at the current state (cached per state)."""
        key = id(g)
        if key in self._terms_cache:
            return self._terms_cache[key]
        A, k = g.v.shape
        p, Jbar = np.empty((A, 2)), np.empty((A, 2, k))
        Mc, Hc, mom = np.empty((A, k, k)), np.empty((A, k)), np.empty(A)
        b = g.batch
        kernels.group_terms(b.lam, b.lengths, b.base, b.phi, b.passive_first_joint, g.q, g.v, p, Jbar, Mc, Hc, mom)
        self._terms_cache[key] = (p, Jbar, mom)
        return p, Jbar, mom

    def passive_momentum(self) -> np.ndarray:
        """Σ_α M_1α q̇_α for every arm, ``(N,)`` (NaN for fully actuated arms)."""
        out = np.full(self.n_arms, np.nan)
        for g in self.groups:
            out[g.arm_ids] = self._group_terms(g)[2]
        return out

    def nominal_velocity(self) -> np.ndarray:
        """The distributed formation law v_i0 = −K_P J̄_iᵀ ê_i (Eq. 39) of every arm, ``(N, k_max)``."""
        P = self.positions()
        z = edge_vectors(self._incidence, P)
        e_hat = formation_gradient(self._incidence, z, edge_errors(z, self.scenario.formation.distances))
        out = np.zeros((self.n_arms, self.k_max))
        for g in self.groups:
            _, Jbar, _ = self._group_terms(g)
            out[g.arm_ids, : g.k] = nominal_velocity(Jbar, e_hat[g.arm_ids], self.scenario.kp)
        return out

    # --------------------------------------------------------------- stepping
    def step(self, command: np.ndarray, substeps: int, *, torque: bool = False,
             max_speed: float = np.inf) -> StepRecord:
        """Advance ``substeps`` physics steps holding a per-arm command.

        Args:
            command: padded ``(N, k_max)`` array: desired actuated velocities (rad/s), tracked by
                the backstepping law and, with the safety filter on, projected by the RCBF-QP at
                every sub-step; or, with ``torque=True``, actuated torques (N·m).
            substeps: number of physics steps (a positive integer).
            torque: the command is a torque.
            max_speed: with the filter on, the filter also keeps every filtered speed |v_t| ≤ max_speed
                (the environments pass their ``max_joint_speed``; the paper's controller has no bound).
        """
        N = self.n_arms
        command = np.asarray(command, dtype=float)
        if command.shape != (N, self.k_max):
            raise ValueError(f"command must have shape {(N, self.k_max)}, got {command.shape}")
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        substeps = int(substeps)
        max_speed = float(max_speed)
        # fresh arrays every step (records handed out are never overwritten), copied from templates
        t = self._record_template
        rec = StepRecord(v_star=t.v_star.copy(), tau=t.tau.copy(), min_clearance=t.min_clearance.copy(),
                         min_barrier=t.min_barrier.copy(), qp_counts=t.qp_counts.copy(),
                         max_tracking_error=t.max_tracking_error.copy(), finite=True)
        piqp = self.safety_filter and self.qp_solver == "piqp"
        if piqp and torque:
            raise ValueError("the torque-mode filter needs qp_solver='active_set'")
        for g in self.groups:
            if piqp and g.obstacle_mask.any():
                for _ in range(substeps):
                    v_star, status, min_h = self._piqp_filter(g, command[g.arm_ids, : g.k], max_speed)
                    self._advance_group(g, v_star, 1, False, False, max_speed, rec)
                    rec.qp_counts[g.arm_ids] += np.eye(3, dtype=np.int64)[status] - np.eye(3, dtype=np.int64)[0]
                    rec.min_barrier[g.arm_ids] = np.minimum(rec.min_barrier[g.arm_ids], min_h)
            else:
                self._advance_group(g, command if g.whole_team else command[g.arm_ids, : g.k], substeps, torque,
                                    self.safety_filter, max_speed, rec)
        self.time += substeps * self.dt
        self.steps += substeps
        if not rec.finite:  # a faulty arm stopped early: include the (finite) state it was left in
            np.minimum(rec.min_clearance, self.clearance(), out=rec.min_clearance)
        np.minimum(self.min_clearance, rec.min_clearance, out=self.min_clearance)
        return rec

    def _advance_group(self, g: ArmGroup, command: np.ndarray, substeps: int, torque: bool, filter_on: bool,
                       max_speed: float, rec: StepRecord) -> None:
        k, n = g.v.shape[1], g.q.shape[1]
        A = len(g.arm_ids)
        finite = np.empty(A, dtype=bool)
        whole = g.whole_team  # then n = n_max and k = k_max
        if whole:  # the kernel writes straight into the record (it accumulates minima and counts)
            v_star, tau_a = rec.v_star, rec.tau  # full rows: the passive entries keep the template's 0
            min_clear, min_h, counts, track = rec.min_clearance, rec.min_barrier, rec.qp_counts, rec.max_tracking_error
        else:
            ids = g.arm_ids
            v_star, tau_a = np.empty((A, k)), np.zeros((A, n))  # full rows, passive entries 0
            min_clear, min_h = rec.min_clearance[ids], rec.min_barrier[ids]
            counts, track = np.zeros((A, 3), dtype=np.int64), rec.max_tracking_error[ids]
            command = command[:, :k]
        b = g.batch
        kernels.group_advance(
            *g.sizes, b.lam, b.lengths, b.base, b.phi, b.passive_first_joint, g.q, g.v, g.v_star_prev, g.has_prev,
            command if command.flags.c_contiguous else np.ascontiguousarray(command), torque, filter_on, g.centers,
            g.radii, g.obstacle_mask, self.kappa, self.epsilon, self.margin, self.scenario.ke, self.dt, substeps,
            max_speed, v_star, tau_a, g.qd, g.p, min_clear, min_h, counts, track, finite)
        if torque:
            g.has_prev[:] = False
        self._positions = None
        self._terms_cache = {}
        if False in finite.tolist():
            rec.finite = False
        if not whole:
            rec.v_star[ids, :k] = v_star
            rec.tau[ids, :n] = tau_a
            rec.min_clearance[ids] = min_clear
            rec.min_barrier[ids] = min_h
            rec.qp_counts[ids] += counts
            rec.max_tracking_error[ids] = track

    def _piqp_filter(self, g: ArmGroup, v_ref: np.ndarray, max_speed: float):
        """The RCBF-QP of one sub-step solved by qpsolvers + PIQP (``qp_solver="piqp"``)."""
        p, Jbar, _ = self._group_terms(g)
        A, b, h = rcbf_constraints(p, Jbar, self._centers, self._radii, self.kappa, self.epsilon,
                                   active=g.obstacle_mask, margin=self.margin)
        if np.isfinite(max_speed):
            n_arms, k = v_ref.shape
            box = np.concatenate([np.eye(k), -np.eye(k)])
            A = np.concatenate([A, np.broadcast_to(box, (n_arms, 2 * k, k))], axis=1)
            b = np.concatenate([b, np.full((n_arms, 2 * k), float(max_speed))], axis=1)
        result = project_velocity(v_ref, A, b, solver="piqp")
        return result.v, result.status, np.where(g.obstacle_mask, h, np.inf).min(axis=-1)

