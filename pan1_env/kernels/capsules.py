"""Whole-arm safety in the sub-step kernel: an arm's protected bodies (every link's capsule, or its
end-effector) against capsule obstacles (still or moving disks, other arms' links), one lane at a time.

The formulas are :mod:`pan1_env.bodies`' (the numpy reference, tested against this): for a body
point x on link ℓ at parameter τ and the closest point y of an obstacle capsule of radius r,

    h = ‖x − y‖² − (r + ρ)²,   ∇_q h = 2 (x − y)ᵀ J_x,   L_g0 h = ∇_q h · g0,   ∂h/∂t = −2 (x − y)·ẏ

(ρ the body's radius: ``link_radius`` for a link, 0 for the end-effector; the closest pair held fixed,
the gradient of the clamped distance, see :mod:`pan1_env.bodies`). The RCBF row, as for the
end-effector rows (docs/MODEL.md §4), with the obstacle's motion and the pair's share σ of the rate
budget (σ = 1 for a world obstacle, ½ for a capsule of another arm that filters too):

    −L_g0 h · v ≤ σ κ (h − margin) + ∂h/∂t − ‖L_g0 h‖² / ε

or with the filter choices of docs/MODEL.md §5a (``distance``: h = ‖x − y‖ − (r + ρ), the row and
∂h/∂t over 2‖x − y‖; ``decay`` λ: ε(h̃) = ε e^{λ h̃}, h̃ = h − margin), as :func:`pan1_env.safety.cbf_rows`.

A capsule is a row of ``capsules (A, C, CAPSULE_COLUMNS)``: its segment's end points at time 0 (equal
for a disk), radius, share, the unit direction, length and speed of its back-and-forth path
(:func:`pan1_env.bodies.obstacle_centers`), whether the arm's filter considers it, its kind (a world
obstacle, or link ``CAP_LINK`` of another arm, whose segment the engine refreshes every sub-step while it is
active), and its floor: a lower bound on its clearance to any body of the arm in any configuration, from the
arm's base and reach and the capsule's path (or the other arm's base and reach).

The first ``n_world`` capsules are the world's obstacles, in the world's order. The other arms' links
follow in order of floor, so the arms whose reach can meet this arm's (floor ≤ 0, active) come first and
a scan of them stops at the first inactive one, and a scan for the clearance stops at the first floor
above the clearance found so far: the work per arm follows the nearby arms, not the team's size.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_ext import _JIT

(CAP_AX, CAP_AY, CAP_BX, CAP_BY, CAP_RADIUS, CAP_SHARE, CAP_UX, CAP_UY, CAP_PATH, CAP_SPEED, CAP_ACTIVE, CAP_ARM,
 CAP_LINK, CAP_FLOOR) = range(14)
CAPSULE_COLUMNS = 14  #: columns of a capsule row; ``CAP_ARM`` is −1 for a world obstacle or an unused slot
#: :func:`whole_arm_rows`' scratch: segment now, its start's velocity, half length, reach, range, share, its end's
#: velocity, whether it is a stretch of path, how much farther the fault margin looks (−1: another arm's link)
NEAR_COLUMNS = 14


@njit(**_JIT, forceinline=True)
def _unit(x):
    return min(max(x, 0.0), 1.0)


@njit(**_JIT, forceinline=True)
def _closest_pair(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y):
    """Parameters (s, t) ∈ [0, 1]² of a closest pair of the segments a1 + s d1 and a2 + t d2 (either may
    have length 0): :func:`pan1_env.bodies.segment_distance`'s construction (Ericson §5.1.9)."""
    rx, ry = a1x - a2x, a1y - a2y
    A = d1x * d1x + d1y * d1y
    E = d2x * d2x + d2y * d2y
    F = d2x * rx + d2y * ry
    if A <= 0.0:
        return 0.0, (_unit(F / E) if E > 0.0 else 0.0)
    C = d1x * rx + d1y * ry
    if E <= 0.0:
        return _unit(-C / A), 0.0
    B = d1x * d2x + d1y * d2y
    denom = A * E - B * B
    s = _unit((B * F - C * E) / denom) if denom > 1e-12 * A * E else 0.0
    t = (B * s + F) / E
    if t < 0.0:
        return _unit(-C / A), 0.0
    if t > 1.0:
        return _unit((B - C) / A), 1.0
    return s, t


