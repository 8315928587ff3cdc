"""Python entry points of the native height-map ray march: rays given per world
(:func:`march_ground_native`) and the head camera's pixel rays in one call (:func:`camera_native`).

They take and return numpy arrays and match the torch reference
(:func:`legoh_rl.envs.sensors.march_ground`) to float32 rounding. Needs
:func:`~legoh_rl.envs.native.build.load_library` to succeed. (The native bilinear lookup is
:meth:`legoh_rl.envs.height_map.HeightMap.numpy`.)
"""

from __future__ import annotations

import ctypes
from typing import TYPE_CHECKING

import numpy as np

from legoh_rl.envs.native.build import load_library, unavailable_reason

__all__ = ["march_ground_native", "camera_native", "same_grid"]

if TYPE_CHECKING:  # height_map imports this package
    from legoh_rl.envs.height_map import HeightMap
    from legoh_rl.envs.obstacle_rays import ObstacleRayCaster

_F32 = ctypes.POINTER(ctypes.c_float)


def _lib() -> ctypes.CDLL:
    lib = load_library()
    if lib is None:
        raise RuntimeError(f"the native height-march kernel is unavailable: {unavailable_reason()}")
    return lib


def _f32(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``a`` as a C-contiguous float32 array of ``shape`` (broadcast), or a ValueError naming it."""
    a = np.asarray(a, dtype=np.float32)
    try:
        return np.ascontiguousarray(np.broadcast_to(a, shape))
    except ValueError:
        raise ValueError(f"{name} must have shape {shape} (or broadcast to it), got {a.shape}") from None


def _check_march(samples: int, refine: int) -> None:
    if not 1 <= samples <= 1024 or refine < 0:
        raise ValueError(f"need 1 <= samples <= 1024 and refine >= 0, got samples={samples}, refine={refine}")


def _world_bounds(z_max, z_min, n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The optional (n,) terrain bounds as float32 arrays (None stays None)."""
    return tuple(None if z is None else _f32(np.asarray(z).reshape(-1), (n,), name)
                 for z, name in ((z_max, "z_max"), (z_min, "z_min")))


def _coarse_args(hm: HeightMap, coarse: bool) -> tuple:
    """(pointer, columns) of the map's coarse max map for the kernel, or (None, 0) without."""
    return (_ptr(hm.coarse_max), hm.coarse_max.shape[1]) if coarse else (None, 0)


def _ptr(a: np.ndarray | None):
    return None if a is None else a.ctypes.data_as(_F32)


def march_ground_native(
    hm: HeightMap,
    origin: np.ndarray,
    dirs: np.ndarray,
    t_max: np.ndarray,
    samples: int = 16,
    refine: int = 3,
    z_max: np.ndarray | None = None,
    z_min: np.ndarray | None = None,
    t_min: np.ndarray | None = None,
    threads: int = 1,
    coarse: bool = True,
) -> np.ndarray:
    """First hit of rays with a height map; the arguments and result of
    :func:`legoh_rl.envs.sensors.march_ground` (origin (n, 3), dirs (n, R, 3), t_max, t_min (n, R),
    z_max, z_min (n,) -> (n, R) float64, ``inf`` for no hit), computed in C on ``threads`` threads.
    Each ray stops at its first sample below the ground. With ``coarse`` the samples that the
    map's :attr:`~legoh_rl.envs.height_map.HeightMap.coarse_max` puts surely above the terrain
    skip the lookup: the same result, bit for bit, faster over open space.

    Raises:
        ValueError: a shape does not match ``dirs`` (named in the message).
        RuntimeError: the kernel could not be built (the reason is in the message).
    """
    dirs = np.asarray(dirs)
    if dirs.ndim != 3 or dirs.shape[2] != 3:
        raise ValueError(f"dirs must be (n, R, 3), got shape {dirs.shape}")
    n, r = dirs.shape[:2]
    origin = np.asarray(origin)
    if origin.shape != (n, 3):
        raise ValueError(f"origin must be ({n}, 3) to match dirs {dirs.shape}, got {origin.shape}")
    _check_march(samples, refine)
    lib = _lib()
    o = _f32(origin, (n, 3), "origin")
    d = _f32(dirs, (n, r, 3), "dirs")
    tm = _f32(t_max, (n, r), "t_max")
    zx, zn = _world_bounds(z_max, z_min, n)
    tn = None if t_min is None else _f32(t_min, (n, r), "t_min")
    out = np.empty((n, r), dtype=np.float64)
    if n * r:
        lib.lh_march(_ptr(hm.heights), *hm.grid_args, *_coarse_args(hm, coarse), _ptr(o), _ptr(d), _ptr(tm), _ptr(zx),
                     _ptr(zn), _ptr(tn), n, r,
                     int(samples), int(refine), out.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
                     int(threads))
    return out


def same_grid(a: HeightMap, b: HeightMap) -> bool:
    """Whether two height maps share one grid (shape, origin, resolution)."""
    return (a.heights.shape == b.heights.shape and a.x0 == b.x0 and a.y0 == b.y0
            and a.resolution == b.resolution)


def camera_native(
    surface: HeightMap,
    ground: HeightMap,
    cam_pos: np.ndarray,
    cam_mat: np.ndarray,
    dirs_cam: np.ndarray,
    t_max: np.ndarray,
    samples: int = 12,
    refine: int = 3,
    z_max: np.ndarray | None = None,
    z_min: np.ndarray | None = None,
    obstacle_margin: float = 0.02,
    threads: int = 1,
    coarse: bool = True,
    caster: ObstacleRayCaster | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The depth camera's surface march in one native call: each world's pixel rays are rotated
    into the world, marched against ``surface`` (as :func:`march_ground_native`), and the hit is
    compared with ``ground`` underneath.

    Args:
        surface, ground: height maps on one grid (surface = ground with obstacle tops).
        cam_pos: (n, 3) camera positions; cam_mat: (n, 3, 3) rotations (columns = camera axes in
            the world).
        dirs_cam: (R, 3) unit pixel rays in the camera frame; t_max: (R,) longest distance per ray.
        samples, refine, z_max, z_min: as :func:`legoh_rl.envs.sensors.march_ground`.
        obstacle_margin: a hit higher than this above the bare ground is flagged, m.
        threads: threads to march on.
        coarse: skip lookups with the maps' coarse max maps (same result), as
            :func:`march_ground_native`.
        caster: the obstacle geoms (:class:`~legoh_rl.envs.obstacle_rays.ObstacleRayCaster`): the
            flagged rays are then resolved in the same call, each to the nearer of the geoms and
            the bare ground marched on from the surface hit (what ``caster.cast`` and
            :func:`march_ground_native` with ``t_min`` give). Without one, ``dist`` of a flagged
            ray is its surface hit.

    Returns:
        dist (n, R) float64 distance to the hit (``inf`` for none) and on_obstacle (n, R) bool
        (the surface hit lies on an obstacle).

    Raises:
        ValueError: the maps are on different grids, or a shape is wrong (named).
    """
    if not same_grid(surface, ground):
        raise ValueError("surface and ground height maps must share one grid (shape, origin, resolution)")
    dirs_cam = np.asarray(dirs_cam)
    if dirs_cam.ndim != 2 or dirs_cam.shape[1] != 3:
        raise ValueError(f"dirs_cam must be (R, 3), got shape {dirs_cam.shape}")
    cam_pos = np.asarray(cam_pos)
    if cam_pos.ndim != 2 or cam_pos.shape[1] != 3:
        raise ValueError(f"cam_pos must be (n, 3), got shape {cam_pos.shape}")
    n, r = cam_pos.shape[0], dirs_cam.shape[0]
    _check_march(samples, refine)
    lib = _lib()
    pos = _f32(cam_pos, (n, 3), "cam_pos")
    mat = _f32(cam_mat, (n, 3, 3), "cam_mat")
    dc = _f32(dirs_cam, (r, 3), "dirs_cam")
    tm = _f32(t_max, (r,), "t_max")
    zx, zn = _world_bounds(z_max, z_min, n)
    dist = np.empty((n, r), dtype=np.float64)
    flag = np.empty((n, r), dtype=np.uint8)
    if n * r:
        (surface_cmax, cny), (ground_cmax, _) = _coarse_args(surface, coarse), _coarse_args(ground, coarse)
        lib.lh_camera(_ptr(surface.heights), _ptr(ground.heights), *surface.grid_args, surface_cmax, ground_cmax, cny, _ptr(pos),
                      _ptr(mat), _ptr(dc), _ptr(tm), _ptr(zx), _ptr(zn), n, r, int(samples), int(refine),
                      float(obstacle_margin), dist.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
                      flag.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)),
                      *(caster.native_geometry() if caster is not None else (0,) + (None,) * 8), int(threads))
    return dist, flag.view(bool)
