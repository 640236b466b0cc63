"""The whole-arm geometry passes between the sub-step kernel's calls, over a team's arrays (row ``copy_rows[b, i]``
is arm i of copy b): every arm's joints, the obstacles where each copy's clock puts them, the other arms' link
segments refreshed into each arm's capsules (:mod:`.capsules` describes their rows), and the clearance between
arms. Each pass runs copy by copy, serially or split into chunks on numba's threads (``_parallel``).

The clearance between arms is exact and follows the nearby arms: an arm walks its capsule slots for the other
arms' links in order of floor (a lower bound on the pair's clearance in any configuration) and stops at the first
floor not below the clearance found so far; :func:`inter_arm_clearance`, over all pairs, is its reference.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._numba_ext import _JIT
from .capsules import CAP_ACTIVE, CAP_ARM, CAP_AX, CAP_AY, CAP_BX, CAP_BY, CAP_FLOOR, CAP_LINK, _capsule_now, _gap


@njit(**_JIT, forceinline=True)
def _box_gap(lox1, hix1, loy1, hiy1, lox2, hix2, loy2, hiy2):
    """The larger of two boxes' gaps along x and y (≤ 0 if they overlap): a lower bound on the distance
    between any point of one and any point of the other."""
    return max(lox2 - hix1, lox1 - hix2, loy2 - hiy1, loy1 - hiy2)


@njit(**_JIT)
def _arm_boxes(P, b, box):
    """Every arm's bounding box ``box (N, 4)`` (x low, high, y low, high) in copy b: its segments lie in that of
    its joints ``P``."""
    for i in range(P.shape[1]):
        box[i, 0], box[i, 1], box[i, 2], box[i, 3] = P[b, i, 0, 0], P[b, i, 0, 0], P[b, i, 0, 1], P[b, i, 0, 1]
        for a in range(1, P.shape[2]):
            box[i, 0], box[i, 1] = min(box[i, 0], P[b, i, a, 0]), max(box[i, 1], P[b, i, a, 0])
            box[i, 2], box[i, 3] = min(box[i, 2], P[b, i, a, 1]), max(box[i, 3], P[b, i, a, 1])


@njit(**_JIT)
def _pair_clearance(P, b, i, j, box, rho, out):
    """Lower ``out[b, i]`` and ``out[b, j]`` to the clearance d − 2ρ between arms i and j of copy b, unless
    their boxes, or a pair of their links' boxes, are too far apart to lower either."""
    L = P.shape[2] - 1
    limit = max(out[b, i], out[b, j]) + 2.0 * rho  # a gap this large cannot lower either minimum
    if _box_gap(box[i, 0], box[i, 1], box[i, 2], box[i, 3], box[j, 0], box[j, 1], box[j, 2], box[j, 3]) >= limit:
        return
    best = np.inf
    for li in range(L):
        a1x, a1y = P[b, i, li, 0], P[b, i, li, 1]
        d1x, d1y = P[b, i, li + 1, 0] - a1x, P[b, i, li + 1, 1] - a1y
        for lj in range(L):
            a2x, a2y = P[b, j, lj, 0], P[b, j, lj, 1]
            d2x, d2y = P[b, j, lj + 1, 0] - a2x, P[b, j, lj + 1, 1] - a2y
            if _box_gap(min(a1x, a1x + d1x), max(a1x, a1x + d1x), min(a1y, a1y + d1y), max(a1y, a1y + d1y),
                        min(a2x, a2x + d2x), max(a2x, a2x + d2x), min(a2y, a2y + d2y),
                        max(a2y, a2y + d2y)) >= min(limit, np.sqrt(best)):
                continue
            _, rx, ry = _gap(a1x, a1y, d1x, d1y, a2x, a2y, d2x, d2y)
            best = min(best, rx * rx + ry * ry)
    clear = np.sqrt(best) - 2.0 * rho
    out[b, i] = min(out[b, i], clear)
    out[b, j] = min(out[b, j], clear)


@njit(**_JIT)
def _inter_arm_copies(P, rho, out, lo, hi):
    """:func:`inter_arm_clearance` for copies ``lo … hi−1``."""
    N = P.shape[1]
    box = np.empty((N, 4))
    for b in range(lo, hi):
        _arm_boxes(P, b, box)
        for i in range(N):
            for j in range(i + 1, N):
                _pair_clearance(P, b, i, j, box, rho, out)


