"""Disk obstacles, robust control barrier functions and the safety QP (docs/MODEL.md §5, Eq. 48–61).

For arm i and obstacle j (centre o_j, radius r_j):

    h_ij = ‖p_i − o_j‖² − r_j²,       L_g0 h_ij = 2 (p_i − o_j)ᵀ J̄_i        (a row, 1 × k)

and the robust CBF condition (Eq. 56) with κ(h) = κ h is

    L_g0 h_ij · v ≥ −κ h_ij + (1/ε) ‖L_g0 h_ij‖².

The safety filter (Eq. 60–61) projects a desired velocity v0 onto these half-spaces:

    v* = argmin ½ ‖v − v0‖²   s.t.   A v ≤ b,   A_j = −L_g0 h_ij,   b_j = κ h_ij − ‖L_g0 h_ij‖² / ε.

With tracking error ‖v − v*‖ ≤ δ the arm stays in h ≥ −Γ(δ), Γ(δ) = ε δ² / (4 κ) (Eq. 57); pass
``margin = Γ(δ̄)`` to filter with h − Γ(δ̄) and keep the original set.

Two exact solvers are offered for the per-arm QP, both batched over arms:

* ``"piqp"`` – qpsolvers with the PIQP interior-point solver (the reference);
* ``"active_set"`` – enumeration of the linearly independent active sets, which is exact for the
  few rows and ≤ n−1 unknowns of this problem (even when rows are parallel: rank A ≤ 2 always).

:func:`active_set_projection` is the enumeration in plain numpy: the readable reference of the compiled
QP inside the engine's sub-step (:func:`pan1_env.kernels.qp_project`; batched as here by
:func:`pan1_env.kernels.compiled_projection`, which tests/test_qp_reference.py checks against it). This
module, like the rest of the reference layer, imports nothing compiled.

:class:`FilterParams` holds κ, ε and the margin (and the whole-arm filter's sensing range) as the
envs and the engine take them (:func:`filter_parameters`).

**Barrier choices** (the distance barrier, the tunable robust term, the activation gate, the fault margin) and the
robust margin Γ(δ) are :mod:`pan1_env.barriers`'; this module takes its rows from there and re-exports them.

If the desired velocity already satisfies every row it is the optimum and is returned unchanged.
If the QP is infeasible (or the solver fails) the documented fallback is **braking**: v* = 0, so
q̇ = g0·0 = 0 and no barrier can decrease; the status says so. (A PAn−1 arm whose passive joint still
carries momentum p₁ would keep drifting at q̇ = e₁ p₁ / M_11 if it braked: the engine's end-effector filter
holds its end-effector instead, docs/MODEL.md §7.)
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .barriers import (
    BARRIERS,
    activation_gate,
    cbf_rows,
    fault_rows,
    momentum_rows,
    robust_epsilon,
    robust_margin,
    shaped_barrier,
    torque_rows,
    tracking_bound,
)
from .validation import real

if TYPE_CHECKING:
    from .scenario import Scenario

__all__ = [
    "Obstacles",
    "barrier",
    "clearance",
    "barrier_lie_derivative",
    "robust_margin",
    "tracking_bound",
    "robust_epsilon",
    "shaped_barrier",
    "activation_gate",
    "cbf_rows",
    "fault_rows",
    "momentum_rows",
    "torque_rows",
    "rcbf_constraints",
    "BARRIERS",
    "FALLBACKS",
    "QPStatus",
    "FilterResult",
    "project_velocity",
    "project_with",
    "active_set_projection",
    "QP_SOLVERS",
    "FilterParams",
    "filter_parameters",
    "check_choices",
]

QP_SOLVERS = ("active_set", "piqp")
#: how the whole-arm filter's last resort measures a row's violation (:attr:`FilterParams.fallback`)
FALLBACKS = ("command", "barrier_rate")


@dataclass(frozen=True)
class Obstacles:
    """Disk obstacles: ``centers`` of shape (O, 2) and ``radii`` of shape (O,), metres."""

    centers: np.ndarray
    radii: np.ndarray

    def __post_init__(self) -> None:
        c = np.array(self.centers, dtype=float).reshape(-1, 2)
        r = np.array(self.radii, dtype=float).reshape(-1)
        if c.shape[0] != r.shape[0]:
            raise ValueError(f"Obstacles: {c.shape[0]} centres but {r.shape[0]} radii")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))):
            raise ValueError("Obstacles: centres and radii must be finite")
        if np.any(r <= 0):
            raise ValueError(f"Obstacles: radii must be positive, got {r.tolist()}")
        c.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, "centers", c)
        object.__setattr__(self, "radii", r)

    def __len__(self) -> int:
        return int(self.radii.shape[0])


def barrier(p: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """h = ‖p − o_j‖² − r_j² for positions ``(..., 2)``: shape ``(..., O)``."""
    d = p[..., None, :] - centers
    return np.sum(d * d, axis=-1) - radii**2


_squared_barrier = barrier  # the module-level function, which rcbf_constraints' keyword `barrier` shadows


def clearance(p: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Signed distance ‖p − o_j‖ − r_j to each obstacle's boundary (negative inside): ``(..., O)``."""
    return np.linalg.norm(p[..., None, :] - centers, axis=-1) - radii


