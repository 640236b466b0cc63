"""Compiled (numba) kernels of the physics sub-step: the engine's single implementation.

The formulas are those of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety` and :mod:`pan1_env.control` (the documented, vectorised numpy reference);
the tests check every kernel against them. The kernels loop over the arms of one group (arms with
the same number of links n and actuation, k actuated joints) so that a sub-step costs a handful of
calls whatever the team size.

Importing this module imports numba (about half a second); :mod:`pan1_env` itself does not, so
``import pan1_env`` stays fast. Compiled code is cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = [
    "group_terms",
    "group_advance",
    "group_advance_parallel",
    "group_end_effectors",
    "group_observations",
    "qp_project",
]

STATUS_NOMINAL, STATUS_SOLVED, STATUS_FALLBACK = 0, 1, 2
# numpy error model: no zero-division checks in the hot loops (a zero pivot gives inf/NaN, caught by the
# finiteness checks); fast-math without nnan/ninf, so NaN and inf tests keep working.
_JIT = {"cache": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "contract", "afn", "reassoc"}}


@njit(**_JIT, inline="always")
def _arm_terms(lam, q, v, passive, M, Mc, Hc, qd, ws):
    """Mass matrix M, q̇ = g0 v, M_comb and H_comb of one arm (writes the output arrays).

    ``ws`` is the scratch space of :func:`_workspace` (no allocation in the hot loop)."""
    n = q.shape[0]
    theta, cosd, sind, R, thd, H = ws[0], ws[1], ws[2], ws[3], ws[4], ws[5]
    acc = 0.0
    for a in range(n):
        acc += q[a]
        theta[a] = acc
    # cos(θ_b − θ_a) and sin(θ_b − θ_a) from n sines and cosines (angle-difference identities)
    c = thd  # scratch, overwritten below
    sn = H
    for a in range(n):
        c[a] = np.cos(theta[a])
        sn[a] = np.sin(theta[a])
    for a in range(n):
        for b in range(n):
            cosd[a, b] = c[b] * c[a] + sn[b] * sn[a]
            sind[a, b] = sn[b] * c[a] - c[b] * sn[a]
    # M = Sᵀ (λ ∘ cos D) S: reverse cumulative sums over both indices.
    for a in range(n):
        acc = 0.0
        for b in range(n - 1, -1, -1):
            acc += lam[a, b] * cosd[a, b]
            R[a, b] = acc
    for b in range(n):
        acc = 0.0
        for a in range(n - 1, -1, -1):
            acc += R[a, b]
            M[a, b] = acc
    off = 1 if passive else 0
    k = n - off
    if passive:
        s = 0.0
        for j in range(k):
            s += M[0, j + 1] * v[j]
        qd[0] = -s / M[0, 0]
    for j in range(k):
        qd[j + off] = v[j]
    # H = Sᵀ h,  h_a = −Σ_b λ_ab sin(θ_b − θ_a) θ̇_b²
    acc = 0.0
    for a in range(n):
        acc += qd[a]
        thd[a] = acc
    acc = 0.0
    for a in range(n - 1, -1, -1):
        h = 0.0
        for b in range(n):
            h -= lam[a, b] * sind[a, b] * thd[b] * thd[b]
        acc += h
        H[a] = acc
    if passive:
        inv = 1.0 / M[0, 0]
        for i in range(k):
            Hc[i] = H[i + 1] - M[i + 1, 0] * H[0] * inv
            for j in range(k):
                Mc[i, j] = M[i + 1, j + 1] - M[i + 1, 0] * M[0, j + 1] * inv
    else:
        for i in range(n):
            Hc[i] = H[i]
            for j in range(n):
                Mc[i, j] = M[i, j]


@njit(**_JIT, inline="always")
def _spd_solve(G, r, x, L, y):
    """Solve G x = r (s × s, symmetric positive definite) by Cholesky; False if not SPD.

    ``L`` (at least s × s) and ``y`` (at least s) are scratch space."""
    s = G.shape[0]
    scale = 0.0
    for i in range(s):
        scale = max(scale, G[i, i])
    for i in range(s):
        for j in range(i + 1):
            acc = G[i, j]
            for t in range(j):
                acc -= L[i, t] * L[j, t]
            if i == j:
                if acc <= 1e-12 * scale:
                    return False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    for i in range(s):
        acc = r[i]
        for t in range(i):
            acc -= L[i, t] * y[t]
        y[i] = acc / L[i, i]
    for i in range(s - 1, -1, -1):
        acc = y[i]
        for t in range(i + 1, s):
            acc -= L[t, i] * x[t]
        x[i] = acc / L[i, i]
    return True


@njit(**_JIT)
def _workspace(n, k):
    """Scratch arrays for one arm of n links and k actuated joints (see _arm_terms, _arm_rhs)."""
    return (np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty(n),
            np.empty((n, n)), np.empty((k, k)), np.empty(k), np.empty(k), np.empty((n, n)), np.empty(n))


@njit(**_JIT, inline="always")
def _arm_rhs(lam, q, v, tau, passive, dq, dv, ws):
    k = v.shape[0]
    M, Mc, Hc, r = ws[6], ws[7], ws[8], ws[9]
    _arm_terms(lam, q, v, passive, M, Mc, Hc, dq, ws)
    for i in range(k):
        r[i] = tau[i] - Hc[i]
    if not _spd_solve(Mc, r, dv, ws[10], ws[11]):
        for i in range(k):
            dv[i] = np.nan


@njit(**_JIT, inline="always")
def _arm_position(lengths, base, phi, q):
    """End-effector position p = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)] of one arm."""
    ang = phi
    px = base[0]
    py = base[1]
    for a in range(q.shape[0]):
        ang += q[a]
        px += lengths[a] * np.sin(ang)
        py += lengths[a] * np.cos(ang)
    return px, py


@njit(**_JIT, inline="always")
def _arm_kinematics(lengths, base, phi, q, M, passive, J, Jbar):
    """End-effector position (returned) and reduced Jacobian J̄ = J g0 (written to Jbar) of one arm.

    p = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)], ∂p/∂q_a = Σ_{α≥a} L_α [cos, −sin](θ_α + φ),
    g0 = [−M_0a / M_00 ; I] for a PA arm (M is the arm's mass matrix), I otherwise."""
    n = q.shape[0]
    k = Jbar.shape[1]
    ang = phi
    px = base[0]
    py = base[1]
    for a in range(n):
        ang += q[a]
        J[0, a] = lengths[a] * np.cos(ang)
        J[1, a] = -lengths[a] * np.sin(ang)
        px += lengths[a] * np.sin(ang)
        py += lengths[a] * np.cos(ang)
    for a in range(n - 2, -1, -1):
        J[0, a] += J[0, a + 1]
        J[1, a] += J[1, a + 1]
    for c in range(2):
        for t in range(k):
            if passive:
                Jbar[c, t] = J[c, t + 1] - J[c, 0] * M[0, t + 1] / M[0, 0]
            else:
                Jbar[c, t] = J[c, t]
    return px, py


@njit(**_JIT)
def group_terms(lam, lengths, base, phi, passive, q, v, p, Jbar, Mc, Hc, momentum):
    """Per arm: end-effector p (A,2), reduced Jacobian J̄ (A,2,k), M_comb, H_comb, passive momentum."""
    A, n = q.shape
    k = v.shape[1]
    M = np.empty((n, n))
    qd = np.empty(n)
    J = np.empty((2, n))
    ws = _workspace(n, k)
    for i in range(A):
        _arm_terms(lam[i], q[i], v[i], passive, M, Mc[i], Hc[i], qd, ws)
        mom = 0.0
        for a in range(n):
            mom += M[0, a] * qd[a]
        momentum[i] = mom if passive else np.nan
        p[i, 0], p[i, 1] = _arm_kinematics(lengths[i], base[i], phi[i], q[i], M, passive, J, Jbar[i])


@njit(**_JIT)
def group_end_effectors(lengths, base, phi, q, p):
    """End-effector positions (A, 2) of a group."""
    for i in range(q.shape[0]):
        p[i, 0], p[i, 1] = _arm_position(lengths[i], base[i], phi[i], q[i])


@njit(**_JIT)
def group_observations(q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present, K, inv_vmax,
                       bound, out):
    """Local observations of the arms ``ids`` (all with n links) of B teams, written to ``out (B, A, size)``.

    Layout and inputs as :meth:`pan1_env.observation.ObservationLayout.build`; the K obstacle slots
    hold the K obstacles of smallest clearance ‖p − o‖ − r (ties: lower index first); entries are
    clipped to ±``bound``; absent slots are zeros.
    """
    Bsz = q.shape[0]
    D = neighbour.shape[1]
    O = radii.shape[1]
    size = out.shape[2]
    n = (size - 2 - 4 * D - 5 * K) // 3
    clear = np.empty(O)
    taken = np.empty(O, dtype=np.bool_)
    for bi in range(Bsz):
        for r in range(ids.shape[0]):
            i = ids[r]
            o = out[bi, r]
            for a in range(n):
                o[a] = np.cos(q[bi, i, a])
                o[n + a] = np.sin(q[bi, i, a])
                o[2 * n + a] = min(max(qd[bi, i, a] * inv_vmax, -bound), bound)
            px = P[bi, i, 0]
            py = P[bi, i, 1]
            o[3 * n] = min(max(px - base[bi, i, 0], -bound), bound)
            o[3 * n + 1] = min(max(py - base[bi, i, 1], -bound), bound)
            c = 3 * n + 2
            for s in range(D):
                if present[i, s]:
                    j = neighbour[i, s]
                    o[c] = 1.0
                    o[c + 1] = min(max(P[bi, j, 0] - px, -bound), bound)
                    o[c + 2] = min(max(P[bi, j, 1] - py, -bound), bound)
                    o[c + 3] = min(max(err[bi, neighbour_edge[i, s]], -bound), bound)
                else:
                    o[c] = 0.0
                    o[c + 1] = 0.0
                    o[c + 2] = 0.0
                    o[c + 3] = 0.0
                c += 4
            for j in range(O):
                dx = centers[bi, j, 0] - px
                dy = centers[bi, j, 1] - py
                clear[j] = np.sqrt(dx * dx + dy * dy) - radii[bi, j]
                taken[j] = False
            for _slot in range(K):
                best = -1
                for j in range(O):
                    if not taken[j] and (best < 0 or clear[j] < clear[best]):
                        best = j
                if best < 0:
                    for f in range(5):
                        o[c + f] = 0.0
                else:
                    taken[best] = True
                    dx = centers[bi, best, 0] - px
                    dy = centers[bi, best, 1] - py
                    rad = radii[bi, best]
                    o[c] = 1.0
                    o[c + 1] = min(max(dx, -bound), bound)
                    o[c + 2] = min(max(dy, -bound), bound)
                    o[c + 3] = min(max(rad, -bound), bound)
                    o[c + 4] = min(max(dx * dx + dy * dy - rad * rad, -bound), bound)
                c += 5


@njit(**_JIT)
def _qp_workspace(m, k):
    """Scratch arrays for :func:`_project_one` with m rows and k unknowns."""
    return (np.empty(m, dtype=np.int64), np.empty(max(k, 1), dtype=np.int64), np.empty((k, k)), np.empty(k),
            np.empty(k), np.empty(k), np.empty((k, k)), np.empty(k), np.empty(m))


@njit(**_JIT)
def _project_one(v0, A, b, active, v_out, qws):
    """Exact min ½‖v − v0‖² s.t. A_j v ≤ b_j (rows with active_j): returns a status code.

    Enumerates sets of active rows (sizes 1..k, rows in order of decreasing violation at v0): the
    projection of v0 onto the rows of a set, with non-negative multipliers and feasible for every
    row, satisfies the KKT conditions of this strictly convex QP, so it is the unique optimum and
    the search stops there (see :mod:`pan1_env.safety`). No such set: infeasible, brake (v = 0).
    """
    m, k = A.shape
    feasible = True
    for j in range(m):
        if active[j]:
            s = 0.0
            for t in range(k):
                s += A[j, t] * v0[t]
            if s > b[j] + 1e-12 * (1.0 + abs(b[j])):
                feasible = False
                break
    if feasible:
        for t in range(k):
            v_out[t] = v0[t]
        return STATUS_NOMINAL
    rows, idx, G_full, r_full, lam_full, cand, L_scratch, y_scratch, viol = qws
    na = 0
    for j in range(m):
        if active[j]:
            nrm = 0.0
            s = 0.0
            for t in range(k):
                nrm += A[j, t] * A[j, t]
                s += A[j, t] * v0[t]
            if nrm > 0.0:
                # insertion by decreasing violation A_j v0 − b_j (most violated rows are tried first)
                w = (s - b[j]) / np.sqrt(nrm)
                x = na
                while x > 0 and viol[x - 1] < w:
                    rows[x] = rows[x - 1]
                    viol[x] = viol[x - 1]
                    x -= 1
                rows[x] = j
                viol[x] = w
                na += 1
            elif b[j] < -1e-12:
                # 0·v ≤ b < 0 can never hold: the QP is infeasible
                for t in range(k):
                    v_out[t] = 0.0
                return STATUS_FALLBACK
    smax = min(na, k)
    for size in range(1, smax + 1):
        # iterate over combinations of `size` rows out of `na` (lexicographic)
        for t in range(size):
            idx[t] = t
        while True:
            G = G_full[:size, :size]
            r = r_full[:size]
            for x in range(size):
                jx = rows[idx[x]]
                acc = 0.0
                for t in range(k):
                    acc += A[jx, t] * v0[t]
                r[x] = acc - b[jx]
                for y in range(size):
                    jy = rows[idx[y]]
                    acc = 0.0
                    for t in range(k):
                        acc += A[jx, t] * A[jy, t]
                    G[x, y] = acc
            lam = lam_full[:size]
            if _spd_solve(G, r, lam, L_scratch, y_scratch):
                lmax = 0.0
                for x in range(size):
                    lmax = max(lmax, abs(lam[x]))
                ok = True
                for x in range(size):
                    if lam[x] < -1e-12 * (1.0 + lmax):
                        ok = False
                if ok:
                    for t in range(k):
                        acc = v0[t]
                        for x in range(size):
                            acc -= A[rows[idx[x]], t] * lam[x]
                        cand[t] = acc
                    cn = 0.0
                    for t in range(k):
                        cn += cand[t] * cand[t]
                    cn = np.sqrt(cn)
                    for jj in range(na):
                        j = rows[jj]
                        s = 0.0
                        an = 0.0
                        for t in range(k):
                            s += A[j, t] * cand[t]
                            an += A[j, t] * A[j, t]
                        if s > b[j] + 1e-9 * (1.0 + abs(b[j]) + np.sqrt(an) * (1.0 + cn)):
                            ok = False
                            break
                    if ok:  # a KKT point: the optimum
                        for t in range(k):
                            v_out[t] = cand[t]
                        return STATUS_SOLVED
            # next combination
            x = size - 1
            while x >= 0 and idx[x] == na - size + x:
                x -= 1
            if x < 0:
                break
            idx[x] += 1
            for y in range(x + 1, size):
                idx[y] = idx[y - 1] + 1
    for t in range(k):
        v_out[t] = 0.0
    return STATUS_FALLBACK


@njit(**_JIT)
def qp_project(v0, A, b, active, v_out, status):
    """Batched exact safety QP: for each arm i, project v0[i] onto {A[i] v ≤ b[i]}."""
    qws = _qp_workspace(A.shape[1], A.shape[2])
    for i in range(v0.shape[0]):
        status[i] = _project_one(v0[i], A[i], b[i], active[i], v_out[i], qws)


@njit(**_JIT)
def _rk4_workspace(n, k):
    """Stage derivatives and trial state for :func:`_rk4_arm`."""
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(k), np.empty(k), np.empty(k),
            np.empty(k), np.empty(n), np.empty(k))