@njit(**_JIT, forceinline=True)
def _gap(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y):
    """(s, rx, ry): the parameter s on the first segment of the closest pair (:func:`_closest_pair`) and
    the vector from the second segment's closest point to the first's."""
    sp, tp = _closest_pair(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y)
    return sp, a1x + sp * d1x - (a2x + tp * d2x), a1y + sp * d1y - (a2y + tp * d2y)


@njit(**_JIT, forceinline=True)
def _wave(speed, length, time):
    """(arc, u) of an obstacle going back and forth on a path of ``length`` at ``speed``: its travel mod 2ℓ (< ℓ
    outward) and its distance along the path, the triangle wave of :func:`pan1_env.bodies.obstacle_centers`."""
    period = 2.0 * length
    arc = speed * time
    arc -= period * np.floor(arc / period)  # mod 2ℓ: a floor and a division cost a fraction of fmod's libm call
    return arc, length - abs(length - arc)


@njit(**_JIT, forceinline=True)
def _capsule_now(caps, i, j, time):
    """Capsule j of arm i at ``time``: its segment's start and direction (a2x, a2y, d2x, d2y) and its
    velocity (vx, vy), the start moved along the path by the triangle wave of
    :func:`pan1_env.bodies.obstacle_centers`."""
    ax, ay = caps[i, j, CAP_AX], caps[i, j, CAP_AY]
    dx, dy = caps[i, j, CAP_BX] - ax, caps[i, j, CAP_BY] - ay
    speed, length = caps[i, j, CAP_SPEED], caps[i, j, CAP_PATH]
    if not (speed > 0.0 and length > 0.0):
        return ax, ay, dx, dy, 0.0, 0.0
    arc, u = _wave(speed, length, time)
    sign = 1.0 if arc < length else -1.0
    ux, uy = caps[i, j, CAP_UX], caps[i, j, CAP_UY]
    return ax + u * ux, ay + u * uy, dx, dy, sign * speed * ux, sign * speed * uy


@njit(**_JIT, forceinline=True)
def _capsule_ahead(caps, i, j, time, lookahead):
    """The stretch of world obstacle j's path that it covers from ``time`` to ``time + lookahead`` (its
    whole path once that is a full period, 2ℓ/speed, or more): the segment's start and direction
    (a2x, a2y, d2x, d2y) and the velocities of its start and of its end (:func:`_capsule_now`'s wave).
    The obstacle is a disk, so the stretch is a capsule of its radius; a still one is itself."""
    ax, ay = caps[i, j, CAP_AX], caps[i, j, CAP_AY]
    speed, length = caps[i, j, CAP_SPEED], caps[i, j, CAP_PATH]
    if not (speed > 0.0 and length > 0.0):
        return ax, ay, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ux, uy = caps[i, j, CAP_UX], caps[i, j, CAP_UY]
    arc, u = _wave(speed, length, time)
    ahead = speed * lookahead
    lo, hi, v_lo, v_hi = 0.0, length, 0.0, 0.0  # the whole path: still
    if ahead < 2.0 * length:
        if arc < length:  # outward: covers u … u + ahead, or turns at ℓ and comes back to 2ℓ − ahead − u
            back = 2.0 * length - ahead - u
            if ahead <= length - u:
                lo, hi, v_lo, v_hi = u, u + ahead, speed, speed
            elif back > 0.0:
                lo, v_lo = (back, -speed) if back < u else (u, speed)
        else:  # inward: covers u − ahead … u, or turns at 0 and goes out again to ahead − u
            out = ahead - u
            if ahead <= u:
                lo, hi, v_lo, v_hi = u - ahead, u, -speed, -speed
            elif out < length:
                hi, v_hi = (out, speed) if out > u else (u, -speed)
    return ax + lo * ux, ay + lo * uy, (hi - lo) * ux, (hi - lo) * uy, v_lo * ux, v_lo * uy, v_hi * ux, v_hi * uy


