"""examples/rllib_pettingzoo.py end to end: one tiny PPO iteration on a local Ray (skipped without RLlib)."""

import importlib.util
import math
import os
from pathlib import Path

import pytest

if os.environ.get("PAN1_REQUIRE_RAY"):  # set by `make test`: a missing Ray is then a failure
    import ray.rllib  # noqa: F401
else:
    pytest.importorskip("ray.rllib")

import ray  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "rllib_pettingzoo.py"
MAX_STEPS = 20
BATCH = 100
N_ARMS = 4


@pytest.fixture
def example():
    """The example module, loaded from its file; Ray is shut down afterwards whatever happens."""
    spec = importlib.util.spec_from_file_location("rllib_pettingzoo", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        yield module
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_one_shielded_iteration_trains_the_shared_policy_and_a_second_resumes_it(example, tmp_path) -> None:
    common = ["--max-steps", str(MAX_STEPS), "--train-batch-size", str(BATCH), "--minibatch-size", "50",
              "--num-epochs", "1", "--out", str(tmp_path)]
    results = example.main(["--iterations", "1", *common])
    assert len(results) == 1
    runners, learners = results[0]["env_runners"], results[0]["learners"]

    steps = runners["num_env_steps_sampled"]
    assert steps >= BATCH
    # parameter sharing: every arm's step went to the one shared module, and it is the only one trained
    assert runners["num_module_steps_sampled"] == {example.SHARED_POLICY: N_ARMS * steps}
    assert set(learners) == {example.SHARED_POLICY, "__all_modules__"}
    assert math.isfinite(learners[example.SHARED_POLICY]["total_loss"])
    assert learners[example.SHARED_POLICY]["num_module_steps_trained"] > 0

    # episodes are truncated at exactly max_steps (no termination by default), and fit in what was sampled
    assert runners["episode_len_min"] == runners["episode_len_max"] == MAX_STEPS
    assert 1 <= runners["num_episodes"] <= steps // MAX_STEPS
    # the team return is the sum of the arms' returns (they share the formation reward)
    per_arm = runners["agent_episode_returns_mean"]
    assert set(per_arm) == {f"arm_{i}" for i in range(N_ARMS)}
    assert runners["episode_return_mean"] == pytest.approx(sum(per_arm.values()))
    assert runners["episode_return_mean"] < 0.0  # the formation error is never exactly zero from the start
    # behind the shield no arm ever enters an obstacle
    assert runners[example.COST_KEY] == 0.0

    # --out: a row per iteration and a checkpoint, from which --resume runs only what is left
    ray.shutdown()
    assert len(example.main(["--iterations", "2", "--resume", *common])) == 1
    lines = (tmp_path / "progress.csv").read_text().splitlines()
    assert lines[0] == "iteration,env_steps,episode_return_mean,episode_cost_mean"
    assert [line.split(",")[0] for line in lines[1:]] == ["1", "2"]
    first, second = (int(line.split(",")[1]) for line in lines[1:])
    assert second > first >= BATCH  # the counters continued from the checkpoint
    with pytest.raises(SystemExit):
        example.main(["--resume", "--out", str(tmp_path / "empty")])


def test_padding_gives_a_mixed_team_one_pair_of_spaces_and_changes_nothing_else(example) -> None:
    import numpy as np

    from pan1_env.environment import parallel_env

    plain = parallel_env("paper_pa_mixed_square", max_steps=3)
    padded = example.PadToLargestArm(parallel_env("paper_pa_mixed_square", max_steps=3))
    sizes = {a: (plain.observation_space(a).shape[0], plain.action_space(a).shape[0]) for a in plain.possible_agents}
    assert len(set(sizes.values())) > 1  # the team is mixed: arm_3 has one actuated joint fewer
    n_obs, n_act = max(o for o, _ in sizes.values()), max(u for _, u in sizes.values())
    assert all(padded.observation_space(a) == padded.observation_space("arm_0") for a in plain.possible_agents)
    assert padded.observation_space("arm_0").shape == (n_obs,)
    assert all(padded.action_space(a).shape == (n_act,) for a in plain.possible_agents)
    obs_plain, _ = plain.reset(seed=4)
    obs_padded, _ = padded.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(3):
        for a, o in obs_padded.items():
            assert o.shape == (n_obs,) and padded.observation_space(a).contains(o)
            n = sizes[a][0]
            assert np.array_equal(o[:n], obs_plain[a]) and not o[n:].any()
        actions = {a: rng.uniform(-1, 1, n_act).astype(np.float32) for a in padded.agents}
        obs_padded, r_padded, *_ = padded.step(actions)
        obs_plain, r_plain, *_ = plain.step({a: u[: sizes[a][1]] for a, u in actions.items()})
        assert r_padded == r_plain


@pytest.mark.slow
def test_one_shared_policy_trains_a_mixed_team(example) -> None:
    results = example.main(["--scenario", "paper_pa_mixed_square", "--iterations", "1", "--max-steps",
                            str(MAX_STEPS), "--train-batch-size", str(BATCH), "--minibatch-size", "50",
                            "--num-epochs", "1"])
    runners, learners = results[0]["env_runners"], results[0]["learners"]
    steps = runners["num_env_steps_sampled"]
    assert runners["num_module_steps_sampled"] == {example.SHARED_POLICY: N_ARMS * steps}
    assert math.isfinite(learners[example.SHARED_POLICY]["total_loss"])
    assert runners[example.COST_KEY] == 0.0
