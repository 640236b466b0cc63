"""Random arm parameters shared by the dynamics and kinematics tests."""

import numpy as np

from pan1_env.dynamics import ArmParams


def random_arm(rng: np.random.Generator, n: int, passive: bool | None = None, placed: bool = False) -> ArmParams:
    """An n-link arm with random masses, lengths, centres of mass and inertias; with ``placed`` also
    a random base and base rotation (else at the origin, φ = 0)."""
    lengths = rng.uniform(0.1, 1.0, n)
    return ArmParams(
        masses=rng.uniform(0.05, 2.0, n),
        lengths=lengths,
        com=lengths * rng.uniform(0.05, 1.0, n),
        inertias=rng.uniform(1e-4, 0.05, n),
        base=rng.uniform(-3.0, 3.0, 2) if placed else np.zeros(2),
        phi=float(rng.uniform(-np.pi, np.pi)) if placed else 0.0,
        passive_first_joint=bool(rng.integers(2)) if passive is None else passive,
    )
