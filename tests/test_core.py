"""The env core: one owner of reset, step, the clock and the infos for every view.

The reset test is the class of the bug where a view forgot a piece of task state between episodes: for
every view and every action mode, an episode after a reset with a seed is identical, step for step, to
the same seed's episode in a fresh env, after an episode that left every piece of task state non-trivial
(the residual gates' filter record, the previous commands, the engine's record).
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from pan1_env.centralized import CentralizedEnv
from pan1_env.config import ACTION_MODES, FormationConfig
from pan1_env.core import FormationCore
from pan1_env.environment import parallel_env
from pan1_env.vector import Pan1VectorEnv

MODE_ARGS = {"velocity": {}, "torque": {}, "gain": {}, "circulation": {},
             "residual": {"blocked_gate": 0.05, "residual_gate": 0.02}}
FIRST_STEPS = 6


def _actions(rng: np.random.Generator, shape) -> np.ndarray:
    return rng.uniform(-1.0, 1.0, shape).astype(np.float32)


def _parallel_episode(env, seed: int, steps: int, rng, constant: float | None = None) -> list:
    obs, infos = env.reset(seed=seed)
    trace = [(obs, infos)]
    for _ in range(steps):
        if not env.agents:
            break
        out = env.step({a: np.full(env.action_space(a).shape, constant, np.float32) if constant is not None
                        else _actions(rng, env.action_space(a).shape) for a in env.agents})
        trace.append(out)
    return trace


def _assert_same(a, b) -> None:
    """Nested observations, rewards and infos equal (numbers to the last bit: the same code on the same input)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("scenario", ["paper_pa_mixed_square", "random"])
@pytest.mark.parametrize("mode", ACTION_MODES)
def test_parallel_env_episode_after_a_full_one_is_the_fresh_envs(mode: str, scenario: str) -> None:
    kw = {"action_mode": mode, "safety_filter": True, "max_steps": 40, "intervention_penalty": 0.1} | MODE_ARGS[mode]
    used = parallel_env(scenario, **kw)
    # to its end (truncation), pushing every arm: the filter holds some back (paper_pa_mixed_square)
    _parallel_episode(used, 0, 1000, None, constant=1.0)
    assert not used.agents and used.last_step is not None
    if mode == "residual" and scenario != "random":
        assert np.any(used.task.blocked > 0), "the episode should leave the blocked gate's record set"
    again = _parallel_episode(used, 5, FIRST_STEPS, np.random.default_rng(1))
    fresh = _parallel_episode(parallel_env(scenario, **kw), 5, FIRST_STEPS, np.random.default_rng(1))
    _assert_same(again, fresh)


def test_the_blocked_gate_starts_closed_in_every_episode() -> None:
    """The bug of 0.1.0: the parallel env kept the last episode's filter record across a reset, so a residual
    correction with ``blocked_gate`` acted in the new episode's first step."""
    env = parallel_env("paper_pa_mixed_square", action_mode="residual", blocked_gate=0.05, safety_filter=True)
    env.reset(seed=0)
    for _ in range(40):
        env.step({a: np.ones(env.action_space(a).shape, np.float32) for a in env.agents})
    assert np.any(env.task.blocked > 0)
    env.reset(seed=0)
    command, _ = env.commands({a: np.ones(env.action_space(a).shape, np.float32) for a in env.agents})
    law = env.task.nominal_velocity(env.engine)
    np.testing.assert_array_equal(command, law)  # the gate is closed: the paper's law alone


