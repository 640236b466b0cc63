"""The package's shape: one owner of stepping, no upward imports, short modules, named arguments."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("pan1_env", "wrappers", "baselines")
MAX_LINES = 700
SUBSTEP_KERNELS = {"group_advance", "group_advance_parallel", "group_advance_generic"}


def _modules(package: str) -> list[Path]:
    root = ROOT / "pan1_env" / package if package != "pan1_env" else ROOT / "pan1_env"
    if package != "pan1_env":  # wrappers/ and baselines/ are installed as pan1_env.wrappers, pan1_env.baselines
        root = ROOT / package
    return sorted(p for p in root.rglob("*.py") if ".venv" not in p.parts)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_is_longer_than_a_few_screens(package: str) -> None:
    lines = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _modules(package)}
    long = {name: n for name, n in lines.items() if n > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def _calls(path: Path, names: set[str]) -> list[int]:
    tree = ast.parse(path.read_text())
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
            and (getattr(node.func, "attr", None) in names or getattr(node.func, "id", None) in names)]


def test_only_the_engine_calls_the_substep_kernel() -> None:
    callers = {str(p.relative_to(ROOT)) for package in PACKAGES for p in _modules(package)
               if _calls(p, SUBSTEP_KERNELS) and "kernels" not in p.relative_to(ROOT).parts}
    assert callers == {"pan1_env/engine.py"}, callers


def test_the_core_never_imports_the_wrappers() -> None:
    """The engine, tasks and envs sit below the wrappers; the command line (cli.py) is a front end
    that uses everything, so it may."""
    for p in _modules("pan1_env"):
        if p.name == "cli.py":
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                assert not any("wrappers" in n for n in names), f"{p.relative_to(ROOT)} imports {names}"


def test_env_constructors_name_their_arguments() -> None:
    from pan1_env.centralized import CentralizedEnv
    from pan1_env.environment import Pan1ParallelEnv
    from pan1_env.reach import PAReachEnv
    from pan1_env.vector import Pan1VectorEnv

    parallel = inspect.signature(Pan1ParallelEnv.__init__).parameters
    assert {"action_mode", "control_dt", "physics_dt", "max_steps", "render_mode", "safety_filter"} <= set(parallel)
    for cls in (Pan1ParallelEnv, PAReachEnv, CentralizedEnv, Pan1VectorEnv):
        params = inspect.signature(cls.__init__).parameters
        assert "safety_filter" in params, cls.__name__
        assert all(p.kind is not p.VAR_KEYWORD for p in params.values()), cls.__name__
