"""Formation graphs and the distance-based formation errors (docs/MODEL.md §4, the paper's Eq. 31–39).

A formation is an undirected graph on the arms' end-effectors with a desired length d_k per edge.
Edge k = (i, j) has the incidence column +1 at i and −1 at j, so ``z_k = p_i − p_j``, and

    e_k = ‖z_k‖² − d_k²,     V(e) = (K_P / 2) Σ_k e_k²,     ê_i = Σ_k B_ik · 2 z_k e_k.

Arms are numbered from 0 here (the paper numbers from 1). The graph must be infinitesimally rigid
for the distances to fix the shape up to a rigid motion; :class:`Formation` checks that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Formation",
    "FormationError",
    "incidence_matrix",
    "SparseIncidence",
    "edge_vectors",
    "edge_errors",
    "edge_length_errors",
    "formation_potential",
    "formation_gradient",
    "rigidity_matrix",
    "is_infinitesimally_rigid",
    "is_connected",
    "shape_positions",
    "realise",
    "SHAPES",
    "RING_DEGREE",
    "most_neighbours",
    "ring_neighbours",
]

SHAPES = ("square", "polygon", "ring")
RING_DEGREE = 4  # a ring arm's neighbours: the two nearest on each side


class FormationError(ValueError):
    """A formation graph that cannot define a rigid shape (disconnected, flexible, unrealisable)."""


def incidence_matrix(edges: np.ndarray, n_agents: int) -> np.ndarray:
    """Incidence matrix B (N × |E|): column k has +1 at edge k's first vertex, −1 at its second."""
    edges = np.asarray(edges, dtype=int).reshape(-1, 2)
    B = np.zeros((n_agents, len(edges)))
    B[edges[:, 0], np.arange(len(edges))] = 1.0
    B[edges[:, 1], np.arange(len(edges))] = -1.0
    return B


@dataclass(frozen=True, eq=False)
class SparseIncidence:
    """B by its non-zeros, for teams whose graph has bounded degree D: the products below cost O(N·D) per
    copy where the dense B's cost O(N·|E|), which for a ring grows as N². ``arm_edges (N, D)`` lists each
    vertex's edges (padded with the index |E| of an edge that is always zero) and ``signs (N, D)`` their
    B_ik (0 for the padding)."""

    edges: np.ndarray
    arm_edges: np.ndarray
    signs: np.ndarray

    @classmethod
    def of(cls, edges: np.ndarray, n_agents: int) -> SparseIncidence:
        """From the edge list ``(|E|, 2)`` of ``n_agents`` vertices."""
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        touching = [[(k, 1.0) for k in np.flatnonzero(edges[:, 0] == i)] +
                    [(k, -1.0) for k in np.flatnonzero(edges[:, 1] == i)] for i in range(n_agents)]
        D = max(1, max(len(t) for t in touching))
        arm_edges, signs = np.full((n_agents, D), len(edges), dtype=np.int64), np.zeros((n_agents, D))
        for i, t in enumerate(touching):
            arm_edges[i, :len(t)] = [k for k, _ in t]
            signs[i, :len(t)] = [sign for _, sign in t]
        return cls(edges, arm_edges, signs)

    def edge_vectors(self, positions: np.ndarray) -> np.ndarray:
        """:func:`edge_vectors`: z_k = p_i − p_j for edge k = (i, j)."""
        return positions[..., self.edges[:, 0], :] - positions[..., self.edges[:, 1], :]

    def gradient(self, z: np.ndarray, e: np.ndarray) -> np.ndarray:
        """:func:`formation_gradient`: ê_i = Σ_k B_ik 2 z_k e_k."""
        w = 2.0 * z * e[..., None]
        w = np.concatenate([w, np.zeros_like(w[..., :1, :])], axis=-2)
        return np.sum(w[..., self.arm_edges, :] * self.signs[:, :, None], axis=-2)

    def largest_at_vertex(self, values: np.ndarray) -> np.ndarray:
        """Each vertex's largest of its edges' ``values (..., |E|)`` (≥ 0), 0 for a vertex with none:
        ``(..., N)``."""
        padded = np.concatenate([values, np.zeros_like(values[..., :1])], axis=-1)
        return np.max(padded[..., self.arm_edges], axis=-1, initial=0.0)


