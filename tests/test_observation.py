"""The compiled observation builder against a plain per-agent reference of the documented layout."""

import numpy as np
import pytest

from pan1_env.environment import parallel_env
from pan1_env.observation import OBS_BOUND


def _reference(env) -> dict[str, np.ndarray]:
    """The layout of Pan1ParallelEnv's docstring, one agent at a time in numpy."""
    sc = env.scenario
    q, qd = env.joint_state()
    P = env.end_effectors()
    z = P[sc.formation.edges[:, 1]] - P[sc.formation.edges[:, 0]]
    err = np.linalg.norm(z, axis=-1) - sc.formation.distances
    centers, radii = sc.obstacles.centers, sc.obstacles.radii
    K, D = env.config.n_obstacle_obs, env.observation_layout.slots
    out = {}
    for i, agent in enumerate(env.agents):
        n = sc.arms[i].n_links
        o = [np.cos(q[i, :n]), np.sin(q[i, :n]), qd[i, :n] / env.config.max_joint_speed, P[i] - sc.arms[i].base]
        nbrs = [int(j) for j in sc.formation.neighbours(i)]
        if env.config.ring:  # the documented shared order: one back, one forward, two back, two forward
            nbrs = [(i + d) % len(sc.arms) for d in (-1, 1, -2, 2)[: len(nbrs)]]
        for s in range(D):
            if s < len(nbrs):
                j = nbrs[s]
                k = next(k for k, (a, b) in enumerate(sc.formation.edges) if {int(a), int(b)} == {i, j})
                o.append(np.array([1.0, *(P[j] - P[i]), err[k]]))
            else:
                o.append(np.zeros(4))
        rel = centers - P[i]
        dist = np.linalg.norm(rel, axis=-1)
        order = np.argsort(dist - radii, kind="stable")[:K]
        for s in range(K):
            if s < len(order):
                j = order[s]
                o.append(np.array([1.0, *rel[j], radii[j], dist[j] ** 2 - radii[j] ** 2]))
            else:
                o.append(np.zeros(5))
        out[agent] = np.clip(np.concatenate(o), -OBS_BOUND, OBS_BOUND).astype(np.float32)
    return out


@pytest.mark.parametrize("kwargs", [
    dict(scenario="paper_pa3_square"),
    dict(scenario="paper_pa3_square", n_obstacle_obs=5),  # more slots than obstacles
    dict(scenario="paper_pa3_square", n_obstacle_obs=1),
    dict(scenario="paper_pa_mixed_square"),
    dict(scenario="random", random_options=dict(n_arms=5, links=(2, 3, 4, 3, 2), n_obstacles=4)),
    dict(scenario="pan1_env/RandomFormation-v2", random_options=dict(n_arms=7)),  # every ring slot used
    dict(scenario="pan1_env/RandomFormation-v2", random_options=dict(n_arms=3)),  # two of four slots padded
])
def test_observations_match_the_per_agent_reference(kwargs) -> None:
    env = parallel_env(**kwargs)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for t in range(30):
        ref = _reference(env)
        assert obs.keys() == ref.keys()
        for agent in obs:
            assert obs[agent].dtype == np.float32 and env.observation_space(agent).contains(obs[agent])
            np.testing.assert_allclose(obs[agent], ref[agent], rtol=2e-6, atol=2e-6, err_msg=f"{agent} step {t}")
        obs, *_ = env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})


def test_multi_threaded_observations_equal_the_serial_ones_and_bad_chunks_are_refused() -> None:
    from pan1_env.vector import Pan1VectorEnv

    venv = Pan1VectorEnv("paper_pa_mixed_square", 5, threads=False)  # three arm kinds
    venv.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(3):
        venv.step(rng.uniform(-1, 1, venv.action_space.shape))
    engine, task = venv.engine, venv.task
    q, qd = engine.joint_state()
    args = (q, qd, engine.positions(), engine.bases, task.edges, task.distances, engine.centers, engine.radii,
            venv.config.max_joint_speed)
    layout = venv.observation_layout
    err, serial = layout.build_with_errors(*args)
    err3, chunked = layout.build_with_errors(*args, 3)
    np.testing.assert_array_equal(err3, err)
    for a, b in zip(chunked, serial, strict=True):
        np.testing.assert_array_equal(a, b)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="n_chunks"):
            layout.build_with_errors(*args, bad)


