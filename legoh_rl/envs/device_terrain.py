"""The terrain lookups of a step: on the host (numpy) or on the simulation's device (torch).

A step reads the terrain under the base and feet, the scandots, and the edge and pit samples
under the feet. :class:`HostTerrain` answers from the trail source's own numpy lookups (the host
step); :class:`DeviceTerrain`, with the same methods, without leaving the device (a
device-resident step, ``HikingEnvConfig.resident``). It holds the trail grid's surface height map
and its edge and pit masks there, with the host lookups' conventions: bilinear surface heights, border clamped (:class:`~legoh_rl.envs.height_map.HeightMap`,
``grid_sample`` in float32), and for the masks the nearest sample, points clamped to the grid
(``TerrainMap.index_of``: round half to even, as ``np.rint`` and ``torch.round`` both do).
"""

from __future__ import annotations

import numpy as np
import torch

from legoh_rl.envs.height_map import HeightMap, yaw_frame_points
from legoh_rl.envs.sensors import scandots

__all__ = ["DeviceTerrain", "HostTerrain", "MaskGrid"]


class HostTerrain:
    """A trail source's numpy lookups, with :class:`DeviceTerrain`'s methods.

    Args:
        trails: the trail source (``height_at``, ``edge_at``; ``pit_at`` for :meth:`pit`; the
            faster ``height_around`` for :meth:`scandots` when it has one).
    """

    def __init__(self, trails) -> None:
        self.trails = trails

    def heights(self, xy: np.ndarray) -> np.ndarray:
        """Surface heights at world points (M, 2) -> (M,)."""
        return self.trails.height_at(xy)

    def edge(self, xy: np.ndarray) -> np.ndarray:
        """Edge samples at world points (M, 2) -> (M,) bool."""
        return self.trails.edge_at(xy).astype(bool)

    def pit(self, xy: np.ndarray) -> np.ndarray:
        """Pit samples at world points (M, 2) -> (M,) bool."""
        return self.trails.pit_at(xy)

    def scandots(self, pos: np.ndarray, yaw: np.ndarray, offsets: np.ndarray, base_height_target: float) -> np.ndarray:
        """(N, K) heights at ``offsets`` (K, 2) around bases at ``pos`` (N, 3) with headings ``yaw``
        (N,), relative to the nominal ground, clipped to [-1, 1] (:func:`~legoh_rl.envs.sensors.scandots`)."""
        return scandots(pos, yaw, offsets, self.trails.height_at, base_height_target,
                        getattr(self.trails, "height_around", None))


class MaskGrid:
    """A boolean sample grid looked up at its nearest sample, on a device.

    Args:
        mask: (nx, ny) bool samples, ``mask[i, j]`` at world ``(x0 + i res, y0 + j res)``.
        origin: world ``(x0, y0)``, m.
        resolution: sample spacing, m.
        device: where the mask and lookups live.
    """

    def __init__(self, mask: np.ndarray, origin: tuple[float, float], resolution: float,
                 device: torch.device | str) -> None:
        mask = np.asarray(mask, dtype=bool)
        if mask.ndim != 2:
            raise ValueError(f"a mask grid must be (nx, ny), got shape {mask.shape}")
        self.mask = torch.as_tensor(mask, device=device)
        self.x0, self.y0 = float(origin[0]), float(origin[1])
        self.resolution = float(resolution)

    def __call__(self, xy: torch.Tensor) -> torch.Tensor:
        """(..., 2) world points -> (...,) bool, the nearest sample of each."""
        nx, ny = self.mask.shape
        i = torch.round(((xy[..., 0] - self.x0) / self.resolution).clamp(0.0, nx - 1.0)).long()
        j = torch.round(((xy[..., 1] - self.y0) / self.resolution).clamp(0.0, ny - 1.0)).long()
        return self.mask[i, j]


class DeviceTerrain:
    """The trails' surface heights, edge and pit samples on ``device``.

    Args:
        trails: a trail source with ``height_at_t`` (a :class:`HeightMap`) and ``edge_grid``
            (as :class:`~legoh_rl.envs.trail_source.GridTrails`); ``pit_grid`` when ``pits``.
        device: the simulation's torch device.
        pits: also hold the pit mask (the ``feet_in_pit`` reward term reads it).

    Raises:
        ValueError: the trail source lacks one of those grids (names it and the type).
    """

    def __init__(self, trails, device: torch.device | str, pits: bool = False) -> None:
        need = ["height_at_t", "edge_grid"] + (["pit_grid"] if pits else [])
        missing = [n for n in need if getattr(trails, n, None) is None]
        if missing or not isinstance(trails.height_at_t, HeightMap):
            raise ValueError(f"a device-resident step reads the terrain's grids {need} on the device; "
                             f"{type(trails).__name__} lacks {missing or ['height_at_t as a HeightMap']}")
        self.surface = trails.height_at_t.to(device)
        self.edge = MaskGrid(*trails.edge_grid, device=device)
        self.pit = MaskGrid(*trails.pit_grid, device=device) if pits else None

    def heights(self, xy: torch.Tensor) -> torch.Tensor:
        """Surface heights at world points (..., 2) -> (...,) float32."""
        return self.surface(xy.to(torch.float32))

    def scandots(self, pos: torch.Tensor, yaw: torch.Tensor, offsets: torch.Tensor,
                 base_height_target: float) -> torch.Tensor:
        """:meth:`HostTerrain.scandots` on the device: (N, K) float32, ``offsets`` (K, 2) there."""
        ground = pos[:, 2:3] - base_height_target
        return (self.heights(yaw_frame_points(pos[:, :2], yaw, offsets)) - ground).clamp(-1.0, 1.0)
