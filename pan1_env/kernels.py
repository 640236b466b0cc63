"""Compiled (numba) kernels of the physics sub-step: the engine's single implementation.

The formulas are those of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety` and :mod:`pan1_env.control` (the documented, vectorised numpy reference);
the tests check the physics, filter and observation kernels against them (the small helpers
:func:`scale_command`, :func:`edge_length_errors`, :func:`formation_observations` and
:func:`reach_observations` through the environments' tests). The kernels loop over the arms of one
group (arms with the same number of links n and actuation, k actuated joints) so that a sub-step
costs a handful of calls whatever the team size.

The sub-step kernel keeps its per-arm scratch space in its own stack frame (:func:`_local`, fixed
shapes from the ``kernel_sizes`` tuples), where LLVM can keep it in registers.

Importing this module imports numba (about half a second); :mod:`pan1_env` itself does not, so
``import pan1_env`` stays fast. Compiled code is cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from .compiled import kernel_sizes  # the first two arguments of group_advance

__all__ = [
    "kernel_sizes",
    "group_terms",
    "group_advance",
    "group_advance_parallel",
    "group_end_effectors",
    "group_observations",
    "group_observations_parallel",
    "qp_project",
    "scale_command",
    "edge_length_errors",
    "formation_observations",
    "reach_observations",
]

STATUS_NOMINAL, STATUS_SOLVED, STATUS_FALLBACK = 0, 1, 2
# numpy error model: no zero-division checks in the hot loops (a zero pivot gives inf/NaN, caught by the
# finiteness checks); fast-math without nnan/ninf, so NaN and inf tests keep working, and without reassoc
# (with it LLVM let a NaN state through the RK4 step's finiteness check: tests/test_robustness.py).
# Without contract either: numba links a called kernel (``_advance_arms``) into its caller's module as a
# weak copy, compiled again there; in the process that compiles them the call goes to the callee's own
# copy, in a process that loads the caller from the disk cache to the caller's copy. With contract,
# LLVM fused multiply-adds differently in the two copies, so the first run after a change did not
# reproduce later runs bit for bit (tests/test_determinism.py). arcp and afn are value-changing too
# and could in principle differ the same way; the test would show it.
_JIT = {"cache": True, "error_model": "numpy", "fastmath": {"nsz", "arcp", "afn"}}


@intrinsic
def _local(typingctx, shape, dtype):
    """``_local((t_1, …, t_d), dtype)``: an uninitialised C-contiguous array of shape
    (len(t_1), …, len(t_d)) in the calling function's stack frame (one ``alloca`` in its entry block).

    The t_i are tuples (such as the ``kernel_sizes`` tuples), so the shape is part of their type and
    fixed at compile time; with the loops over it unrolled, LLVM promotes the array's entries to
    registers, which heap scratch arrays (that may alias any other array) do not allow. The array is
    valid until the calling function returns and must not be returned or stored: use it only for
    scratch space inside one kernel. (Numba has no public stack array: numba issues #2108, #5084.)"""
    if not (isinstance(shape, types.BaseTuple) and all(isinstance(t, types.BaseTuple) for t in shape.types)
            and isinstance(dtype, (types.NumberClass, types.DType))):
        return None
    dims = tuple(len(t) for t in shape.types)
    item = dtype.dtype
    array_type = types.Array(item, len(dims), "C")

    def codegen(context, builder, signature, args):
        data_type = context.get_data_type(item)
        count = int(np.prod(dims))
        data = cgutils.alloca_once(builder, data_type, size=context.get_constant(types.intp, max(count, 1)))
        itemsize = context.get_abi_sizeof(data_type)
        strides = [itemsize * int(np.prod(dims[a + 1:])) for a in range(len(dims))]
        array = make_array(array_type)(context, builder)
        intp = lambda value: context.get_constant(types.intp, value)  # noqa: E731
        populate_array(array, data=data, shape=[intp(d) for d in dims], strides=[intp(x) for x in strides],
                       itemsize=intp(itemsize), meminfo=None)
        return array._getvalue()

    return array_type(shape, dtype), codegen


# ---------------------------------------------------------------------------------------------------
# Per-arm building blocks. They work on small local arrays (one arm's state and scratch space) with
# sizes passed explicitly and no array views, slices or tuples of arrays: in numba each view costs
# an atomic reference-count update, which used to dominate the sub-step.


@njit(**_JIT, inline="always")
def _angles(q, phi, n, c, s):
    """c_α, s_α = cos, sin of the absolute link angle θ_α + φ (θ_α = q_1 + … + q_α)."""
    ang = phi
    for a in range(n):
        ang += q[a]
        c[a] = np.cos(ang)
        s[a] = np.sin(ang)


# Largest angle increments |δ| for which :func:`_rotate_angles` uses its short series (to δ⁶ and δ⁷:
# the first omitted term, δ⁸/8! for the cosine, is then below 2e-17) and its long one (to δ¹⁰ and δ¹¹:
# δ¹²/12! below 1e-19); larger increments take np.cos/np.sin. Both are within an ulp of cos δ and
# sin δ (tests/test_kernels.py). With 10 ms sub-steps the short series covers absolute link speeds
# up to 3 rad/s.
_SERIES_SHORT = 0.03
_SERIES_MAX = 0.125


@njit(**_JIT, inline="always")
def _rotate_angles(c0, s0, thd, h, n, c, s):
    """c, s of the link angles θ_α + h θ̇_α from those of θ_α (``c0``, ``s0``) and the absolute angular
    speeds θ̇_α (``thd``): the angle-sum formulas, with cos δ and sin δ of the small increment
    δ = h θ̇_α from their Taylor series, to δ⁶ and δ⁷ for |δ| ≤ ``_SERIES_SHORT`` and to δ¹⁰ and δ¹¹
    for |δ| ≤ ``_SERIES_MAX`` (within an ulp in both). An RK4 step's stages and end state are
    reached this way from the state at its start, so a sub-step evaluates no sine or cosine (the
    series is a handful of multiplications, and their chain lies on the sub-step's critical path)."""
    for a in range(n):
        d = h * thd[a]
        if abs(d) <= _SERIES_SHORT:
            d2 = d * d
            cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0))
            sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0)))
        elif abs(d) <= _SERIES_MAX:
            d2 = d * d
            cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (1.0 - d2 / 90.0))))
            sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0 * (1.0 - d2 / 110.0)))))
        else:
            cd = np.cos(d)
            sd = np.sin(d)
        c[a] = c0[a] * cd - s0[a] * sd
        s[a] = s0[a] * cd + c0[a] * sd


