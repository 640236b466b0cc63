"""The sub-step kernel: every arm of a group advanced through the physics sub-steps of a control step
(filter, backstepping tracker, RK4), W arms at once; serial and multi-threaded entry points."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..compiled import Control, Physics, Record, Shield, State, WholeArm
from ._numba_ext import _JIT, _LANES, _check_chunks, _local, _quick_when, _slp_vectorised
from .capsules import (
    CAP_ACTIVE,
    NEAR_COLUMNS,
    _joints,
    least_violation,
    whole_arm_clearance_lanes,
    whole_arm_rows,
)
from .physics import (
    _acceleration_lanes,
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
    _project_one,
)

# The kernel's scratch space, named: built from stack arrays (_local) in _advance_arms and handed to the
# steps of a sub-step below. Each lane's arm, parameters and state; kinematics and dynamics at a state;
# command, filter and tracker; the outputs of each lane's last sub-step (kept when it stops); RK4's
# trial state, stage derivative and weighted sums.
_Lanes = namedtuple("_Lanes", "arm real lm ln qi vi vp bx by ph c s qd thd H c0 s0 px py M R Sn J Mc Hc Jbar Lc yc rhs "
                              "ok vdes vs tau acc use_filter prev_ok live status arm_clear arm_h arm_track vs_last "
                              "tau_last counts qt vt dv sq sv")
# the end-effector filter of every lane: its obstacles (centre x, y, radius), active rows, RCBF rows (A_j,
# b_j, ‖A_j‖), one row at a time, the first candidate (_first_projection_lanes); and one lane's rows for
# the full search (speed rows last)
_EndEffector = namedtuple("_EndEffector", "obstacles lane_active obst_rows row_A row_b row_h row_norm row_act filtered "
                                          "needs_qp q_best q_best_viol q_found q_Ab q_bb q_cand A b active rows viol "
                                          "norm")
# one lane's full QP search (_project_one, least_violation): its command, answer and factorisation
_Search = namedtuple("_Search", "v0 vs idx G L r lam cand y")
# whole-arm safety: the lanes' joints and obstacles for the clearance, one lane's rows (bodies × capsules,
# speed bounds) and its joints
_WholeScratch = namedtuple("_WholeScratch", "joints_x joints_y ox oy orad A b active rows viol norm P b0 n0 near")


@njit(**_JIT, forceinline=True)
def _load_lanes(first, hi, n, k, W, O, arms, st, ctl, out, sh, wh, x, e):
    """Copy the arms ``first …`` (the last repeated up to W lanes) into the lanes; True if any lane filters."""
    for w in range(W):
        i = min(first + w, hi - 1)
        x.arm[w] = i
        x.real[w] = first + w < hi
        for y in range(3):
            x.counts[y, w] = 0
        for a in range(n):
            x.qi[a, w] = st.q[i, a]
            x.ln[a, w] = arms.lengths[i, a]
            for b in range(n):
                x.lm[a, b, w] = arms.lam[i, a, b]
        for t in range(k):
            x.vi[t, w] = st.v[i, t]
            x.vp[t, w] = st.v_prev[i, t]
            x.vs_last[t, w] = np.nan
            x.tau_last[t, w] = np.nan
        x.bx[w], x.by[w], x.ph[w] = arms.base[i, 0], arms.base[i, 1], arms.phi[i]
        if x.real[w]:
            out.finite[i] = True
        uf = sh.on and ctl.torque_mode and sh.v_max < np.inf
        for j in range(O):
            e.obstacles[0, j, w] = sh.centers[i, j, 0]
            e.obstacles[1, j, w] = sh.centers[i, j, 1]
            e.obstacles[2, j, w] = sh.radii[i, j]
            e.lane_active[j, w] = sh.mask[i, j]
            if sh.on and sh.mask[i, j]:
                uf = True
        if wh is not None and sh.on and not uf:
            for j in range(wh.caps.shape[1]):  # the first active capsule decides (and spares the others' reads)
                if wh.caps[i, j, CAP_ACTIVE] != 0.0:
                    uf = True
                    break
        x.use_filter[w] = uf
        x.prev_ok[w] = st.has_prev[i]
        x.live[w] = True
        x.arm_clear[w] = out.min_clear[i]
        x.arm_h[w] = out.min_h[i]
        x.arm_track[w] = out.max_track[i]
        if wh is not None and wh.carried:  # those the previous call of the control step ended with
            for a in range(n):
                x.c[a, w] = wh.angles[i, 0, a]
                x.s[a, w] = wh.angles[i, 1, a]
        else:
            _lane_angles(x.qi, x.ph, n, w, x.c, x.s)
    any_filter = False
    for w in range(W):
        any_filter = any_filter | x.use_filter[w]
    return any_filter


@njit(**_JIT, forceinline=True)
def _command(n, k, W, passive, any_filter, ctl, x):
    """The terms at the sub-step's state, and the velocity to filter: the command, or the one-step
    result of the commanded torque (``vdes``; ``vs`` starts as it, the status as nominal)."""
    _mass_lanes(x.lm, x.c, x.s, x.vi, passive, n, k, W, x.M, x.R, x.Sn, x.Mc, x.Hc, x.qd, x.thd, x.H)
    if ctl.torque_mode:
        for t in range(k):
            for w in range(W):
                x.tau[t, w] = ctl.command[x.arm[w], t]
        if any_filter:
            _acceleration_lanes(x.Mc, x.Hc, x.tau, k, W, x.acc, x.rhs, x.Lc, x.yc, x.ok)  # NaN where not SPD: 0 below
            for t in range(k):
                for w in range(W):
                    x.vdes[t, w] = x.vi[t, w] + ctl.dt * (x.acc[t, w] if x.ok[w] else 0.0)
    else:
        for t in range(k):
            for w in range(W):
                x.vdes[t, w] = ctl.command[x.arm[w], t]
    for t in range(k):
        for w in range(W):
            x.vs[t, w] = x.vdes[t, w]
    for w in range(W):
        x.status[w] = STATUS_NOMINAL


@njit(**_JIT, forceinline=True)
def _filter_whole_arm(sub, n, k, W, passive, ctl, sh, wh, x, sr, ws):
    """Whole-arm safety: each filtered lane's rows (its bodies against its capsules at the sub-step's
    time) solved by the full search, with the fallbacks of :func:`_advance_arms`."""
    for w in range(W):
        if x.use_filter[w] and x.live[w] and x.real[w]:
            for t in range(k):
                sr.v0[t] = x.vdes[t, w]
            now = wh.start_time[x.arm[w]] + sub * ctl.dt
            m_w, h_w = whole_arm_rows(x.arm[w], w, n, k, passive, wh.link_bodies, wh.link_radius, wh.sensing,
                                      wh.skin, ctl.dt, x.ln, x.bx, x.by, x.c, x.s, x.qd, x.M, wh.caps, now, sh.kappa,
                                      sh.epsilon, sh.margin, sh.v_max, sr.v0, ws.A, ws.b, ws.active, ws.P, ws.near)
            x.arm_h[w] = min(x.arm_h[w], h_w)
            x.status[w] = _project_one(sr.v0, ws.A, ws.b, ws.active, m_w, k, sr.vs, ws.rows, sr.idx, sr.G, sr.r,
                                       sr.lam, sr.cand, sr.L, sr.y, ws.viol, ws.norm)
            if x.status[w] == STATUS_FALLBACK:
                # infeasible: the fallback first drops the robust term (ε → ∞: the plain CBF condition,
                # which a moving obstacle or a crowd of capsules can leave feasible), then takes the
                # velocity that violates the rows least (braking does not keep a moving obstacle out);
                # reported as a fallback either way
                m_w, _ = whole_arm_rows(x.arm[w], w, n, k, passive, wh.link_bodies, wh.link_radius, wh.sensing,
                                        wh.skin, ctl.dt, x.ln, x.bx, x.by, x.c, x.s, x.qd, x.M, wh.caps, now,
                                        sh.kappa, np.inf, sh.margin, sh.v_max, sr.v0, ws.A, ws.b, ws.active, ws.P,
                                        ws.near)
                if _project_one(sr.v0, ws.A, ws.b, ws.active, m_w, k, sr.vs, ws.rows, sr.idx, sr.G, sr.r, sr.lam,
                                sr.cand, sr.L, sr.y, ws.viol, ws.norm) == STATUS_FALLBACK:
                    least_violation(sr.v0, ws.A, ws.b, ws.active, m_w, k, 2 * k if sh.v_max < np.inf else 0, sr.vs,
                                    ws.b0, ws.n0, ws.rows, sr.idx, sr.G, sr.r, sr.lam, sr.cand, sr.L, sr.y, ws.viol,
                                    ws.norm)
            for t in range(k):
                x.vs[t, w] = sr.vs[t]


@njit(**_JIT, forceinline=True)
def _filter_end_effector(n, k, W, O, m, passive, sizes, lane_qp, sh, x, e, sr):
    """The paper's filter: each filtered lane's RCBF rows against its obstacles, settled for all lanes
    at once where one active row does, else by the full search one lane at a time."""
    _position_lanes(x.ln, x.bx, x.by, x.c, x.s, n, W, x.px, x.py)
    _jacobian_lanes(x.ln, x.c, x.s, x.M, passive, n, k, W, x.J, x.Jbar)
    for w in range(W):
        e.filtered[w] = x.use_filter[w] & x.live[w] & x.real[w]  # a padded lane's result is never used
    # numba prunes a branch only on an argument that is None: lane_qp is None in the generic kernel,
    # sizes in the per-kind ones, so each compiles one of the two QP stages
    if lane_qp is None:
        if sizes is not None:  # the generic kernel: every filtered lane to the full search
            # (whose first test is the feasibility test the lane-batched stage starts with)
            _filter_rows_lanes(x.px, x.py, x.Jbar, e.obstacles, e.lane_active, e.filtered, sh.kappa, sh.epsilon,
                               sh.margin, O, k, W, x.arm_h, e.row_A, e.row_b, e.row_h, e.obst_rows)
            for w in range(W):
                e.needs_qp[w] = e.filtered[w]
                e.q_found[w] = False
    else:
        _first_projection_lanes(x.px, x.py, x.Jbar, e.obstacles, e.lane_active, e.filtered, sh.kappa, sh.epsilon,
                                sh.margin, sh.v_max, O, k, W, x.vdes, x.arm_h, e.row_A, e.row_b, e.row_h, e.row_norm,
                                e.row_act, e.obst_rows, e.needs_qp, e.q_best, e.q_best_viol, e.q_Ab, e.q_bb,
                                e.q_cand, e.q_found)
    for w in range(W):
        if e.needs_qp[w] and e.q_found[w]:
            x.status[w] = STATUS_SOLVED
            for t in range(k):
                x.vs[t, w] = e.q_cand[t, w]
        elif e.needs_qp[w]:  # the full active-set search, on this lane's RCBF rows (speed rows set once)
            for j in range(O):
                for t in range(k):
                    e.A[j, t] = e.obst_rows[j, t, w]
                e.b[j] = e.obst_rows[j, k, w]
                e.active[j] = e.lane_active[j, w]
            for t in range(k):
                sr.v0[t] = x.vdes[t, w]
            x.status[w] = _project_one(sr.v0, e.A, e.b, e.active, m, k, sr.vs, e.rows, sr.idx, sr.G, sr.r, sr.lam,
                                       sr.cand, sr.L, sr.y, e.viol, e.norm)
            for t in range(k):
                x.vs[t, w] = sr.vs[t]


@njit(**_JIT, forceinline=True)
def _track(k, W, inv_dt, ctl, x):
    """Count the sub-step's QP statuses; the torque: the backstepping tracker of v* (velocity mode), or
    the one that reaches a filtered velocity in one sub-step (torque mode); keep the lanes' outputs."""
    for y in range(3):
        for w in range(W):
            x.counts[y, w] += 1 if x.live[w] and x.status[w] == y else 0
    if not ctl.torque_mode:
        # backstepping tracker of v* (Eq. 64), v̇* by backward difference
        for w in range(W):
            err = 0.0
            for t in range(k):
                d = x.vi[t, w] - x.vs[t, w]
                err += d * d
            err = np.sqrt(err)
            x.arm_track[w] = err if x.live[w] and err > x.arm_track[w] else x.arm_track[w]
        for t in range(k):
            for w in range(W):
                vdot = (x.vs[t, w] - x.vp[t, w]) * inv_dt if x.prev_ok[w] else 0.0
                x.acc[t, w] = vdot - ctl.ke * (x.vi[t, w] - x.vs[t, w])
        for r in range(k):
            for w in range(W):
                tr = x.Hc[r, w]
                for t in range(k):
                    tr += x.Mc[r, t, w] * x.acc[t, w]
                x.tau[r, w] = tr
        for t in range(k):
            for w in range(W):
                x.vp[t, w] = x.vs[t, w] if x.live[w] else x.vp[t, w]
        for w in range(W):
            x.prev_ok[w] = x.prev_ok[w] | x.live[w]
    else:
        for w in range(W):
            if x.status[w] != STATUS_NOMINAL:
                # the torque's velocity was unsafe: reach the projected velocity in one step
                for r in range(k):
                    tr = x.Hc[r, w]
                    for t in range(k):
                        tr += x.Mc[r, t, w] * (x.vs[t, w] - x.vi[t, w]) * inv_dt
                    x.tau[r, w] = tr
            elif not x.use_filter[w]:
                for t in range(k):
                    x.vs[t, w] = np.nan
    for t in range(k):
        for w in range(W):
            x.vs_last[t, w] = x.vs[t, w] if x.live[w] else x.vs_last[t, w]
            x.tau_last[t, w] = x.tau[t, w] if x.live[w] else x.tau_last[t, w]


