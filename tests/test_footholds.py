"""The foothold probe (recipes/footholds.py): miss classification on hand-made pit masks, and a
short rollout of the committed oracle on Gap."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))

import footholds  # noqa: E402


def test_a_foot_in_a_crossing_pit_is_short_or_long_by_the_nearer_rim():
    pit = np.zeros((20, 20), dtype=bool)
    pit[8:11, :] = True  # a pit across the trail, x 0.8-1.0 m (samples 8, 9, 10)
    long = footholds.miss_kind(pit, (0.0, 0.0), 0.1, (0.8, 1.0))  # just past the last edge
    assert long["kind"] == "long" and math.isclose(long["behind"], 0.1) and math.isclose(long["ahead"], 0.3)
    assert long["side"] == math.inf  # the pit spans the map's width
    short = footholds.miss_kind(pit, (0.0, 0.0), 0.1, (1.02, 1.0))  # nearest sample 10: before the far rim
    assert short["kind"] == "short" and math.isclose(short["ahead"], 0.1) and math.isclose(short["behind"], 0.3)


def test_a_foot_beside_a_stepping_stone_is_lateral():
    pit = np.zeros((30, 20), dtype=bool)
    pit[5:16, :] = True
    pit[9:12, 0:6] = False  # a stone at x 0.9-1.1 m, y 0-0.5 m
    beside = footholds.miss_kind(pit, (0.0, 0.0), 0.1, (1.0, 0.6))
    assert beside["kind"] == "lateral" and math.isclose(beside["side"], 0.1)
    assert math.isclose(beside["ahead"], 0.6) and math.isclose(beside["behind"], 0.6)  # the pit ends at 0.4 and 1.6 m
    origin = footholds.miss_kind(pit, (-1.0, 2.0), 0.1, (0.0, 2.6))  # the same sample with a shifted origin
    assert origin == beside


def test_the_committed_oracle_misses_gap_footholds_by_a_sample():
    out = footholds.footholds(str(Path(__file__).resolve().parents[1] / "checkpoints" / "oracle_h1.pt"),
                              "gap", 1, robots=2, seconds=4.0, seed=7401, variants=2)
    assert out["robots"] == 2 and out["on_pit"] == len(out["events"]) <= 2
    assert out["short"] + out["long"] + out["lateral"] == out["on_pit"]
    for e in out["events"]:
        assert 0 < e["time_s"] <= 4.0 and min(e["ahead"], e["behind"], e["side"]) <= footholds.REACH
    with pytest.raises(ValueError, match="need robots >= 1 and seconds > 0, got 0, 4.0"):
        footholds.footholds("zero", robots=0, seconds=4.0)
