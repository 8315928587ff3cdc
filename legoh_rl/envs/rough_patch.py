"""A small random rough terrain (heightfield + box obstacles) for physics tests and benchmarks.

It stands apart from the trail generator (``legoh_rl.envs.trails``) on purpose: physics
measurements must not change when the trails change.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["RoughPatch"]


@dataclass
class RoughPatch:
    """Uneven ground of ``size`` x ``size`` metres with ``num_boxes`` box obstacles.

    Implements ``add_to_spec`` (see :class:`legoh_rl.envs.robots.TerrainBuilder`).

    Args:
        size: side of the square patch, m (centred on the origin).
        resolution: heightfield cell size, m.
        roughness: peak-to-peak height noise, m.
        num_boxes: obstacle boxes scattered outside a 1.5 m clear disc around the origin.
        box_height: maximum box height, m.
        seed: seed of the heights and box placement.
    """

    size: float = 16.0
    resolution: float = 0.1
    roughness: float = 0.06
    num_boxes: int = 50
    box_height: float = 0.15
    seed: int = 0

    def heights(self) -> np.ndarray:
        """Heightfield, (n, n) metres, row = y, column = x."""
        rng = np.random.default_rng(self.seed)
        n = int(round(self.size / self.resolution)) + 1
        return rng.uniform(0.0, self.roughness, size=(n, n))

    def add_to_spec(self, spec: mujoco.MjSpec) -> None:
        """Add the heightfield and the boxes to ``spec.worldbody``."""
        h = self.heights()
        n = h.shape[0]
        top = max(float(h.max()), 1e-6)
        hf = spec.add_hfield()
        hf.name = "rough_patch"
        hf.nrow, hf.ncol = n, n
        hf.size = [self.size / 2, self.size / 2, top, 0.5]
        hf.userdata = (h / top).astype(np.float32).flatten().tolist()
        geom = spec.worldbody.add_geom()
        geom.name = "terrain_rough_patch"
        geom.type = mujoco.mjtGeom.mjGEOM_HFIELD
        geom.hfieldname = "rough_patch"
        rng = np.random.default_rng(self.seed + 1)
        placed = 0
        while placed < self.num_boxes:
            x, y = rng.uniform(-self.size / 2 + 0.5, self.size / 2 - 0.5, size=2)
            if np.hypot(x, y) < 1.5:
                continue
            hx, hy = rng.uniform(0.1, 0.4, size=2)
            hz = rng.uniform(0.03, self.box_height) / 2
            box = spec.worldbody.add_geom()
            box.name = f"obstacle_box_{placed}"
            box.group = 1
            box.type = mujoco.mjtGeom.mjGEOM_BOX
            box.size = [hx, hy, hz]
            box.pos = [x, y, hz]
            placed += 1
