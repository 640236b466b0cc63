"""The package's shape: one owner of stepping, no upward imports, short modules, named arguments, and
an import graph you can trust: no cycles, no private name imported from another module, and a numpy
reference layer that imports nothing compiled."""

from __future__ import annotations

import ast
import inspect
import re
import subprocess
import sys
from collections.abc import Iterator
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


MAX_COMPILED_LINES = 100


def _compiled_functions(path: Path) -> Iterator[tuple[str, int]]:
    """``(name, lines)`` of each function of ``path`` compiled by numba (decorated ``njit``/``jit``)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef):
            for deco in node.decorator_list:
                target = deco.func if isinstance(deco, ast.Call) else deco
                if getattr(target, "id", getattr(target, "attr", None)) in {"njit", "jit"}:
                    yield node.name, node.end_lineno - node.lineno + 1


def test_no_compiled_function_is_longer_than_a_screen_or_two() -> None:
    compiled = [(str(p.relative_to(ROOT)), name, n) for p in _modules("pan1_env") for name, n in _compiled_functions(p)]
    assert len(compiled) > 20 and any(name == "_advance_arms" for _, name, _ in compiled)  # the scan sees them
    long = [entry for entry in compiled if entry[2] > MAX_COMPILED_LINES]
    assert not long, f"compiled functions over {MAX_COMPILED_LINES} lines: {long}"


#: the views of the env core: each only reshapes what the core returns
VIEWS = ("pan1_env/environment.py", "pan1_env/centralized.py", "pan1_env/vector.py", "pan1_env/reach.py",
         "pan1_env/marl.py", "baselines/vec_env.py", "baselines/arm_vec_env.py", "wrappers/padding.py")
MAX_VIEW_LINES = 200


def test_views_of_the_env_core_are_short() -> None:
    lines = {view: len((ROOT / view).read_text().splitlines()) for view in VIEWS}
    assert all(n <= MAX_VIEW_LINES for n in lines.values()), lines


def test_every_view_steps_through_the_core() -> None:
    """No view calls the engine's step or the task's evaluate itself: the core owns the episode."""
    for view in VIEWS:
        assert not _calls(ROOT / view, {"evaluate", "load_team", "scale_command"}), view
        assert "engine.step(" not in (ROOT / view).read_text(), view


def _calls(path: Path, names: set[str]) -> list[int]:
    tree = ast.parse(path.read_text())
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
            and (getattr(node.func, "attr", None) in names or getattr(node.func, "id", None) in names)]


def test_only_the_engines_step_calls_the_substep_kernel() -> None:
    callers = {str(p.relative_to(ROOT)) for package in PACKAGES for p in _modules(package)
               if _calls(p, SUBSTEP_KERNELS) and "kernels" not in p.relative_to(ROOT).parts}
    assert callers == {"pan1_env/kernel_step.py"}, callers


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


# --------------------------------------------------------------------------- the import graph

#: The numpy reference formulas (docs/ARCHITECTURE.md): the compiled kernels are tested against them,
#: so they must not run on the kernels themselves.
REFERENCE_LAYER = {f"pan1_env.{name}" for name in ("dynamics", "cascade", "formation", "barriers", "safety", "control",
                                                   "bodies")}
COMPILED = ("pan1_env.kernels", "pan1_env.compiled", "numba")



def _module_name(path: Path) -> str:
    """The installed name: ``wrappers/x.py`` is ``pan1_env.wrappers.x`` and ``baselines/x.py`` is
    ``pan1_env.baselines.x`` (pyproject's package-dir); a package's ``__init__.py`` is the package."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] != "pan1_env":
        parts.insert(0, "pan1_env")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> dict[str, Path]:
    return {_module_name(p): p for package in PACKAGES for p in _modules(package)}


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under ``if TYPE_CHECKING:``, which never run."""
    return {id(node) for block in ast.walk(tree) if isinstance(block, ast.If)
            and getattr(block.test, "id", getattr(block.test, "attr", None)) == "TYPE_CHECKING"
            for stmt in block.body for node in ast.walk(stmt)}


_ENTRY_POINT = re.compile(r"(pan1_env(?:\.\w+)+):\w+$")  # an entry point or forwarded signature: "module:name"


def _imports(name: str, path: Path, modules: set[str], runtime_only: bool = True,
             strings: bool = False) -> Iterator[tuple[str, str, int]]:
    """``(target, imported name or "", line)`` for every import in the module, at module level or in a
    function, relative ones resolved; ``target`` is the module that runs: ``from p import m`` of a
    submodule m is an import of ``p.m``."""
    tree = ast.parse(path.read_text())
    skip = _type_checking_only(tree) if runtime_only else set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, "", node.lineno
        elif (isinstance(node, ast.Call) and _called_name(node.func) == "import_module" and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            yield node.args[0].value, "", node.lineno  # importlib.import_module("pan1_env.x"): an import all the same
        elif strings and isinstance(node, ast.Constant) and isinstance(node.value, str):
            entry = _ENTRY_POINT.match(node.value)  # "pan1_env.x:name": x imported when the name is called for
            if entry:
                yield entry.group(1), "", node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                yield (sub, "", node.lineno) if sub in modules else (base, alias.name, node.lineno)


def _called_name(func: ast.expr) -> str:
    """The name a call calls: ``f`` for ``f(…)`` and ``m.f(…)``."""
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def _graph(strings: bool = False) -> dict[str, set[str]]:
    """Who imports whom; with ``strings``, a ``"pan1_env.x:name"`` constant (a Gymnasium entry point, a forwarded
    signature) counts as importing x: not for the cycles, since Gymnasium's registry needs the view's name while the
    view needs the registry's constants, but for the layers."""
    sources = _sources()
    modules = set(sources)
    return {name: {target for target, _, _ in _imports(name, path, modules, strings=strings)
                   if target in modules and target != name} for name, path in sources.items()}


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(frozenset(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_sees_the_installed_names_and_every_kind_of_import() -> None:
    graph = _graph()
    assert "pan1_env.wrappers.shield" in graph and "pan1_env.baselines.policies" in graph
    assert "pan1_env.safety" in graph["pan1_env.kernels.qp"]  # relative, two levels up
    assert "pan1_env.kernels.capsules" in graph["pan1_env.kernels"]  # from . import capsules
    assert "pan1_env.environment" in graph["pan1_env.centralized"]  # inside a function
    assert "pan1_env.environment" in graph["pan1_env"]  # importlib.import_module("pan1_env.environment")
    assert "pan1_env.scenario" not in graph["pan1_env.safety"]  # under TYPE_CHECKING: never runs
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]


def test_no_import_cycles() -> None:
    """Counting imports inside functions too: a cycle there still ties the two modules' designs."""
    cycles = set(_cycles(_graph()))
    assert not cycles, f"import cycles: {[sorted(c) for c in cycles]}"


def test_no_private_name_is_imported_from_another_module() -> None:
    """``from m import _name`` reaches into another module's implementation. The one exception is
    inside :mod:`pan1_env.kernels`, whose files are one compiled unit split by job: they share inlined
    helpers (``_JIT``, ``_spd_solve``, …) that numba needs at module level and that never leave it."""
    sources = _sources()
    offenders = {}
    for name, path in sources.items():
        for target, imported, line in _imports(name, path, set(sources), runtime_only=False):
            if not (imported.startswith("_") and not imported.startswith("__") and target.startswith("pan1_env")):
                continue
            if name.startswith("pan1_env.kernels") and target.startswith("pan1_env.kernels."):
                continue
            offenders[f"{path.relative_to(ROOT)}:{line}"] = (name, target, imported)
    assert not offenders, f"private names imported across modules: {offenders}"


#: The layers, lowest first (docs/ARCHITECTURE.md): a module imports only from its own layer or a lower one. Every
#: module of the package is in exactly one; ``pan1_env.wrappers`` and ``pan1_env.baselines`` are front ends whole.
LAYERS = {
    "reference": ("validation", "dynamics", "cascade", "formation", "motion", "barriers", "safety", "control",
                  "bodies", "toml_values", "scenario", "random_scenario", "scenarios"),
    "compiled": ("kernels", "kernel_groups", "compiled", "compile_notice", "draw_kernel", "team_draw"),
    "engine": ("engine", "kinds", "step_record", "kernel_step", "piqp_filter"),
    "tasks": ("env_ids", "config", "tasks", "observation"),
    "core": ("core",),
    "views": ("environment", "centralized", "vector", "reach", "marl", "marl_specs", "masked_distribution", "render",
              "registration", "benchmarl_task", "benchmarl_tasks", "simulation", "experiment"),
    "front ends": ("", "__main__", "cli", "figures", "warmup", "wrappers", "baselines"),
}


def _layer(module: str) -> int:
    """The rank of ``module``'s layer in :data:`LAYERS` (a submodule is in its package's layer)."""
    rest = module.removeprefix("pan1_env").removeprefix(".")
    top = rest.split(".")[0]  # "" for the package itself
    for rank, names in enumerate(LAYERS.values()):
        if top in names:
            return rank
    raise KeyError(f"{module} is in no layer of LAYERS: place it (and in docs/ARCHITECTURE.md)")


def test_imports_only_go_down_the_layers() -> None:
    """Every module is in a layer, and no import, at module level or in a function, reaches a higher one."""
    graph = _graph(strings=True)
    assert "pan1_env.centralized" in graph["pan1_env.registration"]  # the entry point's string counts
    rank = {name: _layer(name) for name in graph}  # every module, imported or not
    up = [f"{name} ({list(LAYERS)[rank[name]]}) imports {target} ({list(LAYERS)[rank[target]]})"
          for name, targets in graph.items() for target in targets if rank[target] > rank[name]]
    assert not up, "imports going up the layers:\n" + "\n".join(sorted(up))
    assert _layer("pan1_env.kernels.qp") == _layer("pan1_env.compiled") < _layer("pan1_env.config")
    with pytest.raises(KeyError):
        _layer("pan1_env.nowhere")


def _page_layers() -> dict[str, set[str]]:
    """docs/ARCHITECTURE.md's module table as {layer: top-level module names}: a row's first cell names its layer
    (empty: the row above's), its second the modules in backquotes (``baselines/vec_env`` is in ``baselines``)."""
    table = (ROOT / "docs" / "ARCHITECTURE.md").read_text().split("## Modules", 1)[1].split("\n\n", 2)[1]
    layers: dict[str, set[str]] = {}
    layer = ""
    for row in table.splitlines()[2:]:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        layer = {"env core": "core"}.get(cells[0], cells[0]) or layer
        layers.setdefault(layer, set()).update(m.split("/")[0] for m in re.findall(r"`([\w/]+)`", cells[1]))
    return layers


def test_the_architecture_page_places_every_module_as_the_layer_test_does() -> None:
    """docs/ARCHITECTURE.md's module table and :data:`LAYERS` put the same modules in the same layers, in the same
    order, and name every module of the package."""
    page = _page_layers()
    assert list(page) == list(LAYERS)
    for layer, names in LAYERS.items():
        assert page[layer] == set(names) - {"", "__main__"}, layer
    modules = {name.removeprefix("pan1_env.").split(".")[0] for name in _sources()} - {"pan1_env", "__main__"}
    assert modules <= set().union(*page.values()), sorted(modules - set().union(*page.values()))


def test_the_reference_layer_imports_nothing_compiled() -> None:
    """Neither directly nor through anything it imports (type-only imports included)."""
    sources = _sources()
    reached, todo = set(), sorted(REFERENCE_LAYER)
    imported: dict[str, set[str]] = {}
    while todo:
        name = todo.pop()
        if name in reached:
            continue
        reached.add(name)
        imported[name] = {t for t, _, _ in _imports(name, sources[name], set(sources), runtime_only=False)}
        todo += [t for t in imported[name] if t in sources]
    def is_compiled(module: str) -> bool:
        return any(module == c or module.startswith(c + ".") for c in COMPILED)

    compiled = {(name, t) for name, targets in imported.items() if not is_compiled(name) for t in targets
                if is_compiled(t)}
    assert not compiled, f"the numpy reference layer reaches compiled code: {sorted(compiled)}"


def test_the_package_and_its_views_import_no_heavy_library() -> None:
    """``import pan1_env`` and every env view stay light: torch, TorchRL, SB3 and matplotlib load only
    where they are used (pan1_env.marl, the rl baselines, the figures)."""
    heavy = ("torch", "torchrl", "tensordict", "stable_baselines3", "matplotlib", "benchmarl")
    code = ("import sys, pan1_env, pan1_env.environment, pan1_env.centralized, pan1_env.vector, pan1_env.reach, "
            "pan1_env.wrappers, pan1_env.baselines; "
            f"print([m for m in {heavy!r} if m in sys.modules])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr
