"""The ``pan1-env`` command line (also ``python -m pan1_env``).

Commands:

* ``reproduce SCENARIO --controller nominal|safe --out DIR [--horizon S]``: one closed-loop run
  with the paper's controller; writes ``metrics.json``, ``trajectory.npz`` and the figures.
* ``paper [--out DIR] [--horizon S]``: the paper's whole Section 5 (both scenarios, both
  controllers), the Figure-8 overlays, and a Markdown table of the metrics (``summary.md``).
* ``scenarios``: list the built-in scenarios, ``random`` and the Gymnasium ids.
* ``warmup [--kinds 4p 2f …] [--scenario NAME …] [--no-threaded]``: compile the kernels ahead of time (the
  multi-threaded ones too, unless ``--no-threaded``).
* ``animate SCENARIO --policy reference|zero|random|adversarial|pretrained|marl|sb3:PATH [--no-shield] --out FILE.gif``:
  a GIF of one env episode.
* ``train --algo ppo|sac|ppo-lagrangian --scenario S --shield/--no-shield --timesteps T --seed K --out DIR``:
  Stable-Baselines3 training (the ``rl`` extra).
* ``benchmark --scenarios … --policies reference,zero,random,sb3:PATH --episodes K --seed S [--env-kwargs JSON]``:
  the policy comparison (Markdown, JSON and a plot).
* ``plot RUN_DIR… [--out PATH] [--x timesteps|episodes] [--window N] [--label NAME …]``: learning
  curves of training runs, mean over seeds with a 95 % bootstrap band (a PNG and a CSV).
* ``report RUN_DIR… [--first N] [--teams N] [--json PATH]``: trained models and the paper's law on held-out
  teams, interquartile mean over training seeds with a 95 % stratified bootstrap interval, and marl-eval JSON.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main", "json_object"]

PAPER_SCENARIOS = ("paper_pa3_square", "paper_pa_mixed_square")


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends "(default: …)" to an option's help unless the help already states its default, or
    the default is None (then the help says what happens) or False (an on/off flag, off)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.default is None or action.default is False:
            return text
        return super()._get_help_string(action)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pan1-env",
        description="Multi-arm PAn-1 formation control with robust-CBF safety (the paper's Section 5).",
    )
    # every sub-command's --help shows the defaults (see _HelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True,
                                parser_class=functools.partial(argparse.ArgumentParser,
                                                               formatter_class=_HelpFormatter))

    rep = sub.add_parser("reproduce", help="simulate one scenario with the paper's controller")
    rep.add_argument("scenario", help="built-in scenario name or path to a .toml file")
    rep.add_argument("--controller", choices=("nominal", "safe"), required=True,
                     help="nominal: v* = v0 (Eq. 39); safe: v* from the RCBF-QP (Eq. 61)")
    rep.add_argument("--out", required=True, type=Path, help="output directory")
    _common(rep)

    paper = sub.add_parser("paper", help="reproduce Section 5: both scenarios, both controllers")
    paper.add_argument("--out", type=Path, default=Path("runs/paper"), help="output directory")
    _common(paper)

    sub.add_parser("scenarios", help="list the built-in scenarios, 'random' and the Gymnasium ids")

    warm = sub.add_parser("warmup", help="compile the kernels ahead of time (once per arm kind; cached on disk)",
                          description="Compile (or load from numba's disk cache) the kernels the environments use, "
                                      "so that later processes start in seconds. With no option: the arm kinds "
                                      "of the built-in scenarios and of the random task's default team.")
    warm.add_argument("--kinds", nargs="+", metavar="KIND",
                      help="arm kinds: LINKS followed by p (passive first joint) or f (fully actuated), e.g. 4p 2f")
    warm.add_argument("--scenario", action="append", metavar="NAME",
                      help="a built-in scenario, a .toml path or 'random' (repeatable)")
    warm.add_argument("--threaded", action=argparse.BooleanOptionalAction, default=True,
                      help="also compile the multi-threaded kernels a vector or TorchRL env uses from 256 arms of "
                           "a kind (default: %(default)s; --no-threaded: the serial kernels only)")

    anim = sub.add_parser("animate", help="write a GIF of one episode of the environment")
    anim.add_argument("scenario", help="built-in scenario name, path to a .toml file, 'random' or a team id of "
                                       "pan1_env.ENV_IDS")
    anim.add_argument("--policy", default="reference",
                      help="reference (the paper's nominal law on local observations), zero, random, adversarial, "
                           "pretrained (the shipped model trained for the scenario's task), marl (the shipped "
                           "decentralised one), pretrained:NAME, sb3:PATH, or a name registered with "
                           "pan1_env.baselines.register_policy")
    anim.add_argument("--shield", action=argparse.BooleanOptionalAction, default=True,
                      help="behind the safety shield (with the reference policy this is the paper's safe "
                           "controller)")
    anim.add_argument("--out", type=Path, required=True, help="output .gif file")
    anim.add_argument("--steps", type=_positive_int, default=None,
                      help="env steps (default: the env's max_steps)")
    anim.add_argument("--frames", type=_positive_int, default=120, help="at most this many frames")
    anim.add_argument("--seed", type=int, default=0, help="reset seed (and random policy seed)")
    anim.add_argument("--fps", type=_positive_int, default=20, help="frames per second of the GIF")

    tr = sub.add_parser("train", help="train PPO, SAC or PPO-Lagrangian with Stable-Baselines3 (needs the rl "
                                      "extra)")
    tr.add_argument("--algo", choices=("ppo", "sac", "ppo-lagrangian"), default="ppo",
                    help="Stable-Baselines3 algorithm (ppo-lagrangian: PPO with a Lagrangian cost penalty)")
    tr.add_argument("--scenario", default="paper_pa3_square",
                    help="built-in name, .toml path, 'random' or a team id of pan1_env.ENV_IDS such as "
                         "pan1_env/WholeArmStaticFormation-v0 (--env-kwargs go on top of its options)")
    tr.add_argument("--shield", action=argparse.BooleanOptionalAction, default=True,
                    help="train behind the RCBF-QP safety shield")
    tr.add_argument("--timesteps", type=_positive_int, default=100_000, help="total environment steps")
    tr.add_argument("--seed", type=int, default=0, help="seed of the model and of the env resets")
    tr.add_argument("--out", type=Path, required=True, help="output directory")
    tr.add_argument("--resume", action="store_true", help="continue from the newest checkpoint in --out")
    from .baselines.training import DEFAULT_N_ENVS  # numpy only: SB3 and torch load when training starts

    tr.add_argument("--n-envs", type=_positive_int, default=DEFAULT_N_ENVS,
                    help="copies of the env, stepped together in the batched engine (default: %(default)s)")
    tr.add_argument("--param-sharing", action="store_true",
                    help="one network shared by every arm, each arm acting on its own (padded) observation: IPPO "
                         "with ppo, IPPO-Lagrangian with ppo-lagrangian")
    tr.add_argument("--centralised-critic", action="store_true",
                    help="with --param-sharing and ppo: a critic that also reads the team's global state while "
                         "each arm acts on its own observation (MAPPO; MAPPO-Lagrangian with ppo-lagrangian)")
    tr.add_argument("--team-sizes", type=_team_sizes, default=None, metavar="N,N,…",
                    help="with --param-sharing: train on --n-envs copies of each of these team sizes at once "
                         "(random_options n_arms), e.g. 3,4,5,6,7,8 on pan1_env/RandomFormation-v2, whose arm "
                         "observation has the same size for every team")
    tr.add_argument("--checkpoint-every", type=_positive_int, default=10_000, help="steps between checkpoints")
    tr.add_argument("--max-steps", type=_positive_int, default=None,
                    help="env steps per episode (default: the env's max_steps)")
    # pan1_env.config.ACTION_MODES, written out so that the parser does not import the env (a test checks)
    tr.add_argument("--action-mode", choices=("velocity", "torque", "residual", "gain", "circulation"),
                    default="velocity", help="what an action means (residual: a correction to the paper's law; "
                    "gain: a re-weighting of it; circulation: a re-weighting and a turn round obstacles; default: "
                    "%(default)s)")
    tr.add_argument("--normalize", action=argparse.BooleanOptionalAction, default=True,
                    help="standardise observations and scale rewards (SB3's VecNormalize, saved in model.json)")
    tr.add_argument("--env-kwargs", type=json_object, default=None, metavar="JSON",
                    help="extra env arguments, e.g. '{\"success_bonus\": 1.0}' (see help(pan1_env.parallel_env))")
    tr.add_argument("--algo-kwargs", type=json_object, default=None, metavar="JSON",
                    help="extra arguments of the SB3 algorithm, e.g. '{\"gamma\": 0.995}' (policy_kwargs too)")
    tr.add_argument("--eval-every", type=_positive_int, default=None, metavar="STEPS",
                    help="evaluate the deterministic policy on held-out teams every STEPS steps (eval.csv)")
    tr.add_argument("--critic-warmup", type=int, default=0, metavar="STEPS",
                    help="PPO: train only the critic for the first STEPS steps (actor frozen; default: 0)")
    tr.add_argument("--cost-limit", type=float, default=1.0,
                    help="ppo-lagrangian: allowed cost (arm-steps in an obstacle) per episode (default: %(default)s)")
    tr.add_argument("--lagrangian-lr", type=float, default=0.01,
                    help="ppo-lagrangian: step size of the multiplier update (default: %(default)s)")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")

    bench = sub.add_parser("benchmark", help="compare policies on the same seeded starts, shield on and off")
    bench.add_argument("--scenarios", default="paper_pa3_square,paper_pa_mixed_square",
                       help="comma-separated scenario names, paths, 'random' or team ids of "
                            "pan1_env.ENV_IDS (pan1_env/WholeArmStaticFormation-v0)")
    bench.add_argument("--policies", default="reference,zero,random",
                       help="comma-separated: reference, circulation (the law turning round obstacles), zero, random, "
                            "adversarial, sb3:PATH, pretrained "
                            "(the shipped centralised model trained for each scenario's task), marl (the shipped "
                            "decentralised one: a network shared by the arms), pretrained:NAME, or names "
                            "registered with pan1_env.baselines.register_policy")
    bench.add_argument("--episodes", type=_positive_int, default=5,
                       help="episodes per scenario, policy and shield setting")
    bench.add_argument("--seed", type=int, default=0,
                       help="episode k starts from reset(seed=seed + k); also seeds the random policy")
    bench.add_argument("--shield", choices=("both", "on", "off"), default="both",
                       help="run every policy with the safety shield, without it, or both")
    bench.add_argument("--max-steps", type=_positive_int, default=None,
                       help="env steps per episode (default: the env's max_steps)")
    bench.add_argument("--env-kwargs", type=json_object, default=None, metavar="JSON",
                       help="extra env arguments for every scenario, on top of a team id's options, e.g. "
                            "'{\"random_options\": {\"formation_turn\": [-0.5, 0.5]}}'")
    bench.add_argument("--out", type=Path, default=Path("runs/benchmark"), help="output directory")

    plot = sub.add_parser("plot", help="learning curves of training runs: mean over seeds, 95%% bootstrap band",
                          description="Return, success rate and cost against env steps for runs written by "
                                      "pan1-env train; runs that differ only in --seed form one group.")
    plot.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="directories written by pan1-env train")
    plot.add_argument("--out", type=Path, default=Path("runs/curves.png"), metavar="PATH",
                      help="output .png; the numbers go to the .csv beside it")
    plot.add_argument("--x", choices=("timesteps", "episodes"), default="timesteps",
                      help="x axis: env steps (all copies counted) or episodes finished")
    plot.add_argument("--window", type=_positive_int, default=100, metavar="N",
                      help="each seed's curve is the running mean of its last N episodes")
    plot.add_argument("--label", action="append", metavar="NAME",
                      help="a group's name, repeated once per group in the order the groups first appear "
                           "(default: algo, shield and the arguments that differ)")
    rep = sub.add_parser("report", help="trained models against the paper's law on held-out teams: interquartile "
                                        "mean over seeds, 95%% stratified bootstrap interval (needs the rl extra)",
                         description="Evaluates the final model of every run written by pan1-env train on held-out "
                                     "teams; runs that differ only in --seed form one group.")
    rep.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="directories written by pan1-env train")
    rep.add_argument("--first", type=int, default=2_000_000,
                     help="first reset seed of the held-out random teams (default: %(default)s)")
    rep.add_argument("--teams", type=_positive_int, default=200, help="held-out random teams (default: %(default)s)")
    rep.add_argument("--reps", type=_positive_int, default=2000, help="bootstrap resamples (default: %(default)s)")
    rep.add_argument("--team-size", type=_positive_int, default=None, metavar="N",
                     help="evaluate the runs and the law on teams of N arms of the runs' task, the obstacles at its "
                          "density per arm (models trained on a ring task, e.g. with --team-sizes)")
    rep.add_argument("--json", type=Path, default=None, metavar="PATH",
                     help="also write every episode in marl-eval's raw-data JSON layout")
    suite = sub.add_parser("suite", help="the leaderboard: every entry on every benchmark task's held-out teams "
                                         "(Markdown, marl-eval JSON, rliable figures)",
                           description="Scores the paper's law, the circulation rule and every learner with runs "
                                       "under --runs (else the shipped model of its recipe) on the held-out teams of "
                                       "the suite's tasks (docs/BENCHMARK.md).")
    suite.add_argument("--tasks", default=None, metavar="T,T,…", help="task names or ids (default: every task)")
    suite.add_argument("--entries", default=None, metavar="E,E,…",
                       help="the leaderboard's entries, by name (default: all; an unknown name lists them)")
    suite.add_argument("--runs", type=Path, default=Path("runs/suite"),
                       help="where the learners' runs are, <runs>/<entry>/<task>/seed_<s> (default: %(default)s)")
    suite.add_argument("--out", type=Path, default=Path("runs/leaderboard"), help="output directory")
    suite.add_argument("--quick", action="store_true",
                       help=f"{QUICK_TEAMS} held-out teams per task, episodes cut at {QUICK_STEPS} steps: a check of "
                            "the pipeline (CI), not the leaderboard's numbers")
    suite.add_argument("--teams", type=_positive_int, default=None, help="the first N held-out teams of each task")
    suite.add_argument("--train", nargs=2, default=None, metavar=("ENTRY", "TASK"),
                       help="train a learner's recipe on a task (every training seed, continuing from checkpoints) "
                            "instead of scoring")
    suite.add_argument("--seeds", type=_seeds, default=None, metavar="S,S,…",
                       help="with --train: these training seeds only (default: the task's)")
    suite.add_argument("--from", dest="source", type=Path, action="append", default=None, metavar="JSON",
                       help="re-render a leaderboard JSON (pan1-env suite's leaderboard.json) without scoring; "
                            "given again, merge the boards, a later one's (task, entry) cells replacing the "
                            "earlier's (an entry scored on its own, added to a board)")
    suite.add_argument("--docs", type=Path, default=None, metavar="PATH",
                       help="also write the benchmark page (docs/BENCHMARK.md) there, figures beside it")
    suite.add_argument("--workers", type=_positive_int, default=None,
                       help="processes for the policies run one team at a time (default: one per core)")
    suite.add_argument("--reps", type=_positive_int, default=2000, help="bootstrap resamples (default: %(default)s)")
    suite.add_argument("--no-figures", action="store_true", help="no rliable figures")
    return parser



QUICK_TEAMS, QUICK_STEPS = 2, 150  #: pan1-env suite --quick: a check of the whole pipeline in about a minute


def json_object(text: str) -> dict:
    """An argparse type: ``text`` parsed as a JSON object (``--env-kwargs``, ``--algo-kwargs``), refused in one line."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}: {err}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object such as '{{\"gamma\": 0.995}}', got {text!r}")
    return value