@pytest.mark.parametrize("mode", ["velocity", "residual"])
def test_gymnasium_and_vector_episodes_after_a_full_one_are_the_fresh_envs(mode: str) -> None:
    kw = {"action_mode": mode, "max_steps": 20, "safety_filter": True} | MODE_ARGS[mode]

    def gym_episode(env, seed):
        rng, trace = np.random.default_rng(2), [env.reset(seed=seed)]
        for _ in range(FIRST_STEPS):
            trace.append(env.step(_actions(rng, env.action_space.shape)))
        return trace

    used = CentralizedEnv("random", **kw)
    gym_episode(used, 3)
    for _ in range(30):
        used.step(np.ones(used.action_space.shape, np.float32))  # to the end of the episode
        if used._needs_reset:
            break
    _assert_same(gym_episode(used, 4), gym_episode(CentralizedEnv("random", **kw), 4))

    def vector_episode(venv, seed):
        rng, trace = np.random.default_rng(3), [venv.reset(seed=seed)]
        for _ in range(FIRST_STEPS):
            trace.append(venv.step(_actions(rng, venv.action_space.shape)))
        return trace

    used = Pan1VectorEnv("random", 3, **kw)
    vector_episode(used, 7)
    for _ in range(30):
        used.step(np.ones(used.action_space.shape, np.float32))
    _assert_same(vector_episode(used, 8), vector_episode(Pan1VectorEnv("random", 3, **kw), 8))


@pytest.mark.parametrize("env_id", ["pan1_env/PaperPA3Square-v0", "pan1_env/WholeArmStaticFormation-v0"])
def test_every_view_has_the_same_info_keys_after_a_reset_and_a_step(env_id: str) -> None:
    par = parallel_env(env_id, safety_filter=True, effort_weight=0.1)
    _, reset_infos = par.reset(seed=0)
    _, _, _, _, step_infos = par.step({a: np.zeros(par.action_space(a).shape, np.float32) for a in par.agents})
    keys = set(reset_infos["arm_0"])
    assert keys == set(step_infos["arm_0"]) and {"reward_formation", "reward_effort", "shield_intervened"} <= keys
    assert all(np.issubdtype(np.asarray(v).dtype, np.number) or isinstance(v, bool)
               for v in step_infos["arm_0"].values()), "infos must be numeric (TorchRL's PettingZooWrapper)"
    gym = gymnasium.make(f"pan1_env:{env_id}", safety_filter=True, effort_weight=0.1)
    _, reset_info = gym.reset(seed=0)
    _, _, _, _, step_info = gym.step(np.zeros(gym.action_space.shape, np.float32))
    assert set(reset_info) == set(step_info) == keys
    venv = Pan1VectorEnv(env_id, 2, effort_weight=0.1)
    _, vinfo = venv.reset(seed=0)
    assert {k for k in vinfo if not k.startswith("_")} == keys


def test_team_infos_aggregate_the_arms_as_the_reward_does() -> None:
    core = FormationCore(FormationConfig("paper_pa_mixed_square", safety_filter=True, effort_weight=0.3), 2)
    core.seed([0, 1])
    core.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (2, 4, core.k_max))
    out = core.step(actions)
    team = core.team_infos(out.infos)
    np.testing.assert_allclose(team["reward_formation"] + team["reward_effort"], out.reward.mean(axis=1), atol=1e-12)
    np.testing.assert_array_equal(team["cost"], out.infos["cost"].sum(axis=1))
    np.testing.assert_array_equal(team["min_clearance"], out.infos["min_clearance"].min(axis=1))
    np.testing.assert_array_equal(team["shield_intervened"], out.infos["shield_intervened"].any(axis=1))
    np.testing.assert_array_equal(team["shield_status"], out.infos["shield_status"].max(axis=1))
    # the applied commands laid out as the flat team action: arm i's k_i entries in agent order
    flat = [np.concatenate([row[i, :k] for i, k in enumerate(core.n_actuated)]) for row in out.infos["shield_applied"]]
    np.testing.assert_array_equal(team["shield_applied"], flat)
    for b in range(2):  # the one-copy views' Python reduction gives the same numbers
        one = core.team_info(out.infos, b)
        assert set(one) == set(team)
        for key, value in one.items():
            np.testing.assert_array_equal(value, team[key][b], err_msg=key)


