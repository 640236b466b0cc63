"""An independent geometry checker for whole-arm safety: numpy only, nothing from pan1_env's kinematics.

It rebuilds every arm's link segments from a state vector laid out as ``Pan1ParallelEnv.state()``
documents it (per arm: q, q̇, each padded with zeros to the largest n, then the end-effector p;
then every obstacle's centre and radius) and from the arms' link lengths, bases and base rotations φ,
with the model's convention written out again here (docs/MODEL.md §1):

    θ_α = φ + q_1 + … + q_α,        joint α+1 = joint α + L_α [sin θ_α, cos θ_α],   joint 0 = base

(link angles from the base frame's vertical axis, clockwise). Distances use other algorithms than
:mod:`pan1_env.bodies`: a point's distance to a segment by projecting onto the line and comparing
with both ends; two segments' distance as 0 when they cross (orientation tests), else the smallest
of the four end-point-to-segment distances.
"""

from __future__ import annotations

import math

import numpy as np


def split_state(state: np.ndarray, n_links: list[int], n_obstacles: int) -> dict[str, object]:
    """The parts of a ``state()`` vector: lists ``q``, ``qd`` (unpadded), arrays ``p (N, 2)``,
    ``centers (O, 2)``, ``radii (O,)``."""
    state = np.asarray(state, dtype=float)
    n_max = max(n_links)
    stride = 2 * n_max + 2
    q, qd, p = [], [], []
    for i, n in enumerate(n_links):
        block = state[i * stride:(i + 1) * stride]
        q.append(block[:n])
        qd.append(block[n_max:n_max + n])
        p.append(block[2 * n_max:2 * n_max + 2])
    rest = state[len(n_links) * stride:]
    if rest.size != 3 * n_obstacles:
        raise AssertionError(f"state has {rest.size} numbers after the arms, expected 3 × {n_obstacles}")
    obs = rest.reshape(n_obstacles, 3)
    return {"q": q, "qd": qd, "p": np.array(p), "centers": obs[:, :2], "radii": obs[:, 2]}


def joints(q: np.ndarray, lengths: np.ndarray, base: np.ndarray, phi: float) -> np.ndarray:
    """Base, every joint and the end-effector, ``(n + 1, 2)``, one link at a time."""
    points = [np.array(base, dtype=float)]
    theta = float(phi)
    for q_a, length in zip(q, lengths, strict=True):
        theta += float(q_a)
        x, y = points[-1]
        points.append(np.array([x + length * math.sin(theta), y + length * math.cos(theta)]))
    return np.array(points)


