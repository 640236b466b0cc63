"""Stable-Baselines3 training on the environments, behind the safety shield or not.

:func:`train` trains PPO or SAC either on the batched vector env (one policy for the whole team,
concatenated observations and actions: the Gymnasium view's spaces, B copies stepped in one engine
through :class:`~pan1_env.baselines.vec_env.SB3VecEnv`) or, with ``param_sharing=True``, on every arm
of the same batched engine through :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv` (one policy shared by
every arm, acting on the arm's own observation; observations and actions padded to the largest arm). It
writes into ``out``:

* ``checkpoints/model_<steps>_steps.zip`` and ``state_<steps>_steps.pkl`` at the first update
  boundary after every ``checkpoint_every`` steps and at the end (plus the replay buffer for SAC),
  each written atomically, and ``run.json`` (the arguments);
* ``episodes.csv``: one row per finished episode: ``timesteps, return, length, cost, success``
  (cost: arm-steps inside an obstacle; success: formation error below 1 cm at the end; with
  ``param_sharing`` one row per team episode, its return the mean of the arms');
* ``eval.csv`` (with ``eval_every``): every ``eval_every`` steps, the deterministic policy on held-out
  teams (:mod:`pan1_env.baselines.evaluation`): success at 1, 2 and 5 cm, median final error, return,
  cost, time to formation;
* ``model.zip``: the final model, and ``model.json`` beside it (and beside every checkpoint): what a
  policy needs to run the model on an env, the env arguments (``action_mode``…) and, with
  ``normalize``, the observation statistics (mean, variance, clip) the model was trained with.

``timesteps`` is rounded once to the nearest whole number of collections (a PPO rollout of ``n_steps``
× SB3 envs, or one SAC step of every env), announced on stderr at the start; a budget too short for
any episode to end is announced too. ``env_kwargs`` and ``algo_kwargs`` are checked (names with a
"did you mean", then values) before ``out`` is created.

``critic_warmup=N`` (PPO) trains only the value function for the first N steps, the actor frozen:
useful for residual and gain actions, whose initial policy is the reference controller.

``normalize=True`` (the default) trains through SB3's ``VecNormalize``: observations are
standardised by running statistics (clipped to ±10) and rewards scaled by the running standard
deviation of the discounted return. Episode returns in ``episodes.csv`` stay raw.

``algo="ppo-lagrangian"`` is PPO with a Lagrange multiplier λ on the cost (constrained RL, meant to run
without the shield; :mod:`~pan1_env.baselines.lagrangian`): rewards become (r − λ·cost) / (1 + λ) before
``VecNormalize``, λ ← max(0, λ + ``lagrangian_lr`` · (mean episode cost − ``cost_limit``)) after every
rollout, ``lagrangian.csv`` logs ``timesteps, lambda, episode_cost`` and the checkpoints carry λ.

``resume=True`` continues from the newest checkpoint in ``out`` up to ``timesteps`` in total. A
checkpoint holds the model and optimiser, the vector env itself (pickled mid-episode), the last
observation, the torch/numpy/python random states and the running episode costs, and the episode
log is cut back to the checkpoint, so for PPO an interrupted run resumed with the same arguments
ends exactly where the uninterrupted run does (a test checks it), with ``param_sharing`` too. For SAC
the replay buffer is kept too. With ``param_sharing`` and ``ppo-lagrangian`` each arm is penalised for its
own cost (IPPO-Lagrangian), so ``cost_limit`` is per arm and episode.
Needs the ``rl`` extra (torch, stable-baselines3); torch runs on one thread.
"""

from __future__ import annotations

import csv
import json
import pickle
import random
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["train", "make_training_env", "ALGOS", "latest_checkpoint", "first_episode_end"]

ALGOS = ("ppo", "sac", "ppo-lagrangian")  # ppo-lagrangian: PPO with a Lagrange multiplier on the cost
DEFAULT_N_ENVS = 128  # copies in the batched engine
# PPO for B copies, the usual large-batch recipe: 8192 steps per update (64 per copy) in 4 minibatches,
# 5 epochs. SB3's defaults (2048 steps per copy, minibatches of 64, 10 epochs) are sized for one env:
# with 128 copies an update would take 262,144 steps and 40,960 minibatches. Measured on this
# project's 2-core machine (benchmarks/bench.py, bench_training): the update is then about half the
# wall time, and training runs 14-15x the steps per second of SB3's defaults on 8 separate envs.
PPO_DEFAULTS = {"n_steps": 64, "batch_size": 2048, "n_epochs": 5}


