"""The policy viewer (recipes/play.py): the simulation session, the geometry it draws, the browser
viewer's GUI logic, MuJoCo's native viewer overlay, and a real browser loading the page.

The browser test runs Debian's headless Chromium with software WebGL (SwiftShader): it loads the
viewer's page, checks that the screenshot shows a scene (not a blank page), then changes the trail
with the viewer's category control and checks that the page shows another scene. `.ci/run`
installs Chromium before `make test`; where it is missing this module installs it when it may
(root with apt-get) and otherwise skips that one test, saying why.
"""

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh
from omegaconf import OmegaConf

from legoh_rl.viewer import PlaySession, TrailChoice, anticipated_goals
from legoh_rl.viewer.geometry import geom_mesh, geom_world_poses, simplify_mesh, static_geoms
from legoh_rl.viewer.native import NoDisplayError, check_display, draw_overlay

ROOT = Path(__file__).resolve().parents[1]
STUDENT = str(ROOT / "checkpoints" / "student_h1.pt")
ORACLE = str(ROOT / "checkpoints" / "oracle_h1.pt")
sys.path.insert(0, str(ROOT / "recipes"))


@pytest.fixture(scope="module")
def student():
    """A student on gap level 2, two robots (variants 0 and 1), stepped 20 times."""
    session = PlaySession(STUDENT, category="gap", level=2, num_robots=2)
    for _ in range(20):
        snap = session.step()
    yield session, snap
    session.close()


def test_student_snapshot_has_goals_depth_and_two_lanes(student):
    session, snap = student
    assert session.is_student and session.choice == TrailChoice("h1", "gap", 2, 0)
    g = len(session.robot_meshes)
    assert g > 5 and all(m.kind == "mesh" for m in session.robot_meshes)  # H1's visual meshes
    assert snap.step == 20 and snap.base_pos.shape == (2, 3) and snap.base_yaw.shape == (2,)
    assert snap.geom_pos.shape == (2, g, 3) and snap.geom_quat.shape == (2, g, 4)
    np.testing.assert_allclose(np.linalg.norm(snap.geom_quat, axis=-1), 1.0, atol=1e-9)
    assert snap.anticipated_goals.shape == (2, 3, 3) and np.isfinite(snap.anticipated_goals).all()
    np.testing.assert_allclose(np.linalg.norm(snap.anticipated_dirs, axis=-1), 1.0, atol=1e-6)
    assert snap.depth.shape == (2, 64, 64) and snap.depth.min() >= 0.0 and snap.depth.max() <= 1.0
    assert snap.depth.min() < 0.9  # the camera sees the trail
    # one lane per robot: variant 0 and variant 1, side by side, each its own route
    assert abs(snap.start[1, 1] - snap.start[0, 1]) == pytest.approx(5.0)  # tile width
    for w in range(2):  # the expert goals lead from P_A to P_B (the last) along the lane
        goals = snap.expert_goals[w, :snap.num_expert_goals[w]]
        assert len(goals) > 1 and (np.diff(goals[:, 0]) > 0).all() and goals[0, 0] > snap.start[w, 0]
        np.testing.assert_allclose(goals[-1], snap.end[w])
    length = np.linalg.norm(snap.end[:, :2] - snap.start[:, :2], axis=1)
    assert (snap.distance_to_go > 0).all() and (snap.distance_to_go < length).all()  # walked some of it
    assert np.abs(snap.base_pos[:, 1] - snap.start[:, 1]).max() < 1.0  # each robot on its own lane


def test_anticipated_goals_sit_on_the_expert_goals_when_they_are_right(student):
    """The student's directions placed in the world: fed the expert's own directions (the
    ``expert_goals`` observation) they land exactly on the expert goals."""
    session, snap = student
    base = session.base
    exact = session.td["expert_goals"].cpu().numpy()  # (2, 3, 2): the expert's directions now
    dirs, points = anticipated_goals(exact, snap.base_pos, snap.base_yaw, base.goals, base.goal_idx, base.num_goals,
                                     base.trails.height_at)
    idx = np.minimum(base.goal_idx[:, None] + np.arange(3), base.num_goals[:, None] - 1)
    np.testing.assert_allclose(points[..., :2], base.goals[np.arange(2)[:, None], idx, :2], atol=1e-5)
    np.testing.assert_allclose(points[..., 2], base.trails.height_at(points[..., :2].reshape(-1, 2)).reshape(2, 3))
    turned = anticipated_goals(exact[:, :, ::-1], snap.base_pos, snap.base_yaw, base.goals, base.goal_idx,
                               base.num_goals, base.trails.height_at)[1]
    assert np.abs(turned[..., :2] - points[..., :2]).max() > 0.1  # a wrong direction lands elsewhere


