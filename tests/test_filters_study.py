"""benchmarks/filters.py, the conservatism study, end to end on a few short episodes."""

import importlib.util
import json
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "filters.py"
_spec = importlib.util.spec_from_file_location("pan1_filters", _PATH)
filters = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(filters)


@pytest.mark.slow
def test_study_runs_three_policies_and_classifies_the_references_failures(tmp_path: Path) -> None:
    out = tmp_path / "study"
    assert filters.main(["--teams", "3", "--max-steps", "40", "--tasks", "end_effector", "--settings", "paper,v1",
                         "--out", str(out)]) == 0
    rows = json.loads((out / "filters.json").read_text())["rows"]
    policies = ("reference", "random", "adversarial")
    assert [(r["setting"], r["policy"]) for r in rows] == [
        (filters.SETTINGS[key][0], policy) for key in ("paper", "v1") for policy in policies]
    for r in rows:
        assert r["cost"] == 0 and r["min_clearance_m"] >= 0  # every policy behind either filter stays out
        if r["policy"] == "reference":  # 2 s are too short to form: every team is classified, none formed
            assert r["success_1cm"] == 0 and sum(r["failure_classes"].values()) == 3
            assert r["failure_classes"]["formed"] == 0
        else:
            assert "failure_classes" not in r
    adversarial = [r for r in rows if r["policy"] == "adversarial"]
    assert all(r["intervention_rate"] > 0 for r in adversarial)  # it does push into the obstacles
    text = (out / "filters.md").read_text()
    assert "freeze (held far from obstacles)" in text and (out / "filters.png").exists()


@pytest.mark.parametrize("argv, message", [(["--policies", "reference,greedy"], "--policies: unknown greedy"),
                                           (["--max-steps", "0"], "--max-steps must be"),
                                           (["--settings", "nope"], "--settings: unknown nope")])
def test_study_refuses_bad_arguments_in_one_line(argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        filters.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
