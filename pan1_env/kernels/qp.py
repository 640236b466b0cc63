"""The safety filter's QP in compiled form: the exact active-set projection of one arm
(:func:`_project_one`, :func:`qp_project`, and :func:`compiled_projection` batched as
:func:`pan1_env.safety.project_velocity`) and the filter rows and first candidate of W arms at once.

The numpy reference (:func:`pan1_env.safety.active_set_projection`) owns the algorithm and its
tolerances; this module imports them from it, never the other way round."""

from __future__ import annotations

import numpy as np
from numba import njit

from ..safety import CANDIDATE_TOLERANCE, ROW_TOLERANCE, FilterResult, project_with  # the numpy reference owns them
from ._numba_ext import _JIT
from .physics import _spd_solve

STATUS_NOMINAL, STATUS_SOLVED, STATUS_FALLBACK = 0, 1, 2


@njit(**_JIT, forceinline=True)
def _project_one(v0, A, b, active, m, k, v_out, rows, idx, G, r, lam, cand, L, y, viol, rnorm):
    """Exact min ½‖v − v0‖² s.t. A_j v ≤ b_j (rows j < m with active_j): returns a status code.

    Enumerates sets of active rows (sizes 1..k, rows in order of decreasing violation at v0): the
    projection of v0 onto the rows of a set, with non-negative multipliers and feasible for every
    row, satisfies the KKT conditions of this strictly convex QP, so it is the unique optimum and
    the search stops there (see :mod:`pan1_env.safety`). No such set: infeasible, brake (v = 0).
    The remaining arguments are scratch space: ``rows``, ``viol``, ``rnorm`` (m), ``idx``, ``r``,
    ``lam``, ``cand``, ``y`` (k) and ``G``, ``L`` (k × k).
    """
    if _satisfies_rows(v0, A, b, active, m, k):
        for t in range(k):
            v_out[t] = v0[t]
        return STATUS_NOMINAL
    na = _rows_by_violation(v0, A, b, active, m, k, rows, viol, rnorm)
    if na >= 0:
        for size in range(1, min(na, k) + 1):
            # iterate over combinations of `size` rows out of `na` (lexicographic)
            for t in range(size):
                idx[t] = t
            while True:
                if _kkt_point(v0, A, b, k, na, size, rows, idx, G, r, lam, cand, L, y, rnorm):
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
                for z in range(x + 1, size):
                    idx[z] = idx[z - 1] + 1
    for t in range(k):
        v_out[t] = 0.0
    return STATUS_FALLBACK


@njit(**_JIT, forceinline=True)
def _satisfies_rows(v0, A, b, active, m, k):
    """Whether v0 meets every active row j < m within the row tolerance (the nominal command stands)."""
    for j in range(m):
        if active[j]:
            acc = 0.0
            for t in range(k):
                acc += A[j, t] * v0[t]
            if acc > b[j] + ROW_TOLERANCE * (1.0 + abs(b[j])):
                return False
    return True


@njit(**_JIT, forceinline=True)
def _rows_by_violation(v0, A, b, active, m, k, rows, viol, rnorm):
    """The active non-zero rows into ``rows`` by decreasing violation (A_j v0 − b_j) / ‖A_j‖, the most violated
    first (tried first), with ``viol`` and their norms ``rnorm``: returns their number, or −1 if a zero row
    0·v ≤ b < 0 makes the QP infeasible."""
    na = 0
    for j in range(m):
        if active[j]:
            nrm = 0.0
            acc = 0.0
            for t in range(k):
                nrm += A[j, t] * A[j, t]
                acc += A[j, t] * v0[t]
            if nrm > 0.0:
                root = np.sqrt(nrm)
                w = (acc - b[j]) / root
                x = na
                while x > 0 and viol[x - 1] < w:  # insertion
                    rows[x] = rows[x - 1]
                    viol[x] = viol[x - 1]
                    rnorm[x] = rnorm[x - 1]
                    x -= 1
                rows[x] = j
                viol[x] = w
                rnorm[x] = root  # ‖A_j‖, for the candidate's feasibility tolerance
                na += 1
            elif b[j] < -ROW_TOLERANCE:
                return -1
    return na