def _team_sizes(text: str) -> list[int]:
    sizes = [_positive_int(part.strip()) for part in text.split(",") if part.strip()]
    if not sizes or min(sizes) < 2 or len(set(sizes)) != len(sizes):
        raise argparse.ArgumentTypeError(f"expected distinct team sizes ≥ 2 separated by commas, got {text!r}")
    return sizes


def _seeds(text: str) -> list[int]:
    try:
        seeds = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        seeds = []
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"expected training seeds ≥ 0 separated by commas, got {text!r}")
    return seeds


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {text!r}")
    return value


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--horizon", type=_positive_float, default=None,
                   help="seconds to simulate (default: the scenario's horizon)")
    p.add_argument("--record-dt", type=_positive_float, default=0.01,
                   help="trajectory sampling period in seconds")
    p.add_argument("--qp-solver", choices=("active_set", "piqp"), default="active_set",
                   help="exact active-set kernel or qpsolvers + PIQP")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _reproduce_one(scenario, controller: str, out: Path, args) -> dict:
    import time

    from . import experiment

    started = time.perf_counter()
    result = experiment.run(scenario, controller, horizon=args.horizon, record_dt=args.record_dt,
                            qp_solver=args.qp_solver, progress=not args.no_progress)
    paths = experiment.write_outputs(result, out)
    if not args.no_figures:
        from . import figures

        fig = figures.run_figure(scenario, result.trajectory,
                                 title=f"{scenario.name} — {controller} controller")
        paths["figure"] = figures.save_figure(fig, out / "figure.png")
        fig8 = figures.obstacle_distance_figure(scenario, {controller: result.trajectory})
        if fig8 is not None:
            paths["obstacle_distance"] = figures.save_figure(fig8, out / "obstacle_distance.png")
    result.metrics["outputs"] = {k: str(v) for k, v in paths.items()}
    result.metrics["wall_time_total_s"] = time.perf_counter() - started
    experiment.write_outputs(result, out, trajectory=False)
    return result.metrics


