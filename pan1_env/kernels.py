"""Compiled (numba) kernels of the physics sub-step: the engine's single implementation.

The formulas are those of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety` and :mod:`pan1_env.control` (the documented, vectorised numpy reference);
the tests check the physics, filter and observation kernels against them (the small helpers
:func:`scale_command`, :func:`edge_length_errors`, :func:`formation_observations` and
:func:`reach_observations` through the environments' tests). The kernels loop over the arms of one
group (arms with the same number of links n and actuation, k actuated joints) so that a sub-step
costs a handful of calls whatever the team size.

The sub-step kernel advances the arms W at a time, one arm per lane of arrays whose last axis is
the lanes, so that LLVM's SLP vectoriser (switched on for these kernels only:
:func:`_slp_vectorised`) packs four arms into each AVX register; it keeps this scratch space in
its own stack frame (:func:`_local`, fixed shapes from the ``kernel_sizes`` tuples), where LLVM
can keep it in registers. A lane's results do not depend on the lane count or on the arms that
share its group, bit for bit (tests/test_kernels.py).

Importing this module imports numba (about half a second); :mod:`pan1_env` itself does not, so
``import pan1_env`` stays fast. Compiled code is cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from . import compile_notice
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

compile_notice.install()  # a first use of an arm kind compiles for tens of seconds: say so

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
# Building blocks of the sub-step, for W arms at once (the lanes). They work on small local arrays
# with the lanes as their last axis, shape (…, W), sizes passed explicitly and no array views,
# slices or tuples of arrays (in numba each view costs an atomic reference-count update). In the
# sub-step kernel W is a compile-time constant and every operation is the same for all lanes, so
# LLVM's SLP vectoriser packs four lanes into each AVX register: the sub-step is a long chain of
# dependent operations, and W independent chains in vector registers cost about what one costs.
# Vector instructions round lane by lane, so a lane's results do not depend on W or on which arms
# share its lane group (tests/test_kernels.py). :func:`group_terms` runs them with W = 1.

# Largest angle increments |δ| for which :func:`_rotate_lanes` uses its short series (to δ⁶ and δ⁷:
# the first omitted term, δ⁸/8! for the cosine, is then below 2e-17) and its long one (to δ¹⁰ and δ¹¹:
# δ¹²/12! below 1e-19); larger increments take np.cos/np.sin. Both are within an ulp of cos δ and
# sin δ (tests/test_kernels.py). With 10 ms sub-steps the short series covers absolute link speeds
# up to 3 rad/s.
_SERIES_SHORT = 0.03
_SERIES_MAX = 0.125


@njit(**_JIT, forceinline=True)
def _lane_angles(q, phi, n, w, c, s):
    """c_α, s_α = cos, sin of lane w's absolute link angles θ_α + φ (θ_α = q_1 + … + q_α)."""
    ang = phi[w]
    for a in range(n):
        ang += q[a, w]
        c[a, w] = np.cos(ang)
        s[a, w] = np.sin(ang)


@njit(**_JIT, forceinline=True)
def _rotate_lanes(c0, s0, thd, h, n, W, c, s):
    """c, s of the link angles θ_α + h θ̇_α from those of θ_α (``c0``, ``s0``) and the absolute angular
    speeds θ̇_α (``thd``): the angle-sum formulas, with cos δ and sin δ of the small increment
    δ = h θ̇_α from their Taylor series, to δ⁶ and δ⁷ for |δ| ≤ ``_SERIES_SHORT`` and to δ¹⁰ and δ¹¹
    for |δ| ≤ ``_SERIES_MAX`` (within an ulp in both). An RK4 step's stages and end state are
    reached this way from the state at its start, so a sub-step evaluates no sine or cosine (the
    series is a handful of multiplications, and their chain lies on the sub-step's critical path).
    Both series are evaluated for every lane and one is selected by |δ| (a select, not a branch, so
    the lanes vectorise); lanes with larger |δ| (or NaN) are then redone with np.cos/np.sin."""
    big = False
    for a in range(n):
        for w in range(W):
            d = h * thd[a, w]
            d2 = d * d
            short_c = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0))
            short_s = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0)))
            long_c = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (1.0 - d2 / 90.0))))
            long_s = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0
                                                                                 * (1.0 - d2 / 110.0)))))
            ad = abs(d)
            cd = short_c if ad <= _SERIES_SHORT else long_c
            sd = short_s if ad <= _SERIES_SHORT else long_s
            big = big | (not ad <= _SERIES_MAX)
            c[a, w] = c0[a, w] * cd - s0[a, w] * sd
            s[a, w] = s0[a, w] * cd + c0[a, w] * sd
    if big:
        for a in range(n):
            for w in range(W):
                d = h * thd[a, w]
                if not abs(d) <= _SERIES_MAX:
                    cd = np.cos(d)
                    sd = np.sin(d)
                    c[a, w] = c0[a, w] * cd - s0[a, w] * sd
                    s[a, w] = s0[a, w] * cd + c0[a, w] * sd


