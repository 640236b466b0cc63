"""Barrier choices of the safety filter (docs/MODEL.md §5, §5a, §5c): the numpy specification the compiled filter
is tested against. Every protected pair (end-effector–obstacle, link–obstacle, link–link) has a distance d ≥ 0 to
keep above a radius R (r, r + ρ or 2ρ):

* barrier ``"squared"`` (the paper's): h = d² − R², its row 2 d ∇d g0;
* barrier ``"distance"``: h = d − R (metres, ‖∇_p h‖ = 1), its row ∇d g0 (:func:`shaped_barrier`);
* robust term ‖L_g0 h‖² / ε(h̃) with ε(h̃) = ε e^{λ h̃} (:func:`robust_epsilon`; λ = 0 is the paper's
  constant ε; a tunable ISSf term after Alan, Taylor, He, Orosz & Ames, arXiv 2103.08041);
* activation: every pair, a hard range, or a smooth gate σ(clearance) that relaxes a row before it
  drops it (:func:`activation_gate`, :func:`cbf_rows`);
* the fault margin: a passive arm's barrier less the drift its damped momentum can still bring
  (:func:`fault_rows`), and a fully actuated arm's momentum kept within what it could stop if it lost an
  actuator (:func:`momentum_rows`).

:func:`robust_margin` Γ(δ) and :func:`tracking_bound` δ̄(margin) hold for each choice. :mod:`pan1_env.safety`
builds the filter's rows from these.
"""

from __future__ import annotations

import numpy as np

from .validation import real

__all__ = ["BARRIERS", "robust_margin", "tracking_bound", "robust_epsilon", "shaped_barrier", "activation_gate",
           "cbf_rows", "fault_rows", "momentum_rows", "torque_rows"]

#: the barrier forms of :func:`shaped_barrier`: the paper's squared distance, or the distance itself
BARRIERS = ("squared", "distance")


def robust_margin(delta: float, kappa: float, epsilon: float, decay: float = 0.0, arms: int = 1) -> float:
    """Γ(δ): how far below zero a tracking error ‖v − v*‖ ≤ δ can push the filtered barrier h̃ = h − margin
    (Eq. 57, docs/MODEL.md §5). In the barrier's own unit (m² squared, m distance).

    On a row, ḣ̃ = L_g0 h · (v* + ẽ) ≥ −κ h̃ + ‖L_g0 h‖²/ε(h̃) − ‖L_g0 h‖ δ ≥ −κ h̃ − ε(h̃) δ²/4 (the
    square completed in ‖L_g0 h‖), whatever the row's gradient and so whatever the barrier's form.
    ε(h̃) = ε e^{λ h̃} (``decay`` λ, :func:`robust_epsilon`) is increasing, so ḣ̃ ≥ 0 wherever
    κ (−h̃) ≥ ε e^{λ h̃} δ²/4, i.e. below h̃ = −Γ with

        κ Γ e^{λ Γ} = arms · ε δ² / 4,     Γ = W(λ · arms · ε δ² / (4 κ)) / λ    (Lambert W; λ → 0: arms · ε δ²/(4κ))

    and {h̃ ≥ −Γ} is forward invariant. ``arms`` is how many arms' tracking errors act on the row: 2 for
    an inter-arm row that both arms filter with half the rate each (each brings its own −ε δ²/4)."""
    delta, kappa, epsilon, decay = float(delta), float(kappa), float(epsilon), _decay("robust_margin", decay, arms)
    x = arms * epsilon * delta**2 / (4.0 * kappa)
    if decay == 0.0 or x == 0.0:
        return x
    from scipy.special import lambertw  # here, not at import: scipy.special costs `import pan1_env` time

    return float(lambertw(decay * x).real) / decay


def tracking_bound(margin: float, kappa: float, epsilon: float, decay: float = 0.0, arms: int = 1) -> float:
    """δ̄: the largest tracking error that a filter with ``margin`` still keeps out of the obstacles (h ≥ 0),
    the inverse of :func:`robust_margin`: Γ(δ̄) = margin gives δ̄ = 2 √(κ · margin · e^{λ · margin} / (arms · ε)).
    A tracking error δ ≤ δ̄ keeps h̃ ≥ −Γ(δ) ≥ −margin, so h = h̃ + margin ≥ 0."""
    margin, kappa, epsilon, decay = float(margin), float(kappa), float(epsilon), _decay("tracking_bound", decay, arms)
    return 2.0 * float(np.sqrt(kappa * margin * np.exp(decay * margin) / (arms * epsilon)))


def _decay(owner: str, decay: float, arms: int) -> float:
    """λ as a float, refused below 0: Γ's formula needs an ε(h̃) that does not fall as h̃ grows."""
    if isinstance(arms, bool) or not isinstance(arms, (int, np.integer)) or arms < 1:
        raise ValueError(f"{owner}: arms must be an integer ≥ 1, got {arms!r}")
    return real(f"{owner}: decay", decay, non_negative=True)