def summary_table(rows: Sequence[dict]) -> str:
    """A Markdown table of run metrics (arms numbered 1..N as in the paper)."""
    head = ("| scenario | controller | collided arms | min clearance per arm [mm] | final max edge error [m] "
            "| time to 1 cm [s] | max momentum drift | wall time [s] |")
    lines = [head, "|" + "---|" * 8]
    for m in rows:
        hit = [str(a["index"] + 1) for a in m["arms"] if a["collided"]]
        clears = " / ".join("—" if a["min_clearance_m"] is None else f"{1000 * a['min_clearance_m']:+.1f}"
                            for a in m["arms"])
        t1 = m["time_to_edge_error_1cm_s"]
        drift = m["max_momentum_drift"]
        wall = m.get("wall_time_total_s", m["wall_time_s"])
        lines.append(
            f"| {m['scenario']} | {m['controller']} | {', '.join(hit) or 'none'} | {clears} "
            f"| {m['final_max_edge_error_m']:.2e} | {'never' if t1 is None else f'{t1:.1f}'} "
            f"| {'—' if drift is None else f'{drift:.1e}'} | {wall:.1f} |"
        )
    return "\n".join(lines)


def _print_summary(m: dict) -> None:
    """A run's metrics for people: seconds to 2 decimals, clearances in mm to 1 decimal, errors in
    scientific notation (``metrics.json`` keeps the full precision)."""
    t1 = m["time_to_edge_error_1cm_s"]
    drift = m.get("max_momentum_drift")
    print(f"\n{m['scenario']} / {m['controller']}: {m['steps']:,} steps of {m['physics_dt']:g} s "
          f"in {m['wall_time_s']:.1f} s wall time")
    for a in m["arms"]:
        c = a["min_clearance_m"]
        print(f"  arm {a['index'] + 1}: min clearance "
              f"{'—' if c is None else f'{1000 * c:+.1f} mm'}{'  COLLIDED' if a['collided'] else ''}")
    print(f"  final max edge error {m['final_max_edge_error_m']:.2e} m; "
          f"time to 1 cm: {'never' if t1 is None else f'{t1:.2f} s'}; "
          f"max momentum drift: {'—' if drift is None else f'{drift:.1e}'}; "
          f"QP solved/fallback steps: {m['qp_solved_steps']:,}/{m['qp_fallback_steps']:,}")
    for k, v in m.get("outputs", {}).items():
        print(f"  {k}: {v}")


