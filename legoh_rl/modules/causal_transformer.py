"""Causal transformer over a rolling window of steps (the ``tcvit_ct`` ablation's memory).

The paper compares TC-ViT's GRU with a causal transformer (CT) at the same place. A CT
needs the tokens of the last W-1 steps; inside a TorchRL ``Collector`` the policy only
sees one step at a time, so this module keeps them in the TensorDict, exactly like a GRU
keeps its hidden state:

* ``context`` ``(W-1, dim)``: the previous W-1 input tokens, oldest first;
* ``context_valid`` ``(W-1,)`` bool: which of them belong to the current episode.

Per step (sequential mode) it reads both from the root, attends causally over
``[context, token]`` (masked by validity; ``is_init`` invalidates the whole context),
and writes the shifted window to ``("next", context)`` / ``("next", context_valid)``,
which ``step_mdp`` moves to the root for the next step. :meth:`make_tensordict_primer`
returns the ``TensorDictPrimer`` that registers and zero-fills both keys at reset, so
``torchrl.modules.utils.get_primers_from_module`` finds it like a GRU's.

In recurrent mode (``with torchrl.modules.set_recurrent_mode(True)``) on ``[N, T]``
batches the tokens of all T steps are recomputed with the current parameters (so
gradients flow through the whole window); only the context stored at ``t = 0`` (steps
from before the batch) is read from the data. Episode boundaries inside the batch are
found from ``is_init``. Both modes give the same outputs.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import Unbounded
from torchrl.modules import recurrent_mode

from legoh_rl.modules.configs import CausalTransformerConfig
from legoh_rl.modules.keys import NestedKey
from legoh_rl.modules.transformer import TransformerBlock

__all__ = ["CausalTransformerMemory"]


def _next(key: NestedKey) -> tuple:
    return ("next", *key) if isinstance(key, tuple) else ("next", key)


class CausalTransformerMemory(TensorDictModuleBase):
    """Causal transformer memory with a rolling-window context kept in the TensorDict.

    Args:
        input_size: size of the per-step input token (``in_key``, ``(input_size,)``).
        cfg: window W and transformer size.
        in_key: per-step input. out_key: output ``(cfg.dim,)``.
        context_key, valid_key: the rolling buffer keys (see module docstring).
        is_init_key: episode-start flag ``(1,)`` (written by ``InitTracker``).
    """

    def __init__(
        self,
        input_size: int,
        cfg: CausalTransformerConfig,
        *,
        in_key: NestedKey,
        out_key: NestedKey,
        context_key: NestedKey = "perception_context",
        valid_key: NestedKey = "perception_context_valid",
        is_init_key: NestedKey = "is_init",
    ) -> None:
        super().__init__()
        cfg.validate()
        self.window = cfg.window
        self.dim = cfg.dim
        self.in_key, self.out_key = in_key, out_key
        self.context_key, self.valid_key, self.is_init_key = context_key, valid_key, is_init_key
        self.in_keys = [in_key, context_key, valid_key, is_init_key]
        self.out_keys = [out_key, _next(context_key), _next(valid_key)]
        self.input_proj = nn.Linear(input_size, cfg.dim)
        self.pos = nn.Parameter(torch.zeros(cfg.window, cfg.dim))
        nn.init.trunc_normal_(self.pos, std=0.02)
        self.blocks = nn.ModuleList(
            TransformerBlock(cfg.dim, cfg.heads, cfg.mlp_ratio, cfg.dropout)
            for _ in range(cfg.layers)
        )
        self.norm = nn.LayerNorm(cfg.dim)
        causal = torch.ones(cfg.window, cfg.window, dtype=torch.bool).tril()
        self.register_buffer("_causal", causal, persistent=False)
        self.register_buffer("_eye", torch.eye(cfg.window, dtype=torch.bool), persistent=False)

    def make_tensordict_primer(self):
        """Return the ``TensorDictPrimer`` for the context buffer and its validity mask."""
        from torchrl.envs import TensorDictPrimer

        return TensorDictPrimer(
            {
                self.context_key: Unbounded(shape=(self.window - 1, self.dim)),
                self.valid_key: Unbounded(shape=(self.window - 1,), dtype=torch.bool),
            },
            expand_specs=True,
        )

    def _attend(self, seq: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """Run the blocks on windows ``(B, W, dim)`` with key validity ``(B, W)``.

        Query i attends to keys j <= i that are valid, and always to itself (so no row is
        empty); the returned feature is the last (current) position ``(B, dim)``.
        """
        mask = self._causal & (valid.unsqueeze(-2) | self._eye)  # (B, W, W)
        x = seq + self.pos
        for block in self.blocks:
            x = block(x, mask)
        return self.norm(x[:, -1])

    def _zeros_context(self, lead, device, dtype):
        ctx = torch.zeros(*lead, self.window - 1, self.dim, device=device, dtype=dtype)
        valid = torch.zeros(*lead, self.window - 1, device=device, dtype=torch.bool)
        return ctx, valid

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Sequential (one step per batch element) or recurrent (``[N, T]``) forward."""
        if recurrent_mode():
            return self._forward_recurrent(tensordict)
        return self._forward_step(tensordict)

    def _is_init(self, td: TensorDictBase) -> torch.Tensor:
        is_init = td.get(self.is_init_key, None)
        if is_init is None:
            raise KeyError(
                f"CausalTransformerMemory needs the episode-start flag {self.is_init_key!r}; "
                "add torchrl's InitTracker() to the env"
            )
        return is_init.bool()

    def _read_context(self, td: TensorDictBase, tokens: torch.Tensor):
        ctx = td.get(self.context_key, None)
        valid = td.get(self.valid_key, None)
        if ctx is None or valid is None:
            ctx, valid = self._zeros_context(tokens.shape[:-1], tokens.device, tokens.dtype)
        return ctx, valid.bool()

    def _forward_step(self, td: TensorDictBase) -> TensorDictBase:
        tokens = self.input_proj(td.get(self.in_key))  # (*B, dim)
        lead = tokens.shape[:-1]
        ctx, valid = self._read_context(td, tokens)
        is_init = self._is_init(td).reshape(*lead, 1)
        valid = valid & ~is_init
        ctx = torch.where(is_init.unsqueeze(-1), torch.zeros_like(ctx), ctx)
        seq = torch.cat([ctx, tokens.unsqueeze(-2)], dim=-2)  # (*B, W, dim)
        seq_valid = torch.cat([valid, torch.ones_like(valid[..., :1])], dim=-1)
        out = self._attend(seq.reshape(-1, self.window, self.dim), seq_valid.reshape(-1, self.window))
        td.set(self.out_key, out.reshape(*lead, self.dim))
        td.set(_next(self.context_key), seq[..., 1:, :])
        td.set(_next(self.valid_key), seq_valid[..., 1:])
        return td

    def _forward_recurrent(self, td: TensorDictBase) -> TensorDictBase:
        if td.ndim == 0:
            raise ValueError(
                "CausalTransformerMemory in recurrent mode needs a time dimension; got a "
                "tensordict with empty batch size"
            )
        shape = td.shape
        tdr = td.unsqueeze(0) if td.ndim == 1 else td.reshape(-1, shape[-1])  # (N, T)
        n, t = tdr.shape
        w = self.window
        tokens = self.input_proj(tdr.get(self.in_key))  # (N, T, dim)
        ctx_all, valid_all = self._read_context(tdr, tokens)
        ctx0 = ctx_all[:, 0].to(tokens.dtype)  # (N, W-1, dim): steps before the batch
        is_init = self._is_init(tdr).reshape(n, t)
        episode = is_init.long().cumsum(dim=1)  # (N, T): 0 = episode running at t=0
        valid0 = valid_all[:, 0]  # (N, W-1)
        full = torch.cat([ctx0, tokens], dim=1)  # (N, W-1+T, dim)
        windows = full.unfold(1, w, 1).permute(0, 1, 3, 2)  # (N, T, W, dim)
        # Validity of window position k for query step q: global index g = q + k, sequence
        # step s = g - (W-1). Context entries (s < 0) count if stored valid and no reset
        # happened in [0, q]; in-batch entries if same episode as q.
        ep_full = torch.cat([torch.zeros_like(episode[:, :1]).expand(n, w - 1), episode], dim=1)
        valid_full = torch.cat([valid0, torch.ones_like(is_init)], dim=1)  # (N, W-1+T)
        ep_win = ep_full.unfold(1, w, 1)  # (N, T, W)
        valid_win = valid_full.unfold(1, w, 1) & (ep_win == episode.unsqueeze(-1))
        out = self._attend(windows.reshape(n * t, w, self.dim), valid_win.reshape(n * t, w))
        tdr.set(self.out_key, out.reshape(n, t, self.dim))
        tdr.set(_next(self.context_key), windows[:, :, 1:, :])
        tdr.set(_next(self.valid_key), valid_win[:, :, 1:])
        if tdr is not td:
            td.update(tdr.reshape(shape) if td.ndim > 1 else tdr.squeeze(0))
        return td