@njit(**_JIT, inline="always")
def _mass_terms(lam, c, s, v, passive, n, k, M, R, Sn, Mc, Hc, qd, thd, H):
    """M, q̇ = g0 v, M_comb and H_comb of one arm from its link angles' c, s (written to the arrays).

    M = Sᵀ (λ ∘ cos(θ_b − θ_a)) S and H = Sᵀ h, h_a = −Σ_b λ_ab sin(θ_b − θ_a) θ̇_b² (MODEL.md §1, §3);
    the differences θ_b − θ_a do not depend on φ, so c, s may include it. λ is symmetric, so each
    pair of links is visited once: ``R`` gets λ_ab cos(θ_b − θ_a) (symmetric), ``Sn`` gets
    λ_ab sin(θ_b − θ_a) (antisymmetric)."""
    for a in range(n):
        R[a, a] = lam[a, a]
        Sn[a, a] = 0.0
        for b in range(a + 1, n):
            rab = lam[a, b] * (c[b] * c[a] + s[b] * s[a])
            sab = lam[a, b] * (s[b] * c[a] - c[b] * s[a])
            R[a, b] = rab
            R[b, a] = rab
            Sn[a, b] = sab
            Sn[b, a] = -sab
    # M[a, b] = Σ_{α ≥ a} Σ_{β ≥ b} R[α, β]: suffix sums down the columns, then along the rows
    for b in range(n):
        acc = 0.0
        for a in range(n - 1, -1, -1):
            acc += R[a, b]
            R[a, b] = acc
    for a in range(n):
        acc = 0.0
        for b in range(n - 1, -1, -1):
            acc += R[a, b]
            M[a, b] = acc
    off = 1 if passive else 0
    inv = 1.0 / M[0, 0] if passive else 1.0
    if passive:
        acc = 0.0
        for j in range(k):
            acc += M[0, j + 1] * v[j]
        qd[0] = -acc * inv
    for j in range(k):
        qd[j + off] = v[j]
    acc = 0.0
    for a in range(n):
        acc += qd[a]
        thd[a] = acc
    acc = 0.0
    for a in range(n - 1, -1, -1):
        h = 0.0
        for b in range(n):
            h -= Sn[a, b] * thd[b] * thd[b]
        acc += h
        H[a] = acc
    if passive:
        for i in range(k):
            w = M[i + 1, 0] * inv
            Hc[i] = H[i + 1] - w * H[0]
            for j in range(k):
                Mc[i, j] = M[i + 1, j + 1] - w * M[0, j + 1]
    else:
        for i in range(n):
            Hc[i] = H[i]
            for j in range(n):
                Mc[i, j] = M[i, j]