def _cmd_reproduce(args) -> int:
    from . import scenario as scenario_mod

    sc = scenario_mod.load(args.scenario)
    metrics = _reproduce_one(sc, args.controller, args.out, args)
    _print_summary(metrics)
    return 0


def _cmd_paper(args) -> int:
    from . import scenario as scenario_mod
    from .experiment import atomic_write

    rows = []
    for name in PAPER_SCENARIOS:
        sc = scenario_mod.load(name)
        trajs = {}
        for controller in ("nominal", "safe"):
            out = args.out / name / controller
            rows.append(_reproduce_one(sc, controller, out, args))
            _print_summary(rows[-1])
            if not args.no_figures:
                import numpy as np

                with np.load(out / "trajectory.npz") as data:
                    trajs[controller] = {k: data[k] for k in ("time", "p_end")}
        if trajs:
            from . import figures

            fig8 = figures.obstacle_distance_figure(sc, trajs)
            if fig8 is not None:
                figures.save_figure(fig8, args.out / name / "obstacle_distance.png")
    table = summary_table(rows)
    atomic_write(args.out / "summary.md", lambda fh: fh.write(table + "\n"), mode="w")
    atomic_write(args.out / "summary.json", lambda fh: fh.write(json.dumps(rows, indent=2) + "\n"),
                 mode="w")
    print("\nSection 5 reproduction (arms numbered as in the paper):\n")
    print(table)
    print(f"\nfigures, metrics and trajectories under {args.out}/")
    return 0