def make_training_env(scenario: str, shield: bool, seed: int, n_envs: int = DEFAULT_N_ENVS,
                      param_sharing: bool = False, env_kwargs: dict[str, Any] | None = None,
                      centralised_critic: bool = False, team_sizes: list[int] | None = None):
    """The SB3 ``VecEnv`` to train on (see the module docstring); its copies are seeded with independent streams
    spawned from ``seed`` (:func:`pan1_env.core.copy_generator`). With ``team_sizes``, ``n_envs`` copies of each
    size (:class:`~pan1_env.baselines.mixed_vec_env.SB3MixedArmVecEnv`, parameter sharing)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from .arm_vec_env import SB3ArmVecEnv
    from .vec_env import SB3VecEnv

    kwargs = {"safety_filter": bool(shield), **dict(env_kwargs or {})}
    if centralised_critic:
        kwargs["critic_state"] = True
    if team_sizes:
        from .mixed_vec_env import SB3MixedArmVecEnv

        venv = SB3MixedArmVecEnv(scenario, team_sizes, n_envs, **kwargs)
    else:
        venv = (SB3ArmVecEnv if param_sharing else SB3VecEnv)(scenario, n_envs, **kwargs)
    venv.seed(seed)
    return VecMonitor(venv)


def latest_checkpoint(out: Path) -> tuple[Path, int] | None:
    """The newest ``checkpoints/model_<steps>_steps.zip`` in ``out`` and its step count."""
    found = []
    for path in (Path(out) / "checkpoints").glob("model_*_steps.zip"):
        m = re.fullmatch(r"model_(\d+)_steps\.zip", path.name)
        if m:
            found.append((int(m.group(1)), path))
    if not found:
        return None
    steps, path = max(found)
    return path, steps


def _callbacks(out: Path, checkpoint_every: int, algo: str, total: int, progress: bool,
               initial_costs: np.ndarray | None, sidecar, teams: list[range]):
    import torch
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList

    from pan1_env.experiment import atomic_write

    class EpisodeLog(BaseCallback):
        """Appends a CSV row per finished episode with its return, length, cost and success.

        With parameter sharing each arm is a sub-env of its own (``teams``: each team's consecutive sub-envs,
        ending together): a team's episode is one row, its return the mean of its arms' returns (the
        benchmark's convention) and its cost the sum of its arms' costs."""

        def _on_training_start(self) -> None:
            self.path = out / "episodes.csv"
            new = not self.path.exists() or self.path.stat().st_size == 0
            self.fh = self.path.open("a", newline="")
            self.writer = csv.writer(self.fh)
            if new:  # flushed at once: a run killed before its first episode ends must leave the header
                self.writer.writerow(["timesteps", "return", "length", "cost", "success"])
                self.fh.flush()
            n = self.training_env.num_envs
            self.costs = np.zeros(n) if initial_costs is None else np.array(initial_costs, dtype=float)
            self.bar = None
            if progress:
                from tqdm import tqdm

                self.bar = tqdm(total=total, initial=self.num_timesteps, unit="step", desc=f"train {algo}")

        def _on_step(self) -> bool:
            infos = self.locals["infos"]
            for i, info in enumerate(infos):
                self.costs[i] += float(info.get("cost", 0.0))
            for team in teams:
                ended = [i for i in team if "episode" in infos[i]]
                if not ended:
                    continue
                info = infos[ended[0]]
                success = bool(info.get("is_success", False))
                ret = float(np.mean([infos[i]["episode"]["r"] for i in ended]))
                self.writer.writerow([self.num_timesteps, round(ret, 6), int(info["episode"]["l"]),
                                      float(self.costs[team].sum()), int(success)])
                self.fh.flush()
                self.costs[team] = 0.0
            if self.bar is not None:
                self.bar.update(self.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.fh.close()
            if self.bar is not None:
                self.bar.update(self.num_timesteps - self.bar.n)
                self.bar.close()

    log = EpisodeLog()

    class ResumableCheckpoint(BaseCallback):
        """Saves, between updates, everything needed to continue exactly as if never stopped."""

        def _on_training_start(self) -> None:
            self.last = self.num_timesteps

        def _on_rollout_start(self) -> None:
            if self.num_timesteps - self.last >= checkpoint_every:
                self._save()

        def _on_step(self) -> bool:
            return True

        def _on_training_end(self) -> None:
            if self.num_timesteps > self.last:
                self._save()

        def _save(self) -> None:
            model, steps = self.model, self.num_timesteps
            folder = out / "checkpoints"
            state = {
                "venv": _venv_state(model.get_env()), "last_obs": model._last_obs,
                "last_episode_starts": model._last_episode_starts, "episode_num": model._episode_num,
                # SB3 draws from the legacy global numpy RNG (minibatch shuffling): keep its state
                "torch_rng": torch.get_rng_state(), "numpy_rng": np.random.get_state(),  # noqa: NPY002
                "python_rng": random.getstate(), "costs": log.costs.copy(),
            }
            penalty = _penalty(model.get_env())
            if penalty is not None:  # the Lagrange multiplier and its running episode costs
                state["lagrangian"] = penalty.state_dict()
            if algo == "sac":
                atomic_write(folder / f"model_replay_buffer_{steps}_steps.pkl",
                             lambda fh: pickle.dump(model.replay_buffer, fh))
            normalizer = _normalizer(model.get_env())
            if normalizer is not None:  # SB3 does not pickle its running return; keep it for exact resume
                state["normalize"] = {"obs_rms": normalizer.obs_rms, "ret_rms": normalizer.ret_rms,
                                      "returns": normalizer.returns.copy()}
            atomic_write(folder / f"state_{steps}_steps.pkl", lambda fh: pickle.dump(state, fh))
            sidecar(folder / f"model_{steps}_steps.json", normalizer)
            atomic_write(folder / f"model_{steps}_steps.zip", lambda fh: model.save(fh))
            self.last = steps

    return CallbackList([ResumableCheckpoint(), log])


def _normalizer(venv):
    """The ``VecNormalize`` on top of the training env, or None."""
    from stable_baselines3.common.vec_env import VecNormalize

    return venv if isinstance(venv, VecNormalize) else None


def _monitor(venv):
    """The ``VecMonitor`` of the training env (under the ``VecNormalize`` and the cost penalty, if any)."""
    from stable_baselines3.common.vec_env import VecMonitor

    while not isinstance(venv, VecMonitor):
        venv = venv.venv
    return venv


def _penalty(venv):
    """The :class:`~pan1_env.baselines.lagrangian.CostPenalisedVecEnv` in the training env, or None."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from .lagrangian import CostPenalisedVecEnv

    while isinstance(venv, VecEnvWrapper):
        if isinstance(venv, CostPenalisedVecEnv):
            return venv
        venv = venv.venv
    return None


def _venv_state(venv) -> dict[str, Any]:
    """The picklable state of a ``[VecNormalize(]VecMonitor(SB3VecEnv(...))``: the vector env mid-episode
    (its engine, task and generators) and the monitor's running episode statistics (SB3's wrappers do
    not pickle)."""
    venv = _monitor(venv)
    inner = venv.venv
    return {"vector": inner.venv, "episode_returns": venv.episode_returns, "episode_lengths": venv.episode_lengths,
            "episode_count": venv.episode_count}


def _restore_venv(venv, state: dict[str, Any]) -> None:
    venv = _monitor(venv)
    inner = venv.venv
    inner.venv = state["vector"]
    venv.episode_returns = state["episode_returns"]
    venv.episode_lengths = state["episode_lengths"]
    venv.episode_count = state["episode_count"]


def _truncate_log(path: Path, steps: int) -> None:
    """Drop the episode rows logged after ``steps`` (an interrupted run's work past its checkpoint)."""
    if not path.exists():
        return
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    kept = rows[:1] + [r for r in rows[1:] if int(r[0]) <= steps]
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(kept)


def train(algo: str = "ppo", scenario: str = "paper_pa3_square", *, shield: bool = True, timesteps: int = 100_000,
          seed: int = 0, out: str | Path = "runs/train", resume: bool = False, n_envs: int = DEFAULT_N_ENVS,
          param_sharing: bool = False, centralised_critic: bool = False, checkpoint_every: int = 10_000,
          progress: bool = True,
          env_kwargs: dict[str, Any] | None = None, algo_kwargs: dict[str, Any] | None = None,
          normalize: bool = True, eval_every: int | None = None, critic_warmup: int = 0,
          extra_callbacks: list | None = None, cost_limit: float = 1.0, lagrangian_lr: float = 0.01,
          team_sizes: list[int] | None = None) -> dict[str, Any]:
    """Train and return a summary (see the module docstring). Raises ValueError on bad arguments."""
    from pan1_env.registration import env_arguments

    scenario, env_kwargs = env_arguments(scenario, env_kwargs)  # a Gymnasium id: its scenario and options
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    for name, value in (("timesteps", timesteps), ("n_envs", n_envs), ("checkpoint_every", checkpoint_every)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if isinstance(critic_warmup, bool) or not isinstance(critic_warmup, int) or critic_warmup < 0:
        raise ValueError(f"critic_warmup must be a whole number of steps ≥ 0, got {critic_warmup!r}")
    if centralised_critic and (algo == "sac" or not param_sharing):
        raise ValueError(f"centralised_critic (--centralised-critic, MAPPO) is the critic of an actor the arms share: "
                         f"it needs param_sharing (--param-sharing) and ppo or ppo-lagrangian; got algo={algo!r}, "
                         f"param_sharing={param_sharing}")
    if team_sizes and not param_sharing:
        raise ValueError("team_sizes (--team-sizes) trains one network the arms share on teams of several sizes: "
                         "it needs param_sharing (--param-sharing)")
    if critic_warmup and algo == "sac":
        raise ValueError("critic_warmup is for PPO's actor and critic; SAC has no warm-up here")
    max_steps = _check_env_kwargs(scenario, env_kwargs)
    import torch
    from stable_baselines3 import PPO, SAC

    from pan1_env.experiment import atomic_write

    cls = SAC if algo == "sac" else PPO
    _check_algo_kwargs(cls, algo_kwargs)
    torch.set_num_threads(1)
    out = Path(out)

    def build_env():
        venv = make_training_env(scenario, shield, seed, n_envs, param_sharing, env_kwargs, centralised_critic,
                                 team_sizes)
        if algo == "ppo-lagrangian":
            from .lagrangian import CostPenalisedVecEnv

            # the episode length scales cost per step until episodes end
            venv = CostPenalisedVecEnv(venv, cost_limit=cost_limit, lagrangian_lr=lagrangian_lr,
                                       episode_length=max_steps)
        return _normalized(venv, normalize, algo_kwargs)

    done_steps = 0
    initial_costs = None
    previous = latest_checkpoint(out) if resume else None
    if resume and previous is None:
        raise ValueError(f"nothing to resume in {out}: no checkpoints/model_*_steps.zip")
    if previous is not None:
        _check_resumed_view(out, algo, param_sharing, centralised_critic, team_sizes)
        path, done_steps = previous
        with path.with_name(f"state_{done_steps}_steps.pkl").open("rb") as fh:
            state = pickle.load(fh)
        venv = build_env()
        _restore_venv(venv, state["venv"])
        if "lagrangian" in state:
            _penalty(venv).load_state_dict(state["lagrangian"])
        if "normalize" in state:
            norm = _normalizer(venv)
            norm.obs_rms, norm.ret_rms = state["normalize"]["obs_rms"], state["normalize"]["ret_rms"]
            norm.returns = state["normalize"]["returns"]
        model = cls.load(path, env=venv, device="cpu")
        model._last_obs = state["last_obs"]
        model._last_episode_starts = state["last_episode_starts"]
        model._episode_num = state["episode_num"]
        if algo == "sac":
            with path.with_name(f"model_replay_buffer_{done_steps}_steps.pkl").open("rb") as fh:
                model.replay_buffer = pickle.load(fh)
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])  # noqa: NPY002 - SB3 uses the global RNG
        random.setstate(state["python_rng"])
        initial_costs = state["costs"]
        _truncate_log(out / "episodes.csv", done_steps)
        _truncate_log(out / "eval.csv", done_steps)
        _truncate_log(out / "lagrangian.csv", done_steps)
    else:
        venv = build_env()
        defaults = {} if algo == "sac" else _ppo_defaults(timesteps, venv.num_envs, algo_kwargs or {})
        kwargs = {"seed": seed, "verbose": 0, "device": "cpu", **defaults, **(algo_kwargs or {})}
        try:
            if centralised_critic:  # MAPPO: the actor reads the arm's own entries, the critic the global state too
                from .mappo import LocalActorPolicy

                local = {"actor_inputs": venv.unwrapped.local_size}
                kwargs["policy_kwargs"] = {**kwargs.get("policy_kwargs", {}), **local}
            model = cls(LocalActorPolicy if centralised_critic else "MlpPolicy", venv, **kwargs)
        except (TypeError, ValueError, AssertionError) as err:  # a bad value in algo_kwargs, before anything is written
            venv.close()
            raise ValueError(f"algo_kwargs: {cls.__name__} refused them: {err}") from None
        out.mkdir(parents=True, exist_ok=True)
        for log_name in ("episodes.csv", "eval.csv", "lagrangian.csv"):
            if (out / log_name).exists():
                (out / log_name).unlink()
    chunk = _steps_per_collection(model)
    requested, timesteps = timesteps, max(chunk, int(timesteps / chunk + 0.5) * chunk)  # the nearest whole count
    teams = venv.unwrapped.team_envs  # each copy's SB3 envs: its arms with parameter sharing, else itself
    team_size = venv.num_envs // n_envs  # SB3 envs per --n-envs copy (with mixed sizes, one copy of each size)
    if timesteps != requested:
        _say(f"--timesteps {requested:,} rounded to {timesteps:,}: {_collection_text(model, len(teams))}; "
             "the progress bar, num_timesteps and the last checkpoint all stop there")
    first_end = max_steps * venv.num_envs
    if first_end > timesteps and previous is None:
        per = "arm-steps (each arm counts)" if team_size > 1 else "steps"
        _say(f"no episode may end in this run: an episode lasts up to {max_steps:,} steps and the {n_envs:,} "
             f"copies advance together, so the first episodes end after {first_end:,} {per}, past the budget of "
             f"{timesteps:,}; episodes.csv stays empty. Use --max-steps {_fit(timesteps, venv.num_envs)} or "
             f"--n-envs {_fit(timesteps, max_steps * team_size)}, or a budget of at least {first_end:,}")
    meta = {"algo": algo, "scenario": scenario, "shield": shield, "timesteps": timesteps, "seed": seed,
            "n_envs": n_envs, "param_sharing": param_sharing, "env_kwargs": env_kwargs or {},
            "algo_kwargs": algo_kwargs or {}, "normalize": normalize}
    if critic_warmup:
        meta["critic_warmup"] = critic_warmup
    if team_sizes:
        meta["team_sizes"] = list(venv.unwrapped.team_sizes)
    if centralised_critic:
        meta["centralised_critic"] = True
    if algo == "ppo-lagrangian":
        meta |= {"cost_limit": cost_limit, "lagrangian_lr": lagrangian_lr}

    model_env_kwargs = dict(env_kwargs or {})
    from pan1_env.config import MODE_SETTINGS, FormationConfig

    for name in MODE_SETTINGS.get(model_env_kwargs.get("action_mode"), ()):  # the settings the model was trained
        model_env_kwargs.setdefault(name, getattr(FormationConfig, name))  # with, whatever the defaults when loaded

    def sidecar(path: Path, normalizer) -> None:
        info = {"scenario": scenario, "env_kwargs": model_env_kwargs, "param_sharing": param_sharing,
                "algo": algo, "shield": shield}
        if centralised_critic:
            info["centralised_critic"] = True
        if normalizer is not None:  # of the actor's input: a MAPPO model acts on the arm's own entries alone
            inputs = venv.unwrapped.local_size if centralised_critic else len(normalizer.obs_rms.mean)
            info["observation_normalization"] = {
                "mean": normalizer.obs_rms.mean[:inputs].tolist(), "var": normalizer.obs_rms.var[:inputs].tolist(),
                "clip": float(normalizer.clip_obs), "epsilon": float(normalizer.epsilon)}
        atomic_write(path, lambda fh: fh.write(json.dumps(info) + "\n"), mode="w")

    atomic_write(out / "run.json", lambda fh: fh.write(json.dumps(meta, indent=2) + "\n"), mode="w")
    remaining = timesteps - done_steps
    if remaining > 0:
        from stable_baselines3.common.callbacks import CallbackList

        callbacks = [_callbacks(out, checkpoint_every, algo, timesteps, progress, initial_costs, sidecar, teams)]
        if eval_every:
            from .evaluation import EVAL_SEEDS, eval_callback

            seeds = EVAL_SEEDS if scenario == "random" else EVAL_SEEDS[:1]  # a paper scenario starts one way
            # evaluate before a checkpoint at the same step
            callbacks.insert(0, eval_callback(out, eval_every, scenario, shield, env_kwargs, seeds, progress))
        if critic_warmup > 0:
            callbacks.insert(0, _critic_warmup(critic_warmup))
        if _penalty(venv) is not None:
            from .lagrangian import LagrangianCallback

            callbacks.append(LagrangianCallback(_penalty(venv), log_dir=out))
        callbacks = CallbackList([*callbacks, *(extra_callbacks or [])])
        model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=(previous is None))
    sidecar(out / "model.json", _normalizer(venv))
    atomic_write(out / "model.zip", lambda fh: model.save(fh))
    penalty = _penalty(venv)
    venv.close()
    return {**meta, **({} if penalty is None else {"lambda": penalty.lagrange_multiplier}),
            "resumed_from": done_steps, "model": str(out / "model.zip"),
            "episodes": str(out / "episodes.csv")} | _episode_summary(out / "episodes.csv")