@njit(**_JIT, forceinline=True)
def _kkt_point(v0, A, b, k, na, size, rows, idx, G, r, lam, cand, L, y, rnorm):
    """Project v0 onto the rows ``rows[idx[:size]]`` held with equality (into ``cand``): whether the projection
    is a KKT point, its multipliers non-negative and every one of the ``na`` rows met within the candidate's
    tolerance (then it is the optimum)."""
    for x in range(size):
        jx = rows[idx[x]]
        acc = 0.0
        for t in range(k):
            acc += A[jx, t] * v0[t]
        r[x] = acc - b[jx]
        for z in range(size):
            jz = rows[idx[z]]
            acc = 0.0
            for t in range(k):
                acc += A[jx, t] * A[jz, t]
            G[x, z] = acc
    if not _spd_solve(G, r, lam, size, L, y):
        return False
    lmax = 0.0
    for x in range(size):
        lmax = max(lmax, abs(lam[x]))
    for x in range(size):
        if lam[x] < -ROW_TOLERANCE * (1.0 + lmax):
            return False
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
        acc = 0.0
        for t in range(k):
            acc += A[j, t] * cand[t]
        if acc > b[j] + CANDIDATE_TOLERANCE * (1.0 + abs(b[j]) + rnorm[jj] * (1.0 + cn)):
            return False
    return True


@njit(**_JIT)
def qp_project(v0, A, b, active, v_out, status):
    """Batched exact safety QP: for each arm i, project v0[i] onto {A[i] v ≤ b[i]}."""
    m, k = A.shape[1], A.shape[2]
    kk = max(k, 1)
    rows, viol, rnorm = np.empty(m, dtype=np.int64), np.empty(m), np.empty(m)
    idx = np.empty(kk, dtype=np.int64)
    r, lam, cand, y = np.empty(kk), np.empty(kk), np.empty(kk), np.empty(kk)
    G, L = np.empty((kk, kk)), np.empty((kk, kk))
    for i in range(v0.shape[0]):
        status[i] = _project_one(v0[i], A[i], b[i], active[i], m, k, v_out[i], rows, idx, G, r, lam, cand, L, y,
                                 viol, rnorm)


@njit(**_JIT, forceinline=True)
def _torque_rhs(w, k, r, sign, dt, tau_max, Mc, Hc, vi):
    """The right-hand side of torque row (r, ``sign``) of :func:`_torque_rows` on lane w: dt (τ_max ∓ H_c[r]) ± M_c[r] q̇
    (``sign`` +1: the upper bound, −1: the lower)."""
    mv = 0.0
    for t in range(k):
        mv += Mc[r, t, w] * vi[t, w]
    return dt * (tau_max - sign * Hc[r, w]) + sign * mv


@njit(**_JIT, forceinline=True)
def _torque_rows(w, k, dt, tau_max, Mc, Hc, vi, A, b, active, first):
    """Torque mode's input bound |τ_r| ≤ τ_max as rows ``first`` … ``first`` + 2k − 1 of A v ≤ b on lane w's filtered
    velocity v, whose torque is the one that reaches it in one sub-step, τ = H_c + M_c (v − q̇) / dt
    (:func:`pan1_env.kernels.steps._track`); times dt: ±M_c[r] v ≤ dt (τ_max ∓ H_c[r]) ± M_c[r] q̇. Returns the row
    after them."""
    for r in range(k):
        for x in range(2):
            sign, j = 1.0 - 2.0 * x, first + 2 * r + x
            for t in range(k):
                A[j, t] = sign * Mc[r, t, w]
            b[j] = _torque_rhs(w, k, r, sign, dt, tau_max, Mc, Hc, vi)
            active[j] = True
    return first + 2 * k


@njit(**_JIT, forceinline=True)
def _torque_within(w, k, dt, tau_max, Mc, Hc, vi, v):
    """Whether lane w's velocity ``v`` is reached in one sub-step within ±τ_max (:func:`_torque_rows`, to the QP's
    row tolerance)."""
    for r in range(k):
        acc = 0.0
        for t in range(k):
            acc += Mc[r, t, w] * v[t]
        for sign in (1.0, -1.0):
            bound = _torque_rhs(w, k, r, sign, dt, tau_max, Mc, Hc, vi)
            if sign * acc > bound + ROW_TOLERANCE * (1.0 + abs(bound)):
                return False
    return True


