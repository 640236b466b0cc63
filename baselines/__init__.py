"""Baseline policies: the paper's reference (nominal) law on local observations."""

from .reference import ReferencePolicy, decode_observation

__all__ = ["ReferencePolicy", "decode_observation"]
