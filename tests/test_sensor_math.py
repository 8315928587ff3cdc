"""The env's vectorised state math against MuJoCo and against the plain formulas."""

import mujoco
import numpy as np

from legoh_rl.envs.sensors import quat_to_rotmat, scandot_offsets, scandots, yaw_from_quat
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