@njit(**_JIT, forceinline=True)
def _rk4(n, k, W, passive, dt, x, out):
    """RK4 with τ held into the trial state (qt, vt); the first stage uses the terms at the current
    state, and every stage's link angles come from the current ones (c0, s0) by a small rotation. A
    lane whose trial state is not finite stops (its arm is marked)."""
    for a in range(n):
        for w in range(W):
            x.c0[a, w] = x.c[a, w]
            x.s0[a, w] = x.s[a, w]
    _acceleration_lanes(x.Mc, x.Hc, x.tau, k, W, x.dv, x.rhs, x.Lc, x.yc, x.ok)
    for a in range(n):
        for w in range(W):
            x.sq[a, w] = x.qd[a, w]
    for t in range(k):
        for w in range(W):
            x.sv[t, w] = x.dv[t, w]
    for stage in range(3):
        hs = 0.5 * dt if stage < 2 else dt
        g = 2.0 if stage < 2 else 1.0
        for t in range(k):
            for w in range(W):
                x.vt[t, w] = x.vi[t, w] + hs * x.dv[t, w]
        # the stage's state q + hs q̇: its link angles θ + hs θ̇ (θ̇ = thd of the previous stage)
        _rotate_lanes(x.c0, x.s0, x.thd, hs, n, W, x.c, x.s)
        _mass_lanes(x.lm, x.c, x.s, x.vt, passive, n, k, W, x.M, x.R, x.Sn, x.Mc, x.Hc, x.qd, x.thd, x.H)
        _acceleration_lanes(x.Mc, x.Hc, x.tau, k, W, x.dv, x.rhs, x.Lc, x.yc, x.ok)
        for a in range(n):
            for w in range(W):
                x.sq[a, w] += g * x.qd[a, w]
        for t in range(k):
            for w in range(W):
                x.sv[t, w] += g * x.dv[t, w]
    for w in range(W):
        finite = True
        acc_th = 0.0
        for a in range(n):
            x.qt[a, w] = x.qi[a, w] + dt / 6.0 * x.sq[a, w]
            acc_th += x.sq[a, w]
            x.thd[a, w] = acc_th  # Σ of the weighted stage speeds: the step moves link angle a by dt/6 · thd
            finite = finite & np.isfinite(x.qt[a, w])
        for t in range(k):
            x.vt[t, w] = x.vi[t, w] + dt / 6.0 * x.sv[t, w]
            finite = finite & np.isfinite(x.vt[t, w])
        if x.live[w] and not finite:
            x.live[w] = False
            if x.real[w]:
                out.finite[x.arm[w]] = False
    _rotate_lanes(x.c0, x.s0, x.thd, dt / 6.0, n, W, x.c, x.s)


