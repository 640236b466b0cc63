"""The package's task ids and what each stands for (:func:`env_arguments`); :mod:`pan1_env.registration` registers
them with Gymnasium:

* ``pan1_env/PaperPA3Square-v0`` (Section 5.1),
* ``pan1_env/PaperMixedPA-v0`` (Section 5.2),
* ``pan1_env/RandomFormation-v0`` (a new random team every reset),
* ``pan1_env/RandomFormation-v1`` (the same teams; its filter, wherever it is switched on, uses the
  distance barrier h = ‖p − o‖ − r with κ = 0.5, ε(h̃) = 5 e^{50 h̃}, margin 0: docs/ENVIRONMENTS.md),
* ``pan1_env/WholeArmStaticFormation-v0`` (the same task with whole-arm safety: every link a capsule
  of radius 0.03 m kept out of the obstacles and the other arms),
* ``pan1_env/WholeArmStaticFormation-v1`` (the same teams behind RandomFormation-v1's filter choices),
* ``pan1_env/WholeArmFormation-v0`` (the same with obstacles moving at 0.05–0.2 m/s),
* ``pan1_env/WholeArmFormation-v1`` (the moving obstacles behind RandomFormation-v1's filter choices),
* ``pan1_env/WholeArmFormation-v2`` (moving obstacles whose whole paths keep clear of every arm's start and of
  every vertex, behind v1's filter choices with each path kept out whole: the team held still is never touched,
  and the filter treats a moving obstacle as a still capsule: docs/ENVIRONMENTS.md),
* ``pan1_env/FaultFormation-v0`` (RandomFormation-v1's teams, whose fully actuated arms each lose their
  first joint's actuator with probability ½ at a time drawn from 1–10 s; passive joints damped with
  b = 0.5 N·m·s/rad: docs/ENVIRONMENTS.md),
* ``pan1_env/FaultFormation-v1`` (FaultFormation-v0's teams behind a filter with the fault margin: every damped arm
  keeps the drift a lost actuator leaves it stoppable short of the obstacles: docs/ENVIRONMENTS.md),
* ``pan1_env/MovingFormation-v0`` (RandomFormation-v1's teams, whose formation scales between 0.8 and 1.2
  through keyframes 15 s apart; success is the error below 1 cm for the last 5 s: docs/ENVIRONMENTS.md),
* ``pan1_env/MovingFormation-v1`` (MovingFormation-v0 with the shape placed: at every keyframe it turns within
  ±0.5 rad and its centroid travels up to 0.1 m, each arm brought to its own point: docs/ENVIRONMENTS.md),
* ``pan1_env/RandomFormation-v2`` (RandomFormation-v1's task on a ring: each arm joined to the two nearest on
  each side, so at most 4 neighbours and an observation whose size does not depend on the team's; arms redrawn
  one by one, so that ``random_options={"n_arms": 32}`` draws at once: docs/ENVIRONMENTS.md),
* ``pan1_env/LargeFormation-v0`` (RandomFormation-v2 with 16 arms and 12 obstacles),

and the one-arm task ``pan1_env/PAReach-v0``. Every view takes these ids as its scenario: the config resolves them
here, below the views, which is why the table is not in :mod:`pan1_env.registration`.
"""

from __future__ import annotations

from typing import Any

__all__ = ["env_arguments", "ENV_IDS", "REACH_ENV_ID", "DEFAULT_REACH_STEPS", "MOVING_SUCCESS_HOLD"]

