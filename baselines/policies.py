"""Policies by name: the :class:`Policy` protocol and the registry the benchmark and ``pan1-env animate`` use.

A policy maps the live agents' observations to their actions (the parallel env's dicts). A
*factory* builds one for an env: ``factory(env, seed) -> Policy``, where ``env`` is the parallel
env, wrapped (e.g. in :class:`~pan1_env.wrappers.SafetyShield`) or not, so a factory and its policy
should read only public attributes (``possible_agents``, ``scenario``, ``observation_layout``,
``action_space(agent)``, ``max_joint_speed``, ``action_mode``, …; PettingZoo's wrappers refuse
names starting with ``_``). Register a factory under a name and every consumer of names knows it::

    from pan1_env.baselines import make_policy, register_policy

    register_policy("mine", lambda env, seed: MyPolicy(env, seed))
    policy = make_policy("mine", env, seed=0)   # also: run_benchmark(..., ["mine"]), pan1-env animate

A name ending in ``":"`` registers a *family*: ``make_policy("sb3:PATH", env, seed)`` calls the
``"sb3:"`` factory as ``factory(env, seed, "PATH")``. Built in: ``reference``
(:class:`~pan1_env.baselines.ReferencePolicy`, velocity mode), ``zero`` (:class:`ZeroPolicy`),
``random`` (:class:`RandomPolicy`, seeded), ``adversarial``
(:class:`~pan1_env.baselines.AdversarialPolicy`) and the family ``sb3:PATH`` (a Stable-Baselines3
PPO or SAC model trained on the centralised Gymnasium view of the same scenario, run
deterministically). Registration is per process (a plain dict; not thread-safe).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .adversarial import AdversarialPolicy
from .reference import ReferencePolicy, decode_observation

__all__ = ["Policy", "PolicyFactory", "ZeroPolicy", "RandomPolicy", "register_policy", "unregister_policy",
           "registered_policies", "check_policy_name", "make_policy", "BUILTIN_POLICIES", "load_model",
           "normalise_observation"]


@runtime_checkable
class Policy(Protocol):
    """Anything that maps ``{agent: observation}`` to ``{agent: action}`` (float32 arrays in [−1, 1])."""

    def __call__(self, observations: Mapping[str, np.ndarray], /) -> dict[str, np.ndarray]: ...


PolicyFactory = Callable[..., Policy]
"""``factory(env, seed) -> Policy``; a family's factory (name ending in ``":"``) gets ``(env, seed, argument)``."""

_FACTORIES: dict[str, PolicyFactory] = {}
_METAVARS: dict[str, str] = {}


class ZeroPolicy:
    """Zero action for every agent (the arms hold still in velocity mode, coast in torque mode)."""

    def __init__(self, env) -> None:
        self.env = env

    def __call__(self, observations: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: np.zeros(self.env.action_space(a).shape, np.float32) for a in observations}


class RandomPolicy:
    """Uniform random actions in [−1, 1], from ``numpy.random.default_rng(seed)``."""

    def __init__(self, env, seed: int | None = None) -> None:
        self.env = env
        self.rng = np.random.default_rng(seed)

    def __call__(self, observations: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: self.rng.uniform(-1, 1, self.env.action_space(a).shape).astype(np.float32) for a in observations}


def register_policy(name: str, factory: PolicyFactory, *, overwrite: bool = False, metavar: str = "ARG") -> None:
    """Make ``factory`` available as ``name`` to :func:`make_policy` (and so to the benchmark and the CLI).

    Args:
        name: a non-empty name without whitespace or commas (the CLI splits lists on commas); a
            ``":"`` may appear only as the last character, which registers a family (see the module
            docstring).
        factory: ``factory(env, seed) -> Policy`` (a family's: ``factory(env, seed, argument)``).
        overwrite: replace an existing registration instead of raising ``ValueError``.
        metavar: how error messages show a family's argument (``sb3:PATH``).
    """
    if not isinstance(name, str) or not name or name == ":" or any(c.isspace() or c == "," for c in name) \
            or ":" in name[:-1]:
        raise ValueError(f"policy name must be a non-empty string without whitespace, commas or inner ':', "
                         f"got {name!r}")
    if not callable(factory):
        raise TypeError(f"policy factory for {name!r} must be callable, got {factory!r}")
    if name in _FACTORIES and not overwrite:
        raise ValueError(f"policy {name!r} is already registered; pass overwrite=True to replace it")
    _FACTORIES[name] = factory
    _METAVARS[name] = metavar


def unregister_policy(name: str) -> None:
    """Remove a registered name (``ValueError`` if it is not registered)."""
    if name not in _FACTORIES:
        raise ValueError(f"policy {name!r} is not registered")
    del _FACTORIES[name], _METAVARS[name]


def registered_policies() -> tuple[str, ...]:
    """The registered names, in registration order, families shown with their argument (``sb3:PATH``)."""
    return tuple(f"{n}{_METAVARS[n]}" if n.endswith(":") else n for n in _FACTORIES)


