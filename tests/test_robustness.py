"""Robustness (issue 6): the scenario loader under fuzzing, env copies mid-episode, atomic outputs,
numerical faults reported instead of raised.

The bugs these tests found (numbers beyond the float range, overflowing sub-step ratios, the
clearance reported after a fault) are fixed; the tests keep them fixed.
"""

from __future__ import annotations

import copy
import datetime
import math
import os
import pickle
import sys
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pan1_env  # noqa: F401  (registers the Gymnasium ids)
from pan1_env import scenario
from pan1_env.environment import parallel_env
from pan1_env.experiment import atomic_write
from pan1_env.scenario import Scenario, ScenarioError
from pan1_env.wrappers import SafetyShield

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

BUILTIN_PATH = Path(scenario.__file__).parent / "scenarios" / "paper_pa3_square.toml"
BUILTIN_TEXT = BUILTIN_PATH.read_text(encoding="utf-8")
BUILTIN = tomllib.loads(BUILTIN_TEXT)

# PAN1_FUZZ_EXAMPLES=5000 for a longer hunt
FUZZ = settings(
    max_examples=int(os.environ.get("PAN1_FUZZ_EXAMPLES", "300")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


# ------------------------------------------------------------------------------ a TOML writer


def _toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (datetime.datetime, datetime.date, datetime.time)):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_string(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML for {type(v).__name__}")


def _dumps(doc: dict[str, Any]) -> str:
    """A TOML document (every table inline) that ``tomllib`` reads back as ``doc``."""
    return "".join(f"{_toml_string(k)} = {_toml_value(v)}\n" for k, v in doc.items())


# ------------------------------------------------------------------------------ strategies

_CHARS = st.characters(exclude_categories=("Cs",))
# The keys the schema allows in each table (README, "Scenario files").
_ARM_KEYS = ["masses", "lengths", "com", "inertias", "passive_first_joint", "phi", "base", "q0"]
_SCHEMA = {
    "<root>": ["name", "description", "simulation", "controller", "safety", "arm_defaults", "arms", "formation",
               "obstacles"],
    "simulation": ["physics_dt", "control_dt", "horizon"],
    "controller": ["kp", "ke"],
    "safety": ["kappa", "epsilon", "margin", "ignore_unreachable_obstacles"],
    "arm_defaults": _ARM_KEYS[:6],
    "arms": _ARM_KEYS,
    "formation": ["shape", "size", "edges", "distances"],
    "obstacles": ["center", "radius"],
}
_KNOWN_KEYS = sorted({k for keys in _SCHEMA.values() for k in keys})
_KEYS = st.sampled_from(_KNOWN_KEYS) | st.text(_CHARS, max_size=8)
# Numbers: every 64-bit integer (TOML's range) and every float of moderate size, plus the special
# values. Integers beyond 64 bits and floats near the ends of the double range hit known bugs,
# pinned separately below (test_extreme_numbers_raise_scenario_error).
_FLOATS = st.floats(min_value=-1e9, max_value=1e9, allow_nan=False, allow_subnormal=False).filter(
    lambda x: x == 0.0 or abs(x) >= 1e-9)
_SCALARS = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    _FLOATS,
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e-9, 1e9]),
    st.text(_CHARS, max_size=12),
    st.datetimes() | st.dates() | st.times(),
    st.sampled_from(["pi", "-pi/2", "3*pi/4", "π/3", "pi/0", "1/4", "square", "polygon", "", " "]),
)
_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(_KEYS, inner, max_size=5),
    max_leaves=20,
)
_DOCUMENTS = st.dictionaries(_KEYS, _VALUES, max_size=8)