@njit(**_JIT, forceinline=True)
def _settle(sub, n, k, W, O, dt, wh, x, e, ws):
    """Move the live lanes to their trial state (a stopped one keeps its last finite state and the
    angles the sub-step started from) and lower their clearance; False when no lane is live."""
    n_live = 0
    for w in range(W):
        if x.live[w]:
            n_live += 1
            for a in range(n):
                x.qi[a, w] = x.qt[a, w]
            for t in range(k):
                x.vi[t, w] = x.vt[t, w]
        else:
            for a in range(n):
                x.c[a, w] = x.c0[a, w]
                x.s[a, w] = x.s0[a, w]
    if n_live == 0:
        return False
    # clearance after the sub-step (a stopped lane keeps its value)
    _position_lanes(x.ln, x.bx, x.by, x.c, x.s, n, W, x.px, x.py)
    for j in range(O):
        for w in range(W):
            dx = x.px[w] - e.obstacles[0, j, w]
            dy = x.py[w] - e.obstacles[1, j, w]
            cl = np.sqrt(dx * dx + dy * dy) - e.obstacles[2, j, w]
            x.arm_clear[w] = cl if x.live[w] and cl < x.arm_clear[w] else x.arm_clear[w]
    if wh is not None:
        whole_arm_clearance_lanes(x.arm, x.live, n, W, wh.link_bodies, wh.link_radius, x.ln, x.bx, x.by, x.c, x.s,
                                  wh.caps, wh.n_world, wh.start_time, (sub + 1) * dt, ws.joints_x, ws.joints_y,
                                  ws.ox, ws.oy, ws.orad, x.arm_clear)
    return True


