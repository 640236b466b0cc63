"""M(q) and C(q, q̇)q̇ against Pinocchio (CRBA and RNEA on a planar revolute-z chain, no gravity)."""

import numpy as np
import pytest
from arms import random_arm

from pan1_env.dynamics import ArmParams, coriolis_matrix, coriolis_vector, mass_matrix

pin = pytest.importorskip("pinocchio")


def _pinocchio_chain(arm: ArmParams):
    """A planar chain: joint α rotates about z; link α lies along its frame's x axis."""
    model = pin.Model()
    model.gravity = pin.Motion.Zero()
    parent = 0
    for a in range(arm.n_links):
        offset = 0.0 if a == 0 else float(arm.lengths[a - 1])
        placement = pin.SE3(np.eye(3), np.array([offset, 0.0, 0.0]))
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{a}")
        inertia = pin.Inertia(
            float(arm.masses[a]),
            np.array([float(arm.com[a]), 0.0, 0.0]),
            np.diag([1e-3, 1e-3, float(arm.inertias[a])]),
        )
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    return model, model.createData()


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_mass_matrix_and_coriolis_match_pinocchio(n: int) -> None:
    rng = np.random.default_rng(100 + n)
    for _ in range(20):
        arm = random_arm(rng, n)
        model, data = _pinocchio_chain(arm)
        q = rng.uniform(-np.pi, np.pi, n)
        qd = rng.uniform(-3.0, 3.0, n)
        M_ref = pin.crba(model, data, q)
        M_ref = np.triu(M_ref) + np.triu(M_ref, 1).T
        h_ref = pin.rnea(model, data, q, qd, np.zeros(n))
        M = mass_matrix(arm, q)
        np.testing.assert_allclose(M, M_ref, rtol=1e-10, atol=1e-10 * np.abs(M_ref).max())
        h = coriolis_matrix(arm, q, qd) @ qd
        scale = max(np.abs(h_ref).max(), 1e-12)
        np.testing.assert_allclose(h, h_ref, rtol=1e-10, atol=1e-10 * scale)
        np.testing.assert_allclose(coriolis_vector(arm, q, qd), h_ref, rtol=1e-10, atol=1e-10 * scale)


def test_batched_matches_single() -> None:
    rng = np.random.default_rng(7)
    arm = random_arm(rng, 4)
    q = rng.uniform(-np.pi, np.pi, (5, 4))
    qd = rng.uniform(-2, 2, (5, 4))
    Mb = mass_matrix(arm, q)
    Cb = coriolis_matrix(arm, q, qd)
    assert Mb.shape == (5, 4, 4) and Cb.shape == (5, 4, 4)
    for b in range(5):
        np.testing.assert_allclose(Mb[b], mass_matrix(arm, q[b]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(Cb[b], coriolis_matrix(arm, q[b], qd[b]), rtol=0, atol=1e-14)