@njit(**_JIT, inline="always")
def _rk4_arm(lam, q, v, tau, passive, dt, q_out, v_out, rk, ws, have_terms, Mc1, Hc1, qd1):
    """One RK4 step of one arm's cascaded state (q, v) with τ held; writes q_out, v_out.

    With ``have_terms`` the first stage reuses M_comb, H_comb and q̇ already computed at (q, v)."""
    n = q.shape[0]
    k = v.shape[0]
    k1q, k2q, k3q, k4q, k1v, k2v, k3v, k4v, qt, vt = rk
    if have_terms:
        for a in range(n):
            k1q[a] = qd1[a]
        r = ws[9]
        for i in range(k):
            r[i] = tau[i] - Hc1[i]
        if not _spd_solve(Mc1, r, k1v, ws[10], ws[11]):
            for i in range(k):
                k1v[i] = np.nan
    else:
        _arm_rhs(lam, q, v, tau, passive, k1q, k1v, ws)
    for a in range(n):
        qt[a] = q[a] + 0.5 * dt * k1q[a]
    for a in range(k):
        vt[a] = v[a] + 0.5 * dt * k1v[a]
    _arm_rhs(lam, qt, vt, tau, passive, k2q, k2v, ws)
    for a in range(n):
        qt[a] = q[a] + 0.5 * dt * k2q[a]
    for a in range(k):
        vt[a] = v[a] + 0.5 * dt * k2v[a]
    _arm_rhs(lam, qt, vt, tau, passive, k3q, k3v, ws)
    for a in range(n):
        qt[a] = q[a] + dt * k3q[a]
    for a in range(k):
        vt[a] = v[a] + dt * k3v[a]
    _arm_rhs(lam, qt, vt, tau, passive, k4q, k4v, ws)
    for a in range(n):
        q_out[a] = q[a] + dt / 6.0 * (k1q[a] + 2.0 * k2q[a] + 2.0 * k3q[a] + k4q[a])
    for a in range(k):
        v_out[a] = v[a] + dt / 6.0 * (k1v[a] + 2.0 * k2v[a] + 2.0 * k3v[a] + k4v[a])