@njit(**_JIT)
def _nearby_arm_copies(copy_rows, caps, first, P, rho, out, lo, hi):
    """:func:`inter_arm_clearance` for copies ``lo … hi−1``, each arm walking its slots for the other arms'
    links (from column ``first``, in order of floor) and stopping at the first floor not below its clearance
    so far: no arm after it can lower that, so the walk meets the nearby arms only. The minimum is the
    all-pairs one: the same pairs' clearances, less pairs whose floor (a nanometre below the bound) shows they
    cannot lower it."""
    N, C = P.shape[1], caps.shape[1]
    box = np.empty((N, 4))
    for b in range(lo, hi):
        _arm_boxes(P, b, box)
        for i in range(N):
            row, last = copy_rows[b, i], -1
            for col in range(first, C):
                j = int(caps[row, col, CAP_ARM])
                if j < 0 or not caps[row, col, CAP_FLOOR] < out[b, i]:  # an unused slot, or no lower pair after
                    break
                if j == last:
                    continue
                last = j
                _pair_clearance(P, b, i, j, box, rho, out)


@njit(**_JIT)
def inter_arm_clearance(P, rho, out):
    """Running minimum into ``out (B, N)`` of every arm's clearance d − 2ρ to the other arms' link
    capsules, from the joints ``P (B, N, L + 1, 2)`` of :meth:`pan1_env.engine.Engine.joint_positions`
    (padding links of length 0 at an arm's end-effector change nothing). A pair of arms, or of links,
    whose bounding boxes are farther apart than both running minima (or than the pair's closest links
    so far) is skipped, so seeding ``out`` with a smaller clearance (to the obstacles, say) saves work
    without changing the minimum."""
    _inter_arm_copies(P, rho, out, 0, P.shape[0])


@njit(**_JIT)
def _kind_joints_rows(q, lengths, base, phi, ids, rows, P, lo, hi):
    """:func:`kind_joints` for rows ``rows[lo … hi−1]``."""
    A, n, L = ids.shape[0], q.shape[1], P.shape[2] - 1
    for at in range(lo, hi):
        row = rows[at]
        b, i = row // A, ids[row % A]
        x, y, ang = base[row, 0], base[row, 1], phi[row]
        P[b, i, 0, 0], P[b, i, 0, 1] = x, y
        for a in range(L):
            if a < n:
                ang += q[row, a]
                x += lengths[row, a] * np.sin(ang)
                y += lengths[row, a] * np.cos(ang)
            P[b, i, a + 1, 0], P[b, i, a + 1, 1] = x, y


