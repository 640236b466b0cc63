"""The safety shield: no policy can make an arm enter an obstacle, in either action mode."""

import gymnasium
import numpy as np
import pytest
from rollouts import random_policy, safety_episode

from pan1_env.baselines import AdversarialPolicy, ReferencePolicy
from pan1_env.environment import parallel_env
from pan1_env.safety import robust_margin
from pan1_env.wrappers import GymSafetyShield, SafetyShield

MIXED = {"links": (2, 3, 4, 3), "passive_fraction": 0.5}


def _episode(env, policy, seed: int) -> tuple[float, float, int]:
    """Run to the end; return (total cost, smallest clearance over every sub-step, fallbacks)."""
    run = safety_episode(env, policy, seed)
    return run["cost"], run["clearance"], run["fallbacks"]


@pytest.mark.parametrize("mode", ["velocity", "torque"])
@pytest.mark.parametrize("scenario", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_shield_blocks_adversary_and_random_on_paper_scenarios(scenario: str, mode: str) -> None:
    base = parallel_env(scenario, action_mode=mode, max_steps=200)
    env = SafetyShield(base)
    for policy in (AdversarialPolicy(base), random_policy(base, 0)):
        cost, clearance, _ = _episode(env, policy, seed=0)
        assert cost == 0.0
        assert clearance >= 0.0


@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_adversary_collides_without_the_shield(mode: str) -> None:
    hits = 0
    for scenario in ("paper_pa3_square", "paper_pa_mixed_square"):
        base = parallel_env(scenario, action_mode=mode, max_steps=200)
        cost, clearance, _ = _episode(base, AdversarialPolicy(base), seed=0)
        hits += cost > 0 and clearance < 0
    assert hits == 2


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_shield_on_100_random_scenarios(mode: str) -> None:
    base = parallel_env("random", random_options=MIXED, action_mode=mode, max_steps=60)
    env = SafetyShield(base)
    adversary = AdversarialPolicy(base)
    worst, total, unshielded_hits = np.inf, 0.0, 0
    for seed in range(100):
        for policy in (adversary, random_policy(base, seed)):
            cost, clearance, _ = _episode(env, policy, seed)
            total += cost
            worst = min(worst, clearance)
    assert total == 0.0
    assert worst >= 0.0
    # the same adversary, unshielded, does collide on these scenarios
    plain = parallel_env("random", random_options=MIXED, action_mode=mode, max_steps=60)
    for seed in range(10):
        cost, _, _ = _episode(plain, AdversarialPolicy(plain), seed)
        unshielded_hits += cost > 0
    assert unshielded_hits >= 5


def test_shield_infos_report_the_intervention() -> None:
    base = parallel_env("paper_pa_mixed_square")
    env = SafetyShield(base)
    policy = AdversarialPolicy(base)
    obs, _ = env.reset(seed=0)
    seen = False
    for _ in range(100):
        actions = policy(obs)
        obs, _, _, _, infos = env.step(actions)
        for agent, info in infos.items():
            assert {"shield_applied", "shield_intervened", "shield_min_barrier", "shield_status",
                    "shield_fallback", "qp_counts"} <= set(info)
            assert info["shield_applied"].shape == actions[agent].shape
            assert info["shield_status"] == (2 if info["shield_fallback"] else int(info["shield_intervened"]))
            if agent != "arm_3":  # only the PA arm can reach the obstacle
                assert not info["shield_intervened"] and info["shield_min_barrier"] == np.inf
                np.testing.assert_allclose(info["shield_applied"], np.clip(actions[agent], -1, 1), atol=1e-6)
            elif info["shield_intervened"]:
                seen = True
                assert not np.allclose(info["shield_applied"], actions[agent])
                assert info["shield_min_barrier"] > 0
    assert seen


def test_tightened_set_uses_gamma_margin() -> None:
    from pan1_env.safety import FilterParams

    base = parallel_env("paper_pa3_square")
    SafetyShield(base, params=FilterParams.of(base.scenario, tracking_bound=0.05))
    assert base.safety_filter.margin == pytest.approx(robust_margin(0.05, 0.5, 5.0))
    with pytest.raises(ValueError, match="kappa"):
        FilterParams.of(base.scenario, kappa=-1.0)
    with pytest.raises(ValueError, match="not both"):
        FilterParams.of(base.scenario, margin=0.01, tracking_bound=0.1)


def test_a_shield_takes_one_filter_params_and_refuses_loose_settings() -> None:
    """``params=FilterParams`` switches on exactly that filter, in both shields, and no params the scenario's own; a
    setting given on its own, or something else than a FilterParams, is refused naming the shield and the way in."""
    from pan1_env.safety import FilterParams

    env = parallel_env("paper_pa3_square")
    params = FilterParams.of(env.scenario, barrier="distance", decay=50.0)
    assert SafetyShield(env, params=params).unwrapped.safety_filter == params
    gym_env = gymnasium.make("pan1_env/PaperPA3Square-v0")
    assert GymSafetyShield(gym_env, params=params).unwrapped.parallel.safety_filter == params
    assert SafetyShield(parallel_env("paper_pa3_square")).unwrapped.safety_filter == env.scenario.filter
    with pytest.raises(TypeError, match=r"SafetyShield\(env, params=FilterParams.of\(env.unwrapped.scenario, "
                                        r"kappa=0.5\)\)"):
        SafetyShield(parallel_env("paper_pa3_square"), kappa=0.5)
    with pytest.raises(TypeError, match="GymSafetyShield takes the filter's settings as one FilterParams"):
        GymSafetyShield(gymnasium.make("pan1_env/PaperPA3Square-v0"), barrier="distance", params=params)
    with pytest.raises(TypeError, match="GymSafetyShield: params must be a pan1_env.safety.FilterParams, got dict"):
        GymSafetyShield(gymnasium.make("pan1_env/PaperPA3Square-v0"), params={"kappa": 0.5})


def test_gym_shield_reports_and_blocks() -> None:
    env = GymSafetyShield(gymnasium.make("pan1_env/PaperMixedPA-v0", max_steps=150))
    obs, info = env.reset(seed=0)
    total = 0.0
    rng = np.random.default_rng(0)
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        total += info["cost"]
        assert info["shield_applied"].shape == env.action_space.shape and info["shield_status"] in (0, 1, 2)
        done = term or trunc
    assert total == 0.0


# seconds simulated, not the scenarios' 100 s: past each safe run's moving part, by when every arm is within 0.1 mm
# of its closest approach over the 100 s and the square is formed (edge error < 1 cm). PA3: arm_0 closest at 32.5 s,
# formed at 38.9 s, arm_3 still creeping towards its obstacle until 55 s; mixed: formed at 20.5 s, the PA arm
# held off its obstacle within 0.1 mm of its final clearance from 25 s
_REPRODUCED_HORIZON = {"paper_pa3_square": 55.0, "paper_pa_mixed_square": 25.0}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_reference_policy_behind_shield_reproduces_safe_run(name: str) -> None:
    """Same scenario, same time steps (control_dt = physics_dt = 1 ms), no action saturation: the
    env's trajectory q(t) follows `reproduce --controller safe` (the policy sees float32
    observations, hence the tolerances), and the per-arm clearances and final error agree, over the
    run's moving part: the approach to the obstacles, the shield holding the arms off them and the
    formation of the square (``_REPRODUCED_HORIZON``: later, up to 100 s, no arm comes 0.1 mm nearer an obstacle)."""
    from pan1_env import experiment, scenario

    sc = scenario.load(name)
    horizon = _REPRODUCED_HORIZON[name]
    expected = experiment.run(sc, "safe", horizon=horizon, record_dt=1.0)
    steps_per_s = int(round(1.0 / sc.physics_dt))
    base = parallel_env(name, control_dt=sc.physics_dt, max_steps=int(round(horizon / sc.physics_dt)),
                        max_joint_speed=1e3)
    env = SafetyShield(base)
    policy = ReferencePolicy(base)
    obs, _ = env.reset(seed=0)
    clearance = np.full(4, np.inf)
    q_env = [base.joint_state()[0]]
    intervened = False
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        clearance = np.minimum(clearance, [infos[a]["min_clearance"] for a in base.possible_agents])
        intervened |= any(info["shield_intervened"] for info in infos.values())
        if base.num_steps % steps_per_s == 0:
            q_env.append(base.joint_state()[0])
    q_ref = expected.trajectory["q"]
    np.testing.assert_allclose(expected.trajectory["time"], np.arange(len(q_ref)), atol=1e-9)
    np.testing.assert_allclose(np.array(q_env), q_ref, atol=2e-3, equal_nan=True)
    got = [a["min_clearance_m"] for a in expected.metrics["arms"]]
    np.testing.assert_allclose(clearance, got, atol=2e-4)
    assert infos["arm_0"]["formation_error"] == pytest.approx(expected.metrics["final_max_edge_error_m"], abs=1e-4)
    # the horizon holds what is reproduced: the shield at work and the square formed
    assert intervened and expected.metrics["qp_solved_steps"] > 0
    assert expected.metrics["time_to_edge_error_1cm_s"] is not None


def test_nearly_degenerate_row_brakes_instead_of_blowing_up() -> None:
    """Found by the soak test: a nearly degenerate RCBF row (tiny ‖L_g0 h‖, b < 0) has a huge exact
    optimum; the shield's speed bounds turn it into an infeasible QP and the arm brakes."""
    team = {"n_arms": 4, "links": (2, 3, 4, 3), "passive_fraction": 0.5}
    core = parallel_env("random", random_options=team, control_dt=0.01, physics_dt=0.001, max_steps=200)
    env = SafetyShield(core)
    policy = AdversarialPolicy(core)
    obs, _ = env.reset(seed=1126)
    fallbacks = 0
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        assert all("fault" not in info and info["cost"] == 0.0 for info in infos.values())
        assert max(np.abs(kind.v).max() for kind in core.engine.kinds) < 3.0 * core.config.max_joint_speed
        fallbacks += sum(info["shield_fallback"] for info in infos.values())
    assert fallbacks > 0
