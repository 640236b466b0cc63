"""The seeding convention: one int seeds a batch with independent streams, one per copy.

A batch seeded with s gives copy b the child b of ``SeedSequence(s)``; a one-copy env reset with seed s uses
``SeedSequence(s)`` itself (Gymnasium's ``np_random``). So two training runs with different seeds share no
copy's teams, and no training copy meets a held-out evaluation team (those are one-copy seeds). Under the old
convention, copy b of seed s was the one-copy env's seed s + b, which each test here would catch.
"""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.seeding import np_random

from pan1_env.centralized import CentralizedEnv
from pan1_env.core import copy_generator
from pan1_env.vector import Pan1VectorEnv

B = 6


def _first_teams(seed: int) -> set[bytes]:
    """Every copy's first observation (a team's bases, obstacles and arms) after ``reset(seed=seed)``."""
    obs, _ = Pan1VectorEnv("random", B, max_steps=2).reset(seed=seed)
    return {row.tobytes() for row in obs}


def test_runs_with_different_seeds_share_no_copy_and_the_same_seed_repeats() -> None:
    teams = [_first_teams(s) for s in range(3)]
    assert all(len(t) == B for t in teams)  # the copies of one run differ from each other
    assert not teams[0] & teams[1] and not teams[1] & teams[2] and not teams[0] & teams[2]
    assert _first_teams(1) == teams[1]


def test_no_copy_of_a_seeded_batch_meets_a_one_copy_seed() -> None:
    """The held-out teams are one-copy seeds: a batch's copies are none of them (the seeds s + b the old convention
    gave them, and the first held-out seeds of evaluation and of ``report``)."""
    from pan1_env.baselines.evaluation import EVAL_SEEDS
    from pan1_env.baselines.report import HELD_OUT_FIRST

    held_out = [*range(2 * B), *EVAL_SEEDS[:B], *range(HELD_OUT_FIRST, HELD_OUT_FIRST + B)]
    batch = _first_teams(0)
    single = CentralizedEnv("random")
    singles = {single.reset(seed=s)[0].tobytes() for s in held_out}
    assert not batch & singles
    streams = {copy_generator(s, b).random() for s in range(5) for b in range(64)}
    one_copy_seeds = [*range(100_000), *EVAL_SEEDS, *range(HELD_OUT_FIRST, HELD_OUT_FIRST + 200)]
    one_copy = {np_random(s)[0].random() for s in one_copy_seeds}
    assert len(streams) == 5 * 64 and not streams & one_copy


def test_a_list_of_seeds_gives_each_copy_the_one_copy_team() -> None:
    obs, _ = Pan1VectorEnv("random", 3).reset(seed=[7, 8, 9])
    for b, s in enumerate((7, 8, 9)):
        np.testing.assert_array_equal(obs[b], CentralizedEnv("random").reset(seed=s)[0])


def test_the_sb3_views_seed_as_the_vector_env() -> None:
    pytest.importorskip("stable_baselines3")
    from pan1_env.baselines.vec_env import SB3VecEnv

    sb3 = SB3VecEnv("random", B)
    assert sb3.seed(4) == [4] * B
    np.testing.assert_array_equal(sb3.reset(), Pan1VectorEnv("random", B).reset(seed=4)[0])