@njit(**_JIT, forceinline=True)
def _store_lanes(n, k, W, passive, finish, tau_off, st, out, wh, x, ws):
    """Write the real lanes back: state, outputs, and with whole-arm safety the angles and joints."""
    # joint velocities and end-effector at the (last finite) state; a stopped arm's angles from q
    for w in range(W):
        if not x.live[w]:
            _lane_angles(x.qi, x.ph, n, w, x.c, x.s)
    if finish:
        _mass_lanes(x.lm, x.c, x.s, x.vi, passive, n, k, W, x.M, x.R, x.Sn, x.Mc, x.Hc, x.qd, x.thd, x.H)
        _position_lanes(x.ln, x.bx, x.by, x.c, x.s, n, W, x.px, x.py)
    for w in range(W):
        if x.real[w]:
            i = x.arm[w]
            st.has_prev[i] = x.prev_ok[w]
            for y in range(3):
                out.qp_counts[i, y] += x.counts[y, w]
            out.min_clear[i] = x.arm_clear[w]
            out.min_h[i] = x.arm_h[w]
            out.max_track[i] = x.arm_track[w]
            for t in range(k):
                out.v_star[i, t] = x.vs_last[t, w]
                out.tau[i, tau_off + t] = x.tau_last[t, w]
                st.v[i, t] = x.vi[t, w]
                st.v_prev[i, t] = x.vp[t, w]
            for a in range(n):
                st.q[i, a] = x.qi[a, w]
            if finish:
                for a in range(n):
                    out.qd[i, a] = x.qd[a, w]
                out.p[i, 0] = x.px[w]
                out.p[i, 1] = x.py[w]
            if wh is not None:
                for a in range(n):
                    wh.angles[i, 0, a] = x.c[a, w]
                    wh.angles[i, 1, a] = x.s[a, w]
                _joints(x.ln, x.bx, x.by, x.c, x.s, n, w, ws.P)
                for a in range(wh.joints.shape[1]):
                    wh.joints[i, a, 0] = ws.P[min(a, n), 0]
                    wh.joints[i, a, 1] = ws.P[min(a, n), 1]


