"""Expert navigation goals (LEGO-H appendix "Oracle Navigation Goal Design").

* open trails (RandomMix): evenly spaced points on the straight line along the trail, each
  snapped to the nearest valid sample if it fell on a pit or near an obstacle;
* terrain-specific trails (Ditch, Hurdle, Gap): the primitives' take-off / landing / stone /
  rim spots, in crossing order;
* obstructed trails (Forest): a shortest path on the sample grid around obstacles inflated by
  ``FOREST_PLAN_CLEARANCE``, under a smooth random cost field (different seeds detour
  differently), resampled every metre.

Every goal is *valid*: inside the tile (0.4 m from its sides), no pit sample within
``GOAL_PIT_CLEARANCE`` and no obstacle footprint within ``GOAL_OBSTACLE_CLEARANCE``. Straight
stretches longer than 2 m between goals get intermediate valid goals. The last goal is P_B.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from .config import GOAL_OBSTACLE_CLEARANCE, GOAL_PIT_CLEARANCE
from .obstacles import Obstacle
from .patch import Spot, rough_field

__all__ = [
    "EvenSegment",
    "GoalChecker",
    "plan_path",
    "resample_path",
    "resolve_goals",
    "waypoint_index",
    "polyline_length",
    "SIDE_MARGIN",
    "MAX_GOAL_SPACING",
]

#: Goals keep this far from the tile's long sides, metres.
SIDE_MARGIN = 0.4
#: Straight stretches between goals longer than this get intermediate goals, metres.
MAX_GOAL_SPACING = 2.0
#: Obstacle distances are exact up to this range (beyond it they read +inf), metres.
_DIST_RANGE = 1.0


@dataclass(frozen=True)
class EvenSegment:
    """Evenly spaced goals from ``a`` to ``b`` (both excluded), about ``spacing`` apart."""

    a: tuple[float, float]
    b: tuple[float, float]
    spacing: float = 1.5


class GoalChecker:
    """Validity of goal positions on one tile.

    Args:
        pit: (nx, ny) bool pit samples; sample (i, j) at ``(xs[i], ys[j])``.
        obstacles: obstacles in the same frame.
        xs: (nx,) sample x; ys: (ny,) sample y (centred on the tile line).
        resolution: sample spacing, metres.
        obstacle_clearance / pit_clearance: the rules of the module docstring.

    Attributes:
        obstacle_distance: (nx, ny) distance of each sample to the nearest obstacle footprint
            (negative inside; +inf beyond 1 m).
        pit_distance: (nx, ny) distance of each sample to the nearest pit sample (+inf if none).
        valid: (nx, ny) bool samples that are valid goal positions.
    """

    def __init__(
        self,
        pit: np.ndarray,
        obstacles: list[Obstacle],
        xs: np.ndarray,
        ys: np.ndarray,
        resolution: float,
        obstacle_clearance: float = GOAL_OBSTACLE_CLEARANCE,
        pit_clearance: float = GOAL_PIT_CLEARANCE,
    ) -> None:
        self.pit = pit
        self.obstacles = list(obstacles)
        self.xs, self.ys, self.resolution = xs, ys, float(resolution)
        self.obstacle_clearance = obstacle_clearance
        self.pit_clearance = pit_clearance
        self.obstacle_distance = self._obstacle_map()
        if pit.any():
            self.pit_distance = distance_transform_edt(~pit) * self.resolution
        else:
            self.pit_distance = np.full(pit.shape, np.inf)
        half = -ys[0]
        side = np.abs(ys) <= half - SIDE_MARGIN
        self.valid = (
            (~pit)
            & (self.obstacle_distance >= obstacle_clearance)
            & (self.pit_distance >= pit_clearance - 1e-9)
            & side[None, :]
        )

    def _window(self, lo: np.ndarray, hi: np.ndarray, pad: float) -> tuple[slice, slice]:
        res = self.resolution
        i0 = max(int(np.floor((lo[0] - pad - self.xs[0]) / res)), 0)
        i1 = min(int(np.ceil((hi[0] + pad - self.xs[0]) / res)) + 1, self.xs.size)
        j0 = max(int(np.floor((lo[1] - pad - self.ys[0]) / res)), 0)
        j1 = min(int(np.ceil((hi[1] + pad - self.ys[0]) / res)) + 1, self.ys.size)
        return slice(i0, max(i0, i1)), slice(j0, max(j0, j1))

    def _obstacle_map(self) -> np.ndarray:
        dist = np.full(self.pit.shape, np.inf)
        for ob in self.obstacles:
            fp = ob.footprint
            si, sj = self._window(fp.min(axis=0), fp.max(axis=0), _DIST_RANGE)
            if si.stop <= si.start or sj.stop <= sj.start:
                continue
            px, py = np.meshgrid(self.xs[si], self.ys[sj], indexing="ij")
            d = ob.footprint_distance(np.stack([px, py], axis=-1))
            np.minimum(dist[si, sj], d, out=dist[si, sj])
        return dist

    def min_obstacle_distance(self, xy: np.ndarray) -> float:
        """Exact distance of one point (2,) to the nearest obstacle footprint (inf if none)."""
        if not self.obstacles:
            return float("inf")
        x, y = float(xy[0]), float(xy[1])
        return min(ob.point_distance(x, y) for ob in self.obstacles)

    def min_pit_distance(self, xy: np.ndarray) -> float:
        """Distance of one point (2,) to the nearest pit sample (inf if none within 1 m)."""
        p = np.asarray(xy, dtype=np.float64)
        si, sj = self._window(p, p, 1.0)
        sub = self.pit[si, sj]
        if not sub.any():
            return float("inf")
        px, py = np.meshgrid(self.xs[si], self.ys[sj], indexing="ij")
        return float(np.sqrt((px[sub] - p[0]) ** 2 + (py[sub] - p[1]) ** 2).min())

    def point_ok(self, xy: np.ndarray) -> bool:
        """True if the point (2,) is a valid goal (exact clearances, not the sampled maps)."""
        p = np.asarray(xy, dtype=np.float64)
        half = -self.ys[0]
        if not (self.xs[0] <= p[0] <= self.xs[-1] and abs(p[1]) <= half - SIDE_MARGIN + 1e-9):
            return False
        return (
            self.min_pit_distance(p) >= self.pit_clearance - 1e-9
            and self.min_obstacle_distance(p) >= self.obstacle_clearance
        )

    def snap(self, xy: np.ndarray, radius: float) -> np.ndarray | None:
        """Nearest valid sample within ``radius`` of the point (2,), or None."""
        p = np.asarray(xy, dtype=np.float64)
        si, sj = self._window(p, p, radius)
        ok = self.valid[si, sj]
        if not ok.any():
            return None
        px, py = np.meshgrid(self.xs[si], self.ys[sj], indexing="ij")
        d2 = (px - p[0]) ** 2 + (py - p[1]) ** 2
        d2 = np.where(ok & (d2 <= radius * radius), d2, np.inf)
        k = int(np.argmin(d2))
        if not np.isfinite(d2.flat[k]):
            return None
        return np.array([px.flat[k], py.flat[k]])


def plan_path(
    checker: GoalChecker,
    start: tuple[float, float],
    end: tuple[float, float],
    x_range: tuple[float, float],
    clearance: float,
    rng: np.random.Generator,
    noise: float = 0.6,
) -> np.ndarray | None:
    """Shortest 8-connected path on the samples from ``start`` to ``end`` within ``x_range``,
    keeping ``clearance`` from obstacle footprints, under a smooth random cost in [1, 1+noise].

    Returns:
        (P, 2) path through sample positions, or None if the two are not connected.
    """
    xs, ys, res = checker.xs, checker.ys, checker.resolution
    i0 = max(int(np.floor((x_range[0] - xs[0]) / res)), 0)
    i1 = min(int(np.ceil((x_range[1] - xs[0]) / res)) + 1, xs.size)
    half = -ys[0]
    free = (
        (checker.obstacle_distance[i0:i1] >= clearance)
        & ~checker.pit[i0:i1]
        & (checker.pit_distance[i0:i1] >= checker.pit_clearance - 1e-9)
        & (np.abs(ys) <= half - SIDE_MARGIN)[None, :]
    )
    nx, ny = free.shape
    cost = 1.0 + noise * (rough_field((nx, ny), 0.5, res, rng, cell=1.0) + 0.5)
    ids = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, wts = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = (slice(0, nx - di), slice(max(0, -dj), ny - max(0, dj)))
        b = (slice(di, nx), slice(max(0, dj), ny - max(0, -dj)))
        ok = free[a] & free[b]
        step = res * np.hypot(di, dj)
        w = step * 0.5 * (cost[a] + cost[b])
        rows.append(ids[a][ok])
        cols.append(ids[b][ok])
        wts.append(w[ok])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    w = np.concatenate(wts)
    graph = coo_matrix((np.r_[w, w], (np.r_[r, c], np.r_[c, r])), shape=(nx * ny, nx * ny)).tocsr()

    def nearest_free(p: tuple[float, float]) -> int | None:
        px, py = np.meshgrid(xs[i0:i1], ys, indexing="ij")
        d2 = np.where(free, (px - p[0]) ** 2 + (py - p[1]) ** 2, np.inf)
        k = int(np.argmin(d2))
        return k if np.isfinite(d2.flat[k]) and d2.flat[k] <= 0.5**2 else None

    s, t = nearest_free(start), nearest_free(end)
    if s is None or t is None:
        return None
    dist, pred = dijkstra(graph, directed=True, indices=s, return_predecessors=True)
    if not np.isfinite(dist[t]):
        return None
    path = [t]
    while path[-1] != s:
        path.append(int(pred[path[-1]]))
    path.reverse()
    idx = np.array(path)
    return np.stack([xs[i0 + idx // ny], ys[idx % ny]], axis=1)


def resample_path(path: np.ndarray, spacing: float) -> np.ndarray:
    """Path vertices (K, 2) at arc lengths closest to spacing, 2*spacing, ... (end excluded)."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.r_[0.0, np.cumsum(seg)]
    total = arc[-1]
    n = int(np.floor(total / spacing))
    out = []
    for k in range(1, n + 1):
        target = k * spacing
        if total - target < 0.5 * spacing:
            break
        out.append(path[int(np.argmin(np.abs(arc - target)))])
    return np.array(out).reshape(-1, 2)


