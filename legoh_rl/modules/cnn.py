"""Shallow convolutional encoder for depth images (TC-ViT's beta branch and the baselines)."""

from __future__ import annotations

import torch
from torch import nn

from legoh_rl.modules.configs import DepthCNNConfig

__all__ = ["DepthCNN", "check_trailing_shape"]


def check_trailing_shape(name: str, x: torch.Tensor, expected: tuple[int, ...]) -> None:
    """Raise ``ValueError`` if the last ``len(expected)`` dims of ``x`` are not ``expected``."""
    n = len(expected)
    if x.dim() < n or tuple(x.shape[-n:]) != tuple(expected):
        raise ValueError(
            f"{name}: expected trailing shape {tuple(expected)}, got tensor of shape "
            f"{tuple(x.shape)}"
        )


class DepthCNN(nn.Module):
    """Conv (ELU) stack -> flatten -> linear (ELU): ``(*B, C, H, W) -> (*B, out_dim)``.

    Args:
        in_channels: C. image_size: H = W. cfg: layer sizes (padding ``kernel // 2``).
        name: used in shape errors.
    """

    def __init__(
        self, in_channels: int, image_size: int, cfg: DepthCNNConfig, name: str = "DepthCNN"
    ) -> None:
        super().__init__()
        cfg.validate()
        self.name = name
        self.in_shape = (int(in_channels), int(image_size), int(image_size))
        layers: list[nn.Module] = []
        c_in, size = int(in_channels), int(image_size)
        for c_out, k, s in zip(cfg.channels, cfg.kernel_sizes, cfg.strides, strict=True):
            layers += [nn.Conv2d(c_in, c_out, k, stride=s, padding=k // 2), nn.ELU()]
            size = (size + 2 * (k // 2) - k) // s + 1
            if size < 1:
                raise ValueError(
                    f"{name}: image size {image_size} shrinks to nothing with kernel_sizes="
                    f"{cfg.kernel_sizes}, strides={cfg.strides}"
                )
            c_in = c_out
        self.convs = nn.Sequential(*layers)
        self.flat_dim = c_in * size * size
        self.head = nn.Sequential(nn.Linear(self.flat_dim, cfg.out_dim), nn.ELU())
        self.out_dim = int(cfg.out_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Encode images ``(*B, C, H, W)`` into ``(*B, out_dim)``."""
        check_trailing_shape(self.name, x, self.in_shape)
        lead = x.shape[:-3]
        y = self.convs(x.reshape(-1, *self.in_shape))
        return self.head(y.flatten(1)).reshape(*lead, self.out_dim)
