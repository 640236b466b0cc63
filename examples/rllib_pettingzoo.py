"""Train the arms with Ray RLlib's PPO through its PettingZoo wrapper (for runs that outgrow one machine).

    pip install -e ".[ray]"      (install PyTorch's CPU-only wheel first: see the README)
    python examples/rllib_pettingzoo.py --iterations 5 --num-env-runners 2
    python examples/rllib_pettingzoo.py --scenario paper_pa_mixed_square       # a mixed team, one policy
    python examples/rllib_pettingzoo.py --scenario pan1_env/WholeArmStaticFormation-v0
    python examples/rllib_pettingzoo.py --iterations 40 --out runs/rllib          # then --resume to continue

Shows how :func:`pan1_env.environment.parallel_env` (optionally behind :class:`~pan1_env.wrappers.SafetyShield`)
plugs into RLlib's new API stack: the env is registered with :func:`ray.tune.registry.register_env` and wrapped
in :class:`~ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv`; every arm maps to ONE shared policy
(parameter sharing), so all the arms' experience trains the same network. ``--scenario`` takes any scenario
(a built-in name, a ``.toml`` path, ``random``) or registered id (``pan1-env scenarios`` lists them). Arms of a
team may differ in links and actuated joints: :class:`~pan1_env.wrappers.PadToLargestArm` zero-pads every
observation to the largest arm's and gives every arm the largest action, of which an arm uses its own first
entries (the layout of SuperSuit's ``pad_observations_v0`` and ``pad_action_space_v0``, and of
``pan1-env train --param-sharing``; SuperSuit is not in the ``ray`` extra), so one network fits them all.
``--num-env-runners 0`` samples in the driver process; more runners sample in parallel Ray actors, on this
machine or, with ``--address auto`` (or ``ray://HOST:10001``), on a running Ray cluster: every node needs
``pan1_env`` installed and its kernels compiled (docs/TRAINING.md, *More than one machine*). The printed
episode return is the team's: the sum over the arms.

The infos are flat numbers and arrays (the shield's report included), which RLlib passes through as they are. A
small callback sums ``infos[agent]["cost"]`` over each episode and the arms and reports its mean as
``result["env_runners"]["episode_cost_mean"]`` (0 behind the shield). With ``--out`` every iteration appends a
row to ``progress.csv`` (iteration, env steps, mean episode return and cost) and overwrites a checkpoint, from
which ``--resume`` continues an interrupted run to ``--iterations``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import ray
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

from pan1_env.environment import parallel_env
from pan1_env.wrappers import PadToLargestArm, SafetyShield

ENV_NAME = "pan1_formation"
SHARED_POLICY = "shared"
COST_KEY = "episode_cost_mean"
DEFAULT_SCENARIO = "paper_pa3_square"


def make_env(config: dict[str, Any]) -> ParallelPettingZooEnv:
    """RLlib env creator: the team of ``config["scenario"]`` (any scenario or registered id; default
    Section 5.1's square of three-link PA arms, ``paper_pa3_square``), shielded unless
    ``config["shield"]`` is false, padded so that every arm has the same spaces."""
    env = parallel_env(config.get("scenario", DEFAULT_SCENARIO), max_steps=config.get("max_steps", 200))
    if config.get("shield", True):
        env = SafetyShield(env)
    return ParallelPettingZooEnv(PadToLargestArm(env))


def _add_step_cost(*, episode: Any, **kwargs: Any) -> None:
    """Accumulate the step's cost (summed over the arms) in the episode."""
    step_cost = sum(info.get("cost", 0.0) for info in episode.get_infos(-1).values())
    episode.custom_data["cost"] = episode.custom_data.get("cost", 0.0) + float(step_cost)


def _log_episode_cost(*, episode: Any, metrics_logger: Any, **kwargs: Any) -> None:
    """Report the finished episode's total cost (a windowed mean over episodes, like the return)."""
    metrics_logger.log_value(COST_KEY, episode.custom_data.get("cost", 0.0), reduce="mean", window=100)


def build_config(args: argparse.Namespace) -> PPOConfig:
    """PPO on the new API stack, all arms mapped to one shared policy."""
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config={"scenario": args.scenario, "max_steps": args.max_steps,
                                           "shield": args.shield})
        # a loaded machine or a slow node can take minutes for a batch: wait rather than train on nothing
        .env_runners(num_env_runners=args.num_env_runners, sample_timeout_s=args.sample_timeout)
        .training(train_batch_size_per_learner=args.train_batch_size, minibatch_size=args.minibatch_size,
                  num_epochs=args.num_epochs)
        .multi_agent(policies={SHARED_POLICY}, policy_mapping_fn=lambda agent_id, episode, **kwargs: SHARED_POLICY)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={SHARED_POLICY: RLModuleSpec()}))
        .callbacks(on_episode_step=_add_step_cost, on_episode_end=_log_episode_cost)
        .debugging(seed=args.seed)
    )