def _cmd_scenarios(args) -> int:
    from . import scenario as scenario_mod
    from .registration import ENV_IDS, REACH_ENV_ID

    def count(n: int, noun: str) -> str:
        return f"{n} {noun}{'' if n == 1 else 's'}"

    print("built-in scenarios (pan1-env reproduce, animate, train, benchmark):")
    for name in scenario_mod.builtin_names():
        sc = scenario_mod.load(name)
        print(f"  {name}: {count(sc.n_arms, 'arm')}, {count(len(sc.obstacles), 'obstacle')}, "
              f"horizon {sc.horizon:g} s")
    print("  random: a new random team, formation and obstacles at every reset")
    print("Gymnasium ids (gymnasium.make, and as a scenario of animate, train and benchmark):")
    for env_id, options in ENV_IDS.items():
        extra = {k: v for k, v in options.items() if k != "scenario"}
        print(f"  {env_id}: scenario {options['scenario']}" + "".join(f", {k}={v}" for k, v in extra.items()))
    print(f"  {REACH_ENV_ID}: one arm reaching a target (gymnasium.make only)")
    return 0


def _cmd_warmup(args) -> int:
    from .warmup import warm_up

    warm_up(args.kinds, args.scenario, threaded=args.threaded)
    return 0


def _cmd_animate(args) -> int:
    import numpy as np

    from .environment import parallel_env
    from .experiment import atomic_write

    if args.out.suffix.lower() != ".gif":
        print(f"pan1-env: error: --out must end in .gif, got {args.out}", file=sys.stderr)
        return 2
    from .baselines import make_policy

    env = parallel_env(args.scenario, render_mode="rgb_array")
    if args.shield:
        from .wrappers import SafetyShield

        env = SafetyShield(env)
    steps = args.steps or env.config.max_steps
    every = max(1, int(np.ceil(steps / args.frames)))
    obs, _ = env.reset(seed=args.seed)
    policy = make_policy(args.policy, env, args.seed)
    frames = [env.render()]
    cost = 0.0
    for t in range(steps):
        obs, _, _, _, infos = env.step(policy(obs))
        cost += sum(i["cost"] for i in infos.values())
        if (t + 1) % every == 0 or not env.agents:
            frames.append(env.render())
        if not env.agents:
            break
    env.close()
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    atomic_write(args.out, lambda fh: images[0].save(fh, format="GIF", save_all=True,
                                                      append_images=images[1:], duration=1000 // args.fps,
                                                      loop=0))
    err = next(iter(infos.values()))["formation_error"] if infos else float("nan")
    print(f"{args.out}: {len(frames)} frames of {t + 1} steps; policy {args.policy}, "
          f"shield {'on' if args.shield else 'off'}; "
          f"final max edge error {err:.4f} m; cost (arm-steps in obstacles) {cost:g}")
    return 0


