"""Obstacle primitives: flat ground carrying static geoms.

hurdle (long cuboid), log (fallen horizontal cylinder), rocks (trimesh convex hulls), trees
(upright cylinders) and narrow_passage (two large blocks leaving a passage). Same signature as
the heightfield primitives: ``fn(level, rng, width=5.0, resolution=0.1, **overrides) -> Patch``.
Obstacles are built standing on z = 0 of the patch; the tile builder later settles each one on
the lowest ground under its footprint.
"""

from __future__ import annotations

import math

import numpy as np

from .config import check_level
from .levels import PARAMS, sample_friction
from .obstacles import Obstacle, make_box, make_log, make_rock, make_trunk
from .patch import Patch, Spot, axes, num_samples

__all__ = ["hurdle", "log", "rocks", "trees", "narrow_passage", "TAKEOFF_DISTANCE"]

#: Distance of take-off / landing spots from the faces of a hurdle or log, metres.
TAKEOFF_DISTANCE = 0.45


def _draw(name: str, value: float | None, level: int, rng: np.random.Generator) -> float:
    return PARAMS[name].sample(level, rng) if value is None else float(value)


def _flat(n: int, width: float, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    _, ys = axes(n, width, resolution)
    return np.zeros((n, ys.size)), np.zeros((n, ys.size), dtype=bool)


def _crossing_spots(
    cx: float, cy: float, yaw: float, half_thick: float, route_y: float
) -> list[Spot]:
    """Take-off and landing spots where the line y = route_y crosses a long obstacle whose long
    axis is (-sin yaw, cos yaw), placed along its normal (cos yaw, sin yaw)."""
    s = (route_y - cy) / math.cos(yaw)
    px, py = cx - s * math.sin(yaw), route_y
    d = half_thick + TAKEOFF_DISTANCE
    nx, ny = math.cos(yaw), math.sin(yaw)
    return [Spot(px - d * nx, py - d * ny, "takeoff"), Spot(px + d * nx, py + d * ny, "landing")]


def hurdle(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    height: float | None = None,
    yaw_deg: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A long cuboid across (almost) the whole tile width: ``hurdle_height`` tall, 0.10-0.20 m
    thick, turned by +-``hurdle_yaw_deg``; take-off / landing spots 0.45 m from its faces."""
    check_level(level)
    hh = _draw("hurdle_height", height, level, rng)
    yaw_abs = _draw("hurdle_yaw_deg", None if yaw_deg is None else abs(yaw_deg), level, rng)
    sgn = (
        (1.0 if rng.random() < 0.5 else -1.0)
        if yaw_deg is None
        else (1.0 if yaw_deg >= 0 else -1.0)
    )
    yaw = math.radians(sgn * yaw_abs)
    t = rng.uniform(0.10, 0.20)
    half_len = (width / 2.0 - 0.1 - t / 2.0 * abs(math.sin(yaw))) / math.cos(yaw)
    ext_x = 2 * half_len * abs(math.sin(yaw)) + t * math.cos(yaw)
    approach = 0.8
    n = num_samples(2 * approach + ext_x, resolution)
    h, pit = _flat(n, width, resolution)
    cx = approach + ext_x / 2.0
    friction = sample_friction(rng)
    box = make_box((cx, 0.0), (t / 2.0, half_len), hh, yaw, "hurdle", friction)
    return Patch(
        "hurdle",
        h,
        pit,
        obstacles=[box],
        spots=_crossing_spots(cx, 0.0, yaw, t / 2.0, route_y),
        friction=friction,
        params={"hurdle_height": hh, "hurdle_yaw_deg": yaw_abs},
        resolution=resolution,
    )


def log(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    radius: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A fallen log of ``log_radius`` (top 1.85 r above the ground), 2.5-3.5 m long, lying
    across the route at +-20 deg; take-off / landing spots 0.45 m from it."""
    check_level(level)
    r = _draw("log_radius", radius, level, rng)
    length = min(rng.uniform(2.5, 3.5), width - 0.6)
    yaw = math.radians(rng.uniform(-20.0, 20.0))
    half = length / 2.0
    lim = max(0.0, width / 2.0 - 0.05 - half * math.cos(yaw) - r)
    cy = float(np.clip(route_y + rng.uniform(-0.5, 0.5), -lim, lim))
    ext_x = 2 * half * abs(math.sin(yaw)) + 2 * r * math.cos(yaw)
    approach = 0.7
    n = num_samples(2 * approach + ext_x, resolution)
    h, pit = _flat(n, width, resolution)
    cx = approach + ext_x / 2.0
    friction = sample_friction(rng)
    ob = make_log((cx, cy), r, length, yaw, "log", friction)
    return Patch(
        "log",
        h,
        pit,
        obstacles=[ob],
        spots=_crossing_spots(cx, cy, yaw, r, route_y),
        friction=friction,
        params={"log_radius": r},
        resolution=resolution,
    )


def _scatter(
    rng: np.random.Generator,
    radii: list[float],
    x_range: tuple[float, float],
    y_half: float,
    min_gap: float,
    tries: int = 40,
) -> list[tuple[float, float, float]]:
    """Rejection-sample discs (x, y, r) whose boundaries are at least ``min_gap`` apart."""
    placed: list[tuple[float, float, float]] = []
    for r in radii:
        lo, hi = x_range[0] + r, x_range[1] - r
        yl = y_half - r
        if hi <= lo or yl <= 0:
            continue
        for _ in range(tries):
            x, y = rng.uniform(lo, hi), rng.uniform(-yl, yl)
            if all(math.hypot(x - px, y - py) - r - pr >= min_gap for px, py, pr in placed):
                placed.append((x, y, r))
                break
    return placed


def rocks(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    count: float | None = None,
    height: float | None = None,
) -> Patch:
    """A 1.5-2.2 m field of floor(``rock_count``) rocks (convex hulls), the tallest
    ``rock_height`` above the ground, the others 60-100 % of it, 1-1.8 x as wide as tall."""
    check_level(level)
    c = _draw("rock_count", count, level, rng)
    hmax = _draw("rock_height", height, level, rng)
    length = rng.uniform(1.5, 2.2)
    n = num_samples(length, resolution)
    h, pit = _flat(n, width, resolution)
    k = int(math.floor(c + 1e-9))
    heights = [hmax] + [hmax * rng.uniform(0.6, 1.0) for _ in range(k - 1)]
    dims = [
        (hk, max(0.08, hk * rng.uniform(1.0, 1.8)), max(0.08, hk * rng.uniform(1.0, 1.8)))
        for hk in heights
    ]
    spots_xy = _scatter(
        rng,
        [max(rx, ry) for _, rx, ry in dims],
        (0.3, n * resolution - 0.3),
        width / 2.0 - 0.3,
        0.3,
    )
    obstacles: list[Obstacle] = []
    for (x, y, _), (hk, rx, ry) in zip(spots_xy, dims, strict=False):
        obstacles.append(
            make_rock(
                (x, y), (rx, ry), hk, rng.uniform(0, 2 * math.pi), rng, "rock", sample_friction(rng)
            )
        )
    return Patch(
        "rocks",
        h,
        pit,
        obstacles=obstacles,
        friction=sample_friction(rng),
        params={"rock_count": c, "rock_height": hmax, "rock_count_realised": float(len(obstacles))},
        resolution=resolution,
    )


def trees(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    density: float | None = None,
    passage: float | None = None,
) -> Patch:
    """A 2.5-3.0 m band of tree trunks (radius 0.10-0.30 m, 2.5-4 m tall), ``tree_density``
    trunks per m^2, every two trunks at least ``passage_width`` apart (surface to surface)."""
    check_level(level)
    dens = _draw("tree_density", density, level, rng)
    w = _draw("passage_width", passage, level, rng)
    length = rng.uniform(2.5, 3.0)
    n = num_samples(length, resolution)
    h, pit = _flat(n, width, resolution)
    target = max(1, int(round(dens * length * (width - 0.6))))
    radii = list(rng.uniform(0.10, 0.30, size=target))
    placed = _scatter(rng, radii, (0.3, n * resolution - 0.3), width / 2.0 - 0.3, w, tries=60)
    obstacles = [
        make_trunk((x, y), r, rng.uniform(2.5, 4.0), "tree", sample_friction(rng))
        for x, y, r in placed
    ]
    return Patch(
        "trees",
        h,
        pit,
        obstacles=obstacles,
        friction=sample_friction(rng),
        params={
            "tree_density": dens,
            "passage_width": w,
            "tree_count_realised": float(len(obstacles)),
        },
        resolution=resolution,
    )


def narrow_passage(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    passage: float | None = None,
    route_y: float | None = None,
) -> Patch:
    """Two large blocks (0.6-1.2 m deep, 1.0-1.6 m tall) filling the tile width but for one
    passage of ``passage_width``; goal spots before, inside and after the passage."""
    check_level(level)
    w = _draw("passage_width", passage, level, rng)
    lim = max(0.0, min(1.0, width / 2.0 - w / 2.0 - 0.6))
    yp = rng.uniform(-lim, lim) if route_y is None else float(np.clip(route_y, -lim, lim))
    depth = rng.uniform(0.6, 1.2)
    tall = rng.uniform(1.0, 1.6)
    approach = 0.8
    n = num_samples(2 * approach + depth, resolution)
    h, pit = _flat(n, width, resolution)
    cx = approach + depth / 2.0
    friction = sample_friction(rng)
    obstacles = []
    for lo, hi in ((-width / 2.0 + 0.05, yp - w / 2.0), (yp + w / 2.0, width / 2.0 - 0.05)):
        if hi - lo >= 0.1:
            obstacles.append(
                make_box(
                    (cx, (lo + hi) / 2.0),
                    (depth / 2.0, (hi - lo) / 2.0),
                    tall,
                    0.0,
                    "wall",
                    friction,
                )
            )
    spots = [
        Spot(approach - TAKEOFF_DISTANCE, yp, "passage"),
        Spot(cx, yp, "passage"),
        Spot(approach + depth + TAKEOFF_DISTANCE, yp, "passage"),
    ]
    return Patch(
        "narrow_passage",
        h,
        pit,
        obstacles=obstacles,
        spots=spots,
        friction=friction,
        params={"passage_width": w},
        resolution=resolution,
    )
