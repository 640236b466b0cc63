"""The safety filter's QPs solved by qpsolvers + PIQP instead of the compiled active set: a cross-check.

An :class:`~pan1_env.engine.Engine` built with ``qp_solver="piqp"`` is given a :class:`PiqpFilter`
and steps through it while its filter is on. The filter builds the same rows the kernel builds (the
paper's end-effector rows, or the whole-arm rows of :func:`pan1_env.kernels.capsules.whole_arm_rows`),
solves them with PIQP one sub-step at a time, takes the kernel's fallbacks where a QP is infeasible,
and has the engine advance every arm one sub-step unfiltered at the velocity it found. One copy,
velocity mode; slow (a Python loop over sub-steps and arms), for tests and comparisons.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .compiled import kernels
from .dynamics import link_angles, mass_matrix
from .kernel_step import advance_compiled, advance_kind
from .safety import QPStatus, project_velocity, rcbf_constraints

if TYPE_CHECKING:
    from .engine import Engine
    from .step_record import StepRecord

__all__ = ["PiqpFilter", "whole_arm_rows", "least_violation"]

_STATUS = np.eye(3, dtype=np.int64)  # a row per QP status: added to the record's counts


class PiqpFilter:
    """Steps an engine's copy with every filtered QP solved by qpsolvers + PIQP."""

    name = "piqp"

    @staticmethod
    def check(copies: int, torque: bool = False, faults: bool = False, fault_margin: bool = False) -> None:
        """Refuse what this filter cannot do: more than one copy, torque mode, arms that lose an actuator, or the
        fault margin (whose momentum rows follow the compiled tracker)."""
        if fault_margin:
            raise ValueError("qp_solver='piqp' does not keep the fault margin (FilterParams.fault_margin); use the "
                             "compiled 'active_set' QP")
        if faults:
            raise ValueError("qp_solver='piqp' does not step arms that lose an actuator (Scenario.fault_times); "
                             "use the compiled 'active_set' QP")
        if copies != 1:
            raise ValueError("qp_solver='piqp' steps one copy; use the compiled 'active_set' QP for batches")
        if torque:
            raise ValueError("the torque-mode filter needs qp_solver='active_set'")

    def advance(self, engine: Engine, command: np.ndarray, substeps: int, torque: bool, rec: StepRecord) -> None:
        """``substeps`` sub-steps of ``engine`` at ``command (1, N, k_max)``, into ``rec``: filtered here
        while the engine's filter is on, else the engine's compiled step."""
        if engine.filter is None:
            advance_compiled(engine, command, substeps, torque, rec)
            return
        self.check(engine.copies, torque, fault_margin=engine.filter.fault_margin)
        if engine.whole_arm:
            for _ in range(substeps):
                self._whole_arm_substep(engine, command, rec)
            engine.place_obstacles()
            return
        for kind in engine.kinds:
            if kind.mask.any():
                for _ in range(substeps):
                    self._end_effector_substep(engine, kind, command, rec)
            else:  # nothing to filter: the kernel's own step
                advance_kind(engine, kind, command, substeps, rec, filtered=True)
        engine.tick(substeps)  # advance_kind steps the arms only; the clock (a moving formation's) moves here

    @staticmethod
    def _unfiltered(engine: Engine, kind, v_star: np.ndarray, rec: StepRecord) -> None:
        """One unfiltered sub-step of a kind at ``v_star``; the kernel counts it nominal (the caller
        recounts) and marks its arms finite afresh (kept from before)."""
        finite = rec.finite.copy()
        advance_kind(engine, kind, v_star, 1, rec, filtered=False)
        rec.finite &= finite

    def _end_effector_substep(self, engine: Engine, kind, command: np.ndarray, rec: StepRecord) -> None:
        """One velocity-mode sub-step of a kind whose end-effector RCBF-QP PIQP solves."""
        A, k, f = kind.A, kind.k, engine.filter
        terms = engine.kind_terms(kind)
        rows, b, h = rcbf_constraints(terms.p, terms.Jbar, kind.centers[0], kind.radii[0], f.kappa, f.epsilon,
                                      active=kind.mask, margin=f.margin, barrier=f.barrier, decay=f.decay,
                                      drift=terms.drift)
        if np.isfinite(engine.max_joint_speed):
            box = np.concatenate([np.eye(k), -np.eye(k)])
            rows = np.concatenate([rows, np.broadcast_to(box, (A, 2 * k, k))], axis=1)
            b = np.concatenate([b, np.full((A, 2 * k), engine.max_joint_speed)], axis=1)
        result = project_velocity(command[0, kind.ids, :k], rows, b, solver="piqp")
        v_star = np.zeros_like(command)
        v_star[0, kind.ids, :k] = result.v
        self._unfiltered(engine, kind, v_star, rec)
        rec.qp_counts[0, kind.ids] += _STATUS[result.status] - _STATUS[0]
        rec.min_barrier[0, kind.ids] = np.minimum(rec.min_barrier[0, kind.ids],
                                                  np.where(kind.mask, h, np.inf).min(axis=-1))

    def _whole_arm_substep(self, engine: Engine, command: np.ndarray, rec: StepRecord) -> None:
        """One velocity-mode sub-step of whole-arm safety whose QPs PIQP solves: every filtered arm's rows
        are the kernel's (at the arm's state, the clock and the other arms where they are now), an
        infeasible QP takes the kernel's fallback (the rows without the robust term, then the least
        violating velocity), and every arm then advances one sub-step unfiltered at its v*."""
        f = engine.filter
        engine.refresh_capsules(engine.joint_positions() if engine.inter_arm else None)
        v_star = np.zeros_like(command)
        status = np.zeros(engine.n_arms, dtype=np.int64)
        h_min = np.full(engine.n_arms, np.inf)
        active = kernels().capsules.CAP_ACTIVE
        for kind in engine.kinds:
            for r, i in enumerate(kind.ids):
                v0 = command[0, i, :kind.k]
                if not (kind.caps[r, :, active] != 0.0).any():
                    v_star[0, i, :kind.k] = v0
                    continue
                A, b, h_min[i] = whole_arm_rows(engine, kind, r, v0, f.epsilon)
                result = project_velocity(v0[None], A[None], b[None], solver="piqp")
                status[i], v_star[0, i, :kind.k] = result.status[0], result.v[0]
                if status[i] == QPStatus.FALLBACK:  # as the kernel: without the robust term, then least violation
                    A, b, _ = whole_arm_rows(engine, kind, r, v0, np.inf)
                    retry = project_velocity(v0[None], A[None], b[None], solver="piqp")
                    v_star[0, i, :kind.k] = retry.v[0]
                    if retry.status[0] == QPStatus.FALLBACK:
                        bounded = np.isfinite(engine.max_joint_speed)
                        v_star[0, i, :kind.k] = least_violation(v0, A, b, bounded, f.by_rate)
        for kind in engine.kinds:
            self._unfiltered(engine, kind, v_star, rec)
        rec.qp_counts[0] += _STATUS[status] - _STATUS[0]
        np.minimum(rec.min_barrier[0], h_min, out=rec.min_barrier[0])
        engine.elapsed += engine.physics_dt
        if engine.inter_arm:
            np.minimum(rec.min_clearance, engine.inter_arm_clearance(), out=rec.min_clearance)