@pytest.mark.parametrize("arms", [2, 3, 7, 8, 9])
def test_team_infos_are_numpys_reductions_bit_for_bit(arms: int) -> None:
    """The compiled team aggregates (below 8 arms) and numpy's (from 8, and for dtypes the core does not make) give
    numpy's dtypes and bytes: per-arm infos of faulted random teams with -0.0 and 0.0, NaN of either sign,
    infinities and magnitudes that round, random flags, statuses and counts, in arrays and strided views."""
    config = FormationConfig("pan1_env/FaultFormation-v1", random_options={"n_arms": arms}, safety_filter=True,
                             effort_weight=0.1)
    core = FormationCore(config, 16)
    core.seed(0)
    core.reset()
    out = core.step(np.random.default_rng(0).uniform(-1, 1, (16, arms, core.k_max)))
    rng = np.random.default_rng(arms)
    infos = {}
    for key, value in out.infos.items():
        if value.ndim >= 2 and key != "shield_applied":
            if value.dtype == np.float64:
                value = value * 10.0 ** rng.integers(-12, 12, value.shape)
                for odd in (-0.0, 0.0, np.nan, -np.nan, np.inf, -np.inf):
                    value[rng.random(value.shape) < 0.08] = odd
            elif value.dtype == bool:
                value = rng.random(value.shape) < 0.3
            else:  # the filter's statuses and QP counts
                value = rng.integers(0, 3, value.shape).astype(value.dtype)
            if value.ndim == 2 and value.dtype == np.float64:
                value = np.repeat(value, 2, axis=1)[:, ::2]  # a strided view of the same values
        infos[key] = value
    ties = np.zeros((16, arms))
    ties[:, ::2] = -0.0
    infos["min_clearance"] = ties  # 0.0 and -0.0 alone: numpy's minimum keeps the later
    infos["reward_single"] = rng.standard_normal((16, arms)).astype(np.float32) * 1e3  # numpy adds in float32
    infos["cost"] = (rng.random((16, arms)) < 0.5).astype(np.float32)
    team = core.team_infos(infos)
    rules = {"cost": "sum", "actuator_lost": "sum", "shield_intervened": "any", "shield_fallback": "any",
             "shield_status": "max", "min_clearance": "min", "shield_min_barrier": "min", "qp_counts": "sum"}
    for key, value in infos.items():
        rule = rules.get(key, "mean" if key.startswith("reward_") else None)
        if rule is not None:
            expected = getattr(value, rule)(axis=1)
            assert team[key].dtype == expected.dtype and team[key].tobytes() == expected.tobytes(), key


@pytest.mark.parametrize("mode", ["velocity", "torque", "residual", "gain"])
def test_shield_report_is_flat_and_in_action_units(mode: str) -> None:
    config = FormationConfig("paper_pa_mixed_square", safety_filter=True, action_mode=mode, max_joint_speed=2.0,
                             max_torque=10.0)
    core = FormationCore(config, 1)
    core.seed([3])
    core.reset()
    _, infos = core.start()
    assert (infos["shield_applied"] == 0).all() and (infos["shield_min_barrier"] == np.inf).all()
    out = core.step(np.random.default_rng(3).uniform(-1, 1, (1, 4, core.k_max)))
    applied, rec = out.infos["shield_applied"][0], core.record
    for i, (n, k) in enumerate(zip(core.n_links, core.n_actuated, strict=True)):
        # the torque over max_torque, else the filtered velocity over max_joint_speed (gain mode too)
        command = rec.tau[0, i, n - k : n] / 10.0 if mode == "torque" else rec.v_star[0, i, :k] / 2.0
        np.testing.assert_allclose(applied[i, :k], command, rtol=1e-6)
        assert (applied[i, k:] == 0).all()
    counts = out.infos["qp_counts"][0]
    np.testing.assert_array_equal(out.infos["shield_status"][0], np.where(counts[:, 2] > 0, 2, counts[:, 1] > 0))
    assert all(np.ndim(v) > 0 and v.dtype != object for v in out.infos.values())


def test_every_view_accepts_every_registered_id() -> None:
    for env_id in ("pan1_env/WholeArmStaticFormation-v0", "pan1_env:pan1_env/RandomFormation-v0"):
        env = parallel_env(env_id)
        assert env.config.random and env.scenario.n_arms == 4
    assert parallel_env("pan1_env/WholeArmStaticFormation-v0").scenario.bodies == "links"
    mixed = parallel_env("paper_pa_mixed_square").scenario.name
    assert Pan1VectorEnv("pan1_env/PaperMixedPA-v0", 2).scenario.name == mixed
    # an option given with an id is merged over the id's options, key by key
    env = parallel_env("pan1_env/WholeArmFormation-v0", random_options={"n_obstacles": 2})
    assert len(env.scenario.obstacles) == 2 and env.scenario.obstacle_paths is not None


