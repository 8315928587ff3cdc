"""The env's vectorised state math against MuJoCo and against the plain formulas."""

import mujoco
import numpy as np
import pytest
import torch

from legoh_rl.envs.sensors import (
    FOOT_SCAN_FAR_OFFSETS,
    FOOT_SCAN_OFFSETS,
    foot_scan,
    foot_scan_blocks,
    quat_to_rotmat,
    scandot_offsets,
    scandots,
    yaw_from_quat,
)
from legoh_rl.envs.trail_source import trails_for


def test_quat_to_rotmat_matches_mujoco():
    rng = np.random.default_rng(0)
    q = rng.standard_normal((50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = [1.0, 0.0, 0.0, 0.0]  # identity
    q[1] = [np.cos(0.5), 0.0, 0.0, np.sin(0.5)]  # yaw of 1 rad about z
    expected = np.empty((50, 9))
    for k in range(50):
        mujoco.mju_quat2Mat(expected[k], q[k])
    rot = quat_to_rotmat(q)
    np.testing.assert_allclose(rot.reshape(50, 9), expected, atol=1e-12)
    np.testing.assert_allclose(rot[1], [[np.cos(1), -np.sin(1), 0], [np.sin(1), np.cos(1), 0], [0, 0, 1]], atol=1e-12)
    # the env reads the heading off the matrix: the same as the quaternion formula
    np.testing.assert_allclose(np.arctan2(rot[:, 1, 0], rot[:, 0, 0]), yaw_from_quat(q), atol=1e-12)


def test_scandots_native_lookup_matches_the_plain_one():
    """``heights_around`` (the trail grid's one-call lookup) gives the scandots of the rotated
    points looked up one by one."""
    trails = trails_for(("hurdle",), 1, 0)
    rng = np.random.default_rng(1)
    lo, hi = trails.tile_start[:, :2].min(axis=0), trails.tile_end[:, :2].max(axis=0)
    pos = np.c_[rng.uniform(lo, hi, size=(16, 2)), rng.uniform(0.5, 1.5, 16)]
    yaw = rng.uniform(-np.pi, np.pi, 16)
    offsets = scandot_offsets()
    plain = scandots(pos, yaw, offsets, trails.height_at, 0.98)
    fast = scandots(pos, yaw, offsets, trails.height_at, 0.98, heights_around=trails.height_around)
    assert plain.shape == (16, 132) and plain.dtype == np.float32
    assert np.ptp(plain) > 0.1  # the points see terrain that varies
    np.testing.assert_allclose(fast, plain, atol=1e-5)


def test_the_foot_scan_grid_is_9_by_5_at_5_cm_around_the_ankle():
    assert FOOT_SCAN_OFFSETS.shape == (45, 2)
    grid = FOOT_SCAN_OFFSETS.reshape(9, 5, 2)  # x-major: rows forward, columns left
    np.testing.assert_allclose(grid[:, 0, 0], [-0.1, -0.05, 0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3], atol=1e-12)
    np.testing.assert_allclose(grid[0, :, 1], [-0.1, -0.05, 0.0, 0.05, 0.1], atol=1e-12)


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_foot_scan_reads_the_sole_level_on_a_floor_and_a_pits_depth_at_its_points(kind):
    """Hand-made feet over a floor at 0 with a pit of depth 0.3 at x > 1: the left foot heads +x,
    its sole on the floor, its ankle 0.125 m short of the pit's edge, so grid rows 5-8 (0.15 m
    forward and more) lie over the pit; the right foot heads +y (yaw 90 deg: its left is -x), its
    ankle at x = 1.025 and 2 cm above standing height, so grid columns 0-2 (0 to 0.1 m to its right,
    at x = 1.025-1.125) lie over the pit. A 1.5 m pit reads the clip, -1."""
    rest = 0.065
    pos = np.array([[[0.875, 0.3, rest], [1.025, -0.3, rest + 0.02]]])
    half = np.sqrt(0.5)
    quat = np.array([[[1.0, 0.0, 0.0, 0.0], [half, 0.0, 0.0, half]]])
    xp = np if kind == "numpy" else torch
    cast = np.asarray if kind == "numpy" else (lambda a: torch.as_tensor(a, dtype=torch.float64))

    def pit(depth):
        return lambda xy: xp.where(xy[:, 0] > 1.0, -depth, 0.0 * xy[:, 0])

    def scan(height_fn):
        out = foot_scan(cast(pos), cast(quat), cast(FOOT_SCAN_OFFSETS), height_fn, rest)
        out = out.numpy() if kind == "torch" else out
        assert out.shape == (1, 90)
        return out.reshape(2, 9, 5)  # (foot, forward, left)

    flat = scan(lambda xy: 0.0 * xy[:, 0])
    np.testing.assert_array_equal(flat[0], 0.0)  # a standing sole on the floor
    np.testing.assert_allclose(flat[1], -0.02, atol=1e-12)  # a sole 2 cm above it
    left, right = scan(pit(0.3))
    np.testing.assert_allclose(left[5:], -0.3, atol=1e-12)
    np.testing.assert_array_equal(left[:5], 0.0)
    np.testing.assert_allclose(right[:, :3], -0.32, atol=1e-12)
    np.testing.assert_allclose(right[:, 3:], -0.02, atol=1e-12)
    left, right = scan(pit(1.5))
    np.testing.assert_array_equal(left[5:], -1.0)
    np.testing.assert_array_equal(right[:, :3], -1.0)


def test_the_far_foot_scan_continues_the_grid_to_65_cm_after_the_near_one():
    assert foot_scan_blocks() == (FOOT_SCAN_OFFSETS,)
    near, far = foot_scan_blocks(far=True)
    assert near is FOOT_SCAN_OFFSETS and far is FOOT_SCAN_FAR_OFFSETS and far.shape == (35, 2)
    grid = far.reshape(7, 5, 2)
    np.testing.assert_allclose(grid[:, 0, 0], [0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65], atol=1e-12)
    np.testing.assert_allclose(grid[0, :, 1], FOOT_SCAN_OFFSETS.reshape(9, 5, 2)[0, :, 1], atol=1e-12)


def test_the_far_foot_scan_sees_a_pits_far_rim_that_the_near_one_does_not():
    """A foot with its ankle at x = 0.6 heading +x, its sole on the floor, 0.1 m before a pit 0.4 m
    wide (x in (0.7, 1.1), 1 m deep): the near grid (rows at x = 0.5-0.9) reads the floor up to the
    near rim and the pit beyond it, never the far floor; the far grid (rows at x = 0.95-1.25) reads
    the pit on its rows 0-2 and the floor from the far rim (row 3, x = 1.1) on."""
    rest = 0.065
    pos = np.array([[[0.6, 0.0, rest], [0.6, 0.3, rest]]])
    quat = np.array([[[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]])

    def height(xy):
        return np.where((xy[:, 0] > 0.7 + 1e-9) & (xy[:, 0] < 1.1 - 1e-9), -1.0, 0.0)

    near, far = (foot_scan(pos, quat, xy, height, rest) for xy in foot_scan_blocks(far=True))
    near, far = near.reshape(2, 9, 5)[0], far.reshape(2, 7, 5)[0]  # the left foot's (forward, left)
    np.testing.assert_array_equal(near[:5], 0.0)  # x = 0.5-0.7: the floor up to the near rim
    np.testing.assert_array_equal(near[5:], -1.0)  # x = 0.75-0.9: over the pit, no far floor in sight
    np.testing.assert_array_equal(far[:3], -1.0)  # x = 0.95-1.05: still the pit
    np.testing.assert_array_equal(far[3:], 0.0)  # x = 1.1-1.25: the far rim and the floor past it


def test_yaw_from_quat_on_tensors_and_stacked_quaternions():
    rng = np.random.default_rng(2)
    q = rng.standard_normal((3, 2, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    flat = yaw_from_quat(q.reshape(-1, 4)).reshape(3, 2)
    np.testing.assert_allclose(yaw_from_quat(q), flat, atol=1e-12)
    np.testing.assert_allclose(yaw_from_quat(torch.as_tensor(q)).numpy(), flat, atol=1e-12)
