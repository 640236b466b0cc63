"""The filter choices (distance barrier, tunable ε(h̃) = ε e^{λ h̃}) in the compiled env, end to end:
the parameters' validation, safety under the adversarial and random policies, and the point of the
choices, that arms far from every obstacle keep their command where the paper's rows change it.
The compiled rows themselves are checked against the numpy reference in tests/test_kernels.py."""

import dataclasses

import numpy as np
import pytest
from rollouts import random_policy, safety_episode

from pan1_env.baselines import AdversarialPolicy, ReferencePolicy
from pan1_env.environment import parallel_env
from pan1_env.registration import env_arguments
from pan1_env.safety import FilterParams, robust_margin
from pan1_env.scenario import load
from pan1_env.wrappers import SafetyShield

CHOICE = {"barrier": "distance", "decay": 50.0}


def _episode(env, policy, seed: int) -> tuple[float, float, int]:
    """Run to the end; (total cost, smallest clearance over every sub-step, arm-steps with an intervention)."""
    run = safety_episode(env, policy, seed)
    return run["cost"], run["clearance"], run["interventions"]


def test_filter_params_validate_the_choices() -> None:
    team = load("paper_pa3_square")
    params = FilterParams.of(team, barrier="distance", decay=50.0)
    assert (params.barrier, params.decay, params.paper) == ("distance", 50.0, False)
    assert FilterParams.of(team).paper, "the paper scenarios keep the paper's filter"
    with pytest.raises(ValueError, match=r"barrier must be one of \('squared', 'distance'\), got 'cubic'"):
        FilterParams(0.5, 5.0, barrier="cubic")
    assert FilterParams.of(team).fallback == "command"
    with pytest.raises(ValueError, match=r"SafetyShield: fallback must be one of \('command', 'barrier_rate'\)"):
        FilterParams.of(team, owner="SafetyShield", fallback="brake")
    with pytest.raises(ValueError, match="fallback='barrier_rate' measures the whole-arm filter's last resort"):
        SafetyShield(parallel_env("paper_pa3_square"), params=FilterParams.of(team, fallback="barrier_rate"))
    SafetyShield(parallel_env("paper_pa3_square"), params=FilterParams.of(team, fallback="barrier_rate",
                                                                           sensing_radius=0.1))
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="FilterParams: decay"):
            FilterParams.of(team, decay=bad)
    # δ̄ → Γ(δ̄) with the filter's λ (a larger λ gives a smaller margin)
    shaped = FilterParams.of(team, tracking_bound=0.05, decay=50.0)
    assert shaped.margin == pytest.approx(robust_margin(0.05, 0.5, 5.0, 50.0))
    assert shaped.margin < robust_margin(0.05, 0.5, 5.0)


def test_the_fallback_measure_acts_only_where_the_whole_arm_qp_has_no_answer() -> None:
    """On a team whose passive arm meets a moving obstacle it cannot out-run (WholeArmFormation-v1's held-out
    team 2000145, the law behind the shield), ``fallback="command"`` is the default, step for step, and
    ``"barrier_rate"`` changes what the arm gets, first at a step whose QP took the fallback."""
    scenario, kwargs = env_arguments("pan1_env/WholeArmFormation-v1", {})
    runs = {}
    for fallback in (None, "command", "barrier_rate"):
        base = parallel_env(scenario, **kwargs)
        params = None if fallback is None else FilterParams.of(base.scenario, fallback=fallback)
        env = SafetyShield(base, params=params)
        policy = ReferencePolicy(base)
        obs, _ = env.reset(seed=2000145)
        steps = []
        for _ in range(25):
            obs, _, _, _, infos = env.step(policy(obs))
            steps.append([(infos[a]["shield_status"], np.asarray(infos[a]["shield_applied"]).copy())
                          for a in env.possible_agents])
        runs[fallback] = steps
    same = [[np.array_equal(x[1], y[1]) for x, y in zip(a, b, strict=True)] for a, b in
            zip(runs[None], runs["command"], strict=True)]
    assert np.all(same)
    differ = [(t, i) for t, (a, b) in enumerate(zip(runs["command"], runs["barrier_rate"], strict=True))
              for i, (x, y) in enumerate(zip(a, b, strict=True)) if not np.array_equal(x[1], y[1])]
    assert differ, "the barrier-rate measure never changed a command"
    t, i = differ[0]
    assert runs["command"][t][i][0] == 2 and runs["barrier_rate"][t][i][0] == 2


