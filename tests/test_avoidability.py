"""The judge of avoidability (benchmarks/avoidability.py) on contacts whose answer is known from geometry: an
obstacle crossing a stretched arm faster than any admissible command can fold it away, the same obstacle slow, and
a passive joint's momentum carrying a link into an obstacle; every escape it reports is checked again with the
tests' own kinematics and geometry (tests/geometry.py), not pan1_env's."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from geometry import joints, obstacle_clearances

from pan1_env.dynamics import ArmParams

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "avoidability.py"
_spec = importlib.util.spec_from_file_location("pan1_avoidability", _PATH)
avoidability = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(avoidability)

RHO = 0.03  # link radius


def _arm(passive: bool, damping: float = 0.0) -> ArmParams:
    return ArmParams(masses=[1.0, 0.8, 0.5], lengths=[0.3, 0.3, 0.3], com=[0.15, 0.15, 0.15],
                     inertias=[0.01, 0.008, 0.005], passive_first_joint=passive, passive_damping=damping)


def _crossing(speed: float) -> dict:
    """An obstacle of radius 5 cm on the line y = 0.45 m, heading from x = 0.2 m to x = −0.5 m across the middle of
    an arm stretched along +y (q = 0, base at the origin)."""
    return {"centers": np.array([[0.2, 0.45]]), "path_ends": np.array([[-0.5, 0.45]]), "speeds": np.array([speed]),
            "radii": np.array([0.05])}


def _check_witness(arm: ArmParams, q0: np.ndarray, p1: float, world: dict, verdict, window: float,
                   rho: float = RHO) -> None:
    """The reported escape, rolled out again, keeps every link clear by the tests' own geometry."""
    from pan1_env.bodies import obstacle_centers

    path = avoidability.rollout(arm, q0, p1, verdict.witness[None], window, 0.01)[0]
    times = np.linspace(0.0, window, len(path))
    for q, t in zip(path, times, strict=True):
        centers = obstacle_centers(world["centers"], world["path_ends"], world["speeds"], t)
        points = joints(q, arm.lengths, arm.base, arm.phi)
        assert min(c.min() for c in obstacle_clearances([points], centers, world["radii"], rho)) >= -1e-9


def test_a_fast_obstacle_across_a_slow_arm_cannot_be_avoided() -> None:
    verdict = avoidability.judge(_arm(False), np.zeros(3), 0.0, **_crossing(2.0), link_radius=RHO, max_speed=0.1,
                                 t0=0.0, window=1.0)
    assert not verdict.avoidable and verdict.best_clearance < 0 and verdict.tried > 27


def test_a_slow_obstacle_is_avoided_by_folding_the_arm_away_and_the_escape_holds() -> None:
    world = _crossing(0.05)
    verdict = avoidability.judge(_arm(False), np.zeros(3), 0.0, **world, link_radius=RHO, max_speed=3.0, t0=0.0,
                                 window=6.0)
    assert verdict.avoidable and verdict.best_clearance >= 0
    _check_witness(_arm(False), np.zeros(3), 0.0, world, verdict, 6.0)
    still = avoidability.rollout(_arm(False), np.zeros(3), 0.0, np.zeros((1, 6, 3)), 6.0, 0.01)[0]
    assert np.allclose(still, 0.0), "with no command a fully actuated arm stays where it is"


@pytest.mark.parametrize("momentum, max_speed, damping, avoidable", [(1.0, 0.05, 0.0, False), (0.0, 1.0, 0.0, True),
                                                                    (1.0, 0.05, 50.0, True)])
def test_a_passive_joints_momentum_carries_its_link_into_an_obstacle_unless_damped(momentum, max_speed, damping,
                                                                                  avoidable) -> None:
    arm = _arm(True, damping)
    world = {"centers": np.array([[0.15 * np.sin(0.4), 0.15 * np.cos(0.4)]]), "path_ends": np.zeros((1, 2)),
             "speeds": np.zeros(1), "radii": np.array([0.03])}
    verdict = avoidability.judge(arm, np.zeros(3), momentum, **world, link_radius=0.01, max_speed=max_speed,
                                 t0=0.0, window=2.0)
    assert verdict.avoidable is avoidable
    if avoidable:
        _check_witness(arm, np.zeros(3), momentum, world, verdict, 2.0, rho=0.01)


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="max_speed, window and dt must be > 0"):
        avoidability.judge(_arm(False), np.zeros(3), 0.0, **_crossing(1.0), link_radius=RHO, max_speed=0.0, t0=0.0,
                           window=1.0)
    with pytest.raises(ValueError, match="the state must be finite"):
        avoidability.judge(_arm(False), np.array([0.0, np.nan, 0.0]), 0.0, **_crossing(1.0), link_radius=RHO,
                           max_speed=1.0, t0=0.0, window=1.0)


def test_a_contact_after_a_fault_is_judged_from_the_fault_not_before_it() -> None:
    """Of the recorded step starts (time, q, qd, lost per arm), a contact of an arm that faulted inside the window is
    judged from the first step after its fault; otherwise, and for the other arms, from the oldest step."""
    past = [(0.1 * k, np.full((2, 3), k), np.zeros((2, 3)), np.array([False, k >= 3])) for k in range(6)]
    assert avoidability.judged_from(past, 1)[0] == pytest.approx(0.3)
    assert avoidability.judged_from(past, 0)[0] == 0.0
    faulted_before = [(t, q, qd, np.array([True, lost[1]])) for t, q, qd, lost in past]
    assert avoidability.judged_from(faulted_before, 0)[0] == 0.0


@pytest.mark.parametrize("env_kwargs, message", [("[1]", "expected a JSON object such as"),
                                                 ("{bad", "expected a JSON object, got"),
                                                 ('{"scenario": "random"}', "cannot set the scenario"),
                                                 ('{"bogus": 1}', "unknown argument 'bogus'")])
def test_the_script_refuses_bad_env_arguments_in_one_line(env_kwargs, message, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        avoidability.main(["--task", "pan1_env/FaultFormation-v0", "--teams", "1", "--env-kwargs", env_kwargs])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
