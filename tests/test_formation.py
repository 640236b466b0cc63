"""Formation graphs, the distance-based errors and rigidity (docs/MODEL.md §4, Eq. 31–39)."""

import itertools

import numpy as np
import pytest

from pan1_env.formation import (
    Formation,
    FormationError,
    SparseIncidence,
    edge_errors,
    edge_length_errors,
    edge_vectors,
    formation_gradient,
    formation_potential,
    incidence_matrix,
    is_connected,
    is_infinitesimally_rigid,
    rigidity_matrix,
)

UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
SQUARE_SIDES = [(0, 1), (1, 2), (2, 3), (0, 3)]


def _potential(edges, d, positions, kp):
    """V = (K_P/2) Σ_k (‖p_i − p_j‖² − d_k²)², written out edge by edge."""
    total = 0.0
    for (i, j), dk in zip(edges, d, strict=True):
        diff = positions[i] - positions[j]
        total += (diff @ diff - dk**2) ** 2
    return 0.5 * kp * total


def _rank_rigid(edges, positions) -> bool:
    """Independent rigidity test: rank of the |E| × 2N matrix of ∂(‖p_i − p_j‖²/2)/∂p."""
    n = len(positions)
    R = np.zeros((len(edges), 2 * n))
    for k, (i, j) in enumerate(edges):
        diff = positions[i] - positions[j]
        R[k, 2 * i : 2 * i + 2] = diff
        R[k, 2 * j : 2 * j + 2] = -diff
    return np.linalg.matrix_rank(R, tol=1e-9) == 2 * n - 3


# --------------------------------------------------------------------------- incidence and errors


def test_incidence_matrix_signs() -> None:
    edges = np.array([[0, 1], [2, 1], [3, 0]])
    B = incidence_matrix(edges, 4)
    expected = np.array(
        [
            [1.0, 0.0, -1.0],
            [-1.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ]
    )
    np.testing.assert_array_equal(B, expected)
    np.testing.assert_array_equal(B.sum(axis=0), 0.0)  # each column: one +1, one −1


def test_edge_vectors_are_kronecker_product() -> None:
    rng = np.random.default_rng(0)
    edges = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])
    B = incidence_matrix(edges, 4)
    p = rng.normal(size=(4, 2))
    z = edge_vectors(B, p)
    # z = (B ⊗ I₂)ᵀ p with p stacked as a 2N vector.
    z_kron = (np.kron(B, np.eye(2)).T @ p.reshape(-1)).reshape(-1, 2)
    np.testing.assert_allclose(z, z_kron, rtol=0, atol=1e-15)
    for k, (i, j) in enumerate(edges):
        np.testing.assert_allclose(z[k], p[i] - p[j], rtol=0, atol=1e-15)
    d = rng.uniform(0.5, 1.5, len(edges))
    np.testing.assert_allclose(
        edge_errors(z, d), [np.sum((p[i] - p[j]) ** 2) - dk**2 for (i, j), dk in zip(edges, d, strict=True)]
    )
    np.testing.assert_allclose(
        edge_length_errors(z, d),
        [np.linalg.norm(p[i] - p[j]) - dk for (i, j), dk in zip(edges, d, strict=True)],
    )
    # batched positions
    pb = rng.normal(size=(3, 4, 2))
    zb = edge_vectors(B, pb)
    for b in range(3):
        np.testing.assert_allclose(zb[b], edge_vectors(B, pb[b]), rtol=0, atol=1e-15)


