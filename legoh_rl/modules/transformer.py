"""Pre-norm transformer building blocks (TC-ViT encoder and the causal-transformer ablation).

Attention uses :func:`torch.nn.functional.scaled_dot_product_attention`, which picks the
fastest kernel for the device (flash / memory-efficient on GPU, a fused kernel on CPU).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["FactorisedSpaceTimeBlock", "MultiHeadSelfAttention", "TransformerBlock"]


class MultiHeadSelfAttention(nn.Module):
    """Multi-head self-attention: ``(B, L, D) -> (B, L, D)``.

    Args:
        dim: token width D. heads: number of heads (must divide D). dropout: attention and
            output dropout probability.
    """

    def __init__(self, dim: int, heads: int, dropout: float = 0.0) -> None:
        super().__init__()
        if dim % heads:
            raise ValueError(f"attention dim {dim} is not divisible by heads {heads}")
        self.heads = heads
        self.head_dim = dim // heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        self.dropout = dropout
        self.proj_drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, attn_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Attend over ``L``.

        Args:
            x: tokens ``(B, L, D)``.
            attn_mask: optional bool mask ``(B, L, L)`` (or broadcastable): ``True`` where
                query ``i`` may attend to key ``j``. Every row must allow at least one key.
        """
        b, n, d = x.shape
        qkv = self.qkv(x).view(b, n, 3, self.heads, self.head_dim).permute(2, 0, 3, 1, 4)
        q, k, v = qkv.unbind(0)
        if attn_mask is not None and attn_mask.dim() == 3:
            attn_mask = attn_mask.unsqueeze(1)  # broadcast over heads
        out = F.scaled_dot_product_attention(
            q, k, v, attn_mask=attn_mask, dropout_p=self.dropout if self.training else 0.0
        )
        out = out.transpose(1, 2).reshape(b, n, d)
        return self.proj_drop(self.proj(out))


def _feed_forward(dim: int, mlp_ratio: float, dropout: float) -> nn.Sequential:
    hidden = max(1, int(round(dim * mlp_ratio)))
    return nn.Sequential(
        nn.Linear(dim, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, dim),
        nn.Dropout(dropout),
    )


class TransformerBlock(nn.Module):
    """Pre-norm transformer block: ``x + MHSA(LN(x))`` then ``x + MLP(LN(x))``.

    Shapes: ``(B, L, D) -> (B, L, D)``; ``attn_mask`` as in :class:`MultiHeadSelfAttention`.
    """

    def __init__(self, dim: int, heads: int, mlp_ratio: float = 4.0, dropout: float = 0.0):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = MultiHeadSelfAttention(dim, heads, dropout)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = _feed_forward(dim, mlp_ratio, dropout)

    def forward(self, x: torch.Tensor, attn_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Apply the block to ``x`` ``(B, L, D)``."""
        x = x + self.attn(self.norm1(x), attn_mask)
        return x + self.mlp(self.norm2(x))


class FactorisedSpaceTimeBlock(nn.Module):
    """ViViT "factorised self-attention" block (ViViT model 3) on ``(B, T, S, D)`` tokens.

    Spatial attention among the S patches of each frame, then temporal attention among the
    T frames at each patch location, then a token-wise MLP; all pre-norm and residual.
    """

    def __init__(self, dim: int, heads: int, mlp_ratio: float = 4.0, dropout: float = 0.0):
        super().__init__()
        self.norm_s = nn.LayerNorm(dim)
        self.attn_s = MultiHeadSelfAttention(dim, heads, dropout)
        self.norm_t = nn.LayerNorm(dim)
        self.attn_t = MultiHeadSelfAttention(dim, heads, dropout)
        self.norm_mlp = nn.LayerNorm(dim)
        self.mlp = _feed_forward(dim, mlp_ratio, dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Apply the block to tokens ``(B, T, S, D)``; returns the same shape."""
        b, t, s, d = x.shape
        xs = x.reshape(b * t, s, d)
        xs = xs + self.attn_s(self.norm_s(xs))
        xt = xs.view(b, t, s, d).transpose(1, 2).reshape(b * s, t, d)
        xt = xt + self.attn_t(self.norm_t(xt))
        x = xt.view(b, s, t, d).transpose(1, 2)
        return x + self.mlp(self.norm_mlp(x))
