"""Moving formations: a desired shape that changes with time (docs/MODEL.md §8).

The desired shape is a realisation of the formation that scales and morphs,

    r(t) = s(t) · [(1 − λ(t)) r_A + λ(t) r_B],

with s(t) piecewise linear through keyframes (t_m, s_m) (held before the first and after the last),
r_A the formation's realisation, r_B the shape it switches to (the same edges, other lengths, aligned to
r_A) and λ(t) rising linearly from 0 to 1 over [t_s, t_s + T_s] (a step when T_s = 0). The desired edge
lengths are the shape's, d_k(t) = ‖r_i(t) − r_j(t)‖, so every d(t) is realisable in the plane, and

    d_k ḋ_k = (r_i − r_j) · (ṙ_i − ṙ_j).

The distances fix a shape only up to a rigid motion, so they cannot tell the formation to turn or travel.
A motion with a ``centre`` **places** the shape as well: every arm gets its own desired point,

    p*_i(t) = c + δ(t) + Rot(θ(t)) (r_i(t) − r̄(t)),      r̄ the shape's centroid,

with θ(t) (a turn, rad) and δ(t) (a path of the centroid from c, m) piecewise linear through keyframes of
their own. That is a displacement-based target: the lengths are still the shape's, and each arm is also
pulled to its point.

The **feed-forward** is the smallest set of end-effector velocities that changes every edge at its
desired rate: with the rigidity matrix R(p) (row k: z_kᵀ at arm i, −z_kᵀ at arm j),

    ṗ_ff = Rᵀ (R Rᵀ + μ I)⁻¹ (d ⊙ ḋ),     μ = FEED_FORWARD_DAMPING (m²),

so that z_k · (ṗ_i − ṗ_j) = d_k ḋ_k where R has full row rank: with it, the edge errors
e_k = ‖z_k‖² − d_k² see no disturbance from the motion. μ keeps it bounded where R loses rank (the arms
in a line); at a formation of side 0.5 m it changes ṗ_ff by about 0.1 %. It needs every end-effector,
so the env computes it and gives each arm its own share (the observation's ``formation_velocity``).
A placed shape needs no solve: each arm's share is its point's velocity and a pull to it,

    ṗ_ff,i = ṗ*_i + min(k_place ‖p*_i − p_i‖, v_place) (p*_i − p_i)/‖p*_i − p_i‖,

k_place = PLACEMENT_GAIN (1/s), v_place = PLACEMENT_SPEED (m/s), which only needs the arm's own end-effector and
the clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FormationMotion", "MotionTable", "FEED_FORWARD_DAMPING", "PLACEMENT_GAIN", "PLACEMENT_SPEED",
           "MAX_TARGET_SPEED", "MAX_TURN_RATE", "MIN_EDGE", "edge_rates", "feed_forward", "align", "blend_degenerates",
           "switch_shape", "check_times", "check_motion"]

FEED_FORWARD_DAMPING = 1e-4  # μ in m²: R Rᵀ + μ I stays invertible where the arms line up
PLACEMENT_GAIN = 1.0  # k_place in 1/s: a placed arm closes 63 % of its distance to its point in a second
PLACEMENT_SPEED = 0.1  # m/s: the pull's largest speed, so that an arm far from its point is not rushed there


def _keyframes(times_name: str, values_name: str, times, values, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Checked, read-only keyframes: their times ``(K,)`` (finite, ≥ 0, increasing) and values ``(K, width)``."""
    times = np.array(times, dtype=float).reshape(-1)
    values = np.array(values, dtype=float)
    if times.size == 0 or values.size != times.size * width:
        raise ValueError(f"FormationMotion: {times_name} and {values_name} need K ≥ 1 keyframes ({width} value(s) "
                         f"each), got {times.size} times and {values.size} values")
    values = values.reshape(len(times), width)
    if not (np.all(np.isfinite(times)) and np.all(times >= 0) and np.all(np.diff(times) > 0)):
        raise ValueError(f"FormationMotion.{times_name} must be finite, ≥ 0 and increasing, got {times.tolist()}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"FormationMotion.{values_name} must be finite, got {values.tolist()}")
    times.setflags(write=False)
    values.setflags(write=False)
    return times, values


@dataclass(frozen=True)
class FormationMotion:
    """How a formation's desired shape moves: scale keyframes, an optional switch to another shape and, with a
    ``centre``, where the shape is placed (a turn and a path, each through keyframes of its own).

    Attributes:
        scale_times: ``(K,)`` s, increasing, K ≥ 1: the keyframes' times.
        scales: ``(K,)`` > 0: s at those times (linear between them, held outside).
        switch_shape: ``(N, 2)`` r_B, the shape switched to (same edges as the formation; None: no switch).
        switch_time: t_s (s) when the switch starts.
        switch_duration: T_s ≥ 0 (s) it takes (0: a step).
        centre: ``(2,)`` c (m), where the shape's centroid is placed at δ = 0; None: the shape is not placed (the
            lengths alone are the target, and the turn and path must stay zero).
        turn_times, turns: ``(K,)`` s and rad, the turn θ(t) of the placed shape from its realisation (default:
            none). Between keyframes the shape turns at the rate ω = Δθ/Δt.
        path_times, path: ``(K,)`` s and ``(K, 2)`` m, the offset δ(t) of the placed centroid from ``centre``.
    """

    scale_times: np.ndarray
    scales: np.ndarray
    switch_shape: np.ndarray | None = None
    switch_time: float = math.inf
    switch_duration: float = 0.0
    centre: np.ndarray | None = None
    turn_times: np.ndarray = (0.0,)
    turns: np.ndarray = (0.0,)
    path_times: np.ndarray = (0.0,)
    path: np.ndarray = ((0.0, 0.0),)

    def __post_init__(self) -> None:
        times, scales = _keyframes("scale_times", "scales", self.scale_times, self.scales, 1)
        if not np.all(scales > 0):
            raise ValueError(f"FormationMotion.scales must be positive, got {scales[:, 0].tolist()}")
        if self.switch_shape is not None:
            shape = np.array(self.switch_shape, dtype=float)
            if shape.ndim != 2 or shape.shape[1] != 2 or not np.all(np.isfinite(shape)):
                raise ValueError(f"FormationMotion.switch_shape must be finite (N, 2) positions, got {shape.shape}")
            if not (math.isfinite(self.switch_time) and self.switch_time >= 0):
                raise ValueError(f"FormationMotion.switch_time must be a finite time ≥ 0 (s), got "
                                 f"{self.switch_time!r}")
            shape.setflags(write=False)
            object.__setattr__(self, "switch_shape", shape)
        if not (math.isfinite(self.switch_duration) and self.switch_duration >= 0):
            raise ValueError(f"FormationMotion.switch_duration must be finite and ≥ 0 (s), got "
                             f"{self.switch_duration!r}")
        object.__setattr__(self, "scale_times", times)
        object.__setattr__(self, "scales", scales[:, 0])
        turn_times, turns = _keyframes("turn_times", "turns", self.turn_times, self.turns, 1)
        path_times, path = _keyframes("path_times", "path", self.path_times, self.path, 2)
        object.__setattr__(self, "turn_times", turn_times)
        object.__setattr__(self, "turns", turns[:, 0])
        object.__setattr__(self, "path_times", path_times)
        object.__setattr__(self, "path", path)
        if self.centre is not None:
            centre = np.array(self.centre, dtype=float).reshape(-1)
            if centre.shape != (2,) or not np.all(np.isfinite(centre)):
                raise ValueError(f"FormationMotion.centre must be a finite point (x, y) in m, got {self.centre!r}")
            centre.setflags(write=False)
            object.__setattr__(self, "centre", centre)
        elif np.any(turns != 0) or np.any(path != 0):
            raise ValueError("FormationMotion: a turn or a path places the shape, so it needs a centre (the point "
                             "its centroid starts at)")

    @property
    def keyframes(self) -> int:
        """The most keyframes any of the motion's three functions of time has (a :class:`MotionTable`'s width)."""
        return max(len(self.scale_times), len(self.turn_times), len(self.path_times))

    def shape(self, start: np.ndarray, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """The desired shape r(t) and its velocity ṙ(t), ``(T, N, 2)`` each, from the formation's realisation
        ``start (N, 2)`` at the times ``t (T,)``."""
        return self._at_times(start, t, MotionTable.shape)

    def placement(self, start: np.ndarray, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """The arms' desired points p*(t) and their velocities, ``(T, N, 2)`` each (the shape itself where the
        motion has no centre)."""
        return self._at_times(start, t, MotionTable.placement)

    def _at_times(self, start: np.ndarray, t: np.ndarray | float, method) -> tuple[np.ndarray, np.ndarray]:
        table = MotionTable(1, len(start), self.keyframes)
        table.load(0, start, self)
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return method(table, t, np.zeros(len(t), dtype=np.int64))


def _interpolate(times: np.ndarray, values: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-linear keyframes ``times (B, K)``, ``values (B, K, D)`` (held before the first and after the
    last) at ``t (B,)``: the values ``(B, D)`` and their rates. One row of keyframes, ``times (K,)`` and
    ``values (K, D)``, serves every time (a binary search, for one motion at many times)."""
    if times.ndim == 1:
        seg = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
        t0, t1, v0, v1 = times[seg], times[seg + 1], values[seg], values[seg + 1]
        first, last, held = times[0], times[-1], values[-1]
    else:
        seg = np.clip((times <= t[:, None]).sum(axis=1) - 1, 0, times.shape[1] - 2)[:, None]
        t0, t1 = np.take_along_axis(times, seg, 1)[:, 0], np.take_along_axis(times, seg + 1, 1)[:, 0]
        v0 = np.take_along_axis(values, seg[..., None], 1)[:, 0]
        v1 = np.take_along_axis(values, seg[..., None] + 1, 1)[:, 0]
        first, last, held = times[:, 0], times[:, -1], values[:, -1]
    inside = ((t >= first) & (t < last))[:, None]
    rate = np.where(inside, (v1 - v0) / (t1 - t0)[:, None], 0.0)
    value = v0 + rate * (np.clip(t, first, last) - t0)[:, None]
    return np.where((t >= last)[:, None], held, value), rate


class MotionTable:
    """The moving shapes of B copies, batched: each copy's keyframes (padded by holding the last), its
    shapes r_A, r_B, its switch and its placement, so that one call gives every copy's target at its own clock."""

    def __init__(self, copies: int, n_arms: int, keyframes: int) -> None:
        K = max(keyframes, 2)
        self.start = np.zeros((copies, n_arms, 2))
        self.end = np.zeros((copies, n_arms, 2))
        self.frames = {name: (np.tile(np.arange(K, dtype=float), (copies, 1)), np.full((copies, K, width), fill))
                       for name, width, fill in (("scale", 1, 1.0), ("turn", 1, 0.0), ("path", 2, 0.0))}
        self.switch = np.tile([math.inf, 0.0], (copies, 1))  # t_s, T_s
        self.centre = np.zeros((copies, 2))
        self.placed = np.zeros(copies, dtype=bool)

    def load(self, b: int, start: np.ndarray, motion: FormationMotion | None) -> None:
        """Copy ``b`` moves as ``motion`` from the realisation ``start (N, 2)`` (None: holds it)."""
        self.start[b] = start
        self.end[b] = start if motion is None or motion.switch_shape is None else motion.switch_shape
        m = FormationMotion(np.zeros(1), np.ones(1)) if motion is None else motion
        for name, times, values in (("scale", m.scale_times, m.scales), ("turn", m.turn_times, m.turns),
                                    ("path", m.path_times, m.path)):
            table_times, table_values = self.frames[name]
            K = table_times.shape[1]
            if len(times) > K:
                raise ValueError(f"a motion with {len(times)} {name} keyframes does not fit this env's {K}")
            values = np.asarray(values, dtype=float).reshape(len(times), -1)
            table_times[b] = np.concatenate([times, times[-1] + 1.0 + np.arange(K - len(times))])
            table_values[b] = np.concatenate([values, np.repeat(values[-1:], K - len(times), axis=0)])
        self.switch[b] = (math.inf, 0.0) if m.switch_shape is None else (m.switch_time, m.switch_duration)
        self.placed[b] = m.centre is not None
        self.centre[b] = 0.0 if m.centre is None else m.centre

    def _at(self, name: str, t: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times, values = self.frames[name]
        if len(rows) > 1 and np.all(rows == rows[0]):  # one copy at many times
            return _interpolate(times[rows[0]], values[rows[0]], t)
        return _interpolate(times[rows], values[rows], t)

    def shape(self, t: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """r(t) and ṙ(t), ``(B, N, 2)``, for each copy at its time ``t (B,)`` (``rows``: the table's rows to use,
        one per time, default all; a row may repeat, to give one copy's shape at several times)."""
        rows = np.arange(len(self.start)) if rows is None else rows
        t = np.asarray(t, dtype=float).reshape(-1)
        s, rate = (x[:, 0] for x in self._at("scale", t, rows))
        t_s, dur = self.switch[rows, 0], self.switch[rows, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.where(dur > 0, np.clip((t - t_s) / dur, 0.0, 1.0), (t >= t_s).astype(float))
            lam_rate = np.where((dur > 0) & (t >= t_s) & (t < t_s + dur), 1.0 / dur, 0.0)
        start, end = self.start[rows], self.end[rows]
        blend = start + lam[:, None, None] * (end - start)
        r = s[:, None, None] * blend
        r_dot = rate[:, None, None] * blend + (s * lam_rate)[:, None, None] * (end - start)
        return r, r_dot

    def placement(self, t: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """p*(t) = c + δ(t) + Rot(θ(t)) (r(t) − r̄(t)) and its velocity, ``(B, N, 2)``, for each copy at its time
        ``t (B,)`` (``rows`` as in :meth:`shape`); r(t) and ṙ(t) for copies without a centre."""
        rows = np.arange(len(self.start)) if rows is None else rows
        t = np.asarray(t, dtype=float).reshape(-1)
        return self._placed(t, rows, *self.shape(t, rows))

    def _placed(self, t: np.ndarray, rows: np.ndarray, r: np.ndarray, r_dot: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`placement` from the shapes ``r`` and ``r_dot`` at those times."""
        placed = self.placed[rows]
        if not placed.any():
            return r, r_dot
        theta, omega = (x[:, 0] for x in self._at("turn", t, rows))
        delta, delta_dot = self._at("path", t, rows)
        c, s = np.cos(theta), np.sin(theta)
        turn = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (B, 2, 2)
        turned = np.einsum("bij,bnj->bni", turn, r - r.mean(axis=1, keepdims=True))
        turned_dot = np.einsum("bij,bnj->bni", turn, r_dot - r_dot.mean(axis=1, keepdims=True))
        spin = omega[:, None, None] * np.stack([-turned[..., 1], turned[..., 0]], axis=-1)  # ω J Rot(θ) (r − r̄)
        point = (self.centre[rows] + delta)[:, None] + turned
        velocity = delta_dot[:, None] + spin + turned_dot
        keep = placed[:, None, None]
        return np.where(keep, point, r), np.where(keep, velocity, r_dot)

    def targets(self, t: np.ndarray, edges: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every copy's desired edge lengths d ``(B, E)`` at its time ``t (B,)``, the feed-forward ṗ_ff
        ``(B, N, 2)`` at its end-effectors ``P (B, N, 2)`` and each arm's distance from its point ``(B, N)`` (zero
        for copies whose shape is not placed)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        r, r_dot = self.shape(t)
        distances, rates = edge_rates(edges, r, r_dot)
        ff = feed_forward(edges, P, np.where(self.placed[:, None], 0.0, rates))
        misplacement = np.zeros(P.shape[:2])
        if self.placed.any():
            point, velocity = self._placed(t, np.arange(len(self.start)), r, r_dot)
            pull = point - P
            distance = np.linalg.norm(pull, axis=-1, keepdims=True)
            speed = np.minimum(PLACEMENT_GAIN * distance, PLACEMENT_SPEED)  # far points: approached at a bounded speed
            ff = np.where(self.placed[:, None, None], velocity + speed * pull / np.maximum(distance, 1e-12), ff)
            misplacement = np.where(self.placed[:, None], distance[..., 0], 0.0)
        return distances, ff, misplacement


def edge_rates(edges: np.ndarray, r: np.ndarray, r_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The desired lengths d ``(B, E)`` of the shapes ``r (B, N, 2)`` and d ⊙ ḋ from their velocities ``r_dot``."""
    dz = r[:, edges[:, 0]] - r[:, edges[:, 1]]
    dz_dot = r_dot[:, edges[:, 0]] - r_dot[:, edges[:, 1]]
    return np.sqrt(np.sum(dz * dz, axis=-1)), np.sum(dz * dz_dot, axis=-1)


def feed_forward(edges: np.ndarray, P: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """ṗ_ff = Rᵀ (R Rᵀ + μ I)⁻¹ (d ⊙ ḋ) ``(B, N, 2)`` at the end-effectors ``P (B, N, 2)`` for the edge rates
    ``rates (B, E)`` = d ⊙ ḋ (zero where every rate is zero)."""
    from .formation import rigidity_matrix

    out = np.zeros(P.shape)
    moving = np.any(rates != 0, axis=1)
    if not moving.any():
        return out
    R = rigidity_matrix(edges, P[moving])  # (B, E, 2N)
    gram = R @ R.transpose(0, 2, 1) + FEED_FORWARD_DAMPING * np.eye(len(edges))
    out[moving] = (R.transpose(0, 2, 1) @ np.linalg.solve(gram, rates[moving][..., None]))[..., 0].reshape(
        -1, *P.shape[1:])
    return out


def align(shape: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``shape (N, 2)`` moved rigidly (turned, and mirrored where that fits better) onto ``reference (N, 2)``
    in the least-squares sense: the same distances, placed so that blending the two shapes moves each
    vertex as little as it can."""
    a, b = shape - shape.mean(0), reference - reference.mean(0)
    best = None
    for mirror in (np.eye(2), np.diag([1.0, -1.0])):
        u, _, vt = np.linalg.svd((a @ mirror).T @ b)
        d = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])
        moved = (a @ mirror) @ (u @ d @ vt) + reference.mean(0)
        err = float(np.sum((moved - reference) ** 2))
        if best is None or err < best[0]:
            best = (err, moved)
    return best[1]


MIN_EDGE = 0.01  # m: the shortest edge a moving shape may ask for (its lengths' errors are relative to it)
BLEND_SAMPLES = 401  # points of a switch's blend at which its rigidity is measured
PLACE_SAMPLES = 33  # points between two keyframes at which a placed shape's reach is checked, at least
MAX_CHECK_TIMES = 500_000  # samples of a placed shape's reach check, at most (about 0.5 GB)
MAX_TURN_RATE = 1.0  # rad/s: the fastest a placed shape may turn
MAX_TARGET_SPEED = 0.5  # m/s: the fastest a moving shape's points may move (faster than its arms can follow)
TURN_STEP = 0.02  # rad: the most a placed shape turns between two of those points (a 1 m arm of it: 50 µm off its arc)
BLEND_RIGIDITY = 0.05  # the blend's σ_{2N−3}(R) may fall to this fraction of the smaller of its two ends'


def _triangle_flips(edges: np.ndarray, start: np.ndarray, end: np.ndarray) -> float | None:
    """The first λ in [0, 1] at which a triangle of the graph (three arms joined pairwise by edges) has zero
    signed area on the blend: the area is a quadratic in λ (each side is linear in it), solved exactly."""
    linked = {tuple(sorted(e)) for e in edges.tolist()}
    first = None
    triangles = [(a, b, c) for (a, b) in linked for c in range(b + 1, len(start))
                 if (a, c) in linked and (b, c) in linked]
    for i, j, k in triangles:
        u0, v0 = start[j] - start[i], start[k] - start[i]
        du, dv = end[j] - end[i] - u0, end[k] - end[i] - v0
        c0 = u0[0] * v0[1] - u0[1] * v0[0]
        c1 = u0[0] * dv[1] - u0[1] * dv[0] + du[0] * v0[1] - du[1] * v0[0]
        c2 = du[0] * dv[1] - du[1] * dv[0]
        roots = np.roots([c2, c1, c0]) if (c2 or c1) else np.empty(0)
        real = roots[np.abs(roots.imag) < 1e-12].real if len(roots) else roots
        inside = real[(real >= 0.0) & (real <= 1.0)]
        if len(inside):
            first = float(inside.min()) if first is None else min(first, float(inside.min()))
    return first


def blend_degenerates(edges: np.ndarray, start: np.ndarray, end: np.ndarray) -> float | None:
    """The first fraction λ of the blend (1 − λ) ``start`` + λ ``end`` (``(N, 2)`` each) at which the edges stop
    holding the shape firmly, or None: a triangle of the graph turning over (its signed area through zero,
    found exactly), or the rigidity matrix's (2N − 3)-th singular value below :data:`BLEND_RIGIDITY` of the
    smaller of the two ends' at one of :data:`BLEND_SAMPLES` points (for graphs whose rigidity is not all
    triangles)."""
    from .formation import rigidity_matrix

    flip = _triangle_flips(edges, start, end)
    rank = max(2 * len(start) - 3, 1)
    lams = np.linspace(0.0, 1.0, BLEND_SAMPLES)
    blends = start + lams[:, None, None] * (end - start)
    sigma = np.linalg.svd(rigidity_matrix(edges, blends), compute_uv=False)[:, rank - 1]
    weak = sigma < BLEND_RIGIDITY * min(sigma[0], sigma[-1])
    sampled = float(lams[np.argmax(weak)]) if weak.any() else None
    found = [lam for lam in (flip, sampled) if lam is not None]
    return min(found) if found else None


def switch_shape(edges: np.ndarray, distances: np.ndarray, start: np.ndarray, tries: int = 20) -> np.ndarray | None:
    """The shape with lengths ``distances`` on ``edges`` to switch to from the realisation ``start (N, 2)``: a
    local search from ``start`` (then from ``start`` perturbed, up to ``tries`` searches), turned onto it
    (:func:`align`), the first whose blend with ``start`` stays rigid (:func:`blend_degenerates`): a graph's
    lengths have several realisations, and the folded ones turn a triangle over on the way. None if none is."""
    from .formation import realise

    rng = np.random.default_rng(0)
    scale = float(np.max(distances))
    for k in range(tries):
        near = start if k == 0 else start + rng.normal(0.0, 0.2 * scale, start.shape)
        shape = realise(edges, distances, len(start), near=near)
        if shape is not None:
            shape = align(shape, start)
            if blend_degenerates(edges, start, shape) is None:
                return shape
    return None


def check_times(motion: FormationMotion, horizon: float) -> np.ndarray:
    """The times within ``[0, horizon]`` at which :func:`check_motion` looks at ``motion``: 0 and the keyframes (a
    length is s(t) times a constant outside the switch, with s linear between keyframes, so its extremes lie there),
    just before each of them (a rate's value at a segment's end), :data:`BLEND_SAMPLES` points of the switch and,
    for a placed shape, at least :data:`PLACE_SAMPLES` points between each two keyframes, no more than
    :data:`TURN_STEP` of turn apart (a turning point moves on an arc). ``ValueError`` past :data:`MAX_CHECK_TIMES`."""
    times = [[0.0], motion.scale_times]
    if motion.switch_shape is not None:
        end = motion.switch_time + motion.switch_duration
        times += [[motion.switch_time, end], np.linspace(motion.switch_time, end, BLEND_SAMPLES)]
    if motion.centre is not None:
        times += [motion.turn_times, motion.path_times]
    knots = np.unique(np.clip(np.concatenate(times), 0.0, horizon))
    times.append(knots[1:] - 1e-9 * np.diff(knots))
    if motion.centre is not None:
        turned = np.abs(np.diff(np.interp(knots, motion.turn_times, motion.turns)))
        counts = np.maximum(PLACE_SAMPLES, np.ceil(turned / TURN_STEP) + 1)
        if counts.sum() > MAX_CHECK_TIMES:
            raise ValueError(f"checking where the placed shape's points go takes {counts.sum():.3g} samples "
                             f"({len(knots)} keyframes, {turned.sum():.3g} rad of turn), more than "
                             f"{MAX_CHECK_TIMES:g}: use fewer keyframes or turn less")
        times += [np.linspace(a, b, n) for a, b, n in zip(knots[:-1], knots[1:], counts.astype(int), strict=True)]
    return np.unique(np.concatenate(times))


def check_motion(motion: FormationMotion, start: np.ndarray, edges: np.ndarray, bases: np.ndarray,
                 reaches: np.ndarray, horizon: float, inner: np.ndarray | None = None) -> None:
    """Raise ``ValueError`` for a motion the team cannot follow from the realisation ``start (N, 2)``: keyframes
    or a switch outside ``[0, horizon]``, a switch shape of the wrong size or one the edges do not hold rigid
    along the blend (:func:`blend_degenerates`), an edge shorter than :data:`MIN_EDGE`, or two arms asked to be
    farther apart than their bases' distance plus their reaches (or closer than their bases' distance minus
    them), at each keyframe and through the switch. The last is necessary, not sufficient: a shape that passes
    may still be out of reach as a whole. A placed shape (``motion.centre``) is also checked arm by arm: every
    arm's point must lie in its workspace, the ring between ``inner`` (default 0) and ``reaches`` around its base,
    at the times of :func:`check_times`. A motion whose points move faster than :data:`MAX_TARGET_SPEED` (about
    their centroid, for a shape that is not placed) or that turns faster than :data:`MAX_TURN_RATE` is refused:
    keyframes too close together."""
    N = len(start)
    for name in ("scale", "turn", "path"):
        end = getattr(motion, f"{name}_times")[-1]
        if end > horizon:
            raise ValueError(f"the {name} keyframes end at {end:g} s, after the episode's {horizon:g} s")
    if motion.switch_shape is not None:
        if motion.switch_shape.shape != (N, 2):
            raise ValueError(f"the switch shape has {motion.switch_shape.shape[0]} vertices for {N} arms")
        if motion.switch_time > horizon:
            raise ValueError(f"the switch at {motion.switch_time:g} s comes after the episode's {horizon:g} s")
        lam = blend_degenerates(edges, start, motion.switch_shape)
        if lam is not None:
            raise ValueError(f"the edges stop holding the shape rigid {lam:.0%} of the way through the switch (a "
                             "triangle of the formation turns over): choose other lengths")
    if motion.centre is not None:  # before sampling the turn (check_times' samples grow with it)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            rates = np.abs(np.diff(motion.turns) / np.diff(motion.turn_times))
        if np.any(~(rates <= MAX_TURN_RATE)):
            m = int(np.argmax(~(rates <= MAX_TURN_RATE)))
            raise ValueError(f"the placed shape turns at {rates[m]:.3g} rad/s from t = {motion.turn_times[m]:g} s, "
                             f"faster than {MAX_TURN_RATE:g} rad/s: spread the turn's keyframes further apart")
    grid = check_times(motion, horizon)
    with np.errstate(over="ignore", invalid="ignore"):  # keyframes too close together: refused just below
        r, r_dot = motion.placement(start, grid)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(r_dot))):
        t = grid[np.argmin(np.all(np.isfinite(r) & np.isfinite(r_dot), axis=(1, 2)))]
        raise ValueError(f"the motion's rate is not finite at t = {t:g} s: two keyframes are too close together")
    # a placed point's own speed; a shape's vertices' speed about their centroid (a rigid drift is no motion of it)
    with np.errstate(over="ignore", invalid="ignore"):
        speed = np.linalg.norm(r_dot if motion.centre is not None else r_dot - r_dot.mean(axis=1, keepdims=True),
                               axis=-1)
    if not speed.max() <= MAX_TARGET_SPEED:
        t = grid[int(np.argmax(speed.max(axis=1)))]
        raise ValueError(f"at t = {t:g} s the moving shape's points move at {speed.max():.3g} m/s, faster than "
                         f"{MAX_TARGET_SPEED:g} m/s: spread its keyframes further apart, or lengthen its switch")
    if motion.centre is not None:
        _check_placed(r, grid, bases, reaches, np.zeros(len(bases)) if inner is None else inner)
        r, _ = motion.shape(start, grid)
    i, j = np.triu_indices(N, 1)
    apart = np.linalg.norm(r[:, i] - r[:, j], axis=-1)  # (T, pairs)
    bases_apart = np.linalg.norm(bases[i] - bases[j], axis=-1)
    far, near = bases_apart + reaches[i] + reaches[j], bases_apart - reaches[i] - reaches[j]
    for bad, bound, word in ((apart > far + 1e-9, far, "farther apart"), (apart < near - 1e-9, near, "closer")):
        if bad.any():
            t, p = np.argwhere(bad)[0]
            raise ValueError(f"at t = {grid[t]:g} s the shape puts arms {i[p]} and {j[p]} {apart[t, p]:.3f} m apart, "
                             f"{word} than their reach allows ({bound[p]:.3f} m from their bases' distance and "
                             f"reaches): no placement of the formation is reachable")
    lengths = np.linalg.norm(r[:, edges[:, 0]] - r[:, edges[:, 1]], axis=-1)
    if (lengths < MIN_EDGE).any():
        t = int(np.argwhere(lengths < MIN_EDGE)[0, 0])
        raise ValueError(f"at t = {grid[t]:g} s an edge of the moving shape is shorter than {MIN_EDGE} m")


def _check_placed(points: np.ndarray, grid: np.ndarray, bases: np.ndarray, outer: np.ndarray,
                  inner: np.ndarray) -> None:
    """Raise ``ValueError`` where an arm's point ``points (T, N, 2)`` at the times ``grid`` leaves its workspace."""
    reach = np.linalg.norm(points - bases, axis=-1)  # (T, N)
    for bad, bound, word in ((reach > outer + 1e-9, outer, "farther from"), (reach < inner - 1e-9, inner, "closer to")):
        if bad.any():
            t, i = np.argwhere(bad)[0]
            raise ValueError(f"at t = {grid[t]:g} s the placed shape puts arm {i}'s point {reach[t, i]:.3f} m from its "
                             f"base, {word} it than the arm reaches ({bound[i]:.3f} m)")
