"""Train the arms with BenchMARL's MAPPO or IPPO (one shared policy on each arm's own observation, behind the
shield) on a pan1-env task.

    pip install torch==2.13.0 torchvision==0.28.0 --index-url https://download.pytorch.org/whl/cpu
    pip install -e ".[benchmarl]"
    python examples/benchmarl_mappo.py --task pan1_env/RandomFormation-v1 --frames 200000 --seed 0 --out runs/mappo_v1
    python examples/benchmarl_mappo.py --task paper_pa3_square --algorithm ippo --frames 6000

``--task`` is any scenario or registered id (:data:`pan1_env.benchmarl_task.TASKS` lists the standard ones) or a
task YAML file (``pan1_env/benchmarl_tasks/*.yaml``). BenchMARL writes its CSV logs, including the mean cost per
arm-step and the shield's intervention rate (``Pan1Task.log_info``), under ``--out``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarl.algorithms import IppoConfig, MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig

from pan1_env.benchmarl_task import Pan1Task

ALGORITHMS = {"mappo": MappoConfig, "ippo": IppoConfig}


def build(args: argparse.Namespace) -> Experiment:
    """The experiment: BenchMARL's default configs, with the frame budget, batch and copies given."""
    task = Pan1Task.from_yaml(args.task) if args.task.endswith((".yaml", ".yml")) else Pan1Task(args.task)
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = args.frames
    config.on_policy_collected_frames_per_batch = args.batch
    config.on_policy_n_envs_per_worker = args.copies
    config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, args.batch)
    config.on_policy_n_minibatch_iters = args.epochs
    config.evaluation = False
    config.render = False
    config.loggers = ["csv"]
    config.create_json = True
    config.checkpoint_interval = 0
    args.out.mkdir(parents=True, exist_ok=True)
    config.save_folder = str(args.out)
    return Experiment(task=task, algorithm_config=ALGORITHMS[args.algorithm].get_from_yaml(),
                      model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(),
                      seed=args.seed, config=config)


def main(argv: list[str] | None = None) -> Experiment:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pan1_env/RandomFormation-v1",
                        help="a scenario, a registered id or a task YAML file (default: v1's random teams)")
    parser.add_argument("--algorithm", choices=sorted(ALGORITHMS), default="mappo")
    parser.add_argument("--frames", type=int, default=200_000, help="agent-team frames in all (BenchMARL's count)")
    parser.add_argument("--batch", type=int, default=6000, help="frames collected per update")
    parser.add_argument("--copies", type=int, default=60, help="env copies stepped together")
    parser.add_argument("--epochs", type=int, default=4, help="passes over each batch")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/benchmarl"))
    experiment = build(parser.parse_args(argv))
    experiment.run()
    return experiment


if __name__ == "__main__":
    main()
