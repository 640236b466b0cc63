"""The policy contract: policies read only public attributes (so they work behind any wrapper), the
observation layout is public, and policies are made by name from a registry."""

import numpy as np
import pytest
from pettingzoo.utils.wrappers import BaseParallelWrapper

from pan1_env.baselines import (
    AdversarialPolicy,
    Policy,
    RandomPolicy,
    ReferencePolicy,
    ZeroPolicy,
    decode_observation,
    make_policy,
    register_policy,
    registered_policies,
    unregister_policy,
)
from pan1_env.baselines.benchmark import run_benchmark
from pan1_env.cli import main
from pan1_env.environment import parallel_env
from pan1_env.observation import ObservationLayout
from pan1_env.wrappers import SafetyShield


def test_private_attributes_stay_private_behind_wrappers() -> None:
    """The premise: PettingZoo's wrappers refuse ``_names`` but forward public ones."""
    env = SafetyShield(parallel_env("paper_pa_mixed_square"))
    with pytest.raises(AttributeError, match="private attribute"):
        _ = env._layout
    core = env.unwrapped
    assert env.observation_layout is core.observation_layout
    assert env.scenario is core.scenario and env.possible_agents == core.possible_agents
    assert env.config is core.config and env.config.action_mode == "velocity"  # the wrapper forwards the config


def test_observation_layout_is_public_read_only_and_decodes_observations() -> None:
    env = SafetyShield(parallel_env("paper_pa_mixed_square"))
    layout = env.observation_layout
    assert isinstance(layout, ObservationLayout)
    with pytest.raises(AttributeError):
        env.unwrapped.observation_layout = layout
    obs, _ = env.reset(seed=0)
    q = env.unwrapped.joint_state()[0]
    for i, agent in enumerate(env.possible_agents):
        n = int(layout.n[i])
        seg = layout.segments(n)
        assert seg["obstacles"].stop == layout.size(n) == env.observation_space(agent).shape[0]
        assert layout.n_links(layout.size(n)) == n
        low = env.observation_space(agent).low
        assert (low[seg["neighbours"]][:: 4] == 0).all() and (low[seg["obstacles"]][:: 5] == 0).all()
        d = decode_observation(obs[agent], layout)  # n inferred from the length
        np.testing.assert_allclose(d["q"], q[i][:n], atol=1e-6)
        degree = len(env.scenario.formation.neighbours(i))
        assert d["neighbour_delta"].shape == (degree, 2) and d["neighbour_error"].shape == (degree,)
        assert d["obstacles"].shape == (layout.n_obstacle_obs, 5)
    with pytest.raises(ValueError, match="does not fit"):
        decode_observation(np.zeros(layout.size(2) + 1), layout)
    with pytest.raises(ValueError, match="layout gives"):
        decode_observation(obs["arm_0"], layout, n_links=int(layout.n[0]) + 1)


@pytest.mark.parametrize("wrap", [SafetyShield, BaseParallelWrapper])
def test_policies_act_the_same_on_a_wrapped_env(wrap) -> None:
    core = parallel_env("paper_pa_mixed_square", max_steps=5)
    env = wrap(core)
    obs, _ = env.reset(seed=0)
    for cls in (ReferencePolicy, AdversarialPolicy):
        wrapped, plain = cls(env)(obs), cls(core)(obs)
        assert wrapped.keys() == set(env.possible_agents)
        for agent in env.possible_agents:
            np.testing.assert_array_equal(wrapped[agent], plain[agent])
    for name in ("reference", "zero", "random", "adversarial"):
        actions = make_policy(name, env, seed=0)(obs)
        assert all(env.action_space(a).contains(actions[a]) for a in env.possible_agents)


def _episode(env, policy) -> tuple[float, int, int, dict]:
    """Run one seeded episode: total cost, shield interventions, steps and the last infos."""
    obs, _ = env.reset(seed=0)
    cost, intervened, steps = 0.0, 0, 0
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        cost += sum(info["cost"] for info in infos.values())
        intervened += sum(info.get("shield_intervened", 0) for info in infos.values())
        steps += 1
    return cost, intervened, steps, infos


def test_reference_policy_behind_the_shield_forms_the_square_without_cost() -> None:
    """The way a user writes it: the policy built on the shielded env itself (default max_steps)."""
    env = SafetyShield(parallel_env("paper_pa_mixed_square"))
    cost, _, steps, infos = _episode(env, ReferencePolicy(env))
    assert steps == env.config.max_steps
    assert cost == 0.0
    assert infos["arm_0"]["formation_error"] < 0.01