@njit(**_JIT)
def _advance_arms(links, actuated, lanes, sizes, lane_qp, lo, hi, physics, state, control, record, shield, whole):
    """Arms ``lo … hi−1`` of :func:`group_advance` (the loop body, with its own scratch space).

    With ``sizes`` None (the per-kind kernels), ``n``, ``k`` and the lane count W are compile-time
    constants (the lengths of the tuples ``links``, ``actuated`` and ``lanes``): with the loops over
    links, joints and lanes of known length, LLVM unrolls them and packs the lanes into vector
    registers. With ``sizes = (n, k)`` and ``lane_qp`` None (the generic kernel) n and k are read at
    run time and the tuples only size the scratch arrays, and the QP skips its lane-batched first
    candidate (:func:`_filter_rows_lanes` instead of :func:`_first_projection_lanes`); the
    operations on each value and their order are the same, so are the results, bit for bit (no
    fast-math flag lets LLVM round differently: ``_JIT``).

    Each group of inputs (:mod:`pan1_env.compiled`: ``physics``, ``state``, ``control``, ``record``,
    ``shield``, ``whole``) comes as a plain tuple and is named here; the scratch space is named too
    (:data:`_Lanes`, :data:`_EndEffector`, :data:`_Search`, :data:`_WholeScratch`) and handed to the
    steps of a sub-step (:func:`_load_lanes`, :func:`_command`, the filters, :func:`_track`,
    :func:`_rk4`, :func:`_settle`, :func:`_store_lanes`), which LLVM inlines (``forceinline``): the
    compiled code is one function, as if written out here, whose stack arrays it keeps in registers.

    The arms go W at a time (the last group padded with copies of the last arm, never written
    back). Each group's parameters and state are copied into stack arrays (:func:`_local`) with the
    lanes as their last axis, advanced through the sub-steps there and written back: the hot loop
    makes no array view and, but for the obstacles and the filter's rows, touches no heap scratch.
    Dynamics, tracker, RK4 and the safety filter's rows run on all lanes at once, and so does the QP
    as far as one active row settles it (:func:`_first_projection_lanes`, many filtered sub-steps);
    the lanes it does not settle get the full active-set search one by one (:func:`_project_one`).

    The link angles' sines and cosines are computed from q (``_lane_angles``) once per arm at the
    start of a call (and again after a non-finite state), or with whole-arm ``carried`` read from
    ``angles``, where the previous call left them; RK4 stages and the state a sub-step reaches get
    theirs by rotating those at the sub-step's start (``_rotate_lanes``, within an ulp). Those at the
    state reached serve its clearance and the next sub-step's filter, tracker and first RK4 stage.

    An arm whose state goes non-finite stops there (its lane is frozen at the last finite state and
    its outputs are those of the failing sub-step), as its own loop would; the other lanes go on.

    ``whole`` None (numba prunes the branches that read it) keeps the end-effector filter above; a
    :class:`~pan1_env.compiled.WholeArm` switches to whole-arm safety (:mod:`.capsules`): each
    filtered lane's rows are its bodies against its capsules at the sub-step's time, solved by the
    full search, and the clearance after a sub-step is its bodies' to the world obstacles, the first
    ``n_world`` capsules (the engine passes
    no end-effector obstacles then). ``joints (A, L + 1, 2)`` receives every arm's base, joints and
    end-effector at the final state (the end-effector repeated up to L), from which the engine
    refreshes the other arms' capsules between calls, and ``angles (A, 2, n)`` the cosines and sines
    of its link angles there. ``carried`` True starts every arm from ``angles`` instead of computing
    them from q: the engine's calls after the first within a control step (one per sub-step with
    other arms) then go on from the angles the previous call reached, as one call's sub-steps do,
    while each step's first call starts from q, so a step is a function of the state. ``finish``
    False leaves ``record.qd`` and ``record.p`` unwritten (and their mass matrix uncomputed): the engine's
    calls within a control step need neither, only its last call does."""
    arms, st, ctl, out, sh = Physics(*physics), State(*state), Control(*control), Record(*record), Shield(*shield)
    if sizes is None:  # the per-kind kernel (numba prunes the other branch by the argument's type)
        n = len(links)
        k = len(actuated)
    else:  # the generic kernel: n and k at run time, at most the tuples' lengths (which size the scratch)
        n, k = sizes
    W = len(lanes)
    passive = k < n  # a compile-time constant in the per-kind kernel (the argument, checked by callers, agrees)
    kk = max(k, 1)
    O = sh.radii.shape[1]
    m = O + 2 * k
    dt = ctl.dt
    inv_dt = 1.0 / dt  # divisions by dt as products (_JIT leaves arcp off, so LLVM keeps divisions)
    tau_off = out.tau.shape[1] - k  # 0 for (A, k) torques; n − k for full (A, n) rows (passive entries untouched)
    # Scratch space in this function's stack frame (shapes from the size tuples, so fixed at compile
    # time), the lanes last. Only what depends on the number of obstacles lives on the heap.
    f8, b1, i8 = np.float64, np.bool_, np.int64
    lw, nw, kw = (lanes,), (links, lanes), (actuated, lanes)
    nnw, kkw, kx, kkx = (links, links, lanes), (actuated, actuated, lanes), (actuated,), (actuated, actuated)
    x = _Lanes(_local(lw, i8), _local(lw, b1), _local(nnw, f8), _local(nw, f8), _local(nw, f8), _local(kw, f8),
               _local(kw, f8), _local(lw, f8), _local(lw, f8), _local(lw, f8), _local(nw, f8), _local(nw, f8),
               _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(lw, f8),
               _local(lw, f8), _local(nnw, f8), _local(nnw, f8), _local(nnw, f8), _local(((0, 0), links, lanes), f8),
               _local(kkw, f8), _local(kw, f8), _local(((0, 0), actuated, lanes), f8), _local(kkw, f8),
               _local(kw, f8), _local(kw, f8), _local(lw, b1), _local(kw, f8), _local(kw, f8), _local(kw, f8),
               _local(kw, f8), _local(lw, b1), _local(lw, b1), _local(lw, b1), _local(lw, i8), _local(lw, f8),
               _local(lw, f8), _local(lw, f8), _local(kw, f8), _local(kw, f8), _local(((0, 0, 0), lanes), i8),
               _local(nw, f8), _local(kw, f8), _local(kw, f8), _local(nw, f8), _local(kw, f8))
    e = _EndEffector(np.empty((3, O, W)), np.empty((O, W), dtype=np.bool_), np.empty((O, k + 2, W)), _local(kw, f8),
                     _local(lw, f8), _local(lw, f8), _local(lw, f8), _local(lw, b1), _local(lw, b1), _local(lw, b1),
                     _local(lw, i8), _local(lw, f8), _local(lw, b1), _local(kw, f8), _local(lw, f8), _local(kw, f8),
                     np.zeros((m, kk)), np.zeros(m), np.zeros(m, dtype=np.bool_), np.empty(m, dtype=np.int64),
                     np.empty(m), np.empty(m))
    sr = _Search(_local(kx, f8), _local(kx, f8), _local(kx, i8), _local(kkx, f8), _local(kkx, f8), _local(kx, f8),
                 _local(kx, f8), _local(kx, f8), _local(kx, f8))
    if whole is not None:
        wh = WholeArm(*whole)
        finish = wh.finish  # the joint velocities and end-effectors at the end (left out within a control step)
        jw = (links + (0,), lanes)  # joints: n + 1 per lane
        C = wh.caps.shape[1]
        m_whole = (n if wh.link_bodies else 1) * C + 2 * k
        ws = _WholeScratch(_local(jw, f8), _local(jw, f8), _local(lw, f8), _local(lw, f8), _local(lw, f8),
                           np.zeros((m_whole, kk)), np.zeros(m_whole), np.zeros(m_whole, dtype=np.bool_),
                           np.empty(m_whole, dtype=np.int64), np.empty(m_whole), np.empty(m_whole),
                           np.empty((n + 1, 2)), np.empty(m_whole), np.empty(m_whole), np.empty((C, NEAR_COLUMNS)))
    else:
        wh, ws, finish = None, None, True
    if sh.v_max < np.inf:
        for t in range(k):  # the full search's speed bounds ±v_t ≤ v_max, the same in every lane
            e.A[O + 2 * t, t] = 1.0
            e.A[O + 2 * t + 1, t] = -1.0
            e.b[O + 2 * t] = sh.v_max
            e.b[O + 2 * t + 1] = sh.v_max
            e.active[O + 2 * t] = True
            e.active[O + 2 * t + 1] = True
    for first in range(lo, hi, W):
        any_filter = _load_lanes(first, hi, n, k, W, O, arms, st, ctl, out, sh, wh, x, e)
        for sub in range(ctl.n_sub):
            _command(n, k, W, passive, any_filter, ctl, x)
            if any_filter and whole is not None:  # (numba prunes on an argument, not on wh)
                _filter_whole_arm(sub, n, k, W, passive, ctl, sh, wh, x, sr, ws)
            elif any_filter:
                _filter_end_effector(n, k, W, O, m, passive, sizes, lane_qp, sh, x, e, sr)
            _track(k, W, inv_dt, ctl, x)
            _rk4(n, k, W, passive, dt, x, out)
            if not _settle(sub, n, k, W, O, dt, wh, x, e, ws):
                break
        _store_lanes(n, k, W, passive, finish, tau_off, st, out, wh, x, ws)