@njit(**_JIT, forceinline=True)
def _mass_lanes(lam, c, s, v, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H):
    """M, q̇ = g0 v, M_comb and H_comb of W arms from their link angles' c, s (written to the arrays).

    M = Sᵀ (λ ∘ cos(θ_b − θ_a)) S and H = Sᵀ h, h_a = −Σ_b λ_ab sin(θ_b − θ_a) θ̇_b² (docs/MODEL.md §1, §3);
    the differences θ_b − θ_a do not depend on φ, so c, s may include it. λ is symmetric, so each
    pair of links is visited once: ``R`` gets λ_ab cos(θ_b − θ_a) (symmetric), ``Sn`` gets
    λ_ab sin(θ_b − θ_a) (antisymmetric)."""
    for a in range(n):
        for w in range(W):
            R[a, a, w] = lam[a, a, w]
            Sn[a, a, w] = 0.0
        for b in range(a + 1, n):
            for w in range(W):
                rab = lam[a, b, w] * (c[b, w] * c[a, w] + s[b, w] * s[a, w])
                sab = lam[a, b, w] * (s[b, w] * c[a, w] - c[b, w] * s[a, w])
                R[a, b, w] = rab
                R[b, a, w] = rab
                Sn[a, b, w] = sab
                Sn[b, a, w] = -sab
    # M[a, b] = Σ_{α ≥ a} Σ_{β ≥ b} R[α, β]: suffix sums down the columns, then along the rows
    for b in range(n):
        for w in range(W):
            acc = 0.0
            for a in range(n - 1, -1, -1):
                acc += R[a, b, w]
                R[a, b, w] = acc
    for a in range(n):
        for w in range(W):
            acc = 0.0
            for b in range(n - 1, -1, -1):
                acc += R[a, b, w]
                M[a, b, w] = acc
    off = 1 if passive else 0
    for w in range(W):
        inv = 1.0 / M[0, 0, w] if passive else 1.0
        if passive:
            acc = 0.0
            for j in range(k):
                acc += M[0, j + 1, w] * v[j, w]
            qd[0, w] = -acc * inv
        for j in range(k):
            qd[j + off, w] = v[j, w]
        acc = 0.0
        for a in range(n):
            acc += qd[a, w]
            thd[a, w] = acc
        acc = 0.0
        for a in range(n - 1, -1, -1):
            h = 0.0
            for b in range(n):
                h -= Sn[a, b, w] * thd[b, w] * thd[b, w]
            acc += h
            H[a, w] = acc
        if passive:
            for i in range(k):
                g = M[i + 1, 0, w] * inv
                Hc[i, w] = H[i + 1, w] - g * H[0, w]
                for j in range(k):
                    Mc[i, j, w] = M[i + 1, j + 1, w] - g * M[0, j + 1, w]
        else:
            for i in range(n):
                Hc[i, w] = H[i, w]
                for j in range(n):
                    Mc[i, j, w] = M[i, j, w]


@njit(**_JIT, forceinline=True)
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