@njit(**_JIT, forceinline=True)
def _joints(lengths, bx, by, c, s, n, w, P):
    """Joint positions P[0] = base, …, P[n] = end-effector of lane w, into ``P (n + 1, 2)``."""
    x, y = bx[w], by[w]
    P[0, 0], P[0, 1] = x, y
    for a in range(n):
        x += lengths[a, w] * s[a, w]
        y += lengths[a, w] * c[a, w]
        P[a + 1, 0], P[a + 1, 1] = x, y


@njit(**_JIT, forceinline=True)
def _body(P, n, links, body):
    """Body ``body``'s segment (start, direction) and link: link ``body`` with ``links``, else the
    end-effector (a point: the end of link n − 1)."""
    if links:
        return P[body, 0], P[body, 1], P[body + 1, 0] - P[body, 0], P[body + 1, 1] - P[body, 1], body
    return P[n, 0], P[n, 1], 0.0, 0.0, n - 1


@njit(**_JIT)
def most_rows(bodies, capsules, n_world, k):
    """The most rows :func:`whole_arm_rows` writes for an arm of ``bodies`` bodies and ``k`` actuated joints against
    ``capsules`` capsules, the first ``n_world`` the world's (two rows a body with a look-ahead, and twice that with
    the fault margin), the fault margin's two momentum rows, its speed box and torque mode's input bound."""
    return bodies * (capsules + 3 * n_world) + 2 + 4 * k


@njit(**_JIT, forceinline=True)
def _pair_row(m, ell, tau, rx, ry, passive, n, k, w, lengths, c, s, M, A):
    """Row m of ``A`` := −L_g0 h of the squared barrier h = ‖x − y‖² − R² for the point x at parameter ``tau``
    on link ``ell`` (gap x − y = (rx, ry)); returns ∂h/∂q₁, the passive joint's part (0 for a fully actuated arm).

    ∇_q h = 2 (x − y)ᵀ J_x with ∂x/∂q_a = Σ_{a ≤ α ≤ ell} w_α L_α [cos, −sin](θ_α + φ), w_α = 1 below ell and
    ``tau`` at ell; a PAn−1 arm's L_g0 h = ∇_a h − ∇_0 h M_0a / M_00 (g0 = [−M_0a / M_00 ; I])."""
    grad0 = 0.0
    jx, jy = 0.0, 0.0
    for a in range(ell, -1, -1):
        weight = tau if a == ell else 1.0
        jx += weight * lengths[a, w] * c[a, w]
        jy -= weight * lengths[a, w] * s[a, w]
        grad = 2.0 * (rx * jx + ry * jy)
        if passive and a == 0:
            grad0 = grad
        elif passive:
            A[m, a - 1] = -grad
        else:
            A[m, a] = -grad
    for a in range(ell + 1, n):  # links beyond the body do not move it
        A[m, a - 1 if passive else a] = 0.0
    if passive:
        for t in range(k):
            A[m, t] = A[m, t] + grad0 * M[0, t + 1, w] / M[0, 0, w]
    return grad0