def test_config_validates_once_with_a_hint() -> None:
    with pytest.raises(TypeError, match="did you mean 'success_tolerance'"):
        FormationConfig.of("paper_pa3_square", sucess_tolerance=0.02)
    with pytest.raises(ValueError, match="random_options: unknown option 'n_arm'; did you mean 'n_arms'"):
        FormationConfig("random", random_options={"n_arm": 3})
    with pytest.raises(ValueError, match="max_steps"):
        FormationConfig(max_steps=0)
    config = FormationConfig("paper_pa3_square", control_dt=0.1)
    assert config.max_steps == 1000 and config.substeps == 10 and config.replace(max_steps=7).max_steps == 7


def test_a_bad_reset_option_or_seed_is_refused_in_every_view_and_changes_nothing() -> None:
    from pan1_env.reach import PAReachEnv

    views = [parallel_env("random"), CentralizedEnv("random"), Pan1VectorEnv("random", 2), PAReachEnv()]
    for env in views:
        first = env.reset(seed=3)
        rngs = [rng.bit_generator.state for rng in env.core.rngs]
        state = env.core.engine.joint_state()[0].copy()
        if isinstance(env, PAReachEnv):  # the formation envs take no option (and ignore them, as PettingZoo asks)
            with pytest.raises(ValueError, match="reset option 'colour'"):
                env.reset(seed=4, options={"colour": "red"})
        with pytest.raises(gymnasium.error.Error):
            env.reset(seed=-1)
        assert rngs == [rng.bit_generator.state for rng in env.core.rngs]
        np.testing.assert_array_equal(env.core.engine.joint_state()[0], state)
        _assert_same(env.reset(seed=3), first)
    reach = views[-1]
    with pytest.raises(ValueError, match="2 finite numbers"):
        reach.reset(options={"goal": (0.0, np.nan)})
    _, _ = reach.reset(options={"goal": (0.5, 0.25)})
    np.testing.assert_array_equal(reach.goal, [0.5, 0.25])


def test_replace_resolves_the_defaults_again() -> None:
    config = FormationConfig("paper_pa3_square")
    assert config.physics_dt == 0.01 and config.max_steps == 2000
    assert config.replace(action_mode="torque").physics_dt == 0.002  # torque mode's own default step
    assert config.replace(control_dt=0.1).max_steps == 1000
    assert config.replace(scenario="random").random and not config.random


def test_the_gymnasium_view_renders_every_reset_and_step_in_human_mode(monkeypatch) -> None:
    drawn = []
    monkeypatch.setattr(CentralizedEnv, "render", lambda self: drawn.append(self.num_steps))
    env = gymnasium.make("pan1_env:pan1_env/PaperPA3Square-v0", render_mode="human")
    env.reset(seed=0)
    for _ in range(2):
        env.step(np.zeros(env.action_space.shape, np.float32))
    assert drawn == [0, 1, 2]


def test_a_filter_the_qp_solver_cannot_run_is_refused_when_it_is_switched_on() -> None:
    from pan1_env.wrappers import SafetyShield

    with pytest.raises(ValueError, match="torque-mode filter needs qp_solver='active_set'"):
        parallel_env("paper_pa3_square", action_mode="torque", qp_solver="piqp", safety_filter=True)
    env = parallel_env("paper_pa3_square", action_mode="torque", qp_solver="piqp")
    with pytest.raises(ValueError, match="torque-mode filter needs qp_solver='active_set'"):
        SafetyShield(env)
    assert env.safety_filter is None


