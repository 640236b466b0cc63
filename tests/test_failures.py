"""The failure classifier of benchmarks/failures.py on synthetic episode summaries (no episodes run)."""

import importlib.util
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "failures.py"
_spec = importlib.util.spec_from_file_location("pan1_failures", _PATH)
failures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(failures)


def _record(**overrides) -> dict:
    """A failed, still-converging episode of 4 arms: regular arms, no shield activity, moving."""
    rec = {
        "final_error": 0.2,
        "error_window_start": 0.3,
        "sigma_min": [0.3, 0.2, 0.25, 0.4],
        "grad_norm": [0.5, 0.4, 0.3, 0.2],
        "clearance": [0.3, 0.4, 0.5, 0.6],
        "blocked_fraction": [0.0, 0.0, 0.0, 0.0],
        "travel": [0.05, 0.02, 0.01, 0.03],
    }
    rec.update(overrides)
    return rec


STOPPED = {"travel": [0.0, 0.001, 0.0, 0.002], "error_window_start": 0.2005}

CASES = {
    "deadlock_obstacle": {"blocked_fraction": [0.0, 1.0, 0.0, 0.0], "clearance": [0.3, 0.01, 0.5, 0.6], **STOPPED},
    "shield_far": {"blocked_fraction": [0.0, 1.0, 0.0, 0.0], "clearance": [0.3, 1.5, 0.5, 0.6], **STOPPED},
    "singular_arm": {"sigma_min": [0.3, 1e-5, 0.25, 0.4], **STOPPED},
    "local_minimum": STOPPED,
    "not_converged": {},
}


def test_every_class_is_reachable() -> None:
    assert set(CASES) == set(failures.CLASSES)
    for expected, overrides in CASES.items():
        assert failures.classify(_record(**overrides)) == expected, expected


@pytest.mark.parametrize("overrides", list(CASES.values()), ids=list(CASES))
def test_a_success_is_not_classified(overrides) -> None:
    assert failures.classify(_record(final_error=0.5 * failures.SUCCESS_TOL, **overrides)) is None


def test_order_and_boundaries() -> None:
    # a blocked arm near an obstacle wins over a far one and over a singular arm
    rec = _record(blocked_fraction=[1.0, 1.0, 0, 0], clearance=[2.0, 0.01, 1, 1], sigma_min=[0, 0, 1, 1])
    assert failures.classify(rec) == "deadlock_obstacle"
    # blocked in less than BLOCKED_FRACTION of the window: not blocked
    below = 0.99 * failures.BLOCKED_FRACTION
    assert failures.classify(_record(blocked_fraction=[below, 0, 0, 0], **STOPPED)) == "local_minimum"
    # a singular arm that is no longer asked to move is not the cause
    rec = _record(sigma_min=[0.0, 0.3, 0.3, 0.3], grad_norm=[0.5 * failures.GRAD_ACTIVE, 1, 1, 1], **STOPPED)
    assert failures.classify(rec) == "local_minimum"
    # stopped, but the error still fell by more than STOP_DECREASE over the window: not converged
    rec = _record(travel=[0.0] * 4, error_window_start=0.2 / (1 - 2 * failures.STOP_DECREASE))
    assert failures.classify(rec) == "not_converged"
    # one arm still travelling: not converged
    assert failures.classify(_record(**{**STOPPED, "travel": [0, 0, 2 * failures.STOP_TRAVEL, 0]})) == "not_converged"


def test_the_table_counts_every_class() -> None:
    records = [_record(**o) for o in CASES.values()]
    records[1]["sigma_min"] = [0.0, 0.3, 0.3, 0.3]  # the far-blocked arm is also stretched
    for r in records:
        r["class"] = failures.classify(r)
        r["criteria_met"] = [c for c, ok in failures.criteria(r).items() if ok]
        r.update(success_1cm=False, success_2cm=False, success_5cm=r["class"] == "not_converged")
    text = failures.table(records)
    for title in failures.CLASS_TITLES.values():
        assert f"| {title} | 1 | 20.0 % |" in text
    assert f"| {failures.CLASS_TITLES['shield_far']} | 1 | 20.0 % | 1 |" in text
    assert f"| {failures.CLASS_TITLES['deadlock_obstacle']} | 1 | 20.0 % | 0 |" in text
    assert "| shielded reference | 0.0 % | 0.0 % | 20.0 % |" in text


def test_a_task_that_is_not_random_teams_exits_2_with_one_line(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        failures.main(["--task", "paper_pa3_square", "--episodes", "1", "--out", str(tmp_path / "out")])
    assert exit_info.value.code == 2
    assert "--task paper_pa3_square: not random teams" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("lever, standoff", [(0.5, 0.0265), (1.0, 0.0441), (2.0, 0.0643)])
def test_the_robust_ratio_is_one_where_a_pushed_arm_rests_behind_v1(lever: float, standoff: float) -> None:
    """The standoffs that tests/test_barrier_choices.py measures in closed loop behind v1's rows (κ = 0.5, ε = 5,
    λ = 50, distance barrier, so ‖L_g0 h‖ is the lever): the diagnostic is 1 there, above it nearer, below farther."""
    def ratio(clearance: float) -> float:
        return failures.robust_ratio(lever**2, clearance, 0.5, 5.0, 50.0)

    assert ratio(standoff) == pytest.approx(1.0, abs=0.02)
    assert ratio(standoff - 0.005) > 1.0 > ratio(standoff + 0.005)
    assert failures.robust_ratio(0.3, 0.02, 0.5, 5.0) == pytest.approx(0.3 / (5.0 * 0.5 * 0.02))  # the paper's
    assert failures.robust_ratio(0.3, 0.0, 0.5, 5.0, 50.0) == float("inf")