@njit(**_JIT, forceinline=True)
def _solve_lanes(G, r, k, W, x, L, y, ok):
    """:func:`_spd_solve` of the k × k systems G x = r of W lanes, branch-free (so the lanes
    vectorise): ``ok[w]`` is False where G is not SPD (a pivot at or below 1e-12 × the largest
    diagonal entry), and that lane's x is then meaningless."""
    for w in range(W):
        scale = 0.0
        for i in range(k):
            scale = max(scale, G[i, i, w])
        good = True
        for i in range(k):
            for j in range(i):
                acc = G[i, j, w]
                for t in range(j):
                    acc -= L[i, t, w] * L[t, j, w]
                L[j, i, w] = acc
                L[i, j, w] = acc * L[j, j, w]
            acc = G[i, i, w]
            for t in range(i):
                acc -= L[i, t, w] * L[t, i, w]
            good = good & (not acc <= 1e-12 * scale)
            L[i, i, w] = 1.0 / acc
        ok[w] = good
        for i in range(k):
            acc = r[i, w]
            for t in range(i):
                acc -= L[i, t, w] * y[t, w]
            y[i, w] = acc
        for i in range(k - 1, -1, -1):
            acc = y[i, w] * L[i, i, w]
            for t in range(i + 1, k):
                acc -= L[t, i, w] * x[t, w]
            x[i, w] = acc


@njit(**_JIT, forceinline=True)
def _acceleration_lanes(Mc, Hc, tau, k, W, dv, r, L, y, ok):
    """v̇ = M_comb⁻¹ (τ_a − H_comb) of W lanes (NaN where M_comb is not positive definite)."""
    for t in range(k):
        for w in range(W):
            r[t, w] = tau[t, w] - Hc[t, w]
    _solve_lanes(Mc, r, k, W, dv, L, y, ok)
    for t in range(k):
        for w in range(W):
            dv[t, w] = dv[t, w] if ok[w] else np.nan


@njit(**_JIT, forceinline=True)
def _position_lanes(lengths, bx, by, c, s, n, W, px, py):
    """End-effectors p = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)] of W lanes, into ``px``, ``py`` (W)."""
    for w in range(W):
        x = bx[w]
        y = by[w]
        for a in range(n):
            x += lengths[a, w] * s[a, w]
            y += lengths[a, w] * c[a, w]
        px[w] = x
        py[w] = y


@njit(**_JIT, forceinline=True)
def _jacobian_lanes(lengths, c, s, M, passive, n, k, W, J, Jbar):
    """J̄ = J g0 (2 × k per lane) from the link angles' c, s and the mass matrix (g0 = [−M_0a / M_00 ; I]).

    ∂p/∂q_a = Σ_{α≥a} L_α [cos, −sin](θ_α + φ)."""
    for w in range(W):
        accx = 0.0
        accy = 0.0
        for a in range(n - 1, -1, -1):
            accx += lengths[a, w] * c[a, w]
            accy -= lengths[a, w] * s[a, w]
            J[0, a, w] = accx
            J[1, a, w] = accy
        for r in range(2):
            for t in range(k):
                if passive:
                    Jbar[r, t, w] = J[r, t + 1, w] - J[r, 0, w] * M[0, t + 1, w] / M[0, 0, w]
                else:
                    Jbar[r, t, w] = J[r, t, w]


