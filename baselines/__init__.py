"""Baseline policies: the paper's reference (nominal) law on local observations, and an adversary."""

from .adversarial import AdversarialPolicy
from .reference import ReferencePolicy, decode_observation

__all__ = ["AdversarialPolicy", "ReferencePolicy", "decode_observation"]
