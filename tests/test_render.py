"""Rendering: HikingEnv.render, torchrl's PixelRenderTransform / VideoRecorder, Gymnasium's
render_mode="rgb_array", and the error without an OpenGL backend.

Frames need an off-screen OpenGL context (MUJOCO_GL=egl, set by conftest; `make gl` installs
Mesa's EGL). Like the evaluation video test, the tests that draw frames are skipped, with the
reason, on a machine where no context can be made; the others always run.
"""

import mujoco
import numpy as np
import pytest
import torch
from scenes import BoxScene
from tensordict import TensorDict

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.render import RenderingUnavailableError, TrackingCamera, tile_frames

H, W = 48, 64  # small frames: software EGL draws the trail terrain slowly


def _gl_context_or_skip() -> None:
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except Exception as err:  # no backend or libraries: what `make gl` installs
        pytest.skip(f"no off-screen OpenGL context for MuJoCo ({type(err).__name__}: {err})")


@pytest.fixture(scope="module")
def env():
    """Two worlds on RandomMix trails (real terrain), spawned on different tiles."""
    env = HikingEnv(HikingEnvConfig(num_envs=2, categories=("randommix",), variants=1, num_threads=1))
    env.reset()
    yield env
    env.close()


def _centre(frame: np.ndarray) -> np.ndarray:
    """Mean RGB of a 12 x 8 patch at the frame's centre, (3,)."""
    h, w = frame.shape[:2]
    return frame[h // 2 - 6 : h // 2 + 6, w // 2 - 4 : w // 2 + 4].reshape(-1, 3).mean(0)


def test_tile_frames_lays_frames_out_row_major():
    frames = np.stack([np.full((2, 3, 3), v, np.uint8) for v in (10, 20, 30)])
    grid = tile_frames(frames, cols=2)
    assert grid.shape == (4, 6, 3) and grid.dtype == np.uint8
    assert (grid[:2, :3] == 10).all() and (grid[:2, 3:] == 20).all()
    assert (grid[2:, :3] == 30).all() and (grid[2:, 3:] == 0).all()  # the empty cell is black
    assert tile_frames(frames[:1], cols=2).shape == (2, 3, 3)
    with pytest.raises(ValueError, match="cols must be >= 1"):
        tile_frames(frames, cols=0)


def test_render_refuses_bad_worlds_sizes_and_cameras(env):
    with pytest.raises(ValueError, match=r"world indices must lie in \[0, 2\), got \[2\]"):
        env.render(2)
    with pytest.raises(ValueError, match=r"world indices must lie in \[0, 2\)"):
        env.render([0, -1])
    with pytest.raises(ValueError, match=r"a world mask must have shape \(2,\)"):
        env.render(np.array([True, False, True]))
    with pytest.raises(ValueError, match="render width must be a positive integer"):
        env.render(0, width=0, height=H)
    with pytest.raises(ValueError, match="TrackingCamera.distance must be a positive"):
        TrackingCamera(distance=0.0)


def test_no_gl_backend_raises_a_clear_error_naming_mujoco_gl(env, monkeypatch):
    """What mujoco raises without EGL libraries becomes an error that says what to do."""

    def no_backend(*args, **kwargs):
        raise ImportError("Failed to import OpenGL backend (MUJOCO_GL='egl'): libEGL.so.1: cannot open shared object")

    monkeypatch.setattr(mujoco, "Renderer", no_backend)
    with pytest.raises(RenderingUnavailableError, match="MUJOCO_GL=") as info:
        env.render(0, width=17, height=13)  # a size not drawn before: a new renderer
    msg = str(info.value)
    assert "libegl1 libgl1-mesa-dri" in msg and "make gl" in msg and "libEGL.so.1" in msg
    assert isinstance(info.value.__cause__, ImportError)


def test_render_frames_of_chosen_worlds(env):
    _gl_context_or_skip()
    frames = env.render(width=W, height=H)
    assert isinstance(frames, np.ndarray) and frames.dtype == np.uint8
    assert frames.shape == (2, H, W, 3)
    for f in frames:  # not one flat colour: terrain, sky and robot
        assert f.reshape(-1, 3).std(0).max() > 10.0
        assert np.unique(f.reshape(-1, 3), axis=0).shape[0] > 20
    # the two worlds stand on different tiles: their frames differ
    assert (frames[0] != frames[1]).any(axis=-1).mean() > 0.05
    one = env.render(1, width=W, height=H)
    assert one.shape == (H, W, 3)
    np.testing.assert_array_equal(one, frames[1])  # same state, same pixels
    picked = env.render([1, 0, 1], width=W, height=H)
    assert picked.shape == (3, H, W, 3)
    np.testing.assert_array_equal(picked[0], frames[1])
    np.testing.assert_array_equal(picked[1], frames[0])
    assert env.render(np.array([False, True]), width=W, height=H).shape == (1, H, W, 3)
    assert env.render([], width=W, height=H).shape == (0, H, W, 3)
    assert env.render(0, width=32, height=24).shape == (24, 32, 3)  # a new size, a new renderer


def _looking_at(point: np.ndarray, distance: float = 3.5) -> mujoco.MjvCamera:
    """A free camera at the default tracking camera's angles, looking at a fixed point."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = point
    cam.distance, cam.elevation, cam.azimuth = distance, -20.0, 135.0
    return cam


def _torso_com(env, w: int) -> np.ndarray:
    """World ``w``'s torso subtree centre of mass, (3,): where the tracking camera looks."""
    return env.worlds.batch.get_data(w).subtree_com[env.built.torso_body_id].copy()


def test_tracking_camera_follows_the_torso_and_the_robot_is_drawn(env):
    """Move world 0's robot 1.5 m sideways: the default camera moves with it (its frames are
    those of a camera looking at the torso, before and after), while a camera left where the
    robot was loses it (the centre of its frame turns from the dark robot to the light ground)."""
    _gl_context_or_skip()
    env.reset()
    fixed = _looking_at(_torso_com(env, 0))
    tracked_before = env.render(0, W, H)
    fixed_before = env.render(0, W, H, camera=fixed)
    assert np.abs(tracked_before.astype(int) - fixed_before).mean() < 1.0
    qpos = env.worlds.qpos[[0]].copy()
    qpos[0, 1] += 1.5
    env.worlds.reset([0], qpos=qpos)
    tracked_after = env.render(0, W, H)
    fixed_after = env.render(0, W, H, camera=fixed)
    assert np.abs(tracked_after.astype(int) - env.render(0, W, H, camera=_looking_at(_torso_com(env, 0)))).mean() < 1.0
    assert (fixed_after != fixed_before).any(axis=-1).mean() > 0.02  # the robot left the fixed view
    robot, ground = _centre(fixed_before).mean(), _centre(fixed_after).mean()
    assert ground - robot > 40.0, (robot, ground)
    assert abs(_centre(tracked_after).mean() - robot) < 20.0  # still the robot at the centre
    # other cameras: the head camera sees the trail ahead; a TrackingCamera sets the distance
    head = env.render(0, W, H, camera="head_depth")
    assert head.shape == (H, W, 3) and (head != tracked_after).any(axis=-1).mean() > 0.2
    far = env.render(0, W, H, camera=TrackingCamera(distance=8.0))
    assert np.abs(far.astype(int) - env.render(0, W, H, camera=_looking_at(_torso_com(env, 0), 8.0))).mean() < 1.0
    assert (far != tracked_after).any(axis=-1).mean() > 0.05
    with pytest.raises(ValueError, match=r"camera 'nope' is not a camera of the model; its cameras: \['head_depth'\]"):
        env.render(0, W, H, camera="nope")
    env.reset()


def test_frames_change_as_the_robot_moves(env):
    _gl_context_or_skip()
    env.reset()
    before = env.render(width=W, height=H)
    gen = torch.Generator().manual_seed(0)
    for _ in range(15):  # large random PD targets: the robots flail and fall
        a = (torch.rand(2, env.A, generator=gen) * 2 - 1) * env.cfg.action_clip
        env.step(TensorDict({"action": a}, batch_size=env.batch_size))
    after = env.render(width=W, height=H)
    for w in range(2):
        assert (before[w] != after[w]).any(axis=-1).mean() > 0.02


def test_pixel_render_transform_and_video_recorder(env, tmp_path):
    """torchrl's PixelRenderTransform calls env.render() with no arguments (here with the size as
    its kwargs) and writes the (N, H, W, 3) frames as a "pixels" entry; VideoRecorder tiles the
    worlds into one video."""
    _gl_context_or_skip()
    from torchrl.envs import TransformedEnv
    from torchrl.record import CSVLogger, PixelRenderTransform, VideoRecorder

    logger = CSVLogger(exp_name="render", log_dir=str(tmp_path), video_format="pt")
    tenv = TransformedEnv(env, PixelRenderTransform(width=W, height=H))
    tenv.append_transform(VideoRecorder(logger=logger, tag="hike"))
    spec = tenv.observation_spec["pixels"]
    assert spec.shape == (2, H, W, 3) and spec.dtype == torch.uint8
    td = tenv.rollout(4)
    assert td["pixels"].shape == (2, 4, H, W, 3) and td["pixels"].dtype == torch.uint8
    assert td["next", "pixels"].shape == (2, 4, H, W, 3)
    # the last frames are those of the env's current state; they changed over the rollout
    np.testing.assert_array_equal(td["next", "pixels"][:, -1].numpy(), env.render(width=W, height=H))
    assert (td["pixels"][:, 0] != td["next", "pixels"][:, -1]).any(-1).float().mean() > 0.01
    tenv.transform[-1].dump()
    videos = list((tmp_path / "render" / "videos").glob("hike_*.pt"))
    assert len(videos) == 1
    video = torch.load(videos[0])
    # (1, T, 3, H, 2W): the two worlds side by side, frames of the reset and of each step
    assert video.shape[0] == 1 and video.shape[2:] == (3, H, 2 * W) and video.shape[1] >= 5
    assert video.dtype == torch.uint8


def test_gymnasium_render_mode_rgb_array():
    import gymnasium

    import legoh_rl.envs  # noqa: F401  (registers the ids)

    _gl_context_or_skip()
    env = gymnasium.make("LegoH/Hike-H1-v0", render_mode="rgb_array", trails=BoxScene(), num_threads=1,
                         width=W, height=H)
    assert env.render_mode == "rgb_array"
    assert env.metadata["render_modes"] == ["rgb_array"] and env.metadata["render_fps"] == pytest.approx(50.0)
    env.reset(seed=0)
    first = env.render()  # through Gymnasium's passive checker (render modes, fps, frame)
    assert isinstance(first, np.ndarray) and first.shape == (H, W, 3) and first.dtype == np.uint8
    assert first.reshape(-1, 3).std(0).max() > 10.0
    rng = np.random.default_rng(0)
    for _ in range(15):
        env.step(rng.uniform(-5.0, 5.0, size=env.action_space.shape).astype(np.float32))
    moved = env.render()
    assert (moved != first).any(axis=-1).mean() > 0.02
    env.close()


def test_gymnasium_without_render_mode_and_bad_modes():
    import gymnasium

    from legoh_rl.envs.gym_env import HikingGymEnv

    with pytest.raises(ValueError, match=r"render_mode must be None or one of \['rgb_array'\], got 'depth'"):
        HikingGymEnv(render_mode="depth", trails=BoxScene(), num_threads=1)
    with pytest.raises(ValueError, match="width must be a positive integer"):
        HikingGymEnv(render_mode="rgb_array", width=0, trails=BoxScene(), num_threads=1)
    env = gymnasium.make("LegoH/Hike-H1-v0", trails=BoxScene(), num_threads=1).unwrapped
    assert env.render_mode is None
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="without a render mode"):
        assert env.render() is None


