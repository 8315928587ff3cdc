"""HeightMap lookups and the bracketed ray march on hand-made height grids."""

import numpy as np
import pytest
import torch

from legoh_rl.envs.height_map import HeightMap
from legoh_rl.envs.sensors import march_ground


def ramp_map():
    # h = 0.1 x + 0.2 y on a 0.5 m grid from (-2, -3): bilinear interpolation is exact on a plane
    xs = -2.0 + 0.5 * np.arange(9)
    ys = -3.0 + 0.5 * np.arange(13)
    return HeightMap(0.1 * xs[:, None] + 0.2 * ys[None, :], origin=(-2.0, -3.0), resolution=0.5)


def test_bilinear_values_and_border_clamp():
    hm = ramp_map()
    pts = np.array([[0.0, 0.0], [1.3, -0.7], [-2.0, -3.0], [2.0, 3.0]])
    np.testing.assert_allclose(hm.numpy(pts), 0.1 * pts[:, 0] + 0.2 * pts[:, 1], atol=1e-6)
    # outside the grid the border value holds: x clamps to 2.0, y to -3.0
    np.testing.assert_allclose(hm.numpy(np.array([[10.0, -10.0]])), [0.1 * 2.0 - 0.2 * 3.0], atol=1e-6)


def test_grid_coordinates_are_affine_in_world_coordinates():
    hm = ramp_map()
    p = torch.tensor([[0.3, -1.1]])
    d = torch.tensor([[0.6, 0.8]])
    moved = hm.to_grid(p + 1.7 * d)
    np.testing.assert_allclose(moved, hm.to_grid(p) + 1.7 * hm.dirs_to_grid(d), atol=1e-6)
    np.testing.assert_allclose(hm.sample_grid(hm.to_grid(p)), hm(p), atol=1e-7)


@pytest.mark.parametrize("heights,res,message", [
    (np.zeros(5), 0.1, r"\(nx, ny\) grid"),
    (np.zeros((1, 4)), 0.1, r"nx, ny >= 2, got shape \(1, 4\)"),
    (np.zeros((3, 3)), 0.0, r"resolution must be positive, got 0.0"),
])
def test_bad_grids_refused(heights, res, message):
    with pytest.raises(ValueError, match=message):
        HeightMap(heights, (0.0, 0.0), res)


def test_bracketed_march_is_exact_on_a_plane_and_agrees_with_the_unbracketed_one():
    # flat ground at z = 0.3 with a 0.4 m step up to 0.7 for x > 2
    xs = np.linspace(-5, 5, 201)
    h = np.where(xs[:, None] > 2.0, 0.7, 0.3) + np.zeros((201, 201))
    hm = HeightMap(h, origin=(-5.0, -5.0), resolution=0.05)
    origin = np.array([[0.0, 0.0, 1.5]])
    pitch = np.deg2rad(np.array([20.0, 35.0, 60.0, 89.0]))  # below the horizon
    dirs = np.stack([np.cos(pitch), np.zeros(4), -np.sin(pitch)], axis=-1)[None]
    t_max = np.full((1, 4), 20.0)
    bounded = march_ground(origin, dirs, t_max, hm, samples=8, z_max=np.array([0.7]), z_min=np.array([0.3]))
    free = march_ground(origin, dirs, t_max, hm, samples=64)
    # a steep ray lands on the 0.3 plane before the step: t = 1.2 / sin(pitch)
    np.testing.assert_allclose(bounded[0, 2:], 1.2 / np.sin(pitch[2:]), rtol=1e-4)
    # a shallow ray reaches x = 2 high above 0.7... 20 deg: z at x=2 is 1.5 - 2 tan 20 = 0.77 > 0.7,
    # so it lands on the step top at 0.8 / sin(20 deg)
    np.testing.assert_allclose(bounded[0, 0], 0.8 / np.sin(pitch[0]), rtol=1e-3)
    np.testing.assert_allclose(bounded, free, rtol=2e-3)
    # a ray that never descends below the terrain misses
    up = march_ground(origin, np.array([[[1.0, 0.0, 0.0]]]), np.full((1, 1), 5.0), hm,
                      z_max=np.array([0.7]), z_min=np.array([0.3]))
    assert np.isinf(up).all()


def test_too_few_march_samples_refused():
    from legoh_rl.envs.sensors import DepthCameraConfig

    with pytest.raises(ValueError, match="march_samples must be an integer >= 2, got 1"):
        DepthCameraConfig(march_samples=1)


def test_refine_steps_locate_the_hit_on_a_curved_surface():
    from legoh_rl.envs.sensors import DepthCameraConfig

    x = np.arange(0.0, 8.0, 0.02)
    hm = HeightMap(np.repeat((0.3 * np.sin(2.0 * x))[:, None], 5, axis=1), origin=(0.0, -0.04), resolution=0.02)
    pitch = np.linspace(0.3, 1.2, 16)  # 16 rays in the x-z plane, descending from (0.1, 0, 1.5)
    dirs = np.stack([np.cos(pitch), np.zeros(16), -np.sin(pitch)], axis=1)[None]
    origin, t_max = np.array([[0.1, 0.0, 1.5]]), np.full((1, 16), 6.0)
    ref = march_ground(origin, dirs, t_max, hm, samples=4096, refine=3)
    # 64 samples bracket every first crossing; the refine steps then locate it inside the bracket
    errs = [np.abs(march_ground(origin, dirs, t_max, hm, samples=64, refine=r) - ref).max() for r in (0, 1, 3)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-3
    with pytest.raises(ValueError, match="march_refine must be an integer >= 0, got -1"):
        DepthCameraConfig(march_refine=-1)