def robust_epsilon(h: np.ndarray, epsilon: float, decay: float = 0.0) -> np.ndarray:
    """The tunable robustness ε(h̃) = ε e^{λ h̃} (λ = ``decay`` ≥ 0, in the barrier's inverse unit).

    At the set's edge (h̃ = 0) it is the paper's ε; far inside it grows, so the robust term
    ‖L_g0 h‖²/ε(h̃) fades where the class-K term κ h̃ already keeps the row slack (Alan et al., arXiv
    2103.08041, use this exponential as their example of an increasing tuning function). λ = 0 is the
    paper's constant ε. The exponent is capped so that far rows give a finite ε (then 1/ε ≈ 0)."""
    return epsilon * np.exp(np.minimum(decay * np.asarray(h, dtype=float), 700.0))


def shaped_barrier(h_squared: np.ndarray, radius: np.ndarray | float, barrier: str,
                   *derivatives: np.ndarray) -> tuple[np.ndarray, ...]:
    """A squared barrier h = d² − R² and its derivatives (rows L_g0 h, ∂h/∂t, each ``(..., k)`` or
    ``(...)``) in the chosen form: ``"squared"`` returns them unchanged; ``"distance"`` returns
    h = d − R with d = √(h + R²) and every derivative divided by 2d (∂d = ∂(d²)/(2d)).

    The distance barrier has ‖∇_p h‖ = 1 for the body's point p, so its row ‖L_g0 h‖ = ‖J̄ᵀ n‖ stays
    bounded by the arm's reach while κ h grows with d: far pairs stop binding (the squared barrier's
    row and κ h both grow like d²). Its gradient is undefined at d = 0 (the body's point on the
    obstacle's centre or segment, deep inside); there the rows are 0 and h = −R.

    ``radius`` broadcasts against ``h_squared``. Returns ``(h, *derivatives)``."""
    if barrier not in BARRIERS:
        raise ValueError(f"unknown barrier {barrier!r}; choose one of {BARRIERS}")
    h_squared = np.asarray(h_squared, dtype=float)
    if barrier == "squared":
        return (h_squared, *(np.asarray(x, dtype=float) for x in derivatives))
    radius = np.asarray(radius, dtype=float)
    d = np.sqrt(np.maximum(h_squared + radius**2, 0.0))
    inv = np.where(d > 0.0, 0.5 / np.where(d > 0.0, d, 1.0), 0.0)
    out = []
    for x in derivatives:
        x = np.asarray(x, dtype=float)
        out.append(x * (inv[..., None] if x.ndim > inv.ndim else inv))
    return (d - radius, *out)


def activation_gate(clearance: np.ndarray, on: float, width: float) -> np.ndarray:
    """The smooth activation σ ∈ [0, 1] of a row by its pair's clearance c (m):

        σ = 1 for c ≤ on,   σ = 0 for c ≥ on + width,   σ = 1 − (3 s² − 2 s³), s = (c − on)/width, between

    (C¹: the cubic's slope vanishes at both ends, its steepest is 1.5/width). ``width`` = 0 is a hard
    range (σ = 1 up to ``on``, then 0). What :func:`cbf_rows` does with σ, and why rows it relaxes
    cannot be violated: docs/MODEL.md §5, *Activation*."""
    on = real("activation_gate: on", on, non_negative=True)
    width = real("activation_gate: width", width, non_negative=True)
    c = np.asarray(clearance, dtype=float)
    if width == 0.0:
        return np.where(c <= on, 1.0, 0.0)
    s = np.clip((c - on) / width, 0.0, 1.0)
    return 1.0 - s * s * (3.0 - 2.0 * s)


