"""Adapter from the trail generator's :class:`~legoh_rl.envs.trails.TrailGrid` to the env.

The grid stores its tiles as ``(rows, columns, ...)`` arrays (rows = levels); the env addresses
tiles by a flat index ``t = row * columns + column``. This class flattens the per-tile arrays and
forwards the terrain queries, so the env depends only on the small
:class:`~legoh_rl.envs.hiking.TrailSource` protocol.
"""

from __future__ import annotations

import mujoco
import numpy as np

from legoh_rl.envs.trails import TrailGrid, TrailGridConfig, build_trail_grid, check_category

__all__ = ["GridTrails", "trails_for", "validate_categories"]


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
    ``tile_num_goals`` (T,); ``tile_route_length`` (T,).
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

    def add_to_spec(self, spec: mujoco.MjSpec) -> None:
        """Add the grid's heightfield and obstacles to a model spec."""
        self.grid.add_to_spec(spec)

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Surface height (ground and obstacle tops) at world points, (M, 2) -> (M,)."""
        return self.grid.height_at(xy)

    def edge_at(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points lie on an edge cell, (M, 2) -> (M,) bool."""
        return self.grid.edge_at(xy)


def trails_for(categories, variants: int, seed: int, **grid_kwargs) -> GridTrails:
    """Build the trail grid of the given categories (all levels) and wrap it for the env."""
    cfg = TrailGridConfig(categories=validate_categories(categories), variants=int(variants), seed=int(seed), **grid_kwargs)
    return GridTrails(build_trail_grid(cfg))