@njit(**_JIT, forceinline=True)
def _near_capsules(i, links, rho, sensing, gate, skin, dt, reach_speed, fault_reach, caps, n_world, time, lookahead,
                   P, n, near):
    """The capsules whose segment's box comes within range of the bodies' box (``P`` the arm's joints) into
    ``near``: returns how many. A capsule is out of range of every body if its box is farther than the range along
    an axis (the gap along an axis bounds the distance from below). ``fault_reach`` widens the world capsules' range
    for the fault margin (:func:`whole_arm_rows`)."""
    first = 0 if links else n
    lox, hix, loy, hiy = P[first, 0], P[first, 0], P[first, 1], P[first, 1]
    for a in range(first + 1, n + 1):
        lox, hix = min(lox, P[a, 0]), max(hix, P[a, 0])
        loy, hiy = min(loy, P[a, 1]), max(hiy, P[a, 1])
    n_near = 0
    for j in range(caps.shape[1]):
        if caps[i, j, CAP_ACTIVE] == 0.0:
            if j >= n_world:  # the other arms' active links come first
                break
            continue
        if lookahead > 0.0 and j < n_world:
            a2x, a2y, d2x, d2y, vx, vy, ex, ey = _capsule_ahead(caps, i, j, time, lookahead)
        else:
            a2x, a2y, d2x, d2y, vx, vy = _capsule_now(caps, i, j, time)
            ex, ey = vx, vy
        reach = caps[i, j, CAP_RADIUS] + (rho if links else 0.0) + skin + caps[i, j, CAP_SPEED] * dt
        within = reach + sensing + 2.0 * (reach_speed + caps[i, j, CAP_SPEED]) * dt + gate
        extra = fault_reach if j < n_world else 0.0
        if min(a2x, a2x + d2x) - within - extra > hix or max(a2x, a2x + d2x) + within + extra < lox or \
                min(a2y, a2y + d2y) - within - extra > hiy or max(a2y, a2y + d2y) + within + extra < loy:
            continue
        near[n_near, 0], near[n_near, 1], near[n_near, 2], near[n_near, 3] = a2x, a2y, d2x, d2y
        near[n_near, 4], near[n_near, 5], near[n_near, 6] = vx, vy, 0.5 * np.sqrt(d2x * d2x + d2y * d2y)
        near[n_near, 7], near[n_near, 8], near[n_near, 9] = reach, within, caps[i, j, CAP_SHARE]
        near[n_near, 10], near[n_near, 11] = ex, ey
        near[n_near, 12] = 1.0 if lookahead > 0.0 and j < n_world and d2x * d2x + d2y * d2y > 0.0 else 0.0
        near[n_near, 13] = extra if j < n_world else -1.0  # < 0: another arm's link, which the margin leaves out
        n_near += 1
    return n_near


@njit(**_JIT, forceinline=True)
def _momentum_rows(m, k, w, c_fault, gain, offset, clearance, closing, margin, cull, v_max, M, A, b, active):
    """The fault margin of a fully actuated arm (:func:`whole_arm_rows`): the first joint's momentum at the
    sub-step's end, p₁ = ``gain`` M₀ v + ``offset``, kept within b h / reach, as the two rows
    ±c (g M₀ v + p₀) ≤ max(h − ``closing`` − margin, 0), c = reach / b, with h the arm's smallest clearance to a
    world obstacle now (``clearance``) less what it can lose within the sub-step (a pair beyond the rows' range has
    no row to slow it); left out where the speed box keeps them slack. Returns the rows written."""
    rhs = max(clearance - closing - margin, 0.0)
    bound = 0.0
    for t in range(k):
        bound += abs(M[0, t, w])
    if clearance == np.inf or (cull and c_fault * (gain * bound * v_max + abs(offset)) <= rhs):
        return m
    for sign in (1.0, -1.0):
        for t in range(k):
            A[m, t] = sign * c_fault * gain * M[0, t, w]
        b[m] = rhs - sign * c_fault * offset
        active[m] = True
        m += 1
    return m


@njit(**_JIT, forceinline=True)
def _fault_reach(passive, distance, arm_reach, damping, gain, offset, p1, v_max, k, w, M):
    """The fault margin's c = reach / b (0: no margin) and how much farther it looks at world obstacles: c |p₁| for a
    PAn−1 arm (its rows keep h ≥ c |p₁|), the most c |p₁| can be inside the speed box for a fully actuated one, whose
    momentum at the sub-step's end is p₁ = g M₀ v + p₀ (``gain``, ``offset``; its smallest clearance within that
    range)."""
    c_fault = arm_reach / damping if damping > 0.0 and distance else 0.0
    fault_reach = 0.0
    if c_fault > 0.0 and passive:
        fault_reach = c_fault * abs(p1)
    elif c_fault > 0.0:
        for t in range(k):
            fault_reach += c_fault * gain * v_max * abs(M[0, t, w])
        fault_reach += c_fault * abs(offset)
    return c_fault, fault_reach


