"""Student locomotion module E (paper Sec. "Unified Hiking Policy Learning").

An MLP over ``(z_uni, proprio, delta_g0, goal_next)``, with the same diagonal-Gaussian head
and state-independent std as the oracle actor (:mod:`legoh_rl.modules.distributions`), so
its ``loc`` is directly comparable with the oracle's for action imitation.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor

from legoh_rl.modules.configs import LocomotionConfig
from legoh_rl.modules.distributions import GaussianHead, make_gaussian_actor
from legoh_rl.modules.keys import LocomotionKeys
from legoh_rl.modules.mlp import build_mlp

__all__ = ["LocomotionNet", "make_locomotion_actor"]


class LocomotionNet(nn.Module):
    """``(z_uni (*B, L), proprio (*B, D), delta_g0 (*B, 2), goal_next (*B, 2))
    -> (loc (*B, A), scale (*B, A))``."""

    def __init__(self, cfg: LocomotionConfig) -> None:
        super().__init__()
        cfg.validate()
        self.dims = (cfg.latent_dim, cfg.proprio_dim, cfg.goal_dim, cfg.goal_dim)
        self.body = build_mlp(sum(self.dims), cfg.layers, cfg.activation,
                              last_activation=cfg.body_out_activation)
        self.head = GaussianHead(int(cfg.layers[-1]), cfg.num_actions, cfg.init_std, cfg.loc_bound)

    def forward(self, z_uni, proprio, delta_g0, goal_next):
        """Return ``(loc, scale)``."""
        names = ("z_uni", "proprio", "delta_g0", "goal_next")
        inputs = (z_uni, proprio, delta_g0, goal_next)
        for name, x, d in zip(names, inputs, self.dims, strict=True):
            if x.shape[-1] != d:
                raise ValueError(f"LocomotionNet: {name} has last dim {x.shape[-1]}, expected {d}")
        return self.head(self.body(torch.cat(inputs, dim=-1)))


def make_locomotion_actor(
    cfg: LocomotionConfig, keys: LocomotionKeys | None = None
) -> ProbabilisticActor:
    """``ProbabilisticActor``: ``(z_uni, proprio, delta_g0, goal_next) -> loc, scale -> action``.

    IndependentNormal with ``return_log_prob=True`` (writes ``action_log_prob``).
    """
    keys = keys or LocomotionKeys()
    net = TensorDictModule(
        LocomotionNet(cfg),
        in_keys=[keys.z_uni, keys.proprio, keys.delta_g0, keys.goal_next],
        out_keys=[keys.loc, keys.scale],
    )
    return make_gaussian_actor(net, cfg.num_actions, loc_key=keys.loc, scale_key=keys.scale,
                               action_key=keys.action)