def _slots(node: Any) -> list[tuple[Any, Any]]:
    """Every (container, key or index) in a nested document, the root's children included."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, child in items:
        out.append((node, key))
        out.extend(_slots(child))
    return out


def _schema_keys(doc: dict[str, Any]) -> dict[int, list[str]]:
    """The allowed keys of each table of ``doc`` that sits where the schema expects a table, by id."""
    out = {id(doc): _SCHEMA["<root>"]}
    for name, keys in _SCHEMA.items():
        node = doc.get(name)
        entries = node if isinstance(node, list) and name in ("arms", "obstacles") else [node]
        out.update({id(t): keys for t in entries if isinstance(t, dict)})
    return out


def _mutate(data: st.DataObject, doc: dict[str, Any]) -> dict[str, Any]:
    """Apply 1–4 random edits to a copy of ``doc``: delete, replace with any value, add a key or item.

    Added keys are mostly ones the schema allows in that table, so the value reaches validation.
    """
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 4), label="edits")):
        slots = _slots(doc)
        leaves = [(c, k) for c, k in slots if not isinstance(c[k], (dict, list))]
        op = data.draw(st.sampled_from(["delete", "replace", "perturb", "add"]), label="op")
        if op == "perturb" and leaves:  # a leaf becomes another scalar: reaches the value checks
            container, key = data.draw(st.sampled_from(leaves), label="leaf")
            container[key] = data.draw(_SCALARS, label="scalar")
        elif op in ("delete", "replace") and slots:
            container, key = data.draw(st.sampled_from(slots), label="slot")
            if op == "delete":
                del container[key]
            else:
                container[key] = data.draw(_VALUES, label="value")
        else:
            tables = [doc] + [c[k] for c, k in slots if isinstance(c[k], dict)]
            lists = [c[k] for c, k in slots if isinstance(c[k], list)]
            container = data.draw(st.sampled_from(tables) | st.sampled_from(lists or tables), label="container")
            value = data.draw(_SCALARS | _VALUES, label="value")
            if isinstance(container, dict):
                allowed = _schema_keys(doc).get(id(container))
                keys = st.sampled_from(allowed) | _KEYS if allowed else _KEYS
                container[data.draw(keys, label="key")] = value
            else:
                container.insert(data.draw(st.integers(0, len(container)), label="index"), value)
    return doc


def _accepted_or_scenario_error(call) -> Scenario | None:
    """The property: a valid Scenario, or ScenarioError naming a key. Anything else propagates."""
    try:
        result = call()
    except ScenarioError as err:
        assert isinstance(err, ValueError)
        assert isinstance(err.key, str) and str(err).startswith(f"{err.source}: {err.key}: ")
        return None
    assert isinstance(result, Scenario)
    assert result.n_arms == len(result.q0) >= 1
    assert all(np.all(np.isfinite(q)) for q in result.q0)
    assert 0 < result.physics_dt <= result.control_dt and result.horizon > 0
    return result


# ------------------------------------------------------------------------------ fuzzing the loader


def test_toml_writer_round_trips_the_builtin(tmp_path: Path) -> None:
    # the fuzz tests below go through this writer: it must produce TOML that loads as the original
    text = _dumps(BUILTIN)
    assert tomllib.loads(text) == BUILTIN
    path = tmp_path / "copy.toml"
    path.write_text(text, encoding="utf-8")
    ours, builtin = scenario.load(path), scenario.load("paper_pa3_square")
    assert ours.name == builtin.name and ours.n_arms == builtin.n_arms
    for a, b in zip(ours.q0, builtin.q0, strict=True):
        np.testing.assert_array_equal(a, b)


@FUZZ
@given(doc=_VALUES | _DOCUMENTS)
def test_fuzz_from_dict_random_documents(doc: Any) -> None:
    _accepted_or_scenario_error(lambda: scenario.from_dict(doc))


@FUZZ
@given(data=st.data())
def test_fuzz_from_dict_mutated_builtin(data: st.DataObject) -> None:
    doc = _mutate(data, BUILTIN)
    _accepted_or_scenario_error(lambda: scenario.from_dict(doc, source="<fuzz>"))


_ODD_VALUES = [math.nan, math.inf, -math.inf, -1.0, 0.0, -0.0, 1e-9, 1e9, 2**63 - 1, -(2**63), 3, True, "",
               "pi/0", "x", [], [math.nan], [1.0], [1.0, 2.0], [[0, 1]], {}, {"x": 1}, datetime.date(2000, 1, 1)]


@pytest.mark.parametrize("slot", [f"{t}.{k}" for t, keys in _SCHEMA.items() for k in keys])
def test_every_schema_key_with_odd_values(slot: str) -> None:
    table, key = slot.split(".")
    for value in _ODD_VALUES:
        doc = copy.deepcopy(BUILTIN)
        target = doc if table == "<root>" else doc.setdefault(table, {})
        if isinstance(target, list):  # [[arms]] and [[obstacles]]: the first entry
            target = target[0]
        target[key] = copy.deepcopy(value)
        _accepted_or_scenario_error(lambda doc=doc: scenario.from_dict(doc, source="<odd>"))


@FUZZ
@given(data=st.data())
def test_fuzz_load_mutated_builtin_file(tmp_path: Path, data: st.DataObject) -> None:
    doc = _mutate(data, BUILTIN)
    text = _dumps(doc)
    assert _dumps(tomllib.loads(text)) == text  # the file really holds the mutated document
    path = tmp_path / "fuzz.toml"
    path.write_text(text, encoding="utf-8")
    result = _accepted_or_scenario_error(lambda: scenario.load(path))
    if result is not None:
        assert result.source == str(path)


@FUZZ
@given(doc=_DOCUMENTS)
def test_fuzz_load_random_documents(tmp_path: Path, doc: dict[str, Any]) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_text(_dumps(doc), encoding="utf-8")
    _accepted_or_scenario_error(lambda: scenario.load(path))


@st.composite
def _corrupted_text(draw: st.DrawFn) -> bytes:
    """The built-in file with random byte edits, or random bytes."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=200))
    raw = bytearray(BUILTIN_TEXT.encode("utf-8"))
    for _ in range(draw(st.integers(1, 5))):
        pos = draw(st.integers(0, len(raw)))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        chunk = draw(st.binary(min_size=1, max_size=4) | st.sampled_from([b"[", b"]", b"=", b'"', b"\n", b"[[",
                                                                         b"#", b"{", b"}", b",", b"\xff"]))
        if op == "insert":
            raw[pos:pos] = chunk
        elif op == "delete":
            del raw[pos : pos + len(chunk)]
        else:
            raw[pos : pos + len(chunk)] = chunk
    return bytes(raw)