def test_geom_poses_and_meshes_are_mujocos_own(student):
    session, _ = student
    model = session.base.worlds.model
    data = mujoco.MjData(model)
    session.base.worlds.world_data(1, data)
    mujoco.mj_kinematics(model, data)
    geoms = np.arange(model.ngeom)
    pos, quat = geom_world_poses(model, geoms, data.xpos[None], data.xquat[None])
    mat = np.zeros((model.ngeom, 9))
    for g in geoms:
        mujoco.mju_quat2Mat(mat[g], quat[0, g])
    np.testing.assert_allclose(pos[0], data.geom_xpos, atol=1e-9)
    np.testing.assert_allclose(mat, data.geom_xmat, atol=1e-9)
    terrain = [m for m, _, _ in static_geoms(model) if m.kind == "hfield"]
    assert len(terrain) == 1
    h = int(model.geom_dataid[terrain[0].geom])
    assert terrain[0].vertices.shape == (model.hfield_nrow[h] * model.hfield_ncol[h], 3)
    assert terrain[0].vertices[:, 2].max() == pytest.approx(model.hfield_size[h][2], rel=1e-5)
    box = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom type='box' size='.1 .2 .3'/></worldbody></mujoco>")
    vertices, faces = geom_mesh(box, 0)
    np.testing.assert_allclose(vertices.max(axis=0), [0.1, 0.2, 0.3], rtol=1e-6)
    assert faces.shape == (12, 3)
    # the robot's meshes are drawn simplified: far fewer triangles, the same surface and extent
    mesh = max(session.robot_meshes, key=lambda m: len(m.faces))
    v, f = simplify_mesh(mesh.vertices, mesh.faces, 0.005)
    full, light = trimesh.Trimesh(mesh.vertices, mesh.faces), trimesh.Trimesh(v, f)
    assert len(f) < len(mesh.faces) / 2 and light.area == pytest.approx(full.area, rel=0.05)
    np.testing.assert_allclose(light.bounds, full.bounds, atol=0.005)
    ball = trimesh.creation.icosphere(subdivisions=5, radius=0.1)  # closed, outward: its volume is positive
    v, f = simplify_mesh(ball.vertices, ball.faces, 0.01)
    assert len(f) < len(ball.faces) / 4 and trimesh.Trimesh(v, f).volume == pytest.approx(ball.volume, rel=0.05)
    with pytest.raises(ValueError, match="cell must be a positive length"):
        simplify_mesh(v, f, 0.0)


def test_native_overlay_draws_other_robots_and_markers(student):
    session, snap = student
    model = session.base.worlds.model
    scene = mujoco.MjvScene(model, maxgeom=2000)
    n = draw_overlay(scene, session, snap)
    markers = 2 * 3 + int(snap.num_expert_goals.sum()) + snap.anticipated_goals[:, :, 0].size
    assert n > markers  # plus the second robot's geoms
    centres = np.array([scene.geoms[i].pos for i in range(n)])
    assert np.abs(centres - snap.start[0]).sum(axis=1).min() < 1e-6  # P_A of robot 0
    assert np.abs(centres[:, None] - snap.geom_pos[1][None]).sum(axis=-1).min() < 1e-6  # a geom of robot 1