@pytest.mark.parametrize("gate", [0.0, 0.05], ids=["hard_range", "smooth_gate"])
@pytest.mark.parametrize("env_id", ["pan1_env/WholeArmStaticFormation-v0", "pan1_env/WholeArmFormation-v0"])
def test_whole_arm_filter_with_the_choices_blocks_the_adversary(env_id: str, gate: float) -> None:
    """The whole-arm rows with barrier="distance", λ = 50 (every link a capsule, the other arms, moving
    obstacles in the second id), behind the sensing range's hard edge or a 5 cm smooth gate: the adversary
    and a random policy leave cost 0 on still obstacles; with moving ones, only in steps whose QP took the
    fallback (which cannot always keep a moving obstacle out)."""
    base = parallel_env(env_id, max_steps=60)
    env = SafetyShield(base, params=FilterParams.of(base.scenario, **CHOICE, gate=gate))
    assert (base.safety_filter.barrier, base.safety_filter.decay, base.safety_filter.gate) == ("distance", 50.0, gate)
    adversary = AdversarialPolicy(base)
    interventions = 0
    for seed in range(3):
        for policy in (adversary, random_policy(base, seed)):
            obs, _ = env.reset(seed=seed)
            while env.agents:
                obs, _, _, _, infos = env.step(policy(obs))
                for info in infos.values():
                    interventions += int(info["shield_intervened"])
                    if "WholeArmStatic" in env_id or not info["shield_fallback"]:
                        assert info["cost"] == 0.0, (seed, info)
    assert interventions > 0


@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_distance_barrier_with_decay_blocks_adversary_and_random(mode: str) -> None:
    """barrier="distance", λ = 50 on random 4-arm teams: the adversary (straight at the nearest
    obstacle) and a random policy never enter an obstacle, at any sub-step."""
    base = parallel_env("random", action_mode=mode, max_steps=60)
    env = SafetyShield(base, params=FilterParams.of(base.scenario, **CHOICE))
    assert (base.safety_filter.barrier, base.safety_filter.decay) == ("distance", 50.0)
    adversary = AdversarialPolicy(base)
    worst, total, interventions = np.inf, 0.0, 0
    for seed in range(8):
        for policy in (adversary, random_policy(base, seed)):
            cost, clearance, n = _episode(env, policy, seed)
            total, worst, interventions = total + cost, min(worst, clearance), interventions + n
    assert total == 0.0 and worst >= 0.0
    assert interventions > 0, "the filter must have acted for the test to mean anything"


def test_far_arms_keep_their_command_where_the_paper_filter_changes_it() -> None:
    """The first step of random teams (arms at rest), behind the paper's filter and behind the distance
    barrier with λ = 50, from the same state:

    - a zero command, which the paper's rows refuse wherever their robust term ‖L_g0 h‖²/ε exceeds κ h
      (they push a resting arm away, however far the obstacle): the new filter passes it unchanged for
      every arm more than 0.1 m from every obstacle (there κ h̃ = 0.05 exceeds the robust term
      ‖J̄ᵀn‖² e^{−5}/ε for any ‖J̄ᵀn‖ up to these arms' reach, 1.35 m), and the paper's changes some;
    - the reference law: an arm the new filter leaves alone gets its command exactly, and it frees
      arms more than 0.2 m from every obstacle whose command the paper's filter changes."""
    envs = {}
    for name, kw in (("paper", {}), ("choice", CHOICE)):
        base = parallel_env("random", max_steps=5)
        envs[name] = (SafetyShield(base, params=FilterParams.of(base.scenario, **kw)), base)
    freed = {"zero": 0, "reference": 0}
    for seed in range(40):
        for command in freed:
            infos = {}
            for name, (env, base) in envs.items():
                obs, _ = env.reset(seed=seed)
                action = ReferencePolicy(base)(obs) if command == "reference" else \
                    {a: np.zeros(base.action_space(a).shape, np.float32) for a in obs}
                _, _, _, _, infos[name] = env.step(action)
            for agent, info in infos["choice"].items():
                paper_changed = infos["paper"][agent]["shield_intervened"]
                if command == "zero" and info["min_clearance"] > 0.1:
                    assert not info["shield_intervened"], (seed, agent)
                    freed["zero"] += bool(paper_changed)
                if not info["shield_intervened"]:
                    np.testing.assert_allclose(info["shield_applied"], action[agent], atol=1e-6)
                    freed["reference"] += bool(command == "reference" and info["min_clearance"] > 0.2
                                               and paper_changed)
    assert freed["zero"] >= 5 and freed["reference"] >= 5, freed


