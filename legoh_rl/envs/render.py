"""Off-screen RGB frames of chosen worlds of a batched env (MuJoCo's ``mujoco.Renderer``).

:class:`WorldRenderer` draws worlds of a :class:`~legoh_rl.envs.physics.BatchedWorlds` one after
the other with one OpenGL context: each world's state is copied out of the batch into a scratch
``MjData`` (the batch is persistent, so its positions are those of the last step or reset and no
extra physics call is needed), then drawn from a camera. By default the camera is a
:class:`TrackingCamera` that follows the world's torso; a camera of the model (by name or id) or
any ``mujoco.MjvCamera`` also works. :meth:`HikingEnv.render <legoh_rl.envs.hiking.HikingEnv.render>`
is the public entry point.

The look: frames are drawn with a *rendering model* (:func:`build_render_model`), the physics
model built a second time with visual-only changes (:func:`style_render_spec`): a sky, a ground
with a 1 m grid under a low sun whose shadows follow the robot, obstacles in colours that stand
out from the ground, a lighter robot drawn with lighter meshes. The physics model is never
touched: each frame copies the world's positions into the rendering model's own ``MjData`` and
computes its kinematics there. :func:`add_route_markers` draws a trail's P_A, expert goals,
waypoint and P_B into a scene, and :func:`inset_image` puts a small picture (the student's depth
image) in a frame's corner.

Rendering needs an OpenGL backend. Without a display, set ``MUJOCO_GL=egl`` (or ``osmesa``)
*before* ``mujoco`` is first imported, and install the libraries (Debian/Ubuntu:
``apt-get install libegl1 libgl1-mesa-dri`` for EGL, ``libosmesa6`` for OSMesa; ``make gl`` does
the former). When no context can be made, :class:`RenderingUnavailableError` says so.

Why one file of ~800 lines: the renderer and the rendering model it draws change together (a new
look is a model change and a per-frame update, e.g. :class:`TerrainDetail`, :class:`SeeThrough`),
and ``HikingEnv`` takes both from here; the markers and image helpers are the frame's overlays.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

__all__ = [
    "DEFAULT_HEIGHT",
    "DEFAULT_WIDTH",
    "OBSTACLE_COLOURS",
    "RenderingUnavailableError",
    "SeeThrough",
    "TerrainDetail",
    "TrackingCamera",
    "WorldRenderer",
    "add_route_markers",
    "build_render_model",
    "check_same_layout",
    "decimate_mesh",
    "inset_image",
    "style_render_spec",
    "tile_frames",
]

DEFAULT_HEIGHT = 240
DEFAULT_WIDTH = 320


class RenderingUnavailableError(RuntimeError):
    """MuJoCo could not make an off-screen OpenGL context (no backend or libraries missing)."""


@dataclass(frozen=True)
class TrackingCamera:
    """A free camera that looks at one body of each rendered world (by default its torso).

    Args:
        distance: from the camera to the tracked body, m.
        elevation: degrees; negative looks down on the robot.
        azimuth: degrees about the world z axis (90 looks along +y; 135, the default, views the
            robot from its front-left when it walks along +x).
        body: the tracked body, by name or id; ``None`` is the robot's torso.
    """

    distance: float = 3.5
    elevation: float = -20.0
    azimuth: float = 135.0
    body: str | int | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.distance) and self.distance > 0.0):
            raise ValueError(f"TrackingCamera.distance must be a positive number of metres, got {self.distance!r}")
        for name in ("elevation", "azimuth"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"TrackingCamera.{name} must be finite, got {getattr(self, name)!r}")

    def mjv_camera(self, model: mujoco.MjModel, default_body: int) -> mujoco.MjvCamera:
        """The ``mujoco.MjvCamera`` (``mjCAMERA_TRACKING``) of this camera in ``model``.

        MuJoCo's tracking camera looks at the tracked body's subtree centre of mass of the world
        being drawn, so one camera serves every world.
        """
        body = default_body if self.body is None else self.body
        if isinstance(body, str):
            bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
            if bid < 0:
                raise ValueError(f"TrackingCamera.body {body!r} is not a body of the model")
            body = bid
        if not 0 <= int(body) < model.nbody:
            raise ValueError(f"TrackingCamera.body id {body} is out of range [0, {model.nbody})")
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        cam.trackbodyid = int(body)
        cam.distance, cam.elevation, cam.azimuth = self.distance, self.elevation, self.azimuth
        return cam


def _gl_backend() -> str:
    """The MUJOCO_GL value mujoco read when it was imported (what its renderer uses)."""
    try:
        from mujoco.rendering.classic import gl_context

        return getattr(gl_context, "_MUJOCO_GL", os.environ.get("MUJOCO_GL", ""))
    except ImportError:  # pragma: no cover - other mujoco layouts
        return os.environ.get("MUJOCO_GL", "")


def _unavailable(err: BaseException) -> RenderingUnavailableError:
    used = _gl_backend()
    now = os.environ.get("MUJOCO_GL", "")
    late = (f" (MUJOCO_GL is now {now!r}, but mujoco reads it once, when it is first imported: set it "
            "before importing mujoco or legoh_rl)") if now.lower().strip() != used else ""
    return RenderingUnavailableError(
        f"MuJoCo off-screen rendering is unavailable with MUJOCO_GL={used!r}{late}: "
        f"{type(err).__name__}: {err}. Without a display, set MUJOCO_GL=egl (or MUJOCO_GL=osmesa) and install "
        "the OpenGL libraries: on Debian/Ubuntu `apt-get install libegl1 libgl1-mesa-dri` for EGL "
        "(`make gl` does this) or `apt-get install libosmesa6` for OSMesa."
    )


class WorldRenderer:
    """RGB frames of worlds of a :class:`~legoh_rl.envs.physics.BatchedWorlds`, one GL context.

    Args:
        worlds: the batched worlds (any :class:`~legoh_rl.envs.physics.Worlds` backend).
        track_body: the body a :class:`TrackingCamera` follows by default (the torso).
        height: frame height, pixels (>= 1).
        width: frame width, pixels (>= 1).
        model: the model to draw with: ``None`` draws with ``worlds.model`` itself; a rendering
            model (:func:`build_render_model`) must have the physics model's kinematic layout
            (bodies, joints, lights, cameras: :func:`check_same_layout`), into which each world's
            positions are copied.

    The drawing model's off-screen framebuffer (``vis.global_.offwidth``/``offheight``, a
    drawing-only setting) is enlarged when a frame is bigger than it.

    Raises:
        RenderingUnavailableError: no OpenGL context (names MUJOCO_GL and what to install).
        ValueError: ``model`` has another layout than the physics model.
    """

    def __init__(self, worlds, track_body: int, height: int = DEFAULT_HEIGHT, width: int = DEFAULT_WIDTH,
                 model: mujoco.MjModel | None = None) -> None:
        height, width = _size(height, "height"), _size(width, "width")
        physics = worlds.model
        model = physics if model is None else model
        if model is not physics:
            check_same_layout(physics, model)
        vis = model.vis.global_
        vis.offwidth, vis.offheight = max(int(vis.offwidth), width), max(int(vis.offheight), height)
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as err:  # the GL backend failed: ImportError, RuntimeError, mujoco.FatalError, ...
            raise _unavailable(err) from err
        self.worlds = worlds
        self.model = model
        self.track_body = int(track_body)
        self.height, self.width = height, width
        self._data = mujoco.MjData(model)
        #: a scratch state of the physics model when drawing with another model, else None
        self._physics_data = mujoco.MjData(physics) if model is not physics else None
        self._sun = _sun_light(model)
        self._see_through = SeeThrough(model)
        self._detail = TerrainDetail(model)
        self._default_camera = TrackingCamera().mjv_camera(model, self.track_body)

    def camera(self, camera: TrackingCamera | str | int | mujoco.MjvCamera | None = None):
        """What :meth:`render` draws from: an ``MjvCamera``, or a model camera's name or id.

        ``None`` is the default :class:`TrackingCamera` (3.5 m from the torso, 20 degrees down).
        """
        if camera is None:
            return self._default_camera
        if isinstance(camera, TrackingCamera):
            return camera.mjv_camera(self.model, self.track_body)
        if isinstance(camera, mujoco.MjvCamera):
            return camera
        if isinstance(camera, str):
            if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
                names = [self.model.camera(i).name for i in range(self.model.ncam)]
                raise ValueError(f"camera {camera!r} is not a camera of the model; its cameras: {names}, or pass "
                                 "a TrackingCamera, a mujoco.MjvCamera or None (the torso-tracking camera)")
            return camera
        if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool):
            if not -1 <= int(camera) < self.model.ncam:
                raise ValueError(f"camera id {camera} is out of range [-1, {self.model.ncam})")
            return int(camera)
        raise TypeError(f"camera must be None, a TrackingCamera, a camera name or id, or a mujoco.MjvCamera; "
                        f"got {type(camera).__name__}")

    def render(self, ids: np.ndarray, camera=None, out: np.ndarray | None = None,
               decorate: Callable[[int, mujoco.MjvScene], None] | None = None) -> np.ndarray:
        """Frames of worlds ``ids``.

        Args:
            ids: (n,) int world indices (validated by the caller).
            camera: see :meth:`camera`.
            out: optional (n, height, width, 3) uint8 array to write into.
            decorate: called as ``decorate(world, scene)`` after the scene of ``world`` is made and
                before it is drawn, to add geoms to it (e.g. :func:`add_route_markers`).

        Returns:
            (n, height, width, 3) uint8 RGB frames, row ``i`` of world ``ids[i]``.
        """
        if self._renderer is None:
            raise RuntimeError("this WorldRenderer is closed")
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        cam = self.camera(camera)
        shape = (ids.size, self.height, self.width, 3)
        if out is None:
            out = np.empty(shape, dtype=np.uint8)
        elif out.shape != shape or out.dtype != np.uint8:
            raise ValueError(f"out must be a uint8 array of shape {shape}, got {out.dtype} {out.shape}")
        for i, w in enumerate(ids):
            self._world_state(int(w))
            self._renderer.update_scene(self._data, camera=cam)
            self._see_through(self._renderer.scene, self._data.subtree_com[self.track_body])
            if decorate is not None:
                decorate(int(w), self._renderer.scene)
            self._renderer.render(out=out[i])
        return out

    def _world_state(self, world: int) -> None:
        """World ``world``'s positions in the drawing model's ``MjData``, the sun above its robot."""
        if self._physics_data is None:
            self.worlds.world_data(world, self._data)
        else:  # another model: copy the state, compute its positions there (no physics step)
            src, data, model = self._physics_data, self._data, self.model
            self.worlds.world_data(world, src)
            data.qpos[:] = src.qpos
            data.qvel[:] = src.qvel
            data.mocap_pos[:] = src.mocap_pos
            data.mocap_quat[:] = src.mocap_quat
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            mujoco.mj_camlight(model, data)
        self._detail(self._data.xpos[self.track_body])
        if self._sun is not None:  # a directional light's shadow box is centred on its position
            light, height = self._sun
            self._data.light_xpos[light] = self._data.xpos[self.track_body] - height * self._data.light_xdir[light]

    def close(self) -> None:
        """Free the GL context (idempotent)."""
        renderer, self._renderer = self._renderer, None
        if renderer is not None:
            renderer.close()


# ---------------------------------------------------------------------------------- the look
#: sky gradient, zenith to horizon (RGB in [0, 1])
SKY_ZENITH = (0.33, 0.55, 0.85)
SKY_HORIZON = (0.85, 0.90, 0.96)
#: the ground's 1 m checker (two sandy tones) and its grid lines
GROUND_LIGHT = (0.74, 0.68, 0.55)
GROUND_DARK = (0.64, 0.58, 0.46)
GROUND_LINE = (0.50, 0.45, 0.36)
#: ground checker cell, m (each texture repeat holds 2 x 2 cells)
GROUND_CELL = 1.0
#: obstacle colours by role (the part after ``obstacle_<k>_`` in a geom's name): they stand out
#: from the sandy ground; others (a hand-made scene's boxes) get :data:`OBSTACLE_DEFAULT`
OBSTACLE_COLOURS = {
    "hurdle": (0.90, 0.22, 0.12, 1.0),
    "log": (0.78, 0.42, 0.10, 1.0),
    "tree": (0.20, 0.48, 0.22, 1.0),
    "rock": (0.38, 0.45, 0.62, 1.0),
    "boulder": (0.33, 0.40, 0.58, 1.0),
    "wall": (0.70, 0.28, 0.55, 1.0),
    "block": (0.25, 0.52, 0.80, 1.0),
}
OBSTACLE_DEFAULT = (0.85, 0.50, 0.12, 1.0)
#: the robot's materials are mixed half and half with this steel blue (lighter than the black
#: Menagerie robots, still darker than the ground)
ROBOT_TINT = (0.36, 0.40, 0.50)
#: the sun: direction it shines (down, from the back-left of a robot walking along +x), colour
SUN_DIR = (0.35, -0.45, -0.82)
SUN_DIFFUSE = (0.80, 0.78, 0.72)
SUN_NAME = "legoh_sun"
#: the sun is placed this far (m) from the tracked body, against its direction, every frame; its
#: shadow box is +- :data:`SHADOW_HALF_WIDTH` m around that body
SUN_DISTANCE = 12.0
SHADOW_HALF_WIDTH = 6.0
#: the robot's file meshes are welded on a grid of this cell, m, in the rendering model (H1:
#: 287k triangles -> 27k): a robot a few metres away looks the same and draws ~4x faster
MESH_CELL = 0.01
#: multisampling of the off-screen buffer in the rendering model (MuJoCo's default is 4): with
#: the sun's shadows, 2 samples double a frame's time in software for little gain at 320 x 240
OFFSAMPLES = 0
#: the sun's shadow map, texels a side (1.2 cm each over the +- 6 m box)
SHADOW_SIZE = 1024
#: the trail heightfield is drawn in square chunks of this many samples a side, each at three
#: levels of detail: (sample stride, used up to this distance from the robot, m). A trail grid
#: draws ~300k triangles per pass at full detail, 80% of a frame's time in software; around one
#: robot ~50k, whatever the grid's size
TERRAIN_CHUNK = 32
TERRAIN_LOD = ((1, 6.0), (2, 14.0), (4, float("inf")))
#: geom group of the chunks not drawn this frame (MuJoCo draws groups 0-2 by default)
HIDDEN_GROUP = 5
_CHUNK_PREFIX = "legoh_terrain_lod"


def decimate_mesh(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """A lighter mesh by vertex clustering: vertices in the same ``cell``-sized grid cube are
    welded at their mean; triangles that collapse, and repeats, are dropped.

    Args:
        vertices: (V, 3) float positions.
        faces: (F, 3) int vertex indices.
        cell: grid cube edge, in the vertices' unit (> 0).

    Returns:
        (vertices (V', 3) float64, faces (F', 3) int32), every vertex used by a face.
    """
    if not (np.isfinite(cell) and cell > 0.0):
        raise ValueError(f"decimate_mesh cell must be a positive length, got {cell!r}")
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(faces):
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
    grid = np.floor(vertices / cell).astype(np.int64)
    grid -= grid.min(axis=0)
    span = grid.max(axis=0) + 1
    # one int64 key per cube (1-D np.unique is ~10x faster than on rows)
    _, cluster = np.unique((grid[:, 0] * span[1] + grid[:, 1]) * span[2] + grid[:, 2], return_inverse=True)
    cluster = cluster.reshape(-1)
    count = np.bincount(cluster)
    merged = np.stack([np.bincount(cluster, weights=vertices[:, k]) for k in range(3)], axis=1) / count[:, None]
    tri = cluster[faces]
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    key = np.sort(tri, axis=1)
    _, first = np.unique((key[:, 0] * count.size + key[:, 1]) * count.size + key[:, 2], return_index=True)
    tri = tri[np.sort(first)]
    used, tri = np.unique(tri, return_inverse=True)
    return merged[used], tri.reshape(-1, 3).astype(np.int32)


@functools.lru_cache(maxsize=128)
def _decimated_file(path: str, cell: float) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`decimate_mesh` of a mesh file (read by trimesh), or None when it cannot be read or
    is already light (under 2000 triangles) or would fall apart (under 16 left)."""
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception:  # an unreadable or unknown format: MuJoCo loads it as it is
        return None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    if faces.shape[0] < 2000:
        return None
    vertices, faces = decimate_mesh(np.asarray(mesh.vertices), faces, cell)
    return (vertices, faces) if faces.shape[0] >= 16 else None


