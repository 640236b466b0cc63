"""Wrappers: the RCBF-QP shield for the PettingZoo env and the Gymnasium view, and padding a mixed team's
arms to one set of spaces."""

from .padding import PadToLargestArm
from .shield import GymSafetyShield, SafetyShield

__all__ = ["SafetyShield", "GymSafetyShield", "PadToLargestArm"]
