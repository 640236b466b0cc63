"""Rigid-body model of one planar n-link arm: parameters, inertia, Coriolis, kinematics.

This module owns the equations of docs/MODEL.md §1 (the paper's Eq. 1–8 and 15, with signs restored):

    λ_αα = I_α + m_α l_α² + L_α² Σ_{γ>α} m_γ
    λ_αβ = m_β L_α l_β + L_α L_β Σ_{γ>β} m_γ            (α < β)
    M̄_αβ = λ_αβ cos(θ_β − θ_α),  C̄_αβ = −λ_αβ θ̇_β sin(θ_β − θ_α)
    M = Sᵀ M̄ S,  C = Sᵀ C̄ S,  M q̈ + C q̇ = τ − b q̇₁ e₁   (θ = S q, S lower-triangular ones)
    p_end = p0 + Σ_α L_α [sin(θ_α + φ), cos(θ_α + φ)]

The damping term −b q̇₁ e₁ acts only while joint 1 is passive (docs/MODEL.md §7); b = 0 by default.

Joint angles are relative; link angles θ are measured from the base frame's vertical axis,
positive clockwise (see docs/MODEL.md §6). There is no gravity: the plane is horizontal.

Every function takes ``arm`` (an :class:`ArmParams`, or an :class:`ArmBatch` of arms with the same
number of links) and joint arrays of shape ``(n,)`` or ``(B, n)``; the result has the matching
leading batch shape. With an :class:`ArmBatch`, ``B`` must equal the number of stacked arms.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ArmParams",
    "ArmBatch",
    "inertia_coefficients",
    "mass_matrix",
    "coriolis_matrix",
    "coriolis_vector",
    "link_angles",
    "angle_differences",
    "in_joint_coordinates",
    "checked_joints",
    "joint_positions",
    "end_effector",
    "jacobian",
    "kinetic_energy",
    "damping_torque",
    "forward_dynamics",
    "faulted",
]


def _positive_vector(name: str, values: Sequence[float]) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"ArmParams.{name} must be a 1-D sequence, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"ArmParams.{name} must be finite, got {arr.tolist()}")
    if np.any(arr <= 0):
        raise ValueError(f"ArmParams.{name} must be positive, got {arr.tolist()}")
    return arr


def _damping(value: object) -> float:
    # A negative b would pump energy into the arm and a NaN would poison every step silently.
    try:
        b = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"ArmParams.passive_damping must be a number ≥ 0, got {value!r}") from None
    if not np.isfinite(b) or b < 0:
        raise ValueError(f"ArmParams.passive_damping must be finite and ≥ 0 (N·m·s/rad), got {value!r}")
    return b


@dataclass(frozen=True)
class ArmParams:
    """Physical parameters of one planar arm with revolute joints.

    Args:
        masses: link masses ``m_α`` in kg, one per link (n ≥ 2 links).
        lengths: link lengths ``L_α`` in m.
        com: distance ``l_α`` from joint α to the link's centre of mass, ``0 < l_α ≤ L_α``.
        inertias: link inertias ``I_α`` about the centre of mass, kg·m².
        base: world position ``p0`` of joint 1, metres.
        phi: rotation ``φ`` of the base frame from the world frame, radians.
        passive_first_joint: ``True`` for a PAn−1 arm (joint 1 unactuated), ``False`` for a fully
            actuated arm.
        passive_damping: viscous damping ``b ≥ 0`` of joint 1 in N·m·s/rad, acting (as the torque
            −b q̇₁) only while joint 1 is passive: from the start on a PAn−1 arm, from the fault on
            a fully actuated one (docs/MODEL.md §7). 0, the paper's frictionless model, by default.

    Raises:
        ValueError: on mismatched lengths, fewer than two links, non-positive or non-finite
            values, a centre of mass outside its link, or a negative or non-finite damping.
    """

    masses: np.ndarray
    lengths: np.ndarray
    com: np.ndarray
    inertias: np.ndarray
    base: np.ndarray = field(default_factory=lambda: np.zeros(2))
    phi: float = 0.0
    passive_first_joint: bool = True
    passive_damping: float = 0.0

    def __post_init__(self) -> None:
        names = ("masses", "lengths", "com", "inertias")
        arrays = {name: _positive_vector(name, getattr(self, name)) for name in names}
        sizes = {name: arr.size for name, arr in arrays.items()}
        if len(set(sizes.values())) != 1:
            raise ValueError(f"ArmParams: masses, lengths, com and inertias differ in length: {sizes}")
        if arrays["masses"].size < 2:
            raise ValueError("ArmParams: an arm needs at least 2 links")
        if np.any(arrays["com"] > arrays["lengths"]):
            raise ValueError(
                "ArmParams.com must satisfy 0 < com ≤ length for every link, got "
                f"com={arrays['com'].tolist()} lengths={arrays['lengths'].tolist()}"
            )
        base = np.asarray(self.base, dtype=float)
        if base.shape != (2,) or not np.all(np.isfinite(base)):
            raise ValueError(f"ArmParams.base must be two finite numbers, got {self.base!r}")
        phi = float(self.phi)
        if not np.isfinite(phi):
            raise ValueError(f"ArmParams.phi must be finite, got {self.phi!r}")
        for name, arr in arrays.items():
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        base.setflags(write=False)
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "phi", phi)
        object.__setattr__(self, "passive_first_joint", bool(self.passive_first_joint))
        object.__setattr__(self, "passive_damping", _damping(self.passive_damping))
        lam = _lambda(arrays["masses"], arrays["lengths"], arrays["com"], arrays["inertias"])
        lam.setflags(write=False)
        object.__setattr__(self, "_lambda", lam)

    @property
    def n_links(self) -> int:
        """Number of links (and joints) n."""
        return int(self.masses.size)

    @property
    def n_actuated(self) -> int:
        """Number of actuated joints: n − 1 for a PAn−1 arm, n otherwise."""
        return self.n_links - 1 if self.passive_first_joint else self.n_links

    @property
    def reach(self) -> float:
        """Largest distance from the base the end-effector can reach (Σ L_α)."""
        return float(self.lengths.sum())

    @property
    def inner_reach(self) -> float:
        """Smallest distance from the base the end-effector can reach: max(0, 2 max L_α − Σ L_α) (a longest link
        folded back by the others)."""
        return max(0.0, 2.0 * float(self.lengths.max()) - self.reach)

    @property
    def lam(self) -> np.ndarray:
        """The symmetric coefficient matrix λ (n × n) of docs/MODEL.md §1."""
        return self._lambda  # type: ignore[attr-defined]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ArmParams):
            return NotImplemented
        return (
            all(
                np.array_equal(getattr(self, k), getattr(other, k))
                for k in ("masses", "lengths", "com", "inertias", "base")
            )
            and self.phi == other.phi
            and self.passive_first_joint == other.passive_first_joint
            and self.passive_damping == other.passive_damping
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class ArmBatch:
    """Parameters of B arms with the same number of links, stacked along a leading axis.

    Built with :meth:`ArmBatch.stack`; accepted wherever an :class:`ArmParams` is, with joint
    arrays of shape ``(B, n)``.
    """

    lam: np.ndarray  # (B, n, n)
    lengths: np.ndarray  # (B, n)
    base: np.ndarray  # (B, 2)
    phi: np.ndarray  # (B,)
    passive_first_joint: bool = True
    passive_damping: np.ndarray | float = 0.0  # (B,) or one b for all

    @classmethod
    def stack(cls, arms: Sequence[ArmParams]) -> ArmBatch:
        """Stack arms that share their number of links and their actuation."""
        if not arms:
            raise ValueError("ArmBatch.stack needs at least one arm")
        kinds = {(arm.n_links, arm.passive_first_joint) for arm in arms}
        if len(kinds) != 1:
            raise ValueError(
                "ArmBatch.stack needs arms with one number of links and one actuation "
                f"(passive_first_joint), got {sorted(kinds)}"
            )
        return cls(
            lam=np.stack([arm.lam for arm in arms]),
            lengths=np.stack([arm.lengths for arm in arms]),
            base=np.stack([arm.base for arm in arms]),
            phi=np.array([arm.phi for arm in arms]),
            passive_first_joint=arms[0].passive_first_joint,
            passive_damping=np.array([arm.passive_damping for arm in arms]),
        )

    @property
    def n_links(self) -> int:
        return int(self.lengths.shape[-1])

    @property
    def n_actuated(self) -> int:
        return self.n_links - 1 if self.passive_first_joint else self.n_links

    def __len__(self) -> int:
        return int(self.lengths.shape[0])


Arm = ArmParams | ArmBatch


def _lambda(m: np.ndarray, L: np.ndarray, l: np.ndarray, I: np.ndarray) -> np.ndarray:
    n = m.size
    # tail[α] = Σ_{γ>α} m_γ
    tail = np.concatenate([np.cumsum(m[::-1])[::-1][1:], [0.0]])
    lam = np.empty((n, n))
    for a in range(n):
        lam[a, a] = I[a] + m[a] * l[a] ** 2 + L[a] ** 2 * tail[a]
        for b in range(a + 1, n):
            lam[a, b] = lam[b, a] = m[b] * L[a] * l[b] + L[a] * L[b] * tail[b]
    return lam


def inertia_coefficients(arm: Arm) -> np.ndarray:
    """The λ matrix of docs/MODEL.md §1, shape ``(n, n)`` (or ``(B, n, n)`` for an ArmBatch)."""
    return arm.lam


def checked_joints(arm: Arm, q: np.ndarray, name: str = "q") -> np.ndarray:
    """Joint values ``q`` as floats of shape ``(n,)`` or ``(B, n)`` for ``arm``, or a ValueError naming ``name``."""
    q = np.asarray(q, dtype=float)
    n = arm.lengths.shape[-1]
    if q.ndim not in (1, 2) or q.shape[-1] != n:
        raise ValueError(f"{name} must have shape (n,) or (B, n) with n={n}, got {q.shape}")
    if isinstance(arm, ArmBatch) and (q.ndim != 2 or q.shape[0] != len(arm)):
        raise ValueError(f"{name} must have shape ({len(arm)}, {n}) for this ArmBatch, got {q.shape}")
    return q


def link_angles(q: np.ndarray) -> np.ndarray:
    """Absolute link angles θ = S q (cumulative sum of relative joint angles)."""
    return np.cumsum(q, axis=-1)


def angle_differences(theta: np.ndarray) -> np.ndarray:
    """``D[..., α, β] = θ_β − θ_α``."""
    return theta[..., None, :] - theta[..., :, None]


def in_joint_coordinates(X: np.ndarray) -> np.ndarray:
    """Sᵀ X S for S the lower-triangular matrix of ones (θ = S q): a matrix over the link angles θ in the
    joint angles q, by reverse cumulative sums on both axes."""
    Y = np.cumsum(X[..., :, ::-1], axis=-1)[..., :, ::-1]
    return np.cumsum(Y[..., ::-1, :], axis=-2)[..., ::-1, :]


def mass_matrix(arm: Arm, q: np.ndarray) -> np.ndarray:
    """Inertia matrix M(q), shape ``(n, n)`` or ``(B, n, n)``; symmetric, positive definite,
    independent of q_1."""
    q = checked_joints(arm, q)
    D = angle_differences(link_angles(q))
    return in_joint_coordinates(arm.lam * np.cos(D))


def coriolis_matrix(arm: Arm, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Coriolis/centrifugal matrix C(q, q̇) = Sᵀ C̄ S with C̄_αβ = −λ_αβ θ̇_β sin(θ_β − θ_α)."""
    q = checked_joints(arm, q)
    qd = checked_joints(arm, qd, "qd")
    D = angle_differences(link_angles(q))
    theta_dot = link_angles(qd)
    Cbar = -arm.lam * theta_dot[..., None, :] * np.sin(D)
    return in_joint_coordinates(Cbar)