@njit(**_JIT, inline="always")
def _spd_solve(G, r, x, size, L, y):
    """Solve G x = r (the leading ``size`` × ``size`` block, symmetric positive definite) by the
    square-root-free Cholesky factorisation G = L D Lᵀ; False if it is not SPD (a pivot D_i at or
    below 1e-12 × the largest diagonal entry: the same test as on the squared pivots of Cholesky).
    ``L`` (its diagonal holds 1 / D_i, its upper triangle L_ij D_j) and ``y`` are scratch space.
    One division per row and no square root: in the RK4 stages this chain of dependent operations
    sets much of the sub-step's cost."""
    scale = 0.0
    for i in range(size):
        scale = max(scale, G[i, i])
    for i in range(size):
        for j in range(i):
            acc = G[i, j]
            for t in range(j):
                acc -= L[i, t] * L[t, j]
            L[j, i] = acc  # L_ij D_j, kept in the upper triangle
            L[i, j] = acc * L[j, j]
        acc = G[i, i]
        for t in range(i):
            acc -= L[i, t] * L[t, i]
        if acc <= 1e-12 * scale:
            return False
        L[i, i] = 1.0 / acc
    for i in range(size):
        acc = r[i]
        for t in range(i):
            acc -= L[i, t] * y[t]
        y[i] = acc
    for i in range(size - 1, -1, -1):
        acc = y[i] * L[i, i]
        for t in range(i + 1, size):
            acc -= L[t, i] * x[t]
        x[i] = acc
    return True


@njit(**_JIT, inline="always")
def _position(lengths, bx, by, c, s, n):
    """End-effector p = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)] from the link angles' c, s."""
    px = bx
    py = by
    for a in range(n):
        px += lengths[a] * s[a]
        py += lengths[a] * c[a]
    return px, py


@njit(**_JIT, inline="always")
def _reduced_jacobian(lengths, c, s, M, passive, n, k, J, Jbar):
    """J̄ = J g0 (2 × k) from the link angles' c, s and the mass matrix (g0 = [−M_0a / M_00 ; I]).

    ∂p/∂q_a = Σ_{α≥a} L_α [cos, −sin](θ_α + φ)."""
    accx = 0.0
    accy = 0.0
    for a in range(n - 1, -1, -1):
        accx += lengths[a] * c[a]
        accy -= lengths[a] * s[a]
        J[0, a] = accx
        J[1, a] = accy
    for r in range(2):
        for t in range(k):
            if passive:
                Jbar[r, t] = J[r, t + 1] - J[r, 0] * M[0, t + 1] / M[0, 0]
            else:
                Jbar[r, t] = J[r, t]


@njit(**_JIT, inline="always")
def _acceleration(Mc, Hc, tau, k, dv, r, L, y):
    """v̇ = M_comb⁻¹ (τ_a − H_comb) (NaN if M_comb is not positive definite)."""
    for i in range(k):
        r[i] = tau[i] - Hc[i]
    if not _spd_solve(Mc, r, dv, k, L, y):
        for i in range(k):
            dv[i] = np.nan


@njit(**_JIT)
def group_terms(lam, lengths, base, phi, passive, q, v, p, Jbar, Mc, Hc, momentum):
    """Per arm: end-effector p (A,2), reduced Jacobian J̄ (A,2,k), M_comb, H_comb, passive momentum."""
    A, n = q.shape
    k = v.shape[1]
    c, s, qd, thd, H = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    M, R, Sn, J = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((2, n))
    Mc1, Hc1, Jb = np.empty((k, k)), np.empty(k), np.empty((2, k))
    for i in range(A):
        _angles(q[i], phi[i], n, c, s)
        _mass_terms(lam[i], c, s, v[i], passive, n, k, M, R, Sn, Mc1, Hc1, qd, thd, H)
        mom = 0.0
        for a in range(n):
            mom += M[0, a] * qd[a]
        momentum[i] = mom if passive else np.nan
        p[i, 0], p[i, 1] = _position(lengths[i], base[i, 0], base[i, 1], c, s, n)
        _reduced_jacobian(lengths[i], c, s, M, passive, n, k, J, Jb)
        for r in range(2):
            for t in range(k):
                Jbar[i, r, t] = Jb[r, t]
        for a in range(k):
            Hc[i, a] = Hc1[a]
            for b in range(k):
                Mc[i, a, b] = Mc1[a, b]


@njit(**_JIT)
def group_end_effectors(lengths, base, phi, q, p):
    """End-effector positions (A, 2) of a group."""
    n = q.shape[1]
    c, s = np.empty(n), np.empty(n)
    for i in range(q.shape[0]):
        _angles(q[i], phi[i], n, c, s)
        p[i, 0], p[i, 1] = _position(lengths[i], base[i, 0], base[i, 1], c, s, n)