_WHOLE_ARM = {"bodies": "links", "link_radius": 0.03, "inter_arm": True}
_V1_FILTER = {"barrier": "distance", "decay": 50.0, "kappa": 0.5, "epsilon": 5.0}  # docs/ENVIRONMENTS.md says why
# paths clear of every start (holding still is safe), and the filter keeps each path out whole (docs/ENVIRONMENTS.md)
_CLEAR_PATHS = {"obstacle_speed": (0.05, 0.2), "clear_paths": True, "lookahead": float("inf")}
_FAULTS = {"fault_probability": 0.5, "fault_time": (1.0, 10.0), "passive_damping": 0.5}
_FAULT_MARGIN = {"fault_margin": True}  # every damped arm's drift stoppable short of the obstacles (docs/MODEL.md §5c)
_MOVING = {"formation_scale": (0.8, 1.2), "scale_period": 15.0}
_RING = {"shape": "ring", "arm_redraws": 20}
_PLACED = {"formation_turn": (-0.5, 0.5), "formation_travel": (0.0, 0.1)}  # where the law forms half the teams
MOVING_SUCCESS_HOLD = 5.0  # s: MovingFormation-v0's success is the error below tolerance for this long
ENV_IDS = {
    "pan1_env/PaperPA3Square-v0": {"scenario": "paper_pa3_square"},
    "pan1_env/PaperMixedPA-v0": {"scenario": "paper_pa_mixed_square"},
    "pan1_env/RandomFormation-v0": {"scenario": "random"},
    # the filter choices travel in the drawn scenario (its filter's barrier and decay), so that they
    # apply wherever the filter is switched on: safety_filter=True, the vector env's default, the shields
    "pan1_env/RandomFormation-v1": {"scenario": "random", "random_options": dict(_V1_FILTER)},
    "pan1_env/WholeArmStaticFormation-v0": {"scenario": "random", "random_options": _WHOLE_ARM},
    "pan1_env/WholeArmStaticFormation-v1": {"scenario": "random", "random_options": _WHOLE_ARM | _V1_FILTER},
    "pan1_env/WholeArmFormation-v0": {"scenario": "random",
                                      "random_options": _WHOLE_ARM | {"obstacle_speed": (0.05, 0.2)}},
    "pan1_env/WholeArmFormation-v1": {"scenario": "random",
                                      "random_options": _WHOLE_ARM | _V1_FILTER | {"obstacle_speed": (0.05, 0.2)}},
    "pan1_env/WholeArmFormation-v2": {"scenario": "random", "random_options": _WHOLE_ARM | _V1_FILTER | _CLEAR_PATHS},
    "pan1_env/FaultFormation-v0": {"scenario": "random", "random_options": _V1_FILTER | _FAULTS},
    "pan1_env/FaultFormation-v1": {"scenario": "random", "random_options": _V1_FILTER | _FAULTS | _FAULT_MARGIN},
    "pan1_env/MovingFormation-v0": {"scenario": "random", "random_options": _V1_FILTER | _MOVING,
                                    "success_hold": MOVING_SUCCESS_HOLD},
    "pan1_env/MovingFormation-v1": {"scenario": "random", "random_options": _V1_FILTER | _MOVING | _PLACED,
                                    "success_hold": MOVING_SUCCESS_HOLD},
    "pan1_env/RandomFormation-v2": {"scenario": "random", "random_options": _V1_FILTER | _RING},
    "pan1_env/LargeFormation-v0": {"scenario": "random",
                                   "random_options": _V1_FILTER | _RING | {"n_arms": 16, "n_obstacles": 12}},
}
REACH_ENV_ID = "pan1_env/PAReach-v0"
DEFAULT_REACH_STEPS = 200  # PAReach-v0: 10 s at the default control_dt of 0.05 s


def env_arguments(name: str, overrides: dict[str, Any] | None = None) -> tuple[str, dict[str, Any]]:
    """A scenario (built-in name, ``.toml`` path or ``"random"``) or one of the team ids of
    :data:`ENV_IDS` (with or without the ``pan1_env:`` prefix), as the parallel env's ``scenario`` and
    its further arguments, ``overrides`` on top (``random_options`` merged key by key, so that one
    option changed keeps the id's others): ``"pan1_env/WholeArmFormation-v0"`` →
    ``("random", {"random_options": {"bodies": "links", …}})``, ``"random"`` → ``("random", {})``."""
    env_id = name.removeprefix("pan1_env:") if isinstance(name, str) else name
    kwargs: dict[str, Any] = {}
    if env_id in ENV_IDS:
        kwargs = {key: dict(value) if isinstance(value, dict) else value for key, value in ENV_IDS[env_id].items()}
        name = kwargs.pop("scenario")
    for key, value in (overrides or {}).items():
        if key == "random_options" and isinstance(value, dict) and isinstance(kwargs.get(key), dict):
            kwargs[key] = kwargs[key] | value
        else:
            kwargs[key] = value
    return name, kwargs
