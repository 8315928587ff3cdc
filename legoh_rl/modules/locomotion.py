"""Student locomotion module E (paper Sec. "Unified Hiking Policy Learning").

An MLP over ``(z_uni, proprio, delta_g0, goal_next)``, with the same diagonal-Gaussian head
and state-independent std as the oracle actor (:mod:`legoh_rl.modules.distributions`), so
its ``loc`` is directly comparable with the oracle's for action imitation.

The RMA baselines (paper Sec. "Benchmark": "a frozen oracle policy with an adapter network
to map [...] sensory data to oracle's latent space") use the oracle's own actor instead,
frozen, reading the adapter's estimates in place of the privileged encoders' outputs and the
expert goals (:func:`make_oracle_locomotion_actor`).

Networks by name: :data:`LOCOMOTION_NETWORKS` maps ``LocomotionConfig.network`` (the unified
recipe's ``student.network``) to a class built as ``cls(cfg)``; ``"mlp"`` is :class:`LocomotionNet`.
Plug in your own with :func:`register_locomotion_network`; the recipe, the checkpoints
(``meta["locomotion_network"]``), evaluation and the ONNX export then build it by that name
through :func:`make_locomotion_network`.
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
from legoh_rl.registry import Registry

__all__ = [
    "LOCOMOTION_NETWORKS",
    "LocomotionNet",
    "locomotion_network_class",
    "make_locomotion_actor",
    "make_locomotion_network",
    "make_oracle_locomotion_actor",
    "register_locomotion_network",
]


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


#: the student's locomotion network classes by name (``LocomotionConfig.network``, the unified
#: recipe's ``student.network``). Each is built as ``cls(cfg: LocomotionConfig)`` and maps
#: ``(z_uni (*B, cfg.latent_dim), proprio (*B, cfg.proprio_dim), delta_g0 (*B, cfg.goal_dim),
#: goal_next (*B, cfg.goal_dim)) -> (loc, scale) (*B, cfg.num_actions)``, ``scale > 0`` (the
#: actor's diagonal Gaussian; :class:`~legoh_rl.modules.distributions.GaussianHead` gives both).
LOCOMOTION_NETWORKS: Registry[type[nn.Module]] = Registry(
    "locomotion network", base=nn.Module, base_text="an nn.Module subclass",
    hint="register_locomotion_network in legoh_rl.modules.locomotion adds one")


def register_locomotion_network(name: str, cls: type[nn.Module] | None = None):
    """Register a locomotion network class under ``name`` (also usable as
    ``@register_locomotion_network(name)``); its contract is :data:`LOCOMOTION_NETWORKS`'s.
    Returns ``cls``.

    Raises:
        ValueError: ``name`` is empty or not a string, names another class already, or ``cls``
            is not an ``nn.Module`` subclass.
    """
    return LOCOMOTION_NETWORKS.register(name, cls)


register_locomotion_network("mlp", LocomotionNet)


def locomotion_network_class(name: str) -> type[nn.Module]:
    """The class registered as ``name`` in :data:`LOCOMOTION_NETWORKS`.

    Raises:
        ValueError: an unregistered name (the message lists the registered ones).
    """
    return LOCOMOTION_NETWORKS.lookup(name)


def make_locomotion_network(cfg: LocomotionConfig) -> nn.Module:
    """The locomotion network ``cfg.network`` (a key of :data:`LOCOMOTION_NETWORKS`), untrained.

    Raises:
        ValueError: a bad field of ``cfg``, or an unregistered name (the message lists the
            registered ones).
    """
    cfg.validate()
    return locomotion_network_class(cfg.network)(cfg)


def make_locomotion_actor(
    cfg: LocomotionConfig, keys: LocomotionKeys | None = None
) -> ProbabilisticActor:
    """``ProbabilisticActor``: ``(z_uni, proprio, delta_g0, goal_next) -> loc, scale -> action``,
    the network :func:`make_locomotion_network` builds for ``cfg``.

    IndependentNormal with ``return_log_prob=True`` (writes ``action_log_prob``).
    """
    keys = keys or LocomotionKeys()
    net = TensorDictModule(
        make_locomotion_network(cfg),
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
