"""The env as TorchRL's batched multi-agent environment: B copies × N arms in one call, one group ``arms``.

``torchrl_env(scenario, num_envs=B, device=..., **env_kwargs)`` builds a :class:`torchrl.envs.EnvBase` over the
env core (:class:`~pan1_env.core.FormationCore`), the same engine and task as every other view, with no per-copy
Python loop. Needs the ``marl`` extra (``pip install -e ".[marl]"``, PyTorch's CPU wheel first: see the README);
``import pan1_env`` does not import torch.

Shaped like TorchRL's other multi-agent envs (``VmasEnv``, ``PettingZooWrapper``): ``env.group_map`` is
``{"arms": ["arm_0", …]}``, ``env.n_agents`` is N, and ``env.reward_key``, ``env.action_key`` and ``env.done_key``
(the copy's ``"done"``: every arm of a copy ends with it) name the standard entries. ``device`` is where the
tensors live: the engine itself always steps on the CPU (numba), so on another device every step copies the
actions to the CPU and the results back. An unknown keyword gets a "did you mean", as in ``parallel_env``.

Keys (batch size ``[B]``; every arm of a copy starts and ends its episode together; every float is float32):

* ``("arms", "observation") [B, N, obs]``: each arm's local observation, zero-padded at its end to the largest
  arm's size; ``("arms", "action_mask") [B, N, width]`` bool: which action entries the arm uses; ``"state"
  [B, state_size]``: the global state, for centralised critics.
* ``("arms", "action") [B, N, width]`` in [−1, 1]: an arm applies its own first entries (its actuated joints
  k_i, and one more in circulation mode: ``core.action_sizes``), the rest is ignored. Arms of different kinds
  (link counts, PA or fully actuated) are padded into one group rather than split into one group per kind, so
  that one shared network (BenchMARL's default, ``share_policy_params``) serves every arm of a team, whatever
  its kinds.
* ``("arms", "reward") [B, N, 1]``, and beside the observation ``("arms", "cost") [B, N, 1]`` (1.0 where the
  arm entered an obstacle at some sub-step of the step, the safety-gymnasium convention; 0 after a reset):
  constrained learners read it from ``("next", "arms", "cost")``.
* ``done``, ``terminated``, ``truncated``: ``[B, 1]`` and under ``arms`` ``[B, N, 1]``.
* ``("arms", "info", key)``: the per-arm infos of :mod:`pan1_env.core` as ``[B, N]`` (``[B, N, k_max]``
  for ``shield_applied``, ``[B, N, 3]`` for ``qp_counts``): ``min_clearance``, ``reward_<term>``, and with the
  filter on ``shield_intervened``, ``shield_fallback``, ``shield_status``, ``shield_min_barrier``; and
  ``("info", key) [B]`` for the per-copy ones (``formation_error``, ``is_success``).

**Padded action entries.** In a team of mixed kinds an arm's entries past its own are ignored by the env, but
a policy still samples them, and a plain ``TanhNormal`` over all the width's entries counts them in its log-prob and
entropy: PPO's ratio and entropy bonus then move parameters that change nothing. Mask them: a policy whose
distribution is :class:`MaskedTanhNormal`, reading ``("arms", "action_mask")`` beside its ``loc`` and ``scale``
(``ProbabilisticActor(in_keys={"loc": …, "scale": …, "mask": ("arms", "action_mask")}, …)``), sums the log-prob
over the entries an arm applies only (``examples/torchrl_mappo.py``). In a uniform team the mask is all True.

A reset honours TorchRL's ``"_reset"`` mask (only the copies it marks start again). ``set_seed(s)`` gives every
copy an independent stream spawned from s, as :class:`~pan1_env.vector.Pan1VectorEnv`'s ``reset(seed=s)`` does, so
the two give the same episodes (:func:`pan1_env.core.copy_generator`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from .config import FormationConfig, config_arguments
from .core import FormationCore, per_arm, view_repr
from .marl_specs import GROUP, info_tensor, output_specs
from .masked_distribution import MaskedTanhNormal
from .validation import hints_unknown_keywords

__all__ = ["torchrl_env", "Pan1TorchRLEnv", "MaskedTanhNormal"]


@hints_unknown_keywords
@config_arguments(FormationConfig)
def torchrl_env(scenario: Any = "paper_pa3_square", num_envs: int = 1, *, threads: bool | str = "auto",
                device: torch.device | str = "cpu", **env_kwargs: Any) -> Pan1TorchRLEnv:
    """B copies of ``scenario`` (a built-in name, a ``.toml`` path, ``"random"`` or a registered id) as one
    TorchRL environment whose tensors live on ``device`` (the engine steps on the CPU); ``env_kwargs`` are
    :class:`~pan1_env.config.FormationConfig`'s (``safety_filter`` among them: off by default, as in the
    parallel env)."""
    return Pan1TorchRLEnv(FormationCore(FormationConfig(scenario, **env_kwargs), num_envs, threads=threads),
                          device=device)


class Pan1TorchRLEnv(EnvBase):
    """A TorchRL view of a :class:`~pan1_env.core.FormationCore` (see the module docstring); ``device`` is where
    its tensors live, the core steps on the CPU."""

    batch_locked = True

    def __repr__(self) -> str:  # the scenario, copies, arms and the filter's switch, as every view's repr
        return view_repr(self)

    def __init__(self, core: FormationCore, device: torch.device | str = "cpu") -> None:
        B, N, k = core.copies, len(core.agents), core.action_width
        super().__init__(device=device, batch_size=torch.Size([B]))
        self.core = core
        self._last: tuple[list[np.ndarray], dict[str, np.ndarray]] | None = None  # what it last returned: _keep
        self._mask = torch.from_numpy(np.arange(k) < np.asarray(core.action_sizes)[:, None]).expand(B, N, k)
        core.reset()
        _, infos = core.start()  # the info keys and shapes, the same after every reset and step
        self._arm_keys = [key for key in infos if per_arm(key) and key != "cost"]
        self._copy_keys = [key for key in infos if not per_arm(key) and infos[key].dtype.kind in "biuf"]
        specs = output_specs(core, infos, self._arm_keys, self._copy_keys)
        self.observation_spec, self.action_spec = specs["observation"], specs["action"]
        self.reward_spec, self.done_spec = specs["reward"], specs["done"]

    @property
    def group_map(self) -> dict[str, list[str]]:
        """The agents of each group, as TorchRL's multi-agent envs give it: ``{"arms": ["arm_0", …]}``."""
        return {GROUP: list(self.core.agents)}

    @property
    def agent_names(self) -> list[str]:
        """The arms' names, in the order of the ``arms`` dimension."""
        return list(self.core.agents)

    @property
    def n_agents(self) -> int:
        """N, the arms of a team."""
        return len(self.core.agents)

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step (the config's ``control_dt``), as the other views give it."""
        return self.core.config.control_dt

    @property
    def done_key(self) -> str:
        """``"done"``, a copy's end, which every arm shares (``("arms", "done")`` repeats it per arm, and TorchRL's
        default accessor would refuse to choose among the six done entries)."""
        return "done"

    def _set_seed(self, seed: int | None) -> None:
        if seed is not None:
            self.core.seed(seed)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        which = None  # every copy, unless a reset mask (the root's or the group's, as TorchRL writes them) says
        for key in ("_reset", (GROUP, "_reset")):
            if tensordict is not None and key in tensordict.keys(include_nested=True):
                marked = tensordict.get(key).reshape(self.core.copies, -1).any(-1).cpu().numpy()
                which = marked if which is None else which | marked
        copies = None if which is None or which.all() else which.nonzero()[0]
        last, self._last = self._last, None  # (nothing kept if the reset fails half-way)
        self.core.reset(copies)
        if copies is None or last is None:
            mats, infos = self.core.start()
        else:  # only the copies reset are observed; the others' rows are what this env last returned for them
            mats, infos = self.core.start_among(*last, copies)
        self._keep(mats, infos)
        return self._observations(mats, infos)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get((GROUP, "action")).detach().to("cpu", torch.float64).numpy()
        self._last = None  # (nothing kept if the step fails half-way)
        out = self.core.step(actions)
        self._keep(out.observations, out.infos)
        td = self._observations(out.observations, out.infos)
        B, N = out.reward.shape
        terminated = torch.from_numpy(out.terminated.reshape(B, 1))
        truncated = torch.from_numpy(out.truncated.reshape(B, 1))
        done = terminated | truncated
        td.set((GROUP, "reward"), torch.from_numpy(out.reward.astype(np.float32)).reshape(B, N, 1))
        for name, value in (("done", done), ("terminated", terminated), ("truncated", truncated)):
            td.set(name, value)
            td.set((GROUP, name), value[:, None].expand(B, N, 1).clone())
        return td

    def _keep(self, mats: list[np.ndarray], infos: dict[str, np.ndarray]) -> None:
        """Keep what this env returns for a later partial reset (:meth:`FormationCore.start_among`): the
        observations as copies, since the tensors handed out share their memory (the infos' tensors are copies
        already)."""
        self._last = ([mat.copy() for mat in mats], infos)

    def _observations(self, mats: list[np.ndarray], infos: dict[str, np.ndarray]) -> TensorDictBase:
        B, N = self.core.copies, len(self.core.agents)
        obs = self.core.padded_observations(mats)
        arm_info = {key: info_tensor(np.broadcast_to(infos[key], (B, N, *infos[key].shape[2:])))
                    for key in self._arm_keys}
        copy_info = {key: info_tensor(infos[key]) for key in self._copy_keys}
        cost = torch.from_numpy(infos["cost"].astype(np.float32)).reshape(B, N, 1)
        device = self.device  # every level built on it: a level without one would be moved there again
        arms = {"observation": torch.from_numpy(obs), "action_mask": self._mask.clone(), "cost": cost,
                "info": TensorDict(arm_info, batch_size=(B, N), device=device)}
        return TensorDict({GROUP: TensorDict(arms, batch_size=(B, N), device=device),
                           "state": torch.from_numpy(self.core.state()),
                           "info": TensorDict(copy_info, batch_size=(B,), device=device)},
                          batch_size=(B,), device=device)
