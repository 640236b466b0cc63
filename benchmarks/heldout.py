"""Residual or gain models and the reference they correct, on the same random teams.

    python benchmarks/heldout.py MODEL.zip [MODEL.zip …] [--first 2000000] [--teams 200]

Every model must have been trained by ``pan1-env train --scenario random`` (or a random-team id) with
``--action-mode residual`` or ``gain`` on the same task: the reference is the zero action (the
paper's law) in the env of the first model's ``model.json``. Each policy runs one deterministic
episode per team, reset seeds ``first … first + teams − 1``, batched
(``pan1_env.baselines.evaluation``). Printed per policy: success at 1 / 2 / 5 cm, median final
error, cost (arm-steps inside an obstacle), mean time to formation over the teams it forms and over
the teams both it and the reference form, and how many teams it forms that the reference does not,
and the reverse. The defaults are the held-out teams of docs/TRAINING.md; ``--first 1000000
--teams 64`` gives the evaluation teams that models are chosen on.
"""

from __future__ import annotations

import argparse

import numpy as np

from pan1_env.baselines.evaluation import TOLERANCES, evaluate, law_policy, model_policy, summarise


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+",
                        help="model.zip files written by pan1-env train (residual or gain actions)")
    parser.add_argument("--first", type=int, default=2_000_000, help="first reset seed (default 2000000)")
    parser.add_argument("--teams", type=int, default=200, help="number of teams (default 200)")
    args = parser.parse_args(argv)
    seeds = range(args.first, args.first + args.teams)
    policies = {path: model_policy(path) for path in args.models}
    env_kwargs = next(iter(policies.values()))[1]
    try:
        reference = law_policy("random", env_kwargs)
    except ValueError as err:
        parser.error(f"{args.models[0]} has no reference to compare with: {err}")
    results = {}
    for name, (policy, kwargs) in {"reference": (reference, env_kwargs), **policies}.items():
        if kwargs != env_kwargs:
            parser.error(f"{name} was trained on other env arguments than {args.models[0]}: {kwargs}")
        print(f"{name}: {args.teams} teams …", flush=True)  # about a minute per policy on 2 cores
        results[name] = evaluate(policy, "random", seeds, env_kwargs=kwargs)
    formed_by_reference = results["reference"]["final_error"] < TOLERANCES[0]
    print(f"\n| policy | success 1 / 2 / 5 cm | median final error | cost | time to formation | "
          f"on teams both form | forms, reference not | reference forms, not it |\n{'|---' * 8}|")
    for name, result in results.items():
        s = summarise(result)
        formed = result["final_error"] < TOLERANCES[0]
        both = formed & formed_by_reference
        rates = " / ".join(f"{100 * s[f'success_{round(100 * tol)}cm']:.1f}" for tol in TOLERANCES)
        print(f"| {name} | {rates} % "
              f"| {s['median_final_error_m']:.1e} m | {s['cost']:g} | {s['mean_time_to_formation_s']:.1f} s "
              f"| {np.mean(result['time_to_formation'][both]):.1f} s ({both.sum()} teams) "
              f"| {(formed & ~formed_by_reference).sum()} | {(~formed & formed_by_reference).sum()} |")


if __name__ == "__main__":
    main()
