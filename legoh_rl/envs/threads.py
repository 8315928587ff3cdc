"""Temporarily run torch's CPU operators on a given number of threads."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["torch_threads"]


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Inside the block torch uses ``n`` intra-op threads; the previous count is restored after.

    The env steps physics on all its threads, then renders depth with torch: training recipes keep
    torch on one thread for the networks, which would leave the other cores idle while rendering.
    Switching costs well under a microsecond.

    Raises:
        ValueError: ``n`` is not a positive integer.
    """
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"thread count must be a positive integer, got {n!r}")
    prev = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(prev)
