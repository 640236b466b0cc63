"""The circulation term (pan1_env.baselines.circulation): it moves the blocked point round the obstacle (checked by
forward kinematics, not by the Jacobian it is built of) and leaves the speed into the obstacle alone; the policy
built on it is a registered name; and the study (benchmarks/circulation.py) runs end to end."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from pan1_env.baselines.circulation import SENSES, circulation_term
from pan1_env.bodies import link_clearance, link_point_jacobian, link_segments
from pan1_env.cascade import passive_velocity_map
from pan1_env.dynamics import end_effector
from tests.arms import random_arm

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "circulation.py"
_spec = importlib.util.spec_from_file_location("pan1_circulation", _PATH)
circulation = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(circulation)


RHO, ACTIVATION = 0.02, 0.03  # a capsule radius, and the clearance within which the term acts


def _term(arm, q, v0, centre, radius, links, sense=1.0):
    return circulation_term(arm, q, v0, centre[None], np.array([radius]), RHO, links, 1.0, sense, ACTIVATION)


def _angle_about(x: np.ndarray, o: np.ndarray) -> float:
    return float(np.arctan2(x[1] - o[1], x[0] - o[0]))


def _middle(arm, q: np.ndarray, link: int) -> np.ndarray:
    a, b = link_segments(arm, q)
    return 0.5 * (a[link] + b[link])


@pytest.mark.parametrize("links", [False, True])
def test_the_term_turns_the_blocked_point_round_the_obstacle_in_its_sense(links: bool) -> None:
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(40):
        arm = random_arm(rng, int(rng.integers(3, 5)))
        q = rng.uniform(-np.pi, np.pi, arm.n_links)
        g0 = passive_velocity_map(arm, q)
        # an obstacle 2 cm beyond the end-effector along the last link, or 2 cm off the middle link's middle
        a, b = link_segments(arm, q)
        ell = 1 if links else arm.n_links - 1
        along = (b[ell] - a[ell]) / np.linalg.norm(b[ell] - a[ell])
        x = 0.5 * (a[ell] + b[ell]) if links else end_effector(arm, q)
        out = np.array([-along[1], along[0]]) if links else along
        # 2 cm of clearance, inside the 3 cm activation only if the capsule's radius counts (links)
        o, r = x + (0.05 + 0.02 + (RHO if links else 0.0)) * out, 0.05
        if links and np.sum(link_clearance(arm, q, o[None], np.array([r]), RHO) < ACTIVATION + 0.02) != 1:
            continue  # another link is near the obstacle too
        # the command that drives that point straight at the obstacle fastest
        J = (link_point_jacobian(arm, q, ell, 0.5 if links else 1.0) @ g0)
        v0 = J.T @ (o - x)
        turns = {}
        for sense, sign in SENSES.items():
            term = _term(arm, q, v0, o, r, links, sign)
            normal = (x - o) @ J
            assert abs(term @ normal) <= 1e-9 * np.linalg.norm(term) * np.linalg.norm(normal)
            step = 1e-5
            moved = (_middle(arm, q + step * g0 @ term, ell) if links else end_effector(arm, q + step * g0 @ term))
            turns[sense] = (_angle_about(moved, o) - _angle_about(x, o)) / step
        assert turns["ccw"] > 0 > turns["cw"]
        # away from the obstacle, or pushing away from it, there is no term
        assert not np.any(_term(arm, q, -v0, o, r, links))
        far = x + 0.2 * out
        if links and np.any(link_clearance(arm, q, far[None], np.array([r]), RHO) < ACTIVATION):
            far = x + 10.0 * out  # another link passes near the first choice
        assert not np.any(_term(arm, q, v0, far, r, links))
        checked += 1
    assert checked >= 10


@pytest.mark.slow
def test_the_study_runs_end_to_end_behind_v1s_filter(tmp_path: Path) -> None:
    out = tmp_path / "circulation.json"
    assert circulation.main(["--teams", "2", "--max-steps", "40", "--flip-after", "0,1", "--delay", "0.5",
                             "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [(r["flip_after_s"], r["sense"]) for r in result["runs"]] == [(0, "ccw"), (0, "cw"), (1, "ccw"), (1, "cw")]
    for r in result["runs"]:
        assert r["cost"] == 0 and r["min_clearance_m"] >= 0  # behind v1's filter whatever the term asks
        assert None not in r["classes"]  # every unformed team has a class
    assert result["command"].startswith("python benchmarks/circulation.py")


@pytest.mark.parametrize("argv, message", [(["--gains", "0"], "--gains: every gain must be finite and > 0"),
                                           (["--senses", "up"], "--senses: choose from ccw, cw"),
                                           (["--activation", "-1"], "--activation must be"),
                                           (["--gains", "x"], "--gains: comma-separated numbers"),
                                           (["--flip-after", "-1"], "--flip-after: every value must be"),
                                           (["--delay", "nan"], "--delay must be finite")])
def test_the_study_refuses_bad_arguments_in_one_line(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        circulation.main(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_the_registered_policy_is_the_law_until_an_arm_stays_blocked() -> None:
    """``make_policy("circulation", env)``: for the first ``delay`` seconds of an episode its actions are the law's
    (a term acts only on an arm blocked that long), always within the action bounds; it refuses an env whose
    actions are not velocities."""
    from pan1_env.baselines import ReferencePolicy, make_policy
    from pan1_env.environment import parallel_env
    from pan1_env.wrappers import SafetyShield

    env = SafetyShield(parallel_env("pan1_env/WholeArmStaticFormation-v1"))
    policy, law = make_policy("circulation", env), ReferencePolicy(env)
    observations, _ = env.reset(seed=2_000_000)
    for _ in range(20):  # 1 s, within the default delay of 5 s
        actions, expected = policy(observations), law(observations)
        for agent in env.agents:
            np.testing.assert_allclose(actions[agent], expected[agent], rtol=1e-6, atol=1e-7)
            assert np.all(np.abs(actions[agent]) <= 1.0)
        observations, *_ = env.step(actions)
    with pytest.raises(ValueError, match="outputs velocities"):
        make_policy("circulation", parallel_env("pan1_env/WholeArmStaticFormation-v1", action_mode="gain"))
    with pytest.raises(ValueError, match="sense must be one of"):
        from pan1_env.baselines.circulation import CirculatingPolicy

        CirculatingPolicy(env, sense="up")
    with pytest.raises(ValueError, match="must be finite and ≥ 0"):
        CirculatingPolicy(env, gain=float("nan"))
