"""Expert goals: on traversable ground, clear of obstacles and pits, in route order."""

from functools import cache

import numpy as np
import pytest

from legoh_rl.envs.trails import ALL_CATEGORIES, CATEGORIES, NUM_LEVELS, build_trail
from legoh_rl.envs.trails.config import GOAL_OBSTACLE_CLEARANCE, GOAL_PIT_CLEARANCE
from legoh_rl.envs.trails.goals import SIDE_MARGIN


@cache
def trail(category, level, variant=0):
    length = 24.0 if category == "hill" else None
    return build_trail(category, level, seed=3, variant=variant, length=length)


def _cases():
    return [(c, lv) for c in ALL_CATEGORIES for lv in range(NUM_LEVELS)]


@pytest.mark.parametrize("category,level", _cases())
def test_goals_on_traversable_ground_with_clearance(category, level):
    for variant in (0, 1):
        t = trail(category, level, variant)
        xs = np.arange(t.shape[0]) * t.resolution
        ys = np.arange(t.shape[1]) * t.resolution - t.width / 2
        px, py = np.meshgrid(xs, ys, indexing="ij")
        pit_xy = np.stack([px[t.pit], py[t.pit]], axis=1)
        g = t.goals
        assert g.ndim == 2 and g.shape[1] == 3 and len(g) >= 3
        np.testing.assert_array_equal(g[-1], t.end)
        for p in g:
            # inside the tile, away from its long sides
            assert 0.0 <= p[0] <= t.length and abs(p[1]) <= t.width / 2 - SIDE_MARGIN + 1e-9
            # no obstacle footprint within the clearance (exact geometry)
            for ob in t.obstacles:
                assert float(ob.footprint_distance(p[:2])) >= GOAL_OBSTACLE_CLEARANCE - 1e-9, (
                    category,
                    level,
                    p,
                )
            # no pit sample within the pit clearance
            if len(pit_xy):
                assert np.hypot(*(pit_xy - p[:2]).T).min() >= GOAL_PIT_CLEARANCE - 1e-9
            # on the ground: nearest sample is not raised by an obstacle, z is the bare height
            i, j = t.map.index_of(p[:2])
            assert t.surface[i, j] == pytest.approx(t.heights[i, j])
            assert p[2] == pytest.approx(float(t.map.height_at(p[:2], surface=False)))
        # route order: progress along the trail (forest paths may step back a little)
        assert np.all(np.diff(g[:, 0]) > -0.6)
        assert g[0, 0] > t.start[0]


@pytest.mark.parametrize("category", ALL_CATEGORIES)
def test_waypoint_route_length_and_spacing(category):
    for level in (0, 4):
        t = trail(category, level)
        pts = np.vstack([t.start[None, :2], t.goals[:, :2]])
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        assert t.route_length == pytest.approx(seg.sum())
        assert seg.min() >= 0.3 - 1e-9
        assert seg.max() <= 2.6, (category, level, seg.max())
        k = [i for i, g in enumerate(t.goals) if np.array_equal(g, t.waypoint)]
        assert k and k[0] < len(t.goals) - 1
        arc = np.cumsum(seg)
        assert abs(arc[k[0]] - arc[-1] / 2) <= 1.5  # about half-way


def test_randommix_goals_evenly_spaced_on_the_trail_line():
    for level in range(NUM_LEVELS):
        t = trail("randommix", level)
        g = t.goals[:-1]
        on_line = np.abs(g[:, 1]) < 0.61
        assert on_line.all()
        seg = np.diff(np.vstack([t.start[:2], t.goals[:, :2]])[:, 0])
        assert np.all(seg > 0) and np.median(np.abs(seg - 1.5)) < 0.3


def test_terrain_specific_goals_sit_at_takeoff_and_landing():
    # hurdle: every hurdle has a goal just before and just after it
    t = trail("hurdle", 4)
    for ob in (o for o in t.obstacles if o.role == "hurdle"):
        d = ob.footprint_distance(t.goals[:, :2])
        side = np.sign(t.goals[:, 0] - ob.pos[0])
        assert ((d < 0.75) & (side < 0)).any() and ((d < 0.75) & (side > 0)).any()
    # gap: goals on every stone centre (non-pit, flanked by pits along the route)
    t = trail("gap", 4)
    on_stone = 0
    for p in t.goals:
        i, j = t.map.index_of(p[:2])
        if t.pit[max(i - 6, 0) : i + 7, j].any():
            on_stone += 1
    assert on_stone >= 4


def test_forest_goals_detour_around_obstacles():
    for level in (2, 3, 4):
        t = trail("forest", level)
        pts = np.vstack([t.start[None, :2], t.goals[:, :2]])
        dense = np.concatenate(
            [np.linspace(a, b, 20) for a, b in zip(pts[:-1], pts[1:], strict=True)]
        )
        d = np.min([ob.footprint_distance(dense) for ob in t.obstacles], axis=0)
        assert d.min() > 0.2  # the straight legs between goals keep clear of every obstacle
        straight = np.linspace(t.start[:2], t.end[:2], 200)
        s_min = np.min([ob.footprint_distance(straight) for ob in t.obstacles], axis=0).min()
        if (
            s_min < 0.3
        ):  # the straight line P_A -> P_B grazes or hits an obstacle: the route detours
            assert d.min() > s_min and np.ptp(t.goals[:, 1]) > 0.05


def test_forest_routes_differ_between_variants():
    lat = [tuple(np.round(trail("forest", 3, v).goals[:, 1], 1)) for v in range(2)]
    assert lat[0] != lat[1]
    for cat in CATEGORIES:
        assert trail(cat, 2).goals.shape[0] <= 24


def test_planner_detours_and_reports_blocked_routes():
    from legoh_rl.envs.trails.goals import GoalChecker, plan_path
    from legoh_rl.envs.trails.obstacles import make_box

    xs = np.arange(80) * 0.1
    ys = np.arange(50) * 0.1 - 2.5
    pit = np.zeros((80, 50), dtype=bool)
    rng = np.random.default_rng(0)
    # a wall with one 1.0 m passage at y = +1.0: the path must go through it
    walls = [
        make_box((4.0, -1.0), (0.3, 1.5), 1.0, 0.0, "wall", 1.0),
        make_box((4.0, 2.0), (0.3, 0.5), 1.0, 0.0, "wall", 1.0),
    ]
    chk = GoalChecker(pit, walls, xs, ys, 0.1)
    path = plan_path(chk, (0.5, 0.0), (7.5, 0.0), (0.0, 8.0), 0.35, rng)
    assert path is not None
    at_wall = path[np.abs(path[:, 0] - 4.0) < 0.05]
    assert np.all(np.abs(at_wall[:, 1] - 1.0) <= 0.15 + 1e-9)
    assert min(float(o.footprint_distance(path).min()) for o in walls) >= 0.35 - 1e-9
    # close the passage: no route
    walls.append(make_box((4.0, 1.0), (0.3, 0.6), 1.0, 0.0, "wall", 1.0))
    chk = GoalChecker(pit, walls, xs, ys, 0.1)
    assert plan_path(chk, (0.5, 0.0), (7.5, 0.0), (0.0, 8.0), 0.35, rng) is None
