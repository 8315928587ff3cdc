"""Bilinear lookups on a regular height grid, in torch (float32) for the depth camera's ray march.

The march evaluates the terrain at millions of points per frame. :class:`HeightMap` lets it work
in the grid's own normalised coordinates: ray origins and directions are mapped once per ray
(:meth:`HeightMap.to_grid`, :meth:`HeightMap.dirs_to_grid`, an affine map), so every sample
along the ray is a single multiply-add followed by ``torch.grid_sample``, with no per-sample
coordinate transform.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np
import torch

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.native.build import load_library

__all__ = ["HeightMap", "WorldSampler", "as_grid_sampler", "coarse_max_map", "torch_height_fn", "yaw_frame_points"]

#: samples per side of a block of :attr:`HeightMap.coarse_max` (the C kernel's COARSE_SHIFT = 3)
COARSE_BLOCK = 8


class HeightMap:
    """Heights ``h[i, j]`` at ``(x0 + i * res, y0 + j * res)``, bilinear between, border clamped.

    Args:
        heights: (nx, ny) heights, m (x along rows, y along columns).
        origin: world ``(x0, y0)`` of ``heights[0, 0]``, m.
        resolution: cell size, m.

    Calling the map with world points ``(M, 2)`` (a float32 tensor) returns ``(M,)`` heights;
    :meth:`numpy` does the same on numpy arrays.
    """

    torch_native = True  # see legoh_rl.envs.sensors.torch_height_fn

    def __init__(self, heights: np.ndarray, origin: tuple[float, float], resolution: float) -> None:
        heights = np.asarray(heights)
        if heights.ndim != 2 or min(heights.shape) < 2:
            raise ValueError(f"heights must be a (nx, ny) grid with nx, ny >= 2, got shape {heights.shape}")
        if not resolution > 0:
            raise ValueError(f"resolution must be positive, got {resolution!r}")
        nx, ny = heights.shape
        #: (nx, ny) float32, C-contiguous (read by the native kernels; shares memory with ``image``)
        self.heights = np.array(heights, dtype=np.float32, order="C")
        self.image = torch.from_numpy(self.heights)[None, None]
        self.x0, self.y0 = float(origin[0]), float(origin[1])
        self.resolution = float(resolution)
        self._coarse: np.ndarray | None = None
        self.sx = 2.0 / ((nx - 1) * resolution)
        self.sy = 2.0 / ((ny - 1) * resolution)

    def to(self, device: torch.device | str) -> HeightMap:
        """This map with its ``image`` on ``device`` (a shallow copy; itself when already there),
        for lookups by tensors there; ``heights`` and the native kernels stay on the host."""
        if self.image.device == torch.device(device):
            return self
        other = copy.copy(self)
        other.image = self.image.to(device)
        return other

    def to_grid(self, xy: torch.Tensor) -> torch.Tensor:
        """World points (..., 2) -> ``grid_sample`` coordinates (..., 2) (column, row in [-1, 1])."""
        return torch.stack([(xy[..., 1] - self.y0) * self.sy - 1.0, (xy[..., 0] - self.x0) * self.sx - 1.0], dim=-1)

    def dirs_to_grid(self, dxy: torch.Tensor) -> torch.Tensor:
        """World xy displacements (..., 2) -> displacements in grid coordinates (..., 2)."""
        return torch.stack([dxy[..., 1] * self.sy, dxy[..., 0] * self.sx], dim=-1)

    def sample_grid(self, g: torch.Tensor) -> torch.Tensor:
        """Heights at grid coordinates (..., 2) -> (...)."""
        out = torch.nn.functional.grid_sample(self.image, g.reshape(1, 1, -1, 2), mode="bilinear",
                                              padding_mode="border", align_corners=True)
        return out.reshape(g.shape[:-1])

    def __call__(self, xy: torch.Tensor) -> torch.Tensor:
        return self.sample_grid(self.to_grid(xy))

    def numpy(self, xy: np.ndarray) -> np.ndarray:
        """Heights at world points given as numpy, (M, 2) -> (M,) float64.

        Uses the native bilinear kernel (:mod:`legoh_rl.envs.native`) when it is available (the
        same values: points rounded to float32 as ``grid_sample`` sees them, without torch's
        per-call overhead), else ``grid_sample``.
        """
        lib = load_library()
        if lib is None:
            p = torch.from_numpy(np.asarray(xy, dtype=np.float32).reshape(-1, 2))
            return self(p).numpy().astype(np.float64)
        p = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.empty(p.shape[0])
        lib.lh_heights(self.heights.ctypes.data, *self.grid_args, p.ctypes.data, p.shape[0], out.ctypes.data)
        return out

    def numpy_around(self, xy: np.ndarray, yaw: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Heights at points given in each robot's yaw frame: robots at world ``xy`` (N, 2) with
        headings ``yaw`` (N,), points ``offsets`` (K, 2) (forward, left) -> (N, K) float64.

        The same as :meth:`numpy` at ``xy + R(yaw) offsets``, in one native call when available.
        """
        xy = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2)
        yaw = np.ascontiguousarray(yaw, dtype=np.float64).reshape(-1)
        offsets = np.ascontiguousarray(offsets, dtype=np.float64).reshape(-1, 2)
        if yaw.shape[0] != xy.shape[0]:
            raise ValueError(f"need one yaw per robot: xy has {xy.shape[0]} rows, yaw {yaw.shape[0]}")
        n, k = xy.shape[0], offsets.shape[0]
        lib = load_library()
        if lib is None:
            return self.numpy(yaw_frame_points(xy, yaw, offsets).reshape(-1, 2)).reshape(n, k)
        out = np.empty((n, k))
        lib.lh_heights_around(self.heights.ctypes.data, *self.grid_args, xy.ctypes.data, yaw.ctypes.data,
                              offsets.ctypes.data, n, k, out.ctypes.data)
        return out

    @property
    def coarse_max(self) -> np.ndarray:
        """The coarse max map the native ray march skips open space with, (cnx, cny) float32.

        Block ``(I, J)`` holds the highest of the samples ``heights[8I : 8I + 9, 8J : 8J + 9]``
        (clipped to the grid), so it bounds every bilinear height whose cell's lower corner
        ``(floor ix, floor iy)`` lies in the block. Computed on first use and kept.
        """
        if self._coarse is None:
            self._coarse = coarse_max_map(self.heights, COARSE_BLOCK)
        return self._coarse

    @property
    def grid_args(self) -> tuple:
        """(nx, ny, x0, y0, 1 / resolution): the native kernels' description of the grid."""
        return (*self.heights.shape, self.x0, self.y0, 1.0 / self.resolution)


