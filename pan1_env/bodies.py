"""Geometry of the protected bodies: link capsules, their distances and the whole-arm barriers (numpy).

Link ℓ (numbered from 0, from the base) of an arm at q is the segment from joint ℓ to joint ℓ + 1,
``a_ℓ = P[ℓ]``, ``b_ℓ = P[ℓ + 1]`` with ``P = dynamics.joint_positions(arm, q)``; its *capsule* is
every point within ``link_radius`` ρ of the segment. With x(t) = a + t (b − a), t ∈ [0, 1]:

    closest point to c:  t* = clip((c − a)·(b − a) / ‖b − a‖², 0, 1),   d = ‖x(t*) − c‖

**Link–obstacle barrier** (obstacle centre c, radius r), one per link and obstacle:

    h = d(segment, c)² − (r + ρ)² = ‖x − c‖² − (r + ρ)²            at x = x(t*)
    ∇_q h = 2 (x − c)ᵀ J_x,     J_x = ∂x/∂q at t = t* held fixed               (1 × n)
    L_g0 h = ∇_q h · g0(q)                                           (1 × k, actuated velocities)
    ∂h/∂t = −2 (x − c)·ċ = −∇_x h · ċ                      (a moving obstacle, velocity ċ)

so that ḣ = L_g0 h · v + ∂h/∂t along q̇ = g0 v (g0 = I for a fully actuated arm, cascade's g0 for
a PA arm). The point at parameter t on link ℓ is the end-effector of the same chain with lengths
(L_0, …, L_{ℓ−1}, t L_ℓ, 0, …, 0): it moves like a point on the kinematic chain up to joint ℓ plus
t along link ℓ, so J_x is ``dynamics.jacobian`` of that chain.

**Which gradient where the closest point switches.** d²(q) = min_t g(q, t) with g = ‖x(q, t) − c‖²
strictly convex in t (L_ℓ > 0), so the minimiser t* is unique and continuous in q, and (Danskin)
∇_q d² = ∂_q g(q, t*): inside the link ∂_t g = 0, so the motion of t* adds nothing; with t* clamped
to 0 or 1 it does not move at all. We use this gradient of the *clamped* distance everywhere: it is
the one-sided gradient from the clamped side, and at the switch between the interior and an end
point it equals the interior one (h is C¹ there; only its second derivative jumps).

**Inter-arm barrier** between link ℓ of arm i and link m of arm j (both capsules of radius ρ):

    h = d(segment_iℓ, segment_jm)² − (2ρ)² = ‖x_i − x_j‖² − (2ρ)²   at the closest pair (s*, t*)
    ∇_{q_i} h = 2 (x_i − x_j)ᵀ J_{x_i},   ∇_{q_j} h = 2 (x_j − x_i)ᵀ J_{x_j},   each arm's row through its g0

with the same rule (s*, t* held fixed). For segments that are not parallel the closest pair is
unique and h is C¹ as above; for parallel segments whose projections overlap the closest pairs form
a set, h can have a kink, and the gradient used is the one at the pair :func:`segment_distance`
picks (a one-sided gradient).

Clearances are signed: d − r − ρ to an obstacle, d − 2ρ between capsules; negative means penetration.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .cascade import passive_velocity_map
from .dynamics import ArmParams, jacobian, joint_positions

__all__ = [
    "LinkBarrier",
    "InterArmBarrier",
    "link_segments",
    "closest_point_on_segment",
    "segment_distance",
    "link_point_jacobian",
    "link_obstacle_barrier",
    "link_clearance",
    "capsule_clearance",
    "inter_arm_barrier",
    "inter_arm_clearance",
    "obstacle_centers",
    "obstacle_velocities",
    "obstacle_stretch",
    "obstacle_floors",
    "arm_pair_floors",
    "reachable_obstacles",
]


class _Chain(NamedTuple):
    """The kinematic chain of an arm with some links shortened: what dynamics' kinematics read."""

    lengths: np.ndarray
    base: np.ndarray
    phi: float


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.sum(u * v, axis=-1)