_ADVANCE_DOC = """Advance every arm of a group by ``n_sub`` physics steps with a held command (in place).

    ``links, actuated = kernel_sizes(n, k)`` are tuples of length n and k, the arms' numbers of
    links and actuated joints (``q.shape[1]`` and ``v.shape[1]``, else ValueError): numba types a
    tuple by its length, so n and k are compile-time constants and the kernel is compiled once per
    (n, k) pair, on its first use, and cached on disk. ``physics.passive`` must agree with them
    (k = n − 1 for a PAn−1 arm, k = n for a fully actuated one, else ValueError): the kernel takes it
    from k < n, a compile-time constant too.

    The other arguments are the named groups of :mod:`pan1_env.compiled`, each passed as a plain
    tuple of its fields (:func:`pan1_env.compiled.plain`), per arm (leading axis A):
    ``physics`` (:class:`~pan1_env.compiled.Physics`: see :class:`~pan1_env.dynamics.ArmBatch`),
    ``state`` (:class:`~pan1_env.compiled.State`: ``q (A, n)``, ``v (A, k)``, ``v_prev``, ``has_prev``),
    ``control`` (:class:`~pan1_env.compiled.Control`), ``record`` (:class:`~pan1_env.compiled.Record`,
    the outputs), ``shield`` (:class:`~pan1_env.compiled.Shield`: the filter and the obstacles each
    arm's filter sees, ``centers (A, O, 2)``, ``radii (A, O)``, ``mask (A, O)``; a team's obstacles
    are broadcast to every arm) and ``whole`` (None, or a :class:`~pan1_env.compiled.WholeArm`).

    Velocity mode (``control.torque_mode`` False): ``command`` is the desired active velocity; each
    sub-step filters it through the RCBF-QP when ``shield.on`` (against the obstacles of ``mask``)
    and tracks v* with the backstepping torque, v̇* by backward difference (``v_prev``/``has_prev``
    hold the previous sub-step's v* per arm; on return they hold the last v*). Torque mode:
    ``command`` is τ_a. Without the filter it is applied as is; with it, the velocity the torque
    would produce after one sub-step, v + dt·M_comb⁻¹(τ_a − H_comb), is filtered, and if the QP
    changes it the arm is driven to the filtered velocity in one sub-step,
    τ_a = M_comb (v* − v)/dt + H_comb, instead. With a finite ``v_max`` the filter's QP also bounds
    every actuated speed, |v_t| ≤ ``v_max``, in both modes: the filtered velocity stays within the
    arm's speed limit (without it, steady torque builds speeds at which a sub-step jumps over the
    safe set's boundary, and a nearly degenerate RCBF row, tiny ‖L_g0 h‖ with b < 0, has a huge
    exact optimum). A problem the box makes infeasible takes the braking fallback.

    ``whole``: None for the end-effector filter above (the paper's); a
    :class:`~pan1_env.compiled.WholeArm` for whole-arm safety (:mod:`pan1_env.kernels.capsules`): the
    obstacle arrays are then empty, each filtered arm's rows are its bodies against its capsules at
    the sub-step's time (``start_time`` + elapsed sub-steps), solved by the full search, with a
    fallback that drops the robust term, then takes the least violating velocity, ``min_clear`` is
    its bodies' clearance to the world obstacles, and ``joints`` gets the arms' base, joints and
    end-effector at the final state and ``angles`` their link angles' cosines and sines, from which
    a call with ``carried`` starts (with ``finish`` False, ``record.qd`` and ``record.p`` are left as
    they were).

    Outputs (``record``, per arm): ``v_star``/``tau`` of the last sub-step (``tau`` either ``(A, k)``
    actuated torques or full ``(A, n)`` rows, whose passive entry is left as passed in), ``qd`` the
    joint velocities q̇ = g0 v and ``p`` the end-effector at the final state, ``min_clear`` the
    smallest clearance ‖p − o_j‖ − r_j to any obstacle after every sub-step (running minimum with
    the value passed in), ``min_h`` the smallest filtered barrier seen, ``qp_counts[i, s]`` the
    number of sub-steps with QP status s, ``max_track`` the largest tracking error ‖v − v*‖ at the
    start of a sub-step (velocity mode; running maximum with the value passed in), ``finite``
    False for an arm whose state went non-finite (left at its last finite value). The first stage
    of each RK4 step reuses the terms the filter and tracker computed at the same state.
    """