def test_one_copy_team_info_equals_the_batched_one_for_large_teams_and_nan() -> None:
    """Nine arms (numpy's pairwise summation starts at 8) and a non-finite clearance: the one-copy Python
    reductions give the batched numpy ones bit for bit."""
    config = FormationConfig("random", random_options={"n_arms": 9}, safety_filter=True, effort_weight=0.1)
    core = FormationCore(config, 2)
    core.seed([0, 1])
    core.reset()
    out = core.step(np.random.default_rng(1).uniform(-1, 1, (2, 9, core.k_max)))
    infos = dict(out.infos)
    infos["min_clearance"] = infos["min_clearance"].copy()
    infos["min_clearance"][1, 4] = np.nan
    infos["reward_effort"] = infos["reward_effort"] * np.linspace(1e-3, 1e12, 9)  # magnitudes that round
    team = core.team_infos(infos)
    for b in range(2):
        for key, value in core.team_info(infos, b).items():
            np.testing.assert_array_equal(value, team[key][b], err_msg=key)
    assert np.isnan(core.team_info(infos, 1)["min_clearance"])


def test_every_view_says_in_its_repr_whether_the_filter_is_on() -> None:
    """Views differ in the filter's default; the repr (and Gymnasium's wrappers' repr) shows the switch."""
    from pan1_env.reach import PAReachEnv
    from pan1_env.wrappers import SafetyShield

    expected = [(parallel_env("paper_pa3_square"), "off"), (CentralizedEnv("paper_pa3_square"), "off"),
                (Pan1VectorEnv("paper_pa3_square", 2), "on"), (PAReachEnv(), "on"),
                (parallel_env("paper_pa3_square", safety_filter=True), "on"),
                (gymnasium.make("pan1_env:pan1_env/PaperPA3Square-v0"), "off")]
    for env, state in expected:
        assert f"safety_filter={state}" in repr(env), repr(env)
    shielded = SafetyShield(parallel_env("paper_pa3_square"))
    shielded.reset(seed=0)
    assert "safety_filter=on" in repr(shielded.unwrapped)
    assert "'pan1_env/RandomFormation-v1', copies=3" in repr(Pan1VectorEnv("pan1_env/RandomFormation-v1", 3))


def test_every_view_says_its_step_in_seconds() -> None:
    """``env.dt`` is the simulated time of one step, the config's control_dt, in every view."""
    from pan1_env.reach import PAReachEnv

    views = [parallel_env("paper_pa3_square", control_dt=0.1), CentralizedEnv("paper_pa3_square", control_dt=0.1),
             Pan1VectorEnv("paper_pa3_square", 2, control_dt=0.1), PAReachEnv(control_dt=0.1),
             gymnasium.make("pan1_env/RandomFormation-v1", control_dt=0.1).unwrapped]
    for env in views:
        assert env.dt == env.config.control_dt == 0.1, type(env).__name__


def test_obstacle_centers_now_follow_the_moving_obstacles_and_are_a_copy() -> None:
    """Where the obstacles are after some steps of a moving-obstacle task: the scenario's paths at the elapsed time,
    as :func:`pan1_env.bodies.obstacle_centers` (the reference) puts them; changing the array changes nothing."""
    from pan1_env.bodies import obstacle_centers

    env = parallel_env("random", random_options={"bodies": "links", "link_radius": 0.03, "obstacle_speed": (0.1, 0.2)},
                       control_dt=0.05)
    env.reset(seed=3)
    for _ in range(10):
        env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    sc = env.scenario
    now = env.obstacle_centers_now
    expected = obstacle_centers(sc.obstacles.centers, sc.obstacle_paths, sc.obstacle_speeds, 10 * env.dt)
    np.testing.assert_allclose(now[0], expected, atol=1e-9)
    assert not np.allclose(now[0], sc.obstacles.centers)
    now[:] = 0.0
    np.testing.assert_allclose(env.obstacle_centers_now[0], expected, atol=1e-9)


@pytest.mark.parametrize("env_id", ["pan1_env/RandomFormation-v1", "pan1_env/FaultFormation-v1",
                                    "pan1_env/MovingFormation-v1", "pan1_env/WholeArmFormation-v2"])
