"""TerrainMap: vectorised height / edge queries against hand computations on hand-made grids."""

import math

import numpy as np
import pytest

from legoh_rl.envs.trails import TerrainMap

BARE = np.array(
    [
        [0.0, 0.0, 0.0],
        [0.0, 0.1, 0.0],
        [0.3, 0.3, 0.3],
        [0.3, 0.3, 0.3],
    ]
)  # sample (i, j) at (1.0 + 0.5 i, -1.0 + 0.5 j)
ORIGIN, RES = (1.0, -1.0), 0.5


def ref_height(grid, x, y):
    """Scalar bilinear interpolation, clamped (the hand computation)."""
    nx, ny = grid.shape
    fi = min(max((x - ORIGIN[0]) / RES, 0.0), nx - 1.0)
    fj = min(max((y - ORIGIN[1]) / RES, 0.0), ny - 1.0)
    i0, j0 = min(math.floor(fi), nx - 2), min(math.floor(fj), ny - 2)
    ti, tj = fi - i0, fj - j0
    return (
        grid[i0, j0] * (1 - ti) * (1 - tj)
        + grid[i0 + 1, j0] * ti * (1 - tj)
        + grid[i0, j0 + 1] * (1 - ti) * tj
        + grid[i0 + 1, j0 + 1] * ti * tj
    )


def ref_edge(grid, thr, i, j):
    nx, ny = grid.shape
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        a, b = i + di, j + dj
        if 0 <= a < nx and 0 <= b < ny and abs(grid[a, b] - grid[i, j]) > thr:
            return True
    return False


def test_height_at_hand_values():
    m = TerrainMap(BARE, origin=ORIGIN, resolution=RES)
    pts = np.array([[1.25, -0.75], [1.75, -0.5], [2.5, 0.0], [-10.0, 10.0], [1.5, -0.5]])
    expect = [0.025, 0.2, 0.3, 0.0, 0.1]
    np.testing.assert_allclose(m.height_at(pts), expect, atol=1e-12)
    near = np.array([[1.3, -0.7], [1.8, -0.5], [2.5, 0.0], [-10.0, 10.0], [1.6, -0.4]])
    np.testing.assert_allclose(
        m.height_at(near, interpolation="nearest"), [0.1, 0.3, 0.3, 0.0, 0.1]
    )
    assert m.extent == (1.0, 2.5, -1.0, 0.0)
    np.testing.assert_array_equal(m.contains(pts), [True, True, True, False, True])


def test_surface_vs_bare_and_shapes():
    surf = BARE.copy()
    surf[0, 0] = 0.5  # an obstacle top over sample (0, 0)
    m = TerrainMap(BARE, surf, origin=ORIGIN, resolution=RES)
    p = np.array([[1.0, -1.0]])
    assert m.height_at(p)[0] == pytest.approx(0.5)
    assert m.height_at(p, surface=False)[0] == pytest.approx(0.0)
    assert m.height_at(np.zeros((7, 2))).shape == (7,)
    assert m.height_at(np.zeros((3, 4, 2))).shape == (3, 4)
    assert m.edge_at(np.zeros((3, 4, 2))).shape == (3, 4)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        m.height_at(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="interpolation"):
        m.height_at(p, interpolation="cubic")


def test_edges_hand_values():
    m = TerrainMap(BARE, origin=ORIGIN, resolution=RES, edge_threshold=0.15)
    np.testing.assert_array_equal(m.edge_mask, [[0, 0, 0], [1, 1, 1], [1, 1, 1], [0, 0, 0]])
    m = TerrainMap(BARE, origin=ORIGIN, resolution=RES, edge_threshold=0.25)
    np.testing.assert_array_equal(m.edge_mask, [[0, 0, 0], [1, 0, 1], [1, 0, 1], [0, 0, 0]])
    # the edge band is the jump's cell interval plus half a sample each side
    xs = np.array([[1.2, -0.5], [1.3, -1.0], [2.2, -1.0], [2.3, -1.0]])
    np.testing.assert_array_equal(m.edge_at(xs), [False, True, True, False])
    # dilation by one sample marks the neighbours too
    m = TerrainMap(BARE, origin=ORIGIN, resolution=RES, edge_threshold=0.25, edge_dilation=0.5)
    np.testing.assert_array_equal(m.edge_mask, [[1, 0, 1], [1, 1, 1], [1, 1, 1], [1, 0, 1]])


def test_vectorised_matches_scalar_on_random_grid():
    rng = np.random.default_rng(0)
    bare = rng.uniform(-0.3, 0.3, size=(23, 17))
    surf = bare.copy()
    surf[5:8, 4:6] += 0.4
    m = TerrainMap(bare, surf, origin=ORIGIN, resolution=RES, edge_threshold=0.2)
    pts = np.c_[rng.uniform(0.0, 13.0, 500), rng.uniform(-2.0, 8.0, 500)]
    for grid, surface in ((surf, True), (bare, False)):
        ref = np.array([ref_height(grid, x, y) for x, y in pts])
        np.testing.assert_allclose(m.height_at(pts, surface=surface), ref, atol=1e-12)
    ref_mask = np.array([[ref_edge(surf, 0.2, i, j) for j in range(17)] for i in range(23)])
    np.testing.assert_array_equal(m.edge_mask, ref_mask)
    i = np.clip(np.rint((pts[:, 0] - ORIGIN[0]) / RES), 0, 22).astype(int)
    j = np.clip(np.rint((pts[:, 1] - ORIGIN[1]) / RES), 0, 16).astype(int)
    np.testing.assert_array_equal(m.edge_at(pts), ref_mask[i, j])


def test_bad_inputs():
    with pytest.raises(ValueError, match="2-D grid"):
        TerrainMap(np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        TerrainMap(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="surface shape"):
        TerrainMap(np.zeros((3, 3)), np.zeros((4, 3)))
