"""Scenario files: the two built-in paper scenarios and the validation of user TOML files."""

import math
from pathlib import Path

import numpy as np
import pytest

from pan1_env import scenario
from pan1_env.dynamics import end_effector
from pan1_env.scenario import ScenarioError

PI = math.pi


# --------------------------------------------------------------------------- built-in scenarios


def _edge_set(form) -> set[tuple[int, int]]:
    return {tuple(sorted(e)) for e in form.edges.tolist()}


def test_builtin_names() -> None:
    names = scenario.builtin_names()
    assert "paper_pa3_square" in names and "paper_pa_mixed_square" in names


def test_paper_pa3_square_matches_paper_scenarios_md() -> None:
    sc = scenario.load("paper_pa3_square")
    assert sc.name == "paper_pa3_square"
    assert sc.n_arms == 4
    for arm in sc.arms:
        assert arm.n_links == 4 and arm.passive_first_joint and arm.n_actuated == 3
        np.testing.assert_allclose(arm.masses, [0.3, 0.3, 0.4, 0.4])
        np.testing.assert_allclose(arm.lengths, [0.3, 0.3, 0.4, 0.4])
        np.testing.assert_allclose(arm.com, [0.15, 0.15, 0.2, 0.2])
        np.testing.assert_allclose(arm.inertias, [0.0022, 0.0022, 0.0053, 0.0053])
        assert arm.phi == 0.0
    np.testing.assert_allclose([a.base for a in sc.arms], [[0, 0], [2.5, 0], [2.5, 2], [0, 2]])
    # Initial angles with the signs restored in docs/PAPER_REPRODUCTION.md (paper arms 1..4 = code 0..3).
    expected_q0 = [
        [PI / 3, -PI / 6, PI / 4, -PI / 8],
        [PI / 4, 0.0, -PI / 3, -PI / 2],
        [-3 * PI / 4, PI / 4, -PI / 3, -PI / 6],
        [3 * PI / 4, PI / 4, -PI / 2, PI / 8],
    ]
    for q, ref in zip(sc.q0, expected_q0, strict=True):
        np.testing.assert_allclose(q, ref, rtol=1e-15, atol=0)
    assert sc.q0[2][0] == pytest.approx(-3 * PI / 4, rel=1e-15)
    # Square of side 0.7 with one diagonal.
    assert _edge_set(sc.formation) == {(0, 1), (1, 2), (2, 3), (0, 3), (0, 2)}
    lengths = dict(zip(map(lambda e: tuple(sorted(e)), sc.formation.edges.tolist()),
                       sc.formation.distances, strict=True))
    assert lengths[(0, 1)] == pytest.approx(0.7) and lengths[(0, 2)] == pytest.approx(0.7 * 2**0.5)
    np.testing.assert_allclose(sc.obstacles.centers, [[1.20, 0.70], [0.90, 1.40], [1.04, 1.25]])
    np.testing.assert_allclose(sc.obstacles.radii, [0.08, 0.08, 0.08])
    assert (sc.kp, sc.ke, sc.filter.kappa, sc.filter.epsilon) == (2.0, 100.0, 0.5, 5.0)
    assert sc.physics_dt == 1e-3 and sc.control_dt == 1e-3 and sc.substeps == 1
    assert sc.horizon == 100.0
    # No end-effector starts inside an obstacle.
    for arm, q in zip(sc.arms, sc.q0, strict=True):
        p = end_effector(arm, q)
        assert np.all(np.linalg.norm(sc.obstacles.centers - p, axis=1) > sc.obstacles.radii)