def test_after_some_copies_reset_the_others_keep_their_observations_and_the_reset_ones_are_fresh(env_id: str) -> None:
    """An autoreset observes only the copies that ended: what it returns equals observing every copy anew, and the
    ended copies' last observations are the step's."""
    venv = Pan1VectorEnv(env_id, 4, max_steps=6)
    core = venv.core
    venv.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(3):
        venv.step(rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32))
    core.steps[[0, 2]] = core.config.max_steps - 1  # copies 0 and 2 end in the next step, 1 and 3 go on
    actions = core.padded_actions(rng.uniform(-1, 1, venv.action_space.shape))
    result = core.step(actions, autoreset=True)
    assert result.ended.tolist() == [0, 2]
    for after, anew, last in zip(result.observations, core.observe(), result.final_observations, strict=True):
        np.testing.assert_array_equal(after, anew)
        np.testing.assert_array_equal(after[[1, 3]], last[[1, 3]])
        assert not np.array_equal(after[[0, 2]], last[[0, 2]])


def test_the_team_mean_of_a_few_arms_is_numpys_bit_for_bit() -> None:
    """One value after another as numpy adds them (Python's own sum compensates the rounding from 3.12 on)."""
    from pan1_env.core import team_mean

    rng = np.random.default_rng(0)
    rows = [[0.1, 0.2, 0.3], [1e16, 1.0, -1e16], [-0.0], [-0.0, -0.0],
            *[rng.normal(size=n).tolist() for n in range(1, 12)]]
    for row in rows:
        expected = float(np.add.reduce(np.asarray(row))) / len(row)
        assert np.float64(team_mean(row)).tobytes() == np.float64(expected).tobytes(), row


def _numpy_state(core: FormationCore) -> np.ndarray:
    """The centralised state written with numpy alone: the twin of the compiled :meth:`FormationCore.state`."""
    from pan1_env.observation import OBS_BOUND

    engine, B = core.engine, core.copies
    q, qd = engine.joint_state(pad=0.0)
    arms = np.concatenate([q, qd, engine.positions()], axis=-1)
    joints = arms[..., : 2 * q.shape[-1]]
    joints[np.isnan(joints)] = 0.0
    obstacles = np.concatenate([engine.centers, engine.radii[..., None]], axis=-1)
    out = np.concatenate([arms.reshape(B, -1), obstacles.reshape(B, -1), core.task.target_state(engine)], axis=1)
    return np.clip(out, -OBS_BOUND, OBS_BOUND, out=out).astype(np.float32)


_STATE_SETUPS = {
    "random": ("pan1_env/RandomFormation-v1", {}),  # two kinds out of team order
    "faults": ("pan1_env/FaultFormation-v1", {}),  # arms handed to their faulted twins
    "moving target": ("pan1_env/MovingFormation-v1", {}),
    "moving obstacles": ("pan1_env/WholeArmFormation-v2", {}),
    "one kind in order": ("pan1_env/PaperPA3Square-v0", {}),
    "padding": ("random", {"random_options": {"n_arms": 4, "links": (3, 5, 2, 4)}}),  # n_max 5
}


@pytest.mark.parametrize("setup", list(_STATE_SETUPS))
def test_the_compiled_state_is_its_numpy_twins_bit_for_bit(setup: str) -> None:
    """Every set-up above over an episode with autoreset, then a non-finite arm (its angles and speeds read 0, its
    end-effector NaN) and values beyond the bound: the same bytes as the numpy twin (-0.0 and NaN included)."""
    scenario, kwargs = _STATE_SETUPS[setup]
    core = FormationCore(FormationConfig(scenario, safety_filter=True, **kwargs), 4)
    core.seed(3)
    core.reset()
    rng = np.random.default_rng(0)
    for step in range(40):
        core.step(rng.uniform(-1, 1, (4, len(core.agents), core.k_max)), autoreset=True)
        if step % 10 == 9:
            assert core.state().tobytes() == _numpy_state(core).tobytes()
    if setup == "faults":
        assert any(kind.faulted and len(kind.stepped) for kind in core.engine.kinds)
    kind = next(kind for kind in core.engine.kinds if len(kind.stepped))
    row = int(kind.stepped[0])
    kind.q[row, 0], kind.qd[row, -1], kind.p[row, 0] = np.nan, np.nan, np.nan
    kind.q[row, -1], kind.p[row, 1], kind.qd[row, 0] = 3e6, -4e6, -0.0  # clipped, clipped, kept
    assert core.state().tobytes() == _numpy_state(core).tobytes()


