"""Batched evaluation of a policy on held-out teams, and the training callback that runs it.

:func:`evaluate` runs one episode per seed, all at once in the batched engine
(:class:`~pan1_env.vector.Pan1VectorEnv`, copy b reset with seed ``seeds[b]``, so copy b meets the
same team as ``parallel_env(scenario).reset(seed=seeds[b])``), and reports per episode the final
formation error, the return, the cost and the time to formation; :func:`summarise` turns that into
success rates at 1, 2 and 5 cm. A policy here maps the batch of flat observations ``(B, obs)`` to
actions ``(B, act)`` (the Gymnasium view's spaces), e.g. ``lambda obs: model.predict(obs, True)[0]``.

:class:`EvalCallback` (SB3) evaluates the model being trained, deterministically and with the training
run's current observation statistics, every ``every`` steps on fixed held-out seeds, and appends a row
to ``eval.csv``: stochastic training episodes say little about success at 1 cm, where the exploration
noise alone moves the end-effectors by more than that.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pan1_env.config import SUCCESS_TOLERANCE
from pan1_env.safety import FilterParams

__all__ = ["evaluate", "summarise", "model_policy", "law_policy", "EVAL_SEEDS", "TOLERANCES", "eval_callback",
           "LAW_MODES"]

# held out: one-copy seeds, which no training copy's spawned stream is (pan1_env.core.copy_generator)
EVAL_SEEDS = range(1_000_000, 1_000_064)
# m: success at 1 cm is the task's; 2 and 5 cm show how close the rest came
TOLERANCES = (SUCCESS_TOLERANCE, 0.02, 0.05)
LAW_MODES = ("residual", "gain", "circulation")  #: the action modes whose zero action is the paper's law
EVAL_FIELDS = ("timesteps", "success_1cm", "success_2cm", "success_5cm", "median_final_error_m", "mean_return",
               "cost", "mean_time_to_formation_s")


def evaluate(policy: Callable[[np.ndarray], np.ndarray], scenario: str = "random", seeds: Sequence[int] = EVAL_SEEDS,
             *, shield: bool | FilterParams = True, env_kwargs: dict[str, Any] | None = None) -> dict[str, np.ndarray]:
    """One episode per seed, batched. Returns per-episode arrays: ``final_error`` (m, the largest edge
    error at the end), ``success`` (the task's own rule at the end, ``is_success``: the error below 1 cm, held for
    ``success_hold`` s on a moving formation), ``return`` (sum of the mean agent reward), ``cost`` (arm-steps inside
    an obstacle),
    ``time_to_formation`` (s after which the error stayed below 1 cm; NaN if it never did),
    ``min_clearance`` (m, the smallest over the episode's sub-steps and arms) and, behind the shield,
    ``intervention_rate`` and ``fallback_rate`` (the fraction of steps in which the filter changed some
    arm's command, or fell back for some arm). ``shield``: the vector env's ``safety_filter`` (``True``, ``False``
    or a :class:`~pan1_env.safety.FilterParams`). A policy with an ``attach(venv)`` method (one that reads the
    copies' teams, such as :class:`~pan1_env.baselines.adversarial.VectorAdversary`) is first attached to the
    vector env built here."""
    from pan1_env.vector import Pan1VectorEnv

    seeds = [int(s) for s in seeds]
    venv = Pan1VectorEnv(scenario, len(seeds), safety_filter=shield, **(env_kwargs or {}))
    if hasattr(policy, "attach"):
        policy.attach(venv)
    B, dt = len(seeds), venv.dt
    obs, _ = venv.reset(seed=seeds)
    live = np.ones(B, dtype=bool)
    ret, cost, clearance = np.zeros(B), np.zeros(B), np.full(B, np.inf)
    intervened, fallback, length = np.zeros(B), np.zeros(B), np.zeros(B)
    final, last_failure = np.full(B, np.nan), np.zeros(B)
    success = np.zeros(B, dtype=bool)
    steps = 0
    while live.any():
        obs, reward, terminated, truncated, infos = venv.step(np.asarray(policy(obs), dtype=np.float32))
        steps += 1
        # the step's infos describe the step's end, before copies that ended were reset
        ret += np.where(live, reward, 0.0)
        cost += np.where(live, infos["cost"], 0.0)
        clearance = np.where(live, np.minimum(clearance, infos["min_clearance"]), clearance)
        length += live
        if shield is not False:
            intervened += live & infos["shield_intervened"]
            fallback += live & infos["shield_fallback"]
        error = infos["formation_error"]
        last_failure = np.where(live & (error >= TOLERANCES[0]), steps * dt, last_failure)
        ended = live & (terminated | truncated)
        final[ended] = error[ended]
        success[ended] = infos["is_success"][ended]
        live &= ~ended
    venv.close()
    time = np.where(final < TOLERANCES[0], last_failure, np.nan)
    out = {"final_error": final, "success": success, "return": ret, "cost": cost, "time_to_formation": time,
           "min_clearance": clearance}
    if shield is not False:
        out |= {"intervention_rate": intervened / length, "fallback_rate": fallback / length}
    return out


def model_policy(path: str | Path, env_kwargs: dict[str, Any] | None = None
                 ) -> tuple[Callable[[np.ndarray], np.ndarray], dict[str, Any]]:
    """A model saved by ``pan1-env train`` as a policy for :func:`evaluate` (deterministic, with its
    observation statistics), and the env arguments to evaluate it with: those it was trained with
    (``model.json``), or ``env_kwargs`` (another team size of its task, say): ``evaluate(policy, run_scenario,
    seeds, env_kwargs=env_kwargs)``. A model trained with ``param_sharing`` acts for each arm on the arm's own
    observation; ValueError if that env gives its arms observations of another size than the model's."""
    from .policies import load_model, normalise_observation

    model, meta = load_model(path)
    kwargs = dict(meta.get("env_kwargs", {}) if env_kwargs is None else env_kwargs)
    norm = meta.get("observation_normalization")
    arms = None
    if meta.get("param_sharing"):  # a model shared by the arms: each arm acts on its own observation
        from .arm_vec_env import SB3ArmVecEnv

        arms = SB3ArmVecEnv(meta["scenario"], 1, **kwargs)
        wanted = model.observation_space.shape[0]
        if arms.observation_space.shape[0] != wanted:
            raise ValueError(f"{path}: the model reads an arm observation of {wanted} numbers, this env gives "
                             f"{arms.observation_space.shape[0]} (an observation that grows with the team: train on a "
                             "ring task such as pan1_env/RandomFormation-v2 to serve teams of other sizes)")

    policy = _team_policy(lambda obs: model.predict(obs, deterministic=True)[0], arms,
                          lambda obs: normalise_observation(obs, norm))
    return policy, kwargs


def law_policy(scenario: str, env_kwargs: dict[str, Any]) -> Callable[[np.ndarray], np.ndarray]:
    """The paper's law as a policy for :func:`evaluate` in an env whose actions correct or re-weight it
    (``action_mode`` ``"residual"``, ``"gain"`` or ``"circulation"``): the zero action of the team's size, which
    leaves it as it is."""
    from pan1_env.vector import Pan1VectorEnv

    if env_kwargs.get("action_mode") not in LAW_MODES:
        raise ValueError(f"the zero action is the paper's law only with action_mode 'residual', 'gain' or "
                         f"'circulation', not {env_kwargs.get('action_mode', 'velocity')!r}")
    size = Pan1VectorEnv(scenario, 1, **env_kwargs).single_action_space.shape[0]
    return lambda obs: np.zeros((len(obs), size), np.float32)


def _team_policy(predict: Callable[[np.ndarray], np.ndarray], arms, normalise: Callable[[np.ndarray], np.ndarray]):
    """A model's ``predict`` as a policy on the team views' flat observations: normalised first, and for a model
    shared by the arms (``arms``: its :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv`) cut into each arm's
    observation, its per-arm actions joined into the team's."""
    def policy(obs: np.ndarray) -> np.ndarray:
        if arms is not None:
            obs = arms.arm_observations(obs)
            if arms.critic_state:  # MAPPO in training: the model's full row, which its actor reads the start of
                from .mappo import with_critic_entries

                obs = with_critic_entries(obs, arms.observation_space.shape[0] - arms.local_size)
        action = predict(normalise(obs))
        return action if arms is None else arms.team_actions(action)

    return policy


def summarise(result: dict[str, np.ndarray]) -> dict[str, float]:
    """Success rates at each of :data:`TOLERANCES`, the median final error, mean return, total cost and
    the mean time to formation of the successful episodes (NaN if none)."""
    err, times = result["final_error"], result["time_to_formation"]
    out = {f"success_{round(100 * tol)}cm": float(np.mean(err < tol)) for tol in TOLERANCES}
    out |= {"median_final_error_m": float(np.median(err)), "mean_return": float(np.mean(result["return"])),
            "cost": float(np.sum(result["cost"])),
            "mean_time_to_formation_s": float(np.nanmean(times)) if np.isfinite(times).any() else float("nan")}
    return out


def eval_callback(out: Path, every: int, scenario: str, shield: bool, env_kwargs: dict[str, Any] | None,
                  seeds: Sequence[int] = EVAL_SEEDS, progress: bool = False):
    """The SB3 callback that evaluates the model every ``every`` steps (at the first rollout boundary
    after) and appends to ``out/eval.csv``; built lazily because SB3 is an extra. With ``progress`` it
    says so beside the progress bar (an evaluation takes seconds)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from .arm_vec_env import SB3ArmVecEnv
    from .mixed_vec_env import SB3MixedArmVecEnv

    class EvalCallback(BaseCallback):
        def _on_training_start(self) -> None:
            self.path = Path(out) / "eval.csv"
            self.own_size = None  # built at the first evaluation of a run on mixed team sizes
            self.next = (self.num_timesteps // every + 1) * every if self.num_timesteps else 0

        def _on_rollout_start(self) -> None:
            if self.num_timesteps >= self.next:
                self.run()
                self.next = (self.num_timesteps // every + 1) * every

        def _on_step(self) -> bool:
            return True

        def run(self) -> None:
            if progress:
                from tqdm import tqdm

                tqdm.write(f"evaluating at {self.num_timesteps} steps on {len(seeds)} held-out episodes …")
            env = self.model.get_env()
            norm = env if isinstance(env, VecNormalize) else None
            arms = env.unwrapped if isinstance(env.unwrapped, SB3ArmVecEnv) else None
            if isinstance(env.unwrapped, SB3MixedArmVecEnv):  # the arm view of the evaluation's own team size
                if self.own_size is None:
                    self.own_size = SB3ArmVecEnv(scenario, 1, **(env_kwargs or {}))
                arms = self.own_size
            policy = _team_policy(lambda obs: self.model.predict(obs, deterministic=True)[0], arms,
                                  (lambda obs: obs) if norm is None else norm.normalize_obs)
            row = {"timesteps": self.num_timesteps} | summarise(evaluate(policy, scenario, seeds, shield=shield,
                                                                         env_kwargs=env_kwargs))
            new = not self.path.exists()
            with self.path.open("a", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=EVAL_FIELDS)
                if new:
                    writer.writeheader()
                writer.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})

    return EvalCallback()
