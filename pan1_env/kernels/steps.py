"""The steps of the sub-step kernel (:func:`pan1_env.kernels.substep._advance_arms`) on W lanes:
load the lanes' arms and filter inputs, the velocity to filter, the two filters, the tracker, RK4, the
clearance at the state reached, and the store back to the arms. Each is inlined into the kernel by numba."""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_ext import _JIT
from .capsules import CAP_ACTIVE, _joints, whole_arm_clearance_lanes, whole_arm_rows
from .last_resort import least_violation
from .physics import (
    _acceleration_lanes,
    _drift_lanes,
    _jacobian_lanes,
    _lane_angles,
    _mass_lanes,
    _position_lanes,
    _rotate_lanes,
)
from .qp import (
    STATUS_FALLBACK,
    STATUS_NOMINAL,
    STATUS_SOLVED,
    _filter_rows_lanes,
    _first_projection_lanes,
    _keep_torque,
    _project_one,
    _torque_within,
)

# The steps of _advance_arms, inlined by numba (inline="always": typed and compiled once, as part of it,
# so LLVM sees one function and keeps the stack arrays in registers; as separate compiled functions a
# new kind's first compilation took a quarter to a half longer, measured). Each takes the arrays it
# reads and writes by name, the lanes their last axis; scratch that travels together comes as one of the
# named groups of .scratch (numba inlines no call of more than 30 arguments: CPython passes those as *args), its
# heap arrays unreferenced by the kernel (_borrowed). A step tests ``whole is not None`` only on the kernel's
# own argument: numba prunes the untaken branch of an inlined step on an argument's None type, not on a local.


@njit(**_JIT, inline="always")
def _load_arms(first, hi, rows, n, k, W, lam, lengths, base, phi, q, v, v_prev, whole, arm, real, counts, lm, ln, qi,
               vi, vp, bx, by, ph, vs_last, tau_last, c, s):
    """Lanes 0 … W−1 take arms ``rows[first]`` … (the last real arm repeated as padding): their parameters,
    state and link angles (computed from q, or with whole-arm ``carried`` where the control step's
    previous call left them)."""
    if whole is not None:
        angles, carried = whole.angles, whole.carried
    for w in range(W):
        i = rows[min(first + w, hi - 1)]
        arm[w] = i
        real[w] = first + w < hi
        for x in range(3):
            counts[x, w] = 0
        for a in range(n):
            qi[a, w] = q[i, a]
            ln[a, w] = lengths[i, a]
            for b in range(n):
                lm[a, b, w] = lam[i, a, b]
        for t in range(k):
            vi[t, w] = v[i, t]
            vp[t, w] = v_prev[i, t]
            vs_last[t, w] = np.nan
            tau_last[t, w] = np.nan
        bx[w], by[w], ph[w] = base[i, 0], base[i, 1], phi[i]
        if whole is not None and carried:
            for a in range(n):
                c[a, w] = angles[i, 0, a]
                s[a, w] = angles[i, 1, a]
        else:
            _lane_angles(qi, ph, n, w, c, s)


@njit(**_JIT, inline="always")
def _load_filter(W, O, filter_on, torque_mode, v_max, centers, radii, mask, has_prev, min_clear, min_h, max_track,
                 finite_out, whole, arm, real, obstacles, lane_active, use_filter, prev_ok, live, arm_clear, arm_h,
                 arm_track):
    """The lanes' obstacles, whether each is filtered, and their running outputs; returns whether any
    lane is filtered."""
    if whole is not None:
        caps, n_world = whole.caps, whole.n_world
    for w in range(W):
        i = arm[w]
        if real[w]:
            finite_out[i] = True
        uf = filter_on and torque_mode and v_max < np.inf
        for j in range(O):
            obstacles[0, j, w] = centers[i, j, 0]
            obstacles[1, j, w] = centers[i, j, 1]
            obstacles[2, j, w] = radii[i, j]
            lane_active[j, w] = mask[i, j]
            if filter_on and mask[i, j]:
                uf = True
        if whole is not None and filter_on and not uf:
            # the first active capsule decides: a world obstacle, or the first other arm's link (active ones first)
            for j in range(min(caps.shape[1], n_world + 1)):
                if caps[i, j, CAP_ACTIVE] != 0.0:
                    uf = True
                    break
        use_filter[w] = uf
        prev_ok[w] = has_prev[i]
        live[w] = True
        arm_clear[w] = min_clear[i]
        arm_h[w] = min_h[i]
        arm_track[w] = max_track[i]
    any_filter = False
    for w in range(W):
        any_filter = any_filter | use_filter[w]
    return any_filter