def polyline_length(points: np.ndarray) -> float:
    """Length of a polyline (K, D)."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def waypoint_index(start: np.ndarray, goals: np.ndarray) -> int:
    """Index of the goal (not the last one, P_B) closest to half the route length from start."""
    pts = np.vstack([start[None, :2], goals[:, :2]])
    arc = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(pts, axis=0), axis=1)])[1:]
    if len(goals) == 1:
        return 0
    return int(np.argmin(np.abs(arc[:-1] - arc[-1] / 2.0)))


def resolve_goals(
    items: list,
    checker: GoalChecker,
    start: tuple[float, float],
    end: tuple[float, float],
    snap_radius: float = 0.6,
) -> np.ndarray:
    """Turn a goal plan (Spots and EvenSegments, in route order) into valid goal points.

    Returns:
        (G, 2) goals in route order; the last is ``end`` (P_B).
    """
    raw: list[np.ndarray] = []
    for it in items:
        if isinstance(it, Spot):
            cands = [np.array([it.x, it.y])]
        elif isinstance(it, EvenSegment):
            a, b = np.asarray(it.a, float), np.asarray(it.b, float)
            n = max(1, int(round(np.linalg.norm(b - a) / it.spacing)))
            cands = [a + (b - a) * k / n for k in range(1, n)]
        else:
            raise TypeError(f"goal plan items must be Spot or EvenSegment, got {type(it).__name__}")
        for p in cands:
            q = p if checker.point_ok(p) else checker.snap(p, snap_radius)
            if q is not None:
                raw.append(q)
    s = np.asarray(start, float)
    e = np.asarray(end, float)
    kept: list[np.ndarray] = []
    for q in raw:
        prev = kept[-1] if kept else s
        if np.linalg.norm(q - prev) < 0.3 or np.linalg.norm(q - e) < 0.4 or q[0] < s[0] + 0.2:
            continue
        kept.append(q)
    seq = [s] + kept + [e]
    out: list[np.ndarray] = []
    for a, b in zip(seq[:-1], seq[1:], strict=True):
        d = float(np.linalg.norm(b - a))
        if d > MAX_GOAL_SPACING:
            n = int(np.ceil(d / 1.25))
            for k in range(1, n):
                p = a + (b - a) * k / n
                if checker.point_ok(p):
                    out.append(p)
        out.append(b)
    return np.array(out)