def edge_vectors(B: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """z = (B ⊗ I₂)ᵀ p: ``(..., N, 2)`` positions to ``(..., |E|, 2)`` edge vectors."""
    return np.einsum("ik,...ic->...kc", B, positions)


def edge_errors(z: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """e_k = ‖z_k‖² − d_k²."""
    return np.sum(z * z, axis=-1) - distances**2


def edge_length_errors(z: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """‖z_k‖ − d_k in metres (what the paper's figures plot)."""
    return np.linalg.norm(z, axis=-1) - distances


def formation_potential(e: np.ndarray, kp: float) -> np.ndarray:
    """V(e) = (K_P / 2) Σ_k e_k²."""
    return 0.5 * kp * np.sum(e * e, axis=-1)


def formation_gradient(B: np.ndarray, z: np.ndarray, e: np.ndarray) -> np.ndarray:
    """ê_i = Σ_k B_ik 2 z_k e_k, so that ∂V/∂p_i = K_P ê_i; shape ``(..., N, 2)``."""
    return np.einsum("ik,...kc->...ic", B, 2.0 * z * e[..., None])


def rigidity_matrix(edges: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Rigidity matrix R (|E| × 2N): row k holds z_kᵀ at vertex i and −z_kᵀ at vertex j; for positions
    ``(..., N, 2)``, one per leading index, ``(..., |E|, 2N)``."""
    edges = np.asarray(edges, dtype=int).reshape(-1, 2)
    positions = np.asarray(positions, dtype=float)
    lead, n, k = positions.shape[:-2], positions.shape[-2], np.arange(len(edges))
    R = np.zeros((*lead, len(edges), n, 2))
    z = positions[..., edges[:, 0], :] - positions[..., edges[:, 1], :]
    R[..., k, edges[:, 0], :] = z
    R[..., k, edges[:, 1], :] = -z
    return R.reshape(*lead, len(edges), 2 * n)


def is_infinitesimally_rigid(edges: np.ndarray, positions: np.ndarray, tol: float = 1e-9) -> bool:
    """True when rank R = 2N − 3 at these positions (planar, N ≥ 2)."""
    positions = np.asarray(positions, dtype=float)
    n = positions.shape[0]
    if n < 2:
        return True
    R = rigidity_matrix(edges, positions)
    if R.size == 0:
        return False
    s = np.linalg.svd(R, compute_uv=False)
    # R's entries are edge vectors: the threshold scales with the longest edge, not with the team's extent,
    # which grows with N while a ring's smallest singular value shrinks (about 1e-5 of its edge at 256 arms)
    edges = np.asarray(edges, dtype=int).reshape(-1, 2)
    scale = max(float(np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=-1).max()), 1e-12)
    rank = int(np.sum(s > tol * scale * max(s.size, 1)))
    return rank == 2 * n - 3


def is_connected(edges: np.ndarray, n_agents: int) -> bool:
    """True when the undirected graph reaches every vertex from vertex 0."""
    edges = np.asarray(edges, dtype=int).reshape(-1, 2)
    seen = {0}
    frontier = [0]
    neighbours: dict[int, list[int]] = {i: [] for i in range(n_agents)}
    for i, j in edges:
        neighbours[int(i)].append(int(j))
        neighbours[int(j)].append(int(i))
    while frontier:
        i = frontier.pop()
        for j in neighbours[i]:
            if j not in seen:
                seen.add(j)
                frontier.append(j)
    return len(seen) == n_agents


def shape_positions(shape: str, size: float, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and edges of a named shape of side ``size``.

    ``square``: 4 vertices, the 4 sides plus the diagonal (0, 2) (the paper's graph, Eq. 67).
    ``polygon``: a regular N-gon, its N sides plus the fan of diagonals from vertex 0 (2N − 3 edges,
    infinitesimally rigid; vertex 0 has N − 1 neighbours).
    ``ring``: the same N-gon, its sides plus the chords that skip one vertex (i, i + 2): the square of the cycle,
    2N edges from N = 5 (the complete graph up to N = 4), no vertex with more than :data:`RING_DEGREE` neighbours
    whatever N, each edge local (an arm's nearest two on each side), and rigid with every single edge removed
    (tests/test_formation.py checks both up to N = 33). Vertex i is agent i.
    """
    if shape == "square":
        if n_agents != 4:
            raise FormationError(f"shape 'square' needs exactly 4 arms, got {n_agents}")
        pos = size * np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        edges = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])
        return pos, edges
    if shape in ("polygon", "ring"):
        if n_agents < 2:
            raise FormationError(f"shape {shape!r} needs at least 2 arms, got {n_agents}")
        if n_agents == 2:
            return np.array([[0.0, 0.0], [size, 0.0]]), np.array([[0, 1]])
        radius = size / (2.0 * np.sin(np.pi / n_agents))
        ang = 2.0 * np.pi * np.arange(n_agents) / n_agents
        pos = radius * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        sides = [[i, (i + 1) % n_agents] for i in range(n_agents)]
        if shape == "polygon":
            return pos, np.array(sides + [[0, j] for j in range(2, n_agents - 1)])
        # chords (i, i + 2), each once: N of them from 5 arms; for 4 arms the two diagonals; for 3 arms none (the
        # sides already join every pair)
        n_chords = n_agents if n_agents > 4 else (2 if n_agents == 4 else 0)
        chords = [[i, (i + 2) % n_agents] for i in range(n_chords)]
        return pos, np.array(sides + chords)
    raise FormationError(f"unknown formation shape {shape!r}; choose one of {SHAPES}")


def most_neighbours(shape: str, n_agents: int) -> int:
    """The most neighbours ``shape``'s graph gives an arm of an ``n_agents`` team: a ring's
    :data:`RING_DEGREE` whatever N (so that an observation's neighbour slots do not depend on the team's size),
    a polygon's or a square's N − 1 (the fan's arm 0)."""
    if shape not in SHAPES:
        raise FormationError(f"unknown formation shape {shape!r}; choose one of {SHAPES}")
    return RING_DEGREE if shape == "ring" else n_agents - 1


def ring_neighbours(i: int, n_agents: int) -> list[int]:
    """Arm i's neighbours on the ring in the one order every arm lists them: one back, one forward, two back,
    two forward (those the team has), so that a neighbour slot means the same for every arm."""
    offsets = [-1, 1, -2, 2][: min(RING_DEGREE, n_agents - 1)]
    return [(i + d) % n_agents for d in offsets]


def realise(edges: np.ndarray, distances: np.ndarray, n_agents: int, near: np.ndarray | None = None
            ) -> np.ndarray | None:
    """Planar positions ``(N, 2)`` whose edge lengths equal ``distances`` (None if none is found): with ``near``
    the one a local search finds from those positions first (a graph's distances can have several
    realisations, e.g. a triangle folded over a shared edge; this keeps the one next to ``near``)."""
    from scipy.optimize import least_squares

    def residual(x: np.ndarray) -> np.ndarray:
        p = x.reshape(n_agents, 2)
        return np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=-1) - distances

    scale = float(distances.max())
    rng = np.random.default_rng(0)
    starts = [] if near is None else [np.asarray(near, dtype=float).ravel()]
    for _ in range(20):
        x0 = starts.pop() if starts else rng.uniform(-scale, scale, 2 * n_agents)
        sol = least_squares(residual, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        if np.max(np.abs(sol.fun)) < 1e-9 * scale:
            return sol.x.reshape(n_agents, 2)
    return None


@dataclass(frozen=True)
class Formation:
    """A rigid formation: edges between arms (0-based), desired lengths, and one realisation.

    Build it with :meth:`from_shape` or :meth:`from_edges`; both check that the graph is connected,
    that the distances can be realised in the plane and that the realisation is infinitesimally
    rigid, raising :class:`FormationError` otherwise.
    """

    edges: np.ndarray  # (E, 2) int
    distances: np.ndarray  # (E,)
    target: np.ndarray  # (N, 2): one realisation of the shape (for rendering and checks)

    @property
    def n_agents(self) -> int:
        return int(self.target.shape[0])

    @property
    def incidence(self) -> np.ndarray:
        return incidence_matrix(self.edges, self.n_agents)

    def neighbours(self, i: int) -> list[int]:
        """Arms sharing an edge with arm ``i`` (in edge order)."""
        out = []
        for a, b in self.edges:
            if a == i:
                out.append(int(b))
            elif b == i:
                out.append(int(a))
        return out

    @classmethod
    def from_shape(cls, shape: str, size: float, n_agents: int) -> Formation:
        if not (np.isfinite(size) and size > 0):
            raise FormationError(f"formation size must be positive, got {size!r}")
        pos, edges = shape_positions(shape, float(size), n_agents)
        d = np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=-1)
        return cls._checked(edges, d, pos)

    @classmethod
    def from_edges(
        cls, edges: Sequence[Sequence[int]], distances: Sequence[float], n_agents: int
    ) -> Formation:
        e = np.asarray(edges)
        if e.ndim != 2 or e.shape[1] != 2 or e.shape[0] == 0 or not np.issubdtype(e.dtype, np.integer):
            raise FormationError("edges must be a non-empty list of [i, j] pairs of integers")
        d = np.asarray(distances, dtype=float)
        if d.shape != (e.shape[0],):
            raise FormationError(f"got {e.shape[0]} edges but {d.size} distances")
        if np.any(e < 0) or np.any(e >= n_agents):
            raise FormationError(
                f"edge index out of range: arms are numbered 0..{n_agents - 1}, got {e.tolist()}"
            )
        if np.any(e[:, 0] == e[:, 1]):
            raise FormationError("an edge joins an arm to itself")
        if len({tuple(sorted(p)) for p in e.tolist()}) != len(e):
            raise FormationError("an edge is listed twice")
        if not np.all(np.isfinite(d)) or np.any(d <= 0):
            raise FormationError(f"distances must be positive, got {d.tolist()}")
        pos = realise(e, d, n_agents) if is_connected(e, n_agents) else None
        if pos is None and is_connected(e, n_agents):
            raise FormationError(
                f"no planar placement of the arms realises the distances {d.tolist()} "
                f"on edges {e.tolist()}"
            )
        return cls._checked(e, d, pos if pos is not None else np.zeros((n_agents, 2)))

    @classmethod
    def _checked(cls, edges: np.ndarray, d: np.ndarray, pos: np.ndarray) -> Formation:
        n = pos.shape[0]
        if not is_connected(edges, n):
            raise FormationError(f"the formation graph {edges.tolist()} does not connect all {n} arms")
        if not is_infinitesimally_rigid(edges, pos):
            raise FormationError(
                f"the formation graph {edges.tolist()} is not infinitesimally rigid: the distances do "
                f"not fix the shape (a planar graph on {n} arms needs at least {max(2 * n - 3, 1)} "
                "well-placed edges, e.g. a square needs a diagonal)"
            )
        edges, d, pos = np.array(edges, dtype=int), np.array(d, dtype=float), np.array(pos, float)
        for arr in (edges, d, pos):
            arr.setflags(write=False)
        return cls(edges=edges, distances=d, target=pos)
