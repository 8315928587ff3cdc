"""Adapter from the trail generator's :class:`~legoh_rl.envs.trails.TrailGrid` to the env.

The grid stores its tiles as ``(rows, columns, ...)`` arrays (rows = levels); the env addresses
tiles by a flat index ``t = row * columns + column``. This class flattens the per-tile arrays and
forwards the terrain queries, so the env depends only on the small
:class:`~legoh_rl.envs.hiking.TrailSource` protocol.
"""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from legoh_rl.envs.height_map import HeightMap
from legoh_rl.envs.trails import TrailGrid, TrailGridConfig, build_trail_grid, check_category

__all__ = ["GridTrails", "trails_for", "validate_categories", "VIEW_RADIUS"]

#: Horizontal reach of the head camera's rays (4 m z-depth at 45 deg pitch, 58 deg fov), m.
VIEW_RADIUS = 6.0


def validate_categories(categories) -> tuple[str, ...]:
    """The categories as a tuple, after checking each name (ValueError lists the valid ones)."""
    cats = (categories,) if isinstance(categories, str) else tuple(categories)
    if not cats:
        raise ValueError("at least one trail category is needed")
    for c in cats:
        check_category(c)
    return cats


class GridTrails:
    """Flat per-tile view of a :class:`TrailGrid` (T = rows x columns tiles).

    Attributes: ``categories``, ``num_levels``; ``tile_level``, ``tile_category`` (T,) int;
    ``tile_start``, ``tile_end``, ``tile_waypoint`` (T, 3); ``tile_goals`` (T, G, 3);
    ``tile_num_goals`` (T,); ``tile_route_length`` (T,). ``height_at_t`` and
    ``ground_height_at_t`` are torch versions of the height queries (used by the depth camera).
    """

    def __init__(self, grid: TrailGrid) -> None:
        self.grid = grid
        self.categories = tuple(grid.categories)
        self.num_levels = int(grid.config.num_levels)
        t = grid.num_rows * grid.num_columns
        self.tile_level = grid.tile_level.reshape(t)
        self.tile_category = grid.tile_category.reshape(t)
        self.tile_start = grid.start.reshape(t, 3)
        self.tile_end = grid.end.reshape(t, 3)
        self.tile_waypoint = grid.waypoint.reshape(t, 3)
        self.tile_goals = grid.goals.reshape(t, grid.goals.shape[2], 3)
        self.tile_num_goals = grid.num_goals.reshape(t)
        self.tile_route_length = grid.route_length.reshape(t)
        tm = grid.map
        origin, res = tuple(tm.origin), tm.resolution
        #: torch height maps (world xy tensors in, heights out), used by the depth camera
        self.height_at_t = HeightMap(tm.surface, origin, res)
        self.ground_height_at_t = HeightMap(tm.bare, origin, res)
        # highest surface / lowest ground within VIEW_RADIUS of every sample: the band of heights
        # where a camera's rays can hit (used to bracket the ray march)
        cells = 2 * int(np.ceil(VIEW_RADIUS / tm.resolution)) + 1
        self._zmax = HeightMap(maximum_filter(tm.surface, size=cells, mode="nearest"), origin, res)
        self._zmin = HeightMap(minimum_filter(tm.bare, size=cells, mode="nearest"), origin, res)

    def add_to_spec(self, spec: mujoco.MjSpec) -> None:
        """Add the grid's heightfield and obstacles to a model spec."""
        self.grid.add_to_spec(spec)

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Surface height (ground and obstacle tops) at world points, (M, 2) -> (M,)."""
        return self.height_at_t.numpy(xy)

    def height_around(self, xy: np.ndarray, yaw: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Surface heights at points ``offsets`` (K, 2) in the yaw frames of robots at ``xy`` (N, 2)
        with headings ``yaw`` (N,), (N, K) (the scandots' lookup, one native call)."""
        return self.height_at_t.numpy_around(xy, yaw, offsets)

    def ground_height_at(self, xy: np.ndarray) -> np.ndarray:
        """Bare heightfield height (no obstacles) at world points, (M, 2) -> (M,)."""
        return self.ground_height_at_t.numpy(xy)

    def max_height_near(self, xy: np.ndarray) -> np.ndarray:
        """Highest surface within ``VIEW_RADIUS`` (6 m) of world points, (M, 2) -> (M,): no ray
        from a camera there can hit the terrain above this height (used to skip ray marching)."""
        return self._zmax.numpy(xy)

    def min_height_near(self, xy: np.ndarray) -> np.ndarray:
        """Lowest ground within ``VIEW_RADIUS`` of world points, (M, 2) -> (M,): a ray from a
        camera there that has descended below this height has already hit the terrain."""
        return self._zmin.numpy(xy)

    def edge_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points lie on an edge cell, (M, 2) -> (M,) bool."""
        return self.grid.edge_at(xy)

    def pit_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points lie over a pit sample (gaps, stone fields), (M, 2) -> (M,) bool."""
        return self.grid.pit_at(xy)

    @property
    def edge_grid(self) -> tuple[np.ndarray, tuple[float, float], float]:
        """What :meth:`edge_at` reads: the edge mask (nx, ny) bool, the world (x0, y0) of sample
        (0, 0) and the sample spacing, m (a point reads its nearest sample)."""
        tm = self.grid.map
        return tm.edge_mask, tuple(tm.origin), tm.resolution

    @property
    def pit_grid(self) -> tuple[np.ndarray, tuple[float, float], float]:
        """What :meth:`pit_at` reads, as :attr:`edge_grid`: the pit mask (nx, ny) bool, origin, spacing."""
        tm = self.grid.map
        return tm.pit, tuple(tm.origin), tm.resolution


def trails_for(categories, variants: int, seed: int, **grid_kwargs) -> GridTrails:
    """Build the trail grid of the given categories (all levels) and wrap it for the env."""
    cfg = TrailGridConfig(categories=validate_categories(categories), variants=int(variants), seed=int(seed), **grid_kwargs)
    return GridTrails(build_trail_grid(cfg))