# ------------------------------------------------------------------ the look of the videos


def test_decimate_mesh_welds_a_dense_sphere():
    """Vertex clustering keeps the shape (every vertex within a cell of the sphere) with far
    fewer triangles, no degenerate or unused ones."""
    from legoh_rl.envs.render import decimate_mesh

    u, v = np.meshgrid(np.linspace(0, np.pi, 60), np.linspace(0, 2 * np.pi, 120), indexing="ij")
    verts = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1).reshape(-1, 3)
    idx = np.arange(60 * 120).reshape(60, 120)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    light_v, light_f = decimate_mesh(verts, faces, cell=0.2)
    assert light_f.shape[0] < faces.shape[0] / 8 and light_f.shape[0] > 50
    assert np.abs(np.linalg.norm(light_v, axis=1) - 1.0).max() < 0.2
    assert np.unique(light_f).size == light_v.shape[0]  # every vertex used
    assert ((light_f[:, 0] != light_f[:, 1]) & (light_f[:, 1] != light_f[:, 2]) & (light_f[:, 0] != light_f[:, 2])).all()
    with pytest.raises(ValueError, match="cell must be a positive length"):
        decimate_mesh(verts, faces, cell=0.0)


def test_inset_image_puts_a_framed_depth_tile_top_right():
    from legoh_rl.envs.render import inset_image

    frame = np.full((48, 64, 3), 7, np.uint8)
    depth = np.tile(np.linspace(1.0, 0.0, 8)[:, None], (1, 8))  # far at the top, near at the bottom
    out = inset_image(frame, depth[None], fraction=0.5)
    assert out is frame
    h = w = 24
    top, left = 3, 64 - 3 - w - 2
    assert (frame[top, left : left + w + 2] == 255).all() and (frame[top + h + 1, left : left + w + 2] == 255).all()
    tile = frame[top + 1 : top + 1 + h, left + 1 : left + 1 + w].astype(int)
    assert tile[-1].sum() > tile[0].sum() + 300  # near is bright
    assert (frame[:, :left] == 7).all() and (frame[top + h + 2 :] == 7).all()  # the rest untouched
    with pytest.raises(ValueError, match=r"inset image must be \(h, w\)"):
        inset_image(frame, np.zeros((2, 3, 4, 5)))


