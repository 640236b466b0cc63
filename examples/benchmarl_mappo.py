"""Train the arms with BenchMARL's MAPPO or IPPO (one shared policy on each arm's own observation, behind the
shield) on a pan1-env task.

    pip install torch==2.13.0 torchvision==0.28.0 --index-url https://download.pytorch.org/whl/cpu
    pip install -e ".[benchmarl]"
    python examples/benchmarl_mappo.py --task pan1_env/RandomFormation-v1 --frames 200000 --seed 0 --out runs/mappo_v1
    python examples/benchmarl_mappo.py --task paper_pa3_square --algorithm ippo --frames 12000

``--task`` is any scenario or registered id (:data:`pan1_env.benchmarl_task.TASKS` lists the standard ones) or a
task YAML file (``pan1_env/benchmarl_tasks/*.yaml``). A batch is as long as an episode of every copy: ``--copies``
copies of ``--max-steps`` steps each (6,000 frames by default), so every iteration ends episodes (a copy whose
episode ends early starts another in the batch) and reports a finite return.
After every ``--eval-every`` iterations (and the first), BenchMARL evaluates the deterministic policy on
``--eval-episodes`` episodes. Under ``--out`` it writes its CSV logs, including per batch the mean cost per
arm-step, the shield's intervention rate, the success rate and the least clearance (``Pan1Task.log_info``), and its
JSON (marl-eval's layout), whose evaluation steps hold each episode's return, success, cost, least clearance and
intervention rate (:class:`~pan1_env.benchmarl_task.Pan1EvaluationMetrics`, also in the CSV logs as ``eval/…``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarl.algorithms import IppoConfig, MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig

from pan1_env.benchmarl_task import Pan1EvaluationMetrics, Pan1Task

ALGORITHMS = {"mappo": MappoConfig, "ippo": IppoConfig}


def build(args: argparse.Namespace) -> Experiment:
    """The experiment: BenchMARL's default configs, with the frame budget, episode length, copies and evaluation
    given; a batch is one episode of every copy."""
    task = Pan1Task.from_yaml(args.task) if args.task.endswith((".yaml", ".yml")) else Pan1Task(args.task)
    task.config["max_steps"] = args.max_steps
    batch = args.copies * args.max_steps
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = args.frames
    config.on_policy_collected_frames_per_batch = batch
    config.on_policy_n_envs_per_worker = args.copies
    config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, batch)
    config.on_policy_n_minibatch_iters = args.epochs
    config.evaluation = True
    config.evaluation_interval = batch * args.eval_every
    config.evaluation_episodes = args.eval_episodes
    config.render = False
    config.loggers = ["csv"]
    config.create_json = True
    config.checkpoint_interval = 0
    args.out.mkdir(parents=True, exist_ok=True)
    config.save_folder = str(args.out)
    return Experiment(task=task, algorithm_config=ALGORITHMS[args.algorithm].get_from_yaml(),
                      model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(),
                      seed=args.seed, config=config, callbacks=[Pan1EvaluationMetrics()])


def main(argv: list[str] | None = None) -> Experiment:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pan1_env/RandomFormation-v1",
                        help="a scenario, a registered id or a task YAML file (default: v1's random teams)")
    parser.add_argument("--algorithm", choices=sorted(ALGORITHMS), default="mappo")
    parser.add_argument("--frames", type=int, default=200_000, help="agent-team frames in all (BenchMARL's count)")
    parser.add_argument("--max-steps", type=int, default=100, help="steps per episode (of 0.05 s)")
    parser.add_argument("--copies", type=int, default=60,
                        help="env copies stepped together; a batch is one episode of each")
    parser.add_argument("--epochs", type=int, default=4, help="passes over each batch")
    parser.add_argument("--eval-every", type=int, default=1, help="iterations between evaluations")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/benchmarl"))
    experiment = build(parser.parse_args(argv))
    experiment.run()
    return experiment


if __name__ == "__main__":
    main()