def _role(name: str) -> str:
    """The role in an obstacle geom's name ``obstacle_<k>_<role>`` (``""`` for other names)."""
    parts = name.split("_", 2)
    return parts[2] if len(parts) == 3 and parts[0] == "obstacle" else ""


def style_render_spec(spec: mujoco.MjSpec, mesh_cell: float = MESH_CELL) -> None:
    """Visual-only changes to a model spec for videos (``build_model(visual=...)``).

    A gradient sky (skybox); the ground geoms (group 0) a sandy checker of
    :data:`GROUND_CELL` m cells with grid lines, so slopes, ditches and pits read by their
    shading and the bending grid, the trail's heightfield cut in chunks drawn at a level of
    detail that falls with the distance from the robot (:func:`_chunk_terrain`,
    :class:`TerrainDetail`); obstacles (group 1) in :data:`OBSTACLE_COLOURS`; the robot's
    materials tinted by :data:`ROBOT_TINT` and its file meshes decimated (:func:`decimate_mesh`);
    one directional sun (named :data:`SUN_NAME`) casting shadows, the other lights without; a
    brighter headlight; :data:`OFFSAMPLES` multisampling. Bodies, joints, lights and cameras
    are left as they are, so the compiled model keeps the physics model's kinematic layout
    (:func:`check_same_layout`); the chunks replace one static geom.
    """
    from legoh_rl.envs.robots import GROUND_GEOM_GROUP, OBSTACLE_GEOM_GROUP, ROBOT_GEOM_GROUPS

    sky = spec.add_texture()
    sky.name, sky.type, sky.builtin = "legoh_sky", mujoco.mjtTexture.mjTEXTURE_SKYBOX, mujoco.mjtBuiltin.mjBUILTIN_GRADIENT
    sky.rgb1, sky.rgb2 = list(SKY_ZENITH), list(SKY_HORIZON)
    sky.width, sky.height = 64, 384
    grid = spec.add_texture()
    grid.name, grid.type, grid.builtin = "legoh_ground_grid", mujoco.mjtTexture.mjTEXTURE_2D, mujoco.mjtBuiltin.mjBUILTIN_CHECKER
    grid.rgb1, grid.rgb2 = list(GROUND_LIGHT), list(GROUND_DARK)
    grid.mark, grid.markrgb = mujoco.mjtMark.mjMARK_EDGE, list(GROUND_LINE)
    grid.width = grid.height = 128
    sky.colorspace = grid.colorspace = mujoco.mjtColorSpace.mjCOLORSPACE_LINEAR  # the colours as given
    ground = spec.add_material()
    ground.name = "legoh_ground"
    ground.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = grid.name
    ground.texuniform = True
    ground.texrepeat = [0.5 / GROUND_CELL, 0.5 / GROUND_CELL]  # one texture (2 x 2 cells) per 2 cells
    ground.specular, ground.shininess, ground.reflectance = 0.05, 0.1, 0.0
    _chunk_terrain(spec, ground.name)
    tint = np.asarray(ROBOT_TINT)
    for mat in spec.materials:
        if mat.name.startswith("legoh_"):
            continue
        mat.rgba = [*(0.5 * np.asarray(mat.rgba[:3]) + 0.5 * tint), mat.rgba[3]]
        mat.specular, mat.shininess = 0.4, 0.4
    for geom in spec.geoms:
        if geom.group == GROUND_GEOM_GROUP:
            geom.material = ground.name
            geom.rgba = [0.5, 0.5, 0.5, 1.0]  # MuJoCo's default: the material's colours, not tinted by the geom's
        elif geom.group == OBSTACLE_GEOM_GROUP:
            geom.material = ""
            geom.rgba = list(OBSTACLE_COLOURS.get(_role(geom.name), OBSTACLE_DEFAULT))
        elif geom.group in ROBOT_GEOM_GROUPS and not geom.material:
            geom.rgba = [*(0.5 * np.asarray(geom.rgba[:3]) + 0.5 * tint), geom.rgba[3]]
    folder = Path(spec.modelfiledir or ".") / (spec.meshdir or "")
    for mesh in spec.meshes:
        if not mesh.file:
            continue
        light = _decimated_file(str(folder / mesh.file), float(mesh_cell))
        if light is not None:
            mesh.file = ""
            mesh.uservert = light[0].astype(np.float32).ravel().tolist()
            mesh.userface = light[1].ravel().tolist()
    sun = None
    for light in spec.lights:
        if sun is None and light.type == mujoco.mjtLightType.mjLIGHT_DIRECTIONAL:
            sun = light
            continue
        light.castshadow = False
    if sun is not None:
        direction = np.asarray(SUN_DIR) / np.linalg.norm(SUN_DIR)
        sun.name, sun.dir, sun.castshadow = SUN_NAME, direction.tolist(), True
        sun.diffuse, sun.ambient, sun.specular = list(SUN_DIFFUSE), [0.0, 0.0, 0.0], [0.2, 0.2, 0.2]
    head = spec.visual.headlight
    head.ambient, head.diffuse, head.specular = [0.26, 0.26, 0.28], [0.22, 0.22, 0.22], [0.05, 0.05, 0.05]
    spec.visual.rgba.haze = [*SKY_HORIZON, 1.0]
    spec.visual.quality.offsamples = OFFSAMPLES
    spec.visual.quality.shadowsize = SHADOW_SIZE


