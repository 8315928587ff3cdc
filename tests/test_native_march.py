"""The native (C) height-map kernels agree with the torch reference, and fall back cleanly."""

from pathlib import Path

import numpy as np
import pytest

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.height_map import HeightMap
from legoh_rl.envs.native import build, load_library, march_ground_native, unavailable_reason
from legoh_rl.envs.sensors import (
    DepthCamera,
    DepthCameraConfig,
    march_ground,
    resolve_march_backend,
)
from legoh_rl.envs.trail_source import trails_for

needs_native = pytest.mark.skipif(load_library() is None, reason=f"native kernel unavailable: {unavailable_reason()}")


def _hilly_map(seed=0) -> HeightMap:
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(160) * 0.1, np.arange(120) * 0.1, indexing="ij")
    h = 0.4 * np.sin(0.9 * x) * np.cos(0.7 * y) + 0.05 * rng.standard_normal(x.shape)
    h[60:70, 40:90] += 0.8  # a box-like obstacle top
    return HeightMap(h, origin=(-2.0, -1.0), resolution=0.1)


def _camera_rays(n, r, seed=0):
    rng = np.random.default_rng(seed)
    origin = np.c_[rng.uniform(2.0, 10.0, (n, 2)), np.full(n, 1.6)]
    d = rng.standard_normal((n, r, 3))
    d[..., 2] = -np.abs(d[..., 2]) - 0.2
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return origin, d, np.full((n, r), 6.0)


@needs_native
def test_heights_match_grid_sample(monkeypatch):
    hm = _hilly_map()
    rng = np.random.default_rng(1)
    xy = np.concatenate([rng.uniform(-4.0, 16.0, (2000, 2)), [[-2.0, -1.0], [13.9, 10.9], [100.0, -50.0]]])
    native = hm.numpy(xy)
    monkeypatch.setenv("LEGOH_RL_NATIVE", "0")
    reference = hm.numpy(xy)  # torch grid_sample (border-clamped outside the map)
    np.testing.assert_allclose(native, reference, atol=2e-5)  # float32 coordinates
    # a hand-computed point: the corner cell's bilinear blend
    assert native[-3] == pytest.approx(float(hm.heights[0, 0]), abs=1e-7)
    monkeypatch.delenv("LEGOH_RL_NATIVE")
    assert np.isnan(hm.numpy(np.array([[np.nan, 1.0]])))[0]


@needs_native
@pytest.mark.parametrize("bounds", ["none", "z", "t_min"])
def test_march_matches_torch(bounds):
    hm = _hilly_map()
    origin, dirs, t_max = _camera_rays(6, 2048)
    kw = {}
    if bounds == "z":
        kw = dict(z_max=np.full(6, hm.heights.max()), z_min=np.full(6, hm.heights.min()))
    elif bounds == "t_min":
        kw = dict(t_min=np.random.default_rng(2).uniform(0.0, 2.0, t_max.shape))
    ref = march_ground(origin, dirs, t_max, hm, samples=12, refine=3, **kw)
    for threads in (1, 3):
        got = march_ground_native(hm, origin, dirs, t_max, samples=12, refine=3, threads=threads, **kw)
        assert got.shape == ref.shape and got.dtype == np.float64
        np.testing.assert_array_equal(np.isfinite(got), np.isfinite(ref))
        hit = np.isfinite(ref)
        assert 0.3 < hit.mean() < 1.0  # some rays leave the map's range, most hit
        err = np.abs(got[hit] - ref[hit])
        assert np.mean(err < 1e-4) > 0.999 and err.max() < 0.05  # float32 rounding only


@needs_native
def test_march_hits_a_flat_floor_exactly():
    hm = HeightMap(np.full((50, 50), 0.25), origin=(0.0, 0.0), resolution=0.2)
    origin = np.array([[5.0, 5.0, 1.25]])
    dirs = np.array([[[0.6, 0.0, -0.8], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]])
    got = march_ground_native(hm, origin, dirs, np.full((1, 3), 4.0), samples=4, refine=2)
    # 1 m above the floor: 1 / 0.8 along the slanted ray, 1 straight down, no hit level
    np.testing.assert_allclose(got[0, :2], [1.25, 1.0], atol=1e-5)
    assert np.isinf(got[0, 2])


