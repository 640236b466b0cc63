"""Stable-Baselines3 models as policies: loading a saved PPO or SAC model with the ``model.json`` written
beside it, the observation normalisation it was trained with, and :func:`sb3_policy`, which runs a
centralised model on the parallel env (the ``sb3:PATH`` and ``pretrained`` policies)."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .reference import ReferencePolicy, decode_observation

__all__ = ["load_model", "normalise_observation", "sb3_policy"]


RL_EXTRA_HINT = ("install the rl extra: pip install torch --index-url https://download.pytorch.org/whl/cpu "
                 "&& pip install 'pan1-env[rl]' (or pip install -e '.[rl]' in a clone)")


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """A PPO or SAC model saved by Stable-Baselines3 (on the CPU, one torch thread) and the
    ``model.json`` beside it (empty if there is none): env arguments and observation statistics. A MAPPO
    model comes as its actor (:class:`~pan1_env.baselines.mappo.ActorOnly`), on the arm's own observation."""
    try:
        import torch
        from stable_baselines3 import PPO, SAC
    except ImportError as err:
        raise ImportError(f"running a trained model needs PyTorch and Stable-Baselines3 ({err}); "
                          f"{RL_EXTRA_HINT}") from err

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"no such model file {path}")
    torch.set_num_threads(1)
    for cls in (PPO, SAC):
        try:
            model = cls.load(path, device="cpu")
            break
        except Exception:  # noqa: BLE001 - try the next algorithm
            continue
    else:
        raise ValueError(f"{path} is not a PPO or SAC model saved by Stable-Baselines3")
    meta = json.loads(path.with_suffix(".json").read_text()) if path.with_suffix(".json").exists() else {}
    if hasattr(model.policy, "actor_inputs"):  # MAPPO: only the actor acts, on the arm's own observation
        from .mappo import ActorOnly

        model = ActorOnly(model)
    return model, meta


def normalise_observation(flat: np.ndarray, norm: dict[str, Any] | None) -> np.ndarray:
    """Observations ``(…, obs)`` standardised and clipped as VecNormalize did in training (``norm``:
    ``model.json``'s ``observation_normalization``; None leaves them as they are)."""
    if norm is None:
        return flat
    return np.clip((flat - np.asarray(norm["mean"])) / np.sqrt(np.asarray(norm["var"]) + norm["epsilon"]),
                   -norm["clip"], norm["clip"]).astype(np.float32)


def sb3_policy(path: Path, env) -> Callable[[Mapping[str, np.ndarray]], dict[str, np.ndarray]]:
    """An SB3 model as a policy on the parallel env ``env`` (observations by agent → actions by agent).

    A centralised model (trained on the concatenated observations and actions) acts for the team; a
    per-arm model (``pan1-env train --param-sharing``: one network shared by the arms) acts for each arm on
    its own observation, padded with zeros at the end to the largest arm's size and normalised with the
    per-arm statistics of ``model.json``, and the arm takes the first k entries of its action (the padding of
    :class:`~pan1_env.baselines.arm_vec_env.SB3ArmVecEnv`, on which it was trained; a MAPPO model acts through its
    actor alone). ``model.json`` beside the model
    (written by :func:`~pan1_env.baselines.training.train`) gives its observation normalisation
    (``observation_normalization``: ``mean``, ``var`` of the model's input vector, ``epsilon``, ``clip``)
    and action mode; a model trained on residual (or gain) actions runs on a velocity-mode env by adding
    the reference law to its correction (or by re-weighting the law's terms with its gains)."""
    model, meta = load_model(path)
    trained_mode, mode = meta.get("env_kwargs", {}).get("action_mode", "velocity"), env.config.action_mode
    if trained_mode != mode and (trained_mode not in ("residual", "gain") or mode != "velocity"):
        raise ValueError(f"{path} was trained with action_mode={trained_mode!r}; this env has action_mode={mode!r}")
    agents = list(env.possible_agents)
    sizes = [env.action_space(a).shape[0] for a in agents]
    obs_sizes = [env.observation_space(a).shape[0] for a in agents]
    team_shapes, arm_shapes = ((sum(obs_sizes),), (sum(sizes),)), ((max(obs_sizes),), (max(sizes),))
    shapes = (model.observation_space.shape, model.action_space.shape)
    if shapes not in (team_shapes, arm_shapes):
        raise ValueError(f"{path} was trained on spaces {shapes[0]} → {shapes[1]}; this scenario has "
                         f"{team_shapes[0]} → {team_shapes[1]} for the team, {arm_shapes[0]} → {arm_shapes[1]} "
                         "per arm (padded)")
    per_arm = shapes == arm_shapes and (shapes != team_shapes or bool(meta.get("param_sharing")))
    from pan1_env.config import DEFAULT_GAIN_RANGE, MODE_SETTINGS, FormationConfig

    norm, trained = meta.get("observation_normalization"), meta.get("env_kwargs", {})
    gate = float(trained.get("residual_gate", 0.0))
    blocked_gate = float(trained.get("blocked_gate", 0.0))
    gain_range = float(trained.get("gain_range", DEFAULT_GAIN_RANGE))
    last: dict[str, np.ndarray] = {}  # the velocity actions sent at the previous step (blocked gate)
    for name in MODE_SETTINGS.get(mode, ()) if trained_mode == mode else ():  # its actions mean what they meant
        value = float(trained.get(name, getattr(FormationConfig, name)))
        if value != getattr(env.config, name):
            raise ValueError(f"{path} was trained with {name}={value}; this env has {name}={getattr(env.config, name)}")
    reference = None
    if trained_mode != mode:
        reference = ReferencePolicy(env)  # the paper's law from observations, corrected or re-weighted
    splits = np.cumsum(sizes)[:-1]

    def model_actions(obs) -> dict[str, np.ndarray]:
        if per_arm:
            batch = np.zeros((len(agents), max(obs_sizes)), np.float32)
            for i, a in enumerate(agents):
                batch[i, : obs_sizes[i]] = obs[a]
            action, _ = model.predict(normalise_observation(batch, norm), deterministic=True)
            return {a: np.asarray(action[i, : sizes[i]], np.float32) for i, a in enumerate(agents)}
        flat = normalise_observation(np.concatenate([obs[a] for a in agents]), norm)
        action, _ = model.predict(flat, deterministic=True)
        return dict(zip(agents, np.split(np.asarray(action, np.float32), splits), strict=True))

    def policy(obs):
        actions = model_actions(obs)
        if reference is not None and trained_mode == "gain":
            return {a: reference.act(a, obs[a], gain_range ** np.clip(actions[a], -1, 1)) for a in agents}
        if reference is not None:
            nominal = reference(obs)
            parts = {a: decode_observation(obs[a], env.observation_layout) for a in agents}
            if all(not np.any(p["qd_scaled"]) for p in parts.values()):
                last.clear()  # every arm at rest: an episode's start, where nothing was blocked yet
            for a in agents:
                correction = np.clip(actions[a], -1, 1)
                if gate > 0:  # the env's residual gate, from the agent's own neighbour errors
                    errors = parts[a]["neighbour_error"]
                    correction = correction * min(1.0, (np.max(np.abs(errors), initial=0.0) / gate) ** 2)
                if blocked_gate > 0:  # the filter's change of the last command, seen as the velocity reached
                    k = len(correction)
                    blocked = np.mean((last[a] - parts[a]["qd_scaled"][-k:]) ** 2) if a in last else 0.0
                    correction = correction * min(1.0, blocked / blocked_gate)
                actions[a] = last[a] = np.clip(nominal[a] + correction, -1, 1).astype(np.float32)
        return actions

    return policy
