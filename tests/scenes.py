"""Hand-made terrains with known geometry for env tests (implement the env's TrailSource)."""

from __future__ import annotations

import mujoco
import numpy as np


class BoxScene:
    """Flat ground plus axis-aligned boxes; straight trails along +x, one tile per level.

    Args:
        boxes: list of (center (3,), half sizes (3,)) in world coordinates.
        trail_length: |P_B - P_A| of every tile, m.
        num_levels: tiles (all identical, one per level) so curricula can move.
        goal_spacing: distance between expert goals, m.
        edge_x: x positions of edge lines (for feet-edge tests), or none.
        pit_x: (x_lo, x_hi) of a band of samples marked as pit (for feet-in-pit tests; the ground
            stays flat), or none.
    """

    categories = ("flat",)

    def __init__(self, boxes=(), trail_length=6.0, num_levels=5, goal_spacing=1.5, edge_x=(), pit_x=None):
        self.boxes = [(np.asarray(c, float), np.asarray(h, float)) for c, h in boxes]
        self.num_levels = num_levels
        self.edge_x = np.asarray(edge_x, float)
        self.pit_x = pit_x
        T = num_levels
        self.tile_level = np.arange(T)
        self.tile_category = np.zeros(T, dtype=np.int64)
        self.tile_start = np.zeros((T, 3))
        self.tile_end = np.tile([trail_length, 0.0, 0.0], (T, 1))
        self.tile_waypoint = np.tile([trail_length / 2, 0.0, 0.0], (T, 1))
        xs = np.arange(goal_spacing, trail_length - 1e-6, goal_spacing)
        self.tile_goals = np.tile(np.stack([xs, 0 * xs, 0 * xs], 1)[None], (T, 1, 1))
        self.tile_num_goals = np.full(T, xs.size)

    def add_to_spec(self, spec):
        floor = spec.worldbody.add_geom()
        floor.name = "terrain_floor"
        floor.type = mujoco.mjtGeom.mjGEOM_PLANE
        floor.size = [0, 0, 0.05]
        for i, (c, h) in enumerate(self.boxes):
            g = spec.worldbody.add_geom()
            g.name = f"obstacle_{i}"
            g.group = 1
            g.type = mujoco.mjtGeom.mjGEOM_BOX
            g.pos = c.tolist()
            g.size = h.tolist()

    def height_at(self, xy):
        xy = np.asarray(xy)
        h = np.zeros(xy.shape[0])
        for c, s in self.boxes:
            inside = (np.abs(xy[:, 0] - c[0]) <= s[0]) & (np.abs(xy[:, 1] - c[1]) <= s[1])
            h = np.where(inside, np.maximum(h, c[2] + s[2]), h)
        return h

    def ground_height_at(self, xy):
        return np.zeros(np.asarray(xy).shape[0])

    def edge_at(self, xy):
        xy = np.asarray(xy)
        if self.edge_x.size == 0:
            return np.zeros(xy.shape[0], dtype=bool)
        return (np.abs(xy[:, 0:1] - self.edge_x[None]) < 0.05).any(axis=1)

    def pit_at(self, xy):
        xy = np.asarray(xy)
        if self.pit_x is None:
            return np.zeros(xy.shape[0], dtype=bool)
        return (xy[:, 0] >= self.pit_x[0]) & (xy[:, 0] <= self.pit_x[1])
