"""Baseline policies: the paper's reference (nominal) law on local observations, an adversary, and
the policy registry (:mod:`.policies`: the :class:`Policy` protocol, :func:`register_policy`,
:func:`make_policy`). Every policy works on a wrapped or unwrapped parallel env (public attributes only)."""

from .adversarial import AdversarialPolicy, VectorAdversary
from .policies import (
    BUILTIN_POLICIES,
    Policy,
    PolicyFactory,
    RandomPolicy,
    ZeroPolicy,
    check_policy_name,
    make_policy,
    register_policy,
    registered_policies,
    unregister_policy,
)
from .reference import ReferencePolicy, decode_observation
from .shipped import pretrained

__all__ = ["AdversarialPolicy", "VectorAdversary", "ReferencePolicy", "ZeroPolicy", "RandomPolicy",
           "decode_observation", "Policy", "PolicyFactory", "register_policy", "unregister_policy",
           "registered_policies", "check_policy_name", "make_policy", "BUILTIN_POLICIES", "pretrained"]