@pytest.mark.parametrize("n_agents", [3, 4, 6])
def test_e_hat_is_gradient_of_potential(n_agents: int) -> None:
    rng = np.random.default_rng(n_agents)
    shape = "square" if n_agents == 4 else "polygon"
    form = Formation.from_shape(shape, 0.8, n_agents)
    edges, d = form.edges, form.distances
    B = form.incidence
    kp = 1.7
    h = 1e-6
    for _ in range(10):
        p = form.target + rng.normal(scale=0.3, size=(n_agents, 2))
        z = edge_vectors(B, p)
        e = edge_errors(z, d)
        assert formation_potential(e, kp) == pytest.approx(_potential(edges, d, p, kp), rel=1e-12)
        e_hat = formation_gradient(B, z, e)
        grad_fd = np.zeros_like(p)
        for i, c in itertools.product(range(n_agents), range(2)):
            dp = np.zeros_like(p)
            dp[i, c] = h
            v_plus, v_minus = _potential(edges, d, p + dp, kp), _potential(edges, d, p - dp, kp)
            grad_fd[i, c] = (v_plus - v_minus) / (2 * h)
        np.testing.assert_allclose(kp * e_hat, grad_fd, rtol=1e-6, atol=1e-7)
        # Flipping an edge's orientation changes neither e nor ê.
        flipped = edges.copy()
        flipped[0] = flipped[0][::-1]
        B2 = incidence_matrix(flipped, n_agents)
        z2 = edge_vectors(B2, p)
        np.testing.assert_allclose(formation_gradient(B2, z2, edge_errors(z2, d)), e_hat, atol=1e-14)


@pytest.mark.parametrize(("shape", "n_agents"), [("ring", 3), ("ring", 9), ("ring", 33), ("polygon", 6)])
def test_sparse_incidence_gives_the_dense_products(shape: str, n_agents: int) -> None:
    """The law's products from B's non-zeros equal the dense B's, for a batch of positions, with an edge
    flipped, and each vertex's largest edge value equals the largest over the non-zeros of |B|'s row."""
    rng = np.random.default_rng(n_agents)
    edges = Formation.from_shape(shape, 1.0, n_agents).edges.copy()
    edges[0] = edges[0][::-1]
    B, sparse = incidence_matrix(edges, n_agents), SparseIncidence.of(edges, n_agents)
    p = rng.normal(size=(5, n_agents, 2))
    d = rng.uniform(0.5, 1.5, size=len(edges))
    z = edge_vectors(B, p)
    np.testing.assert_allclose(sparse.edge_vectors(p), z, rtol=1e-12, atol=1e-12)
    e = edge_errors(z, d)
    np.testing.assert_allclose(sparse.gradient(z, e), formation_gradient(B, z, e), rtol=1e-12, atol=1e-12)
    values = np.abs(e)
    dense_max = np.array([[values[b][B[i] != 0].max() for i in range(n_agents)] for b in range(5)])
    np.testing.assert_array_equal(sparse.largest_at_vertex(values), dense_max)
    if shape == "ring":  # the products' width is the bounded degree, not N
        assert sparse.arm_edges.shape[1] == min(n_agents - 1, 4)


def test_e_hat_is_distributed() -> None:
    """ê_i depends only on the positions of i and its neighbours."""
    form = Formation.from_shape("polygon", 1.0, 6)
    rng = np.random.default_rng(3)
    p = form.target + rng.normal(scale=0.2, size=(6, 2))
    B = form.incidence

    def e_hat(pos):
        z = edge_vectors(B, pos)
        return formation_gradient(B, z, edge_errors(z, form.distances))

    base = e_hat(p)
    for i in range(6):
        for j in range(6):
            if j == i or j in form.neighbours(i):
                continue
            moved = p.copy()
            moved[j] += rng.normal(size=2)
            np.testing.assert_allclose(e_hat(moved)[i], base[i], rtol=0, atol=1e-14)


# --------------------------------------------------------------------------- rigidity


def test_square_with_diagonal_is_rigid_without_is_not() -> None:
    with_diag = SQUARE_SIDES + [(0, 2)]
    assert is_infinitesimally_rigid(np.array(with_diag), UNIT_SQUARE)
    assert _rank_rigid(with_diag, UNIT_SQUARE)
    assert not is_infinitesimally_rigid(np.array(SQUARE_SIDES), UNIT_SQUARE)
    assert not _rank_rigid(SQUARE_SIDES, UNIT_SQUARE)
    # Scale invariance: a tiny or a huge square is the same graph.
    for s in (1e-3, 1e3):
        assert is_infinitesimally_rigid(np.array(with_diag), s * UNIT_SQUARE)
        assert not is_infinitesimally_rigid(np.array(SQUARE_SIDES), s * UNIT_SQUARE)


