"""examples/torchrl_mappo.py, the TorchRL-native MAPPO: a few iterations on the paper's team make the deterministic
policy form better than the untrained one, behind the shield at zero cost (skipped without TorchRL, as
tests/test_torchrl.py)."""

import importlib.util
import os
import sys
from pathlib import Path

import pytest

if os.environ.get("PAN1_REQUIRE_MARL"):  # set where the marl extra is installed: missing is a failure
    import torchrl  # noqa: F401
else:
    pytest.importorskip("torchrl")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "torchrl_mappo.py"


@pytest.mark.slow
def test_a_few_iterations_of_mappo_form_the_square_better_at_no_cost() -> None:
    """12 iterations of 32 episodes of 1.25 s. The paper's team starts the same way every episode, so the
    deterministic policy's return (minus the formation error, summed over the episode) is a noiseless measure; the
    untrained policy's squashed mean barely moves the arms. Measured gains in return: 2.07, 1.68 and 0.57 for seeds
    0, 1 and 2 (TorchRL 0.11 and 0.14 give the same numbers). The margin is under half the smallest, so that other
    hardware's rounding (another training trajectory) passes, and a policy that learned nothing fails."""
    spec = importlib.util.spec_from_file_location("torchrl_mappo", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = example  # its dataclass looks its module up there
    spec.loader.exec_module(example)
    before, after = example.main(["--scenario", "paper_pa3_square", "--iterations", "12", "--copies", "32",
                                  "--max-steps", "25", "--epochs", "4", "--minibatch", "400", "--lr", "3e-3",
                                  "--seed", "0"])
    assert after.episode_return > before.episode_return + 0.25
    assert before.total_cost == after.total_cost == 0.0  # behind the shield
