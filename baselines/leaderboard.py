"""The leaderboard: every entry of the benchmark on every task's held-out teams (``pan1-env suite``).

The tasks are :data:`~pan1_env.baselines.suite.SUITE`'s; the entries are :data:`ENTRIES`:

* ``law``: the paper's law behind the task's filter, run batched as the zero action of the gain mode (the same
  law, as ``pan1-env report``'s reference);
* ``circulation``: the law with the circulation rule (:class:`~pan1_env.baselines.circulation.CirculatingPolicy`),
  one team at a time on the parallel env behind the shield, since it keeps a memory per arm;
* learners, each with a recipe (:attr:`Entry.recipe`, the arguments of
  :func:`~pan1_env.baselines.training.train`). A learner's score on a task is its training runs under
  ``<runs>/<entry>/<task>/seed_<s>`` (``pan1-env suite --train ENTRY TASK`` writes them with the task's training
  seeds), one score per run. With no finished run there, the model the package ships for the task, if it was
  trained with the entry's recipe, stands in as one run.

Each run is scored on the task's held-out teams (:attr:`SuiteTask.held_out`, never a training copy's): the
fraction the task's own rule calls formed (``is_success``), the mean time to formation over those, the cost
(arm-steps inside an obstacle, summed over the teams), the smallest clearance and the fraction of steps in which
the shield changed a command. A cell is the interquartile mean over the runs with its 95 % bootstrap interval
(:func:`~pan1_env.baselines.report.iqm_interval`); an entry of one run (the law, the rule, a shipped model) has no
spread over runs, and its success interval is the Wilson interval over its teams instead (the table says which).
:func:`run_suite` returns the leaderboard as JSON-ready data, its ``raw`` part in marl-eval's layout.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .suite import SUITE, SuiteTask, suite_task

__all__ = ["Entry", "ENTRIES", "entry", "run_suite", "load_leaderboard", "merge_leaderboards", "task_dir",
           "finished_runs", "shipped_model", "train_entry", "EPISODE_METRICS"]

# no return: the learners are trained and scored with their own reward arguments, so returns do not compare
EPISODE_METRICS = ("success", "time_to_formation", "cost", "min_clearance", "intervention_rate")
_PPO = {"gamma": 0.995, "n_steps": 2000, "batch_size": 4000, "n_epochs": 5, "policy_kwargs": {"log_std_init": -1.0}}
_SHARED = {"param_sharing": True, "n_envs": 16, "env_kwargs": {"success_bonus": 1.0, "action_mode": "gain"},
           "algo_kwargs": _PPO, "checkpoint_every": 512_000, "eval_every": 1_024_000}
_BENCHMARL = {"trainer": "benchmarl", "algorithm": "mappo", "shield": True, "copies": 16, "rollout_steps": 2000,
              "minibatch_frames": 1000, "epochs": 5, "lr": 3e-4, "gamma": 0.995, "gae_lambda": 0.95,
              "max_grad_norm": 0.5, "initial_std": 0.37, "eval_every": 8, "eval_episodes": 10, "checkpoint_every": 4,
              "env_kwargs": {"success_bonus": 1.0, "action_mode": "gain"}}
# fewer held-out teams than this run in-process: starting spawned workers (each importing numba's kernels) costs more
_POOL_MIN_TEAMS = 16


@dataclass(frozen=True)
class Entry:
    """One entry of the leaderboard: a fixed policy (``policy``, a name of the benchmark's registry) or a learner
    (``recipe``: :func:`~pan1_env.baselines.training.train`'s arguments, less the task, seed, budget and output),
    on the ids in ``tasks`` (None: every task)."""

    name: str
    description: str
    policy: str | None = None
    recipe: dict[str, Any] | None = None
    tasks: tuple[str, ...] | None = None
    trained_on: str | None = None

    def enters(self, task: SuiteTask) -> bool:
        """Whether the entry is scored on the task."""
        return self.tasks is None or task.env_id in self.tasks

    def training_task(self, task: SuiteTask) -> SuiteTask:
        """The task whose seeds, budget and runs serve this one: the task itself, or for a learner trained on one
        task and judged on others (``trained_on``, e.g. teams of several sizes) that task."""
        return task if self.trained_on is None else suite_task(self.trained_on)

    @property
    def trainer(self) -> str | None:
        """The library that trains the recipe: ``"sb3"`` (:func:`~pan1_env.baselines.training.train`),
        ``"benchmarl"`` (:func:`~pan1_env.baselines.benchmarl_training.train_benchmarl`), or None for a policy."""
        return None if self.recipe is None else self.recipe.get("trainer", "sb3")

    @property
    def model_file(self) -> str:
        """The file a finished run of the recipe writes, which marks it finished."""
        return "model.json" if self.trainer == "benchmarl" else "model.zip"


# the paper's squares have one start each: rollouts of the whole 2,000-step episode on 8 copies, explored with gSDE
# (state-dependent noise held for the episode), the recipe that learned there (docs/LEARNING_STUDIES.md)
_GSDE = {**_PPO, "use_sde": True, "sde_sample_freq": -1, "policy_kwargs": {"log_std_init": -2.0}}
_PAPER_TASKS = ("pan1_env/PaperPA3Square-v0", "pan1_env/PaperMixedPA-v0")

# one network for any team size is judged on these; a recipe of one team size trains on none of them
_SIZE_TASKS = ("pan1_env/RandomFormation-v2", "pan1_env/LargeFormation-v0")
_ONE_SIZE_TASKS = tuple(t.env_id for t in SUITE if t.env_id not in _SIZE_TASKS)

ENTRIES = (
    Entry("law", "the paper's law behind the task's filter", policy="reference"),
    # on the tasks it was made for: it runs one team at a time, ~20x slower per team than the batched law
    Entry("circulation", "the law with the circulation rule round obstacles, behind the filter (on the whole-arm "
                         "tasks, where the law's failures are deadlocks at an obstacle)", policy="circulation",
          tasks=("pan1_env/WholeArmStaticFormation-v1", "pan1_env/WholeArmFormation-v2")),
    Entry("ippo", "IPPO behind the shield: one network shared by the arms, each on its own observation, "
                  "re-weighting the law (gain actions)", recipe={"algo": "ppo", "shield": True, **_SHARED},
          tasks=_ONE_SIZE_TASKS),
    Entry("mappo", "MAPPO behind the shield: IPPO with a critic that also reads the team's state",
          recipe={"algo": "ppo", "shield": True, "centralised_critic": True, **_SHARED}, tasks=_ONE_SIZE_TASKS),
    # the rule's turn round an obstacle as one more action of the learner, on the tasks whose failures are deadlocks
    Entry("mappo-circulation", "MAPPO behind the shield whose arms also choose the circulation term: when and which "
                               "way to turn round an obstacle (circulation actions)",
          recipe={"algo": "ppo", "shield": True, "centralised_critic": True, **_SHARED,
                  "env_kwargs": {"success_bonus": 1.0, "action_mode": "circulation"}},
          tasks=("pan1_env/WholeArmStaticFormation-v1", "pan1_env/WholeArmFormation-v2")),
    Entry("mappo-lagrangian", "MAPPO-Lagrangian without the shield: the cost (arm-steps inside an obstacle) "
                              "held to 1 per episode by a multiplier",
          recipe={"algo": "ppo-lagrangian", "shield": False, "centralised_critic": True, "cost_limit": 1.0, **_SHARED},
          tasks=_ONE_SIZE_TASKS),
    Entry("ippo-unshielded", "IPPO without the shield and without a cost",
          recipe={"algo": "ppo", "shield": False, **_SHARED}, tasks=_ONE_SIZE_TASKS),
    Entry("ippo-gsde", "IPPO behind the shield on the paper's squares, each one start: whole-episode rollouts on 8 "
                       "copies explored with gSDE", recipe={"algo": "ppo", "shield": True, **_SHARED, "n_envs": 8,
                                                             "algo_kwargs": _GSDE}, tasks=_PAPER_TASKS),
    # BenchMARL's own Experiment, on one task: its MAPPO with the SB3 entries' batch, epochs, discount and
    # initial spread (BenchMARL's MLP, no observation normalisation)
    Entry("benchmarl-mappo", "BenchMARL's MAPPO through its own Experiment, behind the shield: one actor shared by "
                             "the arms on their own observations, a critic on the team's, re-weighting the law",
          recipe=_BENCHMARL, tasks=("pan1_env/RandomFormation-v1",)),
    Entry("ippo-sizes", "IPPO behind the shield on ring teams of 3 to 8 arms in the same rollouts: one network "
                        "for a team of any size, judged at 4 and 16 arms",
          recipe={"algo": "ppo", "shield": True, **_SHARED, "n_envs": 4, "team_sizes": [3, 4, 5, 6, 7, 8]},
          tasks=_SIZE_TASKS, trained_on="pan1_env/RandomFormation-v2"),
)


def entry(name: str) -> Entry:
    """The entry of that name; ``ValueError`` listing them if none."""
    for candidate in ENTRIES:
        if candidate.name == name:
            return candidate
    raise ValueError(f"no leaderboard entry {name!r}; the entries: {', '.join(e.name for e in ENTRIES)}")


def task_dir(runs: str | Path, entry_: Entry, task: SuiteTask) -> Path:
    """Where a learner's runs on a task live: ``<runs>/<entry>/<id of the task it trains on, without the prefix>``."""
    return Path(runs) / entry_.name / entry_.training_task(task).env_id.split("/")[-1]


def finished_runs(runs: str | Path, entry_: Entry, task: SuiteTask) -> list[Path]:
    """The finished runs (:attr:`Entry.model_file` written) of the training seeds, in seed order."""
    seeds = entry_.training_task(task).train_seeds
    return [d for s in seeds if (d := task_dir(runs, entry_, task) / f"seed_{s}" / entry_.model_file).is_file()]


def _recipe_of(run: dict[str, Any], task: SuiteTask) -> tuple:
    """What makes a run (its ``run.json``, or an entry's recipe) the entry's on a task: the algorithm and its
    arguments, the shield, the shared network and its critic, the copies, the normalisation, the budget and the env
    arguments the recipe sets (not those the task's id and arguments set)."""
    from pan1_env.registration import env_arguments

    if run.get("trainer") == "benchmarl":  # its settings are the recipe's own keys, beside what the run adds
        recipe = {k: v for k, v in run.items() if k not in ("seed", "task", "task_env_kwargs", "timesteps")}
        return "benchmarl", json.dumps(recipe, sort_keys=True), run.get("timesteps", task.train_steps)
    task_keys = (*env_arguments(task.env_id, task.env_kwargs)[1], "random_options")
    algo = run.get("algo", "ppo")
    env = {k: v for k, v in run.get("env_kwargs", {}).items() if k not in task_keys}
    lagrangian = (run.get("cost_limit", 1.0), run.get("lagrangian_lr", 0.01)) if algo == "ppo-lagrangian" else None
    return (algo, bool(run.get("shield", True)), bool(run.get("param_sharing")), bool(run.get("centralised_critic")),
            run.get("n_envs"), json.dumps(run.get("algo_kwargs"), sort_keys=True), bool(run.get("normalize", True)),
            lagrangian, run.get("critic_warmup", 0) or 0, tuple(run.get("team_sizes") or ()),
            run.get("timesteps", task.train_steps),
            json.dumps(env, sort_keys=True))


def shipped_model(entry_: Entry, task: SuiteTask) -> str | None:
    """The shipped model trained for the task with the entry's whole recipe, or None (a model trained another way,
    say with gSDE, is not the entry's)."""
    from pan1_env.registration import env_arguments

    from .shipped import available, serves

    if entry_.recipe is None:
        return None
    scenario, kwargs = env_arguments(task.env_id, task.env_kwargs)
    trained = entry_.training_task(task)
    for name, meta in available().items():
        run = meta.get("provenance", {}).get("run", {})
        if _recipe_of(run, trained) == _recipe_of(entry_.recipe, trained) and serves(meta, scenario, kwargs):
            return name
    return None


def _trained_for(model: Path, task: SuiteTask) -> bool:
    """Whether the model was trained on the task: its scenario and options, in the model's own action mode (the
    suite scores a model in the mode it was trained in; the task's id sets none)."""
    from pan1_env.registration import env_arguments

    from .shipped import serves

    meta = json.loads(model.with_suffix(".json").read_text())
    scenario, kwargs = env_arguments(task.env_id, task.env_kwargs)
    return serves(meta, scenario, kwargs | {"action_mode": meta.get("env_kwargs", {}).get("action_mode", "velocity")})


def _records(result: dict[str, np.ndarray]) -> dict[str, list]:
    """An evaluation's per-team arrays as JSON lists; the time of a team the task's rule does not call formed is None
    (on a moving formation the error can end below 1 cm before it has been held long enough)."""
    formed = np.asarray(result["success"], bool)
    out = {"success": formed.astype(float).tolist()}
    for key in EPISODE_METRICS[1:]:
        if key in result:
            values = np.where(formed, result[key], np.nan) if key == "time_to_formation" else result[key]
            out[key] = [None if not np.isfinite(v) else float(v) for v in np.asarray(values, float)]
    return out


def _law(task: SuiteTask, seeds: list[int], extra: dict[str, Any]) -> dict[str, list]:
    from pan1_env.registration import env_arguments

    from .evaluation import evaluate, law_policy

    scenario, kwargs = env_arguments(task.env_id, task.env_kwargs | extra | {"action_mode": "gain"})
    return _records(evaluate(law_policy(scenario, kwargs), scenario, seeds, env_kwargs=kwargs))


def _team_episodes(env_id: str, env_kwargs: dict[str, Any], policy_name: str, seeds: list[int]) -> list[dict]:
    """Episodes of a registry policy behind the shield, one team at a time (a worker process's share)."""
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments
    from pan1_env.wrappers import SafetyShield

    from .benchmark import run_episode
    from .policies import make_policy

    scenario, kwargs = env_arguments(env_id, env_kwargs)
    env = SafetyShield(parallel_env(scenario, **kwargs))
    policy = make_policy(policy_name, env, 0)
    episodes = [run_episode(env, policy, seed, True) for seed in seeds]
    env.close()
    return episodes


def _per_team(task: SuiteTask, policy_name: str, seeds: list[int], extra: dict[str, Any], workers: int,
              tick: Callable[[int], Any]) -> dict[str, list]:
    """A policy that keeps a memory per team, run on the parallel env: ``workers`` processes share the teams in
    chunks (the per-team env is ~20x slower per team than the batched engine, so this is the suite's long part)."""
    import math
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    size = max(1, math.ceil(len(seeds) / (4 * workers)))
    chunks = [seeds[k:k + size] for k in range(0, len(seeds), size)]
    done: dict[int, list[dict]] = {}
    if workers == 1 or len(seeds) < _POOL_MIN_TEAMS:
        for k, chunk in enumerate(chunks):
            done[k] = _team_episodes(task.env_id, task.env_kwargs | extra, policy_name, chunk)
            tick(len(chunk))
    else:  # spawned, not forked: numba's threading layer does not survive a fork
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(_team_episodes, task.env_id, task.env_kwargs | extra, policy_name, chunk): k
                       for k, chunk in enumerate(chunks)}
            try:
                for future in futures:
                    done[futures[future]] = future.result()
                    tick(len(chunks[futures[future]]))
            except BaseException:  # a chunk failed (or Ctrl-C): do not wait for the others to say so
                pool.shutdown(wait=False, cancel_futures=True)
                raise
    episodes = [e for k in range(len(chunks)) for e in done[k]]
    result = {"success": np.array([e["success"] for e in episodes]),
              "time_to_formation": np.array([np.nan if e["time_to_formation"] is None else e["time_to_formation"]
                                             for e in episodes]),
              "intervention_rate": np.array([e["intervened_steps"] / max(e["steps"], 1) for e in episodes])}
    result |= {key: np.array([e[key] for e in episodes], float) for key in ("cost", "min_clearance")}
    return _records(result)


def _model(path: Path, task: SuiteTask, seeds: list[int], extra: dict[str, Any]) -> dict[str, list]:
    """A model on the task's teams: the task's scenario and arguments (for a model trained on teams of several
    sizes, the task's size) over the model's own action and reward arguments."""
    from pan1_env.registration import env_arguments

    from .evaluation import evaluate, model_policy

    meta = json.loads(path.with_suffix(".json").read_text())
    scenario, task_kwargs = env_arguments(task.env_id, task.env_kwargs)
    if meta.get("trainer") == "benchmarl":
        from .benchmarl_training import checkpoint_policy

        policy, kwargs = checkpoint_policy(path, meta["env_kwargs"] | task_kwargs | extra)
    else:
        policy, kwargs = model_policy(path, meta.get("env_kwargs", {}) | task_kwargs | extra)
    return _records(evaluate(policy, scenario, seeds, shield=meta.get("shield", True), env_kwargs=kwargs))


def _learned_runs(runs: str | Path, entry_: Entry, task: SuiteTask) -> list[tuple[int, Path, str]]:
    """(seed, model, where it comes from) for each run that scores a learner on a task."""
    from .shipped import PRETRAINED_DIR, available

    found = [(int(m.parent.name.removeprefix("seed_")), m) for m in finished_runs(runs, entry_, task)]
    trained = entry_.training_task(task)
    for seed, model in found:
        run = json.loads((model.parent / "run.json").read_text())
        if _recipe_of(run, trained) != _recipe_of(entry_.recipe, trained) or run.get("seed") != seed:
            raise ValueError(f"{model.parent}: not a run of {entry_.name}'s recipe with seed {seed} "
                             f"(its run.json: {json.dumps(run, sort_keys=True)}); pan1-env suite --train writes them")
        if not _trained_for(model, task):
            raise ValueError(f"{model.parent}: its model was not trained for {task.env_id}")
    if found:
        return [(seed, model, str(model.parent)) for seed, model in found]
    name = shipped_model(entry_, task)
    if name is None:
        return []
    seed = available()[name]["provenance"]["run"].get("seed", 0)
    return [(seed, PRETRAINED_DIR / f"{name}.zip", f"shipped:{name}")]


def run_suite(tasks: Sequence[SuiteTask] = SUITE, entries: Sequence[Entry] = ENTRIES, *,
              runs: str | Path = "runs/suite", teams: int | None = None, max_steps: int | None = None,
              workers: int | None = None, progress: Callable[[str], None] | None = None,
              bar: bool | None = None) -> dict[str, Any]:
    """Score every entry on every task's held-out teams (the first ``teams`` of them if given, and episodes cut at
    ``max_steps`` if given: ``--quick``, a check of the pipeline whose numbers are not the leaderboard's). The
    per-team policies run in ``workers`` processes (default: one per core), started with ``spawn``: a script that
    calls this must guard its entry point with ``if __name__ == "__main__":``.

    Returns ``{"tasks": …, "entries": …, "runs": {task: {entry: [{"seed", "source"}]}}, "raw": …}``: ``raw`` in
    marl-eval's layout, ``{"pan1_env": {task id: {entry: {"seed_<s>": {"absolute_metrics": {metric: [one value per
    team]}}}}}}``. A learner with no run and no shipped model for a task is listed under ``missing``."""
    import sys

    from tqdm import tqdm

    from .report import marl_eval_data

    say = progress or (lambda text: None)
    extra = {} if max_steps is None else {"max_steps": max_steps}
    workers = workers or os.cpu_count() or 1
    plan = []  # everything is resolved before the first evaluation, so that a missing model fails at once
    for task in tasks:
        seeds = list(task.held_out)[:teams]  # teams None: all of them
        for e in (e for e in entries if e.enters(task)):
            if e.recipe is None:
                plan.append((task, e, seeds, [(0, None, "policy")]))
            elif found := _learned_runs(runs, e, task):
                plan.append((task, e, seeds, found))
    total = sum(len(seeds) * len(found) for _, _, seeds, found in plan)
    covered = {(t.env_id, e.name) for t, e, _, _ in plan}
    data: dict[str, Any] = {
        "tasks": [{"name": t.name, "env_id": t.env_id, "env_kwargs": t.env_kwargs, "train_steps": t.train_steps,
                   "train_seeds": list(t.train_seeds), "held_out": [t.held_out.start, len(t.held_out)],
                   "teams": len(t.held_out[:teams]), "target": t.target, "goal": asdict(t.goal),
                   "law_success_recorded": t.law_success} for t in tasks],
        "entries": [{"name": e.name, "description": e.description, "policy": e.policy, "recipe": e.recipe,
                     "tasks": e.tasks, "trained_on": e.trained_on} for e in entries],
        "runs": {},
        "missing": [[t.env_id, e.name] for t in tasks for e in entries
                    if e.enters(t) and (t.env_id, e.name) not in covered],
    }
    rows = []
    hide = None if bar is None else not bar
    with tqdm(total=total, unit="team", desc="suite", file=sys.stderr, disable=hide) as ticks:
        for task, e, seeds, found in plan:
            for seed, model, source in found:
                say(f"{e.name} on {task.env_id}: {len(seeds)} held-out teams ({source}) …")
                if e.policy == "reference":
                    record = _law(task, seeds, extra)
                elif e.policy is not None:
                    record = _per_team(task, e.policy, seeds, extra, workers, ticks.update)
                else:
                    record = _model(model, task, seeds, extra)
                if e.policy is None or e.policy == "reference":  # batched: the bar moves by the whole run
                    ticks.update(len(seeds))
                rows.append((task.env_id, e.name, seed, {"absolute_metrics": record}))
                data["runs"].setdefault(task.env_id, {}).setdefault(e.name, []).append(
                    {"seed": seed, "source": source})
    data["raw"] = marl_eval_data(rows)
    return data


def train_entry(entry_: Entry, task: SuiteTask, *, runs: str | Path = "runs/suite", seeds: Sequence[int] | None = None,
                progress: bool = True, say: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Train a learner's recipe on a task, one run per seed (default: the task's training seeds), each into
    ``<runs>/<entry>/<task>/seed_<s>``, continuing from its newest checkpoint if it has one; a finished run is
    left as it is. An entry trained on another task than it is judged on trains there (:meth:`Entry.training_task`).
    Returns the summaries of the runs trained."""
    from .training import latest_checkpoint, train

    if entry_.recipe is None:
        raise ValueError(f"entry {entry_.name!r} is not trained: it is the policy {entry_.policy!r}")
    if not entry_.enters(task):
        raise ValueError(f"entry {entry_.name!r} is not judged on {task.env_id}: its tasks are "
                         f"{', '.join(entry_.tasks)}")
    task = entry_.training_task(task)
    recipe = dict(entry_.recipe)
    recipe["env_kwargs"] = recipe.get("env_kwargs", {}) | task.env_kwargs  # the task's arguments are every entry's
    seeds = task.train_seeds if seeds is None else seeds
    if not set(seeds) <= set(task.train_seeds):
        raise ValueError(f"seeds {sorted(set(seeds) - set(task.train_seeds))} are not {task.env_id}'s training seeds "
                         f"{list(task.train_seeds)}: every entry trains on the same seeds")
    summaries = []
    for seed in seeds:
        out = task_dir(runs, entry_, task) / f"seed_{seed}"
        if (out / entry_.model_file).is_file():
            say(f"{out}: finished, left as it is")
            continue
        if entry_.trainer == "benchmarl":
            from .benchmarl_training import train_benchmarl

            say(f"{entry_.name} on {task.env_id}, seed {seed}: BenchMARL's Experiment into {out} …")
            summaries.append(train_benchmarl(task.env_id, seed, task.train_steps, out, recipe=entry_.recipe,
                                             env_kwargs=task.env_kwargs))
            continue
        resume = latest_checkpoint(out) is not None
        say(f"{entry_.name} on {task.env_id}, seed {seed}: {'resuming' if resume else 'training'} into {out} …")
        summaries.append(train(scenario=task.env_id, seed=seed, timesteps=task.train_steps, out=out, resume=resume,
                               progress=progress, **recipe))
    return summaries


def load_leaderboard(path: str | Path) -> dict[str, Any]:
    """A leaderboard written by ``pan1-env suite`` (its ``leaderboard.json``); ValueError naming the file if it is
    missing, not JSON or not a leaderboard."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: cannot read a leaderboard ({err})") from None
    keys = ("tasks", "entries", "runs", "raw", "missing")
    if not isinstance(data, dict) or any(key not in data for key in keys) or "pan1_env" not in data["raw"]:
        raise ValueError(f"{path}: not a pan1-env suite leaderboard.json (it needs {', '.join(keys)}, raw in "
                         "marl-eval's layout)")
    return data