@FUZZ
@given(raw=_corrupted_text())
def test_fuzz_load_corrupted_bytes(tmp_path: Path, raw: bytes) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_bytes(raw)
    _accepted_or_scenario_error(lambda: scenario.load(path))


def _builtin_with(**tables: dict[str, Any]) -> dict[str, Any]:
    """The built-in document with some keys of some tables replaced (``arms``: every arm)."""
    doc = copy.deepcopy(BUILTIN)
    for table, values in tables.items():
        for target in doc[table] if table == "arms" else [doc[table]]:
            target.update(values)
    return doc


_HUGE_INT = 10**400  # written as a 401-digit integer: valid TOML for tomllib, which does not limit integers
_EXTREME = {
    "integer_beyond_float_kp": lambda: _builtin_with(controller={"kp": _HUGE_INT}),
    "integer_beyond_float_masses": lambda: _builtin_with(arm_defaults={"masses": [_HUGE_INT, 0.3, 0.4, 0.4]}),
    "integer_beyond_float_angle": lambda: _builtin_with(arms={"q0": [_HUGE_INT, 0.1, 0.2, 0.3]}),
    "control_dt_over_physics_dt_overflows": lambda: _builtin_with(simulation={"physics_dt": 1e-300,
                                                                              "control_dt": 1e10}),
    "distances_near_float_max": lambda: {**BUILTIN, "formation": {
        "edges": [[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]], "distances": [1e308, 1e308, 1e308, 1e308, 1.4e308]}},
}


