"""The benchmark's declared tasks (pan1_env.baselines.suite): each is a registered id with five training seeds, and
no copy of any training run meets one of its held-out teams (drawn here, not argued)."""

import numpy as np
import pytest
from gymnasium.utils.seeding import np_random

from pan1_env.baselines.suite import SUITE, suite_task
from pan1_env.core import copy_generator
from pan1_env.random_scenario import RandomScenarioOptions
from pan1_env.registration import ENV_IDS, env_arguments
from pan1_env.team_draw import draw_teams

COPIES = 16  # the recipes' --n-envs on random teams


def test_every_task_is_a_registered_id_with_five_seeds_and_its_held_out_teams() -> None:
    assert len({task.name for task in SUITE}) == len({task.env_id for task in SUITE}) == len(SUITE)
    for task in SUITE:
        assert task.env_id in ENV_IDS
        assert len(set(task.train_seeds)) >= 5 and task.train_steps > 0
        random = env_arguments(task.env_id)[0] == "random"
        # 16-arm episodes cost four times a 4-arm one: that task holds 50 teams out, every other random one 200
        assert len(task.held_out) == (50 if task.env_id == "pan1_env/LargeFormation-v0" else 200 if random else 1)
        assert 0 <= task.law_success <= 1 and task.target
    assert suite_task("pan1_env:pan1_env/MovingFormation-v1") is suite_task("placed, turning, travelling")
    with pytest.raises(ValueError, match="no suite task 'nope'; the suite's: pan1_env/WholeArmStaticFormation-v1"):
        suite_task("nope")


@pytest.mark.parametrize("task", [t for t in SUITE if env_arguments(t.env_id)[0] == "random"], ids=lambda t: t.env_id)
def test_no_training_copy_draws_a_held_out_team(task) -> None:
    """The first team of every copy of every training seed against every held-out team: no two share their
    bases (a team's bases are drawn from its generator's first numbers)."""
    options = RandomScenarioOptions(**env_arguments(task.env_id)[1].get("random_options", {}))
    held_out = draw_teams([np_random(s)[0] for s in task.held_out], options).bases.reshape(len(task.held_out), -1)
    training = draw_teams([copy_generator(s, b) for s in task.train_seeds for b in range(COPIES)], options)
    training = training.bases.reshape(len(task.train_seeds) * COPIES, -1)
    distance = np.abs(training[:, None] - held_out[None]).max(axis=-1)
    assert distance.min() > 1e-9
    assert len(np.unique(np.round(training, 12), axis=0)) == len(training), "training copies share a team"
