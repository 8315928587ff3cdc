"""TC-ViT's visual encoder (paper Sec. "TC-ViT", parts a-b and the gamma fusion).

* :class:`GoalConditionedViViT` (part a): the depth-goal stack ``(T, 1+G, H, W)`` (the final
  goal is already tiled as extra image planes by the ``GoalTiling`` transform, so it is
  fused at tokenisation) is cut into ``P x P`` patches of every frame, embedded, given
  learned spatial and temporal position embeddings, and processed by ``layers``
  factorised space-time blocks (ViViT model 3: spatial attention within each frame, then
  temporal attention across frames at each patch location). alpha is the flattened
  token set (``T * S * dim``) or, optionally, the mean token.
* beta (part b): :class:`~legoh_rl.modules.cnn.DepthCNN` on the current depth frame, no
  goal input.
* :class:`TCViTEncoder`: ``gamma = MLP(concat(alpha, beta))``.
"""

from __future__ import annotations

import torch
from torch import nn

from legoh_rl.modules.cnn import DepthCNN, check_trailing_shape
from legoh_rl.modules.configs import PerceptionConfig, ViViTConfig
from legoh_rl.modules.mlp import build_mlp
from legoh_rl.modules.transformer import FactorisedSpaceTimeBlock

__all__ = ["GoalConditionedViViT", "TCViTEncoder"]


class GoalConditionedViViT(nn.Module):
    """Factorised space-time transformer: ``(*B, T, C, H, W) -> alpha (*B, out_dim)``.

    Args:
        in_channels: C = 1 + G (depth plus tiled goal planes).
        num_frames: T. image_size: H = W (divisible by ``cfg.patch_size``).
        cfg: transformer size; ``out_dim`` is ``T * (H/P)**2 * dim`` with
            ``alpha_pooling="flatten"``, ``dim`` with ``"mean"``.

    Raises:
        ValueError: if the image size is not divisible by the patch size, or on bad sizes.
    """

    def __init__(self, in_channels: int, num_frames: int, image_size: int, cfg: ViViTConfig):
        super().__init__()
        cfg.validate(image_size)
        self.in_shape = (int(num_frames), int(in_channels), int(image_size), int(image_size))
        self.grid = image_size // cfg.patch_size
        self.num_patches = self.grid * self.grid
        self.dim = cfg.dim
        self.pooling = cfg.alpha_pooling
        self.patch_embed = nn.Conv2d(
            in_channels, cfg.dim, kernel_size=cfg.patch_size, stride=cfg.patch_size
        )
        self.pos_space = nn.Parameter(torch.zeros(1, 1, self.num_patches, cfg.dim))
        self.pos_time = nn.Parameter(torch.zeros(1, num_frames, 1, cfg.dim))
        nn.init.trunc_normal_(self.pos_space, std=0.02)
        nn.init.trunc_normal_(self.pos_time, std=0.02)
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(
            FactorisedSpaceTimeBlock(cfg.dim, cfg.heads, cfg.mlp_ratio, cfg.dropout)
            for _ in range(cfg.layers)
        )
        self.norm = nn.LayerNorm(cfg.dim)
        n_tokens = num_frames * self.num_patches
        self.out_dim = n_tokens * cfg.dim if self.pooling == "flatten" else cfg.dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Encode a depth-goal stack ``(*B, T, C, H, W)`` into alpha ``(*B, out_dim)``."""
        check_trailing_shape("GoalConditionedViViT (depth_goal_stack)", x, self.in_shape)
        lead = x.shape[:-4]
        t, c, h, w = self.in_shape
        frames = x.reshape(-1, c, h, w)
        tokens = self.patch_embed(frames).flatten(2).transpose(1, 2)  # (B*T, S, D)
        tokens = tokens.reshape(-1, t, self.num_patches, self.dim)
        tokens = self.drop(tokens + self.pos_space + self.pos_time)
        for block in self.blocks:
            tokens = block(tokens)
        tokens = self.norm(tokens)
        alpha = tokens.flatten(1) if self.pooling == "flatten" else tokens.mean(dim=(1, 2))
        return alpha.reshape(*lead, self.out_dim)


class TCViTEncoder(nn.Module):
    """TC-ViT visual encoder: ``(depth_goal_stack, depth) -> gamma``.

    Shapes: ``depth_goal_stack`` ``(*B, T, 1+G, H, W)``, ``depth`` ``(*B, 1, H, W)`` ->
    ``gamma`` ``(*B, cfg.gamma_dim)``. ``out_dim`` is ``cfg.gamma_dim``.
    """

    def __init__(self, cfg: PerceptionConfig) -> None:
        super().__init__()
        cfg.validate()
        io = cfg.io
        self.vivit = GoalConditionedViViT(io.stack_channels, io.num_frames, io.image_size, cfg.vit)
        self.cnn = DepthCNN(1, io.image_size, cfg.cnn, name="TCViT depth CNN (depth)")
        self.fusion = build_mlp(self.vivit.out_dim + self.cnn.out_dim, cfg.fusion_layers, "elu")
        self.out_dim = cfg.gamma_dim

    def forward(self, depth_goal_stack: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Return gamma = MLP(concat(alpha(depth_goal_stack), beta(depth)))."""
        alpha = self.vivit(depth_goal_stack)
        beta = self.cnn(depth)
        return self.fusion(torch.cat([alpha, beta], dim=-1))