def arms_from_state(state: np.ndarray, scenario) -> tuple[list[np.ndarray], dict[str, object]]:
    """Every arm's joints ``(n_i + 1, 2)`` rebuilt from ``state`` and the scenario's lengths, bases, φ."""
    parts = split_state(state, [len(a.lengths) for a in scenario.arms], len(scenario.obstacles.radii))
    arms = [joints(q, a.lengths, a.base, a.phi) for q, a in zip(parts["q"], scenario.arms, strict=True)]
    return arms, parts


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from point p to segment [a, b]: the foot of the perpendicular if it falls inside, else an end."""
    p, a, b = (np.asarray(v, dtype=float) for v in (p, a, b))
    ab = b - a
    denom = float(ab @ ab)
    if denom > 0:
        u = float((p - a) @ ab) / denom
        if 0.0 <= u <= 1.0:
            return float(np.linalg.norm(p - (a + u * ab)))
    return float(min(np.linalg.norm(p - a), np.linalg.norm(p - b)))


def _orientation(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def segments_cross(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> bool:
    """Whether segments [a, b] and [c, d] share a point (proper crossing or touching)."""
    o1, o2 = _orientation(a, b, c), _orientation(a, b, d)
    o3, o4 = _orientation(c, d, a), _orientation(c, d, b)
    if ((o1 > 0 > o2) or (o1 < 0 < o2)) and ((o3 > 0 > o4) or (o3 < 0 < o4)):
        return True
    return any(point_segment_distance(p, s, e) == 0.0 for p, s, e in ((c, a, b), (d, a, b), (a, c, d), (b, c, d)))


def segment_segment_distance(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> float:
    """Distance between segments [a, b] and [c, d]: 0 if they cross, else the closest end-point distance."""
    if segments_cross(a, b, c, d):
        return 0.0
    return min(point_segment_distance(c, a, b), point_segment_distance(d, a, b),
               point_segment_distance(a, c, d), point_segment_distance(b, c, d))


def obstacle_clearances(arm_joints: list[np.ndarray], centers: np.ndarray, radii: np.ndarray,
                        link_radius: float = 0.0) -> list[np.ndarray]:
    """Per arm, ``(n_i, O)`` signed clearances d(link, centre) − r − ρ (negative: penetration)."""
    out = []
    for P in arm_joints:
        rows = [[point_segment_distance(c, P[k], P[k + 1]) - r - link_radius
                 for c, r in zip(centers, radii, strict=True)] for k in range(len(P) - 1)]
        out.append(np.array(rows).reshape(len(P) - 1, len(radii)))
    return out


def obstacle_penetration(arm_joints: list[np.ndarray], centers: np.ndarray, radii: np.ndarray,
                         link_radius: float = 0.0) -> list[np.ndarray]:
    """Per arm, ``(n_i, O)`` penetration depths max(0, r + ρ − d) of every link capsule into every obstacle."""
    return [np.maximum(0.0, -c) for c in obstacle_clearances(arm_joints, centers, radii, link_radius)]


def inter_arm_clearances(arm_joints: list[np.ndarray], link_radius: float = 0.0) -> dict[tuple[int, int], np.ndarray]:
    """For every pair of arms i < j, ``(n_i, n_j)`` signed clearances d(link, link) − 2ρ between their capsules."""
    out = {}
    for i, Pi in enumerate(arm_joints):
        for j in range(i + 1, len(arm_joints)):
            Pj = arm_joints[j]
            out[i, j] = np.array([[segment_segment_distance(Pi[k], Pi[k + 1], Pj[m], Pj[m + 1]) - 2 * link_radius
                                   for m in range(len(Pj) - 1)] for k in range(len(Pi) - 1)])
    return out


def inter_arm_penetration(arm_joints: list[np.ndarray], link_radius: float = 0.0) -> dict[tuple[int, int], np.ndarray]:
    """For every pair of arms i < j, ``(n_i, n_j)`` penetration depths max(0, 2ρ − d) of their capsules."""
    return {pair: np.maximum(0.0, -c) for pair, c in inter_arm_clearances(arm_joints, link_radius).items()}


def batched_joints(q: np.ndarray, lengths: np.ndarray, base: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """:func:`joints` of many arms at once: ``q``, ``lengths (..., n)`` (a zero length past an arm's links),
    ``base (..., 2)``, ``phi (...)`` → ``(..., n + 1, 2)``."""
    theta = phi[..., None] + np.cumsum(q, axis=-1)
    steps = lengths[..., None] * np.stack([np.sin(theta), np.cos(theta)], axis=-1)
    return np.concatenate([base[..., None, :], base[..., None, :] + np.cumsum(steps, axis=-2)], axis=-2)


def _batched_point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`point_segment_distance` broadcast over leading axes (``(..., 2)`` each)."""
    ab, ap = b - a, p - a
    length2 = np.sum(ab * ab, axis=-1)
    along = np.sum(ap * ab, axis=-1)
    inside = (along > 0) & (along < length2)
    cross = np.abs(ab[..., 0] * ap[..., 1] - ab[..., 1] * ap[..., 0]) / np.sqrt(np.where(inside, length2, 1.0))
    ends = np.minimum(np.linalg.norm(ap, axis=-1), np.linalg.norm(p - b, axis=-1))
    return np.where(inside, cross, ends)


def batched_clearances(P: np.ndarray, centers: np.ndarray, radii: np.ndarray, link_radius: float) -> tuple:
    """Every copy's smallest link-to-obstacle and link-to-link clearance (``(B,)`` each) from arms' joints
    ``P (B, N, n + 1, 2)`` and obstacles ``centers (B, O, 2)``, ``radii (B, O)``: the algorithms of
    :func:`obstacle_clearances` and :func:`inter_arm_clearances`, broadcast."""
    a, b = P[:, :, :-1, None, :], P[:, :, 1:, None, :]  # (B, N, n, 1, 2)
    to_obstacles = _batched_point_segment(centers[:, None, None], a, b) - radii[:, None, None] - link_radius
    i, j = np.triu_indices(P.shape[1], 1)
    a1, b1 = P[:, i, :-1, None, :], P[:, i, 1:, None, :]  # (B, pairs, n, 1, 2)
    a2, b2 = P[:, j, None, :-1, :], P[:, j, None, 1:, :]  # (B, pairs, 1, n, 2)

    def orient(x, y, z):
        return np.sign((y[..., 0] - x[..., 0]) * (z[..., 1] - x[..., 1])
                       - (y[..., 1] - x[..., 1]) * (z[..., 0] - x[..., 0]))

    crossing = (orient(a1, b1, a2) * orient(a1, b1, b2) < 0) & (orient(a2, b2, a1) * orient(a2, b2, b1) < 0)
    ends = np.minimum(np.minimum(_batched_point_segment(a2, a1, b1), _batched_point_segment(b2, a1, b1)),
                      np.minimum(_batched_point_segment(a1, a2, b2), _batched_point_segment(b1, a2, b2)))
    between = np.where(crossing, 0.0, ends) - 2 * link_radius
    return to_obstacles.reshape(len(P), -1).min(axis=1), between.reshape(len(P), -1).min(axis=1, initial=np.inf)