def _check_resumed_view(out: Path, algo: str, param_sharing: bool, centralised_critic: bool,
                        team_sizes: list[int] | None = None) -> None:
    """A run resumes with the algorithm and the view of the env it was trained on: its run.json's."""
    try:
        run = json.loads((out / "run.json").read_text())
    except (OSError, ValueError):
        return  # no readable run.json: SB3's own checks on the saved model remain
    given = {"algo": algo, "param_sharing": param_sharing, "centralised_critic": centralised_critic,
             "team_sizes": list(team_sizes) if team_sizes else None}
    flags = {"algo": "--algo", "param_sharing": "--param-sharing", "centralised_critic": "--centralised-critic",
             "team_sizes": "--team-sizes, in the same order"}
    for key, value in given.items():
        trained = run.get(key, {"algo": "ppo", "team_sizes": None}.get(key, False))
        if trained != value:
            raise ValueError(f"{out} was trained with {key}={trained!r} ({flags[key]}); resume it with the same, "
                             f"not {value!r}")


def _critic_warmup(steps: int):
    """Train only PPO's critic for the first ``steps`` steps: the actor (its network, action head and
    log σ) is frozen. A residual policy starts at a good controller while the value estimates are
    random, and its first advantages would otherwise move it away from the controller."""
    from stable_baselines3.common.callbacks import BaseCallback

    class CriticWarmup(BaseCallback):
        def _actor(self):
            policy = self.model.policy
            return [policy.log_std, *policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]

        def _on_training_start(self) -> None:
            self._set(self.num_timesteps >= steps)

        def _on_rollout_end(self) -> None:
            self._set(self.num_timesteps >= steps)

        def _on_step(self) -> bool:
            return True

        def _set(self, trainable: bool) -> None:
            for p in self._actor():
                p.requires_grad_(trainable)

    return CriticWarmup()


