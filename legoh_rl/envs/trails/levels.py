"""Difficulty schedule: every parameter that makes a trail hard, with its easy and hard values.

A parameter of level ``l`` (0..4) is drawn uniformly from its own band of the easy..hard range::

    t ~ U(l / (4 + s), (l + s) / (4 + s)),   value = easy + (hard - easy) * t,   s = LEVEL_SPREAD

The bands of neighbouring levels do not overlap, so every such parameter is strictly monotone in
the level whatever the seed (level 0 starts at ``easy``, level 4 ends at ``hard``). This table is
the single source of ``docs/trails.md``'s parameter table (``python -m legoh_rl.envs.trails table``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import NUM_LEVELS, PIT_DEPTH, PIT_DEPTH_LEVEL0, check_level

__all__ = ["LEVEL_SPREAD", "LevelParam", "PARAMS", "FRICTION_RANGE", "pit_depth", "sample_friction"]

#: Fraction of a level step covered by one level's band.
LEVEL_SPREAD = 0.5
#: Sliding friction of ground patches and obstacles, U(lo, hi), independent of the level.
FRICTION_RANGE = (0.7, 1.2)


@dataclass(frozen=True)
class LevelParam:
    """A difficulty parameter: ``easy`` at the bottom of level 0, ``hard`` at the top of level 4.

    Attributes:
        name: key in the ``params`` dicts of patches and trails.
        easy: value at the easiest end.
        hard: value at the hardest end (smaller than ``easy`` for parameters that get harder
            as they shrink, e.g. passage width).
        unit: unit for documentation.
        doc: one-line meaning.
    """

    name: str
    easy: float
    hard: float
    unit: str
    doc: str

    @property
    def increasing(self) -> bool:
        """True if the value grows with the level."""
        return self.hard > self.easy

    def band(self, level: int) -> tuple[float, float]:
        """(low, high) of the values drawn at ``level`` (low < high in value order)."""
        lv = check_level(level)
        d = NUM_LEVELS - 1 + LEVEL_SPREAD
        a = self.easy + (self.hard - self.easy) * lv / d
        b = self.easy + (self.hard - self.easy) * (lv + LEVEL_SPREAD) / d
        return (min(a, b), max(a, b))

    def sample(self, level: int, rng: np.random.Generator) -> float:
        """Draw the value for ``level`` (a float inside ``band(level)``)."""
        lv = check_level(level)
        t = (lv + LEVEL_SPREAD * rng.random()) / (NUM_LEVELS - 1 + LEVEL_SPREAD)
        return float(self.easy + (self.hard - self.easy) * t)


def _p(name: str, easy: float, hard: float, unit: str, doc: str) -> LevelParam:
    return LevelParam(name, easy, hard, unit, doc)


#: Every difficulty parameter of the primitives and categories, by name.
PARAMS: dict[str, LevelParam] = {
    p.name: p
    for p in (
        _p(
            "rough_amplitude",
            0.01,
            0.07,
            "m",
            "uneven ground: heights in +-amplitude on a 0.4 m lattice",
        ),
        _p("slope_deg", 3.0, 22.0, "deg", "ramp inclination (slope up / down, RandomMix mound)"),
        _p("step_height", 0.04, 0.20, "m", "stair riser height"),
        _p("stair_tread", 0.40, 0.30, "m", "stair tread depth (shorter is harder)"),
        _p("ditch_depth", 0.10, 0.50, "m", "depth of a ditch with sloped banks"),
        _p("bank_slope_deg", 10.0, 25.0, "deg", "inclination of the ditch banks"),
        _p("gap_width", 0.10, 0.55, "m", "gap (pit) width at its narrowest, take-off to landing"),
        _p(
            "platform_offset",
            0.0,
            0.10,
            "m",
            "height difference of the landing platform after a gap",
        ),
        _p("stone_size", 0.80, 0.40, "m", "side of a square stepping stone (smaller is harder)"),
        _p("stone_gap", 0.05, 0.45, "m", "pit between consecutive stepping stones"),
        _p("stone_height_jitter", 0.0, 0.08, "m", "stepping stone heights in +-jitter"),
        _p("stagger_offset", 0.10, 0.40, "m", "lateral offset of staggered stones from the line"),
        _p("hurdle_height", 0.05, 0.32, "m", "height of a hurdle (long cuboid) above the ground"),
        _p("hurdle_yaw_deg", 0.0, 10.0, "deg", "hurdle angle to the trail normal (random sign)"),
        _p(
            "platform_height",
            0.04,
            0.22,
            "m",
            "step height of a platform (up, or down into a sunken area)",
        ),
        _p("log_radius", 0.04, 0.17, "m", "fallen log radius (top at 1.85 r above the ground)"),
        _p("rock_height", 0.05, 0.30, "m", "tallest rock of a rock field above the ground"),
        _p("rock_count", 2.0, 7.0, "1", "rocks in a rock field (floor of the value)"),
        _p("tree_density", 0.10, 0.40, "1/m^2", "tree trunks per square metre in a tree patch"),
        _p(
            "forest_density",
            0.08,
            0.35,
            "1/m^2",
            "target obstacles per square metre of a Forest trail",
        ),
        _p(
            "passage_width",
            2.00,
            0.90,
            "m",
            "minimum free gap between obstacles (narrower is harder)",
        ),
        _p(
            "turn_offset",
            0.0,
            1.4,
            "m",
            "lateral offset of alternating Ditch crossings (quick turns)",
        ),
        _p(
            "hill_grade_deg",
            4.0,
            14.0,
            "deg",
            "grade of the rising and falling ground of hill trails",
        ),
    )
}


def pit_depth(level: int) -> float:
    """Depth of gap / stone pits below the local ground: 0.1 m on level 0, 1.0 m above."""
    return PIT_DEPTH_LEVEL0 if check_level(level) == 0 else PIT_DEPTH


def sample_friction(rng: np.random.Generator) -> float:
    """Sliding friction of a patch or obstacle, U(FRICTION_RANGE)."""
    return float(rng.uniform(*FRICTION_RANGE))
