"""Trail categories: difficulty grows with level, determinism, level-0 reachability, hills, errors."""

from functools import cache

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from legoh_rl.envs.trails import CATEGORIES, NUM_LEVELS, PARAMS, TrailGridConfig, build_trail
from legoh_rl.envs.trails.categories import KEY_PARAMS
from legoh_rl.envs.trails.config import LEVEL0_MAX_STEP

VARIANTS = range(3)


@cache
def trail(category, level, variant=0, seed=0):
    return build_trail(category, level, seed=seed, variant=variant)


def reachable(t, max_step, start_xy, end_xy):
    """Test-side BFS: is end reachable from start by 4-neighbour moves with |dh| <= max_step on
    the surface map (obstacle tops included), staying inside the tile?"""
    s = t.surface
    nx, ny = s.shape
    ids = np.arange(nx * ny).reshape(nx, ny)
    rows, cols = [], []
    for a, b in (
        ((slice(0, nx - 1), slice(None)), (slice(1, nx), slice(None))),
        ((slice(None), slice(0, ny - 1)), (slice(None), slice(1, ny))),
    ):
        ok = np.abs(s[a] - s[b]) <= max_step
        rows.append(ids[a][ok])
        cols.append(ids[b][ok])
    r, c = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(r.size), (r, c)), shape=(nx * ny, nx * ny))
    _, label = connected_components(g, directed=False)

    def idx(p):
        return int(round(p[0] / t.resolution)) * ny + int(
            round((p[1] + t.width / 2) / t.resolution)
        )

    return label[idx(start_xy)] == label[idx(end_xy)]


@pytest.mark.parametrize("category", CATEGORIES)
def test_key_difficulty_parameters_grow_with_level(category):
    for name in KEY_PARAMS[category]:
        per_level = []
        for lv in range(NUM_LEVELS):
            vals = [v for var in VARIANTS for v in trail(category, lv, var).params[name]]
            assert vals, (category, name, lv)
            per_level.append(vals)
        for lv in range(NUM_LEVELS - 1):
            if PARAMS[name].increasing:
                assert max(per_level[lv]) < min(per_level[lv + 1]), (category, name, lv)
            else:
                assert min(per_level[lv]) > max(per_level[lv + 1]), (category, name, lv)


def test_forest_gets_denser_and_tighter():
    counts = [
        np.mean([len(trail("forest", lv, v).obstacles) for v in VARIANTS])
        for lv in range(NUM_LEVELS)
    ]
    assert counts[-1] >= 2.5 * counts[0]
    assert all(b >= a - 1 for a, b in zip(counts, counts[1:], strict=False))
    for lv in range(NUM_LEVELS):
        for v in VARIANTS:
            t = trail("forest", lv, v)
            w = t.params["passage_width"][0]
            obs = t.obstacles
            for i in range(len(obs)):
                for j in range(i + 1, len(obs)):
                    # min distance between two convex footprints: a vertex of one to the other
                    d = min(
                        obs[i].footprint_distance(obs[j].footprint).min(),
                        obs[j].footprint_distance(obs[i].footprint).min(),
                    )
                    assert d >= w - 1e-6, (lv, v, i, j, d, w)


def test_hurdles_get_higher_and_ditch_turns_get_sharper():
    h = [max(trail("hurdle", lv).params["hurdle_height"]) for lv in range(NUM_LEVELS)]
    assert h[0] <= 0.1 and h[-1] >= 0.29 and h == sorted(h)
    lateral = [np.ptp(trail("ditch", lv).goals[:-1, 1]) for lv in (0, 4)]
    assert lateral[0] < 0.6 and lateral[1] > 1.5


@pytest.mark.parametrize("category", CATEGORIES)
def test_same_seed_same_trail_different_seed_different_trail(category):
    a = build_trail(category, 3, seed=11)
    b = build_trail(category, 3, seed=11)
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(a.goals, b.goals)
    assert [o.pos.tolist() for o in a.obstacles] == [o.pos.tolist() for o in b.obstacles]
    assert a.params == b.params
    for other in (build_trail(category, 3, seed=12), build_trail(category, 3, seed=11, variant=1)):
        assert not np.array_equal(a.heights, other.heights) or not np.array_equal(
            a.goals, other.goals
        )


@pytest.mark.parametrize("category", CATEGORIES)
def test_level0_end_reachable_with_small_steps(category):
    for v in VARIANTS:
        t = trail(category, 0, v)
        assert reachable(t, LEVEL0_MAX_STEP, t.start, t.end), (category, v)


def test_reachability_check_has_teeth():
    # level-4 gaps and stones are 1 m deep pits: no small-step walk crosses them
    for v in VARIANTS:
        t = trail("gap", 4, v)
        assert not reachable(t, LEVEL0_MAX_STEP, t.start, t.end)


def test_tile_layout_start_end_and_flat_pads():
    for cat in CATEGORIES:
        t = trail(cat, 2)
        assert t.heights.shape == (120, 50)
        assert t.start[:2] == pytest.approx([0.75, 0.0])
        assert t.end[:2] == pytest.approx([11.25, 0.0])
        np.testing.assert_allclose(t.heights[:15], 0.0)  # flat start pad at z = 0
        assert np.ptp(t.heights[-15:]) < 1e-9  # flat end pad
        assert t.route_length >= 10.5 - 1e-9
        assert t.sections == (cat,)


def test_hill_chains_categories_over_rising_and_falling_ground():
    for lv in (0, 4):
        t = build_trail("hill", lv, seed=0)
        assert t.length == pytest.approx(36.0)
        assert len(set(t.sections)) >= 3 and set(t.sections) <= set(CATEGORIES)
        # base elevation: the ground along the trail rises and falls
        base = np.median(t.heights, axis=1)
        assert np.ptp(base) > (0.5 if lv == 0 else 1.5)
        d = np.diff(base)
        assert (d > 0.01).any() and (d < -0.01).any()
        assert t.params["hill_grade_deg"][0] == pytest.approx(
            PARAMS["hill_grade_deg"].band(lv)[0], abs=1.2
        )
        assert t.route_length > 33.0
    short = build_trail("hill", 1, seed=0, length=12.0)
    assert len(short.sections) >= 2


def test_errors_list_valid_values():
    with pytest.raises(ValueError, match="randommix, ditch, hurdle, gap, forest, hill"):
        build_trail("jungle", 0)
    with pytest.raises(ValueError, match="valid levels: 0, 1, 2, 3, 4"):
        build_trail("forest", 5)
    with pytest.raises(ValueError, match="valid levels"):
        build_trail("forest", 1.5)
    with pytest.raises(ValueError, match="valid categories"):
        TrailGridConfig(categories=("forest", "Swamp"))
    with pytest.raises(ValueError, match="num_levels"):
        TrailGridConfig(num_levels=6)
    with pytest.raises(ValueError, match="multiple of resolution"):
        TrailGridConfig(tile_length=12.05)
    with pytest.raises(ValueError, match="seed"):
        build_trail("gap", 0, seed=-1)
