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
from .qp import STATUS_FALLBACK, _project_one

(CAP_AX, CAP_AY, CAP_BX, CAP_BY, CAP_RADIUS, CAP_SHARE, CAP_UX, CAP_UY, CAP_PATH, CAP_SPEED, CAP_ACTIVE, CAP_ARM,
 CAP_LINK, CAP_FLOOR) = range(14)
CAPSULE_COLUMNS = 14  #: columns of a capsule row; ``CAP_ARM`` is −1 for a world obstacle or an unused slot
#: :func:`whole_arm_rows`' scratch: segment now, its start's velocity, half length, reach, range, share, its end's
#: velocity, whether it is a stretch of path
NEAR_COLUMNS = 13


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
    ``capsules`` capsules, the first ``n_world`` the world's (two rows a body with a look-ahead), and its speed box."""
    return bodies * (capsules + n_world) + 2 * k


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


@njit(**_JIT)
def whole_arm_rows(i, w, n, k, passive, links, rho, sensing, gate, skin, dt, lengths, bx, by, c, s, qd, M, p1, caps,
                   n_world, time, kappa, epsilon, margin, distance, decay, lookahead, v_max, v0, A, b, active, P, near):
    """The whole-arm RCBF rows of arm i (lane w of the kernel's scratch) at ``time``, then its speed
    bounds (finite ``v_max``), into ``A``, ``b``, ``active``: returns (rows written, smallest barrier h).
    A PAn−1 arm's passive momentum ``p1`` drifts its bodies, q̇ = g0 v + e₁ p₁ / M_11 (docs/MODEL.md §7):
    each b gains (∂h/∂q₁) p₁ / M_11, and the speed bound below |p₁| / M_11.

    ``lookahead`` T > 0 (s) puts, in place of each moving world obstacle's disk, the capsule of the stretch of
    path it covers in the next T s (:func:`_capsule_ahead`; inf: its whole path), and gives each link two rows
    per stretch, at the closest pair and at the link's other end (docs/MODEL.md §5b).

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
    C = caps.shape[1]
    m = 0
    h_min = np.inf
    cull = v_max < np.inf
    # a bound on the joint speeds Σ|q̇_a| during the sub-step: now, and what the filtered command can
    # reach within it (in torque mode the arm is driven to v* in one sub-step): |v_t| ≤ v_max, the
    # passive joint q̇_0 = −Σ_t M_0,t+1/M_00 v_t; without a speed bound, the command's own speeds
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
    reach_speed = arm_reach * max(joint_speed, coupling * commanded + abs(drift_speed))
    _joints(lengths, bx, by, c, s, n, w, P)
    # the bodies' bounding box: a capsule whose segment's box is farther than its range along an axis is
    # out of range of every body (the gap along an axis bounds the distance from below)
    first = 0 if links else n
    lox, hix, loy, hiy = P[first, 0], P[first, 0], P[first, 1], P[first, 1]
    for a in range(first + 1, n + 1):
        lox, hix = min(lox, P[a, 0]), max(hix, P[a, 0])
        loy, hiy = min(loy, P[a, 1]), max(hiy, P[a, 1])
    n_near = 0
    for j in range(C):
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
        if min(a2x, a2x + d2x) - within > hix or max(a2x, a2x + d2x) + within < lox or \
                min(a2y, a2y + d2y) - within > hiy or max(a2y, a2y + d2y) + within < loy:
            continue
        near[n_near, 0], near[n_near, 1], near[n_near, 2], near[n_near, 3] = a2x, a2y, d2x, d2y
        near[n_near, 4], near[n_near, 5], near[n_near, 6] = vx, vy, 0.5 * np.sqrt(d2x * d2x + d2y * d2y)
        near[n_near, 7], near[n_near, 8], near[n_near, 9] = reach, within, caps[i, j, CAP_SHARE]
        near[n_near, 10], near[n_near, 11] = ex, ey
        near[n_near, 12] = 1.0 if lookahead > 0.0 and j < n_world and d2x * d2x + d2y * d2y > 0.0 else 0.0
        n_near += 1
    for body in range(n if links else 1):
        a1x, a1y, d1x, d1y, ell = _body(P, n, links, body)
        half_body = 0.5 * np.sqrt(d1x * d1x + d1y * d1y)
        for x in range(n_near):
            a2x, a2y, d2x, d2y = near[x, 0], near[x, 1], near[x, 2], near[x, 3]
            reach, within = near[x, 7], near[x, 8]
            # the segments' midpoints, less their half lengths, bound their distance from below
            mx, my = a1x + 0.5 * (d1x - d2x) - a2x, a1y + 0.5 * (d1y - d2y) - a2y
            if sensing < np.inf and mx * mx + my * my > (within + half_body + near[x, 6]) ** 2:
                continue
            sp, rx, ry = _gap(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y)
            # a link beside a stretch of path gets a second row, for its other end: segments nearly parallel
            # have their closest pair jump from one end to the other, and a row at the link's inner end alone
            # leaves the joint that swings the outer end free (the other arms' links keep one row)
            for pick in range(2 if links and near[x, 12] > 0.0 else 1):
                if pick == 1:
                    sp = 1.0 if sp < 0.5 else 0.0
                    _, rx, ry = _gap(a1x + sp * d1x, a1y + sp * d1y, 0.0, 0.0, a2x, a2y, d2x, d2y)
                if np.sqrt(rx * rx + ry * ry) > within:
                    continue
                h = rx * rx + ry * ry - reach * reach
                # the closest point's velocity: r·d2 > 0 only where the pair meets at the stretch's far end (≤ 0 at
                # its start); inside, the gap is normal to the path and either end's velocity, along it, adds nothing
                vx, vy = (near[x, 10], near[x, 11]) if rx * d2x + ry * d2y > 0.0 else (near[x, 4], near[x, 5])
                lg2 = 0.0
                grad0 = _pair_row(m, ell, sp if links else 1.0, rx, ry, passive, n, k, w, lengths, c, s, M, A)
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
                bound = 0.0
                for t in range(k):
                    lg2 += A[m, t] * A[m, t]
                    bound += abs(A[m, t])
                if not distance and decay == 0.0:  # the paper's row, its operations as before the choices existed
                    bm = near[x, 9] * kappa * (h - margin) - 2.0 * (rx * vx + ry * vy) - lg2 / epsilon \
                        + grad0 * drift_speed
                else:  # ε(h̃) = ε e^{min(λ h̃, 700)} (pan1_env.safety.robust_epsilon); ε = inf: the fallback's rows
                    ht = h - margin
                    bm = near[x, 9] * kappa * ht + (grad0 * drift_speed - 2.0 * (rx * vx + ry * vy)) * \
                        scale - lg2 / (epsilon * np.exp(min(decay * ht, 700.0)))
                sigma = 1.0
                if gate > 0.0:  # the smooth activation past the range: σ = 1 − (3 u² − 2 u³), u = (c − on)/gate
                    u = min(max((np.sqrt(rx * rx + ry * ry) - (within - gate)) / gate, 0.0), 1.0)
                    sigma = 1.0 - u * u * (3.0 - 2.0 * u)
                    if sigma < 1.0:
                        bm = sigma * bm + (1.0 - sigma) * v_max * bound
                        for t in range(k):
                            A[m, t] = sigma * A[m, t]
                if cull and sigma * bound * v_max <= bm:
                    continue
                b[m] = bm
                active[m] = True
                m += 1
    if cull:
        for t0 in range(k):
            for sign in (1.0, -1.0):
                for t in range(k):
                    A[m, t] = sign if t == t0 else 0.0
                b[m] = v_max
                active[m] = True
                m += 1
    return m, h_min


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