@pytest.mark.parametrize("case", list(_EXTREME))
def test_extreme_numbers_raise_scenario_error(tmp_path: Path, case: str) -> None:
    text = _dumps(_EXTREME[case]())
    tomllib.loads(text)  # the file is valid TOML
    path = tmp_path / "extreme.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError):
        scenario.load(path)


def test_huge_horizon_builds_an_env_or_raises_value_error(tmp_path: Path) -> None:
    # the largest horizon the loader accepts (1e9 s); the env must then either work or say what is wrong
    path = tmp_path / "long.toml"
    path.write_text(_dumps(_builtin_with(simulation={"horizon": 1e9})), encoding="utf-8")
    assert scenario.load(path).horizon == 1e9
    too_long = tmp_path / "too_long.toml"
    too_long.write_text(_dumps(_builtin_with(simulation={"horizon": 1e308})), encoding="utf-8")
    with pytest.raises(ScenarioError, match="out of range"):
        scenario.load(too_long)
    try:
        env = parallel_env(path)
    except ValueError:
        return
    obs, _ = env.reset(seed=0)
    assert all(np.all(np.isfinite(o)) for o in obs.values())


# ------------------------------------------------------------------------------ copies mid-episode

_MIXED = {"links": (2, 3, 4, 3)}


def _make_parallel():
    return parallel_env("paper_pa_mixed_square")


def _make_shielded():
    return SafetyShield(parallel_env("random", random_options=_MIXED))


def _make_gym():
    return gymnasium.make("pan1_env/PaperPA3Square-v0")


