"""Student locomotion module E (paper Sec. "Unified Hiking Policy Learning").

An MLP over ``(z_uni, proprio, delta_g0, goal_next)``, with the same diagonal-Gaussian head
and state-independent std as the oracle actor (:mod:`legoh_rl.modules.distributions`), so
its ``loc`` is directly comparable with the oracle's for action imitation.

The RMA baselines (paper Sec. "Benchmark": "a frozen oracle policy with an adapter network
to map [...] sensory data to oracle's latent space") use the oracle's own actor instead,
frozen, reading the adapter's estimates in place of the privileged encoders' outputs and the
expert goals (:func:`make_oracle_locomotion_actor`).
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
from legoh_rl.modules.oracle import OracleActorNet

__all__ = ["LocomotionNet", "make_locomotion_actor", "make_oracle_locomotion_actor"]


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


def make_oracle_locomotion_actor(net: OracleActorNet, keys: LocomotionKeys | None = None) -> ProbabilisticActor:
    """The oracle's actor as the student's locomotion module, frozen (RMA):
    ``(proprio (*B, D), z_uni (*B, 32), priv_latent_uni (*B, 20), goals_uni (*B, N, 2))
    -> loc, scale (*B, A) -> action``.

    ``net`` (an :class:`~legoh_rl.modules.oracle.OracleActorNet`, typically a copy of a trained
    oracle's ``networks.actor``) reads the student's estimates where the oracle read its
    scandot latent ``z_tea``, its privileged latent and the expert goals; its parameters,
    the std included, get ``requires_grad=False``, so an optimiser over the actor's parameters
    leaves it as it is and gradients pass through it to the perception that feeds it.
    IndependentNormal with ``return_log_prob=True`` (writes ``action_log_prob``).
    """
    keys = keys or LocomotionKeys()
    net.requires_grad_(False)
    module = TensorDictModule(
        net, in_keys=[keys.proprio, keys.z_uni, keys.priv_latent_uni, keys.goals_uni],
        out_keys=[keys.loc, keys.scale],
    )
    return make_gaussian_actor(module, net.head.mean.out_features, loc_key=keys.loc, scale_key=keys.scale,
                               action_key=keys.action)
