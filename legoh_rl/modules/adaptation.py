"""Adaptation module: estimate the oracle's privileged latent from proprioceptive history.

As in RMA and Extreme Parkour (which the paper follows for the oracle stage), a history
encoder maps ``proprio_history`` ``(T_h, D)`` to an estimate of ``priv_latent`` (20). The
recipe trains it by regression to the frozen oracle's ``priv_latent`` and can then run
the oracle on the estimate (:func:`legoh_rl.modules.oracle.make_oracle_actor` with
``priv_latent_module=``).
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn

from legoh_rl.modules.cnn import check_trailing_shape
from legoh_rl.modules.configs import AdaptationConfig, HistoryEncoderConfig
from legoh_rl.modules.keys import AdaptationKeys
from legoh_rl.modules.mlp import build_mlp, make_activation

__all__ = ["ProprioHistoryEncoder", "make_adaptation_module"]


class ProprioHistoryEncoder(nn.Module):
    """Encode ``(*B, T_h, D) -> (*B, out_dim)``.

    ``kind="conv"``: per-step ``Linear(D, embed_dim)`` + ELU, then ``Conv1d`` (ELU) layers
    over time, flatten, ``Linear`` to ``out_dim``. ``kind="mlp"``: flattened history through
    an ELU MLP, then ``Linear`` to ``out_dim``. The output linear has ``out_activation``.

    Raises:
        ValueError: if the history is too short for the conv kernels, or on bad sizes.
    """

    def __init__(
        self,
        proprio_dim: int,
        history_len: int,
        cfg: HistoryEncoderConfig,
        out_dim: int,
        out_activation: str | None = None,
    ) -> None:
        super().__init__()
        cfg.validate(history_len)
        self.in_shape = (int(history_len), int(proprio_dim))
        self.kind = cfg.kind
        self.out_dim = int(out_dim)
        if cfg.kind == "conv":
            self.embed = nn.Sequential(nn.Linear(proprio_dim, cfg.embed_dim), nn.ELU())
            convs: list[nn.Module] = []
            c_in, length = cfg.embed_dim, history_len
            for c_out, k, s in zip(cfg.channels, cfg.kernel_sizes, cfg.strides, strict=True):
                convs += [nn.Conv1d(c_in, c_out, k, stride=s), nn.ELU()]
                c_in, length = c_out, (length - k) // s + 1
            self.body = nn.Sequential(*convs)
            flat = c_in * length
        else:
            self.embed = nn.Identity()
            self.body = build_mlp(history_len * proprio_dim, cfg.mlp_layers, "elu")
            flat = int(cfg.mlp_layers[-1])
        self.out = nn.Sequential(nn.Linear(flat, out_dim), make_activation(out_activation))

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        """Encode a history ``(*B, T_h, D)`` (oldest first)."""
        check_trailing_shape("ProprioHistoryEncoder (proprio_history)", history, self.in_shape)
        lead = history.shape[:-2]
        x = history.reshape(-1, *self.in_shape)
        if self.kind == "conv":
            x = self.body(self.embed(x).transpose(1, 2)).flatten(1)
        else:
            x = self.body(x.flatten(1))
        return self.out(x).reshape(*lead, self.out_dim)


def make_adaptation_module(
    cfg: AdaptationConfig, keys: AdaptationKeys | None = None
) -> TensorDictModule:
    """TensorDictModule ``proprio_history (T_h, D) -> priv_latent_hat (latent_dim,)``.

    The output key is ``keys.priv_latent`` (default ``"priv_latent_hat"``, so it never
    overwrites the oracle's ``priv_latent`` target during regression).
    """
    cfg.validate()
    keys = keys or AdaptationKeys()
    net = ProprioHistoryEncoder(
        cfg.proprio_dim, cfg.history_len, cfg.encoder, cfg.latent_dim, cfg.out_activation
    )
    return TensorDictModule(net, in_keys=[keys.proprio_history], out_keys=[keys.priv_latent])