def _make_whole_arm():  # the kinds' whole-arm arrays are views of the engine's team arrays
    return SafetyShield(parallel_env("random", random_options={
        "bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.1, 0.3)}))


def _actions(env, rng: np.random.Generator):
    if isinstance(env, gymnasium.Env):
        return rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
    return {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}


def _bits(x: Any) -> Any:
    """A comparable, bit-exact image of an observation, reward or info (NaN == NaN, −0 ≠ +0)."""
    if isinstance(x, dict):
        return {k: _bits(v) for k, v in sorted(x.items())}
    if isinstance(x, (np.ndarray, np.generic, float)):
        a = np.asarray(x)
        return (a.dtype.str, a.shape, a.tobytes())
    return x


def _cost(info: dict) -> Any:
    if "agents" in info:  # the Gymnasium view: the team total and the per-arm costs
        return info["cost"], {a: i["cost"] for a, i in info["agents"].items()}
    return {a: i["cost"] for a, i in info.items()}


def _continue(env, actions: list) -> list:
    out = []
    for act in actions:
        obs, reward, term, trunc, info = env.step(act)
        out.append((_bits(obs), _bits(reward), _bits(term), _bits(trunc), _cost(info), _bits(info)))
    return out


@pytest.mark.parametrize("make", [_make_parallel, _make_shielded, _make_gym, _make_whole_arm],
                         ids=["parallel_mixed", "shielded_random", "gym_pa3", "shielded_whole_arm"])
def test_pickled_and_copied_env_continues_identically(make) -> None:
    env = make()
    env.reset(seed=5)
    rng = np.random.default_rng(11)
    for _ in range(20):
        env.step(_actions(env, rng))
    pickled = pickle.loads(pickle.dumps(env))
    copied = copy.deepcopy(env)
    later = [_actions(env, rng) for _ in range(30)]
    # the original runs first: a copy sharing any mutable state with it would then diverge
    reference = _continue(env, later)
    assert any(r[1] != reference[0][1] for r in reference), "the rollout should change the reward"
    for twin in (pickled, copied):
        assert twin is not env
        got = _continue(twin, later)
        for step, (a, b) in enumerate(zip(got, reference, strict=True)):
            assert a[0] == b[0], f"observations differ at step {step}"
            assert a[1] == b[1], f"rewards differ at step {step}"
            assert a[4] == b[4], f"costs differ at step {step}"
            assert a == b, f"terminations, truncations or infos differ at step {step}"


def test_copy_keeps_the_reset_generator() -> None:
    # a copied random env draws the same next team on reset() as the original
    env = parallel_env("random", random_options=_MIXED)
    env.reset(seed=3)
    twin = pickle.loads(pickle.dumps(env))
    a, _ = env.reset()
    b, _ = twin.reset()
    assert _bits(a) == _bits(b)
    np.testing.assert_array_equal([arm.base for arm in env.scenario.arms], [arm.base for arm in twin.scenario.arms])


# ------------------------------------------------------------------------------ atomic outputs


class _Boom(Exception):
    pass


def _listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.mark.parametrize("mode", ["wb", "w"])
@pytest.mark.parametrize("error", [_Boom, KeyboardInterrupt])
def test_failed_atomic_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path: Path, mode: str,
                                                                        error: type[BaseException]) -> None:
    path = tmp_path / "metrics.json"
    path.write_bytes(b'{"good": true}\n')
    (tmp_path / "neighbour.txt").write_bytes(b"untouched")
    before = _listing(tmp_path)
    half = b"x" * 100_000 if mode == "wb" else "x" * 100_000

    def write(fh) -> None:
        fh.write(half)
        fh.flush()  # the partial content reaches the temporary file
        raise error("disk full, halfway")

    with pytest.raises(error, match="halfway"):
        atomic_write(path, write, mode=mode)
    assert _listing(tmp_path) == before


def test_failed_atomic_write_creates_nothing(tmp_path: Path) -> None:
    out = tmp_path / "new" / "trajectory.npz"

    def write(fh) -> None:
        np.savez_compressed(fh, q=np.arange(10.0))
        raise _Boom("halfway")

    with pytest.raises(_Boom):
        atomic_write(out, write)
    assert list(out.parent.iterdir()) == []


@pytest.mark.parametrize("existed", [True, False])
def test_atomic_write_replaces_the_file(tmp_path: Path, existed: bool) -> None:
    path = tmp_path / "summary.md"
    if existed:
        path.write_text("old table\n")
    reference = tmp_path / "plain.md"  # what an ordinary open() creates: the mode the umask allows
    reference.write_text("")
    atomic_write(path, lambda fh: fh.write("new table\n"), mode="w")
    assert path.read_text() == "new table\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.md", "summary.md"]
    assert path.stat().st_mode == reference.stat().st_mode


def test_write_outputs_keeps_good_metrics_when_serialising_fails(tmp_path: Path) -> None:
    from pan1_env.experiment import RunResult, write_outputs

    good = RunResult({"steps": 1}, {"time": np.zeros(2)})
    paths = write_outputs(good, tmp_path)
    before = _listing(tmp_path)
    bad = RunResult({"steps": 2, "not_json": {1, 2}}, {"time": np.ones(3)})
    with pytest.raises(TypeError):
        write_outputs(bad, tmp_path)
    after = _listing(tmp_path)
    assert set(after) == set(before)  # no temporary left behind
    assert after[paths["metrics"].name] == before[paths["metrics"].name]


# ------------------------------------------------------------------------------ numerical faults


def _full_actions(env, rng: np.random.Generator):
    return {a: rng.choice([-1.0, 1.0], env.action_space(a).shape).astype(np.float32) for a in env.agents}


def _nearest_clearance(env, agent: str, obs: np.ndarray) -> float:
    """Clearance of the agent's end-effector to its nearest obstacle, from the documented observation."""
    core = env.unwrapped
    n = core.scenario.arms[core.possible_agents.index(agent)].n_links
    k = core.n_obstacle_obs
    slot = obs.size - 5 * k  # the first (nearest) obstacle slot: present, dx, dy, r, h
    present, dx, dy, r = obs[slot : slot + 4].astype(float)
    assert slot >= 3 * n + 2 and present == 1.0
    return math.hypot(dx, dy) - r


_EXTREME_ENVS = {
    "torque_1e6": lambda: parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e6),
    "velocity_1e6": lambda: parallel_env("paper_pa3_square", max_joint_speed=1e6),
    "shielded_torque_1e6": lambda: SafetyShield(parallel_env("paper_pa3_square", action_mode="torque",
                                                             max_torque=1e6)),
}


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("name", sorted(_EXTREME_ENVS))
def test_extreme_actions_are_reported_not_raised(name: str) -> None:
    env = _EXTREME_ENVS[name]()
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    start = {a: o.copy() for a, o in obs.items()}
    for _ in range(200):
        obs, rewards, terms, truncs, infos = env.step(_full_actions(env, rng))
        assert set(obs) == set(rewards) == set(infos) == set(env.possible_agents)
        for agent in obs:
            assert np.all(np.isfinite(obs[agent])), (agent, obs[agent])
            assert env.observation_space(agent).contains(obs[agent])
            assert np.isfinite(rewards[agent])
            assert np.isfinite(infos[agent]["formation_error"]) and not np.isnan(infos[agent]["min_clearance"])
        assert np.all(np.isfinite(env.unwrapped.state()))
        q, qd = env.unwrapped.joint_state()
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd)), "the state must stay finite (or be reported)"
        faults = [infos[a].get("fault") for a in env.possible_agents]
        if any(f is not None for f in faults):
            assert all(isinstance(f, str) and f for f in faults)
            assert all(truncs.values()) and not any(terms.values())
            assert env.agents == []
            with pytest.raises(RuntimeError, match="reset"):
                env.step(_full_actions(env, rng))
        else:
            core = env.unwrapped
            assert core.num_steps >= core.max_steps or not any(truncs.values()), "truncated without a reason"
            for agent in obs:  # the step's minimum covers its last sub-step
                assert infos[agent]["min_clearance"] <= _nearest_clearance(env, agent, obs[agent]) + 1e-4
        if not env.agents:
            obs, _ = env.reset(seed=0)
            for agent in obs:  # a reset recovers the starting state, fault or not
                np.testing.assert_array_equal(obs[agent], start[agent])