def test_scenario_choices_reach_the_filter(tmp_path) -> None:
    """``[safety] barrier``/``decay``/``gate`` of a scenario file: the filter's defaults; bad values name the key."""
    from importlib import resources

    from pan1_env.scenario import ScenarioError

    text = resources.files("pan1_env.scenarios").joinpath("paper_pa3_square.toml").read_text()
    good = tmp_path / "choice.toml"
    good.write_text(text.replace("[safety]", '[safety]\nbarrier = "distance"\ndecay = 20.0\ngate = 0.04', 1))
    env = parallel_env(str(good), safety_filter=FilterParams.of(load(str(good)), sensing_radius=0.1))
    assert (env.safety_filter.barrier, env.safety_filter.decay, env.safety_filter.gate) == ("distance", 20.0, 0.04)
    for key, line in (("safety.barrier", 'barrier = "cubic"'), ("safety.decay", "decay = -1.0"),
                      ("safety.gate", "gate = -0.1"), ("safety.gate", 'gate = "wide"')):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace("[safety]", f"[safety]\n{line}", 1))
        with pytest.raises(ScenarioError, match=key.replace(".", r"\.")) as err:
            load(str(bad))
        assert "bad.toml" in str(err.value)
    assert dataclasses.replace(load("paper_pa3_square")).filter.barrier == "squared"


@pytest.mark.parametrize("task", ["RandomFormation", "WholeArmStaticFormation", "WholeArmFormation"])
def test_the_v1_ids_carry_their_filter_wherever_the_shield_is_on(task) -> None:
    """A v1 id's filter (v0's, with the distance barrier, κ = 0.5, ε = 5, λ = 50, margin 0) is what the
    Gymnasium shield, the parallel shield, ``safety_filter=True`` and the vector env's default give; v0
    keeps the paper's; ``safety_filter=False`` (the parallel and Gymnasium views' default) keeps it off."""
    import gymnasium

    from pan1_env.vector import Pan1VectorEnv
    from pan1_env.wrappers import GymSafetyShield

    old, new = f"pan1_env/{task}-v0", f"pan1_env/{task}-v1"
    v0 = parallel_env(old, safety_filter=True).safety_filter
    assert v0.paper and (v0.kappa, v0.epsilon, v0.margin) == (0.5, 5.0, 0.0)
    v1 = dataclasses.replace(v0, barrier="distance", decay=50.0)
    gym_env = GymSafetyShield(gymnasium.make(f"pan1_env:{new}"))
    assert gym_env.unwrapped.parallel.safety_filter == v1
    assert parallel_env(new).safety_filter is None
    assert parallel_env(new, safety_filter=True).safety_filter == v1
    shielded = parallel_env(new)
    SafetyShield(shielded)
    assert shielded.safety_filter == v1
    venv = Pan1VectorEnv(new, 2)
    assert venv.safety_filter == v1
    venv.close()
    # the same teams as v0: only the filter differs
    a, b = parallel_env(old), parallel_env(new)
    a.reset(seed=5)
    b.reset(seed=5)
    np.testing.assert_array_equal(a.joint_state()[0], b.joint_state()[0])
    assert a.scenario.obstacles.centers.tolist() == b.scenario.obstacles.centers.tolist()


