"""The five trail categories (and the out-of-domain hill) composed from the primitives.

Every primitive is built by name through the registry (:func:`.primitives.make_primitive`, which
reads :data:`.primitives.PRIMITIVES`), never by calling its function: the registry is the one list
of primitives, and ``tests/test_trails_primitives.py`` fails if a direct call comes back.

A category *body* fills the canvas from its cursor up to sample ``end`` and returns its goal plan
(Spots / EvenSegments in route order, see :mod:`.goals`). ``entry`` and ``exit`` are the route
anchors around the body (P_A and P_B for a whole tile, section ends inside a hill trail).

* randommix - unobstructed mixed terrain: a slope mound always, plus three of stairs / platform
  / gap / log / rocks / rough, on uneven ground; goals evenly spaced on the straight line.
* ditch - uneven ground, sloped-bank ditches and gaps (narrowest at alternating lateral
  crossings: quick turns), sometimes a mound; goals at take-off, bottom and landing spots.
* hurdle - long cuboids across the trail on near-flat ground; goals before / after each.
* gap - gaps between uneven platforms plus straight or staggered stepping stones; goals at
  take-off, on every stone, at landing.
* forest - dense trees, boulders and blocks of varied size, every two at least
  ``passage_width`` apart, sometimes a wall with one passage; goals along a planned detour.
* hill - several of the above chained (one section each) over rising and falling ground.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .canvas import TileCanvas
from .config import CATEGORIES, FOREST_PLAN_CLEARANCE
from .goals import EvenSegment, GoalChecker, plan_path, resample_path
from .levels import PARAMS, sample_friction
from .obstacles import Obstacle, make_box, make_rock, make_trunk
from .patch import Patch, Spot
from .primitives import make_primitive

__all__ = ["BODIES", "KEY_PARAMS"]

#: Difficulty parameters every trail of a category records (the curriculum's "hardness" knobs).
KEY_PARAMS: dict[str, tuple[str, ...]] = {
    "randommix": ("rough_amplitude", "slope_deg"),
    "ditch": ("rough_amplitude", "turn_offset", "ditch_depth", "bank_slope_deg", "gap_width"),
    "hurdle": ("hurdle_height",),
    "gap": ("gap_width", "stone_size", "stone_gap"),
    "forest": ("forest_density", "passage_width"),
    "hill": ("hill_grade_deg",),
}

Plan = list  # list[Spot | EvenSegment]
#: ``maker(rng, route_y, k) -> patches``: builds one feature group; ``k`` is its rank on the
#: trail. The length must not depend on ``route_y`` or ``k``.
Maker = Callable[[np.random.Generator, float, int], list[Patch]]


def _lay(
    cv: TileCanvas,
    makers: list[Maker],
    required: list[bool],
    end: int,
    rng: np.random.Generator,
    spacer: tuple[float, float],
    route_y: Callable[[int], float] | None = None,
) -> list[Spot]:
    """Lay feature groups, in order, with flat spacers before sample ``end``.

    Every group gets its own seed, so it can be measured first and built identically later.
    Required groups are kept first (if they fit), then optional ones are added in order while
    they fit. Group number k on the trail is built with ``route_y(k)``. Returns the spots.
    """
    res = cv.resolution
    seeds = [int(x) for x in rng.integers(0, 2**62, size=len(makers))]
    lengths = [
        sum(p.nx for p in m(np.random.default_rng(sd), 0.0, 0))
        for m, sd in zip(makers, seeds, strict=True)
    ]
    gaps = [int(round(rng.uniform(*spacer) / res)) for _ in makers]
    avail = end - cv.cursor
    chosen: set[int] = set()
    used = 0
    for want_required in (True, False):
        for i in range(len(makers)):
            if required[i] == want_required and used + lengths[i] + gaps[i] <= avail:
                chosen.add(i)
                used += lengths[i] + gaps[i]
    sel = sorted(chosen)
    slack = avail - used
    cv.flat_to(cv.cursor + (int(rng.integers(0, slack // 2 + 1)) if slack > 0 else 0))
    spots: list[Spot] = []
    for k, i in enumerate(sel):
        y = route_y(k) if route_y is not None else 0.0
        for p in makers[i](np.random.default_rng(seeds[i]), y, k):
            spots.extend(cv.place(p))
        if k < len(sel) - 1:
            cv.flat_to(cv.cursor + gaps[i])
    cv.flat_to(end)
    return spots


def _mound(
    level: int, rng: np.random.Generator, w: float, res: float, route_y: float = 0.0
) -> list[Patch]:
    theta = PARAMS["slope_deg"].sample(level, rng)
    ramp = rng.uniform(1.0, 1.5)
    return [
        make_primitive("slope_up", level, rng, w, res, angle_deg=theta, ramp=ramp, route_y=route_y),
        make_primitive("flat", level, rng, w, res, length=rng.uniform(0.3, 0.6)),
        make_primitive("slope_down", level, rng, w, res, angle_deg=theta, ramp=ramp, route_y=route_y),
    ]


def _stairs_pair(level: int, rng: np.random.Generator, w: float, res: float) -> list[Patch]:
    hs = PARAMS["step_height"].sample(level, rng)
    tr = PARAMS["stair_tread"].sample(level, rng)
    k = int(rng.integers(3, 5))
    return [
        make_primitive("stairs_up", level, rng, w, res, step_height=hs, tread=tr, steps=k),
        make_primitive("flat", level, rng, w, res, length=rng.uniform(0.3, 0.6)),
        make_primitive("stairs_down", level, rng, w, res, step_height=hs, tread=tr, steps=k),
    ]


def _gap_maker(level: int, w: float, res: float, first_sign: float, widen: float) -> Maker:
    """Gaps whose landing offsets alternate in sign along the trail (no elevation drift)."""

    def make(g: np.random.Generator, y: float, k: int) -> list[Patch]:
        off = PARAMS["platform_offset"].sample(level, g) * first_sign * (1 if k % 2 == 0 else -1)
        return [make_primitive("gap", level, g, w, res, offset=off, route_y=y, widen=widen)]

    return make


def body_randommix(
    cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit
) -> Plan:
    """Unobstructed mixed terrain (see module docstring)."""
    w, res = cv.width, cv.resolution
    i_start = cv.cursor
    amp = PARAMS["rough_amplitude"].sample(level, rng)
    cv.record("rough_amplitude", amp)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    pool: dict[str, Maker] = {
        "stairs": lambda g, y, k: _stairs_pair(level, g, w, res),
        "platform": lambda g, y, k: [make_primitive("platform", level, g, w, res)],
        "gap": _gap_maker(level, w, res, sign, 0.0),
        "log": lambda g, y, k: [make_primitive("log", level, g, w, res)],
        "rocks": lambda g, y, k: [make_primitive("rocks", level, g, w, res)],
        "rough": lambda g, y, k: [make_primitive("rough", level, g, w, res)],
    }
    names = ["mound"] + [str(n) for n in rng.permutation(list(pool))]
    order = rng.permutation(len(names))
    names = [names[i] for i in order]
    makers = [
        (lambda g, y, k: _mound(level, g, w, res)) if n == "mound" else pool[n] for n in names
    ]
    _lay(cv, makers, [n == "mound" for n in names], end, rng, (0.3, 0.6))
    cv.add_noise(amp, i_start, end, rng)
    return [EvenSegment(tuple(entry), tuple(exit), 1.5)]


def body_ditch(cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit) -> Plan:
    """Uneven ground, ditches and gaps crossed at alternating lateral offsets (quick turns)."""
    w, res = cv.width, cv.resolution
    i_start = cv.cursor
    amp = PARAMS["rough_amplitude"].sample(level, rng)
    turn = PARAMS["turn_offset"].sample(level, rng)
    cv.record("rough_amplitude", amp)
    cv.record("turn_offset", turn)
    kinds = ["ditch", "gap"] + [str(x) for x in rng.choice(["ditch", "gap", "mound"], size=4)]
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    jitter = rng.uniform(-0.15, 0.15, size=len(kinds)) if turn > 0.05 else np.zeros(len(kinds))
    lim = w / 2.0 - 1.0
    gap_make = _gap_maker(level, w, res, 1.0 if rng.random() < 0.5 else -1.0, 0.3)
    makers: list[Maker] = []
    required: list[bool] = []
    for kind in kinds:
        if kind == "ditch":
            makers.append(lambda g, y, k: [make_primitive("ditch", level, g, w, res, route_y=y)])
        elif kind == "gap":
            makers.append(gap_make)
        else:
            makers.append(lambda g, y, k: _mound(level, g, w, res, route_y=y))
        required.append(kind in ("ditch", "gap") and kind not in kinds[: len(required)])

    def route_y(k: int) -> float:
        return float(np.clip(sign * turn * (1 if k % 2 == 0 else -1) + jitter[k], -lim, lim))

    spots = _lay(cv, makers, required, end, rng, (0.2, 0.4), route_y)
    cv.add_noise(amp, i_start, end, rng)
    return list(spots)


def body_hurdle(
    cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit
) -> Plan:
    """Long cuboid hurdles across the trail on near-flat ground (now and then a platform)."""
    w, res = cv.width, cv.resolution
    i_start = cv.cursor
    kinds = ["hurdle", "hurdle"] + [
        "platform" if rng.random() < 0.2 else "hurdle" for _ in range(6)
    ]
    makers: list[Maker] = [
        (lambda g, y, k: [make_primitive("hurdle", level, g, w, res, route_y=y)])
        if kind == "hurdle"
        else (lambda g, y, k: [make_primitive("platform", level, g, w, res, route_y=y)])
        for kind in kinds
    ]
    ys = rng.uniform(-0.4, 0.4, size=len(kinds))
    spots = _lay(
        cv, makers, [i < 2 for i in range(len(kinds))], end, rng, (0.2, 0.6), lambda k: float(ys[k])
    )
    cv.add_noise(0.01, i_start, end, rng)
    return list(spots)


def body_gap(cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit) -> Plan:
    """Gaps between uneven platforms and straight or staggered stepping stones."""
    w, res = cv.width, cv.resolution
    i_start = cv.cursor
    stones = "stepping_stones" if rng.random() < 0.5 else "staggered_stones"
    kinds = ["gap", stones] + [
        str(x) for x in rng.choice(["gap", "stepping_stones", "staggered_stones"], size=3)
    ]
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    gap_make = _gap_maker(level, w, res, 1.0 if rng.random() < 0.5 else -1.0, 0.0)
    makers: list[Maker] = []
    required: list[bool] = []
    seen: set[str] = set()
    for kind in kinds:
        if kind == "gap":
            makers.append(gap_make)
            family = "gap"
        else:
            makers.append(lambda g, y, k, kind=kind: [make_primitive(kind, level, g, w, res)])
            family = "stones"
        required.append(family not in seen)
        seen.add(family)
    ys = rng.uniform(-0.5, 0.5, size=len(kinds))
    spots = _lay(cv, makers, required, end, rng, (0.2, 0.5), lambda k: float(ys[k]))
    cv.add_noise(0.015, i_start, end, rng)
    return list(spots)


def _forest_candidate(rng: np.random.Generator) -> tuple[str, dict, float]:
    """Draw an obstacle kind and its dimensions; return (kind, dims, bounding radius)."""
    u = rng.random()
    kind = "tree" if u < 0.5 else ("boulder" if u < 0.75 else "block")
    if kind == "tree":
        d = {"r": rng.uniform(0.12, 0.35), "h": rng.uniform(2.5, 4.5)}
        return kind, d, d["r"] / math.cos(math.pi / 16)
    if kind == "boulder":
        d = {"rx": rng.uniform(0.3, 0.6), "ry": rng.uniform(0.3, 0.6), "h": rng.uniform(0.5, 1.2)}
        return kind, d, max(d["rx"], d["ry"])
    d = {"hx": rng.uniform(0.2, 0.6), "hy": rng.uniform(0.2, 0.6), "h": rng.uniform(0.6, 1.5)}
    return kind, d, math.hypot(d["hx"], d["hy"])


def _forest_obstacle(rng: np.random.Generator, x: float, y: float, kind: str, d: dict) -> Obstacle:
    f = sample_friction(rng)
    if kind == "tree":
        return make_trunk((x, y), d["r"], d["h"], "tree", f)
    if kind == "boulder":
        return make_rock(
            (x, y), (d["rx"], d["ry"]), d["h"], rng.uniform(0, 2 * math.pi), rng, "boulder", f
        )
    return make_box((x, y), (d["hx"], d["hy"]), d["h"], rng.uniform(0, math.pi), "block", f)


def body_forest(
    cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit
) -> Plan:
    """Dense obstacles of varied size with guaranteed passages; goals on a planned detour."""
    w, res = cv.width, cv.resolution
    i_start = cv.cursor
    x0, x1 = cv.x_of(i_start), cv.x_of(end)
    dens = PARAMS["forest_density"].sample(level, rng)
    passage = PARAMS["passage_width"].sample(level, rng)
    cv.record("forest_density", dens)
    cv.record("passage_width", passage)
    cv.flat_to(end)
    placed: list[Obstacle] = []
    gate: list[Obstacle] = []
    anchors = [np.asarray(entry, float), np.asarray(exit, float)]
    if level >= 1 and x1 - x0 >= 5.0 and rng.random() < 0.5:
        p = make_primitive("narrow_passage", level, rng, w, res, passage=passage)
        if x1 - x0 >= 3.0 + p.length:
            gx = rng.uniform(x0 + 1.5, x1 - 1.5 - p.length)
            gate = [o.translated(gx, 0.0, 0.0) for o in p.obstacles]
            placed.extend(gate)
    target = int(round(dens * (x1 - x0) * (w - 0.6)))
    discs = [(float(o.pos[0]), float(o.pos[1]), o.bounding_radius) for o in placed]
    n_new = 0
    for _ in range(target * 40):
        if n_new >= target:
            break
        kind, dims, rb = _forest_candidate(rng)
        lo, hi = x0 + rb + 0.1, x1 - rb - 0.1
        yl = w / 2.0 - rb - 0.1
        if hi <= lo or yl <= 0:
            continue
        x, y = rng.uniform(lo, hi), rng.uniform(-yl, yl)
        if any(math.hypot(x - a[0], y - a[1]) < rb + 0.8 for a in anchors):
            continue
        # quick test on bounding discs; exact footprint distance only where the discs are close
        close = [
            k
            for k, (px, py, pr) in enumerate(discs)
            if math.hypot(x - px, y - py) - pr - rb < passage
        ]
        if any(placed[k].point_distance(x, y) - rb < passage for k in close):
            continue
        ob = _forest_obstacle(rng, x, y, kind, dims)
        placed.append(ob)
        discs.append((x, y, rb))
        n_new += 1
    cv.record("obstacle_count_realised", float(n_new))
    path = None
    for _ in range(30):
        checker = GoalChecker(cv.pit, cv.obstacles + placed, cv.xs, cv.ys, res)
        path = plan_path(
            checker, tuple(entry), tuple(exit), (x0 - 1.0, x1 + 1.0), FOREST_PLAN_CLEARANCE, rng
        )
        if path is not None:
            break
        movable = [o for o in placed if not any(o is g for g in gate)]
        if not movable:
            break
        a, b = anchors
        seg = b - a
        t = [np.clip(np.dot(o.pos[:2] - a, seg) / np.dot(seg, seg), 0, 1) for o in movable]
        d = [np.linalg.norm(o.pos[:2] - (a + ti * seg)) for o, ti in zip(movable, t, strict=True)]
        victim = movable[int(np.argmin(d))]
        placed = [o for o in placed if o is not victim]
    cv.obstacles.extend(placed)
    cv.add_noise(0.015, i_start, end, rng)
    if path is None:
        return [EvenSegment(tuple(entry), tuple(exit), 1.0)]
    return [Spot(float(p[0]), float(p[1]), "path") for p in resample_path(path, 1.0)]


def body_hill(cv: TileCanvas, end: int, level: int, rng: np.random.Generator, entry, exit) -> Plan:
    """Several categories chained, one section each, over rising and falling ground."""
    res = cv.resolution
    i_start = cv.cursor
    grade = PARAMS["hill_grade_deg"].sample(level, rng)
    cv.record("hill_grade_deg", grade)
    n_body = end - i_start
    k = max(2, int((n_body * res) // 9.0))
    cats = [CATEGORIES[i] for i in rng.permutation(len(CATEGORIES))]
    cats = (cats * (k // len(cats) + 1))[:k]
    bounds = [i_start + (n_body * s) // k for s in range(k + 1)]
    plan: Plan = []
    for s, cat in enumerate(cats):
        a = (cv.x_of(bounds[s]), 0.0) if s > 0 else tuple(entry)
        b = (cv.x_of(bounds[s + 1]), 0.0) if s < k - 1 else tuple(exit)
        plan.extend(BODIES[cat](cv, bounds[s + 1], level, rng, a, b))
        cv.flat_to(bounds[s + 1])
        cv.sections.append(cat)
    # rising and falling base: grade changes every 4-7 m, smoothed over 1.5 m
    x_a, x_b = cv.x_of(i_start), cv.x_of(end)
    knots, z = [x_a], [0.0]
    sign = 1.0
    g = math.tan(math.radians(grade))
    while knots[-1] < x_b:
        step = min(rng.uniform(4.0, 7.0), x_b - knots[-1])
        if z[-1] > 3.0:
            sign = -1.0
        elif z[-1] < -1.5:
            sign = 1.0
        elif rng.random() < 0.6 and len(knots) > 1:
            sign = -sign
        knots.append(knots[-1] + step)
        z.append(z[-1] + sign * g * rng.uniform(0.6, 1.0) * step)
    prof = np.interp(cv.xs, knots, z, left=0.0, right=z[-1])
    kern = max(1, int(round(1.5 / res)))
    padded = np.r_[np.full(kern, prof[0]), prof, np.full(kern, prof[-1])]
    prof = np.convolve(padded, np.ones(kern) / kern, mode="same")[kern:-kern]
    prof[:i_start] = 0.0
    ramp = np.clip((cv.xs - cv.x_of(i_start)) / 1.0, 0.0, 1.0)
    prof *= ramp
    prof[end:] = prof[end - 1]
    cv.add_profile(prof)
    cv.elev += float(prof[-1])
    return plan


#: Category name -> body function ``(canvas, end, level, rng, entry, exit) -> plan``.
BODIES: dict[str, Callable[..., Plan]] = {
    "randommix": body_randommix,
    "ditch": body_ditch,
    "hurdle": body_hurdle,
    "gap": body_gap,
    "forest": body_forest,
    "hill": body_hill,
}