def _save(algo: Any, out: Path) -> None:
    """Replace ``out/checkpoint`` by the algorithm's state, the old one kept until the new one is whole."""
    import shutil

    out.mkdir(parents=True, exist_ok=True)
    fresh, old = out / "checkpoint.new", out / "checkpoint.old"
    shutil.rmtree(fresh, ignore_errors=True)
    algo.save_to_path(str(fresh.resolve()))
    if (out / "checkpoint").exists():
        shutil.rmtree(old, ignore_errors=True)
        (out / "checkpoint").rename(old)
    fresh.rename(out / "checkpoint")
    shutil.rmtree(old, ignore_errors=True)


def _log(path: Path, row: dict[str, Any]) -> None:
    """Append one iteration's row to ``progress.csv`` (a header first in a new file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iterations", type=int, default=5, help="training iterations (default 5)")
    p.add_argument("--scenario", default=DEFAULT_SCENARIO,
                   help="a built-in scenario, a .toml path, 'random' or a registered id such as "
                        f"pan1_env/WholeArmStaticFormation-v0 (default {DEFAULT_SCENARIO})")
    p.add_argument("--max-steps", type=int, default=200, help="episode length in control steps (default 200)")
    p.add_argument("--shield", action=argparse.BooleanOptionalAction, default=True,
                   help="train behind the RCBF-QP safety shield (default: on)")
    p.add_argument("--num-env-runners", type=int, default=0, help="parallel sampling actors; 0 = in the driver")
    p.add_argument("--address", default=None, help="Ray cluster to join (e.g. 'auto'); default: a local Ray")
    p.add_argument("--train-batch-size", type=int, default=4000, help="env steps per training batch")
    p.add_argument("--minibatch-size", type=int, default=128, help="SGD minibatch size")
    p.add_argument("--num-epochs", type=int, default=10, help="SGD epochs per batch")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sample-timeout", type=float, default=600.0,
                   help="seconds to wait for the env runners' samples in an iteration (default 600)")
    p.add_argument("--out", type=Path, default=None,
                   help="write progress.csv (one row per iteration) and a checkpoint after every iteration here")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --out, to --iterations")
    args = p.parse_args(argv)
    if args.resume and (args.out is None or not (args.out / "checkpoint").is_dir()):
        p.error("--resume needs --out with a checkpoint in it (written by an earlier run with --out)")
    if not args.resume and args.out is not None and (args.out / "progress.csv").exists():
        p.error(f"{args.out} holds a run already: add --resume to continue it, or choose another --out")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Train for ``--iterations`` iterations, print each one's return and steps, return RLlib's result dicts."""
    args = parse_args(argv)
    started = not ray.is_initialized()
    if started and args.address:
        ray.init(address=args.address)
    elif started:
        ray.init(num_cpus=max(2, args.num_env_runners + 1), include_dashboard=False)
    register_env(ENV_NAME, make_env)
    results, algo = [], None
    try:
        algo = build_config(args).build_algo()
        done = 0
        if args.resume:  # the module, optimiser and counters of the last finished iteration
            algo.restore_from_path(str((args.out / "checkpoint").resolve()))
            done = int(algo.iteration)
        for i in range(done, args.iterations):
            result = algo.train()
            runners = result.get("env_runners", {})  # empty when no runner returned samples in time
            row = {"iteration": i + 1, "env_steps": int(runners.get("num_env_steps_sampled_lifetime", 0)),
                   "episode_return_mean": runners.get("episode_return_mean", float("nan")),
                   "episode_cost_mean": runners.get(COST_KEY, float("nan"))}
            print(f"iter {i + 1}: episode return mean {row['episode_return_mean']:.2f}, "
                  f"episode cost mean {row['episode_cost_mean']:g}, "
                  f"env steps sampled {runners.get('num_env_steps_sampled', 0)} (total {row['env_steps']})", flush=True)
            if args.out is not None:  # the checkpoint first: a run killed in between redoes no iteration
                _save(algo, args.out)
                _log(args.out / "progress.csv", row)
            results.append(result)
    finally:
        if algo is not None:
            algo.stop()
        if started:
            ray.shutdown()
    return results


if __name__ == "__main__":
    main()