def _partial_start_core(setup: str) -> FormationCore:
    """Five copies of a state set-up (:data:`_STATE_SETUPS`) or of the set-ups below, the filter on."""
    from pan1_env.config import ReachConfig

    if setup == "reach":
        return FormationCore(ReachConfig("paper_pa3_square", safety_filter=True), 5)
    scenario, kwargs = {
        "whole arms among still obstacles": ("pan1_env/WholeArmStaticFormation-v1", {}),
        "success hold": ("pan1_env/MovingFormation-v1", {"success_hold": 1.0}),
        "faulted at the start": ("random", {"random_options": {"fault_probability": 1.0, "fault_time": (0.0, 0.02)}}),
    }.get(setup) or _STATE_SETUPS[setup]
    return FormationCore(FormationConfig(scenario, safety_filter=True, **kwargs), 5)


@pytest.mark.parametrize("setup", ["random", "faults", "moving target", "moving obstacles", "padding",
                                   "whole arms among still obstacles", "success hold", "faulted at the start",
                                   "reach"])
def test_a_partial_start_is_the_full_starts_rows(setup: str) -> None:
    """``start(copies)`` (a partial reset's observations and infos, at a cost of those copies alone) gives the rows
    of ``start()`` bit for bit, after some copies are reset mid-episode, and leaves the task's state (a moving
    formation's success clock) as ``start()`` does; the reset put the reset arms' end-effectors where their joints
    put them and left the others', and the joints and clearances of some copies are those copies' rows of every
    copy's."""
    from pan1_env.compiled import kernels

    core = _partial_start_core(setup)
    core.seed(5)
    core.reset()
    rng = np.random.default_rng(1)
    for _ in range(25):
        core.step(rng.uniform(-1, 1, (5, len(core.agents), core.k_max)))
    copies = np.array([3, 0])
    before = [kind.p.copy() for kind in core.engine.kinds]
    core.reset(copies)
    for kind, p in zip(core.engine.kinds, before, strict=True):  # the reset rows' from their joints, the others kept
        reset = np.isin(np.arange(len(p)), kind.rows(copies))
        from_joints = np.empty_like(p)
        kernels().group_end_effectors(kind.lengths, kind.base, kind.phi, kind.q, from_joints)
        p[reset] = from_joints[reset]
        assert p.tobytes() == kind.p.tobytes()
    if setup == "faulted at the start":
        assert core.engine.faulted[copies].any()
    mats, infos = core.start(copies)
    held = getattr(core.task, "below_since", np.zeros(0)).copy()
    all_mats, all_infos = core.start()
    for mat, whole in zip(mats, all_mats, strict=True):
        assert mat.tobytes() == whole[copies].tobytes()
    assert set(infos) == set(all_infos)
    for key, value in infos.items():
        assert value.tobytes() == all_infos[key][copies].tobytes(), key
    np.testing.assert_array_equal(getattr(core.task, "below_since", np.zeros(0)), held)
    assert core.engine.clearance(copies).tobytes() == core.engine.clearance()[copies].tobytes()
    assert core.engine.joint_positions(copies).tobytes() == core.engine.joint_positions()[copies].tobytes()


@pytest.mark.parametrize("setup", ["random", "reach"])
def test_a_steps_outcome_refuses_copies(setup: str) -> None:
    """``copies`` is for a reset's outcome: with a step's record the tasks refuse it rather than mix rows."""
    core = _partial_start_core(setup)
    core.seed(0)
    core.reset()
    core.step(np.zeros((5, len(core.agents), core.k_max)))
    state = core.task.observe(core.engine)[0]
    with pytest.raises(ValueError, match="covers every copy"):
        core.task.evaluate(core.record, core.engine, state, np.zeros((5, len(core.agents))), copies=np.array([0]))