def test_rigidity_matrix_matches_hand_rows() -> None:
    edges = np.array([[0, 1], [1, 2]])
    pos = np.array([[0.0, 0.0], [2.0, 1.0], [3.0, -1.0]])
    R = rigidity_matrix(edges, pos)
    expected = np.array(
        [
            [-2.0, -1.0, 2.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0, 2.0, 1.0, -2.0],
        ]
    )
    np.testing.assert_array_equal(R, expected)


def test_collinear_triangle_is_not_infinitesimally_rigid() -> None:
    tri = np.array([[0, 1], [1, 2], [0, 2]])
    assert is_infinitesimally_rigid(tri, np.array([[0.0, 0.0], [1.0, 0.0], [0.3, 0.8]]))
    assert not is_infinitesimally_rigid(tri, np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]))


@pytest.mark.parametrize("n_agents", [3, 4, 5, 6, 7, 8])
def test_polygon_shape_is_rigid_with_2n_minus_3_edges(n_agents: int) -> None:
    size = 0.7
    form = Formation.from_shape("polygon", size, n_agents)
    assert form.n_agents == n_agents
    assert len(form.edges) == 2 * n_agents - 3
    assert len({tuple(sorted(e)) for e in form.edges.tolist()}) == len(form.edges)
    assert is_connected(form.edges, n_agents)
    assert _rank_rigid(form.edges.tolist(), form.target)
    # the realisation has the stated lengths and is a regular polygon of side `size`
    lengths = np.linalg.norm(form.target[form.edges[:, 0]] - form.target[form.edges[:, 1]], axis=1)
    np.testing.assert_allclose(lengths, form.distances, rtol=1e-12)
    sides = [np.linalg.norm(form.target[i] - form.target[(i + 1) % n_agents]) for i in range(n_agents)]
    np.testing.assert_allclose(sides, size, rtol=1e-12)