def test_adversarial_policy_on_a_wrapped_env_is_blocked_by_the_shield() -> None:
    env = SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=200))
    cost, intervened, _, _ = _episode(env, AdversarialPolicy(env))
    assert cost == 0.0 and intervened > 0
    # the same adversary behind a plain PettingZoo wrapper (no shield) does hit an obstacle
    plain = BaseParallelWrapper(parallel_env("paper_pa_mixed_square", max_steps=200))
    cost, _, _, _ = _episode(plain, AdversarialPolicy(plain))
    assert cost > 0


class _Constant:
    def __init__(self, env, value: float) -> None:
        self.env, self.value = env, value

    def __call__(self, observations):
        return {a: np.full(self.env.action_space(a).shape, self.value, np.float32) for a in observations}


@pytest.fixture
def registered():
    """Register test policies and remove them afterwards (the registry is per process)."""
    names = []

    def add(name, factory, **kwargs):
        register_policy(name, factory, **kwargs)
        names.append(name)

    yield add
    for name in names:
        unregister_policy(name)


def test_builtin_policies_are_registered_and_satisfy_the_protocol() -> None:
    assert registered_policies()[:6] == ("reference", "circulation", "zero", "random", "adversarial", "sb3:PATH")
    env = parallel_env("paper_pa3_square")
    assert isinstance(make_policy("zero", env, seed=0), ZeroPolicy)
    assert isinstance(make_policy("random", env, seed=0), RandomPolicy)
    assert all(isinstance(make_policy(n, env, seed=0), Policy) for n in ("reference", "zero", "random", "adversarial"))
    with pytest.raises(ValueError, match="outputs velocities"):
        make_policy("reference", parallel_env("paper_pa3_square", action_mode="torque"), seed=0)
    with pytest.raises(ValueError, match="no such model file"):
        make_policy("sb3:/nonexistent/model.zip", env, seed=0)


def test_unknown_policy_names_are_a_clear_error() -> None:
    env = parallel_env("paper_pa3_square")
    for name in ("greedy", "sb3:", "sb3", "Reference", "zero:1"):
        with pytest.raises(ValueError, match=r"unknown policy .*registered: reference, circulation, zero, random, "
                                             r"adversarial, sb3:PATH"):
            make_policy(name, env, seed=0)
    with pytest.raises(ValueError, match="unknown policy 'greedy'"):
        run_benchmark(["paper_pa3_square"], ["zero", "greedy"], episodes=1)


def test_registering_a_policy_makes_it_available_everywhere(registered, tmp_path, capsys) -> None:
    registered("still", lambda env, seed: _Constant(env, 0.0))
    registered("const:", lambda env, seed, arg: _Constant(env, float(arg)), metavar="VALUE")
    assert {"still", "const:VALUE"} <= set(registered_policies())
    env = SafetyShield(parallel_env("paper_pa3_square", max_steps=5))
    obs, _ = env.reset(seed=0)
    assert make_policy("const:0.25", env, seed=0)(obs)["arm_0"].tolist() == [0.25] * env.action_space("arm_0").shape[0]
    with pytest.raises(ValueError, match="already registered"):
        register_policy("still", lambda env, seed: _Constant(env, 1.0))
    with pytest.raises(ValueError, match="policy name"):
        register_policy("two words", lambda env, seed: _Constant(env, 1.0))
    with pytest.raises(ValueError, match="unknown policy 'nope'.*still.*const:VALUE"):
        make_policy("nope", env, seed=0)
    # the benchmark and the CLI know the new names without any change of their own
    rows = run_benchmark(["paper_pa3_square"], ["still", "const:0.5"], episodes=1, max_steps=5)
    assert [(r["policy"], r["shield"]) for r in rows] == [("still", True), ("still", False), ("const:0.5", True),
                                                          ("const:0.5", False)]
    assert rows[0]["intervention_rate"] == 0.0
    out = tmp_path / "still.gif"
    assert main(["animate", "paper_pa3_square", "--policy", "still", "--steps", "3", "--frames", "2",
                 "--out", str(out)]) == 0
    assert out.exists() and "policy still" in capsys.readouterr().out
    assert main(["animate", "paper_pa3_square", "--policy", "nope", "--steps", "3", "--out", str(out)]) == 2
    assert "unknown policy 'nope'" in capsys.readouterr().err


def test_decode_observation_takes_the_layout() -> None:
    env = parallel_env("paper_pa_mixed_square")
    obs, _ = env.reset(seed=0)
    with pytest.raises(TypeError, match="observation_layout"):
        decode_observation(obs["arm_3"], 2, env.observation_layout.slots)


class _OneCopy:
    """What AdversarialPolicy reads of a parallel env, for copy ``b`` of a vector env."""

    def __init__(self, venv, b: int) -> None:
        self.scenario = venv.teams[b]
        self.possible_agents = [f"arm_{i}" for i in range(len(self.scenario.arms))]
        self.observation_layout = venv.observation_layout