def link_segments(arm: ArmParams, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points ``(a, b)`` of every link, each ``(..., n, 2)``, for q ``(n,)`` or ``(B, n)``."""
    P = joint_positions(arm, q)
    return P[..., :-1, :], P[..., 1:, :]


def closest_point_on_segment(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point x = a + t (b − a) of segments ``a, b (..., 2)`` to points ``p (..., 2)`` (broadcast).

    Returns ``(x (..., 2), t (...))`` with t = clip((p − a)·(b − a) / ‖b − a‖², 0, 1) ∈ [0, 1]
    (t = 0 for a zero-length segment).
    """
    a, b, p = (np.asarray(x, dtype=float) for x in (a, b, p))
    ab = b - a
    length2 = _dot(ab, ab)
    t = np.clip(_dot(p - a, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return a + t[..., None] * ab, t


def segment_distance(a1: np.ndarray, b1: np.ndarray, a2: np.ndarray,
                     b2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance between segments [a1, b1] and [a2, b2] (``(..., 2)`` each, broadcast) and the closest pair.

    Returns ``(d, s, t)``: d = ‖x1 − x2‖ with x1 = a1 + s (b1 − a1), x2 = a2 + t (b2 − a2), s, t ∈ [0, 1].
    The closest pair is found as in Ericson, *Real-Time Collision Detection*, §5.1.9: the lines'
    closest pair with s clamped, t from s, then t clamped and s recomputed. Segments of positive length;
    for parallel segments s = 0 is tried first (one of the closest pairs).
    """
    a1, b1, a2, b2 = (np.asarray(x, dtype=float) for x in (a1, b1, a2, b2))
    d1, d2, r = b1 - a1, b2 - a2, a1 - a2
    A, E, B = _dot(d1, d1), _dot(d2, d2), _dot(d1, d2)
    C, F = _dot(d1, r), _dot(d2, r)
    A_safe, E_safe = np.where(A > 0, A, 1.0), np.where(E > 0, E, 1.0)
    denom = A * E - B * B
    general = denom > 1e-12 * A * E
    s = np.where(general, np.clip((B * F - C * E) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    t = (B * s + F) / E_safe
    s = np.where(t < 0, np.clip(-C / A_safe, 0.0, 1.0), np.where(t > 1, np.clip((B - C) / A_safe, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    diff = (a1 + s[..., None] * d1) - (a2 + t[..., None] * d2)
    return np.sqrt(_dot(diff, diff)), s, t


def link_point_jacobian(arm: ArmParams, q: np.ndarray, link: np.ndarray | int, t: np.ndarray | float) -> np.ndarray:
    """∂x/∂q of the point x at parameter ``t`` on link ``link`` (t held fixed): ``(..., 2, n)``.

    ``q (..., n)``, ``link`` and ``t`` broadcast against q's batch shape. The point is the end-effector
    of the chain with lengths (L_0, …, L_{ℓ−1}, t L_ℓ, 0, …), so this is ``dynamics.jacobian`` of it.
    """
    q = np.asarray(q, dtype=float)
    n = arm.n_links
    batch = np.broadcast_shapes(q.shape[:-1], np.shape(link), np.shape(t))
    qf = np.broadcast_to(q, batch + (n,)).reshape(-1, n)
    lf = np.broadcast_to(link, batch).reshape(-1, 1)
    tf = np.broadcast_to(t, batch).reshape(-1, 1)
    alpha = np.arange(n)
    weights = (alpha < lf) + tf * (alpha == lf)
    J = jacobian(_Chain(arm.lengths * weights, arm.base, arm.phi), qf)  # type: ignore[arg-type]
    return J.reshape(batch + (2, n))


class LinkBarrier(NamedTuple):
    """Whole-arm barriers of one arm against every obstacle; ``S`` is q's batch shape, ``n`` links."""

    h: np.ndarray  #: ``S + (n, O)``: d² − (r + ρ)²
    grad_q: np.ndarray  #: ``S + (n, O, n)``: ∇_q h
    row: np.ndarray  #: ``S + (n, O, k)``: L_g0 h = ∇_q h · g0
    dh_dt: np.ndarray  #: ``S + (n, O)``: −2 (x − c)·ċ (zero for still obstacles)
    point: np.ndarray  #: ``S + (n, O, 2)``: the closest point x on the link
    t: np.ndarray  #: ``S + (n, O)``: its parameter along the link


def _flat(arm: ArmParams, q: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    q = np.asarray(q, dtype=float)
    if q.ndim not in (1, 2) or q.shape[-1] != arm.n_links:
        raise ValueError(f"q must have shape (n,) or (B, n) with n={arm.n_links}, got {q.shape}")
    return q.reshape(-1, arm.n_links), q.shape[:-1]


def link_obstacle_barrier(arm: ArmParams, q: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                          link_radius: float = 0.0, velocities: np.ndarray | None = None) -> LinkBarrier:
    """h, ∇_q h, L_g0 h and ∂h/∂t of every link of ``arm`` at q against obstacles ``centers (O, 2)``,
    ``radii (O,)`` moving with ``velocities (O, 2)`` (None: still); see the module docstring."""
    qf, batch = _flat(arm, q)
    centers = np.asarray(centers, dtype=float).reshape(-1, 2)
    radii = np.asarray(radii, dtype=float).reshape(-1)
    a, b = link_segments(arm, qf)  # (M, n, 2)
    x, t = closest_point_on_segment(a[:, :, None], b[:, :, None], centers)  # (M, n, O, 2), (M, n, O)
    rel = x - centers
    h = _dot(rel, rel) - (radii + link_radius) ** 2
    n = arm.n_links
    J = link_point_jacobian(arm, qf[:, None, None, :], np.arange(n)[:, None], t)  # (M, n, O, 2, n)
    grad = 2.0 * np.einsum("...c,...cq->...q", rel, J)
    row = np.einsum("mloq,mqk->mlok", grad, passive_velocity_map(arm, qf))
    dh_dt = np.zeros_like(h) if velocities is None else -2.0 * _dot(rel, np.asarray(velocities, dtype=float))
    out = LinkBarrier(h, grad, row, dh_dt, x, t)
    return LinkBarrier(*(v.reshape(batch + v.shape[1:]) for v in out))


def capsule_clearance(a: np.ndarray, b: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                      link_radius: float = 0.0) -> np.ndarray:
    """Signed clearance d(segment, c) − r − ρ of segments ``a, b (..., L, 2)`` inflated by ρ to disks
    ``centers (..., O, 2)``, ``radii (..., O)`` (leading axes broadcast): ``(..., L, O)``."""
    centers = np.asarray(centers, dtype=float)[..., None, :, :]
    x, _ = closest_point_on_segment(a[..., :, None, :], b[..., :, None, :], centers)
    return np.linalg.norm(x - centers, axis=-1) - np.asarray(radii, dtype=float)[..., None, :] - link_radius


def link_clearance(arm: ArmParams, q: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                   link_radius: float = 0.0) -> np.ndarray:
    """Signed clearance d(segment, c) − r − ρ of every link capsule to every obstacle: ``(..., n, O)``."""
    a, b = link_segments(arm, q)
    return capsule_clearance(a, b, np.asarray(centers, dtype=float).reshape(-1, 2),
                             np.asarray(radii, dtype=float).reshape(-1), link_radius)


class InterArmBarrier(NamedTuple):
    """Barriers between the capsules of arm i (``n_i`` links) and arm j (``n_j``): ``S + (n_i, n_j, …)``."""

    h: np.ndarray  #: d² − (2ρ)²
    grad_i: np.ndarray  #: ∇_{q_i} h, ``(…, n_i)``
    grad_j: np.ndarray  #: ∇_{q_j} h, ``(…, n_j)``
    row_i: np.ndarray  #: ∇_{q_i} h · g0_i, ``(…, k_i)``
    row_j: np.ndarray  #: ∇_{q_j} h · g0_j, ``(…, k_j)``
    point_i: np.ndarray  #: closest point on arm i's link, ``(…, 2)``
    point_j: np.ndarray  #: closest point on arm j's link, ``(…, 2)``
    s: np.ndarray  #: its parameter along arm i's link
    t: np.ndarray  #: its parameter along arm j's link


def inter_arm_barrier(arm_i: ArmParams, q_i: np.ndarray, arm_j: ArmParams, q_j: np.ndarray,
                      link_radius: float = 0.0) -> InterArmBarrier:
    """h and each arm's gradient and row for every pair (link of arm i, link of arm j).

    ``q_i`` and ``q_j`` are ``(n_i,)``/``(n_j,)`` or ``(B, n_i)``/``(B, n_j)`` with the same B.
    """
    qi, batch = _flat(arm_i, q_i)
    qj, batch_j = _flat(arm_j, q_j)
    if batch != batch_j:
        raise ValueError(f"q_i and q_j must have the same batch shape, got {batch} and {batch_j}")
    ai, bi = link_segments(arm_i, qi)
    aj, bj = link_segments(arm_j, qj)
    _, s, t = segment_distance(ai[:, :, None], bi[:, :, None], aj[:, None], bj[:, None])  # (M, n_i, n_j)
    xi = ai[:, :, None] + s[..., None] * (bi - ai)[:, :, None]
    xj = aj[:, None] + t[..., None] * (bj - aj)[:, None]
    rel = xi - xj
    h = _dot(rel, rel) - (2.0 * link_radius) ** 2
    Ji = link_point_jacobian(arm_i, qi[:, None, None, :], np.arange(arm_i.n_links)[:, None], s)
    Jj = link_point_jacobian(arm_j, qj[:, None, None, :], np.arange(arm_j.n_links)[None, :], t)
    grad_i = 2.0 * np.einsum("...c,...cq->...q", rel, Ji)
    grad_j = -2.0 * np.einsum("...c,...cq->...q", rel, Jj)
    row_i = np.einsum("mabq,mqk->mabk", grad_i, passive_velocity_map(arm_i, qi))
    row_j = np.einsum("mabq,mqk->mabk", grad_j, passive_velocity_map(arm_j, qj))
    out = InterArmBarrier(h, grad_i, grad_j, row_i, row_j, xi, xj, s, t)
    return InterArmBarrier(*(v.reshape(batch + v.shape[1:]) for v in out))


def inter_arm_clearance(arm_i: ArmParams, q_i: np.ndarray, arm_j: ArmParams, q_j: np.ndarray,
                        link_radius: float = 0.0) -> np.ndarray:
    """Signed clearance d − 2ρ between every link capsule of arm i and of arm j: ``(..., n_i, n_j)``."""
    ai, bi = link_segments(arm_i, q_i)
    aj, bj = link_segments(arm_j, q_j)
    d, _, _ = segment_distance(ai[..., :, None, :], bi[..., :, None, :], aj[..., None, :, :], bj[..., None, :, :])
    return d - 2.0 * link_radius


def _legs(centers: np.ndarray, path_ends: np.ndarray, speeds: np.ndarray,
          t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    c0 = np.asarray(centers, dtype=float)
    step = np.asarray(path_ends, dtype=float) - c0
    speeds = np.asarray(speeds, dtype=float)
    length = np.linalg.norm(step, axis=-1)
    moving = (speeds > 0) & (length > 0)
    safe = np.where(moving, length, 1.0)
    arc = np.mod(np.asarray(t, dtype=float)[..., None] * speeds, 2.0 * safe)  # (..., O), in [0, 2ℓ)
    return c0, step / safe[..., None], np.where(moving, arc, 0.0), np.where(moving, length, 0.0)


def obstacle_centers(centers: np.ndarray, path_ends: np.ndarray, speeds: np.ndarray,
                     t: np.ndarray | float) -> np.ndarray:
    """Centres at time ``t`` (s, scalar or ``(...)``) of obstacles going back and forth: ``(..., O, 2)``.

    ``centers``, ``path_ends`` ``(O, 2)`` and ``speeds`` ``(O,)``, or with leading axes that broadcast
    against t's (one team per time, as in a batch of copies).

    Obstacle j starts at ``centers[j]`` heading for ``path_ends[j]`` at ``speeds[j]`` m/s, turns
    there, comes back, turns at its centre and so on: its arc length along the path is the triangle
    wave u(t) = ℓ − |ℓ − (s t mod 2ℓ)| with ℓ = ‖path_end − center‖. A speed of 0 (or a path of length
    0) keeps it at its centre.
    """
    c0, unit, arc, length = _legs(centers, path_ends, speeds, t)
    u = length - np.abs(length - arc)
    return c0 + u[..., None] * unit


def obstacle_velocities(centers: np.ndarray, path_ends: np.ndarray, speeds: np.ndarray,
                        t: np.ndarray | float) -> np.ndarray:
    """Velocities ċ at time ``t`` of the obstacles of :func:`obstacle_centers`: ``(..., O, 2)``.

    ±speed along the path: outward while s t mod 2ℓ < ℓ, back otherwise (at a turning instant the
    velocity of the leg that starts there); zero for still obstacles.
    """
    c0, unit, arc, length = _legs(centers, path_ends, speeds, t)
    speeds = np.asarray(speeds, dtype=float)
    sign = np.where(length > 0, np.where(arc < length, 1.0, -1.0), 0.0)
    return (sign * speeds)[..., None] * unit


def obstacle_stretch(centers: np.ndarray, path_ends: np.ndarray, speeds: np.ndarray, t: float,
                     lookahead: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The stretch of its path each obstacle of :func:`obstacle_centers` covers from ``t`` to ``t + lookahead``
    (s, inf allowed): its ends ``start``, ``end`` ``(O, 2)`` (start nearer ``centers[j]``) and their
    velocities ``(O, 2)``. Along the path the position is the triangle wave u(τ); over the window its least
    and greatest values are taken at the window's ends or at a turn inside it (u = 0 or ℓ), and each end of
    the stretch moves as the term that attains it (a turn: still)."""
    c0, unit, _, length = _legs(centers, path_ends, speeds, t)
    speeds = np.asarray(speeds, dtype=float)

    def wave(time: float) -> tuple[np.ndarray, np.ndarray]:  # u and u̇ at ``time``, as obstacle_centers/_velocities
        arc = _legs(centers, path_ends, speeds, time)[2]
        return length - np.abs(length - arc), np.where(length > 0, np.where(arc < length, speeds, -speeds), 0.0)

    (u0, du0), later = wave(t), t + lookahead
    u1, du1 = wave(later) if np.isfinite(later) else (u0, du0)
    period = np.where(length > 0, 2.0 * length / np.where(length > 0, speeds, 1.0), np.inf)
    # the turns in (t, t + lookahead]: at 0 when τ·s ≡ 0, at ℓ when τ·s ≡ ℓ (mod 2ℓ)
    phase = np.where(np.isfinite(period), np.mod(t, np.where(np.isfinite(period), period, 1.0)), 0.0)
    to_far = np.where(phase < period / 2, period / 2 - phase, 1.5 * period - phase)
    to_near = period - phase
    far_turn = (length > 0) & (to_far <= lookahead)
    near_turn = (length > 0) & (to_near <= lookahead)
    lo = np.minimum(u0, u1)
    v_lo = np.where(u0 <= u1, du0, du1)
    lo, v_lo = np.where(near_turn, 0.0, lo), np.where(near_turn, 0.0, v_lo)
    hi = np.maximum(u0, u1)
    v_hi = np.where(u0 >= u1, du0, du1)
    hi, v_hi = np.where(far_turn, length, hi), np.where(far_turn, 0.0, v_hi)
    return c0 + lo[:, None] * unit, c0 + hi[:, None] * unit, v_lo[:, None] * unit, v_hi[:, None] * unit


def obstacle_floors(bases: np.ndarray, reach: np.ndarray, centers: np.ndarray, path_ends: np.ndarray,
                    radii: np.ndarray, body_radius: float) -> np.ndarray:
    """Lower bounds on the clearance of any body of each arm to each obstacle, in any configuration and at any
    time: ``(..., N, O)`` from the arms' ``bases (..., N, 2)`` and ``reach (..., N)`` (Σ L: every body point
    lies within it of the base) and the obstacles of :func:`obstacle_centers` (each stays on the segment from
    its centre to its path's end): the base's distance to that segment, less the reach, the obstacle's radius
    and the body's (``link_radius`` for links, 0 for an end-effector)."""
    start, step = centers[..., None, :, :], (path_ends - centers)[..., None, :, :]
    length2 = np.sum(step * step, axis=-1)
    along = np.sum((bases[..., :, None, :] - start) * step, axis=-1) / np.where(length2 > 0, length2, 1.0)
    nearest = start + np.clip(along, 0.0, 1.0)[..., None] * step
    apart = np.linalg.norm(bases[..., :, None, :] - nearest, axis=-1)
    return apart - reach[..., :, None] - radii[..., None, :] - body_radius


def reachable_obstacles(bases: np.ndarray, reach: np.ndarray, centers: np.ndarray, ends: np.ndarray,
                        radii: np.ndarray, link_radius: float) -> np.ndarray:
    """``(…, N, O)``: whether obstacle o comes, anywhere on its path from ``centers`` to ``ends`` ``(…, O, 2)``,
    within arm i's ``reach (…, N)`` plus its radius (``radii (…, O)``) and ``link_radius`` of the arm's base
    (``bases (…, N, 2)``), batched over any leading axes (:meth:`Scenario.obstacle_mask`, the envs' drawn teams)."""
    at = bases[..., :, None, :]  # (…, N, 1, 2)
    nearest, _ = closest_point_on_segment(centers[..., None, :, :], ends[..., None, :, :], at)
    return np.linalg.norm(nearest - at, axis=-1) <= reach[..., None] + radii[..., None, :] + link_radius


def arm_pair_floors(bases: np.ndarray, reach: np.ndarray, link_radius: float) -> np.ndarray:
    """Lower bounds on the clearance d − 2ρ between any link capsules of arms i and j, in any configurations:
    ``(..., N, N)``, the bases' distance less both reaches and 2ρ (≤ 0: the two reaches can meet)."""
    apart = np.linalg.norm(bases[..., :, None, :] - bases[..., None, :, :], axis=-1)
    return apart - reach[..., :, None] - reach[..., None, :] - 2.0 * link_radius