def test_paper_pa_mixed_square_matches_paper_scenarios_md() -> None:
    sc = scenario.load("paper_pa_mixed_square")
    assert sc.n_arms == 4
    assert [a.passive_first_joint for a in sc.arms] == [False, False, False, True]
    assert [a.n_actuated for a in sc.arms] == [2, 2, 2, 1]
    for arm in sc.arms:
        np.testing.assert_allclose(arm.masses, [0.2, 0.2])
        np.testing.assert_allclose(arm.lengths, [0.5, 0.5])
        np.testing.assert_allclose(arm.com, [0.15, 0.15])
        np.testing.assert_allclose(arm.inertias, [0.005, 0.005])
    np.testing.assert_allclose([a.base for a in sc.arms], [[0, 2], [2, 2], [2.5, 3], [0.5, 3]])
    expected_q0 = [[PI / 3, PI / 6], [0.0, 2 * PI / 3], [PI / 3, PI / 3], [0.0, PI / 2]]
    for q, ref in zip(sc.q0, expected_q0, strict=True):
        np.testing.assert_allclose(q, ref, rtol=1e-15, atol=0)
    assert _edge_set(sc.formation) == {(0, 1), (1, 2), (2, 3), (0, 3), (0, 2)}
    assert min(sc.formation.distances) == pytest.approx(0.8)
    np.testing.assert_allclose(sc.obstacles.centers, [[1.0, 3.3]])
    np.testing.assert_allclose(sc.obstacles.radii, [0.1])
    assert (sc.kp, sc.ke, sc.filter.kappa, sc.filter.epsilon) == (1.0, 100.0, 0.2, 20.0)
    # Only the PA arm (paper arm 4) can reach the obstacle: ‖o − p0‖ ≤ Σ L + r for it alone.
    reach = [np.linalg.norm(np.array([1.0, 3.3]) - a.base) <= a.lengths.sum() + 0.1 for a in sc.arms]
    assert reach == [False, False, False, True]
    np.testing.assert_array_equal(sc.obstacle_mask(), np.array(reach)[:, None])


def test_load_returns_scenario_unchanged() -> None:
    sc = scenario.load("paper_pa3_square")
    assert scenario.load(sc) is sc
    with pytest.raises(TypeError):
        scenario.load(42)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- user files

VALID = """\
name = "tiny"
description = "three 2-link arms"

[simulation]
physics_dt = 0.001
control_dt = 0.005
horizon = 2.0

[controller]
kp = 1.5
ke = 50.0

[safety]
kappa = 0.5
epsilon = 5.0

[arm_defaults]
masses = [0.2, 0.2]
lengths = [0.5, 0.5]
com = [0.25, 0.25]
inertias = [0.005, 0.005]

[[arms]]
base = [0.0, 0.0]
q0 = ["pi/4", "-pi/6"]

[[arms]]
base = [2.0, 0.0]
q0 = [0.0, 0.5]
passive_first_joint = false

[[arms]]
base = [1.0, 1.5]
q0 = ["-3*pi/4", "pi/3"]

[formation]
shape = "polygon"
size = 0.5

[[obstacles]]
center = [1.0, 0.5]
radius = 0.1
"""