@njit(**_JIT, inline="always")
def _obstacle_slots(out, row, col, c, px, py, centers, radii, team, K, bound, clear, taken):
    """Write K obstacle slots (present, dx, dy, r, h) at ``out[row, col, c:]`` for an end-effector at
    (px, py), from the obstacles ``centers[team]``, ``radii[team]``: the K obstacles of smallest
    clearance ‖p − o‖ − r (ties: lower index first), zeros where absent. Inlined, and indices rather
    than views: a view of a heap array costs two atomic reference-count updates."""
    O = radii.shape[1]
    for j in range(O):
        dx = centers[team, j, 0] - px
        dy = centers[team, j, 1] - py
        clear[j] = np.sqrt(dx * dx + dy * dy) - radii[team, j]
        taken[j] = False
    for _slot in range(K):
        best = -1
        for j in range(O):
            if not taken[j] and (best < 0 or clear[j] < clear[best]):
                best = j
        if best < 0:
            for f in range(5):
                out[row, col, c + f] = 0.0
        else:
            taken[best] = True
            dx = centers[team, best, 0] - px
            dy = centers[team, best, 1] - py
            rad = radii[team, best]
            out[row, col, c] = 1.0
            out[row, col, c + 1] = min(max(dx, -bound), bound)
            out[row, col, c + 2] = min(max(dy, -bound), bound)
            out[row, col, c + 3] = min(max(rad, -bound), bound)
            out[row, col, c + 4] = min(max(dx * dx + dy * dy - rad * rad, -bound), bound)
        c += 5


@njit(**_JIT)
def _observation_rows(lo, hi, q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present, K,
                      inv_vmax, bound, out):
    """Teams ``lo … hi−1`` of :func:`group_observations` (the loop body, with its own scratch space)."""
    D = neighbour.shape[1]
    O = radii.shape[1]
    size = out.shape[2]
    n = (size - 2 - 4 * D - 5 * K) // 3
    clear = np.empty(O)
    taken = np.empty(O, dtype=np.bool_)
    for bi in range(lo, hi):
        for r in range(ids.shape[0]):
            i = ids[r]
            for a in range(n):
                out[bi, r, a] = np.cos(q[bi, i, a])
                out[bi, r, n + a] = np.sin(q[bi, i, a])
                out[bi, r, 2 * n + a] = min(max(qd[bi, i, a] * inv_vmax, -bound), bound)
            px = P[bi, i, 0]
            py = P[bi, i, 1]
            out[bi, r, 3 * n] = min(max(px - base[bi, i, 0], -bound), bound)
            out[bi, r, 3 * n + 1] = min(max(py - base[bi, i, 1], -bound), bound)
            c = 3 * n + 2
            for s in range(D):
                if present[i, s]:
                    j = neighbour[i, s]
                    out[bi, r, c] = 1.0
                    out[bi, r, c + 1] = min(max(P[bi, j, 0] - px, -bound), bound)
                    out[bi, r, c + 2] = min(max(P[bi, j, 1] - py, -bound), bound)
                    out[bi, r, c + 3] = min(max(err[bi, neighbour_edge[i, s]], -bound), bound)
                else:
                    out[bi, r, c] = 0.0
                    out[bi, r, c + 1] = 0.0
                    out[bi, r, c + 2] = 0.0
                    out[bi, r, c + 3] = 0.0
                c += 4
            _obstacle_slots(out, bi, r, c, px, py, centers, radii, bi, K, bound, clear, taken)


@njit(**_JIT)
def _check_chunks(n_chunks):
    if n_chunks < 1:
        raise ValueError("n_chunks must be at least 1 (the multi-threaded kernels split their work into n_chunks)")


_OBSERVATIONS_DOC = """Local observations of the arms ``ids`` (all with n links) of B teams, written to
    ``out (B, A, size)``.

    Layout and inputs as :meth:`pan1_env.observation.ObservationLayout.build`; the K obstacle slots
    hold the K obstacles of smallest clearance ‖p − o‖ − r (ties: lower index first); entries are
    clipped to ±``bound``; absent slots are zeros.
    """


@njit(**_JIT)
def group_observations(q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present, K, inv_vmax,
                       bound, out):
    lo = q.shape[0] * 0  # an int64 like the parallel twin's chunk bounds: both run one compiled _observation_rows
    _observation_rows(lo, q.shape[0], q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present,
                      K, inv_vmax, bound, out)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_observations_parallel(q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present, K,
                                inv_vmax, bound, out, n_chunks):
    _check_chunks(n_chunks)
    B = q.shape[0]
    for c in prange(n_chunks):
        _observation_rows(c * B // n_chunks, (c + 1) * B // n_chunks, q, qd, P, base, err, centers, radii, ids,
                          neighbour, neighbour_edge, present, K, inv_vmax, bound, out)


group_observations.__doc__ = _OBSERVATIONS_DOC
group_observations_parallel.__doc__ = _OBSERVATIONS_DOC + """
    The same, with the teams split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches). Both run the same compiled per-team loop.
    """


