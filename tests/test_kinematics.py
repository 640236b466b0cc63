"""Forward kinematics and the end-effector Jacobian (docs/MODEL.md §1, Eq. 15; docs/PAPER_REPRODUCTION.md).

Checked against finite differences and against Pinocchio's forward kinematics of a planar chain of
revolute-z joints whose links lie along x. The project's convention
``p_end = p0 + Σ L_α [sin(θ_α + φ), cos(θ_α + φ)]`` is Pinocchio's ``(x, y)`` swapped, with φ added
to the first joint angle and the base added.
"""

import numpy as np
import pytest
from arms import random_arm

from pan1_env.dynamics import (
    ArmBatch,
    ArmParams,
    coriolis_vector,
    end_effector,
    jacobian,
    joint_positions,
    mass_matrix,
)


def _random_arm(rng: np.random.Generator, n: int, passive: bool | None = None) -> ArmParams:
    return random_arm(rng, n, passive, placed=True)


def _reference_end_effector(arm: ArmParams, q: np.ndarray) -> np.ndarray:
    """Plain loop over the links, written independently of the vectorised code."""
    x, y = float(arm.base[0]), float(arm.base[1])
    theta = arm.phi
    for a in range(arm.n_links):
        theta += q[a]
        x += arm.lengths[a] * np.sin(theta)
        y += arm.lengths[a] * np.cos(theta)
    return np.array([x, y])


# --------------------------------------------------------------------------- finite differences


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_jacobian_matches_central_difference(n: int) -> None:
    rng = np.random.default_rng(10 + n)
    h = 1e-6
    for _ in range(10):
        arm = _random_arm(rng, n)
        q = rng.uniform(-np.pi, np.pi, n)
        J = jacobian(arm, q)
        assert J.shape == (2, n)
        J_fd = np.empty((2, n))
        for k in range(n):
            dq = np.zeros(n)
            dq[k] = h
            J_fd[:, k] = (end_effector(arm, q + dq) - end_effector(arm, q - dq)) / (2 * h)
        # Central difference error is O(h² · reach) ~ 1e-12, round-off O(eps · reach / h) ~ 1e-9.
        np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-8)


def test_end_effector_matches_plain_loop() -> None:
    rng = np.random.default_rng(3)
    for n in range(2, 7):
        for _ in range(10):
            arm = _random_arm(rng, n)
            q = rng.uniform(-2 * np.pi, 2 * np.pi, n)
            np.testing.assert_allclose(
                end_effector(arm, q), _reference_end_effector(arm, q), rtol=0, atol=1e-12
            )


def test_end_effector_convention_hand_example() -> None:
    """Link angles are measured from the vertical axis, positive clockwise (docs/PAPER_REPRODUCTION.md)."""
    arm = ArmParams(
        masses=[1.0, 1.0], lengths=[2.0, 1.0], com=[1.0, 0.5], inertias=[0.1, 0.1], base=[1.0, -1.0]
    )
    # Straight up: p = p0 + (0, 3).
    np.testing.assert_allclose(end_effector(arm, [0.0, 0.0]), [1.0, 2.0], atol=1e-15)
    # First link a quarter turn clockwise (to +x), second link back to vertical.
    np.testing.assert_allclose(end_effector(arm, [np.pi / 2, -np.pi / 2]), [3.0, 0.0], atol=1e-15)
    # A base rotation φ acts like an offset on q_1.
    rotated = ArmParams(
        masses=[1.0, 1.0], lengths=[2.0, 1.0], com=[1.0, 0.5], inertias=[0.1, 0.1],
        base=[1.0, -1.0], phi=np.pi / 2,
    )
    np.testing.assert_allclose(end_effector(rotated, [0.0, 0.0]), [4.0, -1.0], atol=1e-14)


# --------------------------------------------------------------------------- Pinocchio