def cbf_rows(
    h: np.ndarray,
    row: np.ndarray,
    kappa: float,
    epsilon: float,
    margin: float = 0.0,
    decay: float = 0.0,
    dh_dt: np.ndarray | float = 0.0,
    share: np.ndarray | float = 1.0,
    gate: np.ndarray | None = None,
    speed: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The QP rows ``A v ≤ b`` of any barrier ``h (...)`` with row L_g0 h ``(..., k)`` (either form):

        −L_g0 h · v ≤ share · κ h̃ + ∂h/∂t − ‖L_g0 h‖² / ε(h̃),      h̃ = h − margin,  ε(h̃) = ε e^{λ h̃}

    (the robust ISSf condition of Eq. 56 with the tightened barrier, a moving obstacle's ∂h/∂t, and the
    rate ``share`` of a pair two arms filter: ½ each). With ``gate`` σ ``(...)`` in [0, 1]
    (:func:`activation_gate`) the row becomes the convex combination of itself and the trivially true
    0 ≤ S, S = ``speed`` · Σ_t |L_g0 h_t| (the most −L_g0 h · v can be inside the speed box |v_t| ≤ speed):

        −σ L_g0 h · v ≤ σ b + (1 − σ) S.

    σ = 1 is the row itself, σ = 0 a zero row with b ≥ 0 (the QP drops it), and in between a relaxation
    that every v meeting the row meets: the gate can only enlarge the feasible set, and it moves the
    half-space continuously (no jump of v* when a pair comes into range). Returns ``(A, b)``."""
    h = np.asarray(h, dtype=float)
    row = np.asarray(row, dtype=float)
    ht = h - margin
    A = -row
    b = share * kappa * ht + dh_dt - np.sum(row * row, axis=-1) / robust_epsilon(ht, epsilon, decay)
    if gate is not None:
        if speed is None or not np.isfinite(speed):
            raise ValueError("cbf_rows: a gate needs the finite speed bound of the box rows")
        sigma = np.asarray(gate, dtype=float)
        S = speed * np.sum(np.abs(row), axis=-1)
        A = sigma[..., None] * A
        b = sigma * b + (1.0 - sigma) * S
    return A, b


def fault_rows(
    h: np.ndarray, row: np.ndarray, dh_dt: np.ndarray, p1: float, mass_row: np.ndarray, reach: float, damping: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A PAn−1 arm's distance barriers ``h (...)``, with rows L_g0 h ``(..., k)`` and known rates ``dh_dt`` (its drift's
    included), as the fault margin keeps them (docs/MODEL.md §5c): with c = ``reach`` / b, each pair becomes the two
    barriers h − c p₁ and h + c p₁ (both ≥ 0: h ≥ c |p₁|), a last axis of two sides (+, −), with

        L_g0 (h ∓ c p₁) = L_g0 h ∓ reach M₀a / M₀₀,   ∂/∂t (h ∓ c p₁) = ∂h/∂t ± reach p₁ / M₀₀,

    from ṗ₁ = −b q̇₁ and q̇₁ = (p₁ − M₀a v) / M₀₀ (``mass_row`` = the mass matrix's first row M₀ = (M₀₀, M₀a)).
    Braking (v = 0) turns the arm rigidly about its base by p₁ / b in all, which moves no point more than
    reach |p₁| / b, and meets both rows without the robust term if their class-K gain is at least b / M₀₀: the
    fourth value is that floor, for ``cbf_rows``' κ. Returns ``(h_±, row_±, dh_dt_±, b / M₀₀)``."""
    c = reach / damping
    mass_row = np.asarray(mass_row, dtype=float)
    side = np.array([1.0, -1.0])
    h = np.asarray(h, dtype=float)[..., None] - side * c * p1
    row = np.asarray(row, dtype=float)[..., None, :] - side[:, None] * reach * mass_row[1:] / mass_row[0]
    rate = np.asarray(dh_dt, dtype=float)[..., None] + side * reach * p1 / mass_row[0]
    return h, row, rate, damping / mass_row[0]


def momentum_rows(mass_row: np.ndarray, clearance: float, reach: float, damping: float, margin: float = 0.0,
                  gain: float = 1.0, offset: float = 0.0, closing: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A fully actuated arm's fault margin (docs/MODEL.md §5c): the momentum its first joint would keep if that
    joint's actuator were lost at the end of the sub-step, p₁ = g M₀ v + p₀ (``gain`` g and ``offset`` p₀: the
    tracker's momentum there, linear in the command v; g = 1, p₀ = 0 for v itself), within b (h − s − margin) / reach
    of its smallest clearance h to the world's obstacles less ``closing`` s, what h can lose within the sub-step, as
    two QP rows ``A (2, k) v ≤ b (2,)``: ±c (g M₀ v + p₀) ≤ max(h − s − margin, 0), c = reach / b. The arm then
    starts its passive life with h ≥ c |p₁| (:func:`fault_rows`)."""
    c = reach / damping
    mass_row = np.asarray(mass_row, dtype=float)
    A = c * gain * np.stack([mass_row, -mass_row])
    return A, max(clearance - closing - margin, 0.0) - c * offset * np.array([1.0, -1.0])


def torque_rows(mass: np.ndarray, bias: np.ndarray, qd: np.ndarray, dt: float, max_torque: float,
                ) -> tuple[np.ndarray, np.ndarray]:
    """Torque mode's input bound (docs/MODEL.md §5d) as QP rows ``A (2k, k) v ≤ b (2k,)`` on the filtered velocity v of
    the actuated joints: the torque that reaches v from ``qd`` in one sub-step ``dt``, τ = H + M (v − q̇) / dt (the
    engine's torque where the filter changed the command), within ±``max_torque`` in every joint. ``mass`` M (k, k)
    and ``bias`` H (k,) are the actuated joints' (for a PAn−1 arm its reduced terms, with the passive joint's
    acceleration eliminated). Rows 2r and 2r + 1 bound joint r from above and below:
    ±M_r v ≤ dt (τ_max ∓ H_r) ± M_r q̇."""
    mass, bias, qd = (np.asarray(x, dtype=float) for x in (mass, bias, qd))
    side = np.array([1.0, -1.0])
    A = (side[None, :, None] * mass[:, None, :]).reshape(-1, mass.shape[1])
    b = dt * (max_torque - side[None, :] * bias[:, None]) + side[None, :] * (mass @ qd)[:, None]
    return A, b.reshape(-1)
