"""Observations and the envs' small per-step helpers, compiled: local team observations (serial and
multi-threaded), reach observations, edge-length errors, and actions scaled into commands."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._numba_ext import _EXACT, _JIT, _check_chunks


@njit(**_JIT, inline="always")
def _obstacle_slots(out, row, col, c, px, py, centers, radii, velocities, vcol, team, K, bound, clear, taken):
    """Write K obstacle slots (present, dx, dy, r, h) at ``out[row, col, c:]`` for an end-effector at
    (px, py), from the obstacles ``centers[team]``, ``radii[team]``: the K obstacles of smallest
    clearance ‖p − o‖ − r (ties: lower index first), zeros where absent. With ``vcol`` ≥ 0 the same
    slots' obstacle velocities ``velocities[team]`` go to ``out[row, col, vcol:vcol + 2K]``. Inlined,
    and indices rather than views: a view of a heap array costs two atomic reference-count updates."""
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
            if vcol >= 0:
                out[row, col, vcol + 2 * _slot] = 0.0
                out[row, col, vcol + 2 * _slot + 1] = 0.0
        else:
            if vcol >= 0:
                out[row, col, vcol + 2 * _slot] = min(max(velocities[team, best, 0], -bound), bound)
                out[row, col, vcol + 2 * _slot + 1] = min(max(velocities[team, best, 1], -bound), bound)
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
def _observation_rows(lo, hi, q, qd, P, base, err, centers, radii, velocities, ids, neighbour, neighbour_edge,
                      present, K, inv_vmax, bound, out):
    """Teams ``lo … hi−1`` of :func:`group_observations` (the loop body, with its own scratch space)."""
    D = neighbour.shape[1]
    O = radii.shape[1]
    size = out.shape[2]
    moving = velocities.shape[1] > 0
    n = (size - 2 - 4 * D - (7 if moving else 5) * K) // 3
    vcol = size - 2 * K if moving else -1
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
            _obstacle_slots(out, bi, r, c, px, py, centers, radii, velocities, vcol, bi, K, bound, clear, taken)



_OBSERVATIONS_DOC = """Local observations of the arms ``ids`` (all with n links) of B teams, written to
    ``out (B, A, size)``.

    Layout and inputs as :meth:`pan1_env.observation.ObservationLayout.build`; the K obstacle slots
    hold the K obstacles of smallest clearance ‖p − o‖ − r (ties: lower index first); with obstacle
    ``velocities (B, O, 2)`` (an empty ``(B, 0, 2)`` for none) the last 2K entries are the slots'
    obstacle velocities; entries are clipped to ±``bound``; absent slots are zeros.
    """


def group_observations(q, qd, P, base, err, centers, radii, velocities, ids, neighbour, neighbour_edge, present, K,
                       inv_vmax, bound, out):
    # _observation_rows called from Python (no compiled wrapper: one compilation less at a first step,
    # since numba compiles a callee's code again inside each caller); the parallel twin and
    # formation_observations run the same compiled rows
    _observation_rows(0, q.shape[0], q, qd, P, base, err, centers, radii, velocities, ids, neighbour, neighbour_edge,
                      present, K, inv_vmax, bound, out)


@njit(cache=True, error_model="numpy", fastmath=_JIT["fastmath"], parallel=True)
def group_observations_parallel(q, qd, P, base, err, centers, radii, velocities, ids, neighbour, neighbour_edge,
                                present, K, inv_vmax, bound, out, n_chunks):
    _check_chunks(n_chunks)
    B = q.shape[0]
    for c in prange(n_chunks):
        _observation_rows(c * B // n_chunks, (c + 1) * B // n_chunks, q, qd, P, base, err, centers, radii, velocities,
                          ids, neighbour, neighbour_edge, present, K, inv_vmax, bound, out)


group_observations.__doc__ = _OBSERVATIONS_DOC
group_observations_parallel.__doc__ = _OBSERVATIONS_DOC + """
    The same, with the teams split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches). Both run the same compiled per-team loop.
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


@njit(**_EXACT, inline="always")
def _clipped(x, bound):
    """``x`` clipped to ±``bound`` as numpy's clip does it (NaN passes through)."""
    if x < -bound:
        return -bound
    if x > bound:
        return bound
    return x


@njit(**_EXACT)
def kind_state(q, qd, p, rows, ids, A, n_max, bound, out):
    """A kind's part of the team's centralised state (:meth:`pan1_env.core.FormationCore.state`), written to
    ``out (B, S)`` (float32): for each of its ``rows`` (copy ``row // A``, arm ``ids[row % A]``) the arm's block
    ``[q, q̇, p]`` at column arm · (2 n_max + 2), its n angles and speeds from columns 0 and n_max of the block (NaN
    reads 0; the padding up to n_max is the caller's) and its end-effector at 2 n_max, each clipped
    to ±``bound``; numpy's bytes (:data:`_EXACT`)."""
    n = q.shape[1]
    for r in rows:
        b = r // A
        c = ids[r % A] * (2 * n_max + 2)
        for j in range(n):
            out[b, c + j] = 0.0 if np.isnan(q[r, j]) else _clipped(q[r, j], bound)
            out[b, c + n_max + j] = 0.0 if np.isnan(qd[r, j]) else _clipped(qd[r, j], bound)
        out[b, c + 2 * n_max] = _clipped(p[r, 0], bound)
        out[b, c + 2 * n_max + 1] = _clipped(p[r, 1], bound)


@njit(**_EXACT)
def obstacle_state(centers, radii, col, bound, out):
    """The obstacles' part of the team's centralised state: each obstacle's centre ``centers (B, O, 2)`` and radius
    ``radii (B, O)`` at ``out[b, col + 3j:]`` (float32), clipped to ±``bound``."""
    for b in range(radii.shape[0]):
        for j in range(radii.shape[1]):
            out[b, col + 3 * j] = _clipped(centers[b, j, 0], bound)
            out[b, col + 3 * j + 1] = _clipped(centers[b, j, 1], bound)
            out[b, col + 3 * j + 2] = _clipped(radii[b, j], bound)


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
    still = np.empty((q.shape[0], 0, 2))  # no velocities (vcol −1 below)
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
        _obstacle_slots(rows, 0, i, 3 * n + 4, px, py, centers, radii, still, -1, i, K, bound, clear, taken)


@njit(**_JIT)
def formation_observations(P, edges, distances, err, q, qd, base, centers, radii, velocities, ids, neighbour,
                           neighbour_edge, present, K, inv_vmax, bound, out):
    """:func:`edge_length_errors` into ``err (B, E)``, then :func:`group_observations` from them, in one call."""
    edge_length_errors(P, edges, distances, err)
    lo = q.shape[0] * 0  # an int64, as group_observations passes it
    _observation_rows(lo, q.shape[0], q, qd, P, base, err, centers, radii, velocities, ids, neighbour, neighbour_edge,
                      present, K, inv_vmax, bound, out)