@njit(**_JIT)
def _advance_arms(lo, hi, lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command, torque_mode,
                  filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out):
    """Arms ``lo … hi−1`` of :func:`group_advance` (the loop body, with its own scratch space)."""
    n = q.shape[1]
    k = v.shape[1]
    O = radii.shape[1]
    M = np.empty((n, n))
    Mc = np.empty((k, k))
    Hc = np.empty(k)
    qd = np.empty(n)
    J = np.empty((2, n))
    Jbar = np.empty((2, k))
    rows = O + 2 * k
    A = np.zeros((rows, k))
    b = np.empty(rows)
    active = np.zeros(rows, dtype=np.bool_)
    if v_max < np.inf:
        for t in range(k):  # speed bounds ±v_t ≤ v_max
            A[O + 2 * t, t] = 1.0
            A[O + 2 * t + 1, t] = -1.0
            b[O + 2 * t] = v_max
            b[O + 2 * t + 1] = v_max
            active[O + 2 * t] = True
            active[O + 2 * t + 1] = True
    vs = np.empty(k)
    tau = np.empty(k)
    acc = np.empty(k)
    rhs = np.empty(k)
    vt = np.empty(k)
    q_next = np.empty(n)
    v_next = np.empty(k)
    ws = _workspace(n, k)
    rk = _rk4_workspace(n, k)
    qws = _qp_workspace(rows, k)
    for i in range(lo, hi):
        finite_out[i] = True
        use_filter = filter_on and torque_mode and v_max < np.inf
        if filter_on:
            for j in range(O):
                active[j] = mask[i, j]
                if mask[i, j]:
                    use_filter = True
        prev_ok = has_prev[i]
        for t in range(k):
            vs[t] = np.nan
            tau[t] = np.nan
        for _s in range(n_sub):
            have_terms = use_filter or not torque_mode
            if have_terms:
                _arm_terms(lam[i], q[i], v[i], passive, M, Mc, Hc, qd, ws)
            # the velocity to filter: the command, or the one-step result of the commanded torque
            if torque_mode:
                for t in range(k):
                    tau[t] = command[i, t]
                if use_filter:
                    for t in range(k):
                        rhs[t] = tau[t] - Hc[t]
                    if not _spd_solve(Mc, rhs, acc, ws[10], ws[11]):
                        for t in range(k):
                            acc[t] = 0.0
                    for t in range(k):
                        vt[t] = v[i, t] + dt * acc[t]
            else:
                for t in range(k):
                    vt[t] = command[i, t]
            st = STATUS_NOMINAL
            if use_filter:
                px, py = _arm_kinematics(lengths[i], base[i], phi[i], q[i], M, passive, J, Jbar)
                for j in range(O):
                    dx = px - centers[i, j, 0]
                    dy = py - centers[i, j, 1]
                    h = dx * dx + dy * dy - radii[i, j] * radii[i, j]
                    lg2 = 0.0
                    for t in range(k):
                        lg = 2.0 * (dx * Jbar[0, t] + dy * Jbar[1, t])
                        A[j, t] = -lg
                        lg2 += lg * lg
                    b[j] = kappa * (h - margin) - lg2 / epsilon
                    if mask[i, j] and h < min_h[i]:
                        min_h[i] = h
                st = _project_one(vt, A, b, active, vs, qws)
            else:
                for t in range(k):
                    vs[t] = vt[t]
            qp_counts[i, st] += 1
            if not torque_mode:
                # backstepping tracker of v* (Eq. 64), v̇* by backward difference
                err = 0.0
                for t in range(k):
                    err += (v[i, t] - vs[t]) ** 2
                err = np.sqrt(err)
                if err > max_track[i]:
                    max_track[i] = err
                for t in range(k):
                    vdot = (vs[t] - v_prev[i, t]) / dt if prev_ok else 0.0
                    acc[t] = vdot - ke * (v[i, t] - vs[t])
                for r in range(k):
                    s = Hc[r]
                    for t in range(k):
                        s += Mc[r, t] * acc[t]
                    tau[r] = s
                for t in range(k):
                    v_prev[i, t] = vs[t]
                prev_ok = True
            elif st != STATUS_NOMINAL:
                # the torque's velocity was unsafe: reach the projected velocity in one step
                for r in range(k):
                    s = Hc[r]
                    for t in range(k):
                        s += Mc[r, t] * (vs[t] - v[i, t]) / dt
                    tau[r] = s
            if torque_mode and not use_filter:
                for t in range(k):
                    vs[t] = np.nan
            # RK4 with τ held (the first stage reuses the terms at the current state)
            _rk4_arm(lam[i], q[i], v[i], tau, passive, dt, q_next, v_next, rk, ws, have_terms, Mc, Hc, qd)
            finite = True
            for a in range(n):
                if not np.isfinite(q_next[a]):
                    finite = False
            for a in range(k):
                if not np.isfinite(v_next[a]):
                    finite = False
            if not finite:
                finite_out[i] = False
                break
            for a in range(n):
                q[i, a] = q_next[a]
            for a in range(k):
                v[i, a] = v_next[a]
            # clearance after the sub-step
            px, py = _arm_position(lengths[i], base[i], phi[i], q[i])
            for j in range(O):
                c = np.sqrt((px - centers[i, j, 0]) ** 2 + (py - centers[i, j, 1]) ** 2) - radii[i, j]
                if c < min_clear[i]:
                    min_clear[i] = c
        has_prev[i] = prev_ok
        for t in range(k):
            v_star_out[i, t] = vs[t]
            tau_out[i, t] = tau[t]
        # joint velocities and end-effector at the (last finite) state
        _arm_terms(lam[i], q[i], v[i], passive, M, Mc, Hc, qd, ws)
        for a in range(n):
            qd_out[i, a] = qd[a]
        p_out[i, 0], p_out[i, 1] = _arm_position(lengths[i], base[i], phi[i], q[i])


