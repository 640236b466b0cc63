"""examples/rllib_pettingzoo.py end to end: one tiny PPO iteration on a local Ray (skipped without RLlib)."""

import importlib.util
import math
import os
from pathlib import Path

import pytest

if os.environ.get("PAN1_REQUIRE_RAY"):  # set by `make test` in .venv-ray: a missing Ray is then a failure
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
def test_one_shielded_iteration_trains_the_shared_policy(example) -> None:
    results = example.main(["--iterations", "1", "--max-steps", str(MAX_STEPS), "--train-batch-size", str(BATCH),
                            "--minibatch-size", "50", "--num-epochs", "1"])
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