@njit(**_JIT)
def group_terms(lam, lengths, base, phi, passive, q, v, p, Jbar, Mc, Hc, momentum):
    """Per arm: end-effector p (A,2), reduced Jacobian J̄ (A,2,k), M_comb, H_comb, passive momentum
    (one arm at a time, as a single lane of the sub-step kernel's building blocks)."""
    A, n = q.shape
    k = v.shape[1]
    lm, ln, qi, vi = np.empty((n, n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((k, 1))
    bx, by, ph, px, py = np.empty(1), np.empty(1), np.empty(1), np.empty(1), np.empty(1)
    c, s, qd, thd, H = np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1))
    M, R, Sn, J = np.empty((n, n, 1)), np.empty((n, n, 1)), np.empty((n, n, 1)), np.empty((2, n, 1))
    Mc1, Hc1, Jb = np.empty((k, k, 1)), np.empty((k, 1)), np.empty((2, k, 1))
    for i in range(A):
        for a in range(n):
            qi[a, 0] = q[i, a]
            ln[a, 0] = lengths[i, a]
            for b in range(n):
                lm[a, b, 0] = lam[i, a, b]
        for t in range(k):
            vi[t, 0] = v[i, t]
        bx[0], by[0], ph[0] = base[i, 0], base[i, 1], phi[i]
        _lane_angles(qi, ph, n, 0, c, s)
        _mass_lanes(lm, c, s, vi, passive, n, k, 1, M, R, Sn, Mc1, Hc1, qd, thd, H)
        mom = 0.0
        for a in range(n):
            mom += M[0, a, 0] * qd[a, 0]
        momentum[i] = mom if passive else np.nan
        _position_lanes(ln, bx, by, c, s, n, 1, px, py)
        p[i, 0], p[i, 1] = px[0], py[0]
        _jacobian_lanes(ln, c, s, M, passive, n, k, 1, J, Jb)
        for r in range(2):
            for t in range(k):
                Jbar[i, r, t] = Jb[r, t, 0]
        for a in range(k):
            Hc[i, a] = Hc1[a, 0]
            for b in range(k):
                Mc[i, a, b] = Mc1[a, b, 0]


@njit(**_JIT)
def group_end_effectors(lengths, base, phi, q, p):
    """End-effector positions (A, 2) of a group."""
    n = q.shape[1]
    ln, qi, c, s = np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1))
    bx, by, ph, px, py = np.empty(1), np.empty(1), np.empty(1), np.empty(1), np.empty(1)
    for i in range(q.shape[0]):
        for a in range(n):
            qi[a, 0] = q[i, a]
            ln[a, 0] = lengths[i, a]
        bx[0], by[0], ph[0] = base[i, 0], base[i, 1], phi[i]
        _lane_angles(qi, ph, n, 0, c, s)
        _position_lanes(ln, bx, by, c, s, n, 1, px, py)
        p[i, 0], p[i, 1] = px[0], py[0]


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
                root = np.sqrt(nrm)
                w = (acc - b[j]) / root
                x = na
                while x > 0 and viol[x - 1] < w:
                    rows[x] = rows[x - 1]
                    viol[x] = viol[x - 1]
                    rnorm[x] = rnorm[x - 1]
                    x -= 1
                rows[x] = j
                viol[x] = w
                rnorm[x] = root  # ‖A_j‖, for the feasibility tolerance below
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
                        for t in range(k):
                            acc += A[j, t] * cand[t]
                        if acc > b[j] + 1e-9 * (1.0 + abs(b[j]) + rnorm[jj] * (1.0 + cn)):
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
    rows, viol, rnorm = np.empty(m, dtype=np.int64), np.empty(m), np.empty(m)
    idx = np.empty(kk, dtype=np.int64)
    r, lam, cand, y = np.empty(kk), np.empty(kk), np.empty(kk), np.empty(kk)
    G, L = np.empty((kk, kk)), np.empty((kk, kk))
    for i in range(v0.shape[0]):
        status[i] = _project_one(v0[i], A[i], b[i], active[i], m, k, v_out[i], rows, idx, G, r, lam, cand, L, y,
                                 viol, rnorm)