@njit(**_JIT, forceinline=True)
def _keep_row(m, k, A, b, active, bm, bound, gate, gap, within, v_max, cull):
    """Row m (``A[m]``, right side ``bm``, Σ|A_m| = ``bound``) relaxed by the smooth activation past the range
    (``gate`` > 0: σ = 1 − (3 u² − 2 u³), u = (gap − on) / gate, on = ``within`` − gate; :func:`whole_arm_rows`) and
    kept unless it cannot bind inside the speed box: returns the rows written."""
    sigma = 1.0
    if gate > 0.0:
        u = min(max((gap - (within - gate)) / gate, 0.0), 1.0)
        sigma = 1.0 - u * u * (3.0 - 2.0 * u)
        if sigma < 1.0:
            bm = sigma * bm + (1.0 - sigma) * v_max * bound
            for t in range(k):
                A[m, t] = sigma * A[m, t]
    if cull and sigma * bound * v_max <= bm:
        return m
    b[m] = bm
    active[m] = True
    return m + 1


@njit(**_JIT)
def whole_arm_rows(i, w, n, k, passive, links, rho, sensing, gate, skin, dt, lengths, bx, by, c, s, qd, M, p1, faults,
                   caps, n_world, time, kappa, epsilon, margin, distance, decay, lookahead, v_max, v0, A, b, active, P,
                   near):
    """The whole-arm RCBF rows of arm i (lane w of the kernel's scratch) at ``time``, then its speed
    bounds (finite ``v_max``), into ``A``, ``b``, ``active``: returns (rows written, smallest barrier h).
    A PAn−1 arm's passive momentum ``p1`` drifts its bodies, q̇ = g0 v + e₁ p₁ / M_11 (docs/MODEL.md §7):
    each b gains (∂h/∂q₁) p₁ / M_11, and the speed bound below |p₁| / M_11.

    ``lookahead`` T > 0 (s) puts, in place of each moving world obstacle's disk, the capsule of the stretch of
    path it covers in the next T s (:func:`_capsule_ahead`; inf: its whole path), and gives each link two rows
    per stretch, at the closest pair and at the link's other end (docs/MODEL.md §5b).

    ``faults`` = (b, g, p₀): the first joint's damping b (passive or once passive; 0: no margin) and, for a fully
    actuated arm, its momentum at the sub-step's end p₁ = g M₀ v + p₀ (the tracker's; g = 1, p₀ = 0: v itself).
    b > 0 turns on the fault margin against the world's obstacles (distance barrier; docs/MODEL.md §5c), with
    c = reach / b: a PAn−1 arm's pairs keep h ≥ c |p₁| (:func:`_pair_rows`); a fully actuated arm keeps c |p₁|
    within its smallest clearance (:func:`_momentum_rows`), so that if its first joint's actuator is lost it starts
    with h ≥ c |p₁|.

    Only pairs that are close get a row: clearance d − r − ρ at most ``sensing`` plus twice what the
    gap can close in the sub-step ``dt`` (no point of the arm moves faster than its reach times
    Σ|q̇_a|, bounded by the joint speeds now and by those the command ``v0`` can reach within the
    speed bound; the obstacle at its speed). A far pair's RCBF row is not inactive: its robust term
    ‖L_g0 h‖²/ε grows with the distance like κ h does, and with many bodies and capsules the rows of
    far pairs pushed in conflicting directions and made the QP infeasible. A row that cannot bind inside
    the speed box (Σ_t |A_t| v_max ≤ b) is left out too: the box rows are in the same QP, so that does
    not change its optimum. The smallest barrier (of the skin-inflated capsules) is taken over the pairs
    within sensing range.

    ``gate`` > 0 (m) widens that range into a smooth activation (:func:`pan1_env.safety.activation_gate`): a
    pair whose clearance c is past the range ``on`` (``sensing`` plus the sub-step's closing, as above) by
    less than ``gate`` gets the row relaxed to −σ L_g0 h · v ≤ σ b + (1 − σ) S, σ the C¹ cubic of
    (c − on)/gate and S = v_max Σ|L_g0 h| (:func:`pan1_env.safety.cbf_rows`); it needs a finite ``v_max``.
    0 is the hard range.

    The rows keep each capsule ``skin`` plus the obstacle's travel in one sub-step farther out than its
    radius: within a sub-step an obstacle may turn round and the arm lags the filtered velocity, which
    without the skin let capsules graze obstacles by fractions of a millimetre.

    ``near (C, NEAR_COLUMNS)`` is scratch: the capsules whose box comes within range of the bodies' box."""
    cull = v_max < np.inf
    reach_speed, arm_reach, drift_speed = _reach_speed(n, k, w, passive, lengths, qd, M, p1, v0, v_max)
    damping, gain, offset = faults
    c_fault, fault_reach = _fault_reach(passive, distance, arm_reach, damping, gain, offset, p1, v_max, k, w, M)
    _joints(lengths, bx, by, c, s, n, w, P)
    n_near = _near_capsules(i, links, rho, sensing, gate, skin, dt, reach_speed, fault_reach, caps, n_world, time,
                            lookahead, P, n, near)
    m, h_min, h_fault = 0, np.inf, np.inf
    for body in range(n if links else 1):
        a1x, a1y, d1x, d1y, ell = _body(P, n, links, body)
        half_body = 0.5 * np.sqrt(d1x * d1x + d1y * d1y)
        for x in range(n_near):
            a2x, a2y, d2x, d2y = near[x, 0], near[x, 1], near[x, 2], near[x, 3]
            reach, within, extra, world = near[x, 7], near[x, 8], max(near[x, 13], 0.0), near[x, 13] >= 0.0
            if passive:  # its rows keep the smaller of its two barriers h ∓ c p₁, h − c |p₁|, in range
                within += extra
            look = within if passive else within + extra  # a fully actuated arm's smallest clearance looks farther
            # the segments' midpoints, less their half lengths, bound their distance from below
            mx, my = a1x + 0.5 * (d1x - d2x) - a2x, a1y + 0.5 * (d1y - d2y) - a2y
            if sensing < np.inf and mx * mx + my * my > (look + half_body + near[x, 6]) ** 2:
                continue
            sp, rx, ry = _gap(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y)
            # a link beside a stretch of path gets a second row, for its other end: segments nearly parallel
            # have their closest pair jump from one end to the other, and a row at the link's inner end alone
            # leaves the joint that swings the outer end free (the other arms' links keep one row)
            for pick in range(2 if links and near[x, 12] > 0.0 else 1):
                if pick == 1:
                    sp = 1.0 if sp < 0.5 else 0.0
                    _, rx, ry = _gap(a1x + sp * d1x, a1y + sp * d1y, 0.0, 0.0, a2x, a2y, d2x, d2y)
                gap = np.sqrt(rx * rx + ry * ry)
                if not passive and c_fault > 0.0 and world and gap <= look:
                    h_fault = min(h_fault, gap - reach)
                if gap > within:
                    continue
                m, h_min = _pair_rows(m, h_min, near, x, ell, sp if links else 1.0, rx, ry, gap, within,
                                      passive and c_fault > 0.0 and world, n, k, w, passive, lengths, c, s, M,
                                      (kappa, epsilon, margin, distance, decay),
                                      (damping, c_fault, p1, arm_reach, drift_speed), gate, v_max, cull, A, b, active)
    if c_fault > 0.0 and not passive:
        m = _momentum_rows(m, k, w, c_fault, gain, offset, h_fault, reach_speed * dt, margin, cull, v_max, M, A, b,
                           active)
    if cull:
        m = speed_box_rows(m, k, v_max, A, b, active)
    return m, h_min


