"""PPO-Lagrangian over Stable-Baselines3's PPO: constrained RL without the shield (needs the ``rl`` extra).

The constrained problem is  max_π J_r(π)  subject to  J_c(π) ≤ d,  where J_c is the expected episode
cost (here: arm-steps inside an obstacle per episode, ``infos[i]["cost"]`` summed over an episode) and
d is ``cost_limit``. Its Lagrangian relaxation  min_{λ≥0} max_π J_r − λ (J_c − d)  is solved by
alternating two steps:

* **policy step** — :class:`CostPenalisedVecEnv` replaces every step's reward r by

      r' = (r − λ·c) / (1 + λ),

  c being that step's cost, with the current multiplier λ. GAE is linear in the rewards, so PPO's
  advantages are the cost-penalised advantages (A_r − λ·A_c) / (1 + λ) of one critic trained on r'; the
  1 / (1 + λ) keeps the reward scale bounded as λ grows (as OmniSafe's PPOLag does). The original reward
  stays in ``infos[i]["reward_unpenalised"]``; an ended episode's cost is put in
  ``infos[i]["episode_cost"]``.
* **multiplier step** — :class:`LagrangianCallback` runs after each rollout (``_on_rollout_end``, after
  SB3 has computed that rollout's advantages with the λ in force while it was collected) and does
  projected gradient descent on λ:

      λ ← max(0, λ + lagrangian_lr · (Ĵ_c − cost_limit)).

  Ĵ_c is the mean cost of the episodes that ended during the rollout. If none ended (long episodes,
  short rollouts), it is the rollout's mean cost per step per copy times the mean length of the episodes
  ended so far, or, before any has ended, times ``episode_length`` (e.g. the time limit); without
  that, λ is left unchanged until an episode ends.

λ starts at 0 by default: until a cost is seen the learner is exactly PPO on the task reward, so the
comparison with unconstrained PPO is clean, and λ rises only from measured violations (Safety Gym's and
OmniSafe's PPO-Lagrangian start at or near 0 too). ``cost_limit`` defaults to 1 arm-step per episode:
costs are counts, so a limit of 0 leaves Ĵ_c − d ≥ 0 and λ could only grow; 1 is near-zero but gives λ a
fixed point. Costs reach thousands of arm-steps per episode while d is 1, so λ rises far faster than it
falls (by at most lagrangian_lr · d per rollout): keep ``lagrangian_lr`` small.

Meant for PPO (on-policy): an off-policy replay buffer would keep rewards penalised with stale λ. The
multiplier and the per-copy running costs are in ``state_dict()`` / ``load_state_dict()`` of the
wrapper, so a checkpoint can carry them; the callback appends ``timesteps, lambda, episode_cost`` (λ
after the update, the Ĵ_c it used, empty when none) to ``lagrangian.csv`` in ``log_dir`` if given::

    venv = CostPenalisedVecEnv(VecMonitor(SB3VecEnv("paper_pa3_square", 64, safety_filter=False)))
    PPO("MlpPolicy", venv).learn(100_000, callback=LagrangianCallback(venv, log_dir="runs/ppo_lag"))
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

__all__ = ["CostPenalisedVecEnv", "LagrangianCallback", "DEFAULT_COST_LIMIT", "DEFAULT_LAGRANGIAN_LR"]

DEFAULT_COST_LIMIT = 1.0  # arm-steps inside an obstacle per episode
DEFAULT_LAGRANGIAN_LR = 0.01


class CostPenalisedVecEnv(VecEnvWrapper):
    """Rewards r → (r − λ·c) / (1 + λ) with c = ``infos[i]["cost"]``; holds λ and its update (module docstring).

    Args:
        venv: the vector env; every step's per-copy infos must carry ``cost``.
        cost_limit: d, the allowed expected episode cost (≥ 0).
        lagrangian_lr: the multiplier's step size (> 0).
        initial_lambda: λ at the start (≥ 0).
        episode_length: the episode length that scales the cost per step into Ĵ_c before any episode
            has ended (None: no estimate until then).
    """

    def __init__(self, venv: VecEnv, cost_limit: float = DEFAULT_COST_LIMIT,
                 lagrangian_lr: float = DEFAULT_LAGRANGIAN_LR, initial_lambda: float = 0.0,
                 episode_length: int | None = None) -> None:
        for name, value, positive in (("cost_limit", cost_limit, False), ("lagrangian_lr", lagrangian_lr, True),
                                      ("initial_lambda", initial_lambda, False)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value < 0 or (positive and value == 0):
                raise ValueError(f"{name} must be a finite {'positive' if positive else 'non-negative'} "
                                 f"number, got {value!r}")
        if episode_length is not None and (isinstance(episode_length, bool) or not isinstance(episode_length, int)
                                           or episode_length < 1):
            raise ValueError(f"episode_length must be a positive integer or None, got {episode_length!r}")
        super().__init__(venv)
        self.episode_length = episode_length
        self.cost_limit, self.lagrangian_lr = float(cost_limit), float(lagrangian_lr)
        self.lagrange_multiplier = float(initial_lambda)
        n = self.num_envs
        self._episode_costs, self._episode_lengths = np.zeros(n), np.zeros(n, dtype=np.int64)
        self._ended_costs: list[float] = []  # episodes ended since the last multiplier update
        self._rollout_cost, self._rollout_steps = 0.0, 0  # per-copy steps since the last update
        self._ended_length_sum, self._ended_count = 0, 0  # every episode ended so far

    def reset(self) -> Any:
        self._episode_costs[:] = 0.0
        self._episode_lengths[:] = 0
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        try:
            costs = np.array([float(info["cost"]) for info in infos])
        except KeyError:
            raise KeyError("CostPenalisedVecEnv needs a per-copy 'cost' in every step's infos") from None
        lam = self.lagrange_multiplier
        penalised = ((rewards - lam * costs) / (1.0 + lam)).astype(rewards.dtype)
        self._episode_costs += costs
        self._episode_lengths += 1
        self._rollout_cost += float(costs.sum())
        self._rollout_steps += len(costs)
        for i, info in enumerate(infos):
            info["reward_unpenalised"] = float(rewards[i])
            if dones[i]:
                info["episode_cost"] = float(self._episode_costs[i])
                self._ended_costs.append(float(self._episode_costs[i]))
                self._ended_length_sum += int(self._episode_lengths[i])
                self._ended_count += 1
                self._episode_costs[i], self._episode_lengths[i] = 0.0, 0
        return obs, penalised, dones, infos

    def episode_cost_estimate(self) -> float | None:
        """Ĵ_c since the last update (module docstring), or None if there is nothing to estimate it from."""
        if self._ended_costs:
            return float(np.mean(self._ended_costs))
        length = self._ended_length_sum / self._ended_count if self._ended_count else self.episode_length
        if length is None or not self._rollout_steps:
            return None
        return self._rollout_cost / self._rollout_steps * length

    def update_multiplier(self) -> float | None:
        """λ ← max(0, λ + lr·(Ĵ_c − d)); starts the next estimation window. Returns the Ĵ_c used (or None)."""
        estimate = self.episode_cost_estimate()
        if estimate is not None:
            step = self.lagrange_multiplier + self.lagrangian_lr * (estimate - self.cost_limit)
            self.lagrange_multiplier = max(0.0, step)
        self._ended_costs.clear()
        self._rollout_cost, self._rollout_steps = 0.0, 0
        return estimate

    def state_dict(self) -> dict[str, Any]:
        """λ, the update's parameters and the running costs (plain numbers and arrays: picklable)."""
        return {"lambda": self.lagrange_multiplier, "cost_limit": self.cost_limit,
                "lagrangian_lr": self.lagrangian_lr, "episode_length": self.episode_length,
                "episode_costs": self._episode_costs.copy(), "episode_lengths": self._episode_lengths.copy(),
                "ended_costs": list(self._ended_costs), "rollout_cost": self._rollout_cost,
                "rollout_steps": self._rollout_steps, "ended_length_sum": self._ended_length_sum,
                "ended_count": self._ended_count}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if len(state["episode_costs"]) != self.num_envs:
            raise ValueError(f"state is for {len(state['episode_costs'])} copies, this env has {self.num_envs}")
        self.lagrange_multiplier = float(state["lambda"])
        self.cost_limit, self.lagrangian_lr = float(state["cost_limit"]), float(state["lagrangian_lr"])
        self.episode_length = state["episode_length"]
        self._episode_costs = np.array(state["episode_costs"], dtype=float)
        self._episode_lengths = np.array(state["episode_lengths"], dtype=np.int64)
        self._ended_costs = [float(c) for c in state["ended_costs"]]
        self._rollout_cost, self._rollout_steps = float(state["rollout_cost"]), int(state["rollout_steps"])
        self._ended_length_sum, self._ended_count = int(state["ended_length_sum"]), int(state["ended_count"])


class LagrangianCallback(BaseCallback):
    """Updates ``penalised_env``'s λ after every rollout; logs it to SB3's logger and ``log_dir/lagrangian.csv``."""

    def __init__(self, penalised_env: CostPenalisedVecEnv, log_dir: str | Path | None = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.penalised_env = penalised_env
        self.log_path = None if log_dir is None else Path(log_dir) / "lagrangian.csv"

    def _on_training_start(self) -> None:
        if self.log_path is not None and not self.log_path.exists():
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            with self.log_path.open("w", newline="") as fh:
                csv.writer(fh).writerow(["timesteps", "lambda", "episode_cost"])

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        estimate = self.penalised_env.update_multiplier()
        lam = self.penalised_env.lagrange_multiplier
        self.logger.record("lagrangian/lambda", lam)
        if estimate is not None:
            self.logger.record("lagrangian/episode_cost", estimate)
        if self.log_path is not None:
            with self.log_path.open("a", newline="") as fh:
                csv.writer(fh).writerow([self.num_timesteps, repr(lam), "" if estimate is None else repr(estimate)])
