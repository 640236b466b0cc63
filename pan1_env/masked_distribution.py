"""An action distribution for the padded group of :mod:`pan1_env.marl`: :class:`MaskedTanhNormal`, a ``TanhNormal``
whose log-prob leaves out the action entries an arm does not apply (``("arms", "action_mask")`` False). Needs
the ``marl`` extra, as :mod:`pan1_env.marl`, which re-exports it."""

from __future__ import annotations

from typing import Any

import torch
from torchrl.modules import TanhNormal

__all__ = ["MaskedTanhNormal"]


class MaskedTanhNormal(torch.distributions.Distribution):
    """TorchRL's ``TanhNormal`` over an arm's padded action whose log-prob sums over the entries ``mask`` keeps.

    Batch shape ``loc.shape[:-1]`` (copies, arms), event shape ``loc.shape[-1:]`` (the padded action's width),
    as a ``TanhNormal`` over the action: each entry is drawn from its own ``TanhNormal`` (``low``, ``high`` and
    the other keywords are ``TanhNormal``'s), and an arm's padding entries (``("arms", "action_mask")`` False)
    are still sampled, and ignored by the env, but count in no log-prob, so neither in PPO's ratio nor in its
    sampled entropy estimate (``entropy()`` has no closed form, as for ``TanhNormal``)."""

    arg_constraints: dict = {}
    has_rsample = True

    def __init__(self, loc: torch.Tensor, scale: torch.Tensor, mask: torch.Tensor, **kwargs: Any) -> None:
        self.entries = TanhNormal(loc, scale, event_dims=0, **kwargs)  # each entry alone
        self.mask = mask.to(torch.bool)
        super().__init__(loc.shape[:-1], loc.shape[-1:], validate_args=False)

    def rsample(self, sample_shape: tuple[int, ...] = ()) -> torch.Tensor:
        return self.entries.rsample(sample_shape)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        # padded entries are set to 0 before the log-prob, not only masked after: at ±1 an entry's log-prob is
        # infinite, and a masked infinity still sends NaN back through the gradient
        value = torch.where(self.mask, value, torch.zeros_like(value))
        entries = self.entries.log_prob(value)
        return torch.where(self.mask, entries, torch.zeros_like(entries)).sum(-1)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """The action a deterministic policy takes (``TanhNormal``'s: the squashed ``loc``)."""
        return self.entries.deterministic_sample

    @property
    def mode(self) -> torch.Tensor:
        return self.entries.deterministic_sample