def _per_agent_adversary(venv, obs: np.ndarray) -> np.ndarray:
    layout, rows = venv.observation_layout, []
    for b in range(len(obs)):
        copy, start, row = _OneCopy(venv, b), 0, []
        for agent, arm in zip(copy.possible_agents, copy.scenario.arms, strict=True):
            size = layout.size(arm.n_links)
            row.append(AdversarialPolicy(copy).act(agent, obs[b, start:start + size]))
            start += size
        rows.append(np.concatenate(row))
    return np.array(rows)


@pytest.mark.parametrize("task", ["pan1_env/RandomFormation-v1", "pan1_env/WholeArmFormation-v1"])
def test_vector_adversary_acts_as_the_per_agent_adversary_on_every_copy(task: str) -> None:
    from pan1_env.baselines import VectorAdversary
    from pan1_env.registration import env_arguments
    from pan1_env.vector import Pan1VectorEnv

    scenario, kwargs = env_arguments(task)
    venv = Pan1VectorEnv(scenario, 3, **kwargs)
    adversary = VectorAdversary().attach(venv)
    for seeds in ([11, 12, 13], [21, 22, 23]):  # new teams at the second reset: the batched arms follow
        obs, _ = venv.reset(seed=seeds)
        for _ in range(3):
            actions = adversary(obs)
            np.testing.assert_allclose(actions, _per_agent_adversary(venv, obs), rtol=1e-6, atol=1e-7)
            assert np.any(actions != 0)
            obs, *_ = venv.step(actions)


def test_vector_adversary_needs_an_env_and_is_blocked_by_the_shield() -> None:
    from pan1_env.baselines import VectorAdversary
    from pan1_env.baselines.evaluation import evaluate
    from pan1_env.registration import env_arguments

    with pytest.raises(RuntimeError, match="attach"):
        VectorAdversary()(np.zeros((1, 10), np.float32))
    scenario, kwargs = env_arguments("pan1_env/RandomFormation-v1")
    seeds, kwargs = range(7, 15), {**kwargs, "max_steps": 200}
    shielded = evaluate(VectorAdversary(), scenario, seeds, shield=True, env_kwargs=kwargs)
    assert shielded["cost"].sum() == 0 and shielded["intervention_rate"].max() > 0
    bare = evaluate(VectorAdversary(), scenario, seeds, shield=False, env_kwargs=kwargs)
    assert bare["cost"].sum() > 0  # the same adversary without the filter enters obstacles


def test_vector_adversary_without_obstacles_in_sight_sends_zeros() -> None:
    from pan1_env.baselines import VectorAdversary
    from pan1_env.registration import env_arguments
    from pan1_env.vector import Pan1VectorEnv

    scenario, kwargs = env_arguments("pan1_env/RandomFormation-v1")
    venv = Pan1VectorEnv(scenario, 2, **{**kwargs, "n_obstacle_obs": 0})
    obs, _ = venv.reset(seed=[1, 2])
    adversary = VectorAdversary().attach(venv)
    actions = adversary(obs)
    assert actions.shape == (2, venv.single_action_space.shape[0]) and not actions.any()
    with pytest.raises(ValueError, match=r"observations of shape \(1, "):
        adversary(obs[:1])



@pytest.mark.parametrize(("env_id", "kwargs", "column"), [
    ("pan1_env/FaultFormation-v0", {"random_options": {"fault_probability": 1.0, "fault_time": (0.1, 0.3)}},
     "time from fault"),
    ("pan1_env/MovingFormation-v0", {"success_hold": 1.0}, "mean tracking error [mm]"),
], ids=["faults", "moving"])
def test_the_benchmark_adds_a_tasks_own_columns(env_id: str, kwargs: dict, column: str) -> None:
    """On a task whose arms fault: the episodes with a fault, their success and the time from the fault to the
    formation; on a moving formation: the mean tracking error. Neither column on a task without them."""
    from pan1_env.baselines.benchmark import markdown_table, run_benchmark

    row = run_benchmark([env_id], ["reference"], episodes=2, max_steps=40, env_kwargs=kwargs,
                        shield_settings=(True,))[0]
    if "Fault" in env_id:
        assert row["fault_episodes"] == 2 and 0.0 <= row["fault_success_rate"] <= 1.0
        recovered = row["mean_time_from_fault_s"]
        assert recovered is None or 0.0 <= recovered <= row["mean_time_to_formation_s"]
    else:
        assert 0.0 < row["mean_tracking_error_m"] < 1.0
    assert column in markdown_table([row]).splitlines()[0]
    plain = run_benchmark(["paper_pa3_square"], ["zero"], episodes=1, max_steps=5, shield_settings=(False,))[0]
    assert not {"fault_episodes", "mean_tracking_error_m"} & set(plain)
    assert column not in markdown_table([plain])