def merge_leaderboards(boards: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One leaderboard from several (:func:`load_leaderboard`'s), for an entry scored on its own and added to a
    board: every (task, entry) cell of a later board replaces the earlier boards' cell, with its runs and its
    per-team numbers; tasks and entries are the union of the boards' (a later declaration replaces an earlier one
    of the same name), and what is missing is worked out again. ValueError if the boards judge a task on different
    held-out teams, since their cells would not compare."""
    tasks: dict[str, dict] = {}
    entries: dict[str, dict] = {}
    runs: dict[str, dict] = {}
    raw: dict[str, dict] = {}
    for data in boards:
        for task in data["tasks"]:
            seen = tasks.get(task["env_id"])
            if seen is not None and (seen["held_out"], seen["teams"]) != (task["held_out"], task["teams"]):
                raise ValueError(f"the boards judge {task['env_id']} on different held-out teams "
                                 f"({seen['held_out']}, {seen['teams']} teams against {task['held_out']}, "
                                 f"{task['teams']}): their cells do not compare")
            tasks[task["env_id"]] = task
        entries |= {e["name"]: e for e in data["entries"]}
        for env_id, cells in data["runs"].items():
            runs.setdefault(env_id, {}).update(cells)
            raw.setdefault(env_id, {}).update({name: data["raw"]["pan1_env"][env_id][name] for name in cells})

    def enters(e: dict, env_id: str) -> bool:
        return e["tasks"] is None or env_id in e["tasks"]

    return {"tasks": list(tasks.values()), "entries": list(entries.values()),
            "runs": {t: {e: runs[t][e] for e in entries if e in runs.get(t, {})} for t in tasks if t in runs},
            "missing": [[t, e["name"]] for t in tasks for e in entries.values()
                        if enters(e, t) and e["name"] not in runs.get(t, {})],
            "raw": {"pan1_env": {t: {e: raw[t][e] for e in entries if e in raw.get(t, {})} for t in tasks
                                 if t in raw}},
            "quick": any(data.get("quick", False) for data in boards)}


def resolve(tasks: str | None, entries: str | None) -> tuple[list[SuiteTask], list[Entry]]:
    """Comma-separated task names or ids and entry names (None: all) as the suite's objects; ValueError if unknown."""
    chosen_tasks = list(SUITE) if not tasks else [suite_task(t.strip()) for t in tasks.split(",") if t.strip()]
    chosen_entries = list(ENTRIES) if not entries else [entry(e.strip()) for e in entries.split(",") if e.strip()]
    return chosen_tasks, chosen_entries