@njit(**_JIT)
def _check_sizes(links, actuated, physics, state):
    arms, st = Physics(*physics), State(*state)
    if st.q.shape[1] != len(links) or st.v.shape[1] != len(actuated):
        raise ValueError("group_advance: links, actuated must be kernel_sizes(q.shape[1], v.shape[1])")
    if len(actuated) != len(links) - (1 if arms.passive else 0):
        raise ValueError("group_advance: a PAn-1 arm (passive) has k = n - 1 actuated joints, a full one k = n")
    return st.q.shape[0]


@njit(**_JIT)
def group_advance(links, actuated, physics, state, control, record, shield, whole):
    A = _check_sizes(links, actuated, physics, state)
    lo = A * 0  # an int64, like the parallel kernel's chunk bounds
    _advance_arms(links, actuated, _LANES, None, True, lo, A, physics, state, control, record, shield, whole)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_advance_parallel(links, actuated, physics, state, control, record, shield, whole, n_chunks):
    A = _check_sizes(links, actuated, physics, state)
    _check_chunks(n_chunks)
    for c in prange(n_chunks):
        _advance_arms(links, actuated, _LANES, None, True, c * A // n_chunks, (c + 1) * A // n_chunks, physics,
                      state, control, record, shield, whole)


# The generic kernel: arms of any kind up to GENERIC_MAX_LINKS links, n and k read at run time, one
# lane; compiled once for all kinds (the per-kind kernel's helpers are compiled again for every kind,
# since n, k and W are constants in their types). Scratch arrays are sized for the largest kind.
GENERIC_MAX_LINKS = 8
_GENERIC_SIZES = (0,) * GENERIC_MAX_LINKS
_ONE_LANE = (0,)