@njit(**_JIT)
def kind_joints(q, lengths, base, phi, ids, rows, P):
    """Joints of the arms of one kind (rows ``b·A + r`` of ``q (B·A, n)`` …, arm ``ids[r]`` of copy b) that
    are among ``rows`` (int64, valid indices: the kind's stepped rows) into ``P (B, N, L + 1, 2)``: base,
    joints, end-effector, then the end-effector repeated up to L."""
    _kind_joints_rows(q, lengths, base, phi, ids, rows, P, 0, rows.shape[0])


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def kind_joints_parallel(q, lengths, base, phi, ids, rows, P, n_chunks):
    """:func:`kind_joints` with the rows split into ``n_chunks`` chunks on numba's threads."""
    R = rows.shape[0]
    for c in prange(n_chunks):
        _kind_joints_rows(q, lengths, base, phi, ids, rows, P, c * R // n_chunks, (c + 1) * R // n_chunks)


@njit(**_JIT)
def obstacles_now(copy_rows, caps, elapsed, centers, velocities):
    """Every copy's world obstacles where its clock ``elapsed (B,)`` puts them: ``centers`` and
    ``velocities (B, O, 2)``, from the first O capsules of its first arm's row ``copy_rows[b, 0]`` (every
    arm holds the copy's obstacles there), as the filter places them (:func:`_capsule_now`)."""
    for b in range(centers.shape[0]):
        row = copy_rows[b, 0]
        for j in range(centers.shape[1]):
            x, y, _, _, vx, vy = _capsule_now(caps, row, j, elapsed[b])
            centers[b, j, 0], centers[b, j, 1] = x, y
            velocities[b, j, 0], velocities[b, j, 1] = vx, vy


@njit(**_JIT)
def _after_substep_copies(copy_rows, joints, clear, finite, ok, start_time, caps, first, rho, dt, refresh,
                          elapsed, P, between, lo, hi):
    """:func:`after_substep` for copies ``lo … hi−1``."""
    N, J = copy_rows.shape[1], joints.shape[1]
    for b in range(lo, hi):
        for i in range(N):
            row = copy_rows[b, i]
            for a in range(J):
                P[b, i, a, 0], P[b, i, a, 1] = joints[row, a, 0], joints[row, a, 1]
            c, now = clear[row], between[b, i]
            between[b, i] = c if c < now or c != c else now  # np.minimum's rule (NaN wins)
            ok[row] = ok[row] and finite[row]
    _nearby_arm_copies(copy_rows, caps, first, P, rho, between, lo, hi)
    for b in range(lo, hi):
        elapsed[b] += dt
    if refresh:
        _refresh_copies(copy_rows, start_time, caps, first, elapsed, P, lo, hi)


@njit(**_JIT)
def _refresh_copies(copy_rows, start_time, caps, first, elapsed, P, lo, hi):
    """:func:`refresh_capsules` for copies ``lo … hi−1``."""
    N, C = copy_rows.shape[1], caps.shape[1]
    for b in range(lo, hi):
        for i in range(N):
            row = copy_rows[b, i]
            start_time[row] = elapsed[b]
            for col in range(first, C):
                if caps[row, col, CAP_ACTIVE] == 0.0:  # the active links come first
                    break
                j, a = int(caps[row, col, CAP_ARM]), int(caps[row, col, CAP_LINK])
                caps[row, col, CAP_AX], caps[row, col, CAP_AY] = P[b, j, a, 0], P[b, j, a, 1]
                caps[row, col, CAP_BX], caps[row, col, CAP_BY] = P[b, j, a + 1, 0], P[b, j, a + 1, 1]


@njit(**_JIT)
def refresh_capsules(copy_rows, start_time, caps, first, elapsed, P):
    """Before an inter-arm sub-step, on team-level arrays whose row ``copy_rows[b, i]`` is arm i of copy
    b: every arm's clock ``start_time`` from its copy's ``elapsed``, and from column ``first`` of its
    capsules, the active slots' link segments (link ``CAP_LINK`` of arm ``CAP_ARM``) from ``P (B, N, L + 1,
    2)``."""
    _refresh_copies(copy_rows, start_time, caps, first, elapsed, P, 0, P.shape[0])


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def refresh_capsules_parallel(copy_rows, start_time, caps, first, elapsed, P, n_chunks):
    """:func:`refresh_capsules` with the copies split into ``n_chunks`` chunks on numba's threads."""
    B = P.shape[0]
    for c in prange(n_chunks):
        _refresh_copies(copy_rows, start_time, caps, first, elapsed, P, c * B // n_chunks,
                        (c + 1) * B // n_chunks)


@njit(**_JIT)
def after_substep(copy_rows, joints, clear, finite, ok, start_time, caps, first, rho, dt, refresh, elapsed,
                  P, between):
    """Between an inter-arm step's sub-steps, after every kind's kernel call, on team-level arrays whose
    row ``copy_rows[b, i]`` is arm i of copy b: gather the joints the kernel left into ``P (B, N, L + 1,
    2)``, take its running clearance into ``between (B, N)`` (np.minimum's rule) and its finite flags into
    ``ok``, lower ``between`` to the clearance between arms (:func:`inter_arm_clearance`), advance every
    copy's clock ``elapsed`` by ``dt`` and, with ``refresh`` (a sub-step follows), :func:`refresh_capsules`
    for it. Copy by copy: no copy reads another's rows."""
    _after_substep_copies(copy_rows, joints, clear, finite, ok, start_time, caps, first, rho, dt, refresh,
                          elapsed, P, between, 0, P.shape[0])


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def after_substep_parallel(copy_rows, joints, clear, finite, ok, start_time, caps, first, rho, dt, refresh,
                           elapsed, P, between, n_chunks):
    """:func:`after_substep` with the copies split into ``n_chunks`` chunks on numba's threads."""
    B = P.shape[0]
    for c in prange(n_chunks):
        _after_substep_copies(copy_rows, joints, clear, finite, ok, start_time, caps, first, rho, dt,
                              refresh, elapsed, P, between, c * B // n_chunks, (c + 1) * B // n_chunks)
