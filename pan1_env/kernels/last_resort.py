"""The whole-arm filter's last resort, compiled: when a lane's QP has no solution even without the robust term, the
command that violates its rows least (:func:`least_violation`), every barrier row relaxed by the same amount t
(per unit of its norm, or of the barrier's rate), t the smallest that makes the QP feasible, found by bisection
with the speed box kept; Farkas weights (:func:`_farkas_weights`) prove some bisection steps infeasible without
their search. The rows are :func:`pan1_env.kernels.capsules.whole_arm_rows`'; docs/SCENARIOS.md, *Fallback*."""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_ext import _JIT
from .qp import STATUS_FALLBACK, _project_one


@njit(**_JIT)
def _speed_box(A, b, active, m, k, n_box):
    """v_max of the speed bounds, if the last ``n_box`` rows are the box +v_t ≤ v_max, −v_t ≤ v_max
    (t = 0 … k − 1, active, finite) as :func:`whole_arm_rows` writes it; else −1."""
    if n_box != 2 * k:
        return -1.0
    box = 0.0
    for x in range(n_box):
        j = m - n_box + x
        sign = 1.0 if x % 2 == 0 else -1.0
        if not active[j] or not (0.0 <= b[j] < np.inf):
            return -1.0
        for t in range(k):
            if A[j, t] != (sign if t == x // 2 else 0.0):
                return -1.0
        box = max(box, b[j])
    return box


@njit(**_JIT, inline="always")
def _weight(by_rate, norm):
    """A barrier row's weight in :func:`least_violation`'s relaxation: 1 by rate, its norm by command; 0 for
    the speed box's rows (their ``norm`` is kept 0), which are never relaxed."""
    return (1.0 if norm > 0.0 else 0.0) if by_rate else norm


@njit(**_JIT)
def _farkas_weights(A, b, norms, active, m, k, n_box, box, by_rate, y):
    """Weights y ≥ 0 on the active barrier rows (j < m − ``n_box``), Σ_j y_j w_j = 1 (w_j = ‖A_j‖, or 1
    ``by_rate``: :func:`_weight`), that make D(y) = −Σ_j y_j b_j − ``box`` Σ_t |Σ_j y_j A_jt| large: the
    best vertex of the dual of min_{|v_t| ≤ box} max_j (A_j v − b_j)/w_j, so D is that minimum (the uniform
    violation the box cannot avoid) when it is positive. A vertex has a support S of at most k + 1 rows and
    |S| − 1 of the k sums Σ_j y_j A_jt zero; all are tried (at most 6 rows: the 2k that least_violation
    keeps, k ≤ 3). Writes ``y`` (0 off the support); returns D(y), −inf if no vertex was found. Any y ≥ 0
    gives a valid bound (weak duality), so the small solves' rounding costs optimality, never soundness."""
    rows = np.empty(6, dtype=np.int64)
    p = 0
    for j in range(m - n_box):
        if active[j]:
            if p == 6:
                return -np.inf
            rows[p] = j
            p += 1
    for j in range(m):
        y[j] = 0.0
    sel, M, sol, g = np.empty(4, dtype=np.int64), np.empty((4, 5)), np.empty(4), np.empty(k)
    best = -np.inf
    for mask in range(1, 1 << p):
        size = 0
        for x in range(p):
            size += mask >> x & 1
        if size > k + 1:
            continue
        size = 0
        for x in range(p):
            if mask >> x & 1:
                sel[size] = rows[x]
                size += 1
        for zeros in range(1 << k):
            nz = 0
            for t in range(k):
                nz += zeros >> t & 1
            if nz != size - 1:
                continue
            # size equations: Σ_j y_j A_jt = 0 for t in zeros, Σ_j y_j w_j = 1 (augmented, last column)
            e = 0
            for t in range(k):
                if zeros >> t & 1:
                    for c in range(size):
                        M[e, c] = A[sel[c], t]
                    M[e, size] = 0.0
                    e += 1
            for c in range(size):
                M[e, c] = _weight(by_rate, norms[sel[c]])
            M[e, size] = 1.0
            singular = False
            for c in range(size):  # Gaussian elimination with partial pivoting
                piv, big = c, abs(M[c, c])
                for e in range(c + 1, size):
                    if abs(M[e, c]) > big:
                        piv, big = e, abs(M[e, c])
                if not big > 1e-12:
                    singular = True
                    break
                for x in range(size + 1):
                    M[c, x], M[piv, x] = M[piv, x], M[c, x]
                for e in range(c + 1, size):
                    f = M[e, c] / M[c, c]
                    for x in range(c, size + 1):
                        M[e, x] -= f * M[c, x]
            if singular:
                continue
            for c in range(size - 1, -1, -1):
                acc = M[c, size]
                for x in range(c + 1, size):
                    acc -= M[c, x] * sol[x]
                sol[c] = acc / M[c, c]
            total = 0.0
            for c in range(size):
                sol[c] = max(sol[c], 0.0)
                total += sol[c] * _weight(by_rate, norms[sel[c]])
            if not total > 0.0:
                continue
            value = 0.0
            for t in range(k):
                g[t] = 0.0
            for c in range(size):
                value -= sol[c] / total * b[sel[c]]
                for t in range(k):
                    g[t] += sol[c] / total * A[sel[c], t]
            for t in range(k):
                value -= box * abs(g[t])
            if value > best:
                best = value
                for j in range(m):
                    y[j] = 0.0
                for c in range(size):
                    y[sel[c]] = sol[c] / total
    return best


@njit(**_JIT)
def _certainly_infeasible(A, b, norms, m, k, n_box, box, y):
    """Whether rows A v ≤ b (the barrier rows as relaxed now, and the speed box |v_t| ≤ ``box``) are so
    far from feasible that :func:`_project_one` must answer FALLBACK: Farkas weights ``y`` ≥ 0 prove that
    for every v in the box (widened by what the search's tolerance lets through) Σ_j y_j (A_j v − b_j)
    exceeds what the search's tolerances allow any candidate (:data:`CANDIDATE_TOLERANCE`, here taken
    twice, with the sum's own rounding on top)."""
    root_k = np.sqrt(k)
    widen = 2e-9 * (2.0 + box * (1.0 + root_k))  # how far a candidate the search accepts may leave the box
    value, weight, worst, size = 0.0, 0.0, 0.0, 0.0
    g = np.zeros(k)
    for j in range(m - n_box):
        if y[j] > 0.0:
            value -= y[j] * b[j]
            weight += y[j]
            size += y[j] * (abs(b[j]) + norms[j] * root_k * (box + widen))
            worst = max(worst, 1.0 + abs(b[j]) + norms[j] * (1.0 + root_k * (box + widen)))
            for t in range(k):
                g[t] += y[j] * A[j, t]
    spread = 0.0
    for t in range(k):
        spread += abs(g[t])
    value -= (box + widen) * spread
    return value > 2e-9 * weight * worst + 1e-12 * size


@njit(**_JIT)
def least_violation(v0, A, b, active, m, k, n_box, by_rate, v_out, b_given, norms, rows, idx, G, r, lam, cand, L, y,
                    viol, rnorm):
    """The fallback's last resort for an infeasible whole-arm QP: the velocity closest to ``v0`` among
    those that violate the barrier rows least, uniformly: every row j < m − ``n_box`` relaxed to
    A_j v ≤ b_j + t w_j with the smallest t ≥ 0 that makes the QP feasible (20 steps of bisection; the
    last ``n_box`` rows, the speed bounds, are kept). The weight w_j is the row's norm ‖A_j‖ (t is then a
    speed of the command, rad/s), or 1 with ``by_rate`` (t is a rate of the barrier, ḣ: m/s of clearance for
    the distance barrier), which does not let a row of short lever, that asks for a large command to
    gain a little rate, outweigh the others. Only the 2k most demanding barrier rows (smallest b_j/w_j)
    take part. v = 0 is feasible at t = max_j −b_j/w_j, so this always answers. A row of zero norm cannot
    be acted on and is dropped. Writes ``v_out``; ``b`` and ``active`` are left changed, ``b_given`` and
    ``norms`` are scratch. Returns t."""
    hi = 0.0
    for j in range(m):
        b_given[j] = b[j]
        nrm = 0.0
        for t in range(k):
            nrm += A[j, t] * A[j, t]
        norms[j] = np.sqrt(nrm) if j < m - n_box else 0.0
        if j < m - n_box and nrm == 0.0:
            active[j] = False
        elif j < m - n_box:
            hi = max(hi, -b[j] / _weight(by_rate, norms[j]))
    # the search tries sets of up to k rows: keep the 2k most demanding barrier rows (smallest b_j/w_j),
    # so that a crowd of rows cannot make the ~20 solves below slow (a fallback, not the guarantee)
    for _ in range(m - n_box - 2 * k):
        worst, worst_j = -np.inf, -1
        kept = 0
        for j in range(m - n_box):
            if active[j]:
                kept += 1
                if b[j] / _weight(by_rate, norms[j]) > worst:
                    worst, worst_j = b[j] / _weight(by_rate, norms[j]), j
        if kept <= 2 * k:
            break
        active[worst_j] = False
    # Farkas weights for the kept rows (k ≤ 3, with the speed box): the bisection's steps below the least
    # uniform violation would each search every set of rows to the end, and the weights show that such
    # a search must fail, so it is skipped (its answer, FALLBACK, is the same)
    box = _speed_box(A, b, active, m, k, n_box) if k <= 3 else -1.0
    farkas = np.empty(m)
    certify = box >= 0.0 and _farkas_weights(A, b_given, norms, active, m, k, n_box, box, by_rate, farkas) > 0.0
    # relaxing rows never makes a feasible QP infeasible: if the kept rows are feasible as given (t = 0;
    # no certificate says otherwise, and often none does: without the rows left out they rarely conflict),
    # every step below would find its QP feasible and halve hi, so the steps go without their searches.
    # (The search's tolerance can accept rows as given that it rejects relaxed, with b within about 1e-9
    # of a nearly degenerate set; there the answer is the one at t ≈ 0 the tolerance accepted.)
    settled = False
    if not certify:
        for j in range(m):
            b[j] = b_given[j]
        settled = _project_one(v0, A, b, active, m, k, v_out, rows, idx, G, r, lam, cand, L, y, viol, rnorm) \
            != STATUS_FALLBACK
    lo = 0.0
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        if settled:
            hi = mid
            continue
        for j in range(m):
            b[j] = b_given[j] + mid * _weight(by_rate, norms[j])
        if certify and _certainly_infeasible(A, b, norms, m, k, n_box, box, farkas):
            lo = mid
        elif _project_one(v0, A, b, active, m, k, v_out, rows, idx, G, r, lam, cand, L, y, viol, rnorm) \
                == STATUS_FALLBACK:
            lo = mid
        else:
            hi = mid
    for j in range(m):
        b[j] = b_given[j] + hi * _weight(by_rate, norms[j])
    if _project_one(v0, A, b, active, m, k, v_out, rows, idx, G, r, lam, cand, L, y, viol, rnorm) == STATUS_FALLBACK:
        for t in range(k):
            v_out[t] = 0.0
    return hi
