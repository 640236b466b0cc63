"""Safety wrappers: the RCBF-QP shield for the PettingZoo env and the Gymnasium view."""

from .shield import GymSafetyShield, SafetyShield, shield_parameters

__all__ = ["SafetyShield", "GymSafetyShield", "shield_parameters"]