def test_oracle_session_changes_trail_and_refuses_bad_names(tmp_path):
    session = PlaySession(ORACLE, category="gap", level=2)
    try:
        snap = session.step()
        assert session.kind == "oracle" and snap.anticipated_goals is None and snap.depth is None
        before = [m.vertices for m, _, _ in session.terrain_meshes if m.kind == "hfield"][0]
        assert not any(m.kind == "cylinder" for m, _, _ in session.terrain_meshes)
        assert session.change(category="forest", level=1) is True
        assert session.choice == TrailChoice("h1", "forest", 1, 0) and session.steps == 0
        after = [m.vertices for m, _, _ in session.terrain_meshes if m.kind == "hfield"][0]
        assert before.shape != after.shape or np.abs(before - after).max() > 0.05  # another terrain
        assert any(m.kind == "cylinder" for m, _, _ in session.terrain_meshes)  # the forest's trees
        assert int(session.base.trails.tile_level[0]) == 1
        assert session.change(category="forest") is False  # the same choice: nothing rebuilt
        for change, named in (({"robot": "t800"}, "'t800'"), ({"category": "desert"}, "'desert'"),
                              ({"level": 7}, "7"), ({"level": "hard"}, "'hard'"), ({"variant": -1}, "-1")):
            with pytest.raises(ValueError, match=named):
                session.change(**change)
        assert session.choice == TrailChoice("h1", "forest", 1, 0)  # still running as before
        session.step()
        assert session.policy_for("g1").endswith("oracle_g1.pt")  # the sibling checkpoint
        mine = tmp_path / "mine.pt"
        shutil.copy(ORACLE, mine)
        lone = PlaySession(str(mine), category="gap", level=0)
        with pytest.raises(ValueError, match=r"no policy for robot 'g1'.*checkpoints\.g1="):
            lone.policy_for("g1")
        lone.close()
        with pytest.raises(ValueError, match="num_robots must be an integer in \\[1, 16\\], got 0"):
            PlaySession(ORACLE, num_robots=0)
    finally:
        session.close()


def test_web_viewer_applies_and_refuses_control_changes(tmp_path):
    """The GUI's controls queue changes that the loop applies; one it cannot make is reported and
    the control set back."""
    pytest.importorskip("viser")
    from legoh_rl.viewer.web import WebViewer, depth_image, terrain_colors

    mine = tmp_path / "mine.pt"
    shutil.copy(ORACLE, mine)
    session = PlaySession(str(mine), category="gap", level=1)
    viewer = WebViewer(session, port=0)  # a free port
    try:
        assert viewer.revision == 1 and viewer.snapshot.base_pos.shape == (1, 3)
        viewer.controls["level"].value = 3
        assert viewer.process_commands() == 1
        assert session.choice.level == 3 and viewer.revision == 2 and viewer.status == ""
        viewer.controls["robot"].value = "g1"  # no g1 policy beside mine.pt
        viewer.process_commands()
        assert "no policy for robot 'g1'" in viewer.status and session.choice.robot == "h1"
        assert viewer.controls["robot"].value == "h1" and viewer.revision == 2
        viewer.run(seconds=0.3)
        assert session.steps > 0
    finally:
        viewer.close()
        session.close()
    z = np.array([[0.0, 0.0, -1.0], [0.0, 0.5, 0.0], [0.5, 0.0, 0.3]])
    colors = terrain_colors(z, np.array([0.6, 0.5, 0.4, 1.0]))
    assert colors.dtype == np.uint8 and colors[0].sum() < colors[1].sum() < colors[2].sum()  # pits darker
    image = depth_image(np.array([[0.2, 0.5], [0.9, 1.0]]), scale=2)
    assert image.shape == (4, 4, 3) and (image[2:, 2:] == 0).all() and image[0, 0].sum() > image[2, 0].sum()


def test_missing_viser_and_missing_display_are_explained(monkeypatch):
    from legoh_rl.viewer import web

    monkeypatch.setitem(sys.modules, "viser", None)
    with pytest.raises(ImportError, match=r"pip install 'legoh-rl\[viewer\]'"):
        web.require_viser()
    with pytest.raises(NoDisplayError, match="DISPLAY is unset"):
        check_display({}, "linux")
    check_display({"DISPLAY": ":0"}, "linux")
    import play as play_recipe

    cfg = OmegaConf.load(ROOT / "recipes" / "config" / "play.yaml")
    with pytest.raises(ValueError, match="checkpoint is required"):
        play_recipe.play(cfg)
    with pytest.raises(ValueError, match="unknown viewer 'vr'"):
        play_recipe.play(OmegaConf.merge(cfg, {"checkpoint": ORACLE, "viewer": "vr"}))
    with pytest.raises(ValueError, match="port must be an integer in \\[0, 65535\\].*'http'"):
        play_recipe.play(OmegaConf.merge(cfg, {"checkpoint": ORACLE, "port": "http"}))
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        with pytest.raises(NoDisplayError, match="viewer=browser"):
            play_recipe.play(OmegaConf.merge(cfg, {"checkpoint": ORACLE, "viewer": "native"}))