def _write(tmp_path: Path, text: str, name: str = "case.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _replace(old: str, new: str, count: int = 1) -> str:
    assert VALID.count(old) >= count, old
    return VALID.replace(old, new, count)


def _replace_nth(old: str, new: str, n: int) -> str:
    """Replace the n-th (0-based) occurrence of ``old``."""
    parts = VALID.split(old)
    assert len(parts) > n + 1, old
    return old.join(parts[: n + 1]) + new + old.join(parts[n + 1 :])


def test_valid_file_loads_by_path(tmp_path: Path) -> None:
    path = _write(tmp_path, VALID)
    for arg in (path, str(path)):
        sc = scenario.load(arg)
        assert sc.name == "tiny" and sc.description == "three 2-link arms"
        assert sc.n_arms == 3
        assert sc.physics_dt == 0.001 and sc.control_dt == 0.005 and sc.substeps == 5
        assert (sc.kp, sc.ke, sc.filter.kappa, sc.filter.epsilon, sc.horizon) == (1.5, 50.0, 0.5, 5.0, 2.0)
        assert sc.filter.margin == 0.0 and sc.ignore_unreachable_obstacles is True
        assert [a.passive_first_joint for a in sc.arms] == [True, False, True]  # default: passive
        assert [a.passive_damping for a in sc.arms] == [0.0, 0.0, 0.0]  # default: the paper's frictionless joint
        np.testing.assert_allclose(sc.q0[0], [PI / 4, -PI / 6], rtol=1e-15)
        np.testing.assert_allclose(sc.q0[1], [0.0, 0.5], rtol=1e-15)
        np.testing.assert_allclose(sc.q0[2], [-3 * PI / 4, PI / 3], rtol=1e-15)
        assert len(sc.formation.edges) == 3  # a triangle: 2N − 3 = 3
        np.testing.assert_allclose(sc.formation.distances, 0.5)
        assert sc.source == str(path)


def test_passive_damping_is_read_per_arm(tmp_path: Path) -> None:
    text = _replace("masses = [0.2, 0.2]", "masses = [0.2, 0.2]\npassive_damping = 0.3")
    text = text.replace("base = [2.0, 0.0]\n", "base = [2.0, 0.0]\npassive_damping = 1\n")
    sc = scenario.load(_write(tmp_path, text))
    assert [a.passive_damping for a in sc.arms] == [0.3, 1.0, 0.3]


def test_name_defaults_to_file_stem_and_overrides_apply(tmp_path: Path) -> None:
    text = _replace('name = "tiny"\n', "")
    text = text.replace("base = [2.0, 0.0]\n", "base = [2.0, 0.0]\nmasses = [1.0, 2.0]\nphi = \"pi/2\"\n")
    sc = scenario.load(_write(tmp_path, text, "my_team.toml"))
    assert sc.name == "my_team"
    np.testing.assert_allclose(sc.arms[1].masses, [1.0, 2.0])
    np.testing.assert_allclose(sc.arms[0].masses, [0.2, 0.2])
    assert sc.arms[1].phi == pytest.approx(PI / 2, rel=1e-15)


def test_formation_by_edges(tmp_path: Path) -> None:
    text = _replace(
        'shape = "polygon"\nsize = 0.5\n', "edges = [[0, 1], [1, 2], [0, 2]]\ndistances = [0.3, 0.4, 0.5]\n"
    )
    sc = scenario.load(_write(tmp_path, text))
    assert _edge_set(sc.formation) == {(0, 1), (1, 2), (0, 2)}
    np.testing.assert_allclose(sc.formation.distances, [0.3, 0.4, 0.5])


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        ('"pi"', PI),
        ('"-pi"', -PI),
        ('"+pi/2"', PI / 2),
        ('"3*pi/4"', 3 * PI / 4),
        ('"3pi/4"', 3 * PI / 4),
        ('" - 3 * pi / 4 "', -3 * PI / 4),
        ('"π/3"', PI / 3),
        ('"0.25"', 0.25),
        ('"1/4"', 0.25),
        ("-1.5", -1.5),
        ("2", 2.0),
    ],
)
def test_angle_strings(tmp_path: Path, angle: str, expected: float) -> None:
    text = _replace('q0 = ["pi/4", "-pi/6"]', f'q0 = [{angle}, "-pi/6"]')
    sc = scenario.load(_write(tmp_path, text))
    assert sc.q0[0][0] == pytest.approx(expected, rel=1e-15, abs=1e-15)


