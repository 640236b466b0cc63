"""What the TorchRL view (:mod:`pan1_env.marl`) holds in its tensordicts: the specs of the env core's outputs as one
group ``arms`` (:data:`GROUP`) of B copies × N arms, and the conversion of the core's infos to tensors. Needs the
``marl`` extra, as :mod:`pan1_env.marl`, whose module docstring lists the keys."""

from __future__ import annotations

import numpy as np
import torch
from torchrl.data import Bounded, Composite, Unbounded

from .core import FormationCore

__all__ = ["GROUP", "output_specs", "info_tensor"]

GROUP = "arms"  #: the one group of agents: every arm of a team, whatever its kind


def output_specs(core: FormationCore, infos: dict[str, np.ndarray], arm_keys: list[str],
                 copy_keys: list[str]) -> dict[str, Composite]:
    """The ``observation``, ``action``, ``reward`` and ``done`` specs of the TorchRL view of ``core``, with the infos
    ``arm_keys`` per arm and ``copy_keys`` per copy (``infos``: a start's, for their shapes and dtypes)."""
    B, N, k = core.copies, len(core.agents), core.action_width
    low, high = core.padded_observation_bounds()
    size = low.shape[1]
    low, high = torch.from_numpy(low).expand(B, N, size), torch.from_numpy(high).expand(B, N, size)
    arm = {"observation": Bounded(low, high, shape=(B, N, size), dtype=torch.float32),
           "action_mask": Bounded(False, True, shape=(B, N, k), dtype=torch.bool),
           "cost": Unbounded(shape=(B, N, 1), dtype=torch.float32),
           "info": Composite({key: Unbounded(shape=(B, N, *infos[key].shape[2:]), dtype=_info_dtype(infos[key]))
                              for key in arm_keys}, shape=(B, N))}
    observation = Composite({
        GROUP: Composite(arm, shape=(B, N)),
        "state": Unbounded(shape=(B, core.state_size), dtype=torch.float32),
        "info": Composite({key: Unbounded(shape=(B,), dtype=_info_dtype(infos[key])) for key in copy_keys},
                          shape=(B,))}, shape=(B,))
    action = Composite({GROUP: Composite({"action": Bounded(-1.0, 1.0, shape=(B, N, k), dtype=torch.float32)},
                                         shape=(B, N))}, shape=(B,))
    reward = Composite({GROUP: Composite({"reward": Unbounded(shape=(B, N, 1), dtype=torch.float32)}, shape=(B, N))},
                       shape=(B,))
    flag = {name: Bounded(False, True, shape=(B, 1), dtype=torch.bool) for name in ("done", "terminated", "truncated")}
    arm_flag = {name: Bounded(False, True, shape=(B, N, 1), dtype=torch.bool) for name in flag}
    done = Composite({**flag, GROUP: Composite(arm_flag, shape=(B, N))}, shape=(B,))
    return {"observation": observation, "action": action, "reward": reward, "done": done}


def info_tensor(value: np.ndarray) -> torch.Tensor:
    """A tensor of its own (the core's arrays and broadcast views are not the env's to hand out), float32 where
    the core's is a float, as every other float of the env."""
    value = np.asarray(value)
    return torch.from_numpy(np.array(value, dtype=np.float32 if value.dtype.kind == "f" else value.dtype))


def _info_dtype(value: np.ndarray) -> torch.dtype:
    return info_tensor(value[..., :0]).dtype
