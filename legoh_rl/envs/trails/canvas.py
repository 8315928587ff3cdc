"""A tile under construction: patches are laid one after another along +x.

Tile frame (also the frame of :class:`~legoh_rl.envs.trails.trail.Trail`): x from the tile's
start edge, y centred on the tile's centre line, z absolute (the start pad is at z = 0).
"""

from __future__ import annotations

import numpy as np

from .obstacles import Obstacle
from .patch import Patch, Spot, axes, num_samples, rough_field, taper

__all__ = ["TileCanvas"]


class TileCanvas:
    """Mutable heightfield, pit mask and obstacle list of one tile.

    Args:
        length: tile length along the trail, metres.
        width: tile width, metres.
        resolution: sample spacing, metres.

    Attributes:
        heights: (nx, ny) ground heights.
        pit: (nx, ny) bool pit samples.
        obstacles: obstacles in the tile frame.
        cursor: next free sample index along x.
        elev: ground height at the cursor.
        params: difficulty parameters recorded while building, name -> list of values.
        frictions: ground friction of every placed patch.
    """

    def __init__(self, length: float, width: float, resolution: float) -> None:
        self.resolution = float(resolution)
        self.width = float(width)
        self.nx = num_samples(length, resolution)
        self.xs, self.ys = axes(self.nx, width, resolution)
        self.ny = self.ys.size
        self.heights = np.zeros((self.nx, self.ny))
        self.pit = np.zeros((self.nx, self.ny), dtype=bool)
        self.obstacles: list[Obstacle] = []
        self.cursor = 0
        self.elev = 0.0
        self.params: dict[str, list[float]] = {}
        self.frictions: list[float] = []
        self.sections: list[str] = []

    @property
    def length(self) -> float:
        """Tile length, metres."""
        return self.nx * self.resolution

    def x_of(self, index: int) -> float:
        """x of sample ``index``."""
        return index * self.resolution

    def record(self, name: str, value: float) -> None:
        """Append a parameter value to ``params[name]``."""
        self.params.setdefault(name, []).append(float(value))

    def flat_to(self, index: int) -> None:
        """Fill samples [cursor, index) with flat ground at the current elevation."""
        index = min(int(index), self.nx)
        if index > self.cursor:
            self.heights[self.cursor : index] = self.elev
            self.cursor = index

    def place(self, patch: Patch) -> list[Spot]:
        """Lay ``patch`` at the cursor; return its goal spots in the tile frame."""
        if patch.heights.shape[1] != self.ny:
            raise ValueError(
                f"patch {patch.name!r} has {patch.heights.shape[1]} samples across, tile has {self.ny}"
            )
        if self.cursor + patch.nx > self.nx:
            raise ValueError(
                f"patch {patch.name!r} ({patch.nx} samples) does not fit after sample {self.cursor}"
            )
        c, n = self.cursor, patch.nx
        dx = self.x_of(c)
        self.heights[c : c + n] = patch.heights + self.elev
        self.pit[c : c + n] = patch.pit
        self.obstacles.extend(o.translated(dx, 0.0, self.elev) for o in patch.obstacles)
        for k, v in patch.params.items():
            self.record(k, v)
        self.frictions.append(patch.friction)
        self.cursor += n
        self.elev += patch.exit_height
        return [s.shifted(dx) for s in patch.spots]

    def add_noise(
        self, amplitude: float, i0: int, i1: int, rng: np.random.Generator, ramp: float = 0.3
    ) -> None:
        """Add uneven ground of +-amplitude over samples [i0, i1), tapered to 0 at both ends."""
        if amplitude <= 0 or i1 - i0 < 3:
            return
        n = i1 - i0
        noise = (
            rough_field((n, self.ny), amplitude, self.resolution, rng)
            * taper(n, self.resolution, ramp)[:, None]
        )
        self.heights[i0:i1] += noise

    def add_profile(self, profile: np.ndarray) -> None:
        """Add a base elevation profile (nx,) along x to the whole tile (obstacles follow on settle)."""
        self.heights += np.asarray(profile, dtype=np.float64)[:, None]

    def _footprint_samples(self, ob: Obstacle) -> tuple[slice, slice, np.ndarray]:
        fp = ob.footprint
        res = self.resolution
        i0 = max(int(np.floor(fp[:, 0].min() / res)) - 1, 0)
        i1 = min(int(np.ceil(fp[:, 0].max() / res)) + 2, self.nx)
        j0 = max(int(np.floor((fp[:, 1].min() - self.ys[0]) / res)) - 1, 0)
        j1 = min(int(np.ceil((fp[:, 1].max() - self.ys[0]) / res)) + 2, self.ny)
        px, py = np.meshgrid(self.xs[i0:i1], self.ys[j0:j1], indexing="ij")
        inside = ob.footprint_distance(np.stack([px, py], axis=-1)) <= res / 2.0
        return slice(i0, i1), slice(j0, j1), inside

    def settle(self) -> None:
        """Move every obstacle vertically so its bottom is ``embed`` below the lowest non-pit
        ground sample under (half a sample around) its footprint."""
        settled = []
        for ob in self.obstacles:
            si, sj, inside = self._footprint_samples(ob)
            ground = self.heights[si, sj]
            ok = inside & ~self.pit[si, sj]
            if ok.any():
                g = float(ground[ok].min())
            elif inside.any():
                g = float(ground[inside].min())
            else:
                i = int(np.clip(round(ob.pos[0] / self.resolution), 0, self.nx - 1))
                j = int(np.clip(round((ob.pos[1] - self.ys[0]) / self.resolution), 0, self.ny - 1))
                g = float(self.heights[i, j])
            settled.append(ob.translated(0.0, 0.0, g - ob.embed - ob.bottom))
        self.obstacles = settled
