"""TC-ViT part c: recurrent goal adaptation, and the output heads shared by all perception nets.

``z_uni, delta_g0, G = GRU(MLP(gamma, P_B, D_rm, X_pro))`` (paper Sec. "TC-ViT", 3):

* :class:`MemoryInputMLP`: the 2-layer MLP over (features, ``goal_gps``, ``waypoint_gps``,
  ``proprio``); ``waypoint_gps`` only when ``cfg.io.num_waypoints`` is 1 (the default);
* a memory: torchrl's :class:`~torchrl.modules.GRUModule` (``"gru"``), or the
  :class:`~legoh_rl.modules.causal_transformer.CausalTransformerMemory` (``"ct"``);
* :class:`PerceptionHeads`: ``z_uni`` (latent, Tanh like the oracle's ``z_tea``),
  ``delta_g0`` (2,) and ``goals_uni`` (N, 2), each angle a unit (cos, sin) vector.

:func:`make_memory_perception` composes an encoder TensorDictModule (which writes
``keys.features``) with these into one TensorDictSequential; TC-ViT, the ConvGRU
("vanilla") and EP-H baselines differ only in the encoder.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import Composite, Unbounded
from torchrl.modules import GRUModule

from legoh_rl.modules.causal_transformer import CausalTransformerMemory
from legoh_rl.modules.configs import PerceptionConfig
from legoh_rl.modules.keys import PerceptionKeys
from legoh_rl.modules.mlp import build_mlp, unit_normalize

__all__ = [
    "MemoryInputMLP",
    "PerceptionHeads",
    "attach_output_spec",
    "make_heads_module",
    "make_memory_perception",
    "perception_output_spec",
]


class MemoryInputMLP(nn.Module):
    """2-layer (configurable) ELU MLP over the concatenated features and goal/proprio inputs.

    With ``cfg.io.num_waypoints == 1`` (M = 1, LEGO-H)::

        forward(features (*B, F), goal_gps (*B, 2), waypoint_gps (*B, 2), proprio (*B, D))
            -> (*B, layers[-1])

    With M = 0 there is no waypoint input: ``forward(features, goal_gps, proprio)``.
    The inputs are concatenated in this order (``names`` lists them).
    """

    def __init__(self, feature_dim: int, cfg: PerceptionConfig) -> None:
        super().__init__()
        io = cfg.io
        self.num_waypoints = int(io.num_waypoints)
        self.names = ("features", "goal_gps") + ("waypoint_gps",) * self.num_waypoints + ("proprio",)
        self.dims = (feature_dim,) + (io.gps_dim,) * io.gps_inputs + (io.proprio_dim,)
        self.mlp = build_mlp(sum(self.dims), cfg.memory_in_layers, "elu")
        self.out_dim = int(cfg.memory_in_layers[-1])

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Concatenate the inputs (in the order of ``names``) and apply the MLP."""
        if len(inputs) != len(self.names):
            raise TypeError(
                f"MemoryInputMLP (num_waypoints={self.num_waypoints}) takes "
                f"{len(self.names)} inputs {self.names}, got {len(inputs)}"
            )
        for name, x, d in zip(self.names, inputs, self.dims, strict=True):
            if x.shape[-1] != d:
                raise ValueError(f"MemoryInputMLP: {name} has last dim {x.shape[-1]}, expected {d}")
        return self.mlp(torch.cat(inputs, dim=-1))


