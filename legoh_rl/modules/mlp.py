"""Shared multi-layer perceptron builder and small tensor helpers.

Every MLP in :mod:`legoh_rl.modules` is built here, so the convention is the same for all
networks: ``layers`` lists the width of *every* linear layer, including the last one, and
``last_activation`` is the non-linearity after the last listed layer. The paper's
"[128, 64, 32], ELU hidden, Tanh out" scandot encoder is therefore
``build_mlp(132, (128, 64, 32), "elu", last_activation="tanh")``.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["ACTIVATIONS", "build_mlp", "make_activation", "unit_normalize"]

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "elu": nn.ELU,
    "relu": nn.ReLU,
    "gelu": nn.GELU,
    "tanh": nn.Tanh,
    "sigmoid": nn.Sigmoid,
    "silu": nn.SiLU,
    "identity": nn.Identity,
}


def make_activation(name: str | None) -> nn.Module:
    """Return a fresh activation module for ``name`` (``None`` means identity).

    Raises:
        ValueError: if ``name`` is not one of :data:`ACTIVATIONS`.
    """
    if name is None:
        return nn.Identity()
    key = name.lower()
    if key not in ACTIVATIONS:
        raise ValueError(
            f"unknown activation {name!r}; valid names: {sorted(ACTIVATIONS)}"
        )
    return ACTIVATIONS[key]()


def build_mlp(
    in_dim: int,
    layers: Sequence[int],
    activation: str = "elu",
    last_activation: str | None = "same",
) -> nn.Sequential:
    """Build ``Linear -> act -> ... -> Linear -> last_act``.

    Args:
        in_dim: input features ``D_in``; the MLP maps ``(*, D_in) -> (*, layers[-1])``.
        layers: width of every linear layer, the last one included (non-empty).
        activation: non-linearity after every layer but the last.
        last_activation: non-linearity after the last layer; ``"same"`` (default) repeats
            ``activation``, ``None`` leaves the last layer linear.

    Raises:
        ValueError: on an empty ``layers``, a non-positive width or an unknown activation.
    """
    widths = [int(w) for w in layers]
    if in_dim <= 0:
        raise ValueError(f"build_mlp: in_dim must be positive, got {in_dim}")
    if not widths:
        raise ValueError("build_mlp: layers must list at least one width")
    if any(w <= 0 for w in widths):
        raise ValueError(f"build_mlp: every layer width must be positive, got {list(layers)}")
    last = activation if last_activation == "same" else last_activation
    modules: list[nn.Module] = []
    dims = [int(in_dim), *widths]
    for i in range(len(widths)):
        modules.append(nn.Linear(dims[i], dims[i + 1]))
        modules.append(make_activation(activation if i < len(widths) - 1 else last))
    return nn.Sequential(*modules)


def unit_normalize(v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Scale the last dimension of ``v`` to unit length: ``(*, 2) -> (*, 2)``.

    Used for every angle the networks output: an angle is carried as (cos, sin), so the
    raw 2-vector of a linear head is projected onto the unit circle. ``eps`` keeps the
    gradient finite when the raw vector is (nearly) zero.
    """
    return v / v.norm(dim=-1, keepdim=True).clamp_min(eps)