@njit(**_JIT, inline="always")
def _project_one(v0, A, b, active, m, k, v_out, rows, idx, G, r, lam, cand, L, y, viol):
    """Exact min ½‖v − v0‖² s.t. A_j v ≤ b_j (rows j < m with active_j): returns a status code.

    Enumerates sets of active rows (sizes 1..k, rows in order of decreasing violation at v0): the
    projection of v0 onto the rows of a set, with non-negative multipliers and feasible for every
    row, satisfies the KKT conditions of this strictly convex QP, so it is the unique optimum and
    the search stops there (see :mod:`pan1_env.safety`). No such set: infeasible, brake (v = 0).
    The remaining arguments are scratch space: ``rows``, ``viol`` (m), ``idx``, ``r``, ``lam``,
    ``cand``, ``y`` (k) and ``G``, ``L`` (k × k).
    """
    feasible = True
    for j in range(m):
        if active[j]:
            acc = 0.0
            for t in range(k):
                acc += A[j, t] * v0[t]
            if acc > b[j] + 1e-12 * (1.0 + abs(b[j])):
                feasible = False
                break
    if feasible:
        for t in range(k):
            v_out[t] = v0[t]
        return STATUS_NOMINAL
    na = 0
    for j in range(m):
        if active[j]:
            nrm = 0.0
            acc = 0.0
            for t in range(k):
                nrm += A[j, t] * A[j, t]
                acc += A[j, t] * v0[t]
            if nrm > 0.0:
                # insertion by decreasing violation A_j v0 − b_j (most violated rows are tried first)
                w = (acc - b[j]) / np.sqrt(nrm)
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
            if _spd_solve(G, r, lam, size, L, y):
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
                        acc = 0.0
                        an = 0.0
                        for t in range(k):
                            acc += A[j, t] * cand[t]
                            an += A[j, t] * A[j, t]
                        if acc > b[j] + 1e-9 * (1.0 + abs(b[j]) + np.sqrt(an) * (1.0 + cn)):
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
            for z in range(x + 1, size):
                idx[z] = idx[z - 1] + 1
    for t in range(k):
        v_out[t] = 0.0
    return STATUS_FALLBACK


@njit(**_JIT)
def qp_project(v0, A, b, active, v_out, status):
    """Batched exact safety QP: for each arm i, project v0[i] onto {A[i] v ≤ b[i]}."""
    m, k = A.shape[1], A.shape[2]
    kk = max(k, 1)
    rows, viol = np.empty(m, dtype=np.int64), np.empty(m)
    idx = np.empty(kk, dtype=np.int64)
    r, lam, cand, y = np.empty(kk), np.empty(kk), np.empty(kk), np.empty(kk)
    G, L = np.empty((kk, kk)), np.empty((kk, kk))
    for i in range(v0.shape[0]):
        status[i] = _project_one(v0[i], A[i], b[i], active[i], m, k, v_out[i], rows, idx, G, r, lam, cand, L, y,
                                 viol)