def _cmd_train(args) -> int:
    try:
        from .baselines.training import train
    except ImportError as err:  # pragma: no cover - depends on the installed extras
        print(f"pan1-env: error: training needs the rl extra (pip install 'pan1-env[rl]'): {err}",
              file=sys.stderr)
        return 2
    env_kwargs = dict(args.env_kwargs or {})
    if args.max_steps is not None:
        env_kwargs["max_steps"] = args.max_steps
    if args.action_mode != "velocity":
        env_kwargs["action_mode"] = args.action_mode
    summary = train(args.algo, args.scenario, shield=args.shield, timesteps=args.timesteps, seed=args.seed,
                    out=args.out, resume=args.resume, n_envs=args.n_envs, param_sharing=args.param_sharing,
                    centralised_critic=args.centralised_critic,
                    checkpoint_every=args.checkpoint_every, progress=not args.no_progress,
                    env_kwargs=env_kwargs, normalize=args.normalize, algo_kwargs=args.algo_kwargs,
                    eval_every=args.eval_every, critic_warmup=args.critic_warmup, cost_limit=args.cost_limit,
                    lagrangian_lr=args.lagrangian_lr, team_sizes=args.team_sizes)
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_benchmark(args) -> int:
    from .baselines.benchmark import markdown_table, marl_eval_rows, plot_benchmark, run_benchmark
    from .experiment import atomic_write

    shields = {"both": (True, False), "on": (True,), "off": (False,)}[args.shield]
    if args.env_kwargs and "scenario" in args.env_kwargs:
        raise ValueError("--env-kwargs cannot set the scenario: name it in --scenarios")
    rows = run_benchmark([s for s in args.scenarios.split(",") if s], [p for p in args.policies.split(",") if p],
                         episodes=args.episodes, seed=args.seed, shield_settings=shields,
                         max_steps=args.max_steps, env_kwargs=args.env_kwargs, progress=print, bar=True)
    table = markdown_table(rows)
    atomic_write(args.out / "benchmark.md", lambda fh: fh.write(table + "\n"), mode="w")
    atomic_write(args.out / "benchmark.json", lambda fh: fh.write(json.dumps(rows, indent=2) + "\n"), mode="w")
    marl_eval = json.dumps(marl_eval_rows(rows), indent=1) + "\n"
    atomic_write(args.out / "benchmark_marl_eval.json", lambda fh: fh.write(marl_eval), mode="w")
    plot_benchmark(rows, args.out / "benchmark.png")
    print("\n" + table + f"\n\nbenchmark.md, benchmark.json (marl-eval's layout: benchmark_marl_eval.json) and "
          f"benchmark.png under {args.out}/")
    return 0