def _resolve(name: str) -> tuple[PolicyFactory, str | None]:
    if isinstance(name, str):
        if name in _FACTORIES and not name.endswith(":"):
            return _FACTORIES[name], None
        prefix, sep, argument = name.partition(":")
        if sep and argument and prefix + sep in _FACTORIES:
            return _FACTORIES[prefix + sep], argument
    raise ValueError(f"unknown policy {name!r}; registered: {', '.join(registered_policies())}")


def check_policy_name(name: str) -> None:
    """Raise ``ValueError`` (listing the registered names) unless :func:`make_policy` knows ``name``."""
    _resolve(name)


def make_policy(name: str, env, seed: int | None = 0) -> Policy:
    """The policy registered as ``name`` (or in the family ``name``'s prefix names), built for ``env``."""
    factory, argument = _resolve(name)
    policy = factory(env, seed) if argument is None else factory(env, seed, argument)
    if not callable(policy):
        raise TypeError(f"the factory of policy {name!r} returned {type(policy).__name__}, not a callable policy")
    return policy


def _reference(env, seed: int | None) -> Policy:
    if env.action_mode != "velocity":
        raise ValueError("the reference policy outputs velocities: use action_mode='velocity'")
    return ReferencePolicy(env)


def _sb3(env, seed: int | None, path: str) -> Policy:
    path = Path(path)
    if not path.exists():
        raise ValueError(f"policy 'sb3:{path}': no such model file {path}")
    return _sb3_policy(path, env)


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """A PPO or SAC model saved by Stable-Baselines3 (on the CPU, one torch thread) and the
    ``model.json`` beside it (empty if there is none): env arguments and observation statistics."""
    import torch
    from stable_baselines3 import PPO, SAC

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
    return model, meta


def normalise_observation(flat: np.ndarray, norm: dict[str, Any] | None) -> np.ndarray:
    """Observations ``(…, obs)`` standardised and clipped as VecNormalize did in training (``norm``:
    ``model.json``'s ``observation_normalization``; None leaves them as they are)."""
    if norm is None:
        return flat
    return np.clip((flat - np.asarray(norm["mean"])) / np.sqrt(np.asarray(norm["var"]) + norm["epsilon"]),
                   -norm["clip"], norm["clip"]).astype(np.float32)


def _sb3_policy(path: Path, env) -> Policy:
    """A centralised SB3 model as a policy. ``model.json`` beside the model (written by
    :func:`~pan1_env.baselines.training.train`) gives its observation normalisation and action mode;
    a model trained on residual (or gain) actions runs on a velocity-mode env by adding the reference law
    to its correction (or by re-weighting the law's terms with its gains)."""
    model, meta = load_model(path)
    agents = list(env.possible_agents)
    sizes = [env.action_space(a).shape[0] for a in agents]
    n_obs = sum(env.observation_space(a).shape[0] for a in agents)
    if model.observation_space.shape != (n_obs,) or model.action_space.shape != (sum(sizes),):
        raise ValueError(f"{path} was trained on spaces {model.observation_space.shape} → "
                         f"{model.action_space.shape}, this scenario has ({n_obs},) → ({sum(sizes)},)")
    from pan1_env.config import DEFAULT_GAIN_RANGE

    norm, trained = meta.get("observation_normalization"), meta.get("env_kwargs", {})
    trained_mode = trained.get("action_mode", "velocity")
    gate = float(trained.get("residual_gate", 0.0))
    blocked_gate = float(trained.get("blocked_gate", 0.0))
    gain_range = float(trained.get("gain_range", DEFAULT_GAIN_RANGE))
    last: dict[str, np.ndarray] = {}  # the velocity actions sent at the previous step (blocked gate)
    if trained_mode == env.action_mode == "gain" and env.gain_range != gain_range:
        raise ValueError(f"{path} was trained with gain_range={gain_range}; this env has gain_range={env.gain_range}")
    reference = None
    if trained_mode != env.action_mode:
        if trained_mode not in ("residual", "gain") or env.action_mode != "velocity":
            raise ValueError(f"{path} was trained with action_mode={trained_mode!r}; this env has "
                             f"action_mode={env.action_mode!r}")
        reference = ReferencePolicy(env)  # the paper's law from observations, corrected or re-weighted
    splits = np.cumsum(sizes)[:-1]

    def policy(obs):
        flat = normalise_observation(np.concatenate([obs[a] for a in agents]), norm)
        action, _ = model.predict(flat, deterministic=True)
        actions = dict(zip(agents, np.split(np.asarray(action, np.float32), splits), strict=True))
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


register_policy("reference", _reference)
register_policy("zero", lambda env, seed: ZeroPolicy(env))
register_policy("random", lambda env, seed: RandomPolicy(env, seed))
register_policy("adversarial", lambda env, seed: AdversarialPolicy(env))
register_policy("sb3:", _sb3, metavar="PATH")


def _pretrained(env, seed: int | None, name: str | None = None) -> Policy:
    from .shipped import model_for, pretrained

    return pretrained(model_for(env) if name is None else name, env)


register_policy("pretrained", _pretrained)  # the shipped model trained for the env's task
register_policy("pretrained:", _pretrained, metavar="NAME")

BUILTIN_POLICIES = ("reference", "zero", "random", "adversarial")
"""The built-in names besides the ``sb3:PATH`` family."""
