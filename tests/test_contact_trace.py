"""The closing and escape speeds of benchmarks/contact_trace.py against the tests' own kinematics and geometry."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from geometry import joints, point_segment_distance

from pan1_env.dynamics import ArmParams, mass_matrix

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "contact_trace.py"
_spec = importlib.util.spec_from_file_location("pan1_contact_trace", _PATH)
trace = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(trace)

ARM = ArmParams(masses=[1.0, 0.8, 0.5], lengths=[0.4, 0.3, 0.25], com=[0.2, 0.15, 0.12],
                inertias=[0.02, 0.01, 0.005], base=np.array([0.1, -0.2]), phi=0.3, passive_first_joint=False)
RHO = 0.03


def _distances(q: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Each link's distance to ``center``, from the tests' own joint positions."""
    P = joints(q, ARM.lengths, ARM.base, ARM.phi)
    return np.array([point_segment_distance(center, P[k], P[k + 1]) for k in range(len(P) - 1)])


@pytest.mark.parametrize("q", [np.array([0.2, -0.7, 1.1]), np.array([-1.0, 0.4, 0.3])])
def test_closing_and_escape_speeds_are_those_of_the_distance(q: np.ndarray) -> None:
    """Fully actuated: escape = v_max Σ_t |∂d/∂q_t| and closing = −∂d/∂t, by central differences of the
    independent link–centre distance, for the nearest obstacle of every link."""
    centers = np.array([[0.5, 0.6], [-0.4, 0.3]])
    velocities = np.array([[-0.1, 0.05], [0.08, -0.02]])
    radii = np.array([0.05, 0.07])
    out = trace.escape_speeds(ARM, q, centers, velocities, radii, RHO, max_speed=2.0)
    step = 1e-6
    for link in range(3):
        j = out.obstacle[link]
        assert j == np.argmin([_distances(q, c)[link] - r for c, r in zip(centers, radii, strict=True)])
        d = _distances(q, centers[j])[link]
        assert out.clearance[link] == pytest.approx(d - radii[j] - RHO, abs=1e-9)
        grad = [(_distances(q + step * e, centers[j])[link] - _distances(q - step * e, centers[j])[link]) / (2 * step)
                for e in np.eye(3)]
        assert out.escape[link] == pytest.approx(2.0 * np.abs(grad).sum(), rel=1e-5)
        moved = (_distances(q, centers[j] + step * velocities[j])[link]
                 - _distances(q, centers[j] - step * velocities[j])[link]) / (2 * step)
        assert out.closing[link] == pytest.approx(-moved, rel=1e-5, abs=1e-9)


def test_an_obstacle_coming_down_the_last_links_axis_cannot_be_escaped_by_that_link_alone() -> None:
    """Straight arm, obstacle beyond the tip on the arm's axis and coming at it: the tip's nearest point moves
    only across the axis, so the escape speed along the axis is 0, and the closing speed is the obstacle's."""
    q = np.zeros(3)
    P = joints(q, ARM.lengths, ARM.base, ARM.phi)
    axis = (P[-1] - P[-2]) / np.linalg.norm(P[-1] - P[-2])
    center = P[-1] + 0.3 * axis
    out = trace.escape_speeds(ARM, q, center[None], (-0.15 * axis)[None], np.array([0.05]), RHO, max_speed=2.0)
    assert out.escape[2] == pytest.approx(0.0, abs=1e-9)
    assert out.closing[2] == pytest.approx(0.15)
    assert out.clearance[2] == pytest.approx(0.3 - 0.05 - RHO)


def test_a_passive_first_joint_follows_the_others() -> None:
    """A PAn−1 arm's link moves by q̇ = g0 v, the passive joint keeping its momentum M_0· q̇ at 0: the escape is
    v_max Σ_t |∇_q d · g0_t| with g0_t = e_{t+1} − e_0 M_0,t+1 / M_00 (the mass matrix checked against Pinocchio
    elsewhere), ∇_q d by central differences of the independent distance."""
    passive = ArmParams(masses=ARM.masses, lengths=ARM.lengths, com=ARM.com, inertias=ARM.inertias,
                        base=ARM.base, phi=ARM.phi, passive_first_joint=True)
    q = np.array([0.2, -0.7, 1.1])
    center = np.array([0.3, 0.2])
    out = trace.escape_speeds(passive, q, center[None], np.zeros((1, 2)), np.array([0.05]), RHO, max_speed=2.0)
    M = mass_matrix(passive, q)
    g0 = np.vstack([-M[0, 1:] / M[0, 0], np.eye(2)])
    step = 1e-6
    for link in range(3):
        grad = np.array([(_distances(q + step * e, center)[link] - _distances(q - step * e, center)[link]) / (2 * step)
                         for e in np.eye(3)])
        assert out.escape[link] == pytest.approx(2.0 * np.abs(grad @ g0).sum(), rel=1e-5, abs=1e-9)


def test_bad_speed_bound_is_refused() -> None:
    with pytest.raises(ValueError, match="max_speed"):
        trace.escape_speeds(ARM, np.zeros(3), np.zeros((1, 2)), np.zeros((1, 2)), np.array([0.1]), RHO, 0.0)


def test_the_script_refuses_a_window_that_ends_before_it_starts(capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        trace.main(["--seed", "1", "--arm", "0", "--start", "5", "--stop", "1"])
    assert stop.value.code == 2
    assert "--start ≤ --stop" in capsys.readouterr().err