@njit(**_JIT, forceinline=True)
def _rcbf_row_lanes(j, px, py, Jbar, obstacles, kappa, epsilon, margin, k, W, A, b, h):
    """The RCBF row of obstacle j for W lanes, A_j v ≤ b_j, into ``A (k, W)``, ``b (W)``:
    A_j = −L_g0 h_j and b_j = κ (h_j − margin) − ‖L_g0 h_j‖²/ε, with h_j = ‖p − o_j‖² − r_j² (also
    written to ``h``) and L_g0 h_j = 2 (p − o_j)ᵀ J̄ (docs/MODEL.md §4); ``obstacles (3, O, W)`` holds
    every lane's obstacle centres (x, y) and radii."""
    for w in range(W):
        dx = px[w] - obstacles[0, j, w]
        dy = py[w] - obstacles[1, j, w]
        hw = dx * dx + dy * dy - obstacles[2, j, w] * obstacles[2, j, w]
        lg2 = 0.0
        for t in range(k):
            lg = 2.0 * (dx * Jbar[0, t, w] + dy * Jbar[1, t, w])
            A[t, w] = -lg
            lg2 += lg * lg
        b[w] = kappa * (hw - margin) - lg2 / epsilon
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
        violated[w] = violated[w] | (act[w] & (acc > b[w] + 1e-12 * (1.0 + abs(b[w]))))
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
        bad = act[w] & (norm[w] > 0.0) & (acc > b[w] + 1e-9 * (1.0 + abs(b[w]) + norm[w] * (1.0 + cand_norm[w])))
        found[w] = found[w] & (not bad)


@njit(**_JIT, forceinline=True)
def _first_projection_lanes(px, py, Jbar, obstacles, active, filtered, kappa, epsilon, margin, v_max, O, k, W, v0,
                            arm_h, A, b, h, norm, act, rows, violated, best, best_viol, Ab, bb, cand, found):
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
        _rcbf_row_lanes(j, px, py, Jbar, obstacles, kappa, epsilon, margin, k, W, A, b, h)
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
            (not lam < -1e-12 * (1.0 + abs(lam)))
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