def _blow_up(env):
    """Step the paper PA3 team with 1e300 N·m: the state cannot stay finite."""
    env.reset(seed=0)
    return env.step({a: np.ones(env.action_space(a).shape, np.float32) for a in env.agents})


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_non_finite_state_truncates_with_a_fault_and_reset_recovers() -> None:
    env = parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e300)
    fresh, _ = parallel_env("paper_pa3_square").reset(seed=0)
    obs, rewards, terms, truncs, infos = _blow_up(env)
    assert all(truncs.values()) and not any(terms.values()) and env.agents == []
    assert all("non-finite" in infos[a]["fault"] for a in env.possible_agents)
    assert all(np.all(np.isfinite(o)) for o in obs.values())
    assert all(np.isfinite(r) for r in rewards.values())
    q, qd = env.joint_state()
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd))
    obs, _ = env.reset(seed=0)
    for agent in obs:
        np.testing.assert_array_equal(obs[agent], fresh[agent])


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_gym_view_reports_the_fault() -> None:
    env = gymnasium.make("pan1_env/PaperPA3Square-v0", action_mode="torque", max_torque=1e300)
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.ones(env.action_space.shape, np.float32))
    assert truncated and not terminated
    assert "non-finite" in info["fault"]
    assert np.all(np.isfinite(obs)) and np.isfinite(reward)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_fault_step_reports_a_finite_min_clearance() -> None:
    env = parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e300)
    obs, _, _, _, infos = _blow_up(env)
    for agent in env.possible_agents:
        assert "fault" in infos[agent]
        assert infos[agent]["min_clearance"] <= _nearest_clearance(env, agent, obs[agent]) + 1e-4


# ------------------------------------------------------------------------------ rejected actions leave no trace

