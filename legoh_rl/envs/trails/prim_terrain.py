"""Heightfield terrain primitives: features carved into the ground itself.

flat, rough, slope_up, slope_down, stairs_up, stairs_down, ditch, gap, stepping_stones,
staggered_stones, platform. Each is ``fn(level, rng, width=5.0, resolution=0.1, **overrides)
-> Patch``; the difficulty parameters are drawn from ``levels.PARAMS`` unless overridden, and
every feature spans the whole tile width (a robot cannot walk around a gap or a stair).
Lengths are realised on the sample grid (a 0.33 m gap becomes 3 samples = 0.3 m at 0.1 m
resolution); patches record the realised values with a ``_realised`` suffix.
"""

from __future__ import annotations

import math

import numpy as np

from .config import check_level
from .levels import PARAMS, pit_depth, sample_friction
from .patch import Patch, Spot, axes, num_samples, rough_field, taper

__all__ = [
    "flat",
    "rough",
    "slope_up",
    "slope_down",
    "stairs_up",
    "stairs_down",
    "ditch",
    "gap",
    "stepping_stones",
    "staggered_stones",
    "platform",
]


def _draw(name: str, value: float | None, level: int, rng: np.random.Generator) -> float:
    return PARAMS[name].sample(level, rng) if value is None else float(value)


