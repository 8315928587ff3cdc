"""Terrain curriculum (paper appendix "Curriculum Learning").

Each world has a terrain level. When its episode ends, the distance it progressed along the
trail is compared with the distance expected from its commanded speed over the episode length
(capped at the trail's route length, since the trail ends there):

* progress > 80% of the expected distance (or the trail end reached): level up;
* progress < 40%: level down (not below 0);
* a world that levels up past the top level is reassigned to a uniformly random level.

Worlds keep their trail category; a new level puts them on a random variant of that category at
that level (a different tile of the grid; the MuJoCo model is not rebuilt).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from legoh_rl.kinds import Flag, Number, check_fields, setting

__all__ = ["CurriculumConfig", "Curriculum", "world_categories"]


@dataclass
class CurriculumConfig:
    """Thresholds as fractions of the expected distance (paper: 0.8 up, 0.4 down)."""

    enabled: bool = setting(True, Flag())
    up: float = setting(0.8, Number(0))
    down: float = setting(0.4, Number(0))

    def __post_init__(self) -> None:
        check_fields(self)  # each field against its kind (legoh_rl/kinds.py)
        if not 0.0 <= self.down < self.up:
            raise ValueError(f"need 0 <= down < up, got down={self.down}, up={self.up}")


def world_categories(num_worlds: int, categories: np.ndarray, weights=None) -> np.ndarray:
    """The trail category of each world, for good: ``categories`` (C,) int round-robin, or in
    shares proportional to ``weights`` (C,) positive (counts by largest remainder, ties to the
    earlier category). Returns (num_worlds,) int.

    Raises:
        ValueError: ``weights`` does not hold one positive weight per category.
    """
    categories = np.asarray(categories, dtype=np.int64)
    if weights is None:
        return categories[np.arange(num_worlds) % categories.size]
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != categories.shape or not np.all(w > 0):
        raise ValueError(f"need one positive weight per category ({categories.size}), got {list(weights)}")
    quota = num_worlds * w / w.sum()
    counts = np.floor(quota).astype(np.int64)
    rest = num_worlds - int(counts.sum())
    counts[np.argsort(-(quota - counts), kind="stable")[:rest]] += 1
    return np.repeat(categories, counts)


class Curriculum:
    """Level bookkeeping for N worlds.

    Args:
        cfg: thresholds.
        num_levels: levels available (0 .. num_levels - 1).
        levels: initial level of each world, (N,) int.
    """

    def __init__(self, cfg: CurriculumConfig, num_levels: int, levels: np.ndarray) -> None:
        self.cfg = cfg
        self.num_levels = int(num_levels)
        self.levels = np.asarray(levels, dtype=np.int64).copy()

    def update(
        self,
        ids: np.ndarray,
        progress: np.ndarray,
        expected: np.ndarray,
        reached: np.ndarray,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Move worlds ``ids`` between levels after their episodes; return their new levels.

        Args:
            ids: (n,) worlds whose episode ended.
            progress: (n,) distance progressed along the trail, m.
            expected: (n,) expected distance (commanded speed x episode length, capped), m.
            reached: (n,) bool, the trail end was reached.
            rng: generator for the random reassignment.
        """
        if not self.cfg.enabled or ids.size == 0:
            return self.levels[ids]
        ratio = progress / np.maximum(expected, 1e-6)
        up = reached | (ratio > self.cfg.up)
        down = ~up & (ratio < self.cfg.down)
        new = self.levels[ids] + up.astype(np.int64) - down.astype(np.int64)
        past_top = new >= self.num_levels
        new[past_top] = rng.integers(0, self.num_levels, size=int(past_top.sum()))
        self.levels[ids] = np.maximum(new, 0)
        return self.levels[ids]

    def state_dict(self) -> dict:
        """Checkpointable state."""
        return {"levels": self.levels.copy()}

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict`."""
        levels = np.asarray(state["levels"], dtype=np.int64)
        if levels.shape != self.levels.shape:
            raise ValueError(f"curriculum state for {levels.shape[0]} worlds, env has {self.levels.shape[0]}")
        self.levels = levels.copy()