def _chunk_terrain(spec: mujoco.MjSpec, material: str) -> None:
    """Replace the trail's heightfield geom (``"terrain"``, if any) by chunks of
    :data:`TERRAIN_CHUNK` samples at each :data:`TERRAIN_LOD` stride, all hidden
    (:data:`HIDDEN_GROUP`) until :class:`TerrainDetail` shows one level of each chunk.

    Chunks share their edge samples, and MuJoCo draws a heightfield's sides down to its base, so
    neighbours at different levels of detail leave no gap to see the sky through.
    """
    from legoh_rl.envs.trails.mujoco_spec import HFIELD_ASSET, HFIELD_GEOM

    field, geom = spec.hfield(HFIELD_ASSET), spec.geom(HFIELD_GEOM)
    if field is None or geom is None or geom.type != mujoco.mjtGeom.mjGEOM_HFIELD:
        return
    nrow, ncol = int(field.nrow), int(field.ncol)
    data = np.asarray(field.userdata, dtype=np.float64).reshape(nrow, ncol)  # normalised to [0, 1]
    rx, ry, span, base = (float(v) for v in field.size)
    dx, dy = 2.0 * rx / (ncol - 1), 2.0 * ry / (nrow - 1)
    x0, y0, z0 = float(geom.pos[0]) - rx, float(geom.pos[1]) - ry, float(geom.pos[2])
    for level, (stride, _) in enumerate(TERRAIN_LOD):
        for r0 in range(0, nrow - 1, TERRAIN_CHUNK):
            r1 = min(r0 + TERRAIN_CHUNK, nrow - 1)
            for c0 in range(0, ncol - 1, TERRAIN_CHUNK):
                c1 = min(c0 + TERRAIN_CHUNK, ncol - 1)
                step = stride if (r1 - r0) % stride == 0 and (c1 - c0) % stride == 0 else 1
                block = data[r0 : r1 + 1 : step, c0 : c1 + 1 : step]
                lo, hi = float(block.min()), float(block.max())
                flat = (hi - lo) * span < 1e-6
                chunk = spec.add_hfield()
                chunk.name = f"{_CHUNK_PREFIX}{level}_{r0}_{c0}"
                chunk.nrow, chunk.ncol = block.shape
                # MuJoCo rescales each field's samples to [0, 1]: its z range is the block's own
                chunk.size = [(c1 - c0) * dx / 2.0, (r1 - r0) * dy / 2.0, 1e-4 if flat else (hi - lo) * span, base]
                chunk.userdata = (np.zeros_like(block) if flat else (block - lo) / (hi - lo)).ravel().tolist()
                g = spec.worldbody.add_geom()
                g.name, g.type, g.hfieldname = chunk.name, mujoco.mjtGeom.mjGEOM_HFIELD, chunk.name
                g.pos = [x0 + 0.5 * (c0 + c1) * dx, y0 + 0.5 * (r0 + r1) * dy, z0 + lo * span]
                g.contype = g.conaffinity = 0
                g.group, g.material, g.rgba = HIDDEN_GROUP, material, [0.5, 0.5, 0.5, 1.0]
    spec.delete(geom)
    spec.delete(field)