def test_render_model_is_a_styled_copy_and_physics_is_untouched(env):
    """Frames are drawn with a second model: the physics model's visual fields stay as built, and
    steps with renders in between give bit-identical observations and rewards."""
    _gl_context_or_skip()
    from legoh_rl.envs.render import check_same_layout

    phys = env.worlds.model
    before = {k: getattr(phys, k).copy() for k in ("geom_rgba", "geom_group", "geom_matid", "light_castshadow",
                                                    "light_dir", "mat_rgba")}
    gen = torch.Generator().manual_seed(3)
    actions = [(torch.rand(2, env.A, generator=gen) * 2 - 1) * 0.5 for _ in range(6)]

    def rollout(render: bool) -> list:
        env.set_seed(11)
        tds = [env.reset()]
        for a in actions:
            tds.append(env.step(TensorDict({"action": a}, batch_size=env.batch_size))["next"])
            if render:
                env.render(width=W, height=H, route=True)
        return tds

    plain, drawn = rollout(False), rollout(True)
    for x, y in zip(plain, drawn, strict=True):
        for key in x.keys(include_nested=True, leaves_only=True):
            torch.testing.assert_close(x[key], y[key], rtol=0, atol=0, equal_nan=True, msg=str(key))
    for k, v in before.items():
        np.testing.assert_array_equal(getattr(phys, k), v, err_msg=k)
    styled = env.render_model
    assert styled is not phys and styled.ntex >= 2 and phys.ntex == 0  # the sky and the ground's grid
    robot_faces = lambda m: sum(int(m.mesh_facenum[m.geom_dataid[g]]) for g in np.flatnonzero(  # noqa: E731
        (m.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & (m.geom_bodyid > 0)))
    assert robot_faces(styled) < robot_faces(phys) / 5  # the decimated robot
    with pytest.raises(ValueError, match="rendering model's layout differs.*'nq'"):
        check_same_layout(phys, mujoco.MjModel.from_xml_string("<mujoco/>"))


def test_frames_show_sky_lit_ground_and_the_route(env):
    """The video camera's frame: a blue sky (not black), a ground with contrast (checker, grid,
    shading), and with route=True the goal being walked to (yellow), P_A (green) and the route
    (blue), which are not there without it."""
    _gl_context_or_skip()
    from legoh_rl.training.evaluation import VIDEO_CAMERA

    env.reset()
    f = env.render(0, 160, 120, camera=VIDEO_CAMERA, route=True).astype(int)
    g = env.render(0, 160, 120, camera=VIDEO_CAMERA, route=False).astype(int)
    sky = f[:6].reshape(-1, 3).mean(0)
    assert sky[2] > 150 and sky[2] > sky[0] + 30, sky
    assert f[80:120, :50].mean(-1).std() > 6.0  # a ground patch beside the robot

    def marks(x):
        r, gr, b = x[..., 0], x[..., 1], x[..., 2]
        return {"yellow": int(((r > 200) & (gr > 170) & (b < 90)).sum()),
                "green": int(((gr > r + 60) & (gr > b + 40)).sum()),
                "blue": int(((b > r + 80) & (b > gr + 40) & (np.arange(x.shape[0])[:, None] > 30)).sum())}

    with_route, without = marks(f), marks(g)
    assert with_route["yellow"] >= without["yellow"] + 3, (with_route, without)
    assert with_route["green"] >= without["green"] + 10 and with_route["blue"] >= without["blue"] + 10, (with_route,
                                                                                                          without)


def test_terrain_is_drawn_finely_only_near_the_robot(env):
    """The trail heightfield is drawn in chunks: one level of detail per chunk, the finest only
    near the robot; a frame draws far fewer terrain triangles than the whole field."""
    _gl_context_or_skip()
    from legoh_rl.envs.render import TERRAIN_CHUNK, TERRAIN_LOD, TerrainDetail

    m = env.render_model
    detail = TerrainDetail(m)
    xy = env.worlds.qpos[0, :2]
    detail(xy)
    shown = detail.table[m.geom_group[detail.table] == 0]
    assert (m.geom_group[detail.table] == 0).sum(axis=1).tolist() == [1] * len(detail.table)  # one level each
    fine = detail.table[:, 0][m.geom_group[detail.table[:, 0]] == 0]
    assert fine.size and np.all(np.linalg.norm(m.geom_pos[fine, :2] - xy, axis=1)
                                < TERRAIN_LOD[0][1] + TERRAIN_CHUNK * 0.1 * 0.75)
    tris = lambda ids: int(sum(2 * (m.hfield_nrow[m.geom_dataid[g]] - 1) * (m.hfield_ncol[m.geom_dataid[g]] - 1)  # noqa: E731
                               for g in ids))
    phys = env.worlds.model
    whole = 2 * (int(phys.hfield_nrow[0]) - 1) * (int(phys.hfield_ncol[0]) - 1)
    assert tris(shown) < whole / 2, (tris(shown), whole)


def test_video_clips_show_the_students_depth_inset_and_a_progress_bar(tmp_path, capsys):
    """render_videos on an env with the depth camera: one rollout writes every clip (a world may
    be in several), each world's tile has the latest depth image framed in white at its top
    right; a tqdm bar counts the frames."""
    _gl_context_or_skip()
    import imageio.v2 as imageio

    from legoh_rl.training.evaluation import render_videos
    from legoh_rl.training.policies import ZeroPolicy

    scene = BoxScene(boxes=[((1.5, 0.0, 0.15), (0.2, 1.0, 0.15))])
    denv = HikingEnv(HikingEnvConfig(num_envs=2, depth=True, num_threads=1), trails=scene)
    try:
        clips = {tmp_path / "both.mp4": [0, 1], tmp_path / "one.mp4": [1]}
        written = render_videos(denv, ZeroPolicy(denv.A), clips, seconds=0.1, size=(H, W))
        assert set(written) == set(clips)
        both, one = imageio.mimread(tmp_path / "both.mp4"), imageio.mimread(tmp_path / "one.mp4")
        assert len(both) == len(one) == 3 and both[0].shape == (H, 2 * W, 3) and one[0].shape == (H, W, 3)
        assert "video (2 robots)" in capsys.readouterr().err
        h = round(0.34 * H)
        left = W - 3 - h - 2  # a square inset (64 x 64 depth images)
        for tile in (both[-1][:, :W], both[-1][:, W:], one[-1]):
            # the white frame (after the video codec's chroma blur; the sky there is ~185)
            border = tile[3, left : W - 3].astype(int).mean(-1)
            assert (border > 215).all(), border
            inset = tile[4 : 4 + h, left + 1 : W - 4].astype(int).mean(-1)
            assert inset[-1].mean() > inset[0].mean() + 60  # near (the ground below) bright, far dark
    finally:
        denv.close()


def test_category_worlds_take_one_robot_per_level_first():
    from legoh_rl.training.evaluation import EvalProtocol, category_worlds

    protocol = EvalProtocol(categories=("ditch", "gap"), levels=(0, 2, 4), robots_per_cell=2)
    # worlds: ditch L0 r0, r1 = 0, 1; ditch L2 = 2, 3; ditch L4 = 4, 5; gap L0 = 6, 7; ...
    assert category_worlds(protocol, "gap") == [6, 8, 10, 7]
    assert category_worlds(protocol, "ditch", count=2) == [0, 2]
    with pytest.raises(ValueError, match="category 'forest' is not in the protocol's categories"):
        category_worlds(protocol, "forest")


def test_evaluation_writes_one_clip_per_category_when_asked(env, tmp_path):
    """evaluate.py's video_per_category=true: robots.mp4 and videos/<category>.mp4 for each
    category, from one rollout."""
    _gl_context_or_skip()
    import sys
    from pathlib import Path

    import imageio.v2 as imageio
    from omegaconf import OmegaConf

    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import ZeroPolicy

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))
    from legoh_rl.training import eval_run

    protocol = EvalProtocol(categories=("randommix", "gap"), levels=(0,), robots_per_cell=1)  # 2 worlds, as env
    cfg = OmegaConf.create({"video_per_category": True, "video_seconds": 0.06})
    main, per_category = eval_run.eval_videos(env, ZeroPolicy(env.A), protocol, cfg, tmp_path)
    assert main == tmp_path / "robots.mp4" and imageio.mimread(main)[0].shape == (240, 640, 3)
    assert per_category == {c: tmp_path / "videos" / f"{c}.mp4" for c in ("randommix", "gap")}
    for path in per_category.values():
        frames = imageio.mimread(path)
        assert len(frames) == 2 and frames[0].shape == (240, 320, 3)
    cfg.video_per_category, cfg.video_seconds = False, 0.02  # one frame
    assert eval_run.eval_videos(env, ZeroPolicy(env.A), protocol, cfg, tmp_path / "b")[1] == {}
    assert not (tmp_path / "b" / "videos").exists()