@njit(**_JIT)
def _advance_arms(links, actuated, lanes, lo, hi, lam, lengths, base, phi, _passive, q, v, v_prev, has_prev, command,
                  torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                  v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out):
    """Arms ``lo … hi−1`` of :func:`group_advance` (the loop body, with its own scratch space).

    ``n``, ``k`` and the lane count W are compile-time constants (the lengths of the tuples
    ``links``, ``actuated`` and ``lanes``): with the loops over links, joints and lanes of known
    length, LLVM unrolls them and packs the lanes into vector registers.

    The arms go W at a time (the last group padded with copies of the last arm, never written
    back). Each group's parameters and state are copied into stack arrays (:func:`_local`) with the
    lanes as their last axis, advanced through the sub-steps there and written back: the hot loop
    makes no array view and, but for the obstacles and the filter's rows, touches no heap scratch.
    Dynamics, tracker, RK4 and the safety filter's rows run on all lanes at once, and so does the QP
    as far as one active row settles it (:func:`_first_projection_lanes`, many filtered sub-steps);
    the lanes it does not settle get the full active-set search one by one (:func:`_project_one`).

    The link angles' sines and cosines are computed from q (``_lane_angles``) once per arm at the
    start of a call (and again after a non-finite state); RK4 stages and the state a sub-step reaches get
    theirs by rotating those at the sub-step's start (``_rotate_lanes``, within an ulp). Those at the
    state reached serve its clearance and the next sub-step's filter, tracker and first RK4 stage.

    An arm whose state goes non-finite stops there (its lane is frozen at the last finite state and
    its outputs are those of the failing sub-step), as its own loop would; the other lanes go on."""
    n = len(links)
    k = len(actuated)
    W = len(lanes)
    passive = k < n  # a compile-time constant (the argument, checked by the callers, is the same)
    kk = max(k, 1)
    O = radii.shape[1]
    m = O + 2 * k
    tau_off = tau_out.shape[1] - k  # 0 for (A, k) torques; n − k for full (A, n) rows (passive entries untouched)
    # Scratch space in this function's stack frame (shapes from the size tuples, so fixed at compile
    # time), the lanes last. Only what depends on the number of obstacles lives on the heap.
    f8, b1 = np.float64, np.bool_
    lw, nw, kw = (lanes,), (links, lanes), (actuated, lanes)
    nnw, kkw, kx, kkx = (links, links, lanes), (actuated, actuated, lanes), (actuated,), (actuated, actuated)
    # the lanes' arms, parameters and state
    arm, real = _local(lw, np.int64), _local(lw, b1)
    lm, ln, qi, vi, vp = _local(nnw, f8), _local(nw, f8), _local(nw, f8), _local(kw, f8), _local(kw, f8)
    bx, by, ph = _local(lw, f8), _local(lw, f8), _local(lw, f8)
    # kinematics and dynamics at a state
    c, s, qd, thd, H = _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(nw, f8)
    c0, s0, px, py = _local(nw, f8), _local(nw, f8), _local(lw, f8), _local(lw, f8)
    M, R, Sn, J = _local(nnw, f8), _local(nnw, f8), _local(nnw, f8), _local(((0, 0), links, lanes), f8)
    Mc, Hc, Jbar = _local(kkw, f8), _local(kw, f8), _local(((0, 0), actuated, lanes), f8)
    Lc, yc, rhs, ok = _local(kkw, f8), _local(kw, f8), _local(kw, f8), _local(lw, b1)
    # command, filter and tracker, per lane; the outputs of each lane's last sub-step (kept when it stops)
    vdes, vs, tau, acc = _local(kw, f8), _local(kw, f8), _local(kw, f8), _local(kw, f8)
    use_filter, prev_ok, live, status = _local(lw, b1), _local(lw, b1), _local(lw, b1), _local(lw, np.int64)
    arm_clear, arm_h, arm_track = _local(lw, f8), _local(lw, f8), _local(lw, f8)
    vs_last, tau_last, counts = _local(kw, f8), _local(kw, f8), _local(((0, 0, 0), lanes), np.int64)
    # the filter of every lane: its obstacles (centre x, y, radius), active rows, RCBF rows (A_j, b_j,
    # ‖A_j‖), one row at a time, and the first candidate (_first_projection_lanes)
    obstacles, lane_active = np.empty((3, O, W)), np.empty((O, W), dtype=np.bool_)
    obst_rows = np.empty((O, k + 2, W))
    row_A, row_b, row_h, row_norm = _local(kw, f8), _local(lw, f8), _local(lw, f8), _local(lw, f8)
    row_act, filtered, needs_qp = _local(lw, b1), _local(lw, b1), _local(lw, b1)
    q_best, q_best_viol, q_found = _local(lw, np.int64), _local(lw, f8), _local(lw, b1)
    q_Ab, q_bb, q_cand = _local(kw, f8), _local(lw, f8), _local(kw, f8)
    # one lane's full QP search (_project_one)
    Arows, brows, active = np.zeros((m, kk)), np.zeros(m), np.zeros(m, dtype=np.bool_)
    qrows, qviol, qnorm, qidx = np.empty(m, dtype=np.int64), np.empty(m), np.empty(m), _local(kx, np.int64)
    qv0, qvs = _local(kx, f8), _local(kx, f8)
    qG, qL, qr, qlam, qcand, qy = _local(kkx, f8), _local(kkx, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8), \
        _local(kx, f8)
    # RK4: trial state, stage derivative, weighted sums
    qt, vt, dv, sq, sv = _local(nw, f8), _local(kw, f8), _local(kw, f8), _local(nw, f8), _local(kw, f8)
    if v_max < np.inf:
        for t in range(k):  # the full search's speed bounds ±v_t ≤ v_max, the same in every lane
            Arows[O + 2 * t, t] = 1.0
            Arows[O + 2 * t + 1, t] = -1.0
            brows[O + 2 * t] = v_max
            brows[O + 2 * t + 1] = v_max
            active[O + 2 * t] = True
            active[O + 2 * t + 1] = True
    for first in range(lo, hi, W):
        for w in range(W):
            i = min(first + w, hi - 1)
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
            use_filter[w] = uf
            prev_ok[w] = has_prev[i]
            live[w] = True
            arm_clear[w] = min_clear[i]
            arm_h[w] = min_h[i]
            arm_track[w] = max_track[i]
            _lane_angles(qi, ph, n, w, c, s)
        any_filter = False
        for w in range(W):
            any_filter = any_filter | use_filter[w]
        for _s in range(n_sub):
            _mass_lanes(lm, c, s, vi, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
            # the velocity to filter: the command, or the one-step result of the commanded torque
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
            if any_filter:
                _position_lanes(ln, bx, by, c, s, n, W, px, py)
                _jacobian_lanes(ln, c, s, M, passive, n, k, W, J, Jbar)
                for w in range(W):
                    filtered[w] = use_filter[w] & live[w] & real[w]  # a padded lane's result is never used
                _first_projection_lanes(px, py, Jbar, obstacles, lane_active, filtered, kappa, epsilon, margin, v_max,
                                        O, k, W, vdes, arm_h, row_A, row_b, row_h, row_norm, row_act, obst_rows,
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
                        status[w] = _project_one(qv0, Arows, brows, active, m, k, qvs, qrows, qidx, qG, qr, qlam,
                                                 qcand, qL, qy, qviol, qnorm)
                        for t in range(k):
                            vs[t, w] = qvs[t]
            for x in range(3):
                for w in range(W):
                    counts[x, w] += 1 if live[w] and status[w] == x else 0
            if not torque_mode:
                # backstepping tracker of v* (Eq. 64), v̇* by backward difference
                for w in range(W):
                    err = 0.0
                    for t in range(k):
                        e = vi[t, w] - vs[t, w]
                        err += e * e
                    err = np.sqrt(err)
                    arm_track[w] = err if live[w] and err > arm_track[w] else arm_track[w]
                for t in range(k):
                    for w in range(W):
                        vdot = (vs[t, w] - vp[t, w]) / dt if prev_ok[w] else 0.0
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
                        # the torque's velocity was unsafe: reach the projected velocity in one step
                        for r in range(k):
                            tr = Hc[r, w]
                            for t in range(k):
                                tr += Mc[r, t, w] * (vs[t, w] - vi[t, w]) / dt
                            tau[r, w] = tr
                    elif not use_filter[w]:
                        for t in range(k):
                            vs[t, w] = np.nan
            for t in range(k):
                for w in range(W):
                    vs_last[t, w] = vs[t, w] if live[w] else vs_last[t, w]
                    tau_last[t, w] = tau[t, w] if live[w] else tau_last[t, w]
            # RK4 with τ held; the first stage uses the terms at the current state, and every stage's
            # link angles come from the current ones (c0, s0) by a small rotation
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
            for stage in range(3):
                hs = 0.5 * dt if stage < 2 else dt
                g = 2.0 if stage < 2 else 1.0
                for t in range(k):
                    for w in range(W):
                        vt[t, w] = vi[t, w] + hs * dv[t, w]
                # the stage's state q + hs q̇: its link angles θ + hs θ̇ (θ̇ = thd of the previous stage)
                _rotate_lanes(c0, s0, thd, hs, n, W, c, s)
                _mass_lanes(lm, c, s, vt, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
                _acceleration_lanes(Mc, Hc, tau, k, W, dv, rhs, Lc, yc, ok)
                for a in range(n):
                    for w in range(W):
                        sq[a, w] += g * qd[a, w]
                for t in range(k):
                    for w in range(W):
                        sv[t, w] += g * dv[t, w]
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
                else:  # frozen at its last finite state (whose angles the sub-step started from)
                    for a in range(n):
                        c[a, w] = c0[a, w]
                        s[a, w] = s0[a, w]
            if n_live == 0:
                break
            # clearance after the sub-step (a stopped lane keeps its value)
            _position_lanes(ln, bx, by, c, s, n, W, px, py)
            for j in range(O):
                for w in range(W):
                    dx = px[w] - obstacles[0, j, w]
                    dy = py[w] - obstacles[1, j, w]
                    cl = np.sqrt(dx * dx + dy * dy) - obstacles[2, j, w]
                    arm_clear[w] = cl if live[w] and cl < arm_clear[w] else arm_clear[w]
        # joint velocities and end-effector at the (last finite) state; a stopped arm's angles from q
        for w in range(W):
            if not live[w]:
                _lane_angles(qi, ph, n, w, c, s)
        _mass_lanes(lm, c, s, vi, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H)
        _position_lanes(ln, bx, by, c, s, n, W, px, py)
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
                for a in range(n):
                    q[i, a] = qi[a, w]
                    qd_out[i, a] = qd[a, w]
                p_out[i, 0] = px[w]
                p_out[i, 1] = py[w]


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


# The sub-step kernel's lane count: 4 arms at once (one AVX register of doubles), in the serial and
# the multi-threaded kernel alike (measured on this project's machine: 8 or 16 lanes were no faster
# on RK4 and about a fifth slower with the filter, whose per-lane search and larger code weigh more;
# a padded lane also costs as much as a real one).
_LANES = (0,) * 4


def _slp_vectorised(dispatcher):
    """Compile ``dispatcher``'s signatures with LLVM's SLP vectoriser on (numba leaves it off by
    default, ``NUMBA_SLP_VECTORIZE``, after miscompilations in older LLVMs: numba PR #8852). It is
    what packs the sub-step kernel's lanes into vector registers; the flag is set only while this
    dispatcher compiles (holding numba's compiler lock, so no other thread's compilation sees it; the
    small helpers it calls are compiled with it too) and restored after, so the user's numba code is
    compiled as the user configured it. The disk cache does not record the flag: code loaded from it
    was compiled through these dispatchers too. The flag is read when numba builds a pass manager,
    which numba on LLVM's new pass manager does per compilation (``CPUCodegen._pass_builder``,
    numba 0.68 here); with a numba without it the kernels are left as they are (the same results,
    slower).
    ``tests/test_kernels.py`` checks the vectorised kernel against the same kernel compiled without
    SLP, bit for bit."""
    from numba.core import codegen, config
    from numba.core.compiler_lock import global_compiler_lock

    if not hasattr(codegen.CPUCodegen, "_pass_builder"):
        # numba builds its pass managers once, from the first compilation: a flag set around one
        # dispatcher would not take effect (or would for all code). Leave it: same results, slower.
        return dispatcher
    compile_plain = dispatcher.compile

    def compile_slp(sig):
        with global_compiler_lock:  # re-entrant; held by numba around every compilation
            config.reload_config()  # a changed NUMBA_* variable would otherwise reset the flag mid-way
            saved = config.SLP_VECTORIZE
            config.SLP_VECTORIZE = 1
            try:
                return compile_plain(sig)
            finally:
                config.SLP_VECTORIZE = saved

    dispatcher.compile = compile_slp
    return dispatcher


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
    lo = q.shape[0] * 0  # an int64, like the parallel kernel's chunk bounds
    _advance_arms(links, actuated, _LANES, lo, q.shape[0], lam, lengths, base, phi, passive, q, v, v_prev,
                  has_prev, command, torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt,
                  n_sub, v_max, v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track, finite_out)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_advance_parallel(links, actuated, lam, lengths, base, phi, passive, q, v, v_prev, has_prev, command,
                           torque_mode, filter_on, centers, radii, mask, kappa, epsilon, margin, ke, dt, n_sub, v_max,
                           v_star_out, tau_out, qd_out, p_out, min_clear, min_h, qp_counts, max_track,
                           finite_out, n_chunks):
    _check_sizes(links, actuated, passive, q, v)
    _check_chunks(n_chunks)
    A = q.shape[0]
    for c in prange(n_chunks):
        _advance_arms(links, actuated, _LANES, c * A // n_chunks, (c + 1) * A // n_chunks, lam, lengths,
                      base, phi, passive, q, v, v_prev, has_prev, command, torque_mode, filter_on, centers, radii,
                      mask, kappa, epsilon, margin, ke, dt, n_sub, v_max, v_star_out, tau_out, qd_out, p_out,
                      min_clear, min_h, qp_counts, max_track, finite_out)


group_advance.__doc__ = _ADVANCE_DOC
_slp_vectorised(_advance_arms)
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