class PerceptionHeads(nn.Module):
    """Linear heads: ``h (*B, H) -> z_uni (*B, L), delta_g0 (*B, 2), goals_uni (*B, N, 2)``.

    Angles are unit vectors (cos, sin): the raw 2-vectors are normalised to unit length
    (:func:`~legoh_rl.modules.mlp.unit_normalize`), so targets given as (cos, sin) can be
    regressed with SmoothL1 / MSE without the +-pi discontinuity of a raw yaw.
    """

    def __init__(self, in_dim: int, latent_dim: int, num_goals: int, latent_tanh: bool = True):
        super().__init__()
        self.latent = nn.Linear(in_dim, latent_dim)
        self.latent_act = nn.Tanh() if latent_tanh else nn.Identity()
        self.delta = nn.Linear(in_dim, 2)
        self.goals = nn.Linear(in_dim, 2 * num_goals)
        self.num_goals = num_goals

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(z_uni, delta_g0, goals_uni)``."""
        z = self.latent_act(self.latent(h))
        delta = unit_normalize(self.delta(h))
        goals = unit_normalize(self.goals(h).unflatten(-1, (self.num_goals, 2)))
        return z, delta, goals


def make_heads_module(in_key, in_dim: int, cfg: PerceptionConfig, keys: PerceptionKeys):
    """TensorDictModule ``in_key -> (z_uni, delta_g0, goals_uni)``."""
    heads = PerceptionHeads(in_dim, cfg.io.latent_dim, cfg.io.num_goals, cfg.latent_tanh)
    return TensorDictModule(
        heads, in_keys=[in_key], out_keys=[keys.z_uni, keys.delta_g0, keys.goals_uni]
    )


def perception_output_spec(cfg: PerceptionConfig, keys: PerceptionKeys | None = None,
                           priv_latent: bool = False) -> Composite:
    """Output spec of every perception network: ``z_uni`` ``(latent_dim,)``, ``delta_g0``
    ``(2,)``, ``goals_uni`` ``(num_goals, 2)`` and, with ``priv_latent`` (the RMA adapters),
    ``priv_latent_uni`` ``(priv_latent_dim,)`` (feature shapes, no batch dims)."""
    keys = keys or PerceptionKeys()
    io = cfg.io
    specs = {
        keys.z_uni: Unbounded(shape=(io.latent_dim,)),
        keys.delta_g0: Unbounded(shape=(2,)),
        keys.goals_uni: Unbounded(shape=(io.num_goals, 2)),
    }
    if priv_latent:
        specs[keys.priv_latent_uni] = Unbounded(shape=(io.priv_latent_dim,))
    return Composite(specs, shape=())


def attach_output_spec(
    module: TensorDictModuleBase, cfg: PerceptionConfig, keys: PerceptionKeys | None = None,
    priv_latent: bool = False,
) -> TensorDictModuleBase:
    """Set ``module.spec`` to :func:`perception_output_spec` and return ``module``.

    ``spec`` is torchrl's attribute for a module's output spec (``SafeModule``,
    ``ProbabilisticActor``); :class:`~legoh_rl.transforms.PerceptionHold` reads it to size
    its held state, so a network built with non-default sizes needs no ``out_shapes``. It is
    a plain attribute: the module's ``state_dict`` is unchanged.
    """
    module.spec = perception_output_spec(cfg, keys, priv_latent)
    return module


def make_memory_perception(
    encoder: TensorDictModuleBase,
    feature_dim: int,
    cfg: PerceptionConfig,
    keys: PerceptionKeys | None = None,
    memory: str = "gru",
) -> TensorDictSequential:
    """Compose ``encoder -> MemoryInputMLP -> memory -> PerceptionHeads``.

    Args:
        encoder: writes ``keys.features`` ``(feature_dim,)`` from its own inputs.
        feature_dim: size of the encoder's output.
        cfg: perception config (MLP, GRU / CT sizes, heads).
        keys: TensorDict keys (defaults: :class:`PerceptionKeys`).
        memory: ``"gru"`` (torchrl ``GRUModule``; state in ``keys.hidden``
            ``(gru_layers, gru_hidden)``) or ``"ct"`` (causal transformer; state in
            ``keys.context`` / ``keys.context_valid``).

    Returns:
        A ``TensorDictSequential`` writing ``z_uni``, ``delta_g0``, ``goals_uni``, whose
        ``spec`` (:func:`perception_output_spec`) gives their feature shapes; call
        ``torchrl.modules.utils.get_primers_from_module(module)`` for its env primer.
    """
    keys = keys or PerceptionKeys()
    mem_in = MemoryInputMLP(feature_dim, cfg)
    gps_keys = [keys.goal_gps] + [keys.waypoint_gps] * cfg.io.num_waypoints
    mem_in_module = TensorDictModule(
        mem_in,
        in_keys=[keys.features, *gps_keys, keys.proprio],
        out_keys=[keys.memory_in],
    )
    if memory == "gru":
        hidden_next = ("next", *keys.hidden) if isinstance(keys.hidden, tuple) else ("next", keys.hidden)
        mem: TensorDictModuleBase = GRUModule(
            input_size=mem_in.out_dim,
            hidden_size=cfg.gru_hidden,
            num_layers=cfg.gru_layers,
            in_keys=[keys.memory_in, keys.hidden, keys.is_init],
            out_keys=[keys.memory_out, hidden_next],
        )
        mem_dim = cfg.gru_hidden
    elif memory == "ct":
        mem = CausalTransformerMemory(
            mem_in.out_dim,
            cfg.ct,
            in_key=keys.memory_in,
            out_key=keys.memory_out,
            context_key=keys.context,
            valid_key=keys.context_valid,
            is_init_key=keys.is_init,
        )
        mem_dim = cfg.ct.dim
    else:
        raise ValueError(f"unknown memory {memory!r}; valid: ['ct', 'gru']")
    heads = make_heads_module(keys.memory_out, mem_dim, cfg, keys)
    return attach_output_spec(TensorDictSequential(encoder, mem_in_module, mem, heads), cfg, keys)