@njit(**_JIT)
def _advance_arms(links, actuated, lo, hi, lam, lengths, base, phi, _passive, q, v, v_prev, has_prev, command,
                  torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out):
    """Arms ``lo … hi−1`` of :func:`group_advance` (the loop body, with its own scratch space).

    ``n`` and ``k`` are compile-time constants (the lengths of the tuples ``links`` and
    ``actuated``): with the loops over links and joints of known length, LLVM unrolls and
    interleaves them, which halves the sub-step's cost.

    Each arm's parameters and state are copied into small stack arrays (:func:`_local`), advanced
    through the sub-steps there and written back: the hot loop makes no array view and, but for the
    filter's rows, touches no heap scratch. The link angles' sines and cosines are computed from q
    (``_angles``) once per arm at the start of a call (and again after a non-finite state); RK4
    stages and the state a sub-step reaches get theirs by rotating those at the sub-step's start
    (``_rotate_angles``, within an ulp). Those at the state reached serve its clearance and the
    next sub-step's filter, tracker and first RK4 stage."""
    n = len(links)
    k = len(actuated)
    passive = k < n  # a compile-time constant (the argument, checked by the callers, is the same)
    kk = max(k, 1)
    O = radii.shape[1]
    m = O + 2 * k
    tau_off = tau_out.shape[1] - k  # 0 for (A, k) torques; n − k for full (A, n) rows (passive entries untouched)
    # Scratch space in this function's stack frame (shapes from the size tuples, so fixed at compile
    # time): LLVM keeps most of it in registers. Only the filter's rows, whose number depends on the
    # obstacles, live on the heap.
    f8 = np.float64
    nn, kx, NN, KK = (links,), (actuated,), (links, links), (actuated, actuated)
    two_n, two_k = ((0, 0), links), ((0, 0), actuated)
    # one arm's parameters and state
    lm, ln, qi, vi, vp = _local(NN, f8), _local(nn, f8), _local(nn, f8), _local(kx, f8), _local(kx, f8)
    # kinematics and dynamics at a state
    c, s, qd, thd, H = _local(nn, f8), _local(nn, f8), _local(nn, f8), _local(nn, f8), _local(nn, f8)
    c0, s0 = _local(nn, f8), _local(nn, f8)
    M, R, Sn, J = _local(NN, f8), _local(NN, f8), _local(NN, f8), _local(two_n, f8)
    Mc, Hc, Jbar, Lc, yc, rhs = _local(KK, f8), _local(kx, f8), _local(two_k, f8), _local(KK, f8), _local(kx, f8), \
        _local(kx, f8)
    # command, filter and tracker
    vdes, vs, tau, acc = _local(kx, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8)
    Arows, brows, active = np.zeros((m, kk)), np.zeros(m), np.zeros(m, dtype=np.bool_)
    qrows, qviol, qidx = np.empty(m, dtype=np.int64), np.empty(m), _local(kx, np.int64)
    qG, qL, qr, qlam, qcand, qy = _local(KK, f8), _local(KK, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8), \
        _local(kx, f8)
    # RK4: trial state, stage derivative, weighted sums
    qt, vt, dv, sq, sv = _local(nn, f8), _local(kx, f8), _local(kx, f8), _local(nn, f8), _local(kx, f8)
    if v_max < np.inf:
        for t in range(k):  # speed bounds ±v_t ≤ v_max
            Arows[O + 2 * t, t] = 1.0
            Arows[O + 2 * t + 1, t] = -1.0
            brows[O + 2 * t] = v_max
            brows[O + 2 * t + 1] = v_max
            active[O + 2 * t] = True
            active[O + 2 * t + 1] = True
    for i in range(lo, hi):
        for a in range(n):
            qi[a] = q[i, a]
            ln[a] = lengths[i, a]
            for b in range(n):
                lm[a, b] = lam[i, a, b]
        for t in range(k):
            vi[t] = v[i, t]
            vp[t] = v_prev[i, t]
            vs[t] = np.nan
            tau[t] = np.nan
        bx, by, ph = base[i, 0], base[i, 1], phi[i]
        finite_out[i] = True
        use_filter = filter_on and torque_mode and v_max < np.inf
        if filter_on:
            for j in range(O):
                active[j] = mask[i, j]
                if mask[i, j]:
                    use_filter = True
        prev_ok = has_prev[i]
        arm_clear = min_clear[i]
        arm_h = min_h[i]
        arm_track = max_track[i]
        cs_ok = True  # c, s hold the angles of (qi, φ)
        _angles(qi, ph, n, c, s)
        for _s in range(n_sub):
            _mass_terms(lm, c, s, vi, passive, n, k, M, R, Sn, Mc, Hc, qd, thd, H)
            # the velocity to filter: the command, or the one-step result of the commanded torque
            if torque_mode:
                for t in range(k):
                    tau[t] = command[i, t]
                if use_filter:
                    for t in range(k):
                        rhs[t] = tau[t] - Hc[t]
                    if not _spd_solve(Mc, rhs, acc, k, Lc, yc):
                        for t in range(k):
                            acc[t] = 0.0
                    for t in range(k):
                        vdes[t] = vi[t] + dt * acc[t]
            else:
                for t in range(k):
                    vdes[t] = command[i, t]
            st = STATUS_NOMINAL
            if use_filter:
                px, py = _position(ln, bx, by, c, s, n)
                _reduced_jacobian(ln, c, s, M, passive, n, k, J, Jbar)
                for j in range(O):
                    dx = px - centers[i, j, 0]
                    dy = py - centers[i, j, 1]
                    h = dx * dx + dy * dy - radii[i, j] * radii[i, j]
                    lg2 = 0.0
                    for t in range(k):
                        lg = 2.0 * (dx * Jbar[0, t] + dy * Jbar[1, t])
                        Arows[j, t] = -lg
                        lg2 += lg * lg
                    brows[j] = kappa * (h - margin) - lg2 / epsilon
                    if active[j] and h < arm_h:
                        arm_h = h
                st = _project_one(vdes, Arows, brows, active, m, k, vs, qrows, qidx, qG, qr, qlam, qcand, qL, qy,
                                  qviol)
            else:
                for t in range(k):
                    vs[t] = vdes[t]
            qp_counts[i, st] += 1
            if not torque_mode:
                # backstepping tracker of v* (Eq. 64), v̇* by backward difference
                err = 0.0
                for t in range(k):
                    err += (vi[t] - vs[t]) ** 2
                err = np.sqrt(err)
                if err > arm_track:
                    arm_track = err
                for t in range(k):
                    vdot = (vs[t] - vp[t]) / dt if prev_ok else 0.0
                    acc[t] = vdot - ke * (vi[t] - vs[t])
                for r in range(k):
                    tr = Hc[r]
                    for t in range(k):
                        tr += Mc[r, t] * acc[t]
                    tau[r] = tr
                for t in range(k):
                    vp[t] = vs[t]
                prev_ok = True
            elif st != STATUS_NOMINAL:
                # the torque's velocity was unsafe: reach the projected velocity in one step
                for r in range(k):
                    tr = Hc[r]
                    for t in range(k):
                        tr += Mc[r, t] * (vs[t] - vi[t]) / dt
                    tau[r] = tr
            if torque_mode and not use_filter:
                for t in range(k):
                    vs[t] = np.nan
            # RK4 with τ held; the first stage uses the terms at the current state, and every stage's
            # link angles come from the current ones (c0, s0) by a small rotation
            for a in range(n):
                c0[a] = c[a]
                s0[a] = s[a]
            _acceleration(Mc, Hc, tau, k, dv, rhs, Lc, yc)
            for a in range(n):
                sq[a] = qd[a]
            for t in range(k):
                sv[t] = dv[t]
            for stage in range(3):
                hs = 0.5 * dt if stage < 2 else dt
                w = 2.0 if stage < 2 else 1.0
                for t in range(k):
                    vt[t] = vi[t] + hs * dv[t]
                # the stage's state q + hs q̇: its link angles θ + hs θ̇ (θ̇ = thd of the previous stage)
                _rotate_angles(c0, s0, thd, hs, n, c, s)
                _mass_terms(lm, c, s, vt, passive, n, k, M, R, Sn, Mc, Hc, qd, thd, H)
                _acceleration(Mc, Hc, tau, k, dv, rhs, Lc, yc)
                for a in range(n):
                    sq[a] += w * qd[a]
                for t in range(k):
                    sv[t] += w * dv[t]
            finite = True
            acc_th = 0.0
            for a in range(n):
                qt[a] = qi[a] + dt / 6.0 * sq[a]
                acc_th += sq[a]
                thd[a] = acc_th  # Σ of the weighted stage speeds: the step moves link angle a by dt/6 · thd[a]
                if not np.isfinite(qt[a]):
                    finite = False
            for t in range(k):
                vt[t] = vi[t] + dt / 6.0 * sv[t]
                if not np.isfinite(vt[t]):
                    finite = False
            if not finite:
                finite_out[i] = False
                cs_ok = False
                break
            for a in range(n):
                qi[a] = qt[a]
            for t in range(k):
                vi[t] = vt[t]
            # clearance after the sub-step
            _rotate_angles(c0, s0, thd, dt / 6.0, n, c, s)
            px, py = _position(ln, bx, by, c, s, n)
            for j in range(O):
                dx = px - centers[i, j, 0]
                dy = py - centers[i, j, 1]
                cl = np.sqrt(dx * dx + dy * dy) - radii[i, j]
                if cl < arm_clear:
                    arm_clear = cl
        has_prev[i] = prev_ok
        min_clear[i] = arm_clear
        min_h[i] = arm_h
        max_track[i] = arm_track
        for t in range(k):
            v_star_out[i, t] = vs[t]
            tau_out[i, tau_off + t] = tau[t]
            v[i, t] = vi[t]
            v_prev[i, t] = vp[t]
        # joint velocities and end-effector at the (last finite) state
        if not cs_ok:
            _angles(qi, ph, n, c, s)
        _mass_terms(lm, c, s, vi, passive, n, k, M, R, Sn, Mc, Hc, qd, thd, H)
        for a in range(n):
            q[i, a] = qi[a]
            qd_out[i, a] = qd[a]
        p_out[i, 0], p_out[i, 1] = _position(ln, bx, by, c, s, n)