def test_the_smooth_gate_is_refused_where_it_cannot_act() -> None:
    """A negative or non-finite gate is refused by name wherever it is given; a positive one needs the
    whole-arm rows (whole-arm bodies or a sensing radius), a finite speed bound, and at least one
    sub-step's travel, which the engine computes from the team."""
    from pan1_env.engine import Engine, Physics
    from pan1_env.random_scenario import RandomScenarioOptions

    team = load("paper_pa3_square")
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="FilterParams: gate must be"):
            FilterParams(0.5, 5.0, gate=bad)
        with pytest.raises(ValueError, match="FilterParams: gate must be"):
            FilterParams.of(team, gate=bad)
        with pytest.raises(ValueError, match="RandomScenarioOptions.gate must be"):
            RandomScenarioOptions(gate=bad)
    with pytest.raises(ValueError, match="needs whole-arm bodies or a sensing_radius"):
        SafetyShield(parallel_env("paper_pa3_square"), params=FilterParams.of(team, gate=0.05))
    with pytest.raises(ValueError, match="needs a finite max_joint_speed"):
        Engine(team, safety_filter=FilterParams(0.5, 5.0, sensing_radius=0.1, gate=0.05))
    with pytest.raises(ValueError, match=r"at least one sub-step's travel, 0\.01\d* m .*got 0\.001"):
        Engine(team, physics=Physics(max_joint_speed=5.0, physics_dt=0.002),
               safety_filter=FilterParams(0.5, 5.0, sensing_radius=0.1, gate=0.001))
    engine = Engine(team, physics=Physics(max_joint_speed=2.0),
                    safety_filter=FilterParams(0.5, 5.0, sensing_radius=0.1, gate=0.05))
    assert engine.whole_arm_args(engine.kinds[0]).gate == 0.05


def test_the_look_ahead_is_checked_and_travels_with_the_scenario(tmp_path) -> None:
    """``lookahead`` (s, inf allowed) is validated where it is given, refused without whole-arm rows (the
    end-effector filter sees obstacles where they are), read from ``[safety] lookahead`` and ``fallback``, and
    carried by WholeArmFormation-v2's drawn teams to every way of switching the filter on."""
    import gymnasium

    from pan1_env.vector import Pan1VectorEnv
    from pan1_env.wrappers import GymSafetyShield

    team = load("paper_pa3_square")
    assert FilterParams.of(team).lookahead == 0.0 and FilterParams(0.5, 5.0, lookahead=float("inf")).lookahead > 1e9
    for bad in (-1.0, float("nan"), "far"):
        with pytest.raises(ValueError, match="SafetyShield: lookahead"):
            FilterParams.of(team, owner="SafetyShield", lookahead=bad)
    with pytest.raises(ValueError, match="lookahead=2 shapes the whole-arm filter's rows"):
        parallel_env("paper_pa3_square", safety_filter=FilterParams.of(team, lookahead=2.0))
    from importlib import resources

    from pan1_env.scenario import ScenarioError

    text = resources.files("pan1_env.scenarios").joinpath("paper_pa3_square.toml").read_text()
    good = tmp_path / "ahead.toml"
    good.write_text(text.replace("[safety]", '[safety]\nlookahead = inf\nfallback = "barrier_rate"', 1))
    params = FilterParams.of(load(str(good)))
    assert (params.lookahead, params.fallback) == (float("inf"), "barrier_rate")
    for key, line in (("safety.lookahead", "lookahead = -1.0"), ("safety.lookahead", "lookahead = nan"),
                      ("safety.fallback", 'fallback = "brake"')):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace("[safety]", f"[safety]\n{line}", 1))
        with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
            load(str(bad))
    v2 = dataclasses.replace(parallel_env("pan1_env/WholeArmFormation-v1", safety_filter=True).safety_filter,
                             lookahead=float("inf"))
    assert parallel_env("pan1_env/WholeArmFormation-v2", safety_filter=True).safety_filter == v2
    assert GymSafetyShield(gymnasium.make("pan1_env:pan1_env/WholeArmFormation-v2")).unwrapped.parallel \
        .safety_filter == v2
    venv = Pan1VectorEnv("pan1_env/WholeArmFormation-v2", 2)
    assert venv.safety_filter == v2
    venv.close()


