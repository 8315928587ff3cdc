"""Terrain primitives: bounds, difficulty schedule, determinism, geometry of their features."""

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from legoh_rl.envs.trails import NUM_LEVELS, PARAMS, PRIMITIVES, make_primitive
from legoh_rl.envs.trails.levels import pit_depth
from legoh_rl.envs.trails.prim_obstacles import TAKEOFF_DISTANCE

WIDTH, RES = 5.0, 0.1
SEEDS = range(4)


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_every_level_finite_within_documented_bounds(name):
    spec = PRIMITIVES[name]
    lo, hi = spec.height_bounds
    for level in range(NUM_LEVELS):
        for seed in SEEDS:
            p = make_primitive(name, level, seed, width=WIDTH, resolution=RES)
            h = p.heights
            assert h.shape == p.pit.shape and h.shape[1] == round(WIDTH / RES)
            assert np.all(np.isfinite(h))
            assert h.min() >= lo - 1e-9 and h.max() <= hi + 1e-9, (name, level, h.min(), h.max())
            np.testing.assert_allclose(h[0], 0.0, atol=1e-12)  # joins the ground before it
            np.testing.assert_allclose(h[-1], p.exit_height, atol=1e-12)  # and the one after it
            for ob in p.obstacles:
                assert ob.top <= spec.top_bound + 1e-9
                assert ob.bottom == pytest.approx(-ob.embed, abs=1e-9)  # stands on the patch ground
                fp = ob.footprint
                assert fp[:, 0].min() >= 0.0 and fp[:, 0].max() <= p.length
                assert np.abs(fp[:, 1]).max() <= WIDTH / 2
            if spec.top_bound == 0.0:
                assert not p.obstacles
            for pname in spec.params:
                b0, b1 = PARAMS[pname].band(level)
                assert b0 - 1e-12 <= p.params[pname] <= b1 + 1e-12, (name, pname, level)
            if p.pit.any():
                assert h[p.pit].max() <= -pit_depth(level) + 1e-9
                assert h[~p.pit].min() > h[p.pit].max()


def test_level_bands_are_ordered_and_cover_easy_to_hard():
    for p in PARAMS.values():
        bands = [p.band(lv) for lv in range(NUM_LEVELS)]
        if p.increasing:
            assert bands[0][0] == pytest.approx(p.easy) and bands[-1][1] == pytest.approx(p.hard)
            assert all(bands[i][1] < bands[i + 1][0] for i in range(NUM_LEVELS - 1)), p.name
        else:
            assert bands[0][1] == pytest.approx(p.easy) and bands[-1][0] == pytest.approx(p.hard)
            assert all(bands[i][0] > bands[i + 1][1] for i in range(NUM_LEVELS - 1)), p.name


def test_physical_ranges_fit_the_robots():
    # level 0: a blind beginner walks it
    assert PARAMS["gap_width"].band(0)[1] <= 0.15 + 1e-9
    assert PARAMS["hurdle_height"].band(0)[1] <= 0.1
    assert PARAMS["slope_deg"].band(0)[1] <= 8.0
    assert PARAMS["step_height"].band(0)[1] <= 0.08
    assert 2 * PARAMS["log_radius"].band(0)[1] <= 0.12
    assert pit_depth(0) <= 0.1
    # level 4: hard, but within H1 / G1 reach
    assert 0.5 <= PARAMS["gap_width"].band(4)[1] <= 0.6
    assert 0.3 <= PARAMS["hurdle_height"].band(4)[1] <= 0.35
    assert 20.0 <= PARAMS["slope_deg"].band(4)[1] <= 25.0
    assert PARAMS["step_height"].band(4)[1] <= 0.2
    assert 0.8 <= PARAMS["passage_width"].band(4)[0] <= 1.0
    assert pit_depth(1) == pit_depth(4) == 1.0


@pytest.mark.parametrize("name", [n for n in PRIMITIVES if PRIMITIVES[n].params])
def test_difficulty_parameters_monotone_in_level(name):
    for pname in PRIMITIVES[name].params:
        vals = [
            [make_primitive(name, lv, s).params[pname] for s in SEEDS] for lv in range(NUM_LEVELS)
        ]
        for lv in range(NUM_LEVELS - 1):
            if PARAMS[pname].increasing:
                assert max(vals[lv]) < min(vals[lv + 1]), (name, pname, lv)
            else:
                assert min(vals[lv]) > max(vals[lv + 1]), (name, pname, lv)


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_same_seed_same_patch_different_seed_different_patch(name):
    a, b = make_primitive(name, 2, 7), make_primitive(name, 2, 7)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert a.params == b.params
    assert [o.pos.tolist() for o in a.obstacles] == [o.pos.tolist() for o in b.obstacles]
    others = [make_primitive(name, 2, s) for s in range(8, 12)]
    assert any(
        o.heights.shape != a.heights.shape
        or not np.array_equal(o.heights, a.heights)
        or o.friction != a.friction
        for o in others
    )