class TerrainDetail:
    """Shows, each frame, one level of detail of every heightfield chunk (:func:`_chunk_terrain`):
    the finest :data:`TERRAIN_LOD` level whose distance covers the chunk's distance from a point
    (the tracked robot). A model without chunks is left alone.

    Args:
        model: the drawing model (its ``geom_group`` is set per frame).
        group: the group of the chunks shown (the ground's).
    """

    def __init__(self, model: mujoco.MjModel, group: int = 0) -> None:
        slots: dict[tuple[int, int], dict[int, int]] = {}  # (row, col) of a chunk -> {level: geom id}
        for i in range(model.ngeom):
            name = model.geom(i).name
            if name.startswith(_CHUNK_PREFIX):
                level, r0, c0 = (int(v) for v in name[len(_CHUNK_PREFIX):].split("_"))
                slots.setdefault((r0, c0), {})[level] = i
        self.model, self.group = model, int(group)
        #: (chunks, levels) geom ids, by level of detail
        self.table = np.array([[by_level[k] for k in sorted(by_level)] for by_level in slots.values()], dtype=np.int64)
        self.ids = self.table.ravel()
        first = self.table[:, 0] if self.table.size else np.zeros(0, dtype=np.int64)
        self.centre = model.geom_pos[first, :2].copy()
        self.half = model.hfield_size[model.geom_dataid[first], :2].copy()
        self.reach = np.array([r for _, r in TERRAIN_LOD][: self.table.shape[1] if self.table.size else 0])

    def __call__(self, xy: np.ndarray) -> None:
        """Show the chunks' levels for a robot at ``xy`` (2,)."""
        if not self.ids.size:
            return
        gap = np.maximum(np.abs(np.asarray(xy, float)[None, :2] - self.centre) - self.half, 0.0)
        dist = np.hypot(gap[:, 0], gap[:, 1])
        level = np.minimum(np.searchsorted(self.reach, dist), self.table.shape[1] - 1)
        self.model.geom_group[self.ids] = HIDDEN_GROUP
        self.model.geom_group[self.table[np.arange(len(level)), level]] = self.group