_ADVANCE_DOC = """Advance every arm of a group by ``n_sub`` physics steps with a held command (in place).

    ``links, actuated = kernel_sizes(n, k)`` are tuples of length n and k, the arms' numbers of
    links and actuated joints (``q.shape[1]`` and ``v.shape[1]``, else ValueError): numba types a
    tuple by its length, so n and k are compile-time constants and the kernel is compiled once per
    (n, k) pair, on its first use, and cached on disk. ``passive`` must agree with them (k = n − 1
    for a PAn−1 arm, k = n for a fully actuated one, else ValueError): the kernel takes it from k < n,
    a compile-time constant too.

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

    Outputs (per arm): ``v_star_out``/``tau_out`` of the last sub-step (``tau_out`` either
    ``(A, k)`` actuated torques or full ``(A, n)`` rows, whose passive entry is left as passed in), ``qd_out`` the joint
    velocities q̇ = g0 v and ``p_out`` the end-effector at the final state, ``min_clear`` the
    smallest clearance ‖p − o_j‖ − r_j to any obstacle after every sub-step (running minimum with
    the value passed in), ``min_h`` the smallest filtered barrier seen, ``qp_counts[i, s]`` the
    number of sub-steps with QP status s, ``max_track`` the largest tracking error ‖v − v*‖ at the
    start of a sub-step (velocity mode; running maximum with the value passed in), ``finite_out``
    False for an arm whose state went non-finite (left at its last finite value). The first stage
    of each RK4 step reuses the terms the filter and tracker computed at the same state.
    """


@njit(**_JIT)
def _check_sizes(links, actuated, passive, q, v):
    if q.shape[1] != len(links) or v.shape[1] != len(actuated):
        raise ValueError("group_advance: links, actuated must be kernel_sizes(q.shape[1], v.shape[1])")
    if len(actuated) != len(links) - (1 if passive else 0):
        raise ValueError("group_advance: a PAn-1 arm (passive) has k = n - 1 actuated joints, a full one k = n")