def yaw_frame_points(xy, yaw, offsets):
    """World xy of points ``offsets`` (K, 2) (forward, left) in the yaw frames of robots at ``xy``
    (N, 2) with headings ``yaw`` (N,): (N, K, 2) (numpy arrays, or torch tensors on one device)."""
    xp = namespace_of(xy)
    c, s = xp.cos(yaw)[:, None], xp.sin(yaw)[:, None]
    px = xy[:, :1] + c * offsets[:, 0] - s * offsets[:, 1]
    py = xy[:, 1:2] + s * offsets[:, 0] + c * offsets[:, 1]
    return xp.stack([px, py], axis=-1)


def coarse_max_map(heights: np.ndarray, block: int) -> np.ndarray:
    """Block maxima of a (nx, ny) height grid for the bilinear cells: (cnx, cny) with
    ``cnx = (nx - 2) // block + 1`` (likewise cny), block ``(I, J)`` the maximum of
    ``heights[I b : I b + b + 1, J b : J b + b + 1]`` (rows and columns past the grid repeat its
    edge), float32."""
    h = np.asarray(heights, dtype=np.float32)
    nx, ny = h.shape
    cnx, cny = (nx - 2) // block + 1, (ny - 2) // block + 1
    hp = np.pad(h, ((0, cnx * block + 1 - nx), (0, cny * block + 1 - ny)), mode="edge")
    rows = np.maximum(hp[:-1].reshape(cnx, block, -1).max(axis=1), hp[block::block])  # (cnx, W)
    return np.ascontiguousarray(np.maximum(rows[:, :-1].reshape(cnx, cny, block).max(axis=2), rows[:, block::block]))


class WorldSampler:
    """The :class:`HeightMap` sampling interface over any height function of world xy points
    (identity coordinates): lets the ray march take a plain ``(M, 2) -> (M,)`` function."""

    def __init__(self, fn: Callable) -> None:
        self._fn = torch_height_fn(fn)

    def to_grid(self, xy: torch.Tensor) -> torch.Tensor:
        return xy

    def dirs_to_grid(self, dxy: torch.Tensor) -> torch.Tensor:
        return dxy

    def sample_grid(self, g: torch.Tensor) -> torch.Tensor:
        return self._fn(g.reshape(-1, 2)).reshape(g.shape[:-1])


def torch_height_fn(fn: Callable) -> Callable:
    """A height function on torch tensors: ``fn`` itself if it is marked ``torch_native``,
    else a wrapper converting to and from numpy."""
    if getattr(fn, "torch_native", False):
        return fn

    def wrapped(xy: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(fn(xy.double().numpy()), dtype=torch.float32)

    return wrapped


def as_grid_sampler(fn: Callable) -> HeightMap | WorldSampler:
    """``fn`` itself if it is a :class:`HeightMap`, else a :class:`WorldSampler` around it."""
    return fn if isinstance(fn, HeightMap) else WorldSampler(fn)
