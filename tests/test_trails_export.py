"""Mesh export (trimesh), the CLI, hill grids, and the docs images."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from legoh_rl.envs.trails import PRIMITIVES, TrailGridConfig, build_trail_grid, single_trail_grid
from legoh_rl.envs.trails.cli import main, parameter_table

DOCS_IMG = Path(__file__).resolve().parents[1] / "docs" / "img" / "trails"


def _hf_bounds(grid, tile=None):
    if tile is None:
        x0, x1, y0, y1 = grid.map.extent
        h = grid.map.bare
    else:
        r, c = tile
        t = grid.trail(r, c)
        x0, _, y0, _ = grid.tile_bounds[r, c]
        x1, y1 = x0 + (t.shape[0] - 1) * t.resolution, y0 + (t.shape[1] - 1) * t.resolution
        h = t.heights
    return np.array([[x0, y0, h.min()], [x1, y1, h.max()]])


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_exported_trail_mesh_bounds_match_heightfield(tmp_path, suffix):
    grid = single_trail_grid("forest", 3, seed=0)
    path = grid.export(tmp_path / f"forest3{suffix}")
    assert path.stat().st_size > 10_000
    scene = grid.to_trimesh()
    terrain = scene.geometry["terrain"]
    np.testing.assert_allclose(terrain.bounds, _hf_bounds(grid), atol=1e-9)
    assert len(scene.geometry) == 1 + len(grid.obstacles)
    loaded = trimesh.load(str(path), force="scene" if suffix == ".glb" else None)
    if suffix == ".glb":
        # glTF is y-up: trimesh stores our z-up coordinates under a node transform
        np.testing.assert_allclose(loaded.geometry["terrain"].bounds, terrain.bounds, atol=1e-4)
        assert len(loaded.geometry) == len(scene.geometry)
    else:
        lo, hi = loaded.bounds
        np.testing.assert_allclose(lo[:2], terrain.bounds[0][:2], atol=1e-4)
        np.testing.assert_allclose(hi[:2], terrain.bounds[1][:2], atol=1e-4)
        # the lowest point is the terrain's, or the buried bottom of an obstacle
        assert lo[2] == pytest.approx(
            min(terrain.bounds[0][2], min(o.bottom for o in grid.obstacles)), abs=1e-4
        )
        assert hi[2] >= max(o.top for o in grid.obstacles) - 1e-4  # trees stick out of the ground


def test_grid_and_tile_meshes(tmp_path):
    grid = build_trail_grid(TrailGridConfig(categories=("hurdle", "gap"), num_levels=2, variants=1))
    whole = grid.to_trimesh()
    np.testing.assert_allclose(whole.geometry["terrain"].bounds, _hf_bounds(grid), atol=1e-9)
    tile = grid.to_trimesh(1, 0)
    np.testing.assert_allclose(tile.geometry["terrain"].bounds, _hf_bounds(grid, (1, 0)), atol=1e-9)
    assert len(tile.geometry) == 1 + sum(1 for r, c in grid.obstacle_tile if (r, c) == (1, 0))
    n = grid.map.shape[0] * grid.map.shape[1]
    assert len(whole.geometry["terrain"].vertices) == n
    with pytest.raises(ValueError, match=".glb, .obj"):
        grid.export(tmp_path / "grid.fbx")
    with pytest.raises(ValueError, match="both row and column"):
        grid.to_trimesh(row=1)


def test_cli_preview_export_and_errors(tmp_path, capsys):
    png = tmp_path / "forest3.png"
    assert (
        main(["preview", "--category", "forest", "--level", "3", "--seed", "0", "-o", str(png)])
        == 0
    )
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) < 100_000
    width = int.from_bytes(data[16:20], "big")
    assert 300 <= width <= 700
    glb = tmp_path / "forest3.glb"
    assert (
        main(["export", "--category", "forest", "--level", "3", "--seed", "0", "-o", str(glb)]) == 0
    )
    assert glb.read_bytes()[:4] == b"glTF"
    assert main(["preview", "--category", "desert", "--level", "1", "-o", str(png)]) == 2
    err = capsys.readouterr().err
    assert "desert" in err and "randommix, ditch, hurdle, gap, forest, hill" in err
    assert main(["preview", "--category", "gap", "--level", "9", "-o", str(png)]) == 2
    assert "valid levels: 0, 1, 2, 3, 4" in capsys.readouterr().err
    assert main(["primitive", "--name", "volcano", "--level", "1", "-o", str(png)]) == 2
    assert "unknown terrain primitive 'volcano'; registered: [" in capsys.readouterr().err


def test_parameter_table_lists_every_parameter():
    table = parameter_table()
    assert table.count("\n") >= 20 and "| `gap_width` | m | 0.1-0.15 |" in table


def test_hill_grids():
    g = build_trail_grid(
        TrailGridConfig(categories=("gap",), num_levels=2, variants=1, include_hills=True)
    )
    assert g.categories == ("gap", "hill") and g.num_columns == 2
    assert g.trail(1, 1).category == "hill" and len(g.trail(1, 1).sections) >= 2
    ood = TrailGridConfig.out_of_domain(variants=1, num_levels=1)
    assert ood.tile_length == 36.0 and ood.categories == ("hill",)
    g = build_trail_grid(ood)
    assert g.route_length[0, 0] > 33.0 and g.num_goals[0, 0] > 20


def test_docs_images_exist_and_are_small():
    names = [f"primitive_{p}.png" for p in PRIMITIVES]
    names += [
        f"{c}_level{lv}.png"
        for c in ("randommix", "ditch", "hurdle", "gap", "forest")
        for lv in (0, 4)
    ]
    for n in names:
        f = DOCS_IMG / n
        assert f.is_file(), n
        assert f.stat().st_size < 100_000, n