@njit(**_JIT, forceinline=True)
def _keep_torque(w, k, dt, tau_max, Mc, Hc, vi, v0, target, retry, A, b, active, m, v_out, rows, idx, G, r, lam, cand,
                 L, y, viol, rnorm):
    """Torque mode's input bound on lane w, whose filtered velocity ``target`` needs more than ±τ_max
    (docs/MODEL.md §5d). With ``retry`` (the filter's QP had a solution), the QP again from ``v0`` with its rows
    A v ≤ b (j < m) and the torque rows (written at m … m + 2k − 1: A, b and ``active`` need the room). Without it
    (the filter fell back, and its rows may have been relaxed since), or where that has no solution, the velocity
    nearest ``target`` (then the filter's own last resort: braking, holding the end-effector, or the least
    violation) within the torque bound alone, which always holds the velocity the commanded torque reaches (and that
    one itself if it is all there is). Rows j < m are left inactive then. Returns the status: solved, or fallback."""
    _torque_rows(w, k, dt, tau_max, Mc, Hc, vi, A, b, active, m)
    if retry and _project_one(v0, A, b, active, m + 2 * k, k, v_out, rows, idx, G, r, lam, cand, L, y, viol,
                              rnorm) != STATUS_FALLBACK:
        return STATUS_SOLVED
    for j in range(m):
        active[j] = False
    if _project_one(target, A, b, active, m + 2 * k, k, v_out, rows, idx, G, r, lam, cand, L, y, viol,
                    rnorm) == STATUS_FALLBACK:
        for t in range(k):
            v_out[t] = v0[t]
    return STATUS_FALLBACK


@njit(**_JIT, forceinline=True)
def _rcbf_row_lanes(j, px, py, Jbar, drift, obstacles, kappa, epsilon, margin, distance, decay, k, W, A, b, h):
    """The RCBF row of obstacle j for W lanes, A_j v ≤ b_j, into ``A (k, W)``, ``b (W)``:
    A_j = −L_g0 h_j and b_j = κ h̃_j − ‖L_g0 h_j‖²/ε(h̃_j) + ∇h_j · d, h̃_j = h_j − margin (also writes h_j
    to ``h``); ``obstacles (3, O, W)`` holds every lane's obstacle centres (x, y) and radii, ``drift (2, W)``
    the end-effector's drift d = J₁ p₁ / M_11 of a PAn−1 arm with passive momentum p₁ (0 without:
    docs/MODEL.md §7), the part of ṗ that no command changes.

    The barrier (:func:`pan1_env.safety.shaped_barrier`, docs/MODEL.md §5a): the paper's squared
    h_j = ‖p − o_j‖² − r_j² with L_g0 h_j = 2 (p − o_j)ᵀ J̄, or with ``distance`` h_j = d − r_j,
    d = ‖p − o_j‖, whose row is the squared one over 2d (a zero row at d = 0, where the gradient is
    undefined: the reference's choice). The robust term's ε(h̃) = ε e^{min(λ h̃, 700)}, λ = ``decay``
    (:func:`pan1_env.safety.robust_epsilon`).

    The paper's case (squared, λ = 0) keeps its own loop, the operations of the kernel before these
    choices existed: its results stay bit for bit what they were (the golden tests) and it pays no
    exp or square root. ``distance`` and ``decay`` are the same in every lane, so the test is taken
    once per row, outside the lane loop."""
    if not distance and decay == 0.0:
        for w in range(W):
            dx = px[w] - obstacles[0, j, w]
            dy = py[w] - obstacles[1, j, w]
            hw = dx * dx + dy * dy - obstacles[2, j, w] * obstacles[2, j, w]
            lg2 = 0.0
            for t in range(k):
                lg = 2.0 * (dx * Jbar[0, t, w] + dy * Jbar[1, t, w])
                A[t, w] = -lg
                lg2 += lg * lg
            b[w] = kappa * (hw - margin) - lg2 / epsilon + 2.0 * (dx * drift[0, w] + dy * drift[1, w])
            h[w] = hw
        return
    for w in range(W):
        dx = px[w] - obstacles[0, j, w]
        dy = py[w] - obstacles[1, j, w]
        r = obstacles[2, j, w]
        hw = dx * dx + dy * dy - r * r
        scale = 1.0
        if distance:
            # as the reference: d from the squared barrier, every derivative times 1/(2d), 0 at d = 0
            d = np.sqrt(max(hw + r * r, 0.0))
            scale = 0.5 / d if d > 0.0 else 0.0
            hw = d - r
        lg2 = 0.0
        for t in range(k):
            lg = 2.0 * (dx * Jbar[0, t, w] + dy * Jbar[1, t, w]) * scale
            A[t, w] = -lg
            lg2 += lg * lg
        ht = hw - margin
        b[w] = kappa * ht - lg2 / (epsilon * np.exp(min(decay * ht, 700.0))) + \
            2.0 * (dx * drift[0, w] + dy * drift[1, w]) * scale
        h[w] = hw


