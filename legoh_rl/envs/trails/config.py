"""Names, layout constants and the grid configuration of the trail generator.

Every validation error names the bad value and lists the valid ones.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

__all__ = [
    "CATEGORIES",
    "ALL_CATEGORIES",
    "NUM_LEVELS",
    "START_PAD",
    "END_PAD",
    "GOAL_OBSTACLE_CLEARANCE",
    "GOAL_PIT_CLEARANCE",
    "FOREST_PLAN_CLEARANCE",
    "LEVEL0_MAX_STEP",
    "PIT_DEPTH",
    "PIT_DEPTH_LEVEL0",
    "DEFAULT_TILE_LENGTH",
    "DEFAULT_TILE_WIDTH",
    "DEFAULT_HILL_LENGTH",
    "TrailGridConfig",
    "check_category",
    "check_level",
]

#: The five in-domain trail categories of the paper, in grid column order.
CATEGORIES: tuple[str, ...] = ("randommix", "ditch", "hurdle", "gap", "forest")
#: In-domain categories plus the out-of-domain long "hill" trails.
ALL_CATEGORIES: tuple[str, ...] = CATEGORIES + ("hill",)
#: Difficulty levels 0..NUM_LEVELS-1.
NUM_LEVELS = 5

#: Flat pad at the start of every tile (P_A stands in its middle), metres.
START_PAD = 1.5
#: Flat pad at the end of every tile (P_B stands in its middle), metres.
END_PAD = 1.5
#: Minimum horizontal distance of every expert goal from every obstacle footprint, metres.
GOAL_OBSTACLE_CLEARANCE = 0.3
#: Every heightfield sample within this distance of a goal is off pits, metres.
GOAL_PIT_CLEARANCE = 0.15
#: Obstacle inflation used by the Forest path planner (> GOAL_OBSTACLE_CLEARANCE), metres.
FOREST_PLAN_CLEARANCE = 0.35
#: On level-0 trails P_B is reachable from P_A through 4-neighbour moves whose surface height
#: change is at most this (a step a blind beginner walks), metres.
LEVEL0_MAX_STEP = 0.15
#: Depth of gap / stepping-stone pits below the local ground from level 1 on, metres.
PIT_DEPTH = 1.0
#: Depth of the pits on level 0 (a crack a beginner walks through), metres.
PIT_DEPTH_LEVEL0 = 0.1

DEFAULT_TILE_LENGTH = 12.0
DEFAULT_TILE_WIDTH = 5.0
#: Default length of a stand-alone hill trail (``build_trail("hill", ...)``), metres.
DEFAULT_HILL_LENGTH = 36.0


def check_category(category: str) -> str:
    """Return ``category`` if it is a known trail category, else raise ValueError listing them."""
    if not isinstance(category, str) or category not in ALL_CATEGORIES:
        raise ValueError(
            f"unknown trail category {category!r}; valid categories: {', '.join(ALL_CATEGORIES)}"
        )
    return category


def check_level(level: int, num_levels: int = NUM_LEVELS) -> int:
    """Return ``level`` as int if it is in 0..num_levels-1, else raise ValueError listing them."""
    valid = ", ".join(str(i) for i in range(num_levels))
    try:
        lv = operator.index(level)
    except TypeError:
        raise ValueError(
            f"difficulty level must be an integer, got {level!r}; valid levels: {valid}"
        ) from None
    if isinstance(level, bool) or not 0 <= lv < num_levels:
        raise ValueError(f"difficulty level {level!r} is out of range; valid levels: {valid}")
    return lv


def _is_multiple(value: float, step: float) -> bool:
    k = value / step
    return abs(k - round(k)) < 1e-6


@dataclass(frozen=True)
class TrailGridConfig:
    """Configuration of a terrain grid (rows = levels, columns = categories x variants).

    Attributes:
        categories: trail categories, in column order (lower-case names from ``ALL_CATEGORIES``).
        num_levels: rows of the grid, levels 0..num_levels-1 (at most 5).
        variants: seeded variants per category (columns per category).
        tile_length: tile size along the trail direction (+x), metres.
        tile_width: tile size across the trail (y), metres.
        resolution: horizontal heightfield sample spacing, metres.
        border: flat ground around the whole grid, metres.
        seed: master seed; tile (level l, category k, variant v) uses seed ``[seed, k_id, l, v]``.
        include_hills: append the out-of-domain "hill" category to ``categories``.
        edge_threshold: height jump between neighbour samples that makes an edge, metres.
        edge_dilation: extra dilation of the edge map beyond half a sample, metres.
        base_depth: depth of MuJoCo's heightfield base box below the lowest sample, metres.
        ground_friction: sliding friction of the heightfield geom.
        max_goals: goals per tile are padded to this count (raises if a trail needs more).
        pit_depths: per level, how deep gap and stepping-stone pits go at most, metres (one value
            per level; ``None``: the benchmark's 0.1 m on level 0 and 1.0 m above). A training
            curriculum can give the deep pits intermediate rungs this way; evaluation grids keep
            ``None``.
    """

    categories: tuple[str, ...] = CATEGORIES
    num_levels: int = NUM_LEVELS
    variants: int = 4
    tile_length: float = DEFAULT_TILE_LENGTH
    tile_width: float = DEFAULT_TILE_WIDTH
    resolution: float = 0.1
    border: float = 2.0
    seed: int = 0
    include_hills: bool = False
    edge_threshold: float = 0.1
    edge_dilation: float = 0.0
    base_depth: float = 1.0
    ground_friction: float = 1.0
    max_goals: int = 24
    pit_depths: tuple[float, ...] | None = None
    _all: tuple[str, ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        cats = (
            tuple(self.categories) if not isinstance(self.categories, str) else (self.categories,)
        )
        if not cats:
            raise ValueError(
                f"categories must not be empty; valid categories: {', '.join(ALL_CATEGORIES)}"
            )
        for c in cats:
            check_category(c)
        if len(set(cats)) != len(cats):
            raise ValueError(f"categories must be unique, got {cats}")
        object.__setattr__(self, "categories", cats)
        all_cats = cats + (("hill",) if self.include_hills and "hill" not in cats else ())
        object.__setattr__(self, "_all", all_cats)
        if not isinstance(self.num_levels, int) or not 1 <= self.num_levels <= NUM_LEVELS:
            raise ValueError(
                f"num_levels must be an integer in 1..{NUM_LEVELS}, got {self.num_levels!r}"
            )
        if not isinstance(self.variants, int) or self.variants < 1:
            raise ValueError(f"variants must be a positive integer, got {self.variants!r}")
        if not (math.isfinite(self.resolution) and 0.01 <= self.resolution <= 0.5):
            raise ValueError(f"resolution must be in [0.01, 0.5] m, got {self.resolution!r}")
        for name, lo in (("tile_length", 8.0), ("tile_width", 3.0)):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= lo):
                raise ValueError(f"{name} must be at least {lo} m, got {v!r}")
            if not _is_multiple(v, self.resolution):
                raise ValueError(f"{name}={v} must be a multiple of resolution={self.resolution}")
        if not (
            math.isfinite(self.border)
            and self.border >= 0
            and _is_multiple(self.border, self.resolution)
        ):
            raise ValueError(
                f"border must be >= 0 and a multiple of resolution={self.resolution}, got {self.border!r}"
            )
        if not self.edge_threshold > 0:
            raise ValueError(f"edge_threshold must be > 0, got {self.edge_threshold!r}")
        if not self.edge_dilation >= 0:
            raise ValueError(f"edge_dilation must be >= 0, got {self.edge_dilation!r}")
        if not self.base_depth > 0:
            raise ValueError(f"base_depth must be > 0, got {self.base_depth!r}")
        if not self.ground_friction > 0:
            raise ValueError(f"ground_friction must be > 0, got {self.ground_friction!r}")
        if not isinstance(self.max_goals, int) or self.max_goals < 2:
            raise ValueError(f"max_goals must be an integer >= 2, got {self.max_goals!r}")
        if self.pit_depths is not None:
            depths = tuple(float(d) for d in self.pit_depths)
            if len(depths) != self.num_levels or not all(math.isfinite(d) and d > 0 for d in depths):
                raise ValueError(
                    f"pit_depths must give one positive depth (m) per level ({self.num_levels}), "
                    f"got {self.pit_depths!r}"
                )
            object.__setattr__(self, "pit_depths", depths)

    @property
    def all_categories(self) -> tuple[str, ...]:
        """Categories in column order, with "hill" appended when ``include_hills``."""
        return self._all

    @property
    def num_columns(self) -> int:
        """Columns of the grid: ``len(all_categories) * variants``."""
        return len(self._all) * self.variants

    @classmethod
    def out_of_domain(cls, variants: int = 2, seed: int = 0, **kwargs) -> TrailGridConfig:
        """Preset for the long out-of-domain hill trails: categories=("hill",), 36 m tiles."""
        kwargs.setdefault("tile_length", DEFAULT_HILL_LENGTH)
        kwargs.setdefault("max_goals", 64)
        return cls(categories=("hill",), variants=variants, seed=seed, **kwargs)