def test_the_fault_margin_is_checked_and_travels_with_the_scenario(tmp_path) -> None:
    """``fault_margin`` is a bool where it is given, refused with the squared barrier, a gate or no speed bound (it is
    written for the distance barrier and bounds what the box allows), read from ``[safety] fault_margin``, carried by
    FaultFormation-v1's drawn teams to every way of switching the filter on, and it puts an end-effector team's
    filter into the whole-arm rows."""
    from importlib import resources

    import gymnasium

    from pan1_env.engine import Engine, Physics
    from pan1_env.scenario import ScenarioError
    from pan1_env.vector import Pan1VectorEnv
    from pan1_env.wrappers import GymSafetyShield

    team = load("paper_pa3_square")
    assert FilterParams.of(team).fault_margin is False
    for bad in ("yes", 1, 0.0):
        with pytest.raises(ValueError, match="SafetyShield: fault_margin must be True or False"):
            FilterParams.of(team, owner="SafetyShield", fault_margin=bad)
    for params, what in ((FilterParams(0.5, 5.0, fault_margin=True), "barrier='squared'"),
                         (FilterParams(0.5, 5.0, barrier="distance", gate=0.05, fault_margin=True), "gate=0.05")):
        with pytest.raises(ValueError, match=f"fault_margin needs barrier='distance'.*{what}"):
            Engine(team, physics=Physics(max_joint_speed=2.0), safety_filter=params)
    with pytest.raises(ValueError, match="fault_margin needs .*max_joint_speed=inf"):
        Engine(team, safety_filter=FilterParams(0.5, 5.0, barrier="distance", fault_margin=True))
    engine = Engine(team, physics=Physics(max_joint_speed=2.0),
                    safety_filter=FilterParams(0.5, 5.0, barrier="distance", fault_margin=True))
    assert engine.whole_arm and not engine.link_bodies
    text = resources.files("pan1_env.scenarios").joinpath("paper_pa3_square.toml").read_text()
    good = tmp_path / "margin.toml"
    good.write_text(text.replace("[safety]", '[safety]\nfault_margin = true\nbarrier = "distance"', 1))
    assert FilterParams.of(load(str(good))).fault_margin is True
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("[safety]", "[safety]\nfault_margin = 1", 1))
    with pytest.raises(ScenarioError, match=r"safety\.fault_margin: expected true or false, got 1"):
        load(str(bad))
    v1 = dataclasses.replace(parallel_env("pan1_env/FaultFormation-v0", safety_filter=True).safety_filter,
                             fault_margin=True)
    assert parallel_env("pan1_env/FaultFormation-v1", safety_filter=True).safety_filter == v1
    assert GymSafetyShield(gymnasium.make("pan1_env:pan1_env/FaultFormation-v1")).unwrapped.parallel \
        .safety_filter == v1
    venv = Pan1VectorEnv("pan1_env/FaultFormation-v1", 2)
    assert venv.safety_filter == v1 and venv.engine.whole_arm
    venv.close()


def test_a_link_beside_a_kept_out_path_cannot_swing_its_far_end_in() -> None:
    """WholeArmFormation-v2's held-out team 2000023 under the vector adversary: a PA arm's last link lies
    parallel to an obstacle's path, and the closest pair jumps to its inner end. With a row at the closest pair
    alone the QP let the outer joint spin to full speed and the tip went 1.9 mm into the path's capsule at step
    711, with no fallback; the second row, at the link's other end, keeps it out."""
    from pan1_env.baselines import VectorAdversary
    from pan1_env.vector import Pan1VectorEnv

    venv = Pan1VectorEnv("pan1_env/WholeArmFormation-v2", 1)
    obs, _ = venv.reset(seed=[2000023])
    adversary = VectorAdversary().attach(venv)
    worst = np.inf
    for _ in range(760):
        obs, _, _, _, infos = venv.step(adversary(obs))
        worst = min(worst, float(infos["min_clearance"][0]))
        assert infos["cost"][0] == 0.0 and not infos["shield_fallback"][0]
    assert worst > 0.0
    venv.close()