@njit(**_JIT, forceinline=True)
def _speed_row_lanes(t0, sign, v_max, k, W, A, b, h):
    """The speed bound sign · v_t0 ≤ ``v_max`` as a filter row of W lanes. Called with t0 and sign known
    at compile time, so LLVM folds the row's constant entries (its norm is 1) into the arithmetic
    that follows."""
    for w in range(W):
        for t in range(k):
            A[t, w] = sign if t == t0 else 0.0
        b[w] = v_max
        h[w] = np.inf


@njit(**_JIT, forceinline=True)
def _consider_row(j, A, b, h, act, v0, k, W, arm_h, violated, best, best_viol, Ab, bb, found, norm):
    """Row j (``A``, ``b``, ``h``; active in lanes ``act``) in :func:`_first_projection_lanes`' first
    pass; ``norm`` gets ‖A_j‖."""
    for w in range(W):
        arm_h[w] = h[w] if act[w] and h[w] < arm_h[w] else arm_h[w]
        nrm = 0.0
        acc = 0.0
        for t in range(k):
            nrm += A[t, w] * A[t, w]
            acc += A[t, w] * v0[t, w]
        violated[w] = violated[w] | (act[w] & (acc > b[w] + ROW_TOLERANCE * (1.0 + abs(b[w]))))
        root = np.sqrt(nrm)
        norm[w] = root
        viol = (acc - b[w]) / root
        take = act[w] & (nrm > 0.0) & ((best[w] < 0) | (viol > best_viol[w]))
        best[w] = j if take else best[w]
        best_viol[w] = viol if take else best_viol[w]
        for t in range(k):
            Ab[t, w] = A[t, w] if take else Ab[t, w]
        bb[w] = b[w] if take else bb[w]
        # a zero row, or one that is not finite: the full search decides (_project_one's sort and solve
        # treat those its own way)
        found[w] = found[w] & (not (act[w] & (not ((nrm > 0.0) & (nrm < np.inf) & (viol == viol)))))


@njit(**_JIT, forceinline=True)
def _check_row(A, b, norm, act, cand, cand_norm, k, W, found):
    """A row (``A``, ``b``, its norm ``norm``) in :func:`_first_projection_lanes`' second pass:
    ``found[w]`` stays True only if the candidate satisfies the row (where active), with
    :func:`_project_one`'s tolerance."""
    for w in range(W):
        acc = 0.0
        for t in range(k):
            acc += A[t, w] * cand[t, w]
        limit = b[w] + CANDIDATE_TOLERANCE * (1.0 + abs(b[w]) + norm[w] * (1.0 + cand_norm[w]))
        bad = act[w] & (norm[w] > 0.0) & (acc > limit)
        found[w] = found[w] & (not bad)


