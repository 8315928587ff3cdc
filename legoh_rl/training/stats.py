"""Turn collected batches into scalars to log: episode metrics, reward terms, curriculum."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

__all__ = ["episode_stats", "reward_term_stats", "split_episode_stats", "curriculum_stats", "ending_stats",
           "return_stats", "explained_variance"]

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


def curriculum_stats(levels, world_category, categories: tuple[str, ...], prefix: str = "curriculum",
                     num_levels: int = 5) -> dict[str, float]:
    """Mean terrain level of the worlds of each category, ``{prefix}/<category>``, and the
    distribution of the worlds over the levels, ``{prefix}/share_level<l>`` (fractions summing to 1).

    Args:
        levels: (N,) int, each world's curriculum level.
        world_category: (N,) int, each world's category index into ``categories``.
        num_levels: levels 0 .. num_levels - 1 get a share each.
    """
    out = {}
    for i, name in enumerate(categories):
        mask = world_category == i
        if mask.any():
            out[f"{prefix}/{name}"] = float(levels[mask].mean())
    n = max(len(levels), 1)
    for level in range(num_levels):
        out[f"{prefix}/share_level{level}"] = float((levels == level).sum()) / n
    return out


def ending_stats(data: TensorDictBase, prefix: str = "episode/") -> dict[str, float]:
    """How the episodes that ended in ``data`` ended, as shares (%) of them: ``{prefix}end_goal``
    (reached the trail end), ``end_fall`` (terminated otherwise: a fall) and ``end_timeout``
    (truncated: the time limit, or a diverged world reset). {} when no episode ended.

    Args:
        data: a collected batch ([..., T]) with ``("next", "done" | "terminated")`` (bool, [..., T, 1])
            and ``("next", "episode", "success")`` (% of the ended episode, 0 or 100).
    """
    nxt = data["next"]
    done = nxt["done"].squeeze(-1)
    n = int(done.sum())
    if n == 0:
        return {}
    terminated = nxt["terminated"].squeeze(-1)[done]
    goal = nxt["episode", "success"].squeeze(-1)[done] > 50.0
    return {f"{prefix}end_goal": 100.0 * float((terminated & goal).sum()) / n,
            f"{prefix}end_fall": 100.0 * float((terminated & ~goal).sum()) / n,
            f"{prefix}end_timeout": 100.0 * float((~terminated).sum()) / n}


def return_stats(data: TensorDictBase, prefix: str = "episode/") -> dict[str, float]:
    """Mean undiscounted return (``{prefix}return``) and length in control steps
    (``{prefix}length``) of the episodes that ended in ``data``, from torchrl's ``RewardSum``
    (``("next", "episode_reward")``) and ``StepCounter`` (``("next", "step_count")``) entries,
    both [..., T, 1]; the figures whose entry is absent are left out."""
    nxt = data["next"]
    done = nxt["done"].squeeze(-1)
    if not bool(done.any()):
        return {}
    out = {}
    for key, name in (("episode_reward", "return"), ("step_count", "length")):
        if key in nxt.keys():
            out[f"{prefix}{name}"] = float(nxt[key].squeeze(-1)[done].float().mean())
    return out


def explained_variance(values: torch.Tensor, targets: torch.Tensor) -> float:
    """1 - Var(targets - values) / Var(targets): how much of the return targets' variance the
    critic explains (1: perfect, 0: no better than their mean, < 0: worse). NaN when the
    targets do not vary. Any matching shapes."""
    var = float(targets.float().var())
    if not var > 0.0:
        return math.nan
    return 1.0 - float((targets.float() - values.float()).var()) / var
