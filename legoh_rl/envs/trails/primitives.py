"""Registry of the 16 terrain primitives with their parameters and documented bounds."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from legoh_rl.registry import Registry

from . import prim_obstacles as po
from . import prim_terrain as pt
from .patch import Patch

__all__ = ["PrimitiveSpec", "PRIMITIVES", "make_primitive"]


@dataclass(frozen=True)
class PrimitiveSpec:
    """One terrain primitive.

    Attributes:
        name: registry name.
        fn: ``fn(level, rng, width=5.0, resolution=0.1, **overrides) -> Patch``.
        params: its difficulty parameters (names in ``levels.PARAMS``).
        height_bounds: (min, max) of its ground heights relative to the entry, metres, any level.
        top_bound: highest obstacle top above the ground it stands on, metres (0: no obstacle).
        description: one line for the docs.
    """

    name: str
    fn: Callable[..., Patch]
    params: tuple[str, ...]
    height_bounds: tuple[float, float]
    top_bound: float
    description: str


def _s(name, fn, params, bounds, top, desc) -> PrimitiveSpec:
    return PrimitiveSpec(name, fn, tuple(params), bounds, top, desc)


#: The 16 primitives, by name.
PRIMITIVES: Registry[PrimitiveSpec] = Registry("terrain primitive", entries={
    s.name: s
    for s in (
        _s("flat", pt.flat, (), (0.0, 0.0), 0.0, "flat ground, 1-2 m"),
        _s("rough", pt.rough, ("rough_amplitude",), (-0.07, 0.07), 0.0, "uneven ground, 1.5-2.5 m"),
        _s(
            "slope_up",
            pt.slope_up,
            ("slope_deg",),
            (0.0, 0.61),
            0.0,
            "ramp up over 1.0-1.5 m + flat top",
        ),
        _s(
            "slope_down",
            pt.slope_down,
            ("slope_deg",),
            (-0.61, 0.0),
            0.0,
            "ramp down over 1.0-1.5 m + flat foot",
        ),
        _s(
            "stairs_up",
            pt.stairs_up,
            ("step_height", "stair_tread"),
            (0.0, 0.8),
            0.0,
            "3-5 steps up, rise <= 0.8 m",
        ),
        _s(
            "stairs_down",
            pt.stairs_down,
            ("step_height", "stair_tread"),
            (-0.8, 0.0),
            0.0,
            "3-5 steps down, drop <= 0.8 m",
        ),
        _s(
            "ditch",
            pt.ditch,
            ("ditch_depth", "bank_slope_deg"),
            (-0.5, 0.0),
            0.0,
            "gully with sloped banks across the trail",
        ),
        _s(
            "gap",
            pt.gap,
            ("gap_width", "platform_offset"),
            (-1.1, 0.1),
            0.0,
            "pit across the trail between uneven platforms",
        ),
        _s(
            "stepping_stones",
            pt.stepping_stones,
            ("stone_size", "stone_gap", "stone_height_jitter"),
            (-1.0, 0.08),
            0.0,
            "square stones in a straight line over a pit field",
        ),
        _s(
            "staggered_stones",
            pt.staggered_stones,
            ("stone_size", "stone_gap", "stone_height_jitter", "stagger_offset"),
            (-1.0, 0.08),
            0.0,
            "stones alternating left / right of a line over a pit field",
        ),
        _s(
            "hurdle",
            po.hurdle,
            ("hurdle_height", "hurdle_yaw_deg"),
            (0.0, 0.0),
            0.32,
            "long cuboid across the trail",
        ),
        _s(
            "platform",
            pt.platform,
            ("platform_height",),
            (-0.22, 0.22),
            0.0,
            "platform step up/down (or sunken area)",
        ),
        _s(
            "log",
            po.log,
            ("log_radius",),
            (0.0, 0.0),
            0.32,
            "fallen log (horizontal cylinder) across the route",
        ),
        _s(
            "rocks",
            po.rocks,
            ("rock_count", "rock_height"),
            (0.0, 0.0),
            0.30,
            "field of rocks / boulders (convex meshes)",
        ),
        _s(
            "trees",
            po.trees,
            ("tree_density", "passage_width"),
            (0.0, 0.0),
            4.0,
            "band of upright tree trunks",
        ),
        _s(
            "narrow_passage",
            po.narrow_passage,
            ("passage_width",),
            (0.0, 0.0),
            1.6,
            "two large blocks leaving one narrow passage",
        ),
    )
})


def make_primitive(
    name: str,
    level: int,
    rng: np.random.Generator | int,
    width: float = 5.0,
    resolution: float = 0.1,
    **overrides,
) -> Patch:
    """Build primitive ``name`` at ``level`` (ValueError listing the registered names if unknown).

    Args:
        name: a key of ``PRIMITIVES``.
        level: difficulty level 0..4.
        rng: a numpy Generator, or an int seed.
        width: tile width, metres.
        resolution: sample spacing, metres.
        **overrides: primitive-specific parameter values (see each function).

    Returns:
        The :class:`Patch` (heights (nx, ny) with ny = width / resolution).
    """
    spec = PRIMITIVES.lookup(name)
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    return spec.fn(level, gen, width=width, resolution=resolution, **overrides)