@pytest.mark.parametrize("n_agents", [2, 3, 4, 5, 6, 7, 8, 16, 32, 33])
def test_ring_has_bounded_degree_and_is_globally_rigid(n_agents: int) -> None:
    """The ring's degree stays at most 4 whatever N, and its distances fix the shape: it is rigid with any one
    edge removed (redundantly rigid) and stays connected with any two arms removed (3-connected), which in the
    plane makes a graph globally rigid (Jackson and Jordán 2005), unlike the polygon's fan, whose triangles can
    fold over a diagonal. Connectivity is scipy's, rigidity the rank of the hand-built matrix above."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    form = Formation.from_shape("ring", 0.7, n_agents)
    edges = form.edges.tolist()
    assert np.bincount(form.edges.ravel(), minlength=n_agents).max() <= min(4, n_agents - 1)
    assert len({tuple(sorted(e)) for e in edges}) == len(edges)
    assert _rank_rigid(edges, form.target)
    if n_agents < 4:
        assert len(edges) == n_agents * (n_agents - 1) // 2  # the complete graph
        return
    assert all(_rank_rigid(edges[:k] + edges[k + 1:], form.target) for k in range(len(edges)))
    for gone in itertools.combinations(range(n_agents), 2):
        kept = [e for e in edges if not set(e) & set(gone)]
        i, j = np.array(kept).T
        graph = coo_matrix((np.ones(len(kept)), (i, j)), shape=(n_agents, n_agents))
        assert connected_components(graph, directed=False)[0] == 1 + len(gone)  # the two removed stand alone
    # every edge joins arms at most two apart around the ring
    assert all(min((i - j) % n_agents, (j - i) % n_agents) <= 2 for i, j in edges)


def test_square_shape_is_the_papers_graph() -> None:
    form = Formation.from_shape("square", 0.7, 4)
    assert {tuple(sorted(e)) for e in form.edges.tolist()} == {(0, 1), (1, 2), (2, 3), (0, 3), (0, 2)}
    for (i, j), d in zip(form.edges.tolist(), form.distances, strict=True):
        expected = 0.7 * np.sqrt(2.0) if {i, j} == {0, 2} else 0.7
        assert d == pytest.approx(expected, rel=1e-12)
    assert sorted(form.neighbours(0)) == [1, 2, 3]
    assert sorted(form.neighbours(1)) == [0, 2]


def test_from_shape_errors() -> None:
    with pytest.raises(FormationError):
        Formation.from_shape("square", 0.7, 3)
    with pytest.raises(FormationError):
        Formation.from_shape("hexagram", 0.7, 6)
    for bad_size in (0.0, -1.0, float("nan")):
        with pytest.raises(FormationError):
            Formation.from_shape("polygon", bad_size, 4)


# --------------------------------------------------------------------------- from_edges


def test_from_edges_realises_a_valid_graph() -> None:
    form = Formation.from_edges([[0, 1], [1, 2], [0, 2]], [3.0, 4.0, 5.0], 3)
    t = form.target
    np.testing.assert_allclose(
        [np.linalg.norm(t[0] - t[1]), np.linalg.norm(t[1] - t[2]), np.linalg.norm(t[0] - t[2])],
        [3.0, 4.0, 5.0],
        rtol=1e-8,
    )
    square = Formation.from_edges(SQUARE_SIDES + [(0, 2)], [1, 1, 1, 1, np.sqrt(2)], 4)
    assert _rank_rigid(square.edges.tolist(), square.target)
    # FormationError is a ValueError (callers may catch either).
    assert issubclass(FormationError, ValueError)


@pytest.mark.parametrize(
    ("edges", "distances", "n_agents", "what"),
    [
        # disconnected: two separate triangles
        ([[0, 1], [1, 2], [0, 2], [3, 4], [4, 5], [3, 5]], [1.0] * 6, 6, "connect"),
        # disconnected: an isolated arm
        ([[0, 1], [1, 2], [0, 2]], [1.0, 1.0, 1.0], 4, "connect"),
        # flexible: the square without its diagonal
        (SQUARE_SIDES, [1.0] * 4, 4, "rigid"),
        # flexible with 2N − 3 edges: K4 plus a pendant arm
        (
            [[0, 1], [1, 2], [2, 3], [0, 3], [0, 2], [1, 3], [3, 4]],
            [1.0, 1.0, 1.0, 1.0, np.sqrt(2), np.sqrt(2), 1.0],
            5,
            "rigid",
        ),
        # unrealisable: triangle inequality broken
        ([[0, 1], [1, 2], [0, 2]], [1.0, 1.0, 5.0], 3, "placement"),
        # out of range indices
        ([[0, 1], [1, 4], [0, 2]], [1.0, 1.0, 1.0], 3, "range"),
        ([[0, 1], [1, -1], [0, 2]], [1.0, 1.0, 1.0], 3, "range"),
        # duplicate edges, same and reversed orientation
        ([[0, 1], [1, 2], [0, 2], [0, 1]], [1.0] * 4, 3, "twice"),
        ([[0, 1], [1, 2], [0, 2], [1, 0]], [1.0] * 4, 3, "twice"),
        # self loop
        ([[0, 1], [1, 1], [0, 2]], [1.0] * 3, 3, "itself"),
        # bad distances
        ([[0, 1], [1, 2], [0, 2]], [1.0, 0.0, 1.0], 3, "positive"),
        ([[0, 1], [1, 2], [0, 2]], [1.0, -1.0, 1.0], 3, "positive"),
        ([[0, 1], [1, 2], [0, 2]], [1.0, float("nan"), 1.0], 3, "positive"),
        ([[0, 1], [1, 2], [0, 2]], [1.0, 1.0], 3, "distances"),
        # malformed edge lists
        ([], [], 3, "pairs"),
        ([[0, 1, 2]], [1.0], 3, "pairs"),
        ([[0.0, 1.0], [1.0, 2.0], [0.0, 2.0]], [1.0] * 3, 3, "integers"),
    ],
)
def test_from_edges_rejects(edges, distances, n_agents, what) -> None:
    with pytest.raises(FormationError) as info:
        Formation.from_edges(edges, distances, n_agents)
    assert what in str(info.value)