def whole_arm_rows(engine: Engine, kind, r: int, v0: np.ndarray, epsilon: float) -> tuple:
    """The kernel's whole-arm rows ``(A (m, k), b (m,), smallest barrier)`` of row r of an engine's kind
    (arm ``ids[r % A]`` of copy ``r // A``), built from the arm's state by
    :func:`pan1_env.kernels.capsules.whole_arm_rows`, at the capsules and clocks as they are."""
    K, f, n, k = kernels().capsules, engine.filter, kind.n, kind.k
    arm, q = engine.teams[r // kind.A].arms[kind.ids[r % kind.A]], kind.q[r]
    whole = engine.whole_arm_args(kind)
    caps = whole.caps
    angles = link_angles(q) + kind.phi[r]

    def lane(x: np.ndarray) -> np.ndarray:  # one lane (W = 1) of the kernel's scratch: lanes last
        return np.ascontiguousarray(x[..., None])

    m_max = K.most_rows(n if whole.link_bodies else 1, caps.shape[1], whole.n_world, k)
    A, b, active = np.zeros((m_max, k)), np.zeros(m_max), np.zeros(m_max, dtype=bool)
    m, h = K.whole_arm_rows(r, 0, n, k, kind.passive, whole.link_bodies, whole.link_radius, whole.sensing, whole.gate,
                            whole.skin,
                            engine.physics_dt, lane(kind.lengths[r]), kind.base[r, :1].copy(),
                            kind.base[r, 1:].copy(), lane(np.cos(angles)), lane(np.sin(angles)), lane(kind.qd[r]),
                            lane(mass_matrix(arm, q)), float(kind.momentum[r]),
                            (0.0, 1.0, 0.0), caps, whole.n_world,  # no fault margin: PIQP refuses it
                            whole.start_time[r], f.kappa, epsilon, f.margin,
                            f.barrier == "distance", f.decay, f.lookahead, engine.max_joint_speed, v0.copy(), A, b,
                            active,
                            np.empty((n + 1, 2)), np.empty((caps.shape[1], K.NEAR_COLUMNS)))
    return A[:m], b[:m], h


def least_violation(v0: np.ndarray, A: np.ndarray, b: np.ndarray, speed_box: bool, by_rate: bool = False) -> np.ndarray:
    """The kernel's last resort for an infeasible whole-arm QP (its rows end with the speed box when
    ``speed_box``; violation measured by the barrier's rate with ``by_rate``, else per unit of a row's norm):
    :func:`pan1_env.kernels.last_resort.least_violation`."""
    m, k = A.shape
    v = np.empty(k)
    kernels().last_resort.least_violation(
        v0.copy(), A.copy(), b.copy(), np.ones(m, dtype=bool), m, k, 2 * k if speed_box else 0, by_rate, v,
        np.empty(m), np.empty(m), np.empty(m, dtype=np.int64), np.empty(k, dtype=np.int64), np.empty((k, k)),
        np.empty(k), np.empty(k), np.empty(k), np.empty((k, k)), np.empty(k), np.empty(m), np.empty(m))
    return v