def _pinocchio_chain(pin, lengths: np.ndarray):
    """Planar chain: joint α rotates about z; link α lies along its frame's x axis; a frame 'ee'
    sits at the tip of the last link."""
    model = pin.Model()
    parent = 0
    for a in range(len(lengths)):
        offset = 0.0 if a == 0 else float(lengths[a - 1])
        placement = pin.SE3(np.eye(3), np.array([offset, 0.0, 0.0]))
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{a}")
        model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
    tip = pin.SE3(np.eye(3), np.array([float(lengths[-1]), 0.0, 0.0]))
    frame = pin.Frame("ee", parent, 0, tip, pin.FrameType.OP_FRAME)
    fid = model.addFrame(frame)
    return model, model.createData(), fid


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_end_effector_and_jacobian_match_pinocchio(n: int) -> None:
    pin = pytest.importorskip("pinocchio")
    rng = np.random.default_rng(200 + n)
    for _ in range(10):
        arm = _random_arm(rng, n)
        model, data, fid = _pinocchio_chain(pin, arm.lengths)
        q = rng.uniform(-np.pi, np.pi, n)
        q_pin = q.copy()
        q_pin[0] += arm.phi  # φ rotates the whole chain: an offset on the first joint
        pin.forwardKinematics(model, data, q_pin)
        pin.updateFramePlacements(model, data)
        pos = data.oMf[fid].translation
        expected = arm.base + np.array([pos[1], pos[0]])  # (x, y) swapped
        np.testing.assert_allclose(end_effector(arm, q), expected, rtol=0, atol=1e-12)

        # Every joint position too: pinocchio joint α+1 sits at the tip of link α.
        P = joint_positions(arm, q)
        for a in range(1, n):
            t = data.oMi[a + 1].translation
            np.testing.assert_allclose(P[a], arm.base + [t[1], t[0]], rtol=0, atol=1e-12)

        J_pin = pin.computeFrameJacobian(
            model, data, q_pin, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        np.testing.assert_allclose(jacobian(arm, q), J_pin[[1, 0], :], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- joint positions


def test_joint_positions_consistent() -> None:
    rng = np.random.default_rng(5)
    for n in range(2, 7):
        arm = _random_arm(rng, n)
        q = rng.uniform(-np.pi, np.pi, n)
        P = joint_positions(arm, q)
        assert P.shape == (n + 1, 2)
        np.testing.assert_allclose(P[0], arm.base, atol=0)
        np.testing.assert_allclose(P[-1], end_effector(arm, q), rtol=0, atol=1e-12)
        # Consecutive joints are one link length apart.
        np.testing.assert_allclose(
            np.linalg.norm(np.diff(P, axis=0), axis=-1), arm.lengths, rtol=0, atol=1e-12
        )


# --------------------------------------------------------------------------- batching


def test_batched_equals_per_row() -> None:
    rng = np.random.default_rng(6)
    for n in (2, 4, 6):
        arm = _random_arm(rng, n)
        q = rng.uniform(-np.pi, np.pi, (7, n))
        p, J, P = end_effector(arm, q), jacobian(arm, q), joint_positions(arm, q)
        assert p.shape == (7, 2) and J.shape == (7, 2, n) and P.shape == (7, n + 1, 2)
        for b in range(7):
            np.testing.assert_allclose(p[b], end_effector(arm, q[b]), rtol=0, atol=1e-14)
            np.testing.assert_allclose(J[b], jacobian(arm, q[b]), rtol=0, atol=1e-14)
            np.testing.assert_allclose(P[b], joint_positions(arm, q[b]), rtol=0, atol=1e-14)


@pytest.mark.parametrize("passive", [True, False])
def test_arm_batch_gives_per_arm_results(passive: bool) -> None:
    rng = np.random.default_rng(8 + passive)
    n = 4
    arms = [_random_arm(rng, n, passive=passive) for _ in range(5)]
    batch = ArmBatch.stack(arms)
    assert len(batch) == 5 and batch.n_links == n
    q = rng.uniform(-np.pi, np.pi, (5, n))
    qd = rng.uniform(-2.0, 2.0, (5, n))
    p, J, P = end_effector(batch, q), jacobian(batch, q), joint_positions(batch, q)
    M, h = mass_matrix(batch, q), coriolis_vector(batch, q, qd)
    for i, arm in enumerate(arms):
        np.testing.assert_allclose(p[i], _reference_end_effector(arm, q[i]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(J[i], jacobian(arm, q[i]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(P[i], joint_positions(arm, q[i]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(M[i], mass_matrix(arm, q[i]), rtol=0, atol=1e-14)
        np.testing.assert_allclose(h[i], coriolis_vector(arm, q[i], qd[i]), rtol=1e-13, atol=1e-13)


def test_arm_batch_rejects_mixed_arms_and_bad_shapes() -> None:
    rng = np.random.default_rng(9)
    with pytest.raises(ValueError):
        ArmBatch.stack([_random_arm(rng, 3), _random_arm(rng, 4)])
    with pytest.raises(ValueError):
        ArmBatch.stack([_random_arm(rng, 3, passive=True), _random_arm(rng, 3, passive=False)])
    with pytest.raises(ValueError):
        ArmBatch.stack([])
    batch = ArmBatch.stack([_random_arm(rng, 3, passive=True) for _ in range(2)])
    with pytest.raises(ValueError):
        end_effector(batch, np.zeros(3))  # an ArmBatch needs one row per arm
    with pytest.raises(ValueError):
        end_effector(batch, np.zeros((3, 3)))


# --------------------------------------------------------------------------- validation

_GOOD = dict(
    masses=[1.0, 1.0, 1.0],
    lengths=[0.5, 0.5, 0.5],
    com=[0.25, 0.25, 0.25],
    inertias=[0.01, 0.01, 0.01],
)


def test_valid_arm_accepted_and_com_equal_length_allowed() -> None:
    arm = ArmParams(**{**_GOOD, "com": [0.5, 0.5, 0.5]})
    assert arm.n_links == 3 and arm.n_actuated == 2
    assert ArmParams(**_GOOD, passive_first_joint=False).n_actuated == 3
    assert arm.reach == pytest.approx(1.5)


@pytest.mark.parametrize(
    "override",
    [
        {"masses": [1.0, 1.0]},  # mismatched lengths
        {"inertias": [0.01, 0.01, 0.01, 0.01]},
        {"masses": [1.0], "lengths": [0.5], "com": [0.25], "inertias": [0.01]},  # 1 link
        {"masses": [1.0, 0.0, 1.0]},
        {"masses": [1.0, -1.0, 1.0]},
        {"lengths": [0.5, 0.0, 0.5], "com": [0.25, 0.0, 0.25]},
        {"lengths": [0.5, -0.5, 0.5]},
        {"inertias": [0.01, 0.0, 0.01]},
        {"inertias": [0.01, -0.01, 0.01]},
        {"com": [0.25, 0.6, 0.25]},  # com > length
        {"com": [0.25, 0.0, 0.25]},  # com <= 0
        {"com": [0.25, -0.1, 0.25]},
        {"masses": [1.0, float("nan"), 1.0]},
        {"lengths": [0.5, float("nan"), 0.5]},
        {"com": [0.25, float("nan"), 0.25]},
        {"inertias": [float("nan"), 0.01, 0.01]},
        {"masses": [1.0, float("inf"), 1.0]},
        {"masses": [[1.0, 1.0, 1.0]]},  # not 1-D
        {"base": [0.0, 0.0, 0.0]},  # bad base shape
        {"base": [0.0]},
        {"base": [[0.0, 0.0]]},
        {"base": [0.0, float("nan")]},
        {"phi": float("nan")},
        {"phi": float("inf")},
    ],
)
def test_invalid_params_raise(override: dict) -> None:
    with pytest.raises(ValueError):
        ArmParams(**{**_GOOD, **override})


@pytest.mark.parametrize("bad_q", [np.zeros(2), np.zeros(4), np.zeros((2, 2)), np.zeros((2, 2, 3))])
@pytest.mark.parametrize("fn", [end_effector, jacobian, joint_positions, mass_matrix])
def test_wrong_q_shape_raises(fn, bad_q: np.ndarray) -> None:
    arm = ArmParams(**_GOOD)
    with pytest.raises(ValueError):
        fn(arm, bad_q)