@needs_native
def test_march_names_bad_shapes():
    hm = _hilly_map()
    origin, dirs, t_max = _camera_rays(2, 8)
    with pytest.raises(ValueError, match=r"origin must be \(2, 3\)"):
        march_ground_native(hm, origin[:1], dirs, t_max)
    with pytest.raises(ValueError, match="t_max must have shape"):
        march_ground_native(hm, origin, dirs, t_max[:, :3])
    with pytest.raises(ValueError, match="dirs must be"):
        march_ground_native(hm, origin, dirs[..., :2], t_max)


@needs_native
def test_native_depth_matches_torch_depth_with_obstacles():
    trails = trails_for(("forest",), variants=1, seed=1)
    envs = [HikingEnv(HikingEnvConfig(robot="h1", num_envs=3, mode="student", categories=("forest",), levels=(2,),
                                      num_threads=1, depth_camera=DepthCameraConfig(backend=b)), trails=trails)
            for b in ("native", "torch")]
    assert [e.camera.backend for e in envs] == ["native", "torch"]
    images = []
    for env in envs:
        env.reset()
        w = env.worlds
        w.qpos[:, 0] += np.array([1.0, 3.0, 5.0])
        w.batch.forward()
        ids, cam = np.arange(3), env.built.camera_id
        pos, mat = w.cam_xpos[ids, cam], w.cam_xmat[ids, cam].reshape(-1, 3, 3)
        images.append(env.camera.render(w.batch, pos, mat, ids, trails.height_at_t, trails.ground_height_at_t,
                                        z_max=trails.max_height_near(pos[:, :2]),
                                        z_min=trails.min_height_near(pos[:, :2])))
    err_m = np.abs(images[0] - images[1]) * (envs[0].cfg.depth_camera.far - envs[0].cfg.depth_camera.near)
    assert np.mean(err_m < 1e-3) > 0.999


def test_backend_choice_and_fallback(monkeypatch):
    with pytest.raises(ValueError, match="'cuda'"):
        DepthCameraConfig(backend="cuda")
    with pytest.raises(ValueError, match="'gpu'"):
        resolve_march_backend("gpu")
    assert resolve_march_backend("torch") == "torch"
    monkeypatch.setenv("LEGOH_RL_NATIVE", "0")
    assert load_library() is None and "LEGOH_RL_NATIVE=0" in unavailable_reason()
    with pytest.raises(RuntimeError, match="LEGOH_RL_NATIVE=0"):
        resolve_march_backend("native")
    with pytest.warns(RuntimeWarning, match="using the torch ray march"):
        cam = DepthCamera(DepthCameraConfig(backend="auto"), fovy_deg=60.0)
    assert cam.backend == "torch"


def test_failed_build_is_reported(tmp_path, monkeypatch):
    monkeypatch.setenv("LEGOH_RL_CACHE", str(tmp_path))
    with pytest.raises(RuntimeError, match="compiling height_march.c, obstacle_cast.c, body_state.c, parallel.c failed"):
        build.build_library(cc="false")  # a "compiler" that always fails
    assert list(tmp_path.iterdir()) == []  # no half-written library left behind
    monkeypatch.setattr(build.shutil, "which", lambda name: None)
    monkeypatch.delenv("CC", raising=False)
    with pytest.raises(RuntimeError, match="no C compiler found"):
        build.build_library()