_KINEMATIC_SIZES = ("nq", "nv", "nu", "nbody", "njnt", "nmocap", "ncam", "nlight")


def check_same_layout(physics: mujoco.MjModel, model: mujoco.MjModel) -> None:
    """Raise ValueError unless ``model`` has ``physics``' kinematic layout (its joints, bodies,
    cameras and lights: what copying a state from one to the other needs; geoms may differ)."""
    diff = {k: (int(getattr(physics, k)), int(getattr(model, k))) for k in _KINEMATIC_SIZES
            if int(getattr(physics, k)) != int(getattr(model, k))}
    if not diff:
        for field in ("body_parentid", "body_jntnum", "jnt_type", "jnt_qposadr"):
            if not np.array_equal(getattr(physics, field), getattr(model, field)):
                diff[field] = "differs"
    if diff:
        raise ValueError(f"the rendering model's layout differs from the physics model's (physics, rendering): {diff}")


def build_render_model(robot, terrain, timestep: float, physics: mujoco.MjModel | None = None,
                       mesh_cell: float = MESH_CELL) -> mujoco.MjModel:
    """The physics model built again with :func:`style_render_spec`'s visual-only changes.

    Args:
        robot: the robot (a :class:`~legoh_rl.envs.robots.RobotSpec` or its name).
        terrain: the trail source the physics model was built on (``add_to_spec``), or None.
        timestep: the physics timestep, s (the model is never stepped).
        physics: the physics model; its layout is checked against the result's.
        mesh_cell: the robot's mesh decimation cell, m (:func:`decimate_mesh`).

    Returns:
        the rendering model, its shadow box set to +- :data:`SHADOW_HALF_WIDTH` m.
    """
    from legoh_rl.envs.robots import build_model

    model = build_model(robot, terrain=terrain, timestep=timestep,
                        visual=functools.partial(style_render_spec, mesh_cell=mesh_cell)).model
    if physics is not None:
        check_same_layout(physics, model)
    model.vis.map.shadowclip = SHADOW_HALF_WIDTH / max(float(model.stat.extent), 1e-6)
    return model


