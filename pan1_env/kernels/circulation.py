"""The circulation term round obstacles for every arm of a kind (``action_mode="circulation"``).

The compiled twin of :func:`pan1_env.baselines.circulation.circulation_term` with its sense +1 (anticlockwise) and
gain 1, one arm per row: for every body point x of the arm within ``activation`` m of obstacle o (each link's closest
point to o, or the end-effector), with J_x the point's Jacobian through g0 (actuated velocities to ẋ), a = (x − o)ᵀ J_x
and t the quarter turn of (x − o) through J_x less its part along a, the sum of max(0, −a·v0)/‖a‖ · t/‖t‖ over the
pairs. The term is linear in the sense, so a signed strength scales it afterwards (:meth:`pan1_env.engine.Engine.
circulation`); the arm's mass matrix (for g0) comes from the sub-step's own :func:`.physics._mass_lanes`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_ext import _JIT
from .capsules import _joints
from .physics import _lane_angles, _mass_lanes

TINY = 1e-12  #: a row or a tangent shorter than this has no direction (the rule's threshold)


@njit(**_JIT)
def group_circulation(lam, lengths, base, phi, passive, q, copy_of_row, centers, radii, link_radius, links,
                      activation, v0, out):
    """``out (A, k)``: the anticlockwise circulation term of each arm row at joint angles ``q (A, n)`` for its law's
    command ``v0 (A, k)``, against the obstacles ``centers (B, O, 2)``, ``radii (B, O)`` of its copy
    ``copy_of_row (A,)``; ``links`` whether the bodies are the links (capsules of ``link_radius``), else the
    end-effector."""
    A, n = q.shape
    k = v0.shape[1]
    lm, qi, vi, pm, bd = np.empty((n, n, 1)), np.empty((n, 1)), np.zeros((k, 1)), np.zeros(1), np.zeros(1)
    c, s, qd, thd, H = np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1))
    M, R, Sn = np.empty((n, n, 1)), np.empty((n, n, 1)), np.empty((n, n, 1))
    Mc1, Hc1 = np.empty((k, k, 1)), np.empty((k, 1))
    joints, g0, Jg = np.empty((n + 1, 2)), np.zeros((n, k)), np.empty((2, k))
    av, tv = np.empty(k), np.empty(k)
    ph, ln, bx, by = np.empty(1), np.empty((n, 1)), np.empty(1), np.empty(1)
    for i in range(A):
        for a in range(n):
            qi[a, 0] = q[i, a]
            ln[a, 0] = lengths[i, a]
            for b in range(n):
                lm[a, b, 0] = lam[i, a, b]
        ph[0], bx[0], by[0] = phi[i], base[i, 0], base[i, 1]
        _lane_angles(qi, ph, n, 0, c, s)
        _joints(ln, bx, by, c, s, n, 0, joints)  # the whole-arm rows' joint positions
        for j in range(k):
            out[i, j] = 0.0
        _circulation_pairs(i, n, k, passive, copy_of_row[i], centers, radii, link_radius, links, activation, joints,
                           lm, c, s, vi, pm, bd, M, R, Sn, Mc1, Hc1, qd, thd, H, g0, Jg, av, tv, v0, out)


@njit(**_JIT)
def _circulation_pairs(i, n, k, passive, b, centers, radii, link_radius, links, activation, joints, lm, c, s, vi,
                       pm, bd, M, R, Sn, Mc1, Hc1, qd, thd, H, g0, Jg, av, tv, v0, out):
    """Row i's term summed over its (body point, obstacle) pairs in range, links outer and obstacles inner (the
    rule's order); g0 is computed at the first pair only."""
    have_g0 = False
    first = 0 if links else n - 1
    for link in range(first, n):
        for o in range(radii.shape[1]):
            ox, oy = centers[b, o, 0], centers[b, o, 1]
            if links:  # the link's closest point to the obstacle's centre
                ax, ay = joints[link, 0], joints[link, 1]
                dx, dy = joints[link + 1, 0] - ax, joints[link + 1, 1] - ay
                dd = dx * dx + dy * dy
                t = min(max(((ox - ax) * dx + (oy - ay) * dy) / dd, 0.0), 1.0) if dd > 0.0 else 0.0
                x, y = ax + t * dx, ay + t * dy
                gap = np.sqrt((x - ox) ** 2 + (y - oy) ** 2) - radii[b, o] - link_radius
            else:
                x, y = joints[n, 0], joints[n, 1]
                gap = np.sqrt((x - ox) ** 2 + (y - oy) ** 2) - radii[b, o]
            if not gap < activation:
                continue
            if not have_g0:
                _passive_map(n, k, passive, lm, c, s, vi, pm, bd, M, R, Sn, Mc1, Hc1, qd, thd, H, g0)
                have_g0 = True
            _point_jacobian(n, k, link, x, y, joints, g0, Jg)
            rx, ry = x - ox, y - oy
            for j in range(k):
                av[j] = rx * Jg[0, j] + ry * Jg[1, j]
                tv[j] = -ry * Jg[0, j] + rx * Jg[1, j]
            _add_turn(i, k, av, tv, v0, out)


@njit(**_JIT)
def _passive_map(n, k, passive, lm, c, s, vi, pm, bd, M, R, Sn, Mc1, Hc1, qd, thd, H, g0):
    """g0 (n, k) at the angles c, s: [−M_1a / M_11 ; I] for a PAn−1 arm, I otherwise."""
    _mass_lanes(lm, c, s, vi, pm, bd, passive, n, k, 1, M, R, Sn, Mc1, Hc1, qd, thd, H)
    shift = 1 if passive else 0
    for a in range(n):
        for j in range(k):
            g0[a, j] = 1.0 if a == j + shift else 0.0
    if passive:
        for j in range(k):
            g0[0, j] = -M[0, j + 1, 0] / M[0, 0, 0]


@njit(**_JIT)
def _point_jacobian(n, k, link, x, y, joints, g0, Jg):
    """J_x g0 (2, k) of the point (x, y) moved by joints 0 … link: joint m turns it about joint m's position,
    ∂(x, y)/∂q_m = (y − y_m, −(x − x_m)) (the angles run clockwise from the y axis)."""
    for j in range(k):
        Jg[0, j] = 0.0
        Jg[1, j] = 0.0
    for m in range(link + 1):
        jx, jy = y - joints[m, 1], -(x - joints[m, 0])
        for j in range(k):
            Jg[0, j] += jx * g0[m, j]
            Jg[1, j] += jy * g0[m, j]


@njit(**_JIT)
def _add_turn(i, k, av, tv, v0, out):
    """Add max(0, −a·v0)/‖a‖ · t̂ to row i, t the tangent ``tv`` less its part along ``av``."""
    na2, into, ta = 0.0, 0.0, 0.0
    for j in range(k):
        na2 += av[j] * av[j]
        into -= av[j] * v0[i, j]
        ta += tv[j] * av[j]
    na = np.sqrt(na2)
    if na < TINY or into <= 0.0:
        return
    nt2 = 0.0
    for j in range(k):
        tv[j] -= ta / na2 * av[j]
        nt2 += tv[j] * tv[j]
    nt = np.sqrt(nt2)
    if nt > TINY:
        for j in range(k):
            out[i, j] += into / na * tv[j] / nt
