"""Turn collected batches into scalars to log: episode metrics, reward terms, curriculum."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

__all__ = ["episode_stats", "reward_term_stats"]

METRICS = ("success", "trail_completion", "traverse_rate", "mev", "ttf", "time_to_reach")


def episode_stats(data: TensorDictBase, prefix: str = "episode/") -> dict[str, float]:
    """Mean of each episode metric over the episodes that ended in ``data`` ([..., T] batch).

    ``time_to_reach`` is averaged over successful episodes only. Returns {} when no episode
    ended. Also reports ``episodes`` (count) and ``level`` (mean trail level of those episodes).
    """
    nxt = data["next"]
    done = nxt["done"].squeeze(-1)
    n = int(done.sum())
    if n == 0:
        return {}
    out = {f"{prefix}episodes": float(n)}
    for name in METRICS:
        v = nxt["episode", name].squeeze(-1)[done].float()
        v = v[~torch.isnan(v)]
        out[f"{prefix}{name}"] = float(v.mean()) if v.numel() else math.nan
    out[f"{prefix}level"] = float(nxt["episode", "level"].squeeze(-1)[done].float().mean())
    return out


def reward_term_stats(data: TensorDictBase, prefix: str = "reward/") -> dict[str, float]:
    """Mean per step of each weighted reward term and of the total reward."""
    nxt = data["next"]
    out = {f"{prefix}total": float(nxt["reward"].mean())}
    for name, value in nxt["reward_terms"].items():
        out[f"{prefix}{name}"] = float(value.mean())
    return out
