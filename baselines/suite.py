"""The benchmark's tasks, declared once: what each entry is trained on and judged on.

A researcher who adds an entry to the leaderboard trains it with a task's :attr:`SuiteTask.train_seeds` and
:attr:`SuiteTask.train_steps` and evaluates it on :attr:`SuiteTask.held_out` (``pan1-env report --first``), the
same for every entry, so the numbers compare. The held-out teams are one-copy reset seeds; a training run's copy
b of seed s draws from the stream spawned as child b of ``SeedSequence(s)`` (:func:`pan1_env.core.copy_generator`),
never from an integer seed, so no training copy meets a held-out team (``tests/test_suite.py`` draws both). The
law's numbers are this project's measurements on the same held-out teams, behind the task's filter
(docs/ENVIRONMENTS.md); the targets are what a shipped decentralised policy should reach.

    from pan1_env.baselines.suite import SUITE
    for task in SUITE:
        print(task.name, task.env_id, task.law_success, task.target)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["SuiteTask", "Target", "SUITE", "suite_task", "METRICS", "HELD_OUT_FIRST"]

HELD_OUT_FIRST = 2_000_000  #: the first held-out reset seed of every random-team task (pan1-env report's default)
#: what every entry is judged on, per task: pan1-env report's and benchmark's columns
METRICS = ("success at 1 cm", "time to formation", "time ÷ the law's on teams both form", "cost", "min clearance",
           "interventions")


@dataclass(frozen=True)
class Target:
    """A task's target as numbers, which the leaderboard checks every entry against (its IQM over the runs).

    Attributes:
        success: the least fraction of the held-out teams formed (None: no floor).
        vs_law: ``"at least"`` or ``"above"`` the law's success on the same teams (None: no comparison).
        time_ratio: the most time to formation, as a multiple of the law's on the teams both form (None: any).
        cost: the most cost, arm-steps inside an obstacle over the held-out teams (None: any).
    """

    success: float | None = None
    vs_law: str | None = None
    time_ratio: float | None = None
    cost: float | None = 0.0


@dataclass(frozen=True)
class SuiteTask:
    """One task of the benchmark.

    Attributes:
        name: the short name the leaderboard uses.
        env_id: the registered id (``gymnasium.make("pan1_env:" + env_id)``).
        env_kwargs: the env arguments on top of the id's (``pan1-env train --env-kwargs``), the same for every entry.
        train_steps: arm-steps per training run.
        train_seeds: the training seeds (``pan1-env train --seed``), at least five.
        held_out_teams: held-out episodes, on reset seeds ``HELD_OUT_FIRST …`` (1 for a fixed scenario, whose one
            start is the task).
        law_success: the paper's law behind the task's filter on the held-out teams (fraction formed), as measured.
        target: what the shipped decentralised policy should reach, in words.
        goal: the same as numbers (:class:`Target`), which the leaderboard checks.
    """

    name: str
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    train_steps: int = 16_384_000
    train_seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    held_out_teams: int = 200
    law_success: float | None = None
    target: str = ""
    goal: Target = field(default_factory=Target)

    @property
    def held_out(self) -> range:
        """The held-out reset seeds."""
        return range(HELD_OUT_FIRST, HELD_OUT_FIRST + self.held_out_teams)


SUITE = (
    SuiteTask("whole-arm, still obstacles", "pan1_env/WholeArmStaticFormation-v1", law_success=0.785,
              target="success ≥ 90 %", goal=Target(success=0.90)),
    # v2: paths clear of every start and kept out whole, so even the law's cost is 0 (v1's law: 49 %, cost 519)
    SuiteTask("whole-arm, moving obstacles", "pan1_env/WholeArmFormation-v2", law_success=0.745,
              target="success ≥ 65 % and above the law's, cost 0", goal=Target(success=0.65, vs_law="above")),
    # v1: the fault margin, so that no lost actuator's drift reaches an obstacle (v0's law: 76 %, cost 0 on these
    # teams, but penetrations when arms fault at speed)
    SuiteTask("faults", "pan1_env/FaultFormation-v1", law_success=0.65, target="success ≥ 88 %, cost 0",
              goal=Target(success=0.88)),
    SuiteTask("placed, turning, travelling", "pan1_env/MovingFormation-v1", law_success=0.505,
              target="success ≥ 75 %", goal=Target(success=0.75)),
    SuiteTask("random teams", "pan1_env/RandomFormation-v1", law_success=0.955,
              target="success ≥ the law's, time ≤ 0.75× the law's", goal=Target(vs_law="at least", time_ratio=0.75)),
    # one network for any team size: trained on ring teams of 3-8 arms (the ippo-sizes entry), judged at 4 and 16;
    # 62 whole rollouts of that recipe (2,000 steps x 132 arms) make its budget
    SuiteTask("ring teams, 4 arms", "pan1_env/RandomFormation-v2", train_steps=16_368_000, law_success=0.98,
              target="success ≥ the law's at every team size, one network for all", goal=Target(vs_law="at least")),
    SuiteTask("ring teams, 16 arms", "pan1_env/LargeFormation-v0", train_steps=16_368_000, held_out_teams=50,
              law_success=0.0, target="success ≥ the law's, trained on teams of at most 8 arms",
              goal=Target(vs_law="at least")),
    SuiteTask("Section 5.1's square", "pan1_env/PaperPA3Square-v0", train_steps=4_096_000, held_out_teams=1,
              law_success=1.0, target="time ≤ 0.25× the law's (39.1 s)",
              goal=Target(vs_law="at least", time_ratio=0.25)),
    SuiteTask("Section 5.2's square", "pan1_env/PaperMixedPA-v0", train_steps=4_096_000, held_out_teams=1,
              law_success=1.0, target="time ≤ 0.25× the law's (21.4 s)",
              goal=Target(vs_law="at least", time_ratio=0.25)),
)


def suite_task(name_or_id: str) -> SuiteTask:
    """The suite's task of that name or id (``pan1_env:`` prefix allowed); ``ValueError`` listing them if none."""
    key = name_or_id.removeprefix("pan1_env:")
    for task in SUITE:
        if key in (task.name, task.env_id):
            return task
    raise ValueError(f"no suite task {name_or_id!r}; the suite's: {', '.join(t.env_id for t in SUITE)}")
