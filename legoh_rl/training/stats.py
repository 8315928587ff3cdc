"""Turn collected batches into scalars to log: episode metrics, reward terms, curriculum."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

__all__ = ["episode_stats", "reward_term_stats", "split_episode_stats", "curriculum_stats"]

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


def split_episode_stats(data: TensorDictBase, categories: tuple[str, ...], prefix: str = "episode") -> dict[str, float]:
    """Success and trail completion of the episodes that ended in ``data``, split by trail
    category and by level: ``{prefix}/<category>/success``, ``{prefix}/level<l>/success`` (and
    ``/trail_completion``, ``/episodes``), for the groups with at least one ended episode.

    Args:
        data: a collected batch ([..., T]) with ``("next", "episode", ...)`` entries.
        categories: the trail grid's category names; ``("episode", "category")`` indexes them.
    """
    nxt = data["next"]
    done = nxt["done"].squeeze(-1)
    if not bool(done.any()):
        return {}
    cat = nxt["episode", "category"].squeeze(-1)[done]
    lvl = nxt["episode", "level"].squeeze(-1)[done]
    vals = {m: nxt["episode", m].squeeze(-1)[done].float() for m in ("success", "trail_completion")}
    out: dict[str, float] = {}
    groups = [(name, cat == i) for i, name in enumerate(categories)]
    groups += [(f"level{int(v)}", lvl == v) for v in torch.unique(lvl)]
    for name, mask in groups:
        n = int(mask.sum())
        if n:
            out[f"{prefix}/{name}/episodes"] = float(n)
            for m, v in vals.items():
                out[f"{prefix}/{name}/{m}"] = float(v[mask].mean())
    return out


def curriculum_stats(levels, world_category, categories: tuple[str, ...], prefix: str = "curriculum") -> dict[str, float]:
    """Mean terrain level of the worlds of each category: ``{prefix}/<category>``.

    Args:
        levels: (N,) int, each world's curriculum level.
        world_category: (N,) int, each world's category index into ``categories``.
    """
    out = {}
    for i, name in enumerate(categories):
        mask = world_category == i
        if mask.any():
            out[f"{prefix}/{name}"] = float(levels[mask].mean())
    return out