# Each broken variant: (id, TOML text, the key the error must name).
BROKEN = [
    # missing keys and tables
    ("missing_horizon", _replace("horizon = 2.0\n", ""), "simulation.horizon"),
    ("missing_physics_dt", _replace("physics_dt = 0.001\n", ""), "simulation.physics_dt"),
    ("missing_controller", _replace("[controller]\nkp = 1.5\nke = 50.0\n", ""), "controller"),
    ("missing_kappa", _replace("kappa = 0.5\n", ""), "safety.kappa"),
    ("missing_q0", _replace_nth("q0 = [0.0, 0.5]\n", "", 0), "arms[1].q0"),
    ("missing_base", _replace_nth("base = [1.0, 1.5]\n", "", 0), "arms[2].base"),
    ("missing_masses", _replace("masses = [0.2, 0.2]\n", ""), "arms[0].masses"),
    ("missing_radius", _replace("radius = 0.1\n", ""), "obstacles[0].radius"),
    ("missing_center", _replace("center = [1.0, 0.5]\n", ""), "obstacles[0].center"),
    ("missing_formation", _replace('[formation]\nshape = "polygon"\nsize = 0.5\n', ""), "formation"),
    # unknown keys
    ("unknown_top", "colour = 'red'\n" + VALID, "colour"),
    ("unknown_simulation", _replace("horizon = 2.0\n", "horizon = 2.0\nsubsteps = 3\n"),
     "simulation.substeps"),
    ("unknown_arm", _replace("passive_first_joint = false\n", "passive_first_joint = false\nmass = 1\n"),
     "arms[1].mass"),
    ("unknown_default", _replace("inertias = [0.005, 0.005]\n", "inertias = [0.005, 0.005]\nbase = [0, 0]\n"),
     "arm_defaults.base"),
    ("unknown_obstacle", _replace("radius = 0.1\n", "radius = 0.1\nheight = 2.0\n"),
     "obstacles[0].height"),
    # wrong types
    ("kp_string", _replace("kp = 1.5", 'kp = "fast"'), "controller.kp"),
    ("kp_bool", _replace("kp = 1.5", "kp = true"), "controller.kp"),
    ("masses_string", _replace("passive_first_joint = false\n",
                               'passive_first_joint = false\nmasses = "heavy"\n'), "arms[1].masses"),
    ("base_string_entry", _replace("base = [0.0, 0.0]", 'base = [0.0, "a"]'), "arms[0].base"),
    ("base_three", _replace("base = [0.0, 0.0]", "base = [0.0, 0.0, 0.0]"), "arms[0].base"),
    ("passive_int", _replace("passive_first_joint = false", "passive_first_joint = 0"),
     "arms[1].passive_first_joint"),
    ("damping_negative", _replace("passive_first_joint = false\n",
                                  "passive_first_joint = false\npassive_damping = -0.1\n"), "arms[1].passive_damping"),
    ("damping_string", _replace("masses = [0.2, 0.2]", 'masses = [0.2, 0.2]\npassive_damping = "low"'),
     "arm_defaults.passive_damping"),
    ("simulation_not_table", _replace("[simulation]\nphysics_dt = 0.001\ncontrol_dt = 0.005\nhorizon = 2.0\n",
                                      "simulation = 3\n"), "simulation"),
    ("radius_string", _replace("radius = 0.1", 'radius = "big"'), "obstacles[0].radius"),
    ("shape_number", _replace('shape = "polygon"', "shape = 4"), "formation.shape"),
    # bad values
    ("negative_mass", _replace("passive_first_joint = false\n",
                               "passive_first_joint = false\nmasses = [0.2, -0.2]\n"), "arms[1].masses"),
    ("zero_length", _replace("lengths = [0.5, 0.5]", "lengths = [0.5, 0.0]"), "arm_defaults.lengths"),
    # a value inherited from [arm_defaults] is reported there, and a size mismatch names the odd list out
    ("defaults_negative_mass", _replace("masses = [0.2, 0.2]", "masses = [0.2, -0.2]"), "arm_defaults.masses"),
    ("defaults_masses_three", _replace("masses = [0.2, 0.2]", "masses = [0.2, 0.2, 0.2]"),
     "arm_defaults.masses"),
    ("com_beyond_link", _replace_nth("base = [1.0, 1.5]\n", "base = [1.0, 1.5]\ncom = [0.25, 0.6]\n", 0),
     "arms[2].com"),
    ("negative_radius", _replace("radius = 0.1", "radius = -0.1"), "obstacles[0].radius"),
    ("negative_kp", _replace("kp = 1.5", "kp = -1.5"), "controller.kp"),
    ("negative_margin", _replace("epsilon = 5.0\n", "epsilon = 5.0\nmargin = -0.1\n"), "safety.margin"),
    ("nan_horizon", _replace("horizon = 2.0", "horizon = nan"), "simulation.horizon"),
    # mismatched list lengths
    ("lengths_three", _replace("passive_first_joint = false\n",
                               "passive_first_joint = false\nlengths = [0.5, 0.5, 0.5]\n"),
     "arms[1].lengths"),
    ("q0_three", _replace('q0 = ["pi/4", "-pi/6"]', 'q0 = ["pi/4", "-pi/6", 0.0]'), "arms[0].q0"),
    ("one_link", _replace("masses = [0.2, 0.2]\nlengths = [0.5, 0.5]\ncom = [0.25, 0.25]\n"
                          "inertias = [0.005, 0.005]",
                          "masses = [0.2]\nlengths = [0.5]\ncom = [0.25]\ninertias = [0.005]"),
     "arm_defaults.masses"),
    # time steps
    ("control_dt_not_multiple", _replace("control_dt = 0.005", "control_dt = 0.0025"),
     "simulation.control_dt"),
    ("control_dt_below_physics", _replace("control_dt = 0.005", "control_dt = 0.0005"),
     "simulation.control_dt"),
    # formation
    ("flexible_formation", _replace('shape = "polygon"\nsize = 0.5\n',
                                    "edges = [[0, 1], [1, 2]]\ndistances = [0.5, 0.5]\n"), "formation"),
    ("arm_index_out_of_range", _replace('shape = "polygon"\nsize = 0.5\n',
                                        "edges = [[0, 1], [1, 3], [0, 2]]\ndistances = [0.5, 0.5, 0.5]\n"),
     "formation"),
    ("unrealisable_formation", _replace('shape = "polygon"\nsize = 0.5\n',
                                        "edges = [[0, 1], [1, 2], [0, 2]]\ndistances = [1.0, 1.0, 5.0]\n"),
     "formation"),
    ("square_of_three", _replace('shape = "polygon"', 'shape = "square"'), "formation"),
    ("shape_and_edges", _replace("size = 0.5\n", "size = 0.5\nedges = [[0, 1]]\n"), "formation"),
    ("edges_not_pairs", _replace('shape = "polygon"\nsize = 0.5\n',
                                 "edges = [[0, 1, 2]]\ndistances = [0.5]\n"), "formation.edges"),
    # an end-effector starting inside an obstacle (arm 0's starts near (0.483, 0.836))
    ("start_inside_obstacle", _replace("center = [1.0, 0.5]", "center = [0.5, 0.8]"), "arms[0].q0"),
    # angles
    ("angle_div_zero", _replace('q0 = ["pi/4", "-pi/6"]', 'q0 = ["pi/0", "-pi/6"]'), "arms[0].q0[0]"),
    ("angle_banana", _replace('q0 = ["pi/4", "-pi/6"]', 'q0 = ["pi/4", "banana"]'), "arms[0].q0[1]"),
    ("angle_bool", _replace('q0 = ["pi/4", "-pi/6"]', 'q0 = [true, "-pi/6"]'), "arms[0].q0[0]"),
    ("angle_empty", _replace('q0 = ["pi/4", "-pi/6"]', 'q0 = ["", "-pi/6"]'), "arms[0].q0[0]"),
    ("phi_bad", _replace("inertias = [0.005, 0.005]\n", 'inertias = [0.005, 0.005]\nphi = "2*banana"\n'),
     "arms[0].phi"),
    # not TOML at all
    ("invalid_toml", VALID + "\n[[arms]\nbase = \n", "<toml>"),
]


@pytest.mark.parametrize(("text", "key"), [b[1:] for b in BROKEN], ids=[b[0] for b in BROKEN])
def test_broken_file_raises_scenario_error(tmp_path: Path, text: str, key: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    message = str(info.value)
    assert str(path) in message, message
    assert key in message, message
    assert info.value.key.startswith(key) or key in info.value.key, (info.value.key, key)
    assert info.value.source == str(path)
    assert isinstance(info.value, ValueError)


def test_unknown_builtin_name() -> None:
    with pytest.raises(ScenarioError) as info:
        scenario.load("paper_pa7_hexagon")
    assert "paper_pa7_hexagon" in str(info.value)
    # the message lists what does exist
    assert "paper_pa3_square" in str(info.value)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.toml"
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    assert str(path) in str(info.value)


def test_non_utf8_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(VALID.replace("three 2-link arms", "drei Arme \xe4").encode("latin-1"))
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    assert str(path) in str(info.value)
