"""Procedural hiking trails (LEGO-H appendix "Simulated Hiking Trail Constructions").

16 terrain primitives -> 5 trail categories (+ out-of-domain hills) x 5 levels x seeded
variants -> one terrain grid compiled into one MuJoCo model (one heightfield + obstacle geoms),
with vectorised height / edge queries and per-tile start, end, waypoint and expert goals.
See ``docs/trails.md``.
"""

from .config import (
    ALL_CATEGORIES,
    CATEGORIES,
    NUM_LEVELS,
    TrailGridConfig,
    check_category,
    check_level,
)
from .grid import TrailGrid, build_trail_grid, single_trail_grid
from .levels import PARAMS, LevelParam
from .obstacles import Obstacle
from .patch import Patch, Spot
from .primitives import PRIMITIVES, PrimitiveSpec, make_primitive
from .terrain_map import TerrainMap
from .trail import Trail, build_trail

__all__ = [
    "ALL_CATEGORIES",
    "CATEGORIES",
    "NUM_LEVELS",
    "PARAMS",
    "PRIMITIVES",
    "LevelParam",
    "Obstacle",
    "Patch",
    "PrimitiveSpec",
    "Spot",
    "TerrainMap",
    "Trail",
    "TrailGrid",
    "TrailGridConfig",
    "build_trail",
    "build_trail_grid",
    "check_category",
    "check_level",
    "make_primitive",
    "single_trail_grid",
]