@njit(**_JIT)
def group_advance(links, actuated, lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command, torque_mode,
                  filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out):
    _check_sizes(links, actuated, passive, q, v)
    lo = q.shape[0] * 0  # an int64 like the parallel kernel's chunk bounds: both run one compiled _advance_arms
    _advance_arms(links, actuated, lo, q.shape[0], lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command,
                  torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_advance_parallel(links, actuated, lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command,
                           torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                           v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track,
                           finite_out, n_chunks):
    _check_sizes(links, actuated, passive, q, v)
    _check_chunks(n_chunks)
    A = q.shape[0]
    for c in prange(n_chunks):
        _advance_arms(links, actuated, c * A // n_chunks, (c + 1) * A // n_chunks, lam, lengths, base, phi, passive,
                      q, v, v_prev, has_prev, command, torque_mode, filter_on, centers, radii, mask, kappa, epsilon,
                      margin, ke, dt, n_sub, v_max, v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts,
                      max_track, finite_out)


group_advance.__doc__ = _ADVANCE_DOC
group_advance_parallel.__doc__ = _ADVANCE_DOC + """
    The same, with the arms split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches; a call costs a few microseconds more than :func:`group_advance`). Both run the same
    compiled per-arm loop with no reduction across arms; compiled without contraction (see ``_JIT``)
    they have agreed bit for bit in every test (``tests/test_vector.py``, ``tests/test_determinism.py``).
    """


@njit(**_JIT)
def scale_command(command, k, scale, effort):
    """Actions to a physical command, in place: clip each row's first ``k[i]`` entries to [−1, 1],
    write ``effort[i] = ‖clipped row‖² / k[i]`` and multiply by ``scale``. Returns the first row
    holding NaN or inf (left untouched), or −1."""
    for i in range(command.shape[0]):
        for t in range(k[i]):
            if not np.isfinite(command[i, t]):
                return i
    for i in range(command.shape[0]):
        e = 0.0
        for t in range(k[i]):
            a = min(max(command[i, t], -1.0), 1.0)
            e += a * a
            command[i, t] = a * scale
        effort[i] = e / max(k[i], 1)
    return -1


@njit(**_JIT)
def edge_length_errors(P, edges, distances, out):
    """‖p_i − p_j‖ − d_k for every edge k = (i, j) of B teams: P (B, N, 2), distances and out (B, E)."""
    for b in range(P.shape[0]):
        for e in range(edges.shape[0]):
            dx = P[b, edges[e, 0], 0] - P[b, edges[e, 1], 0]
            dy = P[b, edges[e, 0], 1] - P[b, edges[e, 1], 1]
            out[b, e] = np.sqrt(dx * dx + dy * dy) - distances[b, e]


@njit(**_JIT)
def reach_observations(q, qd, p, base, goal, centers, radii, K, inv_vmax, bound, out):
    """Observations of A one-arm reaching tasks, written to ``out (A, 3n + 4 + 5K)`` (float32):
    ``[cos q, sin q, q̇·inv_vmax, p − base, goal − p, K obstacle slots]``, each arm with its own
    goal ``(A, 2)`` and obstacles ``centers (A, O, 2)``, ``radii (A, O)``; entries other than
    cos/sin and flags clipped to ±``bound``."""
    n = q.shape[1]
    O = radii.shape[1]
    clear = np.empty(O)
    taken = np.empty(O, dtype=np.bool_)
    rows = out.reshape((1, out.shape[0], out.shape[1]))  # the layout _obstacle_slots indexes
    for i in range(q.shape[0]):
        for a in range(n):
            out[i, a] = np.cos(q[i, a])
            out[i, n + a] = np.sin(q[i, a])
            out[i, 2 * n + a] = min(max(qd[i, a] * inv_vmax, -bound), bound)
        px = p[i, 0]
        py = p[i, 1]
        out[i, 3 * n] = min(max(px - base[i, 0], -bound), bound)
        out[i, 3 * n + 1] = min(max(py - base[i, 1], -bound), bound)
        out[i, 3 * n + 2] = min(max(goal[i, 0] - px, -bound), bound)
        out[i, 3 * n + 3] = min(max(goal[i, 1] - py, -bound), bound)
        _obstacle_slots(rows, 0, i, 3 * n + 4, px, py, centers, radii, i, K, bound, clear, taken)


@njit(**_JIT)
def formation_observations(P, edges, distances, err, q, qd, base, centers, radii, ids, neighbour, neighbour_edge,
                           present, K, inv_vmax, bound, out):
    """:func:`edge_length_errors` into ``err (B, E)``, then :func:`group_observations` from them, in one call."""
    edge_length_errors(P, edges, distances, err)
    group_observations(q, qd, P, base, err, centers, radii, ids, neighbour, neighbour_edge, present, K, inv_vmax,
                       bound, out)