@njit(**_JIT, forceinline=True)
def _reach_speed(n, k, w, passive, lengths, qd, M, p1, v0, v_max):
    """A bound on how fast any point of arm w moves during the sub-step, its reach times a bound on Σ|q̇_a|: now,
    and what the filtered command can reach within it (in torque mode the arm is driven to v* in one sub-step):
    |v_t| ≤ v_max, the passive joint q̇_0 = −Σ_t M_0,t+1/M_00 v_t plus the drift p₁ / M_00; without a speed
    bound, the command's own speeds. Returns (that bound, the reach, the drift speed p₁ / M_00)."""
    joint_speed, arm_reach, coupling, drift_speed, commanded = 0.0, 0.0, 1.0, 0.0, 0.0
    for a in range(n):
        joint_speed += abs(qd[a, w])
        arm_reach += lengths[a, w]
    if passive:
        for t in range(k):
            coupling += abs(M[0, t + 1, w] / M[0, 0, w])
        drift_speed = p1 / M[0, 0, w]
    for t in range(k):
        commanded += min(abs(v0[t]), v_max)
    return arm_reach * max(joint_speed, coupling * commanded + abs(drift_speed)), arm_reach, drift_speed


@njit(**_JIT, forceinline=True)
def _pair_rows(m, h_min, near, x, ell, tau, rx, ry, gap, within, two_sided, n, k, w, passive, lengths, c, s, M,
               barrier, fault, gate, v_max, cull, A, b, active):
    """The RCBF rows of one close pair of a body and a capsule (row x of :func:`_near_capsules`' table
    ``near``), gap vector (rx, ry) at the body's point τ, into ``A``, ``b``, ``active`` from row m: returns (rows
    written, smallest barrier h). ``barrier`` = (κ, ε, margin, distance, decay) and the speed box are
    :func:`whole_arm_rows`'; ``fault`` = (b, c, p₁, reach, p₁ / M₀₀).

    The fault margin (c = reach / b = ``c_fault`` > 0, b the first joint's damping): a PAn−1 arm's world pair
    (``two_sided``) keeps two rows in place of one, for h − c p₁ ≥ 0 and h + c p₁ ≥ 0 (h ≥ c |p₁|), each gaining
    ±reach M₀a / M₀₀ and its b the rate ±reach p₁ / M₀₀, with κ at least b / M₀₀."""
    kappa, epsilon, margin, distance, decay = barrier
    damping, c_fault, p1, arm_reach, drift_speed = fault
    d2x, d2y = near[x, 2], near[x, 3]
    # a damped passive arm's world pairs (the fault margin) keep both h − c p₁ ≥ 0 and h + c p₁ ≥ 0,
    # i.e. h ≥ c |p₁|, each a smooth barrier, with κ at least b / M₀₀ so that braking meets both
    sides = 2 if two_sided else 1
    kap = max(kappa, damping / M[0, 0, w]) if sides == 2 else kappa
    reach = near[x, 7]
    for side in range(sides):
        h = rx * rx + ry * ry - reach * reach
        # the closest point's velocity: r·d2 > 0 only where the pair meets at the stretch's far end (≤ 0
        # at its start); inside, the gap is normal to the path and either end's velocity adds nothing
        vx, vy = (near[x, 10], near[x, 11]) if rx * d2x + ry * d2y > 0.0 else (near[x, 4], near[x, 5])
        lg2 = 0.0
        grad0 = _pair_row(m, ell, tau, rx, ry, passive, n, k, w, lengths, c, s, M, A)
        fault_rate = 0.0
        if distance:
            # h = d − R (pan1_env.safety.shaped_barrier): the row and ∂h/∂t of the squared barrier
            # over 2d, d from the squared h as the reference takes it; a zero row at d = 0
            d = np.sqrt(max(h + reach * reach, 0.0))
            scale = 0.5 / d if d > 0.0 else 0.0
            h = d - reach
            for t in range(k):
                A[m, t] = A[m, t] * scale
        else:
            scale = 1.0
        h_min = min(h_min, h)
        if sides == 2:  # h ∓ c p₁: d/dt(∓ c p₁) = ±reach q̇₁, ṗ₁ = −b q̇₁, q̇₁ = (p₁ − M₀a v) / M₀₀
            pm = 1.0 - 2.0 * side
            h -= pm * c_fault * p1
            fault_rate = pm * arm_reach * p1 / M[0, 0, w]
            for t in range(k):
                A[m, t] += pm * arm_reach * M[0, t + 1, w] / M[0, 0, w]
        bound = 0.0
        for t in range(k):
            lg2 += A[m, t] * A[m, t]
            bound += abs(A[m, t])
        if not distance and decay == 0.0:  # the paper's row, its operations as before the choices existed
            bm = near[x, 9] * kap * (h - margin) - 2.0 * (rx * vx + ry * vy) - lg2 / epsilon + grad0 * drift_speed
        else:  # ε(h̃) = ε e^{min(λ h̃, 700)} (pan1_env.safety.robust_epsilon); ε = inf: the fallback's rows
            ht = h - margin
            bm = near[x, 9] * kap * ht + (grad0 * drift_speed - 2.0 * (rx * vx + ry * vy)) * scale + fault_rate \
                - lg2 / (epsilon * np.exp(min(decay * ht, 700.0)))
        m = _keep_row(m, k, A, b, active, bm, bound, gate, gap, within, v_max, cull)
    return m, h_min