def coriolis_vector(arm: Arm, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """C(q, q̇) q̇ without forming C: Sᵀ (−(λ ∘ sin D) θ̇²). Shape ``(n,)`` or ``(B, n)``."""
    q = checked_joints(arm, q)
    qd = checked_joints(arm, qd, "qd")
    D = angle_differences(link_angles(q))
    theta_dot = link_angles(qd)
    cbar_thetadot = -np.einsum("...ab,...b->...a", arm.lam * np.sin(D), theta_dot**2)
    # Sᵀ x: reverse cumulative sum.
    return np.cumsum(cbar_thetadot[..., ::-1], axis=-1)[..., ::-1]


def _phi(arm: Arm) -> np.ndarray:
    return np.asarray(arm.phi, dtype=float)[..., None]


def joint_positions(arm: Arm, q: np.ndarray) -> np.ndarray:
    """World positions of the base, every joint and the end-effector: shape ``(..., n + 1, 2)``."""
    q = checked_joints(arm, q)
    ang = link_angles(q) + _phi(arm)
    steps = arm.lengths[..., None] * np.stack([np.sin(ang), np.cos(ang)], axis=-1)
    base = np.broadcast_to(arm.base, steps.shape[:-2] + (2,))
    return np.concatenate([base[..., None, :], base[..., None, :] + np.cumsum(steps, axis=-2)], -2)


def end_effector(arm: Arm, q: np.ndarray) -> np.ndarray:
    """End-effector position p_end = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)], shape ``(..., 2)``."""
    q = checked_joints(arm, q)
    ang = link_angles(q) + _phi(arm)
    x = np.sum(arm.lengths * np.sin(ang), axis=-1)
    y = np.sum(arm.lengths * np.cos(ang), axis=-1)
    return arm.base + np.stack([x, y], axis=-1)


def jacobian(arm: Arm, q: np.ndarray) -> np.ndarray:
    """End-effector Jacobian J = ∂p_end/∂q, shape ``(2, n)`` or ``(B, 2, n)``."""
    q = checked_joints(arm, q)
    ang = link_angles(q) + _phi(arm)
    cx = arm.lengths * np.cos(ang)
    cy = -arm.lengths * np.sin(ang)
    rows = np.stack([cx, cy], axis=-2)
    return np.cumsum(rows[..., ::-1], axis=-1)[..., ::-1]


def kinetic_energy(arm: Arm, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Kinetic energy ½ q̇ᵀ M(q) q̇ (the only energy: there is no gravity)."""
    qd = checked_joints(arm, qd, "qd")
    return 0.5 * np.einsum("...a,...ab,...b->...", qd, mass_matrix(arm, q), qd)


def damping_torque(arm: Arm, qd: np.ndarray) -> np.ndarray:
    """The viscous torque at a passive joint 1 as a full joint vector: ``[−b q̇₁, 0, …, 0]``.

    Zero while joint 1 is actuated: the model takes a working drive to cancel its joint's friction,
    so a fully actuated arm moves as in the paper until its fault (docs/MODEL.md §7).
    """
    qd = checked_joints(arm, qd, "qd")
    out = np.zeros_like(qd)
    if arm.passive_first_joint:
        out[..., 0] = -np.asarray(arm.passive_damping, dtype=float) * qd[..., 0]
    return out


def forward_dynamics(arm: Arm, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """q̈ = M⁻¹ (τ − C q̇ − b q̇₁ e₁) for the full joint torque ``tau`` (all n entries; a passive
    joint's entry should be 0). The damping term is :func:`damping_torque`."""
    rhs = np.asarray(tau, dtype=float) - coriolis_vector(arm, q, qd) + damping_torque(arm, qd)
    return np.linalg.solve(mass_matrix(arm, q), rhs[..., None])[..., 0]


def faulted(arm: Arm) -> Arm:
    """The same arm after joint 1 lost its actuator: a PAn−1 arm with the same parameters and b.

    The state is not part of the arm, so a fault keeps q, q̇ and the momentum p₁ (docs/MODEL.md §7).

    Raises:
        ValueError: if joint 1 is passive already (there is no actuator to lose).
    """
    if arm.passive_first_joint:
        raise ValueError("faulted: joint 1 of this arm is passive already; a fault needs an actuated joint 1")
    return dataclasses.replace(arm, passive_first_joint=True)
