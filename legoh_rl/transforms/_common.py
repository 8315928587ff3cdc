"""Small helpers shared by the transforms in this package (private)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey


def batch_flag(
    td: TensorDictBase | None, key: NestedKey | None, batch_size: torch.Size, what: str
) -> torch.Tensor | None:
    """Read a boolean per-world flag and return it with shape ``batch_size``.

    Accepts a flag stored as ``(*batch,)`` or ``(*batch, 1, ...)`` (trailing singleton or
    multi-entry dims are reduced with ``any``). Returns ``None`` when ``td`` is ``None``,
    ``key`` is ``None`` or the key is absent, so callers can decide what absence means.
    """
    if td is None or key is None:
        return None
    flag = td.get(key, None)
    if flag is None:
        return None
    flag = torch.as_tensor(flag)
    nb = len(batch_size)
    if tuple(flag.shape[:nb]) != tuple(batch_size):
        raise ValueError(
            f"{what} key {key!r} has shape {tuple(flag.shape)}, which does not start with the "
            f"batch size {tuple(batch_size)}"
        )
    flag = flag.bool()
    if flag.ndim > nb:
        flag = flag.flatten(nb).any(-1) if nb > 0 else flag.any()
    return flag


def expand_right(mask: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """View ``mask`` (shape ``like.shape[:mask.ndim]``) with trailing singleton dims added."""
    return mask.reshape(*mask.shape, *([1] * (like.ndim - mask.ndim)))