@pytest.mark.parametrize("setting, message", [
    ({"levle": 2}, "play's config has no setting 'levle'"),
    ({"level": 7}, "level must be an integer in [0, 4], got 7"),
    ({"category": "swamp"}, "category: unknown trail category 'swamp'"),
    ({"robot": "atlas"}, "robot: unknown robot 'atlas'"),
    ({"num_robots": 17}, "num_robots must be an integer in [1, 16], got 17"),
    ({"variant": -1}, "variant must be an integer >= 0, got -1"),
    ({"speed": 0}, "speed must be a number in (0.0, 1.0], got 0"),
    ({"seconds": -1.0}, "seconds must be a positive number, got -1.0 (or null)"),
    ({"follow": "yes"}, "follow must be true or false, got 'yes'"),
    ({"device": "tpu"}, "device='tpu' is not a device"),
    ({"checkpoints": 5}, "checkpoints must map robot names to checkpoints, got 5"),
    ({"checkpoints": {"atlas": "atlas.pt"}}, "checkpoints: unknown robot 'atlas'"),
    ({"checkpoints": {"g1": ""}}, "checkpoints.g1 must be a non-empty string, got ''"),
    ({"screenshot_size": [640]}, "screenshot_size must be [width, height] in pixels (>= 64), got [640]"),
    ({"screenshot_size": [10, 10]}, "screenshot_size must be a non-empty list of integers >= 64, got [10, 10]"),
])
def test_play_refuses_a_bad_setting_by_name_before_any_work(setting, message, monkeypatch):
    """play.py's validate: every key and value checked before a policy is loaded or a port opened."""
    import play as play_recipe

    built = []
    monkeypatch.setattr(play_recipe, "PlaySession", lambda *a, **k: built.append(1))
    cfg = OmegaConf.merge(OmegaConf.load(ROOT / "recipes" / "config" / "play.yaml"), {"checkpoint": ORACLE})
    play_recipe.validate(cfg)  # the yaml's own values with a checkpoint are valid
    with pytest.raises(ValueError) as refused:
        play_recipe.play(OmegaConf.merge(cfg, setting))
    assert message in str(refused.value)
    assert built == []


# ---------------------------------------------------------------------- a real browser
@pytest.fixture(scope="module")
def chromium() -> str:
    """Debian's Chromium: found, or installed here when we may (root with apt-get)."""
    from legoh_rl.viewer.browser import find_chromium

    try:
        return find_chromium()
    except FileNotFoundError as missing:
        if os.geteuid() != 0 or not shutil.which("apt-get"):
            pytest.skip(f"{missing} (not root: cannot install it here)")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    subprocess.run(["apt-get", "update", "-qq"], check=True, env=env, capture_output=True)
    subprocess.run(["apt-get", "install", "-y", "-qq", "chromium"], check=True, env=env, capture_output=True)
    return find_chromium()


@pytest.mark.slow
def test_browser_shows_the_scene_and_a_control_changes_the_trail(chromium, tmp_path):
    pytest.importorskip("viser")
    from legoh_rl.viewer.browser import HeadlessChromium, changed_fraction, scene_stats
    from legoh_rl.viewer.web import WebViewer

    session = PlaySession(STUDENT, category="gap", level=1)
    viewer = WebViewer(session, port=0)  # a free port
    for _ in range(25):
        session.step()
    viewer.draw()
    viewer.controls["pause"].value = True  # a still scene: the screenshots wait for it, not for motion
    loop = threading.Thread(target=viewer.run, kwargs={"seconds": 240}, daemon=True)
    loop.start()
    try:
        with HeadlessChromium(viewer.url, binary=chromium, width=800, height=500, timeout=120) as browser:
            first = browser.wait_for_scene(settle=1.0, timeout=150)
            (tmp_path / "gap.png").write_bytes(first)
            stats = scene_stats(first)
            assert stats["drawn"] > 0.6 and stats["colors"] > 1000, stats  # a drawn scene, not a blank page
            viewer.controls["category"].value = "forest"  # as the page's dropdown does, from the server
            deadline = time.monotonic() + 60
            while viewer.revision < 2 and time.monotonic() < deadline:
                time.sleep(0.1)
            assert session.choice.category == "forest" and viewer.revision == 2
            second = browser.wait_for_scene(settle=1.0, timeout=150, changed_from=first)
            (tmp_path / "forest.png").write_bytes(second)
            assert changed_fraction(first, second) > 0.05  # the page shows the new trail
    finally:
        viewer.close()
        loop.join(timeout=30)
        session.close()
