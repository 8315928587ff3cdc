"""Oracle (teacher) actor-critic: scandot and privileged encoders, actor and critic MLPs.

Paper appendix "Network Architectures":

* scandot encoder: MLP [128, 64, 32], ELU hidden, Tanh out: ``scandots (132,) -> z_tea (32,)``;
* privileged encoder: MLP [64, 20] (ELU): ``privileged (P,) -> priv_latent (20,)``;
* actor and critic: MLP [512, 256, 128], ELU hidden, Tanh out, over
  ``concat(proprio, z_tea, priv_latent, expert_goals.flatten())``; a final linear maps the
  128 Tanh features to A action means (actor, see :class:`GaussianHead`) or to the value.

"Tanh out" is read as the activation of the MLP's last listed layer (128), which is the
only reading that also works for the critic (whose value is unbounded). Action means are
therefore unbounded by default and the env applies ``q* = q_default + 0.25 a`` and its
clip; ``OracleConfig.loc_bound`` optionally bounds them with ``bound * tanh``.

Networks by name: :data:`ORACLE_NETWORKS` maps ``OracleConfig.network`` (the recipe's
``model.network``) to a class built as ``cls(cfg)``; ``"mlp"`` is :class:`OracleNetworks`. Plug in
your own with :func:`register_oracle_network` (as rsl_rl's runner takes a ``class_name``); the
recipe, the checkpoints (``oracle_config["network"]``), evaluation, the teacher and the ONNX export
then build it by that name through :func:`make_oracle_networks`.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.modules import ProbabilisticActor, ValueOperator

from legoh_rl.modules.configs import OracleConfig
from legoh_rl.modules.distributions import GaussianHead, make_gaussian_actor
from legoh_rl.modules.keys import OracleKeys
from legoh_rl.modules.mlp import build_mlp
from legoh_rl.registry import Registry

__all__ = [
    "ORACLE_NETWORKS",
    "ORACLE_NETWORK_PARTS",
    "OracleActorNet",
    "OracleCriticNet",
    "OracleNetworks",
    "make_oracle_actor",
    "make_oracle_actor_critic",
    "make_oracle_critic",
    "make_oracle_networks",
    "oracle_network_class",
    "register_oracle_network",
    "scandot_input_keys",
]


def _check_dims(owner: str, named: dict[str, tuple[torch.Tensor, int]]) -> None:
    for name, (x, d) in named.items():
        if x.shape[-1] != d:
            raise ValueError(f"{owner}: {name} has last dim {x.shape[-1]}, expected {d}")


class OracleActorNet(nn.Module):
    """``(proprio (*B, D), z_tea (*B, 32), priv_latent (*B, 20), expert_goals (*B, N, 2))
    -> (loc (*B, A), scale (*B, A))``."""

    def __init__(self, cfg: OracleConfig) -> None:
        super().__init__()
        self.dims = (cfg.proprio_dim, cfg.latent_dim, cfg.priv_latent_dim, 2 * cfg.num_goals)
        self.body = build_mlp(sum(self.dims), cfg.actor_layers, cfg.activation,
                              last_activation=cfg.body_out_activation)
        self.head = GaussianHead(int(cfg.actor_layers[-1]), cfg.num_actions, cfg.init_std,
                                 cfg.loc_bound, max_std=cfg.max_std)

    def forward(self, proprio, z_tea, priv_latent, expert_goals):
        """Return ``(loc, scale)``."""
        goals = expert_goals.flatten(-2)
        _check_dims("OracleActorNet", {
            "proprio": (proprio, self.dims[0]), "z_tea": (z_tea, self.dims[1]),
            "priv_latent": (priv_latent, self.dims[2]), "expert_goals (flattened)": (goals, self.dims[3]),
        })
        return self.head(self.body(torch.cat([proprio, z_tea, priv_latent, goals], dim=-1)))


class OracleCriticNet(nn.Module):
    """``(proprio, scandots (*B, 132), privileged (*B, P), expert_goals (*B, N, 2))
    -> state_value (*B, 1)``.

    Runs its scandot and privileged encoders itself (its own copies, or the actor's
    when ``share_encoders``), then the [512, 256, 128] MLP and a linear value head.
    """

    def __init__(self, cfg: OracleConfig, scandot_encoder: nn.Module, priv_encoder: nn.Module):
        super().__init__()
        self.scandot_encoder = scandot_encoder
        self.priv_encoder = priv_encoder
        self.dims = (cfg.proprio_dim, cfg.latent_dim, cfg.priv_latent_dim, 2 * cfg.num_goals)
        self.body = build_mlp(sum(self.dims), cfg.critic_layers, cfg.activation,
                              last_activation=cfg.body_out_activation)
        self.value = nn.Linear(int(cfg.critic_layers[-1]), 1)

    def forward(self, proprio, scandots, privileged, expert_goals) -> torch.Tensor:
        """Return the state value ``(*B, 1)``."""
        z = self.scandot_encoder(scandots)
        p = self.priv_encoder(privileged)
        goals = expert_goals.flatten(-2)
        _check_dims("OracleCriticNet", {
            "proprio": (proprio, self.dims[0]), "expert_goals (flattened)": (goals, self.dims[3]),
        })
        return self.value(self.body(torch.cat([proprio, z, p, goals], dim=-1)))


class OracleNetworks(nn.Module):
    """All oracle parameters in one module (handy for checkpoints and freezing).

    Attributes:
        scandot_encoder: ``(*B, 132) -> (*B, 32)``. priv_encoder: ``(*B, P) -> (*B, 20)``.
        actor: :class:`OracleActorNet`. critic: :class:`OracleCriticNet`.
        actor_class: the class of ``actor``, built as ``actor_class(cfg)`` (a subclass that
            replaces the actor sets it; the student's frozen-oracle locomotion builds the actor alone).
    """

    actor_class: type[nn.Module] = OracleActorNet

    def __init__(self, cfg: OracleConfig) -> None:
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.scandot_encoder = build_mlp(cfg.scandots_dim, cfg.scandot_layers, cfg.activation,
                                         last_activation=cfg.encoder_out_activation)
        self.priv_encoder = build_mlp(cfg.privileged_dim, cfg.priv_layers, cfg.activation,
                                      last_activation=cfg.priv_out_activation)
        self.actor = self.actor_class(cfg)
        if cfg.share_encoders:
            critic_scan, critic_priv = self.scandot_encoder, self.priv_encoder
        else:
            critic_scan = build_mlp(cfg.scandots_dim, cfg.scandot_layers, cfg.activation,
                                    last_activation=cfg.encoder_out_activation)
            critic_priv = build_mlp(cfg.privileged_dim, cfg.priv_layers, cfg.activation,
                                    last_activation=cfg.priv_out_activation)
        self.critic = OracleCriticNet(cfg, critic_scan, critic_priv)


#: oracle network classes by name (``OracleConfig.network``, the recipe's ``model.network``)
ORACLE_NETWORKS: Registry[type[nn.Module]] = Registry(
    "oracle network", base=nn.Module, base_text="an nn.Module subclass",
    hint="register_oracle_network in legoh_rl.modules.oracle adds one")

#: what every oracle network has (the contract of :class:`OracleNetworks`):
#: ``cfg`` its :class:`OracleConfig`;
#: ``scandot_encoder`` ``scandots (*B, S) -> z_tea (*B, cfg.latent_dim)``;
#: ``priv_encoder`` ``privileged (*B, P) -> priv_latent (*B, cfg.priv_latent_dim)``;
#: ``actor`` ``(proprio, z_tea, priv_latent, expert_goals (*B, N, 2)) -> (loc, scale) (*B, A)``,
#: whose ``head`` is a :class:`~legoh_rl.modules.distributions.GaussianHead` (the teacher reads
#: its std); ``critic`` ``(proprio, scandots, privileged, expert_goals) -> state_value (*B, 1)``.
#: ``actor_class`` builds the actor alone as ``actor_class(cfg)``.
ORACLE_NETWORK_PARTS = ("cfg", "scandot_encoder", "priv_encoder", "actor", "critic", "actor_class")


def register_oracle_network(name: str, cls: type[nn.Module] | None = None):
    """Register an oracle network class under ``name`` (also usable as ``@register_oracle_network(name)``).

    ``cls(cfg: OracleConfig)`` must build an ``nn.Module`` with the parts of
    :data:`ORACLE_NETWORK_PARTS`; subclassing :class:`OracleNetworks` and replacing some of them is
    the short way. Returns ``cls``.

    Raises:
        ValueError: ``name`` is empty or not a string, names another class already, or ``cls``
            is not an ``nn.Module`` subclass.
    """
    return ORACLE_NETWORKS.register(name, cls)


register_oracle_network("mlp", OracleNetworks)


def oracle_network_class(name: str) -> type[nn.Module]:
    """The class registered as ``name`` in :data:`ORACLE_NETWORKS`.

    Raises:
        ValueError: an unregistered name (the message lists the registered ones).
    """
    return ORACLE_NETWORKS.lookup(name)


def make_oracle_networks(cfg: OracleConfig) -> nn.Module:
    """The oracle network ``cfg.network`` (a key of :data:`ORACLE_NETWORKS`), untrained.

    Raises:
        ValueError: an unregistered name (the message lists the registered ones), or a class
            whose instance lacks a part of :data:`ORACLE_NETWORK_PARTS` (named).
    """
    networks = oracle_network_class(cfg.network)(cfg)
    missing = [p for p in ORACLE_NETWORK_PARTS if not hasattr(networks, p)]
    if missing:
        raise ValueError(f"oracle network {cfg.network!r} ({type(networks).__qualname__}) lacks {missing}: "
                         f"an oracle network has {list(ORACLE_NETWORK_PARTS)} (see OracleNetworks)")
    return networks


def scandot_input_keys(networks: nn.Module) -> list[str]:
    """The state-dict keys of the weights that read ``scandots`` directly: the first
    ``nn.Linear`` of the actor's ``scandot_encoder`` and of the critic's (``critic.scandot_encoder``,
    where the network has one), each ``(out, S)`` with S the scandots' width. With
    ``share_encoders`` the one module is named both ways, and both names are listed (a state dict
    holds both). What a warm start onto wider scandots widens (``checkpoint.init_widen``).

    Raises:
        ValueError: an encoder with no ``nn.Linear`` (names the network's class).
    """
    encoders = [networks.scandot_encoder] + [e for e in (getattr(networks.critic, "scandot_encoder", None),)
                                             if e is not None]
    firsts = []
    for encoder in encoders:
        first = next((m for m in encoder.modules() if isinstance(m, nn.Linear)), None)
        if first is None:
            raise ValueError(f"{type(networks).__qualname__}: a scandot encoder without an nn.Linear "
                             f"({type(encoder).__qualname__}): no first layer reads the scandots")
        firsts.append(first)
    return [f"{name}.weight" for name, module in networks.named_modules(remove_duplicate=False)
            if any(module is first for first in firsts)]


def make_oracle_actor(
    networks: OracleNetworks,
    keys: OracleKeys | None = None,
    priv_latent_module: TensorDictModuleBase | None = None,
) -> ProbabilisticActor:
    """Oracle actor: ``scandots -> z_tea``, ``privileged -> priv_latent``, ``-> loc, scale -> action``.

    Args:
        networks: the parameters (shared with any other actor/critic built from them).
        keys: TensorDict keys (defaults: :class:`OracleKeys`).
        priv_latent_module: if given, replaces the privileged encoder: a TensorDictModule
            whose first out key holds the latent estimate (e.g. the adaptation module's
            ``priv_latent_hat`` from ``proprio_history``). The actor then needs no
            ``privileged`` input, which is how the oracle runs without privileged state.

    Returns:
        A ``ProbabilisticActor`` (IndependentNormal, ``return_log_prob=True``) whose
        outputs include ``z_tea``, the latent, ``loc``, ``scale``, ``action`` and
        ``action_log_prob``.
    """
    keys = keys or OracleKeys()
    steps: list[TensorDictModuleBase] = [
        TensorDictModule(networks.scandot_encoder, in_keys=[keys.scandots], out_keys=[keys.z_tea])
    ]
    if priv_latent_module is None:
        steps.append(TensorDictModule(networks.priv_encoder, in_keys=[keys.privileged],
                                      out_keys=[keys.priv_latent]))
        latent_key = keys.priv_latent
    else:
        steps.append(priv_latent_module)
        latent_key = priv_latent_module.out_keys[0]
    steps.append(TensorDictModule(
        networks.actor,
        in_keys=[keys.proprio, keys.z_tea, latent_key, keys.expert_goals],
        out_keys=[keys.loc, keys.scale],
    ))
    return make_gaussian_actor(
        TensorDictSequential(*steps), networks.cfg.num_actions,
        loc_key=keys.loc, scale_key=keys.scale, action_key=keys.action,
    )


def make_oracle_critic(networks: OracleNetworks, keys: OracleKeys | None = None) -> ValueOperator:
    """Oracle critic: ``(proprio, scandots, privileged, expert_goals) -> state_value (1,)``."""
    keys = keys or OracleKeys()
    return ValueOperator(
        networks.critic,
        in_keys=[keys.proprio, keys.scandots, keys.privileged, keys.expert_goals],
        out_keys=[keys.state_value],
    )


def make_oracle_actor_critic(
    cfg: OracleConfig,
    keys: OracleKeys | None = None,
    networks: OracleNetworks | None = None,
) -> tuple[ProbabilisticActor, ValueOperator]:
    """Build the oracle ``(actor, critic)`` pair from ``cfg`` (or from existing ``networks``).

    The actor's outputs include ``z_tea`` and ``loc`` (the student's distillation targets).
    To run the same oracle on the adaptation module's estimate instead of the privileged
    encoder, build ``networks = OracleNetworks(cfg)`` once and call
    ``make_oracle_actor(networks, keys, priv_latent_module=adaptation)``.
    """
    networks = networks if networks is not None else make_oracle_networks(cfg)
    return make_oracle_actor(networks, keys), make_oracle_critic(networks, keys)
