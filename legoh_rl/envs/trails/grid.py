"""The terrain grid: every trail tile in one heightfield (rows = levels, columns = categories x
variants, the legged_gym layout), compiled into one MuJoCo model, with per-tile arrays.

World layout: sample (0, 0) of the heightfield is at world (0, 0). A flat ``border`` surrounds
the tiles. Tile (row r, column c) covers x in [border + r * L, border + (r + 1) * L) and
y in [border + c * W, border + (c + 1) * W); its trail runs along +x, so walking past P_B leads
into the next (harder) level of the same column. Column c holds category
``categories[c // variants]``, variant ``c % variants``.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from .config import TrailGridConfig
from .levels import pit_depth
from .mujoco_spec import HFIELD_GEOM, add_terrain_to_spec, obstacle_geom_name
from .obstacles import Obstacle
from .patch import num_samples
from .terrain_map import TerrainMap
from .trail import Trail, build_trail

__all__ = ["TrailGrid", "build_trail_grid", "single_trail_grid"]


class TrailGrid:
    """All tiles of a terrain grid in one height map; vectorised queries; the MuJoCo hook.

    Args:
        trails: rows x columns of :class:`Trail`, all the same size and resolution.
        config: the configuration (border, edge map, base depth, friction, max goals).

    Attributes (R rows, C columns, G = ``config.max_goals``; world coordinates):
        map: the :class:`TerrainMap` of the whole grid (bare, surface, edges, pits).
        obstacles: every obstacle geom in world coordinates.
        categories: category name of each category index.
        tile_origin: (R, C, 3) tile centre (x, y) and z = 0, the start-pad height.
        tile_bounds: (R, C, 4) xmin, xmax, ymin, ymax.
        start, end, waypoint: (R, C, 3) P_A, P_B, intermediate waypoint (z = bare ground).
        route_length: (R, C) P_A -> goals -> P_B polyline length, metres.
        goals: (R, C, G, 3) expert goals, padded by repeating P_B; ``num_goals`` (R, C) int.
        tile_level, tile_category, tile_variant: (R, C) int.
        tile_friction: (R, C) lowest ground friction drawn for the tile (for per-world DR; the
            MuJoCo heightfield has one friction, ``config.ground_friction``).
    """

    def __init__(self, trails: list[list[Trail]], config: TrailGridConfig) -> None:
        if not trails or not trails[0]:
            raise ValueError("a TrailGrid needs at least one trail")
        ref = trails[0][0]
        n_cols = len(trails[0])
        for row in trails:
            if len(row) != n_cols:
                raise ValueError("every row of the grid must hold the same number of trails")
            for t in row:
                if t.shape != ref.shape or abs(t.resolution - ref.resolution) > 1e-12:
                    raise ValueError(
                        f"all tiles must share shape and resolution; got {t.shape} @ {t.resolution} "
                        f"vs {ref.shape} @ {ref.resolution}"
                    )
        self.config = config
        self.trails = trails
        self.categories: tuple[str, ...] = tuple(config.all_categories)
        res = ref.resolution
        self.resolution = res
        self.tile_length = ref.length
        self.tile_width = ref.width
        nb = num_samples(config.border, res) if config.border > 0 else 0
        tx, ty = ref.shape
        n_rows = len(trails)
        nx, ny = 2 * nb + n_rows * tx + 1, 2 * nb + n_cols * ty + 1
        bare = np.zeros((nx, ny))
        surface = np.zeros((nx, ny))
        pit = np.zeros((nx, ny), dtype=bool)
        g_max = config.max_goals
        shape = (n_rows, n_cols)
        self.tile_origin = np.zeros(shape + (3,))
        self.tile_bounds = np.zeros(shape + (4,))
        self.start = np.zeros(shape + (3,))
        self.end = np.zeros(shape + (3,))
        self.waypoint = np.zeros(shape + (3,))
        self.route_length = np.zeros(shape)
        self.goals = np.zeros(shape + (g_max, 3))
        self.num_goals = np.zeros(shape, dtype=np.int64)
        self.tile_level = np.zeros(shape, dtype=np.int64)
        self.tile_category = np.zeros(shape, dtype=np.int64)
        self.tile_variant = np.zeros(shape, dtype=np.int64)
        self.tile_friction = np.zeros(shape)
        self.obstacles: list[Obstacle] = []
        self.obstacle_tile = []
        for r, row in enumerate(trails):
            for c, t in enumerate(row):
                i0, j0 = nb + r * tx, nb + c * ty
                # pits of a shallower curriculum rung: their floors raised by the difference
                lift = _pit_lift(config, t.level) * t.pit
                bare[i0 : i0 + tx, j0 : j0 + ty] = t.heights + lift
                surface[i0 : i0 + tx, j0 : j0 + ty] = t.surface + lift
                pit[i0 : i0 + tx, j0 : j0 + ty] = t.pit
                ox, oy = i0 * res, j0 * res
                shift = np.array([ox, oy + t.width / 2.0, 0.0])
                self.tile_bounds[r, c] = (ox, ox + tx * res, oy, oy + ty * res)
                self.tile_origin[r, c] = (ox + tx * res / 2.0, oy + ty * res / 2.0, 0.0)
                self.start[r, c] = t.start + shift
                self.end[r, c] = t.end + shift
                self.waypoint[r, c] = t.waypoint + shift
                self.route_length[r, c] = t.route_length
                n = len(t.goals)
                if n > g_max:
                    raise ValueError(
                        f"trail {t.category} level {t.level} variant {t.variant} has {n} goals, more than "
                        f"max_goals={g_max}; raise TrailGridConfig.max_goals"
                    )
                self.goals[r, c, :n] = t.goals + shift
                self.goals[r, c, n:] = t.goals[-1] + shift
                self.num_goals[r, c] = n
                self.tile_level[r, c] = t.level
                self.tile_category[r, c] = self.categories.index(t.category)
                self.tile_variant[r, c] = t.variant
                self.tile_friction[r, c] = t.friction
                for ob in t.obstacles:
                    self.obstacles.append(ob.translated(*shift))
                    self.obstacle_tile.append((r, c))
        self.obstacle_tile = np.array(self.obstacle_tile, dtype=np.int64).reshape(-1, 2)
        self.map = TerrainMap(
            bare,
            surface,
            origin=(0.0, 0.0),
            resolution=res,
            edge_threshold=config.edge_threshold,
            edge_dilation=config.edge_dilation,
            pit=pit,
        )

    # ----------------------------------------------------------------- layout
    @property
    def num_rows(self) -> int:
        """Rows (levels) of the grid."""
        return self.start.shape[0]

    @property
    def num_columns(self) -> int:
        """Columns (categories x variants) of the grid."""
        return self.start.shape[1]

    def column(self, category: str, variant: int = 0) -> int:
        """Column index of ``category`` / ``variant`` (ValueError listing valid values)."""
        if category not in self.categories:
            raise ValueError(
                f"category {category!r} is not in this grid; grid categories: {', '.join(self.categories)}"
            )
        v = self.config.variants
        if not 0 <= int(variant) < v:
            raise ValueError(f"variant {variant!r} out of range; valid variants: 0..{v - 1}")
        return self.categories.index(category) * v + int(variant)

    def trail(self, row: int, column: int) -> Trail:
        """The :class:`Trail` of tile (row, column) (tile-frame coordinates)."""
        return self.trails[row][column]

    def tile_at(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) indices (each (...,) int) of the tiles under points (..., 2); -1 off tiles."""
        xy = np.asarray(xy, dtype=np.float64)
        x0, y0 = self.tile_bounds[0, 0, 0], self.tile_bounds[0, 0, 2]
        r = np.floor((xy[..., 0] - x0) / self.tile_length).astype(np.int64)
        c = np.floor((xy[..., 1] - y0) / self.tile_width).astype(np.int64)
        off = (r < 0) | (r >= self.num_rows) | (c < 0) | (c >= self.num_columns)
        return np.where(off, -1, r), np.where(off, -1, c)

    # ---------------------------------------------------------------- queries
    def height_at(
        self, xy: np.ndarray, surface: bool = True, interpolation: str = "bilinear"
    ) -> np.ndarray:
        """Terrain height (..., 2) -> (...,); ``surface`` includes obstacle tops (see TerrainMap)."""
        return self.map.height_at(xy, surface=surface, interpolation=interpolation)

    def edge_at(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) -> (...,) bool: the nearest sample is an edge sample."""
        return self.map.edge_at(xy)

    def pit_at(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) -> (...,) bool: the nearest sample is a pit sample."""
        return self.map.pit_at(xy)

    def spawn_positions(
        self, rows: np.ndarray, columns: np.ndarray, standing_height: float
    ) -> np.ndarray:
        """(N,) rows, (N,) columns -> (N, 3) spawn points: P_A lifted to the surface height there
        plus ``standing_height``."""
        rows = np.asarray(rows, dtype=np.int64)
        columns = np.asarray(columns, dtype=np.int64)
        p = self.start[rows, columns].copy()
        p[..., 2] = self.height_at(p[..., :2], surface=True) + standing_height
        return p

    def goals_of(self, rows: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) rows, (N,) columns -> goals (N, G, 3) and their counts (N,)."""
        rows = np.asarray(rows, dtype=np.int64)
        columns = np.asarray(columns, dtype=np.int64)
        return self.goals[rows, columns], self.num_goals[rows, columns]

    # ----------------------------------------------------------------- MuJoCo
    @property
    def obstacle_geom_names(self) -> list[str]:
        """MuJoCo names of the obstacle geoms, in ``obstacles`` order."""
        return [obstacle_geom_name(k, ob) for k, ob in enumerate(self.obstacles)]

    @property
    def terrain_geom_names(self) -> list[str]:
        """MuJoCo names of every terrain geom: the heightfield ("terrain") then the obstacles."""
        return [HFIELD_GEOM] + self.obstacle_geom_names

    def add_to_spec(self, spec: mujoco.MjSpec) -> None:
        """Add the terrain (one hfield asset + one hfield geom + obstacle geoms, all static, in
        spec.worldbody) to spec."""
        add_terrain_to_spec(
            spec,
            self.map.bare,
            self.map.origin,
            self.resolution,
            self.obstacles,
            base_depth=self.config.base_depth,
            friction=self.config.ground_friction,
        )

    # ---------------------------------------------------------------- export
    def to_trimesh(self, row: int | None = None, column: int | None = None):
        """The grid (or one tile, in world coordinates) as a ``trimesh.Scene``: geometry
        "terrain" (the heightfield surface) and one "obstacle_<k>" per obstacle."""
        from .mesh import terrain_scene

        if row is None and column is None:
            return terrain_scene(self.map.bare, self.map.origin, self.resolution, self.obstacles)
        if row is None or column is None:
            raise ValueError("give both row and column, or neither")
        tx, ty = self.trails[row][column].shape
        x0, _, y0, _ = self.tile_bounds[row, column]
        i0, j0 = int(round(x0 / self.resolution)), int(round(y0 / self.resolution))
        obs = [
            o
            for o, (r, c) in zip(self.obstacles, self.obstacle_tile, strict=True)
            if r == row and c == column
        ]
        return terrain_scene(
            self.map.bare[i0 : i0 + tx, j0 : j0 + ty], (x0, y0), self.resolution, obs
        )

    def export(self, path: str | Path, row: int | None = None, column: int | None = None) -> Path:
        """Write the grid (or one tile) as a mesh; format from the suffix (.glb, .obj, .ply, .stl)."""
        from .mesh import export_scene

        return export_scene(self.to_trimesh(row, column), path)


def _pit_lift(config: TrailGridConfig, level: int) -> float:
    """How far the pit floors of a level-``level`` tile are raised: the benchmark's depth minus
    ``config.pit_depths[level]`` (0 without ``pit_depths``, or where that is not shallower)."""
    if config.pit_depths is None:
        return 0.0
    return max(0.0, pit_depth(level) - config.pit_depths[level])


def build_trail_grid(config: TrailGridConfig | None = None) -> TrailGrid:
    """Generate every tile of ``config`` (default: 5 categories x 5 levels x 4 variants) and
    assemble the grid. Tile (level l, category k, variant v) equals
    ``build_trail(k, l, config.seed, v, config.tile_length, config.tile_width, config.resolution)``."""
    cfg = TrailGridConfig() if config is None else config
    rows = []
    for level in range(cfg.num_levels):
        row = []
        for cat in cfg.all_categories:
            for v in range(cfg.variants):
                row.append(
                    build_trail(
                        cat, level, cfg.seed, v, cfg.tile_length, cfg.tile_width, cfg.resolution
                    )
                )
        rows.append(row)
    return TrailGrid(rows, cfg)


def single_trail_grid(
    category: str,
    level: int,
    seed: int = 0,
    variant: int = 0,
    length: float | None = None,
    width: float = 5.0,
    resolution: float = 0.1,
    border: float = 1.0,
) -> TrailGrid:
    """A 1 x 1 grid holding one trail (for previews, exports and single-trail evaluation)."""
    t = build_trail(category, level, seed, variant, length, width, resolution)
    cfg = TrailGridConfig(
        categories=(category,),
        num_levels=1,
        variants=1,
        tile_length=t.length,
        tile_width=t.width,
        resolution=resolution,
        border=border,
        seed=seed,
        max_goals=max(24, len(t.goals)),
    )
    return TrailGrid([[t]], cfg)