def test_gap_realised_width_and_depth():
    prev = 0.0
    for level in range(NUM_LEVELS):
        widths = []
        for seed in SEEDS:
            p = make_primitive("gap", level, seed)
            centre = p.pit[:, p.pit.shape[1] // 2]
            n = int(centre.sum())
            assert n * RES == pytest.approx(p.params["gap_width_realised"])
            assert abs(n * RES - p.params["gap_width"]) <= RES / 2 + 1e-9
            assert np.all(p.pit.sum(axis=0) == n)  # no widening: same width across the trail
            assert p.heights[p.pit].max() <= -pit_depth(level) + 1e-9
            widths.append(n * RES)
        assert min(widths) >= prev - 1e-9
        prev = max(widths)
    assert prev >= 0.5


def test_gap_widens_away_from_the_crossing():
    p = make_primitive("gap", 3, 0, route_y=1.0, widen=0.3)
    ys = np.arange(p.pit.shape[1]) * RES - WIDTH / 2
    per_col = p.pit.sum(axis=0) * RES
    j = int(np.argmin(np.abs(ys - 1.0)))
    assert per_col[j] == pytest.approx(per_col.min())
    assert per_col[0] > per_col[j] + 0.3


def test_stones_carry_goal_spots_and_pits_between():
    for name in ("stepping_stones", "staggered_stones"):
        p = make_primitive(name, 4, 3)
        stones = [s for s in p.spots if s.kind == "stone"]
        assert len(stones) >= 3
        for s in stones:
            i, j = round(s.x / RES), round((s.y + WIDTH / 2) / RES)
            assert not p.pit[i, j]
        lateral = np.array([s.y for s in stones])
        if name == "staggered_stones":
            assert np.all(np.abs(np.diff(lateral)) >= 2 * p.params["stagger_offset"] - RES)
        else:
            assert np.ptp(lateral) == 0.0
        # a real pit between two consecutive stones on level 4
        a, b = stones[0], stones[1]
        seg = p.pit[round(a.x / RES) : round(b.x / RES), round((a.y + WIDTH / 2) / RES)]
        assert seg.any()


def test_hurdle_and_log_spots_are_clear_of_the_obstacle_on_both_sides():
    for name, key in (("hurdle", "hurdle_height"), ("log", "log_radius")):
        for seed in SEEDS:
            p = make_primitive(name, 4, seed)
            (ob,) = p.obstacles
            take, land = p.spots
            for s in (take, land):
                d = float(ob.footprint_distance(np.array([s.x, s.y])))
                assert d >= TAKEOFF_DISTANCE - 0.02
            # the straight line take-off -> landing crosses the obstacle
            line = np.linspace([take.x, take.y], [land.x, land.y], 50)
            assert (ob.footprint_distance(line) < 0).any()
            if name == "hurdle":
                assert ob.top == pytest.approx(p.params[key])
            else:
                assert ob.top == pytest.approx(1.85 * p.params[key])


def test_trees_keep_the_passage_width_between_trunks():
    for level in range(NUM_LEVELS):
        p = make_primitive("trees", level, 1)
        w = p.params["passage_width"]
        c = [(o.pos[0], o.pos[1], o.size[0]) for o in p.obstacles]
        for i in range(len(c)):
            for j in range(i + 1, len(c)):
                gap = math.hypot(c[i][0] - c[j][0], c[i][1] - c[j][1]) - c[i][2] - c[j][2]
                assert gap >= w - 1e-9


def test_narrow_passage_width():
    p = make_primitive("narrow_passage", 4, 0)
    left, right = sorted(p.obstacles, key=lambda o: o.pos[1])
    gap = (right.pos[1] - right.size[1]) - (left.pos[1] + left.size[1])
    assert gap == pytest.approx(p.params["passage_width"])
    assert 0.9 <= gap <= 1.0


def test_unknown_primitive_and_bad_level_raise_listing_valid_values():
    with pytest.raises(ValueError, match=r"unknown terrain primitive 'lava'; registered: \[.*'flat'.*'rough'"):
        make_primitive("lava", 0, 0)
    with pytest.raises(ValueError, match="valid levels: 0, 1, 2, 3, 4"):
        make_primitive("gap", 5, 0)
    with pytest.raises(ValueError, match="valid levels"):
        make_primitive("gap", -1, 0)


def _direct_primitive_uses(source: str) -> list[str]:
    """What in ``source`` reaches a primitive without the registry: an import of the primitive
    modules (or of a name from them), or a call ``make_primitive(name, ...)`` whose name is a
    string that is not registered. Each entry names the line."""
    modules = {"prim_terrain", "prim_obstacles"}
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            names = {a.name for a in node.names}
            if (node.module or "").split(".")[-1] in modules or names & modules:
                found.append(f"line {node.lineno}: imports {sorted(names)} from {node.module or '.'}")
        elif isinstance(node, ast.Import) and any(a.name.split(".")[-1] in modules for a in node.names):
            found.append(f"line {node.lineno}: imports {[a.name for a in node.names]}")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "make_primitive"
              and node.args and isinstance(node.args[0], ast.Constant) and node.args[0].value not in PRIMITIVES):
            found.append(f"line {node.lineno}: make_primitive({node.args[0].value!r}) is not registered")
    return found


def test_categories_build_terrain_only_through_the_registry():
    """``categories.py`` reaches primitives only by name through ``make_primitive`` (PRIMITIVES)."""
    import legoh_rl.envs.trails.categories as categories

    source = Path(categories.__file__).read_text()
    assert _direct_primitive_uses(source) == []
    assert "make_primitive(" in source
    primitive_fns = {id(s.fn) for s in PRIMITIVES.values()}
    leaked = [n for n, v in vars(categories).items()
              if id(v) in primitive_fns or getattr(v, "__name__", "").endswith(("prim_terrain", "prim_obstacles"))]
    assert leaked == []
    # the scan itself sees each way a direct call could come back
    assert len(_direct_primitive_uses("from . import prim_terrain as pt\npt.gap(0, rng)")) == 1
    assert len(_direct_primitive_uses("from .prim_obstacles import log\nlog(0, rng)")) == 1
    assert len(_direct_primitive_uses("import legoh_rl.envs.trails.prim_terrain")) == 1
    assert len(_direct_primitive_uses('make_primitive("gapp", 0, rng)')) == 1
