"""The terrain grid: layout, per-tile arrays, vectorised queries, and the MuJoCo model."""

import mujoco
import numpy as np
import pytest

from legoh_rl.envs.trails import CATEGORIES, TrailGridConfig, build_trail, build_trail_grid
from legoh_rl.envs.trails.mujoco_spec import OBSTACLE_GROUP, TERRAIN_GROUP

HALF = 0.2  # half side of the falling test boxes


@pytest.fixture(scope="module")
def grid():
    return build_trail_grid(TrailGridConfig())  # 5 categories x 5 levels x 4 variants


def test_layout_and_per_tile_arrays(grid):
    cfg = grid.config
    R, C = cfg.num_levels, len(CATEGORIES) * cfg.variants
    assert (grid.num_rows, grid.num_columns) == (R, C) == (5, 20)
    assert grid.map.shape == (2 * 20 + 5 * 120 + 1, 2 * 20 + 20 * 50 + 1)
    for name in ("tile_origin", "start", "end", "waypoint"):
        assert getattr(grid, name).shape == (R, C, 3)
    assert grid.goals.shape == (R, C, cfg.max_goals, 3) and grid.num_goals.shape == (R, C)
    np.testing.assert_array_equal(grid.tile_level, np.repeat(np.arange(R)[:, None], C, axis=1))
    np.testing.assert_array_equal(grid.tile_category[0], np.repeat(np.arange(5), 4))
    np.testing.assert_array_equal(grid.tile_variant[0], np.tile(np.arange(4), 5))
    assert grid.column("forest", 2) == 18
    with pytest.raises(ValueError, match="grid categories: randommix"):
        grid.column("hill")
    b = grid.tile_bounds
    for p in (grid.start, grid.end, grid.waypoint):
        assert np.all((p[..., 0] > b[..., 0]) & (p[..., 0] < b[..., 1]))
        assert np.all((p[..., 1] > b[..., 2]) & (p[..., 1] < b[..., 3]))
    # walking +x from a tile leads into the next level of the same column
    np.testing.assert_allclose(b[1:, :, 0], b[:-1, :, 1])
    rows, cols = grid.tile_at(grid.start[..., :2])
    np.testing.assert_array_equal(rows, grid.tile_level)
    np.testing.assert_array_equal(cols, np.broadcast_to(np.arange(C), (R, C)))
    assert grid.tile_at(np.array([[-5.0, -5.0]]))[0][0] == -1


def test_tiles_equal_standalone_trails_in_world_coordinates(grid):
    r, c = 3, grid.column("gap", 1)
    t = build_trail("gap", 3, seed=0, variant=1)
    shift = np.array([grid.tile_bounds[r, c, 0], grid.tile_bounds[r, c, 2] + t.width / 2, 0.0])
    np.testing.assert_allclose(grid.start[r, c], t.start + shift)
    n = grid.num_goals[r, c]
    assert n == len(t.goals)
    np.testing.assert_allclose(grid.goals[r, c, :n], t.goals + shift)
    np.testing.assert_allclose(
        grid.goals[r, c, n:], np.broadcast_to(grid.end[r, c], (grid.goals.shape[2] - n, 3))
    )
    assert grid.route_length[r, c] == pytest.approx(t.route_length)
    # heights of the grid at the tile's samples are the trail's heights
    xs = shift[0] + np.arange(t.shape[0]) * t.resolution
    ys = shift[1] - t.width / 2 + np.arange(t.shape[1]) * t.resolution
    px, py = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([px, py], axis=-1)
    np.testing.assert_allclose(grid.height_at(pts, surface=False), t.heights, atol=1e-12)
    np.testing.assert_allclose(grid.height_at(pts), t.surface, atol=1e-12)
    goals, counts = grid.goals_of(np.array([r, 0]), np.array([c, 0]))
    assert goals.shape == (2, grid.goals.shape[2], 3) and counts[0] == n


def test_start_heights_and_spawn(grid):
    z = grid.height_at(grid.start[..., :2].reshape(-1, 2), surface=False).reshape(
        grid.start.shape[:2]
    )
    np.testing.assert_allclose(grid.start[..., 2], z, atol=1e-9)
    np.testing.assert_allclose(grid.start[..., 2], 0.0, atol=1e-9)  # start pads are at z = 0
    sp = grid.spawn_positions(np.array([0, 4]), np.array([3, 17]), standing_height=1.0)
    np.testing.assert_allclose(sp[:, :2], grid.start[[0, 4], [3, 17], :2])
    np.testing.assert_allclose(sp[:, 2], 1.0, atol=1e-9)


