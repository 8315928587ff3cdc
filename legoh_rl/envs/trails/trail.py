"""One finished trail (a tile) and its builder.

Tile frame: x along the trail from the tile's start edge, y centred on the tile's centre line,
z absolute (the start pad is at z = 0). P_A stands in the middle of the 1.5 m start pad,
P_B in the middle of the 1.5 m end pad, both on the centre line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .canvas import TileCanvas
from .categories import BODIES
from .config import (
    ALL_CATEGORIES,
    DEFAULT_HILL_LENGTH,
    DEFAULT_TILE_LENGTH,
    DEFAULT_TILE_WIDTH,
    END_PAD,
    START_PAD,
    check_category,
    check_level,
)
from .goals import GoalChecker, polyline_length, resolve_goals, waypoint_index
from .levels import sample_friction
from .obstacles import Obstacle, rasterise_tops
from .patch import num_samples
from .terrain_map import TerrainMap

__all__ = ["Trail", "build_trail", "trail_seed"]


@dataclass
class Trail:
    """A generated trail tile (all coordinates in the tile frame, see module docstring).

    Attributes:
        category, level, variant, seed: what was built.
        length, width, resolution: tile size and sample spacing, metres.
        heights: (nx, ny) bare heightfield, sample (i, j) at (i * res, -width / 2 + j * res).
        surface: (nx, ny) heights raised to obstacle tops.
        pit: (nx, ny) bool pit samples.
        obstacles: settled obstacle geoms.
        start, end, waypoint: (3,) P_A, P_B and the intermediate waypoint (z = bare ground).
        goals: (G, 3) expert goals in route order; ``goals[-1] == end``.
        route_length: length of the polyline P_A -> goals, metres.
        friction: lowest ground friction drawn by the tile's patches.
        params: difficulty parameters drawn while building, name -> values.
        sections: for hill trails, the categories chained in order; else ``(category,)``.
    """

    category: str
    level: int
    variant: int
    seed: int
    length: float
    width: float
    resolution: float
    heights: np.ndarray
    surface: np.ndarray
    pit: np.ndarray
    obstacles: list[Obstacle]
    start: np.ndarray
    end: np.ndarray
    waypoint: np.ndarray
    goals: np.ndarray
    route_length: float
    friction: float
    params: dict[str, list[float]] = field(default_factory=dict)
    sections: tuple[str, ...] = ()

    @property
    def shape(self) -> tuple[int, int]:
        """(nx, ny) samples."""
        return self.heights.shape  # type: ignore[return-value]

    @property
    def origin(self) -> tuple[float, float]:
        """(x, y) of sample (0, 0) in the tile frame."""
        return (0.0, -self.width / 2.0)

    @cached_property
    def map(self) -> TerrainMap:
        """Height / edge queries in the tile frame."""
        return TerrainMap(self.heights, self.surface, self.origin, self.resolution, pit=self.pit)

    def checker(self) -> GoalChecker:
        """The goal validity rules on this tile (see :mod:`.goals`)."""
        xs = np.arange(self.shape[0]) * self.resolution
        ys = np.arange(self.shape[1]) * self.resolution + self.origin[1]
        return GoalChecker(self.pit, self.obstacles, xs, ys, self.resolution)


def trail_seed(seed: int, category: str, level: int, variant: int) -> list[int]:
    """Entropy of the tile's random generator: ``[seed, category id, level, variant]``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(variant, bool) or not isinstance(variant, (int, np.integer)) or variant < 0:
        raise ValueError(f"variant must be a non-negative integer, got {variant!r}")
    return [int(seed), ALL_CATEGORIES.index(category), int(level), int(variant)]


def build_trail(
    category: str,
    level: int,
    seed: int = 0,
    variant: int = 0,
    length: float | None = None,
    width: float = DEFAULT_TILE_WIDTH,
    resolution: float = 0.1,
) -> Trail:
    """Generate one trail.

    Args:
        category: one of ``ALL_CATEGORIES`` (ValueError listing them otherwise).
        level: difficulty 0..4 (ValueError listing them otherwise).
        seed: master seed; with ``variant`` it fixes the trail (same inputs, same trail).
        variant: variant index (the grid column within the category).
        length: tile length, metres; default 12 m (36 m for "hill").
        width: tile width, metres.
        resolution: sample spacing, metres.

    Returns:
        The :class:`Trail`.
    """
    check_category(category)
    level = check_level(level)
    if length is None:
        length = DEFAULT_HILL_LENGTH if category == "hill" else DEFAULT_TILE_LENGTH
    if not (math.isfinite(length) and length >= 8.0):
        raise ValueError(f"trail length must be at least 8 m, got {length!r}")
    if not (math.isfinite(width) and width >= 3.0):
        raise ValueError(f"trail width must be at least 3 m, got {width!r}")
    if not (math.isfinite(resolution) and 0.01 <= resolution <= 0.5):
        raise ValueError(f"resolution must be in [0.01, 0.5] m, got {resolution!r}")
    rng = np.random.default_rng(trail_seed(seed, category, level, variant))
    cv = TileCanvas(length, width, resolution)
    n_end = num_samples(END_PAD, resolution)
    cv.flat_to(num_samples(START_PAD, resolution))
    start_xy = (START_PAD / 2.0, 0.0)
    end_xy = (cv.length - END_PAD / 2.0, 0.0)
    plan = BODIES[category](cv, cv.nx - n_end, level, rng, start_xy, end_xy)
    cv.flat_to(cv.nx)
    cv.settle()
    if category != "hill":
        cv.sections.append(category)

    surface = cv.heights.copy()
    origin = (0.0, -width / 2.0)
    rasterise_tops(cv.obstacles, surface, origin, resolution)
    checker = GoalChecker(cv.pit, cv.obstacles, cv.xs, cv.ys, resolution)
    goals_xy = resolve_goals(plan, checker, start_xy, end_xy)
    tmap = TerrainMap(cv.heights, surface, origin, resolution)

    def lift(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.c_[xy, tmap.height_at(xy, surface=False)]

    start = lift(start_xy)[0]
    goals = lift(goals_xy)
    wi = waypoint_index(start, goals)
    return Trail(
        category=category,
        level=level,
        variant=int(variant),
        seed=int(seed),
        length=cv.length,
        width=float(width),
        resolution=float(resolution),
        heights=cv.heights,
        surface=surface,
        pit=cv.pit,
        obstacles=cv.obstacles,
        start=start,
        end=goals[-1].copy(),
        waypoint=goals[wi].copy(),
        goals=goals,
        route_length=polyline_length(np.vstack([start[None, :2], goals[:, :2]])),
        friction=float(min(cv.frictions)) if cv.frictions else sample_friction(rng),
        params=cv.params,
        sections=tuple(cv.sections),
    )