def barrier_lie_derivative(p: np.ndarray, Jbar: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """L_g0 h_j = 2 (p − o_j)ᵀ J̄ for ``p (..., 2)`` and ``J̄ (..., 2, k)``: shape ``(..., O, k)``."""
    d = p[..., None, :] - centers
    return 2.0 * np.einsum("...oc,...ck->...ok", d, Jbar)


def rcbf_constraints(
    p: np.ndarray,
    Jbar: np.ndarray,
    centers: np.ndarray,
    radii: np.ndarray,
    kappa: float,
    epsilon: float,
    active: np.ndarray | None = None,
    margin: float = 0.0,
    *,
    barrier: str = "squared",
    decay: float = 0.0,
    gate: tuple[float, float] | None = None,
    speed: float | None = None,
    drift: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The QP rows ``A v ≤ b`` of Eq. 61 and the barrier values used.

    Args:
        p: end-effector positions ``(..., 2)``.
        Jbar: reduced Jacobians ``(..., 2, k)``.
        centers, radii: obstacles ``(O, 2)``, ``(O,)``.
        kappa, epsilon: the class-K gain κ and the robustness parameter ε.
        active: optional boolean mask ``(..., O)``; rows where it is False are switched off
            (A = 0, b = +inf), e.g. obstacles beyond an arm's reach.
        margin: Γ(δ̄) to tighten the set (h − margin replaces h), in the barrier's unit.
        barrier: ``"squared"`` (the paper's h = ‖p − o‖² − r²) or ``"distance"`` (h = ‖p − o‖ − r).
        decay: λ of the tunable ε(h̃) = ε e^{λ h̃} (0: the paper's constant ε).
        gate: ``(on, width)`` of :func:`activation_gate` on the clearance ‖p − o‖ − r (None: every
            obstacle; width 0: a hard range); needs ``speed``, the joint speed bound, see :func:`cbf_rows`.
        drift: the end-effectors' drift ``(..., 2)``, the velocity no command changes: J₁ p₁ / M_11 for a
            PAn−1 arm with passive momentum p₁ (:func:`pan1_env.cascade.end_effector_drift`, docs/MODEL.md
            §7). Its rate ∇h · d joins every b as a known ∂h/∂t. None: no drift (the paper's arm at rest).

    Returns:
        ``A (..., O, k)``, ``b (..., O)``, ``h (..., O)`` (h before tightening, in the chosen form).
    """
    h_sq = barrier_values = _squared_barrier(p, centers, radii)
    Lg = barrier_lie_derivative(p, Jbar, centers)
    rate = 0.0 if drift is None else barrier_lie_derivative(p, np.asarray(drift)[..., None], centers)[..., 0]
    if barrier == "squared" and decay == 0.0 and gate is None:  # the paper's rows, written out
        A = -Lg
        b = kappa * (h_sq - margin) - np.sum(Lg * Lg, axis=-1) / epsilon + rate
    else:
        barrier_values, Lg, rate = shaped_barrier(h_sq, radii, barrier, Lg, rate)
        sigma = None if gate is None else activation_gate(clearance(p, centers, radii), *gate)
        A, b = cbf_rows(barrier_values, Lg, kappa, epsilon, margin, decay, dh_dt=rate, gate=sigma, speed=speed)
    if active is not None:
        A = np.where(active[..., None], A, 0.0)
        b = np.where(active, b, np.inf)
    return A, b, barrier_values


class QPStatus(IntEnum):
    """Outcome of the safety QP for one arm."""

    NOMINAL = 0  #: the desired velocity satisfied every row and was returned unchanged
    SOLVED = 1  #: the QP was solved and its optimum returned
    FALLBACK = 2  #: infeasible or solver failure: braking fallback v* = 0 was returned


class FilterResult(NamedTuple):
    v: np.ndarray  #: filtered velocities ``(B, k)``
    status: np.ndarray  #: ``QPStatus`` per arm ``(B,)``


def _feasible(A: np.ndarray, b: np.ndarray, v: np.ndarray, tol: float) -> np.ndarray:
    lhs = np.einsum("...ok,...k->...o", A, v)
    scale = 1.0 + np.abs(b) + np.linalg.norm(A, axis=-1) * (1.0 + np.linalg.norm(v, axis=-1))[..., None]
    return np.all(lhs <= b + tol * np.where(np.isfinite(scale), scale, 1.0), axis=-1)


#: PIQP's settings for the filter's QP: tight tolerances and low regularisation floors, so that the
#: interior-point answer matches the exact optimum to ~5e-11 on the test problems (degenerate rows
#: included); floors below 1e-14 made PIQP give up on nearly degenerate rows with huge optima.
PIQP_SETTINGS = {"eps_abs": 1e-13, "eps_rel": 1e-13, "eps_duality_gap_abs": 1e-13, "eps_duality_gap_rel": 1e-13,
                 "max_iter": 1000, "reg_lower_limit": 1e-14, "reg_finetune_lower_limit": 1e-14}


def _solve_piqp(v0: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import qpsolvers

    B, m, k = A.shape
    out = np.zeros((B, k))
    found = np.zeros(B, dtype=bool)
    P = np.eye(k)
    for i in range(B):
        keep = np.isfinite(b[i])
        problem = qpsolvers.Problem(P, -v0[i], A[i, keep], b[i, keep])
        try:
            sol = qpsolvers.solve_problem(problem, solver="piqp", **PIQP_SETTINGS)
        except Exception:  # noqa: BLE001 - any solver failure takes the documented fallback
            continue
        if sol.found and sol.x is not None and np.all(np.isfinite(sol.x)):
            out[i] = sol.x
            found[i] = True
    return out, found


# The active-set QP's tolerances, here and in the compiled QP (pan1_env.kernels imports them). An exact
# QP still rounds: a row met to ROW_TOLERANCE counts as met, and a multiplier above −ROW_TOLERANCE as
# non-negative (relative to 1 + |b_j|, 1 + max |λ|). A candidate's final check is looser, so that a
# projection the search accepted is not refused by the rounding of its own product A_j·v.
ROW_TOLERANCE = 1e-12
CANDIDATE_TOLERANCE = 1e-9  # relative to 1 + |b_j| + ‖A_j‖ (1 + ‖v‖)
PIVOT_TOLERANCE = 1e-12  # rows are independent if every pivot of their Gram matrix exceeds this × its top diagonal


def active_set_projection(
    v0: np.ndarray, A: np.ndarray, b: np.ndarray, active: np.ndarray | None = None
) -> FilterResult:
    """Exact v* = argmin ½‖v − v0‖² s.t. A_j v ≤ b_j (rows with ``active``), in numpy, one arm at a time.

    The numpy reference of the compiled :func:`pan1_env.kernels.qp_project`, step for step:

    1. v0 meets every active row (within ``ROW_TOLERANCE``): return it, status NOMINAL.
    2. A zero row with b_j < −ROW_TOLERANCE (0·v ≤ b_j < 0) can never hold: FALLBACK. Other zero
       rows are dropped, and the rest sorted by decreasing normalised violation (A_j v0 − b_j)/‖A_j‖.
    3. For sizes 1..k, every set S of those rows in lexicographic order: if the rows of S are
       independent (Cholesky pivots of G = A_S A_Sᵀ above ``PIVOT_TOLERANCE``), solve the KKT system
       G λ = A_S v0 − b_S; if λ ≥ 0 and the candidate v = v0 − A_Sᵀ λ meets every row (within
       ``CANDIDATE_TOLERANCE``), v satisfies the KKT conditions of this strictly convex QP, so it is
       the unique optimum: status SOLVED. (A feasible QP has an optimum whose active rows include an
       independent set with λ ≥ 0, so the search finds it.)
    4. No set qualifies: infeasible, FALLBACK with the braking velocity v = 0. (So is a feasible QP
       whose optimum needs rows dependent to within PIVOT_TOLERANCE, e.g. a far wedge vertex.)

    Args:
        v0: ``(..., k)`` desired velocities; A ``(..., m, k)``; b ``(..., m)``.
        active: ``(..., m)`` mask of the rows that count; default ``isfinite(b)`` (as project_velocity).

    Returns:
        :class:`FilterResult` with v ``(..., k)`` and the kernel's status codes ``(...)`` (QPStatus).
    """
    v0, A, b = (np.asarray(x, dtype=float) for x in (v0, A, b))
    active = np.isfinite(b) if active is None else np.asarray(active, dtype=bool)
    k, m = v0.shape[-1], A.shape[-2]
    v0s, As, bs, acts = v0.reshape(-1, k), A.reshape(-1, m, k), b.reshape(-1, m), active.reshape(-1, m)
    v, status = np.zeros_like(v0s), np.empty(v0s.shape[0], dtype=np.int64)
    for i in range(v0s.shape[0]):  # one arm at a time: clarity over speed
        v[i], status[i] = _project_arm(v0s[i], As[i][acts[i]], bs[i][acts[i]])
    return FilterResult(v.reshape(v0.shape), status.reshape(v0.shape[:-1]))


def _project_arm(v0: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, QPStatus]:
    """One arm of :func:`active_set_projection`; A ``(m, k)`` and b ``(m,)`` hold its active rows."""
    if not np.any(A @ v0 > b + ROW_TOLERANCE * (1.0 + np.abs(b))):
        return v0.copy(), QPStatus.NOMINAL
    norm2 = np.sum(A * A, axis=1)
    if np.any(~(norm2 > 0.0) & (b < -ROW_TOLERANCE)):
        return np.zeros_like(v0), QPStatus.FALLBACK
    keep = norm2 > 0.0
    A, b, norm = A[keep], b[keep], np.sqrt(norm2[keep])
    order = np.argsort(-(A @ v0 - b) / norm, kind="stable")  # most violated first; ties keep row order
    A, b, norm = A[order], b[order], norm[order]
    for size in range(1, min(len(b), v0.shape[0]) + 1):
        for S in map(list, itertools.combinations(range(len(b)), size)):
            G = A[S] @ A[S].T
            try:
                pivots = np.diag(np.linalg.cholesky(G)) ** 2
            except np.linalg.LinAlgError:
                continue  # not positive definite: dependent rows
            if np.min(pivots) <= PIVOT_TOLERANCE * np.max(np.diag(G)):
                continue
            lam = np.linalg.solve(G, A[S] @ v0 - b[S])
            if np.any(lam < -ROW_TOLERANCE * (1.0 + np.max(np.abs(lam)))):
                continue
            v = v0 - A[S].T @ lam
            slack = CANDIDATE_TOLERANCE * (1.0 + np.abs(b) + norm * (1.0 + np.linalg.norm(v)))
            if not np.any(A @ v > b + slack):
                return v, QPStatus.SOLVED
    return np.zeros_like(v0), QPStatus.FALLBACK


def _solve_active_set(v0: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    result = active_set_projection(v0, A, b)
    return result.v, result.status != QPStatus.FALLBACK


def project_velocity(
    v_desired: np.ndarray, A: np.ndarray, b: np.ndarray, solver: str = "active_set"
) -> FilterResult:
    """Solve v* = argmin ½‖v − v_desired‖² s.t. A v ≤ b for each arm of a batch.

    Args:
        v_desired: ``(B, k)`` desired velocities.
        A, b: ``(B, m, k)`` and ``(B, m)`` rows from :func:`rcbf_constraints` (+inf b = no row).
        solver: ``"active_set"`` (:func:`active_set_projection`, the exact enumeration in numpy) or
            ``"piqp"`` (qpsolvers + PIQP). :func:`pan1_env.kernels.compiled_projection` gives the
            same answers as ``"active_set"``, compiled: several hundred times faster on a batch.

    Returns:
        :class:`FilterResult` with the filtered velocities and a :class:`QPStatus` per arm.
    """
    if solver not in QP_SOLVERS:
        raise ValueError(f"unknown QP solver {solver!r}; choose one of {QP_SOLVERS}")
    return project_with({"active_set": _solve_active_set, "piqp": _solve_piqp}[solver], v_desired, A, b)


def project_with(
    solve: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    v_desired: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
) -> FilterResult:
    """:func:`project_velocity` with any exact solver ``solve(v0, A, b) -> (v, found)`` of a batch:
    the arms whose desired velocity meets every row keep it (NOMINAL); the others get ``solve``'s
    answer (SOLVED), or the braking fallback v = 0 where it found none (FALLBACK)."""
    v_desired = np.asarray(v_desired, dtype=float)
    status = np.full(v_desired.shape[0], int(QPStatus.NOMINAL))
    v = v_desired.copy()
    if A.shape[-2] == 0:
        return FilterResult(v, status)
    nominal_ok = _feasible(A, b, v_desired, 1e-12)
    todo = np.flatnonzero(~nominal_ok)
    if todo.size == 0:
        return FilterResult(v, status)
    sol, found = solve(v_desired[todo], A[todo], b[todo])
    v[todo] = np.where(found[:, None], sol, 0.0)
    status[todo] = np.where(found, int(QPStatus.SOLVED), int(QPStatus.FALLBACK))
    return FilterResult(v, status)


@dataclass(frozen=True)
class FilterParams:
    """The RCBF-QP safety filter's parameters (docs/MODEL.md §5, §5a): κ and ε of the robust barrier
    condition, and ``margin`` subtracted from every barrier h (m² for the squared barrier, m for the
    distance one).

    ``sensing_radius`` (m): None (the paper's filter: an end-effector row for every obstacle in reach),
    or the range within which the whole-arm filter gives a body a row (docs/SCENARIOS.md, *Whole-arm
    safety*; default there :data:`pan1_env.engine.SENSING_RADIUS`, or in torque mode behind its torque bound
    :data:`pan1_env.engine.BRAKING_SENSING_RADIUS`). Given for an end-effector scenario,
    the engine filters through the whole-arm rows with the end-effector as the body: far obstacles then
    hold no arm back.

    ``barrier``: ``"squared"`` (the paper's h = ‖p − o‖² − r²) or ``"distance"`` (h = ‖p − o‖ − r,
    :func:`shaped_barrier`); ``decay``: λ ≥ 0 of the tunable robustness ε(h̃) = ε e^{λ h̃}
    (:func:`robust_epsilon`; 0 is the paper's constant ε). The engine's compiled filter takes both, for
    the end-effector rows and the whole-arm ones (links, other arms, moving obstacles, ``sensing_radius``).

    ``gate`` (m): the width of the smooth activation past the sensing range (:func:`activation_gate`,
    docs/MODEL.md §5, *Activation*): 0 (the default) is a hard range, a row there or not; > 0 relaxes a
    pair's row continuously from whole at the range's edge to none ``gate`` farther out, so that the
    filtered command does not jump when a pair comes into range. It needs the whole-arm rows (whole-arm
    bodies, or a ``sensing_radius``), a finite speed bound, and at least one sub-step's travel (the
    engine checks all three).

    ``fallback``: how the whole-arm filter picks a command when its QP has no solution even without the
    robust term (docs/SCENARIOS.md, *Whole-arm safety*, the fallback): the command that violates every row
    least, measured per unit of the row's norm (``"command"``, the default: a speed of the command), or per
    unit of the barrier's rate (``"barrier_rate"``: m/s of clearance for the distance barrier), which keeps
    a link of short lever from outweighing one that can still get away.

    ``lookahead`` (s): what the whole-arm rows keep out of a moving obstacle: 0 (the default) the disk where it
    is now; T > 0 the capsule of the stretch of its path it covers in the next T s, inf (or a full period or
    more) its whole path, which the filter then treats as a still obstacle (docs/MODEL.md §5b).

    ``fault_margin``: keep every arm able to stop a lost actuator's drift short of the world's obstacles
    (docs/MODEL.md §5c). An arm whose first joint is damped (b > 0, passive now or once it faults) keeps
    h ≥ (reach / b) |p₁| against each world obstacle: while passive as two rows a pair (:func:`fault_rows`), while
    fully actuated by holding its first joint's momentum within b h / reach (:func:`momentum_rows`). It needs the
    distance barrier, a finite speed bound and no gate, and it filters through the whole-arm rows (an end-effector
    scenario with the end-effector as the body, as a ``sensing_radius`` does)."""

    kappa: float
    epsilon: float
    margin: float = 0.0
    sensing_radius: float | None = None
    barrier: str = "squared"
    decay: float = 0.0
    gate: float = 0.0
    fallback: str = "command"
    lookahead: float = 0.0
    fault_margin: bool = False

    def __post_init__(self) -> None:
        checked = _checked("FilterParams", self.kappa, self.epsilon, self.margin, self.sensing_radius, self.barrier,
                           self.decay, self.gate, self.fallback, self.lookahead, self.fault_margin)
        for name, value in zip(("kappa", "epsilon", "margin", "sensing_radius", "barrier", "decay", "gate",
                                "fallback", "lookahead", "fault_margin"), checked, strict=True):
            object.__setattr__(self, name, value)

    @property
    def by_rate(self) -> bool:
        """Whether the whole-arm last resort measures violation by the barrier's rate (``fallback``)."""
        return self.fallback == "barrier_rate"

    @property
    def paper(self) -> bool:
        """The paper's rows: the squared barrier with a constant ε."""
        return self.barrier == "squared" and self.decay == 0.0

    @classmethod
    def of(
        cls,
        scenario: Scenario,
        kappa: float | None = None,
        epsilon: float | None = None,
        margin: float | None = None,
        tracking_bound: float | None = None,
        sensing_radius: float | None = None,
        owner: str = "FilterParams",
        *,
        barrier: str | None = None,
        decay: float | None = None,
        gate: float | None = None,
        fallback: str | None = None,
        lookahead: float | None = None,
        fault_margin: bool | None = None,
    ) -> FilterParams:
        """The scenario's κ, ε, margin, barrier, λ, gate, fallback, look-ahead and fault margin, each replaced where
        given.
        ``tracking_bound`` δ̄ instead of a margin sets it to Γ(δ̄) (:func:`robust_margin`, with the filter's λ), so
        that an arm tracking within δ̄ stays in the original set. Errors name the argument, prefixed by ``owner``
        (the API that took it)."""
        if margin is not None and tracking_bound is not None:
            raise ValueError(f"{owner}: give margin or tracking_bound, not both")
        own = scenario.filter
        kappa, epsilon, margin, sensing_radius, barrier, decay, gate, fallback, lookahead, fault_margin = _checked(
            owner,
            own.kappa if kappa is None else kappa,
            own.epsilon if epsilon is None else epsilon,
            own.margin if margin is None else margin,
            own.sensing_radius if sensing_radius is None else sensing_radius,
            own.barrier if barrier is None else barrier,
            own.decay if decay is None else decay,
            own.gate if gate is None else gate,
            own.fallback if fallback is None else fallback,
            own.lookahead if lookahead is None else lookahead,
            own.fault_margin if fault_margin is None else fault_margin,
        )
        if tracking_bound is not None:
            delta = real(f"{owner}: tracking_bound", tracking_bound, non_negative=True)
            margin = robust_margin(delta, kappa, epsilon, decay)
        return cls(kappa, epsilon, margin, sensing_radius, barrier, decay, gate, fallback, lookahead, fault_margin)


def _checked(
    owner: str, kappa: float, epsilon: float, margin: float, sensing_radius: float | None, barrier: str = "squared",
    decay: float = 0.0, gate: float = 0.0, fallback: str = "command", lookahead: float = 0.0,
    fault_margin: bool = False,
) -> tuple[float, float, float, float | None, str, float, float, str, float, bool]:
    """The filter's parameters as floats (the barrier a name of :data:`BARRIERS`, the fallback one of
    :data:`FALLBACKS`, the fault margin a bool), or a ValueError naming the first bad one."""
    if not isinstance(barrier, str) or barrier not in BARRIERS:
        raise ValueError(f"{owner}: barrier must be one of {BARRIERS}, got {barrier!r}")
    if not isinstance(fallback, str) or fallback not in FALLBACKS:
        raise ValueError(f"{owner}: fallback must be one of {FALLBACKS}, got {fallback!r}")
    if not isinstance(fault_margin, (bool, np.bool_)):
        raise ValueError(f"{owner}: fault_margin must be True or False, got {fault_margin!r}")
    return (
        real(f"{owner}: kappa", kappa, positive=True),
        real(f"{owner}: epsilon", epsilon, positive=True),
        real(f"{owner}: margin", margin, non_negative=True),
        None if sensing_radius is None else real(f"{owner}: sensing_radius", sensing_radius, positive=True),
        barrier,
        real(f"{owner}: decay", decay, non_negative=True),
        real(f"{owner}: gate", gate, non_negative=True),
        fallback,
        real(f"{owner}: lookahead", lookahead, non_negative=True, allow_inf=True),
        bool(fault_margin),
    )


def check_choices(params: FilterParams, whole_arm: bool, max_speed: float, reach: float, physics_dt: float) -> None:
    """The filter's choices that act on the whole-arm rows, checked against the engine that would apply them (an
    arm of ``reach`` m at most, its speed bound ``max_speed`` rad/s, its sub-step ``physics_dt`` s): ValueError
    naming the first that would do nothing or could not work.

    - ``fallback`` other than ``"command"`` measures the whole-arm last resort (the end-effector filter brakes,
      or holds a drifting end-effector, instead);
    - ``lookahead`` > 0 shapes the whole-arm rows (the end-effector filter sees obstacles where they are);
    - ``gate`` > 0 widens the whole-arm rows' sensing range, relaxes rows towards the speed box, and is a gate only
      if it is wider than what a body covers in a sub-step (its far end turning at ``max_speed``; docs/MODEL.md
      §5, *Activation*);
    - ``fault_margin`` is written for the distance barrier, bounds the momentum the speed box allows, and has no
      gate (its range is the margin's own)."""
    if params.fault_margin and (params.barrier != "distance" or not np.isfinite(max_speed) or params.gate > 0.0):
        raise ValueError("FilterParams.fault_margin needs barrier='distance', a finite max_joint_speed and gate=0, got "
                         f"barrier={params.barrier!r}, max_joint_speed={max_speed:g}, gate={params.gate:g}")
    rows = whole_arm or params.sensing_radius is not None or params.fault_margin
    if params.fallback != "command" and not rows:
        raise ValueError(f"FilterParams.fallback={params.fallback!r} measures the whole-arm filter's last resort: "
                         "it needs whole-arm bodies or a sensing_radius (the end-effector filter brakes instead)")
    if params.lookahead > 0 and not rows:
        raise ValueError(f"FilterParams.lookahead={params.lookahead:g} shapes the whole-arm filter's rows: it needs "
                         "whole-arm bodies or a sensing_radius (the end-effector filter sees obstacles where they are)")
    if params.gate == 0.0:
        return
    if not rows:
        raise ValueError("FilterParams.gate widens a sensing range: it needs whole-arm bodies or a sensing_radius")
    if not np.isfinite(max_speed):
        raise ValueError("FilterParams.gate relaxes rows towards the speed box: it needs a finite max_joint_speed")
    travel = max_speed * reach * physics_dt
    if params.gate < travel:
        raise ValueError(f"FilterParams.gate must be 0 (a hard range) or at least one sub-step's travel, "
                         f"{travel:.4g} m (max_speed {max_speed:g} rad/s × reach {reach:.3g} m × physics_dt "
                         f"{physics_dt:g} s), got {params.gate:g}")


def filter_parameters(safety_filter: bool | FilterParams | None, scenario: Scenario) -> FilterParams | None:
    """The ``safety_filter`` argument every env takes: ``False`` (off), ``True`` (on, the scenario's
    κ, ε and margin) or a :class:`FilterParams`. Returns the parameters, or None when off."""
    if safety_filter is None or safety_filter is False:
        return None
    if safety_filter is True:
        return scenario.filter
    if isinstance(safety_filter, FilterParams):
        return safety_filter
    raise ValueError(f"safety_filter must be False, True or a FilterParams, got {safety_filter!r}")
