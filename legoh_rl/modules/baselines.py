"""Baseline and ablation perception networks (paper Secs. "Ablation Study" and "Benchmark").

All write the same outputs as TC-ViT (``z_uni``, ``delta_g0``, ``goals_uni``) so recipes
swap them by name through :func:`legoh_rl.modules.perception.make_perception`:

* ``vanilla`` ("Vanilla", ConvGRU): a conv encoder over the whole depth-goal stack (the
  T x (1+G) planes as input channels) replaces TC-ViT's encoder; same MLP + GRU + heads.
* ``eph`` (EP-H, after Extreme Parkour): a CNN on the *current* depth frame only, with far
  depth cut off (normalised depth clipped at ``eph_depth_cutoff`` and rescaled to [0, 1]),
  then MLP + GRU + heads (the GRU predicts the latent and the goal yaws).
* ``rmah`` (RMA-H): a feed-forward adapter from ``proprio_history`` and the current depth
  frame (plus the GPS vectors) to the frozen oracle's latents (``z_uni`` estimates
  ``z_tea``, ``priv_latent_uni`` its privileged latent), with small goal heads. As in the
  paper, its locomotion is the oracle's actor, frozen
  (:func:`~legoh_rl.modules.locomotion.make_oracle_locomotion_actor`).
* ``rmab`` (RMA-B): the same adapter, blind (no depth).
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn

from legoh_rl.modules.adaptation import ProprioHistoryEncoder
from legoh_rl.modules.cnn import DepthCNN, check_trailing_shape
from legoh_rl.modules.configs import PerceptionConfig
from legoh_rl.modules.goal_adaptation import (
    attach_output_spec,
    make_heads_module,
    make_memory_perception,
)
from legoh_rl.modules.keys import PerceptionKeys
from legoh_rl.modules.mlp import build_mlp

__all__ = [
    "CutoffDepthEncoder",
    "RMAAdapter",
    "StackConvEncoder",
    "make_eph",
    "make_rmab",
    "make_rmah",
    "make_vanilla",
]


class StackConvEncoder(nn.Module):
    """ConvGRU's encoder: ``depth_goal_stack (*B, T, C, H, W) -> (*B, out_dim)``.

    The T frames' C planes are stacked as ``T * C`` input channels of one CNN.
    """

    def __init__(self, cfg: PerceptionConfig) -> None:
        super().__init__()
        io = cfg.io
        self.in_shape = (io.num_frames, io.stack_channels, io.image_size, io.image_size)
        self.cnn = DepthCNN(io.num_frames * io.stack_channels, io.image_size, cfg.vanilla_cnn,
                            name="vanilla ConvGRU encoder")
        self.out_dim = self.cnn.out_dim

    def forward(self, depth_goal_stack: torch.Tensor) -> torch.Tensor:
        """Encode the stack."""
        check_trailing_shape("StackConvEncoder (depth_goal_stack)", depth_goal_stack, self.in_shape)
        return self.cnn(depth_goal_stack.flatten(-4, -3))


class CutoffDepthEncoder(nn.Module):
    """EP-H's encoder: ``depth (*B, 1, H, W) -> (*B, out_dim)``, far depth cut off.

    ``depth`` is normalised to [0, 1] (near..far); values beyond ``cutoff`` are clipped to
    it and the result is rescaled by ``1 / cutoff``, so only the near range is seen.
    """

    def __init__(self, cfg: PerceptionConfig) -> None:
        super().__init__()
        self.cutoff = float(cfg.eph_depth_cutoff)
        self.cnn = DepthCNN(1, cfg.io.image_size, cfg.cnn, name="EP-H depth CNN (depth)")
        self.out_dim = self.cnn.out_dim

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        """Clip, rescale and encode the current depth frame."""
        return self.cnn(depth.clamp(max=self.cutoff) / self.cutoff)


class RMAAdapter(nn.Module):
    """RMA adapter trunk: ``(proprio_history, goal_gps, waypoint_gps[, depth]) -> (*B, F)``.

    ``proprio_history`` ``(*B, T_h, D)`` goes through a
    :class:`~legoh_rl.modules.adaptation.ProprioHistoryEncoder`; with ``use_depth`` the
    current ``depth`` ``(*B, 1, H, W)`` through a :class:`DepthCNN`; everything is
    concatenated with the GPS vectors (``goal_gps`` (*B, 2) and, when
    ``cfg.io.num_waypoints`` is 1, ``waypoint_gps`` (*B, 2)) and passed through the
    ``rma_layers`` MLP. With M = 0: ``forward(proprio_history, goal_gps[, depth])``.
    """

    def __init__(self, cfg: PerceptionConfig, use_depth: bool) -> None:
        super().__init__()
        io = cfg.io
        hist_dim = int(cfg.rma_layers[0])
        self.history = ProprioHistoryEncoder(io.proprio_dim, io.history_len, cfg.history,
                                             hist_dim, out_activation="elu")
        self.use_depth = use_depth
        self.num_waypoints = int(io.num_waypoints)
        in_dim = hist_dim + io.gps_inputs * io.gps_dim
        if use_depth:
            self.cnn = DepthCNN(1, io.image_size, cfg.cnn, name="RMA-H depth CNN (depth)")
            in_dim += self.cnn.out_dim
        self.trunk = build_mlp(in_dim, cfg.rma_layers, "elu")
        self.out_dim = int(cfg.rma_layers[-1])

    def forward(self, proprio_history, goal_gps, *rest) -> torch.Tensor:
        """Encode the inputs into trunk features (``rest``: ``[waypoint_gps][, depth]``)."""
        expected = self.num_waypoints + int(self.use_depth)
        if len(rest) != expected:
            names = ["waypoint_gps"] * self.num_waypoints + ["depth"] * int(self.use_depth)
            raise TypeError(
                f"RMAAdapter takes (proprio_history, goal_gps, {', '.join(names) or '-'}) here "
                f"(num_waypoints={self.num_waypoints}, use_depth={self.use_depth}), got "
                f"{2 + len(rest)} inputs"
            )
        parts = [self.history(proprio_history), goal_gps, *rest[: self.num_waypoints]]
        if self.use_depth:
            parts.append(self.cnn(rest[-1]))
        return self.trunk(torch.cat(parts, dim=-1))


def make_vanilla(cfg: PerceptionConfig, keys: PerceptionKeys | None = None) -> TensorDictSequential:
    """``vanilla``: ConvGRU (conv encoder over the depth-goal stack, then MLP + GRU + heads)."""
    cfg.validate()
    keys = keys or PerceptionKeys()
    enc = StackConvEncoder(cfg)
    module = TensorDictModule(enc, in_keys=[keys.depth_goal_stack], out_keys=[keys.features])
    return make_memory_perception(module, enc.out_dim, cfg, keys, memory="gru")


def make_eph(cfg: PerceptionConfig, keys: PerceptionKeys | None = None) -> TensorDictSequential:
    """``eph``: EP-H (per-frame CNN on cut-off current depth, MLP + GRU + heads)."""
    cfg.validate()
    keys = keys or PerceptionKeys()
    enc = CutoffDepthEncoder(cfg)
    module = TensorDictModule(enc, in_keys=[keys.depth], out_keys=[keys.features])
    return make_memory_perception(module, enc.out_dim, cfg, keys, memory="gru")


def _make_rma(cfg: PerceptionConfig, keys: PerceptionKeys | None, use_depth: bool):
    cfg.validate()
    keys = keys or PerceptionKeys()
    adapter = RMAAdapter(cfg, use_depth)
    in_keys = [keys.proprio_history, keys.goal_gps] + [keys.waypoint_gps] * cfg.io.num_waypoints
    if use_depth:
        in_keys.append(keys.depth)
    trunk = TensorDictModule(adapter, in_keys=in_keys, out_keys=[keys.features])
    heads = make_heads_module(keys.features, adapter.out_dim, cfg, keys)
    # RMA's adapter maps the sensors to the oracle's whole latent: the scandot latent (z_uni)
    # and the privileged one, which a frozen oracle actor reads as the student's locomotion
    priv = TensorDictModule(nn.Linear(adapter.out_dim, cfg.io.priv_latent_dim), in_keys=[keys.features],
                            out_keys=[keys.priv_latent_uni])
    return attach_output_spec(TensorDictSequential(trunk, heads, priv), cfg, keys, priv_latent=True)


def make_rmah(cfg: PerceptionConfig, keys: PerceptionKeys | None = None) -> TensorDictSequential:
    """``rmah``: RMA-H adapter (proprio history + current depth -> oracle latent + goals)."""
    return _make_rma(cfg, keys, use_depth=True)


def make_rmab(cfg: PerceptionConfig, keys: PerceptionKeys | None = None) -> TensorDictSequential:
    """``rmab``: RMA-B adapter (blind: proprio history + GPS -> oracle latent + goals)."""
    return _make_rma(cfg, keys, use_depth=False)
