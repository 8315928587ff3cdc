"""Vectorised terrain queries on a regular height grid: heights and edges at many points at once.

Sample (i, j) sits at ``(x0 + i * res, y0 + j * res)``; ``bare`` is the heightfield (what MuJoCo's
hfield geom holds), ``surface`` the bare heights raised to the top of every obstacle over them
(what scandots and spawn heights need).

Edges: sample s is an edge sample when one of its 4 neighbours differs from it by more than
``edge_threshold`` on the *surface* map. Both samples of a jump are marked, so with the
nearest-sample lookup of :meth:`TerrainMap.edge_at` a point is "on an edge" within the jump's
cell interval dilated by ``res / 2`` on each side (5 cm at the default 0.1 m resolution);
``edge_dilation`` adds ``ceil(edge_dilation / res)`` more samples (a disc).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import binary_dilation

__all__ = ["TerrainMap", "compute_edges"]


def compute_edges(surface: np.ndarray, threshold: float, dilation_cells: int = 0) -> np.ndarray:
    """(nx, ny) bool edge mask of a height grid (see module docstring)."""
    e = np.zeros(surface.shape, dtype=bool)
    dx = np.abs(np.diff(surface, axis=0)) > threshold
    e[:-1] |= dx
    e[1:] |= dx
    dy = np.abs(np.diff(surface, axis=1)) > threshold
    e[:, :-1] |= dy
    e[:, 1:] |= dy
    if dilation_cells > 0:
        k = dilation_cells
        ii, jj = np.mgrid[-k : k + 1, -k : k + 1]
        e = binary_dilation(e, structure=(ii * ii + jj * jj) <= k * k)
    return e


class TerrainMap:
    """Height and edge queries for N points at once (numpy, no Python loop over points).

    Args:
        bare: (nx, ny) heightfield heights, metres.
        surface: (nx, ny) bare heights raised to obstacle tops; ``None`` -> same as ``bare``.
        origin: (x, y) of sample (0, 0), metres.
        resolution: sample spacing, metres.
        edge_threshold: height jump between neighbour samples that makes an edge, metres.
        edge_dilation: extra dilation of the edge mask, metres.
        pit: optional (nx, ny) bool pit samples (kept for the env / metrics).

    Queries outside the grid are clamped to its border samples.
    """

    def __init__(
        self,
        bare: np.ndarray,
        surface: np.ndarray | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
        resolution: float = 0.1,
        edge_threshold: float = 0.1,
        edge_dilation: float = 0.0,
        pit: np.ndarray | None = None,
    ) -> None:
        self.bare = np.ascontiguousarray(bare, dtype=np.float64)
        if self.bare.ndim != 2 or min(self.bare.shape) < 2:
            raise ValueError(
                f"bare heights must be a 2-D grid of at least 2 x 2, got shape {self.bare.shape}"
            )
        if not np.all(np.isfinite(self.bare)):
            raise ValueError("bare heights must be finite")
        self.surface = (
            self.bare if surface is None else np.ascontiguousarray(surface, dtype=np.float64)
        )
        if self.surface.shape != self.bare.shape:
            raise ValueError(f"surface shape {self.surface.shape} != bare shape {self.bare.shape}")
        if resolution <= 0:
            raise ValueError(f"resolution must be > 0, got {resolution!r}")
        self.origin = (float(origin[0]), float(origin[1]))
        self.resolution = float(resolution)
        self.edge_threshold = float(edge_threshold)
        self.edge_dilation = float(edge_dilation)
        self.pit = (
            np.zeros(self.bare.shape, dtype=bool) if pit is None else np.asarray(pit, dtype=bool)
        )
        cells = int(np.ceil(edge_dilation / resolution - 1e-9)) if edge_dilation > 0 else 0
        self.edge_mask = compute_edges(self.surface, self.edge_threshold, cells)

    @property
    def shape(self) -> tuple[int, int]:
        """(nx, ny)."""
        return self.bare.shape  # type: ignore[return-value]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the sample positions, metres."""
        nx, ny = self.bare.shape
        x0, y0 = self.origin
        return (x0, x0 + (nx - 1) * self.resolution, y0, y0 + (ny - 1) * self.resolution)

    def _frac(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape[-1] != 2:
            raise ValueError(f"points must have shape (..., 2), got {xy.shape}")
        nx, ny = self.bare.shape
        fi = np.clip((xy[..., 0] - self.origin[0]) / self.resolution, 0.0, nx - 1.0)
        fj = np.clip((xy[..., 1] - self.origin[1]) / self.resolution, 0.0, ny - 1.0)
        return fi, fj

    def index_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest sample indices (i, j), each (...,) int, of points (..., 2) (clamped)."""
        fi, fj = self._frac(xy)
        return np.rint(fi).astype(np.int64), np.rint(fj).astype(np.int64)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(...,) bool: the points (..., 2) lie within the sampled area."""
        xy = np.asarray(xy, dtype=np.float64)
        x0, x1, y0, y1 = self.extent
        return (xy[..., 0] >= x0) & (xy[..., 0] <= x1) & (xy[..., 1] >= y0) & (xy[..., 1] <= y1)

    def height_at(
        self, xy: np.ndarray, surface: bool = True, interpolation: str = "bilinear"
    ) -> np.ndarray:
        """Terrain height under points.

        Args:
            xy: (..., 2) world x, y (e.g. (N, 2) robots or (N, 132, 2) scandots).
            surface: True -> include obstacle tops; False -> bare heightfield.
            interpolation: "bilinear" or "nearest" (the sample the point is closest to).

        Returns:
            (...,) heights, metres.
        """
        grid = self.surface if surface else self.bare
        if interpolation == "nearest":
            i, j = self.index_of(xy)
            return grid[i, j]
        if interpolation != "bilinear":
            raise ValueError(
                f"unknown interpolation {interpolation!r}; valid: 'bilinear', 'nearest'"
            )
        fi, fj = self._frac(xy)
        nx, ny = grid.shape
        i0 = np.minimum(np.floor(fi).astype(np.int64), nx - 2)
        j0 = np.minimum(np.floor(fj).astype(np.int64), ny - 2)
        ti, tj = fi - i0, fj - j0
        h00, h10 = grid[i0, j0], grid[i0 + 1, j0]
        h01, h11 = grid[i0, j0 + 1], grid[i0 + 1, j0 + 1]
        return (h00 * (1 - ti) + h10 * ti) * (1 - tj) + (h01 * (1 - ti) + h11 * ti) * tj

    def edge_at(self, xy: np.ndarray) -> np.ndarray:
        """(...,) bool: the sample nearest to each point (..., 2) is an edge sample."""
        i, j = self.index_of(xy)
        return self.edge_mask[i, j]

    def pit_at(self, xy: np.ndarray) -> np.ndarray:
        """(...,) bool: the sample nearest to each point (..., 2) is a pit sample."""
        i, j = self.index_of(xy)
        return self.pit[i, j]
