"""benchmarks/formable.py: the bound on what any policy can form at rest behind the paper's filter."""

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import pan1_env
from pan1_env.baselines.evaluation import evaluate
from pan1_env.cascade import reduced_jacobian
from pan1_env.dynamics import end_effector
from pan1_env.formation import Formation, edge_length_errors, edge_vectors
from pan1_env.kernels import compiled_projection
from pan1_env.safety import QPStatus, rcbf_constraints

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "formable.py"
_spec = importlib.util.spec_from_file_location("pan1_formable", _PATH)
formable = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(formable)


def _team(seed: int):
    env = pan1_env.parallel_env("random")
    env.reset(seed=seed)
    return env.unwrapped.scenario


def test_inverse_kinematics_and_jacobian_match_the_packages() -> None:
    scenario = _team(7)
    rng = np.random.default_rng(0)
    turned = [dataclasses.replace(arm, phi=0.4) for arm in scenario.arms[::2]]  # a base frame rotated by φ
    for arm in (*scenario.arms, *turned):  # PA arms and fully actuated ones
        points = arm.base + rng.uniform(-0.8, 0.8, (40, 2))
        angles, i = formable.arm_ik(arm, points, np.linspace(-np.pi, np.pi, 24, endpoint=False))
        q = formable.joint_angles(arm, angles)
        assert len(q) > 40
        np.testing.assert_allclose(end_effector(arm, q), points[i], atol=1e-9)
        elbows = np.sign(np.round(np.sin(q[:, 1]), 9))
        assert {-1.0, 1.0} <= set(elbows.tolist())
        np.testing.assert_allclose(formable.reduced_jacobian_at(arm, angles), reduced_jacobian(arm, q),
                                   rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("n", [4, 5])
def test_every_realisation_has_the_shapes_edge_lengths(n: int) -> None:
    shape = Formation.from_shape("polygon", 0.7, n)
    found = formable.realisations(shape.edges, shape.distances, n)
    assert len(found) == 2 ** (n - 2)
    for pos in found:
        errors = edge_length_errors(edge_vectors(shape.incidence, pos), shape.distances)
        assert np.abs(errors).max() < 1e-9
    shapes = {tuple(np.round(np.sort(np.linalg.norm(pos[:, None] - pos[None], axis=-1), axis=None), 6))
              for pos in found}
    assert len(shapes) > 1, "folded realisations (not congruent to the polygon) are counted too"


@pytest.mark.parametrize("size", [0.5, 0.9])
def test_a_formed_team_lies_within_the_formed_deviation_of_a_realisation(size: float) -> None:
    """End-effectors whose edges are all within 1 cm of their lengths, aligned (Kabsch) to the nearest
    realisation, are within FORMED_DEVIATION of it: the slack's first term."""
    shape = Formation.from_shape("polygon", size, 4)
    found = formable.realisations(shape.edges, shape.distances, 4)
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(2000):
        # scale the perturbation of a realisation until its largest edge error is just under 1 cm
        base = found[rng.integers(len(found))]
        noise = rng.normal(0.0, 1.0, (4, 2))
        err = np.abs(edge_length_errors(edge_vectors(shape.incidence, base + noise), shape.distances)).max()
        X = base + noise * 0.0099 / max(err, 1e-12)
        if np.abs(edge_length_errors(edge_vectors(shape.incidence, X), shape.distances)).max() >= 0.01:
            continue
        best = np.inf
        for R in found:
            U, _, Vt = np.linalg.svd(R.T @ (X - X.mean(0)))
            rot = U @ np.diag([1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
            best = min(best, np.linalg.norm((X - X.mean(0)) @ rot.T - R, axis=-1).max())
        worst = max(worst, best)
    assert 0.002 < worst <= formable.FORMED_DEVIATION


def test_resting_cells_hold_the_configurations_the_filter_keeps_still() -> None:
    """Joint-space sampling through the package's rows and QP (forward kinematics, not the script's
    inverse kinematics): a configuration the filter keeps still (v = 0 allowed, or the QP with the
    speed box infeasible, so it brakes) lies in a cell that resting_cells marks, and every marked cell
    holds such a configuration."""
    from scipy.spatial import cKDTree

    scenario = _team(1_000_001)
    mask = scenario.obstacle_mask()
    i = int(np.argmax(mask.sum(1)))
    arm, centers, radii = scenario.arms[i], scenario.obstacles.centers[mask[i]], scenario.obstacles.radii[mask[i]]
    cell, speed = 0.05, 2.0
    xs = np.arange(-2.0, 2.0 + cell, cell)
    cells = arm.base + np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    f = scenario.filter
    marked = formable.resting_cells(arm, cells, centers, radii, f.kappa, f.epsilon, 0.0, speed,
                                    np.linspace(-np.pi, np.pi, 180, endpoint=False))
    assert 0 < marked.sum() < (np.linalg.norm(cells - arm.base, axis=-1) <= arm.lengths.sum()).sum()

    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (200_000, 3))
    p = end_effector(arm, q)
    A, b, _ = rcbf_constraints(p, reduced_jacobian(arm, q), centers, radii, f.kappa, f.epsilon)
    k = A.shape[-1]
    box = np.broadcast_to(np.concatenate([np.eye(k), -np.eye(k)]), (len(q), 2 * k, k))
    status = compiled_projection(np.zeros((len(q), k)), np.concatenate([A, box], 1),
                              np.concatenate([b, np.full((len(q), 2 * k), speed)], 1)).status
    still = p[status != QPStatus.SOLVED]
    assert len(still) > 100
    gap, _ = cKDTree(cells[marked]).query(still)
    assert np.quantile(gap, 0.99) <= cell / np.sqrt(2) + 1e-9
    back, _ = cKDTree(still).query(cells[marked])
    assert np.quantile(back, 0.95) < cell


@pytest.mark.parametrize("argv", [["--cell", "0"], ["--headings", "0"], ["--teams", "-1"], ["--cell", "nan"],
                                  ["--slack", "-0.01"]])
def test_bad_arguments_are_refused(argv, capsys) -> None:
    with pytest.raises(SystemExit):
        formable.main(argv)
    assert "must be" in capsys.readouterr().err


@pytest.mark.slow
def test_every_team_the_reference_forms_is_formable() -> None:
    """The bound holds on real episodes: the shielded reference forms only teams judged formable, and
    the chosen teams include one it forms and one judged not formable."""
    seeds = [1_000_000, 1_000_001, 1_000_010]
    final = evaluate(lambda obs: np.zeros((len(obs), 10), np.float32), "random", seeds,
                     env_kwargs={"action_mode": "residual"})["final_error"]
    verdicts = [formable.formable(_team(s), 0.01, 180, 2.0)["formable"] for s in seeds]
    formed = final < 0.01
    assert formed.any() and not all(verdicts)
    assert all(v for v, f in zip(verdicts, formed, strict=True) if f)