def test_coarse_max_map_bounds_every_bilinear_cell():
    """Block (I, J) of the coarse map is the maximum of samples [8I, 8I + 8] x [8J, 8J + 8]: hand
    checked on a small grid, and an upper bound of the bilinear height anywhere in the block."""
    from legoh_rl.envs.height_map import coarse_max_map

    h = np.zeros((10, 19), dtype=np.float32)  # 9 cells x 18 cells: blocks (0..1) x (0..2)
    h[8, 8] = 5.0  # the shared corner row/column of blocks (0, 0), (0, 1), (1, 0), (1, 1)
    h[9, 18] = 2.0  # the far corner: only block (1, 2)
    h[3, 12] = 1.0  # inside block (0, 1)
    cm = coarse_max_map(h, 8)
    np.testing.assert_array_equal(cm, [[5.0, 5.0, 0.0], [5.0, 5.0, 2.0]])
    hm = _hilly_map()
    rng = np.random.default_rng(3)
    ij = rng.uniform(0.0, [hm.heights.shape[0] - 1, hm.heights.shape[1] - 1], size=(5000, 2))
    xy = np.array([hm.x0, hm.y0]) + ij * hm.resolution
    cell = np.minimum(np.floor(ij).astype(int), np.array(hm.heights.shape) - 2) // 8
    assert (hm.numpy(xy) <= hm.coarse_max[cell[:, 0], cell[:, 1]] + 1e-6).all()


@needs_native
def test_coarse_skipping_changes_no_bit():
    """Skipping the lookups of samples the coarse max map puts above the terrain gives the same
    march and camera results, bit for bit (rays over hills, an obstacle top, and the sky)."""
    from legoh_rl.envs.native import camera_native

    hm = _hilly_map()
    origin, dirs, t_max = _camera_rays(8, 1024, seed=4)
    dirs[:, :100, 2] *= -1.0  # some rays go up (never descend into the terrain's band)
    kw = dict(z_max=np.full(8, hm.heights.max()), z_min=np.full(8, hm.heights.min()), samples=12, refine=3)
    with_map = march_ground_native(hm, origin, dirs, t_max, coarse=True, **kw)
    without = march_ground_native(hm, origin, dirs, t_max, coarse=False, **kw)
    assert np.isfinite(with_map).mean() > 0.5 and np.isinf(with_map).any()
    np.testing.assert_array_equal(with_map, without)
    ground = HeightMap(hm.heights - 0.3, (hm.x0, hm.y0), hm.resolution)
    rng = np.random.default_rng(5)
    cam_mat = np.stack([np.linalg.qr(rng.standard_normal((3, 3)))[0] for _ in range(8)])
    dirs_cam = dirs[0]
    a = camera_native(hm, ground, origin, cam_mat, dirs_cam, t_max[0], coarse=True, z_max=kw["z_max"],
                      z_min=kw["z_min"])
    b = camera_native(hm, ground, origin, cam_mat, dirs_cam, t_max[0], coarse=False, z_max=kw["z_max"],
                      z_min=kw["z_min"])
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@needs_native
@pytest.mark.parametrize("native", [True, False])
def test_heights_around_a_robot_match_the_rotated_points(native, monkeypatch):
    """``numpy_around``: the heights at yaw-frame offsets equal the plain lookup at the points
    rotated by hand (a robot facing +y sees the point 1 m ahead at +1 m in y)."""
    hm = _hilly_map()
    if not native:
        monkeypatch.setenv("LEGOH_RL_NATIVE", "0")
    xy = np.array([[3.0, 4.0], [6.0, 2.0]])
    yaw = np.array([np.pi / 2, -0.3])
    offsets = np.array([[1.0, 0.0], [0.0, 0.5], [-0.45, -0.75]])
    got = hm.numpy_around(xy, yaw, offsets)
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got[0, 0], hm.numpy(np.array([[3.0, 5.0]]))[0], atol=1e-6)
    c, s = np.cos(yaw[1]), np.sin(yaw[1])  # robot 1's last point by hand
    x, y = 6.0 + c * -0.45 - s * -0.75, 2.0 + s * -0.45 + c * -0.75
    np.testing.assert_allclose(got[1, 2], hm.numpy(np.array([[x, y]]))[0], atol=1e-6)
    with pytest.raises(ValueError, match="one yaw per robot"):
        hm.numpy_around(xy, yaw[:1], offsets)