_ADVANCE_DOC = """Advance every arm of a group by ``n_sub`` physics steps with a held command (in place).

    Arrays are per arm (leading axis A): parameters ``lam, lengths, base, phi`` (see
    :class:`~pan1_env.dynamics.ArmBatch`), state ``q (A, n)``, ``v (A, k)``, obstacles
    ``centers (A, O, 2)``, ``radii (A, O)`` and ``mask (A, O)`` (the obstacles each arm's filter
    sees; a team's obstacles are broadcast to every arm).

    Velocity mode (``torque_mode`` False): ``command`` is the desired active velocity; each
    sub-step filters it through the RCBF-QP when ``filter_on`` (against the obstacles of ``mask``)
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

    Outputs (per arm): ``v_star_out``/``tau_out`` of the last sub-step, ``qd_out`` the joint
    velocities q̇ = g0 v and ``p_out`` the end-effector at the final state, ``min_clear`` the
    smallest clearance ‖p − o_j‖ − r_j to any obstacle after every sub-step (running minimum with
    the value passed in), ``min_h`` the smallest filtered barrier seen, ``qp_counts[i, s]`` the
    number of sub-steps with QP status s, ``max_track`` the largest tracking error ‖v − v*‖ at the
    start of a sub-step (velocity mode; running maximum with the value passed in), ``finite_out``
    False for an arm whose state went non-finite (left at its last finite value). The first stage
    of each RK4 step reuses the terms the filter and tracker computed at the same state.
    """


@njit(**_JIT)
def group_advance(lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command, torque_mode,
                  filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out):
    _advance_arms(0, q.shape[0], lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command, torque_mode,
                  filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_advance_parallel(lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command, torque_mode,
                           filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                           v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track,
                           finite_out, n_chunks):
    A = q.shape[0]
    for c in prange(n_chunks):
        _advance_arms(c * A // n_chunks, (c + 1) * A // n_chunks, lam, lengths, base, phi, passive, q, v, v_prev,
                      has_prev, command, torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke,
                      dt, n_sub, v_max, v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts,
                      max_track, finite_out)


group_advance.__doc__ = _ADVANCE_DOC
group_advance_parallel.__doc__ = _ADVANCE_DOC + """
    The same, with the arms split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches; a call costs a few microseconds more than :func:`group_advance`).
    """
