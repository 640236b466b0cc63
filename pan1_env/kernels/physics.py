"""The sub-step's building blocks for W arms at once (dynamics, kinematics, Jacobians, the SPD solve),
and two group kernels built from them: :func:`group_terms` and :func:`group_end_effectors`."""

from __future__ import annotations

import numpy as np
from numba import njit

from ..safety import PIVOT_TOLERANCE
from ._numba_ext import _JIT

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
            # the coefficients as products with reciprocals, 1/12 etc. rounded once: a division per term
            # would cost more than the rest of the series (_JIT leaves arcp off, so LLVM keeps divisions)
            short_c = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)))
            short_s = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))))
            long_c = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) * (
                1.0 - d2 * (1.0 / 56.0) * (1.0 - d2 * (1.0 / 90.0)))))
            long_s = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0) * (
                1.0 - d2 * (1.0 / 72.0) * (1.0 - d2 * (1.0 / 110.0))))))
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
def _mass_lanes(lam, c, s, v, p1, damping, passive, n, k, W, M, R, Sn, Mc, Hc, qd, thd, H):
    """M, q̇, M_comb and H_comb of W arms from their link angles' c, s (written to the arrays).

    A PAn−1 arm's passive speed comes from its momentum ``p1`` (docs/MODEL.md §7):
    q̇₁ = (p₁ − M_1a v) / M_11, so q̇ = g0 v + e₁ p₁ / M_11, and its H_comb carries the passive joint's
    damping ``damping`` b: H_comb = H_a − M_a1 (H_1 + b q̇₁) / M_11. With p₁ = b = 0 this is §3's
    cascade, operation for operation (the paper's arm at rest before its first step).

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
            qd[0, w] = (p1[w] - acc) * inv
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
            h_passive = H[0, w] + damping[w] * qd[0, w]
            for i in range(k):
                g = M[i + 1, 0, w] * inv
                Hc[i, w] = H[i + 1, w] - g * h_passive
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
    below PIVOT_TOLERANCE × the largest diagonal entry: the same test as on the squared pivots of Cholesky).
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
        if acc <= PIVOT_TOLERANCE * scale:
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
    vectorise): ``ok[w]`` is False where G is not SPD (a pivot at or below PIVOT_TOLERANCE × the largest
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
            good = good & (not acc <= PIVOT_TOLERANCE * scale)
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


@njit(**_JIT, forceinline=True)
def _drift_lanes(J, M, p1, passive, W, drift):
    """The end-effector's drift d = J₁ p₁ / M_11 into ``drift (2, W)``: the velocity a PAn−1 arm's passive
    momentum p₁ gives it whatever the command (docs/MODEL.md §7); 0 for a fully actuated arm."""
    for w in range(W):
        per_momentum = p1[w] / M[0, 0, w] if passive else 0.0
        drift[0, w] = J[0, 0, w] * per_momentum
        drift[1, w] = J[1, 0, w] * per_momentum


@njit(**_JIT)
def group_terms(lam, lengths, base, phi, damping, passive, q, v, p1, p, Jbar, Mc, Hc, momentum, drift):
    """Per arm, at the state (q, v, p1): end-effector p (A,2), reduced Jacobian J̄ (A,2,k), M_comb, H_comb,
    the passive momentum Σ_α M_1α q̇_α recomputed from q̇ (NaN for a fully actuated arm) and the
    end-effector's drift J₁ p₁ / M_11 (A,2) (0 for a fully actuated arm), one arm at a time, as a single
    lane of the sub-step kernel's building blocks."""
    A, n = q.shape
    k = v.shape[1]
    lm, ln, qi, vi = np.empty((n, n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((k, 1))
    bx, by, ph, px, py = np.empty(1), np.empty(1), np.empty(1), np.empty(1), np.empty(1)
    pm, bd, d = np.empty(1), np.empty(1), np.empty((2, 1))
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
        pm[0], bd[0] = p1[i], damping[i]
        _lane_angles(qi, ph, n, 0, c, s)
        _mass_lanes(lm, c, s, vi, pm, bd, passive, n, k, 1, M, R, Sn, Mc1, Hc1, qd, thd, H)
        mom = 0.0
        for a in range(n):
            mom += M[0, a, 0] * qd[a, 0]
        momentum[i] = mom if passive else np.nan
        _position_lanes(ln, bx, by, c, s, n, 1, px, py)
        p[i, 0], p[i, 1] = px[0], py[0]
        _jacobian_lanes(ln, c, s, M, passive, n, k, 1, J, Jb)
        _drift_lanes(J, M, pm, passive, 1, d)
        drift[i, 0], drift[i, 1] = d[0, 0], d[1, 0]
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