@needs_native
def test_camera_resolves_obstacle_rays_in_the_same_call():
    """``camera_native(caster=...)`` gives each flagged ray the nearer of the obstacle geoms and
    the bare ground marched from the surface hit: the two-stage result (caster + march)."""
    from legoh_rl.envs.native import camera_native

    trails = trails_for(("forest",), variants=1, seed=1)
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=6, mode="student", categories=("forest",), levels=(2, 3),
                                    num_threads=1), trails=trails)
    env.reset()
    w, cam = env.worlds, env.camera
    w.qpos[:, 0] += np.linspace(0.5, 6.0, 6)
    w.batch.forward()
    pos, mat = w.cam_xpos[:, env.built.camera_id], w.cam_xmat[:, env.built.camera_id].reshape(-1, 3, 3)
    t_ray = cam.cfg.far / cam._axis_cos
    kw = dict(z_max=trails.max_height_near(pos[:, :2]), z_min=trails.min_height_near(pos[:, :2]), threads=2)
    args = (trails.height_at_t, trails.ground_height_at_t, pos, mat, cam._dirs_cam, t_ray)
    surface, flagged = camera_native(*args, **kw)
    fused, flagged2 = camera_native(*args, caster=cam.obstacle_caster, **kw)
    np.testing.assert_array_equal(flagged, flagged2)
    assert flagged.sum() > 100  # the trees are in view
    np.testing.assert_array_equal(fused[~flagged], surface[~flagged])  # unflagged rays untouched
    two_stage = cam._exact_on_obstacles(w.batch, pos, mat, None, t_ray, np.arange(6), flagged, surface.copy(),
                                        trails.ground_height_at_t, kw["z_max"], kw["z_min"])
    assert (np.isfinite(fused) == np.isfinite(two_stage)).all()
    fin = np.isfinite(fused)
    np.testing.assert_allclose(fused[fin], two_stage[fin], atol=1e-4)
    assert (np.abs(fused - surface)[flagged & fin] > 1e-3).mean() > 0.5  # the exact geoms moved most flagged hits


def test_a_prebuilt_library_loads_where_no_compiler_is(tmp_path):
    """``export_library`` here, then a process whose PATH finds no compiler: with
    ``$LEGOH_RL_NATIVE_PREBUILT`` at the folder it loads the copy (named by the source digest) and
    reads the height map as the torch reference does; a folder holding only another source version's library
    leaves the kernels unavailable, with the missing compiler as the reason."""
    import json
    import subprocess
    import sys

    folder = tmp_path / "prebuilt"
    copy = build.export_library(folder)
    assert copy.name == build.prebuilt_name() and build.source_digest() in copy.name and copy.stat().st_size > 0
    probe = (
        "import json, os, numpy as np\n"
        "from legoh_rl.envs.height_map import HeightMap\n"
        "from legoh_rl.envs.native.build import load_library, unavailable_reason\n"
        "lib = load_library()\n"
        "out = {'loaded': lib is not None, 'reason': unavailable_reason(), 'path': getattr(lib, '_name', None)}\n"
        "if lib is not None:\n"
        "    x, y = np.meshgrid(np.arange(40) * 0.1, np.arange(30) * 0.1, indexing='ij')\n"
        "    hm = HeightMap(0.4 * np.sin(0.9 * x) * np.cos(0.7 * y), origin=(-1.0, -1.0), resolution=0.1)\n"
        "    xy = np.random.default_rng(0).uniform(-1.5, 3.5, (500, 2))\n"
        "    native = hm.numpy(xy)\n"
        "    os.environ['LEGOH_RL_NATIVE'] = '0'\n"
        "    out['max_diff'] = float(np.abs(native - hm.numpy(xy)).max())\n"
        "print(json.dumps(out))\n")

    def run(prebuilt):
        env = {"PATH": str(tmp_path / "empty"), "LEGOH_RL_CACHE": str(tmp_path / "cache"), "HOME": str(tmp_path),
               "LEGOH_RL_NATIVE_PREBUILT": str(prebuilt)}
        done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                              cwd=str(Path(__file__).resolve().parents[1]), timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        return json.loads(done.stdout.strip().splitlines()[-1])

    got = run(folder)
    assert got["loaded"] and got["path"] == str(copy) and got["max_diff"] < 2e-5, got
    other = tmp_path / "other"
    other.mkdir()
    (other / "legoh_native-src-0123456789abcdef.so").write_bytes(copy.read_bytes())  # another source's name
    got = run(other)
    assert not got["loaded"] and "no C compiler found" in got["reason"], got