@njit(**_JIT, forceinline=True)
def speed_box_rows(m, k, v_max, A, b, active):
    """The speed box ±v_t ≤ ``v_max`` as 2k rows from row m: returns the rows written."""
    for t0 in range(k):
        for sign in (1.0, -1.0):
            for t in range(k):
                A[m, t] = sign if t == t0 else 0.0
            b[m] = v_max
            active[m] = True
            m += 1
    return m


@njit(**_JIT, forceinline=True)
def whole_arm_clearance_lanes(arm, live, n, W, links, rho, lengths, bx, by, c, s, caps, n_world, start_time,
                              elapsed, joints_x, joints_y, ox, oy, orad, clear):
    """Running minimum into ``clear (W)`` of each live lane's smallest signed clearance d − r − ρ of its
    bodies (arm ``arm[w]``) to the world obstacles (the first ``n_world`` capsules of its row, disks,
    active for its filter or not) at its clock ``start_time[arm[w]] + elapsed``; other arms' capsules
    are left to the engine, which measures them from every arm's state. Lanes at once: each body and
    obstacle pair is a point–segment distance, whose clamp is a select (``joints_x``, ``joints_y (n + 1, W)``,
    ``ox``, ``oy``, ``orad (W)`` are scratch). The same operations in the same order as
    :func:`_gap` for a segment and a point, so the same clearance, bit for bit. An obstacle whose floor
    is at least every live lane's clearance so far cannot lower it and is not measured (the floors are a
    nanometre below the bound, so rounding cannot make that a near thing)."""
    for w in range(W):  # the joints: base, link ends (link a runs from joint a to joint a + 1)
        x, y = bx[w], by[w]
        joints_x[0, w], joints_y[0, w] = x, y
        for a in range(n):
            x += lengths[a, w] * s[a, w]
            y += lengths[a, w] * c[a, w]
            joints_x[a + 1, w], joints_y[a + 1, w] = x, y
    radius = rho if links else 0.0
    for j in range(n_world):
        lowers = False
        for w in range(W):
            lowers = lowers or (live[w] and caps[arm[w], j, CAP_FLOOR] < clear[w])
        if not lowers:
            continue
        for w in range(W):
            row = arm[w]
            ox[w], oy[w], _, _, _, _ = _capsule_now(caps, row, j, start_time[row] + elapsed)
            orad[w] = caps[row, j, CAP_RADIUS]
        for body in range(n if links else 1):
            start = body if links else n  # the end-effector: a point, the segment from joint n to itself
            end = body + 1 if links else n
            for w in range(W):
                ax, ay = joints_x[start, w], joints_y[start, w]
                dx, dy = joints_x[end, w] - ax, joints_y[end, w] - ay
                length2 = dx * dx + dy * dy
                u = _unit(((ox[w] - ax) * dx + (oy[w] - ay) * dy) / length2) if length2 > 0.0 else 0.0
                rx, ry = ax + u * dx - ox[w], ay + u * dy - oy[w]
                cl = np.sqrt(rx * rx + ry * ry) - orad[w] - radius
                clear[w] = cl if live[w] and cl < clear[w] else clear[w]