EARLY_FAULTS = {"fault_probability": 1.0, "fault_time": (0.1, 0.3)}  # every full arm faults within 0.3 s


@pytest.mark.parametrize(("env_id", "options", "keyword", "bad", "message"), [
    ("pan1_env/FaultFormation-v0", EARLY_FAULTS, "faulted", np.zeros((1, 3), dtype=bool),
     r"this layout observes faults: pass faulted of shape \(1, 4\)"),
    ("pan1_env/MovingFormation-v0", {}, "formation_velocity", np.zeros((1, 4, 3)),
     r"this layout observes a moving formation: pass formation_velocity of shape \(1, 4, 2\)"),
], ids=["faults", "moving"])
def test_a_layout_needs_what_its_team_observes(env_id, options, keyword, bad, message) -> None:
    """A layout whose team may fault needs the fault flags, and one whose formation moves the feed-forward:
    missing or misshapen, a clear error."""
    env = parallel_env(env_id, random_options=options)
    env.reset(seed=1)
    engine, layout, task = env.engine, env.observation_layout, env.task
    q, qd = engine.joint_state()
    args = (q, qd, engine.positions(), engine.bases, np.zeros((1, len(task.edges))), engine.centers, engine.radii,
            env.config.max_joint_speed)
    for value in (None, bad):
        with pytest.raises(ValueError, match=message):
            layout.build(*args, **{keyword: value})
    good = {"faulted": engine.faulted, "formation_velocity": task.feed_forward}[keyword]
    built = layout.build(*args, **{keyword: good})
    assert [m.shape[-1] for m in built] == [layout.size(n) for n, _ in layout.groups]


@pytest.mark.parametrize("env_id", ["pan1_env/RandomFormation-v2", "pan1_env/LargeFormation-v0"])
def test_a_rings_observation_has_the_same_size_and_slots_for_every_team_size(env_id: str) -> None:
    """On the ring an arm's observation has 4 neighbour slots whatever N, so one shared policy's input fits a
    team of any size, and slot s means the same for every arm: the arm one back, one forward, two back, two
    forward around the ring (its relative position p_j − p_i), absent slots zero."""
    sizes = {}
    for n_arms in (2, 3, 4, 8, 32):
        env = parallel_env(env_id, random_options={"n_arms": n_arms, "n_obstacles": max(3, 3 * n_arms // 4)})
        obs, _ = env.reset(seed=n_arms)
        P = env.end_effectors()
        sizes[n_arms] = {env.observation_space(a).shape for a in env.agents}
        for i, agent in enumerate(env.agents):
            slots = obs[agent][env.observation_layout.segments(3)["neighbours"]].reshape(4, 4)
            present = min(4, n_arms - 1)
            assert slots[:, 0].tolist() == [1.0] * present + [0.0] * (4 - present)
            for s, d in enumerate((-1, 1, -2, 2)[:present]):
                np.testing.assert_allclose(slots[s, 1:3], P[(i + d) % n_arms] - P[i], atol=1e-5)
            assert not slots[present:].any()
    assert len(set().union(*sizes.values())) == 1, sizes


@pytest.mark.parametrize("n_arms", [3, 7])
def test_the_reference_from_a_rings_observations_is_the_law(n_arms: int) -> None:
    """The paper's distributed law needs only an arm's graph neighbours: from the ring's 4 padded slots the
    reference policy computes what the env's own law computes from the state."""
    from rollouts import reference_and_law

    def make(**kw):
        return parallel_env("pan1_env/RandomFormation-v2", random_options={"n_arms": n_arms}, **kw)

    _, _, pairs, _ = reference_and_law(make, seed=2, steps=10, action_seed=1)
    for law, reference in pairs:
        np.testing.assert_allclose(law, reference, rtol=1e-4, atol=1e-5)