def _empty(
    nx: int, width: float, resolution: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    xs, ys = axes(nx, width, resolution)
    return xs, ys, np.zeros((nx, ys.size)), np.zeros((nx, ys.size), dtype=bool)


def flat(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    length: float | None = None,
) -> Patch:
    """Flat ground, 1-2 m long. No difficulty parameter (friction is random)."""
    check_level(level)
    n = num_samples(rng.uniform(1.0, 2.0) if length is None else length, resolution)
    _, _, h, pit = _empty(n, width, resolution)
    return Patch("flat", h, pit, friction=sample_friction(rng), resolution=resolution)


def rough(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    amplitude: float | None = None,
    length: float | None = None,
) -> Patch:
    """Uneven ground, 1.5-2.5 m: heights in +-``rough_amplitude``, tapered to 0 at both ends."""
    check_level(level)
    amp = _draw("rough_amplitude", amplitude, level, rng)
    n = num_samples(rng.uniform(1.5, 2.5) if length is None else length, resolution)
    _, ys, _, pit = _empty(n, width, resolution)
    h = rough_field((n, ys.size), amp, resolution, rng) * taper(n, resolution, 0.3)[:, None]
    return Patch(
        "rough",
        h,
        pit,
        friction=sample_friction(rng),
        params={"rough_amplitude": amp},
        resolution=resolution,
    )


def _slope(
    name: str,
    direction: float,
    level: int,
    rng: np.random.Generator,
    width: float,
    resolution: float,
    angle_deg: float | None,
    ramp: float | None,
    route_y: float,
) -> Patch:
    check_level(level)
    theta = _draw("slope_deg", angle_deg, level, rng)
    n_r = num_samples(rng.uniform(1.0, 1.5) if ramp is None else ramp, resolution)
    n_l = num_samples(rng.uniform(0.3, 0.5), resolution)
    n = n_r + n_l + 1
    xs, _, h, pit = _empty(n, width, resolution)
    grade = math.tan(math.radians(theta))
    prof = direction * np.minimum(xs, n_r * resolution) * grade
    h[:] = prof[:, None]
    kind = "crest" if direction > 0 else "foot"
    spot = Spot((n_r + n_l / 2.0) * resolution, route_y, kind)
    return Patch(
        name,
        h,
        pit,
        spots=[spot],
        exit_height=float(prof[-1]),
        friction=sample_friction(rng),
        params={"slope_deg": theta, "ramp_length_realised": n_r * resolution},
        resolution=resolution,
    )


def slope_up(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    angle_deg: float | None = None,
    ramp: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A ramp up at ``slope_deg`` over 1.0-1.5 m, then a 0.3-0.5 m flat top (rise <= 0.61 m)."""
    return _slope("slope_up", 1.0, level, rng, width, resolution, angle_deg, ramp, route_y)


def slope_down(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    angle_deg: float | None = None,
    ramp: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A ramp down at ``slope_deg`` over 1.0-1.5 m, then a 0.3-0.5 m flat foot."""
    return _slope("slope_down", -1.0, level, rng, width, resolution, angle_deg, ramp, route_y)


def _stairs(
    name: str,
    direction: float,
    level: int,
    rng: np.random.Generator,
    width: float,
    resolution: float,
    step_height: float | None,
    tread: float | None,
    steps: int | None,
    route_y: float,
) -> Patch:
    check_level(level)
    hs = _draw("step_height", step_height, level, rng)
    tr = _draw("stair_tread", tread, level, rng)
    n_t = max(2, int(round(tr / resolution)))
    k = int(rng.integers(3, 6)) if steps is None else int(steps)
    k = max(1, min(k, int(math.floor(0.8 / hs + 1e-9))))
    n_a = num_samples(0.3, resolution)
    n_l = num_samples(rng.uniform(0.4, 0.6), resolution)
    n = n_a + k * n_t + n_l
    _, _, h, pit = _empty(n, width, resolution)
    idx = np.arange(n)
    step_no = np.where(idx < n_a, 0, np.minimum((idx - n_a) // n_t + 1, k))
    prof = direction * step_no * hs
    h[:] = prof[:, None]
    spot = Spot(
        (n_a + k * n_t + n_l / 2.0) * resolution, route_y, "top" if direction > 0 else "foot"
    )
    return Patch(
        name,
        h,
        pit,
        spots=[spot],
        exit_height=float(prof[-1]),
        friction=sample_friction(rng),
        params={"step_height": hs, "stair_tread": tr, "stair_tread_realised": n_t * resolution},
        resolution=resolution,
    )


def stairs_up(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    step_height: float | None = None,
    tread: float | None = None,
    steps: int | None = None,
    route_y: float = 0.0,
) -> Patch:
    """3-5 steps up (``step_height``, ``stair_tread``), total rise <= 0.8 m, then a landing."""
    return _stairs(
        "stairs_up", 1.0, level, rng, width, resolution, step_height, tread, steps, route_y
    )


def stairs_down(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    step_height: float | None = None,
    tread: float | None = None,
    steps: int | None = None,
    route_y: float = 0.0,
) -> Patch:
    """3-5 steps down (``step_height``, ``stair_tread``), total drop <= 0.8 m, then a landing."""
    return _stairs(
        "stairs_down", -1.0, level, rng, width, resolution, step_height, tread, steps, route_y
    )


def ditch(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    depth: float | None = None,
    bank_slope_deg: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A gully across the trail: bank down at ``bank_slope_deg`` to ``ditch_depth``, a
    0.3-0.6 m flat bottom, bank up. Goal spots: near rim, bottom, far rim (at ``route_y``)."""
    check_level(level)
    d = _draw("ditch_depth", depth, level, rng)
    beta = _draw("bank_slope_deg", bank_slope_deg, level, rng)
    bottom = rng.uniform(0.3, 0.6)
    bank = d / math.tan(math.radians(beta))
    a = 0.3
    knots = np.array(
        [0.0, a, a + bank, a + bank + bottom, a + 2 * bank + bottom, 2 * a + 2 * bank + bottom]
    )
    n = num_samples(knots[-1], resolution) + 1
    xs, _, h, pit = _empty(n, width, resolution)
    prof = np.interp(xs, knots, [0.0, 0.0, -d, -d, 0.0, 0.0])
    h[:] = prof[:, None]
    spots = [
        Spot(a * 0.5, route_y, "takeoff"),
        Spot(a + bank + bottom / 2.0, route_y, "bottom"),
        Spot(min(knots[4] + a * 0.5, xs[-1]), route_y, "landing"),
    ]
    return Patch(
        "ditch",
        h,
        pit,
        spots=spots,
        exit_height=0.0,
        friction=sample_friction(rng),
        params={"ditch_depth": d, "bank_slope_deg": beta},
        resolution=resolution,
    )


def gap(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    gap_width: float | None = None,
    offset: float | None = None,
    route_y: float = 0.0,
    widen: float = 0.0,
    max_widen: float = 0.5,
) -> Patch:
    """A pit across the trail, ``gap_width`` wide at ``route_y``, between a 0.5 m take-off
    platform and a 0.6 m landing platform ``platform_offset`` higher or lower (random sign).

    With ``widen`` > 0 the gap grows by ``widen`` m per metre away from ``route_y`` (at most
    ``max_widen``): the narrowest crossing is where the goals are. Pits are ``pit_depth(level)``
    deep (0.1 m on level 0, 1 m above).
    """
    check_level(level)
    g = _draw("gap_width", gap_width, level, rng)
    off = _draw("platform_offset", None if offset is None else abs(offset), level, rng)
    sign = (
        (1.0 if rng.random() < 0.5 else -1.0) if offset is None else (1.0 if offset >= 0 else -1.0)
    )
    n_g = max(1, int(round(g / resolution)))
    n_a = num_samples(0.5, resolution)
    n_e = num_samples(max_widen, resolution) if widen > 0 else 0
    n_l = num_samples(0.6, resolution)
    n = n_a + n_g + n_e + n_l
    _, ys, h, pit = _empty(n, width, resolution)
    extra = np.zeros(ys.size, dtype=int)
    if widen > 0:
        extra = np.minimum(
            np.round(np.minimum(widen * np.abs(ys - route_y), max_widen) / resolution), n_e
        ).astype(int)
    land = sign * off
    bottom = min(0.0, land) - pit_depth(level)
    idx = np.arange(n)[:, None]
    in_pit = (idx >= n_a) & (idx < n_a + n_g + extra[None, :])
    h[:] = np.where(idx >= n_a, land, 0.0)
    h[in_pit] = bottom
    pit[:] = in_pit
    spots = [
        Spot(n_a * resolution - 0.3, route_y, "takeoff"),
        Spot((n_a + n_g) * resolution + 0.25, route_y, "landing"),
    ]
    return Patch(
        "gap",
        h,
        pit,
        spots=spots,
        exit_height=float(land),
        friction=sample_friction(rng),
        params={"gap_width": g, "gap_width_realised": n_g * resolution, "platform_offset": off},
        resolution=resolution,
    )


def _stones(
    name: str,
    staggered: bool,
    level: int,
    rng: np.random.Generator,
    width: float,
    resolution: float,
    size: float | None,
    stone_gap: float | None,
    jitter: float | None,
    offset: float | None,
    route_y: float | None,
) -> Patch:
    check_level(level)
    s = _draw("stone_size", size, level, rng)
    g = _draw("stone_gap", stone_gap, level, rng)
    jit = _draw("stone_height_jitter", jitter, level, rng)
    off = _draw("stagger_offset", offset, level, rng) if staggered else 0.0
    n_s = max(2, int(round(s / resolution)))
    n_g = int(round(g / resolution))
    n_a = num_samples(0.4, resolution)
    n_e = num_samples(0.5, resolution)
    region = rng.uniform(1.8, 2.6)
    k = max(3, int(region // ((n_s + n_g) * resolution)))
    n = n_a + k * (n_s + n_g) + n_g + n_e
    xs, ys, h, pit = _empty(n, width, resolution)
    lat = max(0.0, min(0.8, width / 2.0 - s - off - 0.4))
    y0 = rng.uniform(-lat, lat) if route_y is None else float(np.clip(route_y, -lat, lat))
    depth = pit_depth(level)
    h[n_a : n - n_e] = -depth
    pit[n_a : n - n_e] = True
    sgn = 1.0 if rng.random() < 0.5 else -1.0
    spots: list[Spot] = []
    first_y = None
    for i in range(k):
        yk = y0 + (off * sgn * (1 if i % 2 == 0 else -1) if staggered else 0.0)
        yk = ys[int(np.argmin(np.abs(ys - yk)))]
        cols = np.abs(ys - yk) <= s / 2.0 + 1e-9
        i0 = n_a + n_g + i * (n_s + n_g)
        h[i0 : i0 + n_s, cols] = rng.uniform(-jit, jit) if jit > 0 else 0.0
        pit[i0 : i0 + n_s, cols] = False
        spots.append(Spot(xs[i0] + (n_s - 1) * resolution / 2.0, float(yk), "stone"))
        first_y = yk if first_y is None else first_y
    last_y = spots[-1].y
    spots.insert(0, Spot(n_a * resolution - 0.25, float(first_y), "takeoff"))
    spots.append(Spot((n - n_e) * resolution + 0.3, float(last_y), "landing"))
    params = {
        "stone_size": s,
        "stone_gap": g,
        "stone_height_jitter": jit,
        "stone_size_realised": n_s * resolution,
        "stone_gap_realised": n_g * resolution,
    }
    if staggered:
        params["stagger_offset"] = off
    return Patch(
        name,
        h,
        pit,
        spots=spots,
        exit_height=0.0,
        friction=sample_friction(rng),
        params=params,
        resolution=resolution,
    )


def stepping_stones(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    size: float | None = None,
    stone_gap: float | None = None,
    jitter: float | None = None,
    route_y: float | None = None,
) -> Patch:
    """Square stones (``stone_size``) in a straight line across a 1.8-2.6 m pit field, separated
    by ``stone_gap``, heights in +-``stone_height_jitter``; goal spots on every stone."""
    return _stones(
        "stepping_stones",
        False,
        level,
        rng,
        width,
        resolution,
        size,
        stone_gap,
        jitter,
        None,
        route_y,
    )


def staggered_stones(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    size: float | None = None,
    stone_gap: float | None = None,
    jitter: float | None = None,
    offset: float | None = None,
    route_y: float | None = None,
) -> Patch:
    """Like ``stepping_stones`` but alternating +-``stagger_offset`` left and right of the line."""
    return _stones(
        "staggered_stones",
        True,
        level,
        rng,
        width,
        resolution,
        size,
        stone_gap,
        jitter,
        offset,
        route_y,
    )


def platform(
    level: int,
    rng: np.random.Generator,
    width: float = 5.0,
    resolution: float = 0.1,
    height: float | None = None,
    direction: float | None = None,
    route_y: float = 0.0,
) -> Patch:
    """A 0.8-1.4 m platform ``platform_height`` above (step up, then down) or below (step down
    into a sunken area, then up) the ground, random direction."""
    check_level(level)
    hp = _draw("platform_height", height, level, rng)
    sgn = (
        (1.0 if rng.random() < 0.5 else -1.0)
        if direction is None
        else (1.0 if direction >= 0 else -1.0)
    )
    n_a = num_samples(0.4, resolution)
    n_p = num_samples(rng.uniform(0.8, 1.4), resolution)
    n_e = num_samples(0.4, resolution)
    n = n_a + n_p + n_e
    _, _, h, pit = _empty(n, width, resolution)
    h[n_a : n_a + n_p] = sgn * hp
    spots = [
        Spot(n_a * resolution - 0.3, route_y, "takeoff"),
        Spot((n_a + (n_p - 1) / 2.0) * resolution, route_y, "top"),
        Spot((n_a + n_p) * resolution + 0.3, route_y, "landing"),
    ]
    return Patch(
        "platform",
        h,
        pit,
        spots=spots,
        exit_height=0.0,
        friction=sample_friction(rng),
        params={"platform_height": hp},
        resolution=resolution,
    )