def group_advance_generic(links, actuated, physics, state, control, record, shield, whole):
    """:func:`group_advance` (same arguments, same results bit for bit) through one kernel compiled for
    every arm kind of at most ``GENERIC_MAX_LINKS`` links: a new kind costs no compilation, and the
    kernel steps 3–4× slower (one arm at a time, loops of run-time length). The engine uses it while a
    kind's own kernel is neither compiled nor in the disk cache (:mod:`pan1_env.kernels.specialise`).
    It calls :func:`_advance_arms` from Python: a compiled wrapper would compile its code a second time
    (numba links a callee into its caller's module), about 2 s more."""
    arms, st = Physics(*physics), State(*state)
    n, k = len(links), len(actuated)
    if st.q.shape[1] != n or st.v.shape[1] != k or not 1 <= k <= n <= GENERIC_MAX_LINKS or \
            k != n - bool(arms.passive):
        raise ValueError(f"group_advance_generic: arms of n ≤ {GENERIC_MAX_LINKS} links (q.shape[1]) and k actuated "
                         "joints (v.shape[1]), links, actuated = kernel_sizes(n, k): k = n − 1 with a passive first "
                         "joint, else k = n")
    physics = tuple(arms._replace(passive=bool(arms.passive)))  # one signature for numpy's bools and Python's
    _advance_arms(_GENERIC_SIZES, _GENERIC_SIZES, _ONE_LANE, (n, k), None, 0, st.q.shape[0], physics, tuple(state),
                  tuple(control), tuple(record), tuple(shield), None if whole is None else tuple(whole))


group_advance.__doc__ = _ADVANCE_DOC
_quick_when(_slp_vectorised(_advance_arms), 3)  # the generic kernel's signature (sizes given) at LLVM -O1
_slp_vectorised(group_advance)
_slp_vectorised(group_advance_parallel)
group_advance_parallel.__doc__ = _ADVANCE_DOC + """
    The same, with the arms split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches; a call costs a few microseconds more than :func:`group_advance`). Both run the same
    compiled :func:`_advance_arms`, chunk by chunk here: each lane computes its own arm with no
    reduction across lanes or arms, so the chunks' padded lane groups change nothing and the two give
    the same results bit for bit (``tests/test_kernels.py``, ``tests/test_vector.py``,
    ``tests/test_determinism.py``).
    """