def test_edges_mark_pits_and_hurdles(grid):
    r, c = 4, grid.column("gap", 0)
    t = grid.trail(r, c)
    shift = np.array([grid.tile_bounds[r, c, 0], grid.tile_bounds[r, c, 2]])
    i, j = np.nonzero(t.pit)
    pit_xy = shift + np.c_[i, j] * t.resolution
    assert grid.edge_at(pit_xy).any() and grid.pit_at(pit_xy).all()
    assert not grid.edge_at(grid.start[r, c, :2][None])[0]
    hurdles = [o for o in grid.obstacles if o.role == "hurdle" and o.top - o.bottom > 0.25]
    assert hurdles
    ob = hurdles[0]
    assert grid.edge_at(ob.pos[:2][None])[0] or grid.edge_at(ob.footprint).any()


def test_compiles_in_mujoco_and_boxes_rest_on_every_tile(grid):
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.005
    starts = grid.start.reshape(-1, 3)
    for k, p in enumerate(starts):
        body = spec.worldbody.add_body(name=f"box{k}", pos=[p[0], p[1], p[2] + 1.0])
        body.add_freejoint()
        g = body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[HALF] * 3, mass=50.0)
        g.contype, g.conaffinity = 2, 1  # boxes touch the terrain, not each other
    grid.add_to_spec(spec)
    model = spec.compile()
    assert model.nhfield == 1 and model.nhfielddata == grid.map.shape[0] * grid.map.shape[1]
    assert model.ngeom == len(starts) + len(grid.terrain_geom_names)
    for name in grid.terrain_geom_names:
        gid = model.geom(name).id
        assert model.geom_group[gid] in (TERRAIN_GROUP, OBSTACLE_GROUP)
        assert model.geom_bodyid[gid] == 0 and model.geom_condim[gid] == 3
    hf = model.geom("terrain").id
    assert model.geom_pos[hf, 2] == pytest.approx(grid.map.bare.min())  # base at the lowest sample
    assert model.hfield_size[0, 3] == pytest.approx(grid.config.base_depth)
    data = mujoco.MjData(model)
    for _ in range(200):  # 1 s
        mujoco.mj_step(model, data)
    assert not np.isnan(data.qpos).any()
    z = data.qpos.reshape(-1, 7)[:, 2]
    ground = grid.height_at(data.qpos.reshape(-1, 7)[:, :2])
    np.testing.assert_array_less(ground + HALF - 0.03, z)  # above the surface (no fall-through)
    np.testing.assert_array_less(z, ground + HALF + 0.05)  # and resting on it
    assert np.abs(data.qvel.reshape(-1, 6)[:, :3]).max() < 0.05
    spec2 = mujoco.MjSpec()
    grid.add_to_spec(spec2)
    with pytest.raises(ValueError, match="once per spec"):
        grid.add_to_spec(spec2)


def test_heightfield_orientation_matches_queries(grid):
    spec = mujoco.MjSpec()
    grid.add_to_spec(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(1)
    nx, ny = grid.map.shape
    ij = np.c_[rng.integers(0, nx, 300), rng.integers(0, ny, 300)]
    xy = ij * grid.resolution
    groups = np.zeros(6, dtype=np.uint8)
    groups[TERRAIN_GROUP] = 1
    gid = np.zeros(1, dtype=np.int32)
    hit = []
    for x, y in xy:
        d = mujoco.mj_ray(
            model, data, np.array([x, y, 10.0]), np.array([0.0, 0.0, -1.0]), groups, 1, -1, gid
        )
        hit.append(10.0 - d)
    span = np.ptp(grid.map.bare)
    np.testing.assert_allclose(hit, grid.map.bare[ij[:, 0], ij[:, 1]], atol=1e-5 * span + 1e-6)
    assert grid.map.bare.min() < -0.5  # pits below zero are represented


def test_pit_depths_raise_only_the_pit_floors_of_each_level():
    base_cfg = TrailGridConfig(categories=("gap",), variants=1, seed=4)
    base = build_trail_grid(base_cfg)
    rungs = build_trail_grid(TrailGridConfig(categories=("gap",), variants=1, seed=4,
                                             pit_depths=(0.1, 0.3, 0.6, 1.0, 1.0)))
    diff = rungs.map.bare - base.map.bare
    pit = base.map.pit
    assert np.array_equal(pit, rungs.map.pit) and np.all(diff[~pit] == 0.0)  # only pit samples move
    for level, lift in enumerate((0.0, 0.7, 0.4, 0.0, 0.0)):  # 1 m benchmark pits above level 0
        x0, x1 = base.tile_bounds[level, 0, :2]
        i0, i1 = (np.array([x0, x1]) - base.map.origin[0]) / base.map.resolution
        sel = np.zeros_like(pit)
        sel[int(round(i0)):int(round(i1))] = True
        assert pit[sel].any(), level  # every Gap tile has pits
        np.testing.assert_allclose(diff[sel & pit], lift, atol=1e-9)
    with pytest.raises(ValueError, match=r"pit_depths must give one positive depth \(m\) per level \(5\)"):
        TrailGridConfig(pit_depths=(0.1, 0.3))
    with pytest.raises(ValueError, match=r"pit_depths must give one positive depth"):
        TrailGridConfig(pit_depths=(0.1, 0.0, 1.0, 1.0, 1.0))