def _sun_light(model: mujoco.MjModel) -> tuple[int, float] | None:
    """(light id, distance) of the rendering model's sun, which follows the tracked body; None
    for a model without one (the physics model)."""
    lid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_LIGHT, SUN_NAME)
    return None if lid < 0 else (int(lid), SUN_DISTANCE)


class SeeThrough:
    """Draws the obstacles that stand between the camera and the tracked body translucent.

    A tree or a wall in front of the camera would hide the robot; each frame, the static
    obstacle geoms (``group``, children of the world body) whose bounding box (MuJoCo's
    ``geom_aabb`` in the geom's frame, grown by ``margin``) the line of sight from the camera to
    the body crosses get alpha ``alpha``. The last ``keep`` metres of the line are not tested,
    so the obstacle the robot is stepping over stays solid.

    Args:
        model: the drawing model.
        group: the obstacles' geom group.
        alpha: their opacity when in the way.
        margin: growth of their boxes, m.
        keep: metres before the body where nothing is faded.
    """

    def __init__(self, model: mujoco.MjModel, group: int = 1, alpha: float = 0.25, margin: float = 0.05,
                 keep: float = 0.6) -> None:
        self.ids = np.flatnonzero((model.geom_group == group) & (model.geom_bodyid == 0))
        self.alpha, self.keep = float(alpha), float(keep)
        rot = np.empty((self.ids.size, 9))
        for i, g in enumerate(self.ids):
            mujoco.mju_quat2Mat(rot[i], model.geom_quat[g])
        self.rot = rot.reshape(-1, 3, 3)
        aabb = model.geom_aabb[self.ids].reshape(-1, 6)
        self.centre = model.geom_pos[self.ids] + np.einsum("kij,kj->ki", self.rot, aabb[:, :3])
        self.half = aabb[:, 3:] + margin
        self._faded = np.zeros(model.ngeom, dtype=bool)

    def blocking(self, eye: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Ids of the obstacle geoms the segment ``eye`` -> ``target`` crosses (but for its last
        ``keep`` metres)."""
        if not self.ids.size:
            return self.ids
        d = np.asarray(target, float) - np.asarray(eye, float)
        length = float(np.linalg.norm(d))
        if length < 1e-9:
            return self.ids[:0]
        p = np.einsum("kji,kj->ki", self.rot, np.asarray(eye, float) - self.centre)  # eye in each box's frame
        v = np.einsum("kji,j->ki", self.rot, d)
        v = np.where(np.abs(v) < 1e-12, 1e-12, v)  # parallel to a slab: +-huge, the sign decides
        t1, t2 = (-self.half - p) / v, (self.half - p) / v
        near, far = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
        hit = (far >= near) & (far >= 0.0) & (near <= 1.0 - self.keep / length)
        return self.ids[hit]

    def __call__(self, scene: mujoco.MjvScene, target: np.ndarray) -> None:
        """Fade the obstacles of ``scene`` (after ``mjv_updateScene``) that hide ``target``."""
        if not self.ids.size:
            return
        eye = 0.5 * (np.asarray(scene.camera[0].pos) + np.asarray(scene.camera[1].pos))
        blocking = self.blocking(eye, target)
        if not blocking.size:
            return
        self._faded[:] = False
        self._faded[blocking] = True
        for i in range(scene.ngeom):
            geom = scene.geoms[i]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and self._faded[geom.objid]:
                geom.rgba[3] = min(float(geom.rgba[3]), self.alpha)


# ---------------------------------------------------------------------------------- markers
#: marker colours (RGBA): P_A, P_B, the waypoint, expert goals ahead, the goal being walked
#: to, goals already reached, the route line
MARKER_START = (0.15, 0.80, 0.25, 1.0)
MARKER_END = (0.95, 0.10, 0.10, 1.0)
MARKER_WAYPOINT = (0.95, 0.20, 0.85, 1.0)
MARKER_GOAL = (0.0, 0.80, 1.0, 1.0)
MARKER_CURRENT = (1.0, 0.85, 0.0, 1.0)
MARKER_REACHED = (0.55, 0.60, 0.62, 0.8)
MARKER_ROUTE = (0.05, 0.35, 0.95, 1.0)
_EYE = np.eye(3).ravel()


def _add_geom(scene: mujoco.MjvScene, kind, size, pos, rgba, mat=_EYE, emission: float = 0.4) -> bool:
    if scene.ngeom >= scene.maxgeom:
        return False
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, kind, np.asarray(size, float), np.asarray(pos, float), np.asarray(mat, float),
                        np.asarray(rgba, np.float32))
    geom.category = mujoco.mjtCatBit.mjCAT_DECOR
    geom.emission = emission
    scene.ngeom += 1
    return True


def add_route_markers(scene: mujoco.MjvScene, start: np.ndarray, goals: np.ndarray, current: int = 0,
                      waypoint: np.ndarray | None = None, lift: float = 0.05) -> int:
    """Draw a trail into ``scene``: the route as a line, P_A (a green disc), the expert goals
    (cyan balls; the one being walked to larger and yellow, those reached grey), the waypoint (a
    magenta diamond) and P_B (a red ball on a pole).

    Args:
        scene: the scene after ``mjv_updateScene`` (its user geoms are appended).
        start: (3,) P_A.
        goals: (G, 3) the expert goals then P_B (the last row), ground heights in z.
        current: index into ``goals`` of the goal being walked to.
        waypoint: (3,) or None.
        lift: markers' height above the given points, m.

    Returns:
        the geoms added (fewer when the scene is full).
    """
    before = scene.ngeom
    goals = np.asarray(goals, dtype=np.float64).reshape(-1, 3)
    start = np.asarray(start, dtype=np.float64).reshape(3)
    up = np.array([0.0, 0.0, lift])
    route = np.vstack([start[None], goals]) + up
    for a, b in zip(route[:-1], route[1:], strict=True):
        if scene.ngeom >= scene.maxgeom:
            break
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), _EYE,
                            np.asarray(MARKER_ROUTE, np.float32))
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, 0.015, a, b)
        geom.category, geom.emission = mujoco.mjtCatBit.mjCAT_DECOR, 0.5
        scene.ngeom += 1
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, (0.25, 0.0, 0.01), start + up, MARKER_START)
    for k, goal in enumerate(goals[:-1]):
        if k < current:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, (0.05, 0, 0), goal + up, MARKER_REACHED, emission=0.1)
        elif k == current:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, (0.11, 0, 0), goal + 2 * up, MARKER_CURRENT)
        else:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, (0.07, 0, 0), goal + up, MARKER_GOAL)
    if waypoint is not None:
        diamond = np.array([[0.7071, -0.7071, 0.0], [0.7071, 0.7071, 0.0], [0.0, 0.0, 1.0]])  # 45 deg about z
        tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.7071, -0.7071], [0.0, 0.7071, 0.7071]])
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, (0.07, 0.07, 0.07), np.asarray(waypoint, float) + 4 * up,
                  MARKER_WAYPOINT, mat=(diamond @ tilt).ravel())
    end = goals[-1]
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, (0.02, 0.0, 0.5), end + np.array([0.0, 0.0, 0.5]), MARKER_END,
              emission=0.2)
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, (0.13, 0, 0), end + np.array([0.0, 0.0, 1.05]),
              MARKER_END if current < len(goals) - 1 else MARKER_CURRENT)
    return scene.ngeom - before


# ---------------------------------------------------------------------------------- insets
def inset_image(frame: np.ndarray, image: np.ndarray, fraction: float = 0.34, cmap: str = "inferno_r",
                margin: int = 3) -> np.ndarray:
    """``frame`` with ``image`` (values in [0, 1], e.g. a normalised depth image) in its top-right
    corner, coloured by a matplotlib ``cmap`` (default: near (0) bright yellow, far (1) black), in a
    white frame.

    Args:
        frame: (H, W, 3) uint8; written in place and returned.
        image: (h, w) (or (1, h, w)) floats in [0, 1] (NaN as 1).
        fraction: the inset's height as a share of the frame's height.
        margin: pixels between the inset and the frame's edges.
        cmap: a matplotlib colormap name.

    Returns:
        ``frame``.
    """
    img = np.nan_to_num(np.asarray(image, dtype=np.float32).squeeze(), nan=1.0)
    if img.ndim != 2:
        raise ValueError(f"inset image must be (h, w) or (1, h, w), got shape {np.shape(image)}")
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"frame must be (H, W, 3) uint8, got {frame.dtype} {frame.shape}")
    H, W = frame.shape[:2]
    h = max(4, int(round(fraction * H)))
    w = max(4, int(round(h * img.shape[1] / img.shape[0])))
    if h + 2 * margin + 2 > H or w + 2 * margin + 2 > W:
        return frame  # too small a frame for an inset
    rows = np.minimum((np.arange(h) * img.shape[0]) // h, img.shape[0] - 1)
    cols = np.minimum((np.arange(w) * img.shape[1]) // w, img.shape[1] - 1)
    values = np.clip(img[rows][:, cols], 0.0, 1.0)
    rgb = (_colormap(cmap)[np.round(values * 255).astype(np.int64)] * 255).astype(np.uint8)
    top, left = margin, W - margin - w - 2
    frame[top : top + h + 2, left : left + w + 2] = 255
    frame[top + 1 : top + 1 + h, left + 1 : left + 1 + w] = rgb
    return frame


@functools.lru_cache(maxsize=8)
def _colormap(name: str) -> np.ndarray:
    """(256, 3) RGB in [0, 1] of matplotlib colormap ``name``."""
    from matplotlib import colormaps

    return np.asarray(colormaps[name](np.linspace(0.0, 1.0, 256)))[:, :3]


def _size(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"render {name} must be a positive integer number of pixels, got {value!r}")
    return int(value)


def tile_frames(frames: np.ndarray, cols: int = 2) -> np.ndarray:
    """Frames laid out in a grid, row-major, empty cells black.

    Args:
        frames: (n, H, W, 3) uint8, n >= 1.
        cols: columns of the grid (>= 1).

    Returns:
        (rows * H, min(cols, n) * W, 3) uint8 with ``rows = ceil(n / cols)``.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[0] < 1:
        raise ValueError(f"frames must be (n >= 1, H, W, C), got shape {frames.shape}")
    if cols < 1:
        raise ValueError(f"cols must be >= 1, got {cols}")
    n, h, w, c = frames.shape
    cols = min(cols, n)
    rows = -(-n // cols)
    grid = np.zeros((rows * h, cols * w, c), dtype=frames.dtype)
    for i in range(n):
        r, k = divmod(i, cols)
        grid[r * h : (r + 1) * h, k * w : (k + 1) * w] = frames[i]
    return grid
