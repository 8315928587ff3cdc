"""Adding the terrain to a :class:`mujoco.MjSpec`: one heightfield asset + geom, obstacle geoms.

* The heightfield geom is named ``"terrain"`` (asset ``"terrain_hfield"``), geom group 0.
* Obstacles are named ``"obstacle_<k>_<role>"`` (rock meshes ``"obstacle_mesh_<k>"``), geom
  group 1. All are static children of ``spec.worldbody``, condim 3, MuJoCo's default collision
  class (contype = conaffinity = 1).
* MuJoCo stores hfield elevations normalised to [0, 1] and places them at
  ``geom z + data * size[2]``; the geom sits at the lowest sample height (which may be
  negative: ditches, pits), ``size[2]`` is the height range, and the base box reaches
  ``base_depth`` below the lowest sample, so nothing can pass under the terrain.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .obstacles import Obstacle

__all__ = [
    "HFIELD_ASSET",
    "HFIELD_GEOM",
    "OBSTACLE_PREFIX",
    "TERRAIN_GROUP",
    "OBSTACLE_GROUP",
    "add_terrain_to_spec",
    "obstacle_geom_name",
]

HFIELD_ASSET = "terrain_hfield"
HFIELD_GEOM = "terrain"
OBSTACLE_PREFIX = "obstacle_"
TERRAIN_GROUP = 0
OBSTACLE_GROUP = 1
_MIN_RANGE = 1e-3
_GROUND_RGBA = (0.55, 0.50, 0.40, 1.0)
_RGBA = {
    "tree": (0.40, 0.26, 0.13, 1.0),
    "log": (0.45, 0.30, 0.15, 1.0),
    "hurdle": (0.80, 0.45, 0.15, 1.0),
    "rock": (0.50, 0.50, 0.50, 1.0),
    "boulder": (0.45, 0.45, 0.47, 1.0),
}


def obstacle_geom_name(index: int, ob: Obstacle) -> str:
    """MuJoCo geom name of obstacle ``index``."""
    return f"{OBSTACLE_PREFIX}{index:04d}_{ob.role}"


def add_terrain_to_spec(
    spec: mujoco.MjSpec,
    bare: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    obstacles: list[Obstacle],
    base_depth: float = 1.0,
    friction: float = 1.0,
) -> list[str]:
    """Add heightfield + obstacles to ``spec.worldbody``.

    Args:
        spec: the model spec (typically holding the robot already).
        bare: (nx, ny) heights, sample (i, j) at ``origin + (i, j) * resolution`` (x-major).
        origin: world (x, y) of sample (0, 0).
        resolution: sample spacing, metres.
        obstacles: obstacle geoms in world coordinates.
        base_depth: heightfield base box depth below the lowest sample, metres.
        friction: sliding friction of the heightfield geom.

    Returns:
        Names of the added geoms (the heightfield first).
    """
    if spec.geom(HFIELD_GEOM) is not None or spec.hfield(HFIELD_ASSET) is not None:
        raise ValueError(
            f"the spec already holds a terrain ('{HFIELD_GEOM}'); add_to_spec may be called once per spec"
        )
    bare = np.asarray(bare, dtype=np.float64)
    nx, ny = bare.shape
    zmin, zmax = float(bare.min()), float(bare.max())
    span = zmax - zmin
    if span < _MIN_RANGE:
        norm = np.zeros_like(bare)
        span = _MIN_RANGE
    else:
        norm = (bare - zmin) / span
    rx = (nx - 1) * resolution / 2.0
    ry = (ny - 1) * resolution / 2.0
    hf = spec.add_hfield()
    hf.name = HFIELD_ASSET
    hf.nrow = ny  # MuJoCo rows run along y, columns along x
    hf.ncol = nx
    hf.size = [rx, ry, span, float(base_depth)]
    hf.userdata = norm.T.astype(np.float32).ravel().tolist()
    g = spec.worldbody.add_geom()
    g.name = HFIELD_GEOM
    g.type = mujoco.mjtGeom.mjGEOM_HFIELD
    g.hfieldname = HFIELD_ASSET
    g.pos = [origin[0] + rx, origin[1] + ry, zmin]
    g.group = TERRAIN_GROUP
    g.condim = 3
    g.friction = [float(friction), 0.005, 0.0001]
    g.rgba = list(_GROUND_RGBA)
    names = [HFIELD_GEOM]
    for k, ob in enumerate(obstacles):
        geom = spec.worldbody.add_geom()
        geom.name = obstacle_geom_name(k, ob)
        geom.group = OBSTACLE_GROUP
        geom.condim = 3
        geom.friction = [float(ob.friction), 0.005, 0.0001]
        geom.rgba = list(_RGBA.get(ob.role, (0.55, 0.45, 0.35, 1.0)))
        geom.pos = ob.pos.tolist()
        geom.quat = ob.quat.tolist()
        if ob.kind == "box":
            geom.type = mujoco.mjtGeom.mjGEOM_BOX
            geom.size = ob.size.tolist()
        elif ob.kind == "cylinder":
            geom.type = mujoco.mjtGeom.mjGEOM_CYLINDER
            geom.size = [float(ob.size[0]), float(ob.size[1]), 0.0]
        else:
            mesh = spec.add_mesh()
            mesh.name = f"{OBSTACLE_PREFIX}mesh_{k:04d}"
            mesh.uservert = np.asarray(ob.mesh_vertices, dtype=np.float32).ravel().tolist()
            mesh.userface = np.asarray(ob.mesh_faces, dtype=np.int32).ravel().tolist()
            geom.type = mujoco.mjtGeom.mjGEOM_MESH
            geom.meshname = mesh.name
        names.append(geom.name)
    return names