@njit(**_JIT, forceinline=True)
def _first_projection_lanes(px, py, Jbar, drift, obstacles, active, filtered, kappa, epsilon, margin, distance, decay,
                            v_max, O, k, W, v0, arm_h, A, b, h, norm, act, rows, violated, best, best_viol, Ab, bb,
                            cand, found):
    """The safety QP of W lanes as far as it goes without a search, all lanes at once (branch-free, so
    they vectorise):

    - ``violated[w]``: v0 breaks one of the lane's active rows (the test :func:`_project_one` starts
      with; only lanes with ``filtered`` count), and ``arm_h[w]`` takes the smallest
      active barrier h_j;
    - ``cand[:, w]``: the first candidate :func:`_project_one` tries, the projection of v0 onto the
      active row of largest normalised violation (A_j v0 − b_j)/‖A_j‖ (ties: the lower row), and
      ``found[w]``: it is the optimum (its multiplier non-negative and every active row satisfied,
      with :func:`_project_one`'s tolerances).

    Where ``found[w]``, ``cand[:, w]`` is :func:`_project_one`'s answer bit for bit (the same
    operations in the same order); elsewhere (a zero row, a non-finite value, or another active set)
    the lane needs the full search. Many filtered steps that change the command end here.

    Rows go one at a time through the stack arrays ``A``, ``b``, ``h``, ``norm``, ``act``: the RCBF
    rows (:func:`_rcbf_row_lanes`, kept in ``rows (O, k + 2, W)`` as A_j, b_j, ‖A_j‖ for the second
    pass and the full search), then the speed bounds' rows (:func:`_speed_row_lanes`,
    active in every lane when ``v_max`` is finite), in :func:`_project_one`'s order."""
    speed = v_max < np.inf
    for w in range(W):
        violated[w] = False
        best[w] = -1
        best_viol[w] = 0.0
        found[w] = True
        bb[w] = 0.0
        for t in range(k):
            Ab[t, w] = 0.0
    for j in range(O):
        _rcbf_row_lanes(j, px, py, Jbar, drift, obstacles, kappa, epsilon, margin, distance, decay, k, W, A, b, h)
        for w in range(W):
            act[w] = active[j, w] & filtered[w]
        _consider_row(j, A, b, h, act, v0, k, W, arm_h, violated, best, best_viol, Ab, bb, found, norm)
        for w in range(W):
            for t in range(k):
                rows[j, t, w] = A[t, w]
            rows[j, k, w] = b[w]
            rows[j, k + 1, w] = norm[w]
    if speed:
        for w in range(W):
            act[w] = filtered[w]
        for t0 in range(k):
            _speed_row_lanes(t0, 1.0, v_max, k, W, A, b, h)
            _consider_row(O + 2 * t0, A, b, h, act, v0, k, W, arm_h, violated, best, best_viol, Ab, bb, found, norm)
            _speed_row_lanes(t0, -1.0, v_max, k, W, A, b, h)
            _consider_row(O + 2 * t0 + 1, A, b, h, act, v0, k, W, arm_h, violated, best, best_viol, Ab, bb, found,
                          norm)
    any_violated = False
    for w in range(W):
        any_violated = any_violated | violated[w]
    if not any_violated:
        return
    for w in range(W):
        acc = 0.0
        nrm = 0.0
        for t in range(k):
            acc += Ab[t, w] * v0[t, w]
            nrm += Ab[t, w] * Ab[t, w]
        lam = (acc - bb[w]) * (1.0 / nrm)
        cn = 0.0
        for t in range(k):
            cand[t, w] = v0[t, w] - Ab[t, w] * lam
            cn += cand[t, w] * cand[t, w]
        cn = np.sqrt(cn)
        found[w] = found[w] & (best[w] >= 0) & np.isfinite(lam) & np.isfinite(cn) & \
            (not lam < -ROW_TOLERANCE * (1.0 + abs(lam)))
        best_viol[w] = cn  # reused: ‖candidate‖, for the feasibility tolerance
    for j in range(O):
        for w in range(W):
            for t in range(k):
                A[t, w] = rows[j, t, w]
            b[w] = rows[j, k, w]
            norm[w] = rows[j, k + 1, w]
            act[w] = active[j, w]
        _check_row(A, b, norm, act, cand, best_viol, k, W, found)
    if speed:
        for w in range(W):
            act[w] = True
            norm[w] = 1.0
        for t0 in range(k):
            _speed_row_lanes(t0, 1.0, v_max, k, W, A, b, h)
            _check_row(A, b, norm, act, cand, best_viol, k, W, found)
            _speed_row_lanes(t0, -1.0, v_max, k, W, A, b, h)
            _check_row(A, b, norm, act, cand, best_viol, k, W, found)




@njit(**_JIT, forceinline=True)
def _filter_rows_lanes(px, py, Jbar, drift, obstacles, active, filtered, kappa, epsilon, margin, distance, decay, O, k,
                       W, arm_h, A, b, h, rows):
    """The generic kernel's lighter stand-in for :func:`_first_projection_lanes`: the RCBF rows into
    ``rows (O, k + 2, W)`` (A_j and b_j; the norm is not needed) and the smallest active barrier into
    ``arm_h``, no candidate. The caller hands every filtered lane to :func:`_project_one`, which
    starts with the same feasibility test as the first pass there, so the answers are the same; a
    smaller kernel compiles faster, which is the generic kernel's purpose."""
    for j in range(O):
        _rcbf_row_lanes(j, px, py, Jbar, drift, obstacles, kappa, epsilon, margin, distance, decay, k, W, A, b, h)
        for w in range(W):
            act = active[j, w] & filtered[w]
            arm_h[w] = h[w] if act and h[w] < arm_h[w] else arm_h[w]
            for t in range(k):
                rows[j, t, w] = A[t, w]
            rows[j, k, w] = b[w]


def _solve_compiled(v0: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    active = np.isfinite(b)
    v = np.empty_like(v0)
    status = np.empty(v0.shape[0], dtype=np.int64)
    qp_project(np.ascontiguousarray(v0), np.ascontiguousarray(A), np.where(active, b, 0.0), active, v, status)
    return v, status != STATUS_FALLBACK


def compiled_projection(v_desired: np.ndarray, A: np.ndarray, b: np.ndarray) -> FilterResult:
    """:func:`pan1_env.safety.project_velocity` with ``solver="active_set"``, the enumeration run by
    :func:`qp_project` instead of its numpy reference: for callers that solve many problems."""
    return project_with(_solve_compiled, np.asarray(v_desired, dtype=float), np.asarray(A, dtype=float),
                        np.asarray(b, dtype=float))
