"""Off-screen RGB frames of chosen worlds of a batched env (MuJoCo's ``mujoco.Renderer``).

:class:`WorldRenderer` draws worlds of a :class:`~legoh_rl.envs.physics.BatchedWorlds` one after
the other with one OpenGL context: each world's state is copied out of the batch into a scratch
``MjData`` (the batch is persistent, so its positions are those of the last step or reset and no
extra physics call is needed), then drawn from a camera. By default the camera is a
:class:`TrackingCamera` that follows the world's torso; a camera of the model (by name or id) or
any ``mujoco.MjvCamera`` also works. :meth:`HikingEnv.render <legoh_rl.envs.hiking.HikingEnv.render>`
is the public entry point.

Rendering needs an OpenGL backend. Without a display, set ``MUJOCO_GL=egl`` (or ``osmesa``)
*before* ``mujoco`` is first imported, and install the libraries (Debian/Ubuntu:
``apt-get install libegl1 libgl1-mesa-dri`` for EGL, ``libosmesa6`` for OSMesa; ``make gl`` does
the former). When no context can be made, :class:`RenderingUnavailableError` says so.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = [
    "DEFAULT_HEIGHT",
    "DEFAULT_WIDTH",
    "RenderingUnavailableError",
    "TrackingCamera",
    "WorldRenderer",
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

    The model's off-screen framebuffer (``vis.global_.offwidth``/``offheight``, a drawing-only
    setting) is enlarged when a frame is bigger than it.

    Raises:
        RenderingUnavailableError: no OpenGL context (names MUJOCO_GL and what to install).
    """

    def __init__(self, worlds, track_body: int, height: int = DEFAULT_HEIGHT, width: int = DEFAULT_WIDTH) -> None:
        height, width = _size(height, "height"), _size(width, "width")
        model = worlds.model
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

    def render(self, ids: np.ndarray, camera=None, out: np.ndarray | None = None) -> np.ndarray:
        """Frames of worlds ``ids``.

        Args:
            ids: (n,) int world indices (validated by the caller).
            camera: see :meth:`camera`.
            out: optional (n, height, width, 3) uint8 array to write into.

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
            self.worlds.world_data(int(w), self._data)
            self._renderer.update_scene(self._data, camera=cam)
            self._renderer.render(out=out[i])
        return out

    def close(self) -> None:
        """Free the GL context (idempotent)."""
        renderer, self._renderer = self._renderer, None
        if renderer is not None:
            renderer.close()


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