def first_episode_end(scenario: str, env_kwargs: dict[str, Any], n_envs: int, param_sharing: bool) -> int:
    """The step count (as SB3 counts them, every copy and, with parameter sharing, every arm) at which
    the first episodes of a training run reach their time limit."""
    from pan1_env.config import FormationConfig
    from pan1_env.registration import env_arguments

    scenario, env_kwargs = env_arguments(scenario, env_kwargs)
    config = FormationConfig.of(scenario, **env_kwargs)
    return config.max_steps * n_envs * (config.team.n_arms if param_sharing else 1)


def _say(text: str) -> None:
    """A note for the person who started the run, at its start (stderr: stdout carries the summary)."""
    print(f"pan1-env train: {text}", file=sys.stderr, flush=True)


def _fit(budget: int, per: int) -> int:
    """A setting that lets every copy finish about four episodes within ``budget`` steps."""
    return max(1, budget // (4 * per))


def _check_env_kwargs(scenario: str, env_kwargs: dict[str, Any] | None) -> int:
    """``env_kwargs`` checked as the env will (names with a "did you mean", then values), before anything
    is built or written; returns the episode length (``max_steps``)."""
    from pan1_env.config import ARGUMENTS, FormationConfig
    from pan1_env.validation import refuse_unknown

    env_kwargs = dict(env_kwargs or {})
    for key in ("scenario", "safety_filter"):
        if key in env_kwargs:
            raise ValueError(f"env_kwargs: {key!r} is set by the training's own "
                             f"{'scenario' if key == 'scenario' else 'shield'} argument; leave it out")
    refuse_unknown("env_kwargs", env_kwargs, [a for a in ARGUMENTS if a not in ("scenario", "safety_filter")])
    try:
        return FormationConfig.of(scenario, **env_kwargs).max_steps
    except TypeError as err:
        raise ValueError(f"env_kwargs: {err}") from None


def _check_algo_kwargs(cls, algo_kwargs: dict[str, Any] | None) -> None:
    """The names of ``algo_kwargs`` checked against the SB3 class's constructor ("did you mean")."""
    import inspect

    from pan1_env.validation import refuse_unknown

    names = [name for name, p in inspect.signature(cls.__init__).parameters.items()
             if name not in ("self", "policy", "env") and not name.startswith("_") and p.kind is not p.VAR_KEYWORD]
    refuse_unknown(f"algo_kwargs ({cls.__name__})", algo_kwargs or {}, names)


def _ppo_defaults(timesteps: int, num_envs: int, algo_kwargs: dict[str, Any]) -> dict[str, Any]:
    """PPO_DEFAULTS fitted to the budget and to the SB3 envs (B copies, or B × arms with parameter
    sharing): one rollout never exceeds the budget, and the minibatch divides the rollout."""
    n_steps = algo_kwargs.get("n_steps", min(PPO_DEFAULTS["n_steps"], max(1, timesteps // num_envs)))
    out = {"n_steps": n_steps, "n_epochs": PPO_DEFAULTS["n_epochs"]}
    if "batch_size" not in algo_kwargs:
        out["batch_size"] = _divisor_near(n_steps * num_envs, PPO_DEFAULTS["batch_size"])
    return out


def _divisor_near(n: int, target: int) -> int:
    """The divisor of ``n`` nearest ``target`` by ratio (at least 2 when n ≥ 2: SB3 needs it)."""
    divisors = {d for k in range(1, int(n ** 0.5) + 1) if n % k == 0 for d in (k, n // k)}
    divisors = {d for d in divisors if d >= 2} or {n}
    return min(divisors, key=lambda d: (abs(np.log(d / target)), -d))


def _steps_per_collection(model) -> int:
    """The steps SB3 adds to ``num_timesteps`` between two checks of the budget: a whole rollout for
    PPO, ``train_freq`` steps of every env for SAC (1 for a frequency counted in episodes)."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
    from stable_baselines3.common.type_aliases import TrainFrequencyUnit

    if isinstance(model, OnPolicyAlgorithm):
        return model.n_steps * model.n_envs
    freq = model.train_freq
    return model.n_envs * (freq.frequency if freq.unit == TrainFrequencyUnit.STEP else 1)


def _collection_text(model, copies: int) -> str:
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    envs = f"{model.n_envs:,} SB3 envs (the arms of {copies:,} copies)" if model.n_envs > copies \
        else f"{model.n_envs:,} copies"
    if isinstance(model, OnPolicyAlgorithm):
        return f"PPO collects whole rollouts of {model.n_steps:,} steps × {envs} = {_steps_per_collection(model):,}"
    return f"SAC steps all {envs} together, {_steps_per_collection(model):,} steps at a time"


def _normalized(venv, normalize: bool, algo_kwargs: dict[str, Any] | None):
    """``venv`` behind SB3's ``VecNormalize`` (observations and rewards) when ``normalize``."""
    if not normalize:
        return venv
    from stable_baselines3.common.vec_env import VecNormalize

    return VecNormalize(venv, gamma=(algo_kwargs or {}).get("gamma", 0.99))


def _episode_summary(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {"n_episodes": 0}
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return {"n_episodes": 0}
    returns = [float(r["return"]) for r in rows]
    costs = [float(r["cost"]) for r in rows]
    return {"n_episodes": len(rows), "mean_return_last10": float(np.mean(returns[-10:])),
            "total_cost": float(np.sum(costs)), "success_rate_last10":
            float(np.mean([int(r["success"]) for r in rows[-10:]]))}