_BAD_PARALLEL = {  # mode, corruption of a good action dict, what the error says
    "torque_inf": ("torque", lambda good: {**good, "arm_1": np.array([0.0, np.inf, 0.0], np.float32)}, "NaN or inf"),
    "torque_minus_inf": ("torque", lambda good: {**good, "arm_0": np.array([-np.inf, 0.0, 0.0])}, "NaN or inf"),
    "torque_nan": ("torque", lambda good: {**good, "arm_3": np.array([0.0, 0.0, np.nan])}, "NaN or inf"),
    "torque_string": ("torque", lambda good: {**good, "arm_2": "full"},
                      r"action for arm_2 must be an array of numbers of shape \(3,\), got str 'full'"),
    "torque_dict": ("torque", lambda good: {**good, "arm_1": {"q": 1.0}},
                    r"action for arm_1 must be an array of numbers of shape \(3,\), got dict \{'q': 1.0\}"),
    "velocity_ragged": ("velocity", lambda good: {**good, "arm_0": [0.1, [0.2, 0.3], 0.4]},
                        r"action for arm_0 must be an array of numbers of shape \(3,\), got list"),
    "torque_none": ("torque", lambda good: {**good, "arm_2": None}, "shape"),
    "velocity_list_not_dict": ("velocity", lambda good: list(good.values()), "dict keyed by agent"),
    "velocity_scalar": ("velocity", lambda good: {**good, "arm_0": 0.5}, "shape"),
}


@pytest.mark.parametrize("shielded", [False, True], ids=["plain", "shielded"])
@pytest.mark.parametrize("case", sorted(_BAD_PARALLEL))
def test_rejected_action_leaves_no_trace(case: str, shielded: bool) -> None:
    mode, corrupt, match = _BAD_PARALLEL[case]

    def make():
        env = parallel_env("paper_pa3_square", action_mode=mode)
        return SafetyShield(env) if shielded else env

    env, twin = make(), make()
    rng = np.random.default_rng(1)
    env.reset(seed=0)
    twin.reset(seed=0)
    for _ in range(3):  # mid-episode, with a previous command and v* in the state
        act = _actions(env, rng)
        env.step(act)
        twin.step(act)
    good = _actions(env, rng)
    with pytest.raises(ValueError, match=match):
        env.step(corrupt(good))
    assert env.unwrapped.num_steps == twin.unwrapped.num_steps == 3
    for _ in range(5):
        act = _actions(env, rng)
        assert _continue(env, [act]) == _continue(twin, [act])


_GYM_VIEW_MESSAGES = {
    "nan": "NaN or inf", "inf": "NaN or inf", "short": r"shape \(12,\), got \(11,\)",
    "long": r"shape \(12,\), got \(13,\)",
    "dict": r"action must be an array of numbers of shape \(12,\), got dict \{'arm_0'",
    "string": r"action must be an array of numbers of shape \(12,\), got str 'zeros'",
}


@pytest.mark.parametrize("bad", sorted(_GYM_VIEW_MESSAGES))
def test_gym_view_rejects_bad_action_without_trace(bad: str) -> None:
    env, twin = gymnasium.make("pan1_env/PaperPA3Square-v0"), gymnasium.make("pan1_env/PaperPA3Square-v0")
    rng = np.random.default_rng(2)
    env.reset(seed=0)
    twin.reset(seed=0)
    for _ in range(2):
        act = _actions(env, rng)
        env.step(act)
        twin.step(act)
    action = _actions(env, rng)
    if bad in ("nan", "inf"):
        action[4] = np.nan if bad == "nan" else np.inf
    elif bad in ("short", "long"):
        action = action[:-1] if bad == "short" else np.append(action, 0.0)
    elif bad == "dict":  # the parallel env's per-agent dict, given to the one-agent view
        action = {f"arm_{i}": part for i, part in enumerate(np.split(action, 4))}
    else:
        action = "zeros"
    with pytest.raises(ValueError, match=_GYM_VIEW_MESSAGES[bad]):
        env.step(action)
    for _ in range(5):
        act = _actions(env, rng)
        assert _continue(env, [act]) == _continue(twin, [act])
