"""A terrain patch (what a primitive returns) and the sampling helpers primitives share.

Patch frame: x runs along the trail from the patch entry (sample i at ``x = i * resolution``),
y across it, centred on the tile's centre line (sample j at
``y = -width / 2 + j * resolution``), z relative to the ground height at the entry.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import map_coordinates

from .obstacles import Obstacle

__all__ = ["Spot", "Patch", "num_samples", "axes", "rough_field", "taper"]


@dataclass(frozen=True)
class Spot:
    """A place where an expert goal belongs (take-off, landing, stone centre, crest...).

    Attributes:
        x, y: position in the owner frame (patch or tile), metres.
        kind: "takeoff", "landing", "stone", "bottom", "crest", "top", "passage".
    """

    x: float
    y: float
    kind: str

    def shifted(self, dx: float) -> Spot:
        """The same spot moved by ``dx`` along the trail."""
        return Spot(self.x + dx, self.y, self.kind)


@dataclass
class Patch:
    """The output of a terrain primitive.

    Attributes:
        name: primitive name.
        heights: (nx, ny) ground heights in metres relative to the entry height.
        pit: (nx, ny) bool, samples that are pits (no footing).
        obstacles: obstacle geoms in the patch frame (they are settled on the ground later).
        spots: goal spots in the patch frame, in crossing order.
        exit_height: height of the last sample row (the entry height of the next patch).
        friction: sliding friction of the ground of this patch.
        params: the difficulty parameters drawn for this patch (``levels.PARAMS`` names), plus
            realised values (e.g. ``gap_width_realised``).
        resolution: sample spacing, metres.
    """

    name: str
    heights: np.ndarray
    pit: np.ndarray
    obstacles: list[Obstacle] = field(default_factory=list)
    spots: list[Spot] = field(default_factory=list)
    exit_height: float = 0.0
    friction: float = 1.0
    params: dict[str, float] = field(default_factory=dict)
    resolution: float = 0.1

    @property
    def nx(self) -> int:
        """Samples along the trail."""
        return int(self.heights.shape[0])

    @property
    def length(self) -> float:
        """Length along the trail, metres (``nx * resolution``)."""
        return self.nx * self.resolution


def num_samples(length: float, resolution: float) -> int:
    """Samples covering ``length`` metres (at least 1)."""
    return max(1, int(round(length / resolution)))


def axes(nx: int, width: float, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample coordinates of a patch: x (nx,) from 0, y (ny,) centred on the trail line."""
    ny = num_samples(width, resolution)
    return np.arange(nx) * resolution, np.arange(ny) * resolution - width / 2.0


def rough_field(
    shape: tuple[int, int],
    amplitude: float,
    resolution: float,
    rng: np.random.Generator,
    cell: float = 0.4,
) -> np.ndarray:
    """Smooth random heights in [-amplitude, amplitude], shape ``shape``.

    Uniform values on a lattice of ``cell`` metres, bilinearly interpolated to the samples (so
    the slope between neighbour samples stays below ``2 * amplitude * resolution / cell``).
    """
    nx, ny = shape
    step = resolution / cell
    cx = int(np.ceil((nx - 1) * step)) + 2
    cy = int(np.ceil((ny - 1) * step)) + 2
    coarse = rng.uniform(-amplitude, amplitude, size=(cx, cy))
    ii, jj = np.meshgrid(np.arange(nx) * step, np.arange(ny) * step, indexing="ij")
    return map_coordinates(coarse, [ii, jj], order=1, mode="nearest")


def taper(nx: int, resolution: float, ramp: float) -> np.ndarray:
    """(nx,) window: 0 at both ends, rising linearly to 1 over ``ramp`` metres."""
    x = np.arange(nx) * resolution
    length = (nx - 1) * resolution
    return np.clip(np.minimum(x, length - x) / max(ramp, 1e-9), 0.0, 1.0)
