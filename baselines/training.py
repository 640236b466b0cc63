"""Stable-Baselines3 training on the environments, behind the safety shield or not.

:func:`train` trains PPO or SAC either on the Gymnasium view (one policy for the whole team,
concatenated observations and actions) or, with ``param_sharing=True``, on the PettingZoo env
through SuperSuit (one policy shared by every arm; observations and actions padded to the largest
arm). It writes into ``out``:

* ``checkpoints/model_<steps>_steps.zip`` every ``checkpoint_every`` steps (plus the replay buffer
  for SAC), and ``run.json`` (the arguments);
* ``episodes.csv``: one row per finished episode: ``timesteps, return, length, cost, success``
  (cost: arm-steps inside an obstacle; success: formation error below 1 cm at the end);
* ``model.zip``: the final model.

``resume=True`` continues from the newest checkpoint in ``out`` up to ``timesteps`` in total.
Needs the ``rl`` extra (torch, stable-baselines3, supersuit); torch runs on one thread.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["train", "make_training_env", "ALGOS", "latest_checkpoint"]

ALGOS = ("ppo", "sac")


def make_training_env(scenario: str, shield: bool, seed: int, n_envs: int = 1, param_sharing: bool = False,
                      env_kwargs: dict[str, Any] | None = None):
    """The SB3 ``VecEnv`` to train on (see the module docstring)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    env_kwargs = dict(env_kwargs or {})
    if param_sharing:
        import supersuit as ss

        from pan1_env.environment import parallel_env
        from pan1_env.wrappers import SafetyShield

        penv = parallel_env(scenario, **env_kwargs)
        if shield:
            penv = SafetyShield(penv)
        penv = ss.pad_action_space_v0(ss.pad_observations_v0(penv))
        venv = ss.pettingzoo_env_to_vec_env_v1(penv)
        venv = ss.concat_vec_envs_v1(venv, n_envs, num_cpus=0, base_class="stable_baselines3")
        venv = _SeededSuperSuit(venv)
        venv.seed(seed)
        return VecMonitor(venv)

    def factory(rank: int):
        def make():
            from pan1_env.registration import CentralizedEnv
            from pan1_env.wrappers import GymSafetyShield

            env = CentralizedEnv(scenario, **env_kwargs)
            if shield:
                env = GymSafetyShield(env)
            env.reset(seed=seed + rank)
            return env

        return make

    venv = DummyVecEnv([factory(r) for r in range(n_envs)])
    venv.seed(seed)
    return VecMonitor(venv)


def _seeded_supersuit_class():
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class SeededSuperSuit(VecEnvWrapper):
        """SuperSuit's SB3 wrapper cannot be seeded with SB3 2.x (its ConcatVecEnv has no ``seed``):
        keep the seed and pass it to the next ``reset`` of the SuperSuit vector env instead."""

        def __init__(self, venv) -> None:
            super().__init__(venv)
            self._next_seed = None

        def seed(self, seed=None):
            self._next_seed = seed
            return [seed] * self.num_envs

        def reset(self):
            obs, self.venv.reset_infos = self.venv.venv.reset(seed=self._next_seed)
            self._next_seed = None
            return obs

        def step_wait(self):
            return self.venv.step_wait()

    return SeededSuperSuit


def _SeededSuperSuit(venv):  # noqa: N802 - builds the wrapper class lazily (SB3 is an extra)
    return _seeded_supersuit_class()(venv)


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


def _callbacks(out: Path, checkpoint_every: int, n_envs: int, algo: str, total: int, progress: bool):
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback

    class EpisodeLog(BaseCallback):
        """Appends a CSV row per finished episode with its return, length, cost and success."""

        def _on_training_start(self) -> None:
            self.path = out / "episodes.csv"
            new = not self.path.exists()
            self.fh = self.path.open("a", newline="")
            self.writer = csv.writer(self.fh)
            if new:
                self.writer.writerow(["timesteps", "return", "length", "cost", "success"])
            self.costs = np.zeros(self.training_env.num_envs)
            self.bar = None
            if progress:
                from tqdm import tqdm

                self.bar = tqdm(total=total, initial=self.num_timesteps, unit="step", desc=f"train {algo}")

        def _on_step(self) -> bool:
            infos = self.locals["infos"]
            for i, info in enumerate(infos):
                self.costs[i] += float(info.get("cost", 0.0))
                if "episode" in info:
                    success = bool(info.get("is_success", False))
                    self.writer.writerow([self.num_timesteps, round(float(info["episode"]["r"]), 6),
                                          int(info["episode"]["l"]), self.costs[i], int(success)])
                    self.fh.flush()
                    self.costs[i] = 0.0
            if self.bar is not None:
                self.bar.update(self.num_timesteps - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.fh.close()
            if self.bar is not None:
                self.bar.close()

    ckpt = CheckpointCallback(save_freq=max(1, checkpoint_every // n_envs), save_path=str(out / "checkpoints"),
                              name_prefix="model", save_replay_buffer=(algo == "sac"))
    return CallbackList([ckpt, EpisodeLog()])


def train(algo: str = "ppo", scenario: str = "paper_pa3_square", *, shield: bool = True, timesteps: int = 100_000,
          seed: int = 0, out: str | Path = "runs/train", resume: bool = False, n_envs: int = 1,
          param_sharing: bool = False, checkpoint_every: int = 10_000, progress: bool = True,
          env_kwargs: dict[str, Any] | None = None, algo_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train and return a summary (see the module docstring). Raises ValueError on bad arguments."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    for name, value in (("timesteps", timesteps), ("n_envs", n_envs), ("checkpoint_every", checkpoint_every)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    import torch
    from stable_baselines3 import PPO, SAC

    from pan1_env.experiment import atomic_write

    torch.set_num_threads(1)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cls = PPO if algo == "ppo" else SAC
    venv = make_training_env(scenario, shield, seed, n_envs, param_sharing, env_kwargs)
    done_steps = 0
    previous = latest_checkpoint(out) if resume else None
    if resume and previous is None and (out / "model.zip").exists():
        raise ValueError(f"nothing to resume in {out}: no checkpoints/model_*_steps.zip")
    if previous is not None:
        path, done_steps = previous
        model = cls.load(path, env=venv, device="cpu")
        buffer = path.with_name(f"model_replay_buffer_{done_steps}_steps.pkl")
        if algo == "sac" and buffer.exists():
            model.load_replay_buffer(buffer)
    else:
        if (out / "episodes.csv").exists() and not resume:
            (out / "episodes.csv").unlink()
        kwargs = {"seed": seed, "verbose": 0, "device": "cpu", **(algo_kwargs or {})}
        model = cls("MlpPolicy", venv, **kwargs)
    meta = {"algo": algo, "scenario": scenario, "shield": shield, "timesteps": timesteps, "seed": seed,
            "n_envs": n_envs, "param_sharing": param_sharing, "env_kwargs": env_kwargs or {},
            "algo_kwargs": algo_kwargs or {}}
    atomic_write(out / "run.json", lambda fh: fh.write(json.dumps(meta, indent=2) + "\n"), mode="w")
    remaining = timesteps - done_steps
    if remaining > 0:
        callbacks = _callbacks(out, checkpoint_every, venv.num_envs, algo, timesteps, progress)
        model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=(previous is None))
    atomic_write(out / "model.zip", lambda fh: model.save(fh))
    venv.close()
    return {**meta, "resumed_from": done_steps, "model": str(out / "model.zip"),
            "episodes": str(out / "episodes.csv")} | _episode_summary(out / "episodes.csv")


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
