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
(:class:`~pan1_env.baselines.AdversarialPolicy`), the family ``sb3:PATH`` (a Stable-Baselines3
PPO or SAC model trained by ``pan1-env train`` on the same scenario, run deterministically: a centralised
model acts for the team, a ``--param-sharing`` one for each arm on its own observation), ``pretrained``
(the shipped centralised model for the env's task) and ``marl`` (the shipped decentralised one).
Registration is per process (a plain dict; not thread-safe).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from .adversarial import AdversarialPolicy
from .reference import ReferencePolicy
from .sb3 import load_model, normalise_observation, sb3_policy

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
    if env.config.action_mode != "velocity":
        raise ValueError("the reference policy outputs velocities: use action_mode='velocity'")
    return ReferencePolicy(env)


def _sb3(env, seed: int | None, path: str) -> Policy:
    path = Path(path)
    if not path.exists():
        raise ValueError(f"policy 'sb3:{path}': no such model file {path}")
    return sb3_policy(path, env)


def _circulation(env, seed: int | None) -> Policy:
    from .circulation import CirculatingPolicy

    return CirculatingPolicy(env)


register_policy("reference", _reference)
register_policy("circulation", _circulation)
register_policy("zero", lambda env, seed: ZeroPolicy(env))
register_policy("random", lambda env, seed: RandomPolicy(env, seed))
register_policy("adversarial", lambda env, seed: AdversarialPolicy(env))
register_policy("sb3:", _sb3, metavar="PATH")


def _pretrained(env, seed: int | None, name: str | None = None) -> Policy:
    from .shipped import model_for, pretrained

    return pretrained(model_for(env) if name is None else name, env)


register_policy("pretrained", _pretrained)  # the shipped model trained for the env's task
register_policy("pretrained:", _pretrained, metavar="NAME")


def _marl(env, seed: int | None) -> Policy:
    from .shipped import model_for, pretrained

    return pretrained(model_for(env, decentralised=True), env)


register_policy("marl", _marl)  # the shipped decentralised model (shared by the arms) for the env's task

BUILTIN_POLICIES = ("reference", "circulation", "zero", "random", "adversarial")
"""The built-in names besides the ``sb3:PATH`` family."""