def _cmd_plot(args) -> int:
    import warnings

    from .baselines.curves import plot_curves

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            png, csv_path = plot_curves(args.runs, args.out, x=args.x, window=args.window, labels=args.label)
        except OSError as err:  # a missing run directory, run.json or episodes.csv
            print(f"pan1-env: error: {err}", file=sys.stderr)
            return 2
    for w in caught:
        print(f"pan1-env: warning: {w.message}", file=sys.stderr)
    print(f"{png}\n{csv_path}")
    return 0


def _cmd_report(args) -> int:
    from tqdm import tqdm

    from .baselines.report import markdown, marl_eval_json, report

    try:
        rows = report(args.runs, first=args.first, teams=args.teams, reps=args.reps, team_size=args.team_size,
                      progress=lambda message: tqdm.write(message, file=sys.stderr))
    except OSError as err:  # a missing run directory or model
        print(f"pan1-env: error: {err}", file=sys.stderr)
        return 2
    print(markdown(rows))
    if args.json is not None:
        print(marl_eval_json(rows, args.json))
    return 0


def _cmd_suite(args) -> int:
    from tqdm import tqdm

    from .baselines import leaderboard as board
    from .baselines.leaderboard_table import benchmark_page, leaderboard_rows, markdown
    from .experiment import atomic_write

    for flag, given, needs in (("--seeds", args.seeds, args.train), ("--teams", args.teams, not args.quick)):
        if given is not None and not needs:
            raise ValueError(f"{flag} goes with {'--train' if flag == '--seeds' else 'a full run, not --quick'}")
    if args.source is not None and (args.tasks or args.entries or args.quick or args.teams or args.train):
        raise ValueError("--from re-renders a leaderboard as it is: no --tasks, --entries, --quick, --teams or --train")
    tasks, entries = board.resolve(args.tasks, args.entries)
    if args.train is not None:
        from .baselines.suite import suite_task

        board.train_entry(board.entry(args.train[0]), suite_task(args.train[1]), runs=args.runs, seeds=args.seeds)
        return 0
    if args.source is not None:
        data = board.merge_leaderboards([board.load_leaderboard(path) for path in args.source])
    else:
        data = board.run_suite(tasks, entries, runs=args.runs, teams=QUICK_TEAMS if args.quick else args.teams,
                               max_steps=QUICK_STEPS if args.quick else None, workers=args.workers, bar=True,
                               progress=lambda message: tqdm.write(message, file=sys.stderr))
        data["quick"] = bool(args.quick) or any(args.teams is not None and args.teams < len(t.held_out) for t in tasks)
    text, raw = json.dumps(data, indent=1) + "\n", json.dumps(data["raw"], indent=1) + "\n"
    for where in {args.out, *([args.docs.parent] if args.docs is not None else [])}:
        atomic_write(where / "leaderboard.json", lambda fh: fh.write(text), mode="w")
    atomic_write(args.out / "leaderboard_marl_eval.json", lambda fh: fh.write(raw), mode="w")
    table = markdown(leaderboard_rows(data, args.reps))
    atomic_write(args.out / "leaderboard.md", lambda fh: fh.write(table + "\n"), mode="w")
    figures = []
    if not args.no_figures:
        from .baselines.leaderboard_figures import leaderboard_figures

        place = args.out if args.docs is None else args.docs.parent / "figures"
        figures = leaderboard_figures(data, place, args.reps)
    if args.docs is not None:
        names = [str(f.relative_to(args.docs.parent)) for f in figures]
        page = benchmark_page(data, names, args.reps)
        atomic_write(args.docs, lambda fh: fh.write(page), mode="w")
    print(table + f"\n\nleaderboard.md, leaderboard.json and leaderboard_marl_eval.json under {args.out}/"
          + "".join(f"\n{f}" for f in figures) + (f"\n{args.docs} (leaderboard.json beside it)" if args.docs else ""))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pan1-env`` console script."""
    from .scenario import ScenarioError

    args = _parser().parse_args(argv)
    handlers = {"reproduce": _cmd_reproduce, "paper": _cmd_paper, "scenarios": _cmd_scenarios,
                "warmup": _cmd_warmup,
                "animate": _cmd_animate, "train": _cmd_train, "benchmark": _cmd_benchmark, "plot": _cmd_plot,
                "report": _cmd_report, "suite": _cmd_suite}
    try:
        return handlers[args.command](args)
    except (ScenarioError, ValueError) as err:
        print(f"pan1-env: error: {err}", file=sys.stderr)
        return 2
    except ImportError as err:
        if not _missing_extra(err):
            raise  # a bug inside pan1_env: its traceback, not a hint to install something
        hint = "" if "extra" in str(err) else " (an optional library: the README's Install section lists the extras)"
        print(f"pan1-env: error: {err}".replace("\n", " ") + hint, file=sys.stderr)
        return 2


def _missing_extra(err: ImportError) -> bool:
    """An optional library a command or policy needs is missing: the package's own message naming the extra (a
    plain ``ImportError`` saying so), or a module not found outside ``pan1_env``."""
    if isinstance(err, ModuleNotFoundError):
        return not (err.name or "").startswith("pan1_env")
    return "extra" in str(err)
