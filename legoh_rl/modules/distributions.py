"""Diagonal-Gaussian policy head shared by the oracle actor and the student locomotion module.

Distribution: :class:`torchrl.modules.IndependentNormal` (a diagonal Gaussian) with a
*state-independent* learnable standard deviation, as in rsl_rl's ``ActorCritic`` that
legged-robot PPO (legged_gym, Extreme Parkour) uses. Why not ``TanhNormal``: actions are
joint-target offsets (``q* = q_default + 0.25 a``) that the env clips, not a bounded box the
policy must respect; a Gaussian has an exact log-prob for any action (the DAgger/teacher
actions included), a closed-form entropy for PPO's entropy bonus, and ``loc`` is the
deterministic action the student imitates.
"""

from __future__ import annotations

import math

import torch
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import Unbounded
from torchrl.modules import IndependentNormal, ProbabilisticActor

from legoh_rl.modules.keys import NestedKey

__all__ = ["GaussianHead", "make_gaussian_actor", "set_action_std"]


class GaussianHead(nn.Module):
    """Map features to ``(loc, scale)``: ``(*B, F) -> (*B, A), (*B, A)``.

    ``loc = Linear(features)`` (or ``loc_bound * tanh(Linear(features))`` when
    ``loc_bound`` is set); ``scale = exp(log_std)`` is a learnable per-action parameter,
    independent of the state, initialised to ``init_std``, floored at ``min_std`` and, when
    ``max_std`` is set, capped there (exploration noise that cannot grow past a ceiling). The cap
    is a clamp: while ``exp(log_std)`` stands above it no gradient reaches ``log_std``, so the std
    stays at the ceiling until :func:`set_action_std` sets it under (``model.start_std``).
    """

    def __init__(
        self,
        in_dim: int,
        num_actions: int,
        init_std: float = 1.0,
        loc_bound: float | None = None,
        min_std: float = 1e-4,
        max_std: float | None = None,
    ) -> None:
        super().__init__()
        if init_std <= 0:
            raise ValueError(f"GaussianHead: init_std must be positive, got {init_std}")
        if max_std is not None and not max_std > min_std:
            raise ValueError(f"GaussianHead: max_std must exceed min_std ({min_std}), got {max_std}")
        self.mean = nn.Linear(in_dim, num_actions)
        self.log_std = nn.Parameter(torch.full((num_actions,), math.log(init_std)))
        self.loc_bound = loc_bound
        self.min_std = min_std
        self.max_std = max_std

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(loc, scale)``."""
        loc = self.mean(features)
        if self.loc_bound is not None:
            loc = self.loc_bound * torch.tanh(loc)
        scale = self.log_std.exp().clamp(self.min_std, self.max_std).expand_as(loc)
        return loc, scale


def make_gaussian_actor(
    module: TensorDictModuleBase,
    num_actions: int,
    *,
    loc_key: NestedKey = "loc",
    scale_key: NestedKey = "scale",
    action_key: NestedKey = "action",
) -> ProbabilisticActor:
    """Wrap ``module`` (which writes ``loc`` and ``scale``) into a ``ProbabilisticActor``.

    The actor samples ``action`` ``(A,)`` from ``IndependentNormal(loc, scale)`` under
    ``ExplorationType.RANDOM`` (collectors) and returns ``loc`` under ``DETERMINISTIC``;
    it writes ``action_log_prob`` (``return_log_prob=True``) for PPO.
    """
    return ProbabilisticActor(
        module,
        in_keys={"loc": loc_key, "scale": scale_key},
        out_keys=[action_key],
        distribution_class=IndependentNormal,
        return_log_prob=True,
        spec=Unbounded(shape=(num_actions,)),
    )


def set_action_std(actor: nn.Module, std: float) -> float:
    """Set the action std of every :class:`GaussianHead` in ``actor`` to ``std`` (all actions;
    the learnable ``log_std`` keeps training from there). Used where a policy trained on its mean
    starts to explore (the student's PPO phase: ``student.ppo_join_std``).

    Returns:
        ``std``.

    Raises:
        ValueError: ``actor`` has no GaussianHead, or ``std`` is not within a head's
            ``[min_std, max_std]``.
    """
    heads = [m for m in actor.modules() if isinstance(m, GaussianHead)]
    if not heads:
        raise ValueError(f"set_action_std: {type(actor).__name__} has no GaussianHead whose std could be set")
    for head in heads:
        if not head.min_std <= std <= (head.max_std if head.max_std is not None else math.inf):
            raise ValueError(f"set_action_std: std {std} is outside the head's range "
                             f"[{head.min_std}, {head.max_std}]")
    with torch.no_grad():
        for head in heads:
            head.log_std.fill_(math.log(std))
    return float(std)