@njit(**_JIT, inline="always")
def _desired_velocity(n, k, W, passive, any_filter, torque_mode, dt, command, arm, lm, vi, pj, c, s, dyn, chol, tau,
                      acc, vdes, vs, status):
    """The terms at the sub-step's state, and the velocity to filter: the command, or the one-step
    result of the commanded torque; the filtered velocity starts as it, the status as nominal."""
    M, R, Sn, Mc, Hc, qd, thd, H = dyn.M, dyn.R, dyn.Sn, dyn.Mc, dyn.Hc, dyn.qd, dyn.thd, dyn.H
    rhs, Lc, yc, ok = chol.rhs, chol.Lc, chol.yc, chol.ok
    _mass_lanes(lm, c, s, vi, pj.p1, pj.damping, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
    if torque_mode:
        for t in range(k):
            for w in range(W):
                tau[t, w] = command[arm[w], t]
        if any_filter:
            _acceleration_lanes(Mc, Hc, tau, k, W, acc, rhs, Lc, yc, ok)  # NaN where not SPD: 0 below
            for t in range(k):
                for w in range(W):
                    vdes[t, w] = vi[t, w] + dt * (acc[t, w] if ok[w] else 0.0)
    else:
        for t in range(k):
            for w in range(W):
                vdes[t, w] = command[arm[w], t]
    for t in range(k):
        for w in range(W):
            vs[t, w] = vdes[t, w]
    for w in range(W):
        status[w] = STATUS_NOMINAL


@njit(**_JIT, inline="always")
def _filter_whole_arm(sub, n, k, W, passive, rcbf, v_max, dt, whole, scratch, arm, real, ln, bx, by, c, s, dyn, pj,
                      tracker, use_filter, live, vdes, vs, status, arm_h, search):
    """Whole-arm safety: each filtered lane's rows are its bodies (``whole``: :class:`pan1_env.kernel_groups.WholeArm`)
    against its capsules at the sub-step's time, solved by the full search, one lane at a time. ``pj`` holds the
    lanes' passive momenta (their drift) and dampings; ``tracker`` the terms for the fault margin's momentum at the
    sub-step's end (:func:`_momentum_ahead`) and torque mode's input bound
    (:func:`pan1_env.kernels.qp._keep_torque`)."""
    kappa, epsilon, margin, distance, decay = rcbf.kappa, rcbf.epsilon, rcbf.margin, rcbf.distance, rcbf.decay
    by_rate, lookahead, fault, tau_max = rcbf.by_rate, rcbf.lookahead, rcbf.fault_margin, rcbf.tau_max
    M, Mc, Hc, qd, H = dyn.M, dyn.Mc, dyn.Hc, dyn.qd, dyn.H
    qidx, qv0, qvs, qtarget = search.qidx, search.qv0, search.qvs, search.qtarget
    qG, qL, qr, qlam, qcand, qy = search.qG, search.qL, search.qr, search.qlam, search.qcand, search.qy
    wA, wb, wact, wP, wnear = scratch.wA, scratch.wb, scratch.wact, scratch.wP, scratch.wnear
    wrows, wviol, wnorm, wb0, wn0 = scratch.wrows, scratch.wviol, scratch.wnorm, scratch.wb0, scratch.wn0
    caps, start_time, n_world = whole.caps, whole.start_time, whole.n_world
    rho, link_bodies, sensing, gate, skin = whole.link_radius, whole.link_bodies, whole.sensing, whole.gate, whole.skin
    torque_mode, vi = tracker.torque_mode, tracker.v
    for w in range(W):
        if use_filter[w] and live[w] and real[w]:
            for t in range(k):
                qv0[t] = vdes[t, w]
            time = start_time[arm[w]] + sub * dt
            p1 = pj.p1[w] if passive else 0.0
            # the fault margin (docs/MODEL.md §5c): the damping, and a full arm's momentum at the sub-step's end
            gain, offset = _momentum_ahead(k, w, dt, tracker, M, H) if fault and not passive else (1.0, 0.0)
            faults = (pj.damping[w] if fault else 0.0, gain, offset)
            m_w, h_w = whole_arm_rows(arm[w], w, n, k, passive, link_bodies, rho, sensing, gate, skin, dt, ln, bx, by,
                                      c, s, qd, M, p1, faults, caps, n_world, time, kappa, epsilon, margin, distance,
                                      decay, lookahead, v_max, qv0, wA, wb, wact, wP, wnear)
            arm_h[w] = min(arm_h[w], h_w)
            status[w] = _project_one(qv0, wA, wb, wact, m_w, k, qvs, wrows, qidx, qG, qr, qlam, qcand, qL, qy, wviol,
                                     wnorm)
            if status[w] == STATUS_FALLBACK:
                # infeasible: the fallback first drops the robust term (ε → ∞: the plain CBF condition,
                # which a moving obstacle or a crowd of capsules can leave feasible), then takes the
                # velocity that violates the rows least (braking does not keep a moving obstacle out);
                # reported as a fallback either way
                m_w, _ = whole_arm_rows(arm[w], w, n, k, passive, link_bodies, rho, sensing, gate, skin, dt, ln, bx,
                                        by, c, s, qd, M, p1, faults, caps, n_world, time, kappa, np.inf, margin,
                                        distance, decay, lookahead, v_max, qv0, wA, wb, wact, wP, wnear)
                if _project_one(qv0, wA, wb, wact, m_w, k, qvs, wrows, qidx, qG, qr, qlam, qcand, qL, qy, wviol,
                                wnorm) == STATUS_FALLBACK:
                    least_violation(qv0, wA, wb, wact, m_w, k, 2 * k if v_max < np.inf else 0, by_rate, qvs, wb0, wn0,
                                    wrows, qidx, qG, qr, qlam, qcand, qL, qy, wviol, wnorm)
            if torque_mode and tau_max < np.inf and status[w] != STATUS_NOMINAL and \
                    not _torque_within(w, k, dt, tau_max, Mc, Hc, vi, qvs):
                for t in range(k):  # the target of the torque bound's last resort: the filter's own answer
                    qtarget[t] = qvs[t]
                status[w] = _keep_torque(w, k, dt, tau_max, Mc, Hc, vi, qv0, qtarget,
                                         status[w] != STATUS_FALLBACK, wA, wb, wact, m_w, qvs, wrows, qidx, qG, qr,
                                         qlam, qcand, qL, qy, wviol, wnorm)
            for t in range(k):
                vs[t, w] = qvs[t]


@njit(**_JIT, inline="always")
def _momentum_ahead(k, w, dt, tracker, M, H):
    """A fully actuated arm's first-joint momentum at the end of the sub-step, p₁⁺ = g M₀ v* + p₀, as (g, p₀). q₁ is
    cyclic, so ṗ₁ = τ₁ exactly, and τ is held over the sub-step: p₁⁺ = M₀ q̇ + dt τ₁, τ = H + M acc the computed
    torque of :func:`_track`. In velocity mode acc = (v* − v*₋)/dt − K_e (q̇ − v*), so p₁⁺ = M₀ ((1 + a) v* + (1 − a) q̇
    − v*₋) + dt H₀, a = K_e dt (before a last v* is set, M₀ (a v* + (1 − a) q̇) + dt H₀); in torque mode, which reaches
    v* in one sub-step, M₀ v* + dt H₀. A jump of v* and its overshoot are then in the margin."""
    torque_mode, ke, vi, vp, prev_ok = tracker.torque_mode, tracker.ke, tracker.v, tracker.v_prev, tracker.has_prev
    offset = dt * H[0, w]
    if torque_mode:
        return 1.0, offset
    a = ke * dt
    gain = 1.0 + a if prev_ok[w] else a
    for t in range(k):
        offset += M[0, t, w] * ((1.0 - a) * vi[t, w] - (vp[t, w] if prev_ok[w] else 0.0))
    return gain, offset


@njit(**_JIT, inline="always")
def _filter_end_effector(n, k, W, passive, sizes, lane_qp, rcbf, v_max, real, ln, bx, by, c, s, dyn, pj, px, py,
                         obstacles, lane_active, use_filter, live, vdes, vs, status, arm_h, ee, search, tracker):
    """The paper's end-effector filter on every lane at once as far as one active row settles it
    (:func:`_first_projection_lanes`), then the full active-set search lane by lane. A PAn−1 arm's
    rows take the end-effector's drift J₁ p₁ / M_11 (docs/MODEL.md §7), and where p₁ ≠ 0 its fallback
    holds the end-effector instead of braking (:func:`_hold_end_effector`). The search's rows are the obstacles'
    then the speed bounds'."""
    O = obstacles.shape[1]
    m = O + 2 * k
    kappa, epsilon, margin, distance, decay = rcbf.kappa, rcbf.epsilon, rcbf.margin, rcbf.distance, rcbf.decay
    tau_max = rcbf.tau_max
    M, Mc, Hc = dyn.M, dyn.Mc, dyn.Hc
    J, Jbar, drift, filtered, row_A, row_b = ee.J, ee.Jbar, ee.drift, ee.filtered, ee.row_A, ee.row_b
    row_h, row_norm, row_act, obst_rows, needs_qp = ee.row_h, ee.row_norm, ee.row_act, ee.obst_rows, ee.needs_qp
    q_best, q_best_viol, q_Ab, q_bb = ee.q_best, ee.q_best_viol, ee.q_Ab, ee.q_bb
    q_cand, q_found = ee.q_cand, ee.q_found
    Arows, brows, active, qrows = search.Arows, search.brows, search.active, search.qrows
    qviol, qnorm, qidx, qv0, qvs = search.qviol, search.qnorm, search.qidx, search.qv0, search.qvs
    qG, qL, qr, qlam, qcand, qy = search.qG, search.qL, search.qr, search.qlam, search.qcand, search.qy
    _position_lanes(ln, bx, by, c, s, n, W, px, py)
    _jacobian_lanes(ln, c, s, M, passive, n, k, W, J, Jbar)
    _drift_lanes(J, M, pj.p1, passive, W, drift)
    for w in range(W):
        filtered[w] = use_filter[w] & live[w] & real[w]  # a padded lane's result is never used
    # numba prunes a branch only on an argument that is None: lane_qp is None in the generic kernel,
    # sizes in the per-kind ones, so each compiles one of the two QP stages
    if lane_qp is None:
        if sizes is not None:  # the generic kernel: every filtered lane to the full search (whose first
            # test is the feasibility test the lane-batched stage starts with)
            _filter_rows_lanes(px, py, Jbar, drift, obstacles, lane_active, filtered, kappa, epsilon, margin, distance,
                               decay, O, k, W, arm_h, row_A, row_b, row_h, obst_rows)
            for w in range(W):
                needs_qp[w] = filtered[w]
                q_found[w] = False
    else:
        _first_projection_lanes(px, py, Jbar, drift, obstacles, lane_active, filtered, kappa, epsilon, margin, distance,
                                decay, v_max, O, k, W, vdes, arm_h, row_A, row_b, row_h, row_norm, row_act, obst_rows,
                                needs_qp, q_best, q_best_viol, q_Ab, q_bb, q_cand, q_found)
    for w in range(W):
        if needs_qp[w] and q_found[w]:
            status[w] = STATUS_SOLVED
            for t in range(k):
                vs[t, w] = q_cand[t, w]
        elif needs_qp[w]:  # the full active-set search, on this lane's RCBF rows (speed rows set above)
            for j in range(O):
                for t in range(k):
                    Arows[j, t] = obst_rows[j, t, w]
                brows[j] = obst_rows[j, k, w]
                active[j] = lane_active[j, w]
            for t in range(k):
                qv0[t] = vdes[t, w]
            status[w] = _project_one(qv0, Arows, brows, active, m, k, qvs, qrows, qidx, qG, qr, qlam, qcand, qL, qy,
                                     qviol, qnorm)
            if status[w] == STATUS_FALLBACK and passive and pj.p1[w] != 0.0:
                _hold_end_effector(k, w, Jbar, drift, v_max, qvs)
            for t in range(k):
                vs[t, w] = qvs[t]
    if tracker.torque_mode and tau_max < np.inf:
        _bound_torque(k, W, O, m, tau_max, v_max, Mc, Hc, tracker, obst_rows, lane_active, filtered, vdes, vs, status,
                      search)


@njit(**_JIT, inline="always")
def _bound_torque(k, W, O, m, tau_max, v_max, Mc, Hc, tracker, obst_rows, lane_active, filtered, vdes, vs, status,
                  search):
    """Torque mode's input bound on the end-effector filter's lanes (docs/MODEL.md §5d): a lane whose filtered
    velocity needs more than ±τ_max in its sub-step takes the QP again with the torque rows
    (:func:`pan1_env.kernels.qp._keep_torque`), and where that has no solution, the velocity nearest the filter's
    own answer (its braking or hold included) within the bound: as far towards it as the bound allows."""
    Arows, brows, active, qrows = search.Arows, search.brows, search.active, search.qrows
    qviol, qnorm, qidx, qv0, qvs = search.qviol, search.qnorm, search.qidx, search.qv0, search.qvs
    qG, qL, qr, qlam, qcand, qy = search.qG, search.qL, search.qr, search.qlam, search.qcand, search.qy
    qtarget = search.qtarget
    dt, vi = tracker.dt, tracker.v
    for w in range(W):
        if not filtered[w] or status[w] == STATUS_NOMINAL:
            continue
        for t in range(k):
            qvs[t] = vs[t, w]
        if _torque_within(w, k, dt, tau_max, Mc, Hc, vi, qvs):
            continue
        for j in range(O):
            for t in range(k):
                Arows[j, t] = obst_rows[j, t, w]
            brows[j] = obst_rows[j, k, w]
            active[j] = lane_active[j, w]
        for t in range(k):  # the last resort's target: the filter's own answer (its braking or hold included)
            qv0[t] = vdes[t, w]
            qtarget[t] = vs[t, w]
        status[w] = _keep_torque(w, k, dt, tau_max, Mc, Hc, vi, qv0, qtarget, status[w] != STATUS_FALLBACK, Arows,
                                 brows, active, m, qvs, qrows, qidx, qG, qr, qlam, qcand, qL, qy, qviol, qnorm)
        for t in range(k):
            vs[t, w] = qvs[t]
        for j in range(O, m):  # the speed rows, which the fallback's search left inactive
            active[j] = v_max < np.inf


@njit(**_JIT)  # not inlined: the same types in every kind, so compiled once, not once per kind
def _hold_end_effector(k, w, Jbar, drift, v_max, v):
    """The fallback of a drifting PAn−1 arm (lane w): braking (v = 0) leaves its end-effector moving at the drift
    d = J₁ p₁ / M_11, so the actuated speeds that hold it, v = −J̄⁺ d (least squares, ṗ = J̄ v + d), scaled
    into the speed bound; ḣ = ∇h · ṗ is then 0 wherever J̄ has rank 2 and the bound allows."""
    a, c, e = 0.0, 0.0, 0.0  # J̄ J̄ᵀ = [[a, c], [c, e]]
    for t in range(k):
        a += Jbar[0, t, w] * Jbar[0, t, w]
        c += Jbar[0, t, w] * Jbar[1, t, w]
        e += Jbar[1, t, w] * Jbar[1, t, w]
    det = a * e - c * c
    if det > 1e-12 * (a * e + 1e-300):  # v = −J̄ᵀ (J̄ J̄ᵀ)⁻¹ d
        y0, y1 = (e * drift[0, w] - c * drift[1, w]) / det, (a * drift[1, w] - c * drift[0, w]) / det
    elif a + e > 0.0:  # rank 1 (one actuated joint, or a singular posture): along J̄'s one direction
        y0, y1 = drift[0, w] / (a + e), drift[1, w] / (a + e)
    else:
        y0, y1 = 0.0, 0.0
    peak = 0.0
    for t in range(k):
        v[t] = -(Jbar[0, t, w] * y0 + Jbar[1, t, w] * y1)
        peak = max(peak, abs(v[t]))
    if peak > v_max:
        for t in range(k):
            v[t] *= v_max / peak


@njit(**_JIT, inline="always")
def _track(k, W, torque_mode, ke, inv_dt, vi, vp, Mc, Hc, use_filter, live, prev_ok, status, counts, arm_track, vs,
           acc, tau, vs_last, tau_last):
    """The torque of the sub-step: the backstepping tracker of v* (Eq. 64, v̇* by backward difference)
    in velocity mode; in torque mode the command, or, where the filter changed its velocity, the torque
    that reaches the filtered velocity in one sub-step. Counts the QP statuses, keeps the outputs."""
    for x in range(3):
        for w in range(W):
            counts[x, w] += 1 if live[w] and status[w] == x else 0
    if not torque_mode:
        for w in range(W):
            err = 0.0
            for t in range(k):
                e = vi[t, w] - vs[t, w]
                err += e * e
            err = np.sqrt(err)
            arm_track[w] = err if live[w] and err > arm_track[w] else arm_track[w]
        for t in range(k):
            for w in range(W):
                vdot = (vs[t, w] - vp[t, w]) * inv_dt if prev_ok[w] else 0.0
                acc[t, w] = vdot - ke * (vi[t, w] - vs[t, w])
        for r in range(k):
            for w in range(W):
                tr = Hc[r, w]
                for t in range(k):
                    tr += Mc[r, t, w] * acc[t, w]
                tau[r, w] = tr
        for t in range(k):
            for w in range(W):
                vp[t, w] = vs[t, w] if live[w] else vp[t, w]
        for w in range(W):
            prev_ok[w] = prev_ok[w] | live[w]
    else:
        for w in range(W):
            if status[w] != STATUS_NOMINAL:
                for r in range(k):
                    tr = Hc[r, w]
                    for t in range(k):
                        tr += Mc[r, t, w] * (vs[t, w] - vi[t, w]) * inv_dt
                    tau[r, w] = tr
            elif not use_filter[w]:
                for t in range(k):
                    vs[t, w] = np.nan
    for t in range(k):
        for w in range(W):
            vs_last[t, w] = vs[t, w] if live[w] else vs_last[t, w]
            tau_last[t, w] = tau[t, w] if live[w] else tau_last[t, w]


@njit(**_JIT, inline="always")
def _rk4(n, k, W, passive, dt, finite_out, arm, real, live, lm, qi, vi, pj, tau, c, s, c0, s0, dyn, chol, stages):
    """One RK4 step with τ held; returns the number of lanes still live. The first stage uses the terms
    at the current state, and every stage's link angles come from the current ones (c0, s0) by a small
    rotation. A PAn−1 arm's momentum p₁ is integrated with them, ṗ₁ = −b q̇₁ (constant without damping).
    A lane whose state goes non-finite stops at its last finite state."""
    M, R, Sn, Mc, Hc, qd, thd, H = dyn.M, dyn.R, dyn.Sn, dyn.Mc, dyn.Hc, dyn.qd, dyn.thd, dyn.H
    rhs, Lc, yc, ok = chol.rhs, chol.Lc, chol.yc, chol.ok
    qt, vt, dv, sq, sv, pt, sp = stages.qt, stages.vt, stages.dv, stages.sq, stages.sv, stages.pt, stages.sp
    p1, damping = pj.p1, pj.damping
    for a in range(n):
        for w in range(W):
            c0[a, w] = c[a, w]
            s0[a, w] = s[a, w]
    _acceleration_lanes(Mc, Hc, tau, k, W, dv, rhs, Lc, yc, ok)
    for a in range(n):
        for w in range(W):
            sq[a, w] = qd[a, w]
    for t in range(k):
        for w in range(W):
            sv[t, w] = dv[t, w]
    if passive:
        for w in range(W):
            sp[w] = -damping[w] * qd[0, w]
    for stage in range(3):
        hs = 0.5 * dt if stage < 2 else dt
        g = 2.0 if stage < 2 else 1.0
        for t in range(k):
            for w in range(W):
                vt[t, w] = vi[t, w] + hs * dv[t, w]
        if passive:  # the stage's momentum, from the previous stage's q̇₁
            for w in range(W):
                pt[w] = p1[w] - hs * damping[w] * qd[0, w]
        # the stage's state q + hs q̇: its link angles θ + hs θ̇ (θ̇ = thd of the previous stage)
        _rotate_lanes(c0, s0, thd, hs, n, W, c, s)
        _mass_lanes(lm, c, s, vt, pt, damping, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
        _acceleration_lanes(Mc, Hc, tau, k, W, dv, rhs, Lc, yc, ok)
        for a in range(n):
            for w in range(W):
                sq[a, w] += g * qd[a, w]
        for t in range(k):
            for w in range(W):
                sv[t, w] += g * dv[t, w]
        if passive:
            for w in range(W):
                sp[w] -= g * damping[w] * qd[0, w]
    for w in range(W):
        finite = True
        acc_th = 0.0
        for a in range(n):
            qt[a, w] = qi[a, w] + dt / 6.0 * sq[a, w]
            acc_th += sq[a, w]
            thd[a, w] = acc_th  # Σ of the weighted stage speeds: the step moves link angle a by dt/6 · thd
            finite = finite & np.isfinite(qt[a, w])
        for t in range(k):
            vt[t, w] = vi[t, w] + dt / 6.0 * sv[t, w]
            finite = finite & np.isfinite(vt[t, w])
        if passive:
            pt[w] = p1[w] + dt / 6.0 * sp[w]
            finite = finite & np.isfinite(pt[w])
        if live[w] and not finite:
            live[w] = False
            if real[w]:
                finite_out[arm[w]] = False
    _rotate_lanes(c0, s0, thd, dt / 6.0, n, W, c, s)
    n_live = 0
    for w in range(W):
        if live[w]:
            n_live += 1
            for a in range(n):
                qi[a, w] = qt[a, w]
            for t in range(k):
                vi[t, w] = vt[t, w]
            if passive:
                p1[w] = pt[w]
        else:  # frozen at its last finite state (whose angles the sub-step started from)
            for a in range(n):
                c[a, w] = c0[a, w]
                s[a, w] = s0[a, w]
    return n_live


@njit(**_JIT, inline="always")
def _clearance_after(time, n, W, O, whole, scratch, arm, live, ln, bx, by, c, s, px, py, obstacles, arm_clear):
    """Running minimum into ``arm_clear`` of each live lane's clearance at the state its sub-step reached, ``time``
    after the call's start (a stopped lane keeps its value): the end effector's to the filter's obstacles, and with
    ``whole`` the bodies' to the world's obstacles at each arm's clock ``whole.start_time`` + ``time``."""
    _position_lanes(ln, bx, by, c, s, n, W, px, py)
    for j in range(O):
        for w in range(W):
            dx, dy = px[w] - obstacles[0, j, w], py[w] - obstacles[1, j, w]
            cl = np.sqrt(dx * dx + dy * dy) - obstacles[2, j, w]
            arm_clear[w] = cl if live[w] and cl < arm_clear[w] else arm_clear[w]
    if whole is not None:
        whole_arm_clearance_lanes(arm, live, n, W, whole.link_bodies, whole.link_radius, ln, bx, by, c, s, whole.caps,
                                  whole.n_world, whole.start_time, time, scratch.joints_x, scratch.joints_y,
                                  scratch.ox, scratch.oy, scratch.orad, arm_clear)


@njit(**_JIT, inline="always")
def _store_outputs(k, W, arm, real, has_prev, prev_ok, qp_counts, counts, min_clear, arm_clear, min_h, arm_h,
                   max_track, arm_track, v_star_out, vs_last, tau_out, tau_last, v, vi, v_prev, vp):
    """The real lanes' running outputs, velocities and last commands back to their arms."""
    tau_off = tau_out.shape[1] - k  # 0 for (A, k) torques; n − k for full (A, n) rows (passive entries untouched)
    for w in range(W):
        if real[w]:
            i = arm[w]
            has_prev[i] = prev_ok[w]
            for x in range(3):
                qp_counts[i, x] += counts[x, w]
            min_clear[i] = arm_clear[w]
            min_h[i] = arm_h[w]
            max_track[i] = arm_track[w]
            for t in range(k):
                v_star_out[i, t] = vs_last[t, w]
                tau_out[i, tau_off + t] = tau_last[t, w]
                v[i, t] = vi[t, w]
                v_prev[i, t] = vp[t, w]


@njit(**_JIT, inline="always")
def _store_state(n, k, W, passive, whole, scratch, q, momentum, qd_out, p_out, arm, real, live, ph, lm, ln, bx, by, qi,
                 vi, pj, c, s, dyn, px, py):
    """The real lanes' joint angles back to their arms, with the joint velocities and end-effector at the
    (last finite) state (a stopped arm's angles from q), and with whole-arm safety its joints and link
    angles; a whole-arm call that does not ``finish`` leaves the joint velocities and end-effectors out."""
    M, R, Sn, Mc, Hc, qd, thd, H = dyn.M, dyn.R, dyn.Sn, dyn.Mc, dyn.Hc, dyn.qd, dyn.thd, dyn.H
    finish = True
    if whole is not None:
        joints_out, angles, finish, wP = whole.joints, whole.angles, whole.finish, scratch.wP
    for w in range(W):
        if not live[w]:
            _lane_angles(qi, ph, n, w, c, s)
    if finish:
        _mass_lanes(lm, c, s, vi, pj.p1, pj.damping, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
        _position_lanes(ln, bx, by, c, s, n, W, px, py)
    for w in range(W):
        if real[w]:
            i = arm[w]
            for a in range(n):
                q[i, a] = qi[a, w]
            if passive:
                momentum[i] = pj.p1[w]
            if finish:
                for a in range(n):
                    qd_out[i, a] = qd[a, w]
                p_out[i, 0] = px[w]
                p_out[i, 1] = py[w]
            if whole is not None:
                for a in range(n):
                    angles[i, 0, a] = c[a, w]
                    angles[i, 1, a] = s[a, w]
                _joints(ln, bx, by, c, s, n, w, wP)
                for a in range(joints_out.shape[1]):
                    joints_out[i, a, 0] = wP[min(a, n), 0]
                    joints_out[i, a, 1] = wP[min(a, n), 1]
